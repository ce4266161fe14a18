#!/usr/bin/env python
"""The diagnosis's time with the first-order vs the second-order stepper, side by side (issue 12, item 3).

Two comparisons, each run case by case, alternating, one diagnosis process at a time per lane (--jobs 1,
NUMBA_NUM_THREADS=1, nice 5), every process fresh (a kernel cache per tree, warmed first):

  ab     tree A = b232b5f (first-order stepper, choose_substeps among 20/40/80/160, screening at 20) against
         tree B = 1d52dd5 (the merge that brought the second-order stepper, 5/10/20/40/80, screening at 10).
         Extract them outside git first:  git -C MAIN archive b232b5f | tar -x -C out/A  (1d52dd5 -> out/B),
         a venv in each (pip install -e '.[dev]'). B runs the proof's case first and keeps its two recordings
         (pickled); A diagnoses exactly those recordings, so the inputs are identical.
  today  this tree (the script's own), the same proof cases: the diagnosis at the substeps tree A chose for that
         case (Options.substeps forced: the time today's diagnosis would spend if it still needed first-order
         steps) against the default choice. The default run keeps the recordings, the forced run reuses them.
  summary  per-case table and medians of the rows in --out.

Per run the row holds the proof's results (named effect(s), verdict, RMS after, held-out RMS after / the noise
the truth added) and the diagnosis's own wall and CPU time (resource.getrusage around ``diagnose``), its
``integrator_substeps`` and, where the tree reports it, ``elapsed_breakdown_s``.

    python scripts/stepper_diagnosis_ab.py ab --a-tree out/A --b-tree out/B --out out/ab \\
        --families clean coil_heating --seeds 0 1 2 --duration 10 --warm
    python scripts/stepper_diagnosis_ab.py today --out out/ab          # after (or while) `ab` runs
    python scripts/stepper_diagnosis_ab.py summary --out out/ab
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve()
ROOT = HERE.parents[1]


# ---------------------------------------------------------------- worker: one proof case in one tree's venv
def worker(a) -> int:
    import pickle
    import resource
    from argparse import Namespace

    from etb_gym.diagnose import proof
    from etb_gym.diagnose import run as run_mod

    share = Path(a.share)
    share.mkdir(parents=True, exist_ok=True)
    made = []

    def make_recording(*args, **kw):                # keep (mode save) or replay (mode load) the case's recordings
        k = len(made)
        made.append(k)
        f = share / f"{a.case}_{a.seed}_{k}.pkl"
        if a.recs == "load":
            with open(f, "rb") as fh:
                return pickle.load(fh)
        rec = real_make(*args, **kw)
        if a.recs == "save":
            with open(f, "wb") as fh:
                pickle.dump(rec, fh)
        return rec

    real_make = proof.make_recording
    proof.make_recording = make_recording
    timing = {}

    def diagnose(*args, **kw):                      # the diagnosis alone: wall and CPU (this process + children)
        opts = kw.get("options")
        if a.substeps:
            import dataclasses
            kw["options"] = dataclasses.replace(opts, substeps=a.substeps)
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        res = run_mod.diagnose(*args, **kw)
        timing["diag_wall_s"] = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        timing["diag_cpu_s"] = (r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime
                                + c1.ru_utime + c1.ru_stime - c0.ru_utime - c0.ru_stime)
        rep = res.report
        timing["substeps"] = rep.get("integrator_substeps")
        timing["elapsed_breakdown_s"] = rep.get("elapsed_breakdown_s")
        return res

    proof.diagnose = diagnose
    args = Namespace(duration=a.duration, jobs=1, max_effects=2, candidates=None, nameplate=a.nameplate,
                     truth_substeps=200)
    if hasattr(proof, "_parser"):                   # today's proof: its own defaults, then the same settings
        args = proof._parser().parse_args(["--duration", str(a.duration), "--jobs", "1", "--nameplate", a.nameplate])
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    row, _ = proof.run_case(a.case, a.seed, args, str(work))
    keep = ("family", "seed", "closed", "noise_deg", "nameplate", "effects", "verdict", "named", "rms_before",
            "rms_after", "noise_floor", "heldout_rms_before", "heldout_rms_after", "true_noise", "effect_size",
            "time_s", "cpu_s")
    out = {"label": a.label, "case": a.case, **{k: row.get(k) for k in keep}, **timing,
           "forced_substeps": a.substeps, "process_wall_s": time.perf_counter() - t0,
           "twin": row["heldout_rms_after"] / row["true_noise"]}
    print("ROW " + json.dumps(out, default=float), flush=True)
    return 0


# ---------------------------------------------------------------- driver
def run_one(tree: Path, label: str, case: str, seed: int, a, recs: str, substeps: int | None = None,
            duration: float | None = None) -> dict | None:
    """One fresh worker process in ``tree``'s venv; returns its row (None if it failed)."""
    out = Path(a.out).resolve()                     # the worker runs in the tree: absolute paths only
    env = dict(os.environ, ETB_GYM_CACHE=str(tree / ".kcache"), NUMBA_NUM_THREADS="1", PYTHONHASHSEED="0")
    cmd = ["nice", "-n", "5", str(tree / ".venv" / "bin" / "python"), str(HERE), "worker", "--label", label,
           "--case", case, "--seed", str(seed), "--duration", str(duration or a.duration), "--nameplate", a.nameplate,
           "--share", str(out / "recs" / ("today" if label.startswith("today") else "ab")),
           "--work", str(out / "work" / label), "--recs", recs]
    if substeps:
        cmd += ["--substeps", str(substeps)]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=str(tree), env=env, capture_output=True, text=True)
    rows = [json.loads(x[4:]) for x in p.stdout.splitlines() if x.startswith("ROW ")]
    if p.returncode or not rows:
        print(f"  {label} {case} s{seed}: FAILED (exit {p.returncode})\n{p.stderr[-2000:]}", file=sys.stderr)
        return None
    row = rows[0]
    print(f"  {label:8s} {case:24s} s{seed}: {row['substeps']:3d} substeps, diagnosis {row['diag_cpu_s']:6.1f} s CPU "
          f"{row['diag_wall_s']:6.1f} s wall (process {time.perf_counter() - t0:.0f} s); {row['verdict']} "
          f"{row['effects']} twin {row['twin']:.2f}", flush=True)
    return row


