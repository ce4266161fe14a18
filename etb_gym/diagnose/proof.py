"""Blind proof of the diagnosis tool: rig-like recordings from a truth plant with a concealed effect.

For every effect family and seed: build a truth plant (calibration parameters perturbed, integrator at 200
substeps, the concealed effect at a random magnitude between large and about the detection limit), record it
open-loop or closed-loop (the package's PID on the sensor's readings) with white or coloured (AR(1)) sensor
noise and 12-bit quantization, write the files, and run ``etb-gym diagnose`` on the files only. Then score:

  size       how far the effect moves the reading: max 100 ms moving RMS of (with - without) / noise;
             runs with size >= 3 are "detectable" (the issue's lower end of magnitudes)
  named      the concealed effect is the first one reported (clean runs: no effect reported)
  windows    precision / recall of mismatch_windows_s against where the concealed effect moves the angle
             by more than 3x the noise (truth with vs without the effect)
  params     relative error of the family's main parameter and whether its 90 % interval covers the truth
  improve    RMS on a held-out recording (other excitation): calibrated nominal vs final model
  time       wall time of the diagnosis

Nameplates (``--nameplate random``): the truth's R, L, c_M, J, limp-home, stops, friction and spring levels are
drawn from wide ranges (``synthetic.NAMEPLATE_RANGES``) and the tool is given a plant file of that nameplate
whose friction and spring are 10-20 % off (``synthetic.nameplate_file_plant``); closed-loop runs use the PID
designed on that plant file, open-loop runs an excitation scaled to it (``synthetic.DutyMap``: 3B's duties
moved between the file's break-away and open-stop holding duties; on 3B they are unchanged).

rows.jsonl survives SIGKILL: each finished run is appended as one line in a single write and flushed to disk;
on --resume a torn last line (a run killed while its row was written) is dropped and that run is redone.

    python -m etb_gym.diagnose.proof --quick            # a few families, short recordings (tests)
    python -m etb_gym.diagnose.proof --seeds 4 --out out/proof       # every family, both loops and noise levels
    python -m etb_gym.diagnose.proof --seeds 8 --out out/proof --resume    # more seeds later, nothing re-run
    python -m etb_gym.diagnose.proof --nameplate random --seeds 4 --out out/proof_np   # other nameplates
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ..io import write_atomic
from ..plant import make_plant
from ..plantfile import load_plant, save_plant
from ..recordings import save_recording
from .locate import moving_rms
from .model import angle_residuals_deg, prepare, simulate
from .proof_tables import DETECTABLE, loop_table, pair_table, summarize, table, targets  # noqa: F401
from .proof_truth import (FAMILIES, OUTSIDE, PAIRS, QUICK, SHAPES, AirflowMap, effect_footprint,  # noqa: F401
                          family_shape, pair_footprints, sensor_model, truth_for, truth_plant)
from .run import Options, diagnose
from .synthetic import make_recording, nameplate_file_plant


def overlap(a, b):
    tot = 0.0
    for x0, x1 in a:
        for y0, y1 in b:
            tot += max(0.0, min(x1, y1) - max(x0, y0))
    return tot


def length(ws):
    return sum(b - a for a, b in ws)


def truth_windows(rec_t, ang_with, ang_without, sigma, dt):
    d = ang_with - ang_without
    m = moving_rms(d, int(0.1 / dt)) > 3 * sigma
    out = []
    idx = np.flatnonzero(np.diff(np.concatenate([[0], m.astype(int), [0]])))
    for a, b in zip(idx[::2], idx[1::2]):
        out.append([rec_t[a], rec_t[b - 1]])
    return out


def _controller(plant_file):
    """The reference PID designed on the user's plant file (a lower crossover if the default cannot be met)."""
    from etb_gym.controllers.pid import PIDController
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for wc in (50.0, 30.0, 15.0):
            try:
                return PIDController(model=plant_file, crossover_rad_s=wc)
            except ValueError:
                continue
    return PIDController(model=plant_file, crossover_rad_s=15.0, phase_margin_deg=30.0)


