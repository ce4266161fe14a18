"""Naming survey (issue 15): is the concealed effect named first when its truth shape is NOT the candidate's formula,
on the default 3B and on random nameplates, in open and closed loop?

One case per (family, truth shape, nameplate, loop), each the proof's own case (``proof.run_case``: the same truth,
recording, plant file and scoring). The proof alternates the loop with the seed (even seeds open, odd closed,
``proof.record_and_diagnose``), so loop ``open`` is seed ``2 k`` and ``closed`` seed ``2 k + 1`` (k = --seed-index).
Families: the catalogue's (shapes 1 and 2, never the candidate's formula), ``clean`` and the two outside the
catalogue (detent_torque, current_ripple; shape 0 only).

Rows go to --out (JSON lines, one per case, appended whole as each case finishes); an existing file is resumed
(cases already there are skipped). --summary prints the tables (Markdown) of one or two row files side by side.

    nice -n 10 python scripts/naming_survey.py --out out/survey_before.jsonl --jobs 1
    python scripts/naming_survey.py --summary out/survey_before.jsonl out/survey_after.jsonl
    python scripts/naming_survey.py --out out/survey_after.jsonl --redo-misses out/survey_before.jsonl
    python scripts/naming_survey.py --out out/survey_after.jsonl --same-as out/survey_before.jsonl
    python scripts/naming_survey.py --out out/s.jsonl --seed-index 1 2 --loops closed --keep out/s_reports
    python scripts/naming_survey.py --out out/r.jsonl --nameplates random --loops open --rotate --seed-index 3 4 5

Rows keep the diagnosis's CPU time (report.json ``cpu_s``; the summary scales it to a 10 s recording) and, on
closed loops, the effect's footprint as the observer residual sees it (``effect_size_observer``: the replay
footprint ``effect_size`` overstates what a closed loop shows; docs/diagnosis-history.md, "Survey subset").
"""
from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

CLEAN = "clean"
DETECTABLE = 3.0
KEEP = ("family", "seed", "nameplate", "closed", "loop_detected", "verdict", "effects", "outside", "named",
        "effect_size", "effect_size_observer", "catalogue_given", "period_deg", "period_true_deg", "rms_before", "rms_after", "noise_floor",
        "heldout_rms_before", "heldout_rms_after", "true_noise", "time_s", "cpu_s", "skipped")


def plan(families, shapes, nameplates, loops, seed_indices, rotate=False):
    """Every (family, shape, nameplate, loop, seed index); ``rotate``: one shape and one seed index per family
    instead of all of them, taken in turn from ``shapes`` and ``seed_indices`` by the family's position (so
    a one-case-per-family survey still covers both shapes and spreads its seeds)."""
    from etb_gym.diagnose.proof_truth import FAMILIES, OUTSIDE
    cases = []
    for j, fam in enumerate(families):
        if fam not in FAMILIES:
            raise SystemExit(f"--families: {fam!r} is not a proof family; expected some of {', '.join(FAMILIES)}")
        ks = [0] if (fam == CLEAN or fam in OUTSIDE) else [k for k in shapes if k]
        sis = seed_indices
        if rotate:
            ks, sis = [ks[j % len(ks)]], [seed_indices[j % len(seed_indices)]]
        for k in ks:
            for np_ in nameplates:
                for loop in loops:
                    for si in sis:
                        seed = 2 * si + (1 if loop == "closed" else 0)
                        cases.append({"case": fam if k == 0 else f"{fam}@{k}", "nameplate": np_, "seed": seed,
                                      "loop": loop})
    random.Random(0).shuffle(cases)        # a survey stopped early still covers families, shapes and rigs evenly
    return cases


def key(c) -> tuple:
    return c.get("case", c.get("family")), c["nameplate"], c["seed"]


KEEP_FILES = ("report.json", "report.md")


def run_one(c: dict, duration: float, keep: str | None = None) -> dict:
    """One case; ``keep``: a folder where the case's report (report.json, report.md) is kept for a post-mortem
    (in ``CASE_RIG_SEED/``), else everything is removed with the case's temporary folder."""
    from etb_gym.diagnose import proof
    opts = proof._parser().parse_args(["--duration", str(duration), "--jobs", "1", "--nameplate", c["nameplate"]])
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as work:
        try:
            row, case_out = proof.run_case(c["case"], c["seed"], opts, work)
        except Exception as e:          # a crash is a finding: recorded as such, the survey goes on
            return {"family": c["case"], "nameplate": c["nameplate"], "seed": c["seed"], "loop": c["loop"],
                    "crash": f"{type(e).__name__}: {e}", "time_s": time.perf_counter() - t0}
        if keep:
            dest = Path(keep) / f"{c['case'].replace('@', '_s')}_{c['nameplate']}_{c['seed']}"
            dest.mkdir(parents=True, exist_ok=True)
            for name in KEEP_FILES:
                if (Path(case_out) / name).exists():
                    shutil.copy2(Path(case_out) / name, dest / name)
    out = {k: row.get(k) for k in KEEP}
    out["loop"] = c["loop"]
    out["case"] = c["case"]
    out["duration_s"] = duration
    return out