def append(path: Path, row: dict) -> None:
    with open(path, "a") as fh:
        fh.write(json.dumps(row, default=float) + "\n")


def read(path: Path) -> list:
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()] if path.exists() else []


def cases(a):
    """Every (family, seed), in rounds that rotate the seeds over the families, so that a run cut short still
    has both loops and both noise levels (seed 0 open 0.01 deg, 1 closed 0.01, 2 open 0.03, 3 closed 0.03)."""
    S, F = a.seeds, a.families
    return [(f, S[(k + j) % len(S)]) for k in range(len(S)) for j, f in enumerate(F)]


def warm(a, trees):
    for label, tree in trees:
        if a.warm and label not in a.warm:
            continue
        for f in a.families:
            print(f"warming {label} ({f}, 2 s)", flush=True)
            run_one(tree, label + "_warm", f, 0, a, "none", duration=2.0)


def cmd_ab(a):
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    A, B = Path(a.a_tree).resolve(), Path(a.b_tree).resolve()
    if a.warm is not None:
        warm(a, [("A", A), ("B", B)])
    rows_file = out / "ab_rows.jsonl"
    done = {(r["label"], r["case"], r["seed"]) for r in read(rows_file)}
    for case, seed in cases(a):
        for label, tree, recs in (("B", B, "save"), ("A", A, "load")):   # B keeps the recordings, A replays them
            if (label, case, seed) in done:
                continue
            row = run_one(tree, label, case, seed, a, recs)
            if row:
                append(rows_file, row)


def cmd_today(a):
    out = Path(a.out)
    ab = out / "ab_rows.jsonl"
    rows_file = out / "today_rows.jsonl"
    if a.warm is not None:
        warm(a, [("today", ROOT)])
    done = {(r["label"], r["case"], r["seed"]) for r in read(rows_file)}
    todo = cases(a)
    while todo:
        chosen = {(r["case"], r["seed"]): r["substeps"] for r in read(ab) if r["label"] == "A"}
        ready = [c for c in todo if c in chosen]
        if not ready:
            if not a.wait:
                print(f"no A row yet in {ab} for {todo}: run `ab` first (or --wait)", file=sys.stderr)
                return 1
            time.sleep(20)
            continue
        case, seed = ready[0]
        todo.remove((case, seed))
        for label, n, recs in (("today", None, "save"), ("today_n", chosen[(case, seed)], "load")):
            if (label, case, seed) not in done:
                row = run_one(ROOT, label, case + "", seed, a, recs, substeps=n)
                if row:
                    append(rows_file, row)
    return 0


def med(xs):
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else float("nan")