def record_and_diagnose(name, seed, rng, truth, sensor_kw, args, workdir):
    """The case's recording and held-out recording of ``truth`` (loop, noise level and colour from the seed),
    the diagnosis of the recording's file, and the row's common fields."""
    closed = seed % 2 == 1                      # seeds cycle open/closed loop, then noise level, then colour:
    noise = [0.01, 0.03][(seed // 2) % 2]       # any 4 consecutive seeds cover both loops and both levels
    colour = 0.5 if (seed // 4) % 2 else 0.0
    kw = dict(noise_deg=noise, colour=colour, **sensor_kw)
    rec_seed = int(rng.integers(1 << 30))
    plant_file, ctrl, known = None, None, make_plant("3B")
    if args.nameplate == "random":              # the user's file: this nameplate, friction and spring 10-20 % off
        plant_file = Path(workdir) / f"{name}_{seed}_plant.toml"
        save_plant(nameplate_file_plant(truth, rng), plant_file)
        known = load_plant(plant_file)
        ctrl = _controller(known)
    kw["nameplate"] = known                     # the open-loop excitation is scaled to the plant the tool is given
    rec = make_recording(truth, np.random.default_rng(rec_seed), duration_s=args.duration, closed=closed,
                         name=f"{name}_{seed}.csv", controller=ctrl, **kw)
    held = make_recording(truth, np.random.default_rng(rec_seed + 1), duration_s=args.duration, closed=not closed,
                          name=f"{name}_{seed}_heldout.csv", controller=ctrl, **kw)
    path = Path(workdir) / rec.name
    save_recording(rec, path)
    out = Path(workdir) / f"out_{name}_{seed}"
    t0 = time.perf_counter()
    opts = Options(model="3B", plant=load_plant(plant_file) if plant_file else None, jobs=args.jobs, progress=False,
                   verbose=False, max_effects=args.max_effects,
                   candidates=tuple(args.candidates) if args.candidates else Options().candidates)
    res = diagnose([path], out=out, options=opts)
    elapsed = time.perf_counter() - t0
    rep = res.report
    row = {"seed": seed, "noise_deg": noise, "colour": colour, "closed": closed, "nameplate": args.nameplate,
           "loop_detected": rep.get("loop", {}).get(rec.name), "skipped": rep.get("skipped_candidates", []),
           "verdict": rep["verdict"], "effects": [e["id"] for e in rep["effects"]],
           "shaped": [e["id"] for e in rep["effects"] if "shape" in e], "outside": rep.get("outside_catalogue"),
           "rms_before": rep["rms_before_deg"],
           "rms_after": rep["rms_after_deg"], "noise_floor": rep["noise_floor_deg"], "time_s": elapsed,
           "cpu_s": rep.get("cpu_s")}
    q = getattr(sensor_kw.get("reading"), "resolution_deg", None) or sensor_kw.get("resolution_deg", 90.0 / 4096)
    row["true_noise"] = math.sqrt(noise ** 2 + q ** 2 / 12.0)        # what the truth added (incl. quantization)
    return rec, held, res, row, out


def score_windows(row, rec, rep, with_, without):
    """Effect size and window precision / recall against where (with - without) exceeds 3x the noise."""
    d = with_ - without
    row["effect_size"] = float(np.max(moving_rms(d, int(0.1 / rec.dt_s)))) / row["true_noise"]
    row["effect_rms"] = float(np.sqrt(np.mean(d ** 2)))
    tw = truth_windows(rec.t_s, with_, without, row["true_noise"], rec.dt_s)
    rw = rep["mismatch_windows_s"][rec.name]
    row["win_precision"] = overlap(rw, tw) / length(rw) if length(rw) > 0 else (1.0 if not tw else 0.0)
    row["win_recall"] = overlap(rw, tw) / length(tw) if length(tw) > 0 else 1.0


def score_param(rep, fid, pname, ptrue):
    """The fitted main parameter of effect ``fid`` against the truth (None if the effect was not reported)."""
    for e in rep["effects"]:
        if e["id"] == fid and pname in e["parameters"]:
            v, se = e["parameters"][pname]["value"], e["parameters"][pname]["stderr"]
            return {"param": pname, "param_true": ptrue, "param_fit": v, "param_stderr": se,
                    "param_rel_err": abs(v - ptrue) / abs(ptrue),
                    "param_covered": bool(se is not None and abs(v - ptrue) <= 1.645 * se)}
    return None


def score_heldout(row, res, held):
    """RMS on the held-out recording (other excitation): calibrated nominal vs final model."""
    hd = prepare([held], 12.0)
    nom_plant, nom_sensor = res.nominal_fit.spec.build(res.nominal_fit.x)
    r0 = angle_residuals_deg(simulate(nom_plant, nom_sensor, hd), hd)[0]
    r1 = angle_residuals_deg(simulate(res.plant, res.sensor, hd), hd)[0]
    row["heldout_rms_before"] = float(np.sqrt(np.mean(r0 ** 2)))
    row["heldout_rms_after"] = float(np.sqrt(np.mean(r1 ** 2)))
    row["heldout_noise"] = hd.recs[0].noise_deg                     # the tool's estimate from the held-out file


def run_case(family, seed, args, workdir):
    if family.startswith("pair:"):
        return run_pair(family[5:], seed, args, workdir)
    fam, shape = family_shape(family)       # "family@k": the family's truth shape k (0: the candidate's formula)
    rng = np.random.default_rng(10_000 * (FAMILIES.index(fam) + 1) + 1_000_000 * shape + seed)
    scale = rng.uniform(0.0, 1.0)
    effects, sensor_kw, pname, ptrue = truth_for(fam, rng, scale, shape)
    truth = truth_plant(rng, effects, substeps=args.truth_substeps, nameplate=args.nameplate)
    rec, held, res, row, out = record_and_diagnose(family.replace("@", "_s"), seed, rng, truth, sensor_kw, args,
                                                   workdir)
    rep = res.report
    ids = row["effects"]
    row = {"family": family, "seed": seed, "scale": scale, **row}
    if fam in OUTSIDE:                      # no catalogue effect given, reported outside it, period within 10 %
        score_outside(row, rep, ptrue)
    else:
        row["named"] = (not ids) if fam == "clean" else (bool(ids) and ids[0] == fam)
    if fam != "clean":                      # where the concealed effect acts: truth with vs without it (deg)
        score_windows(row, rec, rep, *effect_footprint(truth, rec, effects, sensor_kw))
        if row["closed"]:                   # ... and what of it the closed-loop residual (observer) can see
            fp = effect_footprint(truth, rec, effects, sensor_kw, residual="observer")
            if fp is not None:
                row["effect_size_observer"] = float(np.max(moving_rms(fp[0] - fp[1], int(0.1 / rec.dt_s)))) \
                    / row["true_noise"]
    if pname and row["named"] and fam not in OUTSIDE:
        row.update(score_param(rep, fam, pname, ptrue) or {})
    score_heldout(row, res, held)
    return row, out


def score_outside(row, rep, period_true):
    """A truth outside the catalogue: named when no catalogue effect is given as the explanation and the
    report says "outside the catalogue" with the true period (within 10 %)."""
    out = [u for u in rep["unexplained"] if u.get("outside_catalogue")]
    sh = out[0].get("shape", {}) if out else {}
    ang = next((d for d in (sh.get("angle", {}), sh.get("current", {})) if d.get("periodic")), {})
    per = ang.get("period_deg") if ang.get("periodic") else None
    row["catalogue_given"] = bool(row["effects"])
    row["outside_id"] = out[0]["id"] if out else None
    row["outside_summary"] = out[0]["description"] if out else None
    row["period_deg"], row["period_true_deg"] = per, period_true
    row["period_ok"] = bool(per is not None and abs(per - period_true) <= 0.1 * period_true)
    row["named"] = bool(out) and not row["catalogue_given"] and row["period_ok"]


# ---------------------------------------------------------------- two concealed effects at once


def run_pair(pair, seed, args, workdir):
    """Two families concealed at once, each at a moderate to large magnitude. Named: both reported (either
    order); detectable: each moves the reading by >= DETECTABLE x the noise on its own."""
    fams = pair.split("+")
    rng = np.random.default_rng(10_000 * (100 + PAIRS.index(pair)) + seed)
    parts = []
    for f in fams:
        scale = rng.uniform(0.3, 1.0)
        parts.append((f, scale) + tuple(truth_for(f, rng, scale)))
    effects = [e for p in parts for e in p[2]]
    sensor_kw = {k: v for p in parts for k, v in p[3].items()}
    truth = truth_plant(rng, effects, substeps=args.truth_substeps, nameplate=args.nameplate)
    rec, held, res, row, out = record_and_diagnose("pair_" + "_".join(fams), seed, rng, truth, sensor_kw, args, workdir)
    rep = res.report
    ids = row["effects"]
    row = {"family": "pair:" + pair, "seed": seed, "scales": [p[1] for p in parts], **row}
    row["named"] = set(ids[:2]) == set(fams)
    row["named_first"] = bool(ids) and ids[0] in fams
    both, neither, each = pair_footprints(truth, rec, parts, sensor_kw)
    score_windows(row, rec, rep, both, neither)
    row["effect_sizes"] = [float(np.max(moving_rms(d, int(0.1 / rec.dt_s)))) / row["true_noise"] for d in each]
    row["params"] = [dict(family=f, **(score_param(rep, f, pn, pt) or {})) for f, _, _, _, pn, pt in parts if pn]
    score_heldout(row, res, held)
    return row, out


def _atomic(path: Path, text: str) -> None:
    write_atomic(path, text)


DOCS = {"docs/diagnosis.md": ("targets", "families", "pairs"), "README.md": ("targets",)}


def update_docs(root: Path, blocks: dict) -> list:
    """Replace the text between ``<!-- proof:NAME -->`` and ``<!-- /proof:NAME -->`` in the files of DOCS."""
    import re
    changed = []
    for rel, names in DOCS.items():
        path = root / rel
        text = path.read_text()
        for name in names:
            pat = re.compile(rf"(<!-- proof:{name} -->\n).*?(\n<!-- /proof:{name} -->)", re.S)
            if not pat.search(text):
                raise SystemExit(f"{path}: markers <!-- proof:{name} --> ... <!-- /proof:{name} --> not found")
            text = pat.sub(lambda m: m.group(1) + blocks[name] + m.group(2), text)
        _atomic(path, text)
        changed.append(str(path))
    return changed


def read_rows(rows_file: Path) -> list:
    """The finished runs of ``rows_file``. A torn last line (the proof was killed while writing it) is cut off
    the file, so that run is done again and appended whole; a torn line anywhere else is an error."""
    raw = rows_file.read_bytes()
    lines = raw.split(b"\n")
    rows, good = [], 0
    for k, line in enumerate(lines):
        if not line.strip():
            good += len(line) + (1 if k < len(lines) - 1 else 0)
            continue
        try:
            rows.append(json.loads(line))
        except ValueError:
            if k < len(lines) - 1 and any(x.strip() for x in lines[k + 1:]):
                raise SystemExit(f"{rows_file}: line {k + 1} is not a JSON row: repair or remove it")
            break
        if k == len(lines) - 1:          # a last row without its newline was not written whole
            rows.pop()
            break
        good += len(line) + 1
    if good < len(raw):
        with open(rows_file, "r+b") as fh:
            fh.truncate(good)
    return rows


def append_row(rows_file: Path, row: dict) -> None:
    """Append one run as one line: a single write on an O_APPEND descriptor, then fsync. A SIGKILL leaves the
    row whole or (at worst) a torn last line without its newline, which :func:`read_rows` drops."""
    data = (json.dumps(row, default=float) + "\n").encode()
    fd = os.open(rows_file, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, data)
        os.fsync(fd)
    finally:
        os.close(fd)


def _key(r) -> tuple:
    return r["family"], r["seed"], r.get("nameplate", "3B")


def main(argv=None) -> int:
    """``etb-gym prove`` / ``python -m etb_gym.diagnose.proof``: exit code 0, or 2 on a usage error."""
    try:
        run(argv)
    except SystemExit as e:
        if e.code in (None, 0):
            return 0
        if isinstance(e.code, str):
            print(f"etb-gym prove: {e.code}", file=sys.stderr)
            return 2
        return int(e.code)
    return 0


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="etb-gym prove", description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n", 2)[2])
    ap.add_argument("--quick", action="store_true", help=f"families {QUICK}, 1 seed, 4 s recordings, small library")
    ap.add_argument("--families", nargs="+", choices=FAMILIES, default=None)
    ap.add_argument("--shapes", nargs="+", type=int, choices=SHAPES, default=[0],
                    help="truth shapes per family: 0 the candidate's formula (airflow: a Gaussian map), 1 and 2 "
                         "shapes that are not the candidate's formula (docs/diagnosis.md, 'Truth shapes'); "
                         "default 0; rows of shape k > 0 are families 'NAME@k'")
    ap.add_argument("--pairs", nargs="*", choices=PAIRS, default=None, metavar="PAIR",
                    help=f"run two-effect cases: these, or all of {PAIRS} if none is named (with --families: as well)")
    ap.add_argument("--seeds", type=int, default=20, help="seeds per family (default 20)")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=10.0, help="recording length [s] (default 10)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--max-effects", type=int, default=2)
    ap.add_argument("--candidates", nargs="+", default=None, help="restrict the library")
    ap.add_argument("--nameplate", choices=("3B", "random"), default="3B",
                    help="the truth's nameplate: the default 3B (the tool runs with --model 3B), or drawn from wide "
                         "ranges (the tool gets a plant file of it with friction and spring 10-20 %% off)")
    ap.add_argument("--truth-substeps", type=int, default=200,
                    help="integrator substeps of the truth plant (default 200: 5 us, near the exact solution)")
    ap.add_argument("--out", default=None, help="write rows.jsonl (one line per run), proof.json, proof.md and "
                    "example figures here")
    ap.add_argument("--resume", action="store_true", help="continue the proof in --out (skips finished runs)")
    ap.add_argument("--summarize", action="store_true", help="only rebuild proof.md/proof.json from --out's rows")
    ap.add_argument("--update-docs", action="store_true",
                    help="also write the tables into docs/diagnosis.md and README.md (between <!-- proof:... --> markers)")
    return ap


def _plan(a):
    """(output directory or None, rows file or None, the rows already there, the (family, seed) runs to do)."""
    if a.quick:
        a.families = a.families or QUICK
        a.seeds = min(a.seeds, 1) if a.seeds == 20 else a.seeds
        a.duration = min(a.duration, 4.0)
        a.candidates = a.candidates or ["shaft_flux_loss", "spring_asymmetry", "sensor_offset_gain", "airflow_torque",
                                        "stribeck_friction"]
    fams = a.families or ([] if a.pairs is not None else FAMILIES)
    fams = [f if k == 0 else f"{f}@{k}" for f in fams for k in a.shapes
            if k == 0 or (f != "clean" and f not in OUTSIDE)]
    if a.pairs is not None:
        fams = list(fams) + ["pair:" + p for p in (a.pairs or PAIRS)]
    out = Path(a.out) if a.out else None
    rows_file = out / "rows.jsonl" if out else None
    rows = []
    if out:
        out.mkdir(parents=True, exist_ok=True)
        if rows_file.exists():
            if not (a.resume or a.summarize):
                raise SystemExit(f"{rows_file} exists: pass --resume to continue that proof (or --summarize), "
                                 "or choose another --out")
            rows = read_rows(rows_file)
    elif a.resume or a.summarize:
        raise SystemExit("--resume and --summarize need --out DIR")
    done = {_key(r) for r in rows}
    todo = [(f, s) for s in range(a.first_seed, a.first_seed + a.seeds) for f in fams
            if (f, s, a.nameplate) not in done]
    return out, rows_file, rows, ([] if a.summarize else todo)


def _run_all(a, todo, rows, out, rows_file) -> None:
    """Run ``todo``, appending each row to ``rows`` (and the rows file); the first seed's figures to ``out``."""
    from tqdm import tqdm
    with tempfile.TemporaryDirectory() as work:
        bar = tqdm(total=len(todo), unit="run", disable=not todo)
        for f, s in todo:                   # seeds outer: a stopped proof still covers every family
            row, outdir = run_case(f, s, a, work)
            rows.append(row)
            if rows_file:
                append_row(rows_file, row)       # whole or not at all, also on SIGKILL
            bar.set_description(f"{f} seed {s}: {row['effects']} ({row['time_s']:.0f} s)")
            bar.update(1)
            if out and s == a.first_seed:
                import shutil
                dst = out / ("example_" + f.replace("pair:", "pair_").replace("+", "_"))
                dst.mkdir(parents=True, exist_ok=True)
                for fn in ("residual_time.png", "residual_regimes.png", "angle_fit.png", "report.json", "report.md"):
                    if (outdir / fn).exists():
                        shutil.copy(outdir / fn, dst / fn)
        bar.close()


def run(argv=None):
    """Run (or summarize) the proof; returns (rows, per-family summary)."""
    a = _parser().parse_args(argv)
    out, rows_file, rows, todo = _plan(a)
    _run_all(a, todo, rows, out, rows_file)
    fam = summarize(rows)
    pairs = pair_table(rows)
    loops = loop_table(rows) if rows else ""
    txt = table(fam) + "\n\n" + targets(rows) + ("\n\n" + loops if loops else "") + ("\n\n" + pairs if pairs else "")
    print(txt)
    if rows:
        total_time = [r["time_s"] for r in rows]
        print(f"\n{len(rows)} runs, diagnosis time median {np.median(total_time):.0f} s, max {np.max(total_time):.0f} s")
    if out:
        _atomic(out / "proof.json", json.dumps({"rows": rows, "families": fam, "args": vars(a)}, indent=1, default=float))
        _atomic(out / "proof.md", txt + "\n")
    if a.update_docs:
        for f in update_docs(Path(__file__).resolve().parents[2], {"targets": targets(rows), "families": table(fam),
                                                                  "pairs": pairs or "(no two-effect runs)"}):
            print(f"updated {f}")
    return rows, fam

if __name__ == "__main__":
    sys.exit(main())