def read(path: Path) -> list:
    rows = []
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                rows.append(json.loads(line))
            except ValueError:
                pass                     # a torn last line (a killed run): that case is redone
    return rows


def append(path: Path, row: dict) -> None:
    data = (json.dumps(row, default=float) + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, data)
        os.fsync(fd)
    finally:
        os.close(fd)


# ------------------------------------------------------------------------------------------- tables
def kind(r) -> str:
    from etb_gym.diagnose.proof_truth import OUTSIDE
    fam = r["family"].split("@")[0]
    return "clean" if fam == CLEAN else "outside" if fam in OUTSIDE else "catalogue"


def ok(r) -> bool:
    """The target this case counts for: catalogue, named first (detectable only); clean, no effect claimed;
    outside, no catalogue effect given and the period within 10 %."""
    if "crash" in r:
        return False
    return bool(r["named"]) if kind(r) != "clean" else not r["effects"]


def counted(r) -> bool:
    """Clean cases always; effects (catalogue or outside it) when detectable: >= DETECTABLE x the noise."""
    return kind(r) == "clean" or "crash" in r or (r.get("effect_size") or 0.0) >= DETECTABLE


def seen(r) -> bool:
    """A catalogue effect the diagnosis's residual can see: >= DETECTABLE x the noise in the replay footprint
    (open loop) or in the observer's (closed loop: effect_size_observer, what the one-step residual shows)."""
    if "crash" in r:
        return True
    size = r.get("effect_size_observer") if r["loop"] == "closed" else r.get("effect_size")
    return (size or 0.0) >= DETECTABLE


def match(r) -> bool:
    return "crash" not in r and r["verdict"] == "match"


GROUPS = (("detectable catalogue effects named first (>= 90 %)", "catalogue", counted, ok),
          ("... of them, >= 3x in the residual the tool scores (closed loop: observer footprint)", "catalogue",
           seen, ok),
          ("outside the catalogue (detectable): no catalogue effect, period within 10 % (>= 90 %)", "outside", counted,
           ok),
          ("clean: no effect claimed (>= 95 %)", "clean", counted, ok),
          ("clean: verdict match (>= 90 %)", "clean", counted, match))


def rate(rs, use=counted, good=ok) -> str:
    rs = [r for r in rs if use(r)]
    return f"{sum(good(r) for r in rs)}/{len(rs)}" if rs else "-"


def per_10s(r) -> float | None:
    """The diagnosis's CPU time scaled to a 10 s recording (report.json cpu_s x 10 s / the recording's length)."""
    c = r.get("cpu_s")
    return None if c is None else c * 10.0 / r.get("duration_s", 6.0)


def summary(files) -> str:
    sets = [(Path(f).stem, read(Path(f))) for f in files]
    out = []
    hdr = " | ".join(n for n, _ in sets)
    out += [f"| target | rig | loop | {hdr} |", "| --- | --- | --- |" + " --- |" * len(sets)]
    for title, kd, use, good in GROUPS:
        for np_, loop in (("3B", "open"), ("3B", "closed"), ("random", "open"), ("random", "closed"), ("all", "all")):
            cells = []
            for _, rows in sets:
                rs = [r for r in rows if kind(r) == kd and np_ in ("all", r["nameplate"]) and loop in ("all", r["loop"])]
                cells.append(rate(rs, use, good))
            out.append(f"| {title} | {np_} | {loop} | " + " | ".join(cells) + " |")
    out += ["", "| case | rig | loop | " + " | ".join(f"{n}: size, named / effects, verdict" for n, _ in sets) + " |",
            "| --- | --- | --- |" + " --- |" * len(sets)]
    keys = sorted({key(r) for _, rows in sets for r in rows})
    for k in keys:
        cells = []
        for _, rows in sets:
            r = next((x for x in rows if key(x) == k), None)
            if r is None:
                cells.append("")
            elif "crash" in r:
                cells.append(f"CRASH {r['crash'][:80]}")
            else:
                sz = r.get("effect_size")
                mark = ("ok" if ok(r) else "MISS") if counted(r) else "(below 3x)"
                if r.get("effect_size_observer") is not None:
                    mark = f"observer {r['effect_size_observer']:.1f}, " + mark
                eff = ", ".join(r["effects"]) or "-"
                if r.get("outside"):
                    eff += f"; outside ({r['outside']}, period {r.get('period_deg') or 0:.1f}/{r.get('period_true_deg') or 0:.1f})"
                cpu = per_10s(r)
                cells.append(f"{'' if sz is None else f'{sz:.1f}, '}{mark}: {eff}, {r['verdict']}, "
                             + (f"{cpu:.0f} s CPU per 10 s" if cpu is not None else f"{r['time_s']:.0f} s wall"))
        loop = "closed" if k[2] % 2 else "open"
        out.append(f"| {k[0]} | {k[1]} | {loop} | " + " | ".join(cells) + " |")
    for n, rows in sets:
        ts = sorted(r["time_s"] for r in rows)
        cs = sorted(c for c in map(per_10s, rows) if c is not None)
        if ts:
            out.append(f"\n{n}: {len(rows)} cases, diagnosis wall time median "
                       f"{ts[len(ts) // 2]:.0f} s, max {ts[-1]:.0f} s"
                       + (f"; diagnosis CPU per 10 s recording (report cpu_s x 10 s / length, {len(cs)} cases) "
                          f"median {float(np.median(cs)):.1f} s, max {cs[-1]:.1f} s" if cs else ""))
    return "\n".join(out)