def pair_table(rows, x, y, title):
    """Per case: y vs x (substeps, CPU, wall, results) and the medians."""
    by = {(r["label"], r["case"], r["seed"]): r for r in rows}
    keys = sorted({(r["case"], r["seed"]) for r in rows}, key=lambda k: (k[1], k[0]))
    L = [f"### {title}", "",
         f"| case | seed | loop | noise | substeps {x} / {y} | CPU {x} / {y} [s] | ratio | wall {x} / {y} [s] | "
         f"effects {x} / {y} | verdict {x} / {y} | RMS after {x} / {y} | twin {x} / {y} |",
         "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    cx, cy, wx, wy = [], [], [], []
    same = 0
    for c, s in keys:
        p, q = by.get((x, c, s)), by.get((y, c, s))
        if not p or not q:
            continue
        cx.append(p["diag_cpu_s"]), cy.append(q["diag_cpu_s"]), wx.append(p["diag_wall_s"]), wy.append(q["diag_wall_s"])
        same += p["effects"] == q["effects"] and p["verdict"] == q["verdict"]
        nm = lambda r: ",".join(r["effects"]) or "-"
        L.append(f"| {c} | {s} | {'closed' if p['closed'] else 'open'} | {p['noise_deg']} | {p['substeps']} / "
                 f"{q['substeps']} | {p['diag_cpu_s']:.1f} / {q['diag_cpu_s']:.1f} | {q['diag_cpu_s'] / p['diag_cpu_s']:.2f} | "
                 f"{p['diag_wall_s']:.1f} / {q['diag_wall_s']:.1f} | {nm(p)} / {nm(q)} | {p['verdict']} / {q['verdict']} | "
                 f"{p['rms_after']:.4f} / {q['rms_after']:.4f} | {p['twin']:.2f} / {q['twin']:.2f} |")
    if cx:
        L += ["", f"{len(cx)} cases, same effects and verdict {same}/{len(cx)}. Median CPU {x} {med(cx):.1f} s, {y} "
              f"{med(cy):.1f} s: {y}/{x} = {med(cy) / med(cx):.2f} (change {med(cy) / med(cx) - 1:+.0%}); median of the "
              f"per-case ratios {med([b / a for a, b in zip(cx, cy)]):.2f}. Median wall {x} {med(wx):.1f} s, {y} "
              f"{med(wy):.1f} s: {med(wy) / med(wx):.2f}. Total CPU {sum(cx):.0f} s -> {sum(cy):.0f} s "
              f"({sum(cy) / sum(cx):.2f})."]
    return "\n".join(L)


def breakdown(rows, label):
    """Median share of the diagnosis's stages (elapsed_breakdown_s) over ``label``'s rows."""
    bs = [r["elapsed_breakdown_s"] for r in rows if r["label"] == label and r.get("elapsed_breakdown_s")]
    if not bs:
        return ""
    names = list(dict.fromkeys(k for b in bs for k in b))
    tot = sum(sum(v for v in b.values() if isinstance(v, (int, float))) for b in bs)
    return (f"{label}: where the diagnosis's wall time goes (sum over {len(bs)} runs, elapsed_breakdown_s): "
            + ", ".join(f"{k} {sum(b.get(k, 0.0) for b in bs):.0f} s ({sum(b.get(k, 0.0) for b in bs) / tot:.0%})"
                        for k in names))


def cmd_summary(a):
    out = Path(a.out)
    ab, td = read(out / "ab_rows.jsonl"), read(out / "today_rows.jsonl")
    parts = []
    if ab:
        parts.append(pair_table(ab, "A", "B", "A = b232b5f (first order) vs B = 1d52dd5 (second order), same recordings"))
    if td:
        parts.append(pair_table(td, "today_n", "today",
                                "today's tree: substeps forced to A's choice (today_n) vs its own choice (today)"))
        parts.append(breakdown(td, "today"))
        parts.append(breakdown(td, "today_n"))
    print("\n\n".join(p for p in parts if p))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0], epilog=__doc__.split("\n", 2)[2],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)

    def common(p):
        p.add_argument("--out", required=True, help="folder of the rows (ab_rows.jsonl, today_rows.jsonl), "
                                                    "the kept recordings and the diagnoses' output")
        p.add_argument("--families", nargs="+", default=["clean", "coil_heating", "stribeck_friction", "supply_drop",
                                                          "end_stop_compliance"])
        p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3], help="the proof's seeds (default 0-3: "
                       "both loops, both noise levels)")
        p.add_argument("--duration", type=float, default=10.0, help="recording length [s] (default 10)")
        p.add_argument("--nameplate", choices=("3B", "random"), default="3B")
        p.add_argument("--warm", nargs="*", default=None, help="first one 2 s case per family in each tree "
                       "(compiles; the kernel caches are kept), or in the trees named (A, B, today)")

    p = sub.add_parser("ab", help="tree A vs tree B, alternating case by case")
    common(p)
    p.add_argument("--a-tree", required=True, help="extracted b232b5f with its .venv")
    p.add_argument("--b-tree", required=True, help="extracted 1d52dd5 with its .venv")
    p = sub.add_parser("today", help="this tree: substeps forced to A's choice vs the default choice")
    common(p)
    p.add_argument("--wait", action="store_true", help="wait for A's rows (run alongside `ab`)")
    p = sub.add_parser("summary", help="the per-case tables and medians")
    p.add_argument("--out", required=True)
    p = sub.add_parser("worker", help="(internal) one case in the current interpreter's tree")
    for k in ("--label", "--case", "--share", "--work", "--recs"):
        p.add_argument(k, required=True)
    p.add_argument("--seed", type=int, required=True)
    p.add_argument("--duration", type=float, required=True)
    p.add_argument("--nameplate", default="3B")
    p.add_argument("--substeps", type=int, default=None)
    a = ap.parse_args(argv)
    return {"ab": cmd_ab, "today": cmd_today, "summary": cmd_summary, "worker": worker}[a.cmd](a) or 0


if __name__ == "__main__":
    sys.exit(main())