def main(argv=None) -> int:
    from etb_gym.diagnose.proof_truth import FAMILIES
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--out", help="rows file (JSON lines); resumed if it exists")
    ap.add_argument("--families", nargs="+", default=list(FAMILIES), help="proof families (default: all)")
    ap.add_argument("--shapes", nargs="+", type=int, default=[1, 2], choices=[1, 2],
                    help="truth shapes of the catalogue's families (default 1 2)")
    ap.add_argument("--nameplates", nargs="+", default=["3B", "random"], choices=["3B", "random"])
    ap.add_argument("--loops", nargs="+", default=["open", "closed"], choices=["open", "closed"])
    ap.add_argument("--seed-index", type=int, nargs="+", default=[0],
                    help="k ...: loop open is seed 2k, closed 2k+1 (default 0)")
    ap.add_argument("--rotate", action="store_true",
                    help="one case per family: its shape and seed index taken in turn from --shapes and --seed-index")
    ap.add_argument("--duration", type=float, default=6.0, help="recording length [s] (default 6)")
    ap.add_argument("--jobs", type=int, default=1, help="cases run in parallel, one core each (default 1)")
    ap.add_argument("--redo-misses", metavar="ROWS", help="only the cases that missed their target (or crashed) in ROWS")
    ap.add_argument("--same-as", metavar="ROWS", help="only the cases that ROWS holds (an after-run of a before-run), "
                    "in ROWS's order")
    ap.add_argument("--limit", type=int, default=None, help="at most this many cases")
    ap.add_argument("--keep", metavar="DIR", help="keep every case's report.json and report.md under DIR "
                    "(default: removed with the case's temporary folder)")
    ap.add_argument("--summary", nargs="+", metavar="ROWS", help="print the tables of these row files and exit")
    a = ap.parse_args(argv)
    if a.summary:
        print(summary(a.summary))
        return 0
    if not a.out:
        ap.error("--out is required (or --summary)")
    if a.duration <= 0:
        ap.error(f"--duration = {a.duration} is invalid: expected a positive length in seconds")
    if a.jobs < 1:
        ap.error(f"--jobs = {a.jobs} is invalid: expected 1 or more")
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cases = plan(a.families, a.shapes, a.nameplates, a.loops, a.seed_index, a.rotate)
    if a.redo_misses:
        prev = {key(r): r for r in read(Path(a.redo_misses))}
        cases = [c for c in cases if key(c) in prev and counted(prev[key(c)]) and not ok(prev[key(c)])]
    if a.same_as:
        order = {key(r): k for k, r in enumerate(read(Path(a.same_as)))}
        cases = sorted((c for c in cases if key(c) in order), key=lambda c: order[key(c)])
    done = {key(r) for r in read(out)}
    todo = [c for c in cases if key(c) not in done][:a.limit]
    from tqdm import tqdm
    bar = tqdm(total=len(todo), unit="case")
    if a.jobs == 1:
        for c in todo:
            r = run_one(c, a.duration, a.keep)
            append(out, r)
            bar.set_description(f"{c['case']} {c['nameplate']} {c['loop']}: {r.get('effects', r.get('crash'))}")
            bar.update(1)
    else:
        with ProcessPoolExecutor(max_workers=a.jobs) as ex:
            futs = {ex.submit(run_one, c, a.duration, a.keep): c for c in todo}
            for f in as_completed(futs):
                c, r = futs[f], f.result()
                append(out, r)
                bar.set_description(f"{c['case']} {c['nameplate']} {c['loop']}: {r.get('effects', r.get('crash'))}")
                bar.update(1)
    bar.close()
    print(summary([out]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
