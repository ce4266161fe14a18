"""Calibration / verdict / held-out twin harness (issue 15): a handful of proof cases, measured side by side.

For each (family, seed, nameplate) case the proof's truth and recordings are rebuilt exactly as
``etb_gym.diagnose.proof.run_case`` builds them, and the script reports

  * the noise floor the tool estimates against the noise the truth added,
  * the *truth's own* residual (the true plant, the diagnosis's integrator step, the truth's sensor map) on the
    recording and on the held-out recording: the best any twin can do under the proof's scores,
  * with ``--diagnose``: the proof's row (verdict, effects, fit = final RMS / noise floor, held-out twin RMS /
    true noise, time), and the calibrated nominal parameters against the truth's.

    nice -n 10 .venv/bin/python scripts/twin_harness.py --cases clean:0 clean:2 sensor_delay:0 --diagnose
    nice -n 10 .venv/bin/python scripts/twin_harness.py --cases clean:0 --nameplate random --diagnose --out rows.jsonl

A case is ``FAMILY[@K]:SEED[:NAMEPLATE]``: a truth shape K of the family (0: the candidate's formula; with
``--diagnose`` only) and a nameplate for this case (``3B`` or ``random``; default ``--nameplate``), e.g.
``airflow_torque@1:0:random``.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from etb_gym.diagnose import proof as PR
from etb_gym.diagnose.locate import windows
from etb_gym.diagnose.model import angle_residuals_deg, prepare, simulate
from etb_gym.diagnose.proof_truth import FAMILIES, sensor_model, truth_for, truth_plant


def truth_case(family: str, seed: int, nameplate: str = "3B"):
    """(truth plant, its sensor kwargs, the rng after the truth was drawn): as run_case draws them."""
    if family not in FAMILIES:
        raise SystemExit(f"--cases: family {family!r} is not one of the proof's families ({', '.join(FAMILIES)}); "
                         "truth shapes (NAME@K) run with scripts/proof_case.py")
    rng = np.random.default_rng(10_000 * (FAMILIES.index(family) + 1) + seed)
    scale = rng.uniform(0.0, 1.0)
    effects, sensor_kw, _, _ = truth_for(family, rng, scale)
    truth = truth_plant(rng, effects, substeps=200, nameplate=nameplate)
    return truth, sensor_kw, rng


def truth_residual(truth, sensor_kw, rec, substeps: int, residual: str = "replay") -> dict:
    """The true plant's (at ``substeps``) residual on ``rec``: RMS / estimated floor, RMS / true noise, windows."""
    data = prepare([rec], truth.supply.voltage_V, residual=residual)
    rd = data.recs[0]
    sm = sensor_model({k: v for k, v in sensor_kw.items() if k != "resolution_deg"}, rec.dt_s)
    pred = simulate(truth.replace(substeps=substeps), sm, data)
    if pred is None:
        return {"failed": True}
    r = angle_residuals_deg(pred, data)[0]
    rms = float(np.sqrt(np.mean(r ** 2)))
    return {"rms_over_floor": rms / rd.noise_deg, "floor": rd.noise_deg, "rms": rms,
            "windows": len(windows(rec.t_s, r, rd.noise_deg, None))}


def parse_case(case: str, default_nameplate: str) -> tuple[str, int, str]:
    """``FAMILY[@K]:SEED[:NAMEPLATE]`` -> (family with shape, seed, nameplate)."""
    parts = case.split(":")
    if len(parts) not in (2, 3) or not parts[1].isdigit() or (len(parts) == 3 and parts[2] not in ("3B", "random")):
        raise SystemExit(f"--cases: {case!r} is not FAMILY[@K]:SEED[:3B|random] (e.g. airflow_torque@1:0:random)")
    return parts[0], int(parts[1]), parts[2] if len(parts) == 3 else default_nameplate


def run(case: str, args, work: Path) -> dict:
    fam, seed, nameplate = parse_case(case, args.nameplate)
    ns = argparse.Namespace(jobs=args.jobs, max_effects=2, candidates=None, nameplate=nameplate,
                            duration=args.duration, truth_substeps=200)
    row = {"case": case, "nameplate": nameplate}
    shaped = "@" in fam
    if shaped and args.truth:
        raise SystemExit(f"--cases: {case!r}: --truth rebuilds only the families' shape 0 (no @K)")
    truth, sensor_kw, _ = (None, None, None) if shaped else truth_case(fam, seed, nameplate)
    if args.diagnose:
        t0 = time.perf_counter()
        r, _ = PR.run_case(fam, seed, ns, str(work))
        row.update({k: r.get(k) for k in ("verdict", "effects", "closed", "noise_deg", "colour", "effect_size",
                                          "named")})
        row["fit"] = r["rms_after"] / r["noise_floor"]
        row["fit0"] = r["rms_before"] / r["noise_floor"]
        row["ho"] = r["heldout_rms_after"] / r["true_noise"]
        row["ho0"] = r["heldout_rms_before"] / r["true_noise"]
        row["floor_over_true"] = r["noise_floor"] / r["true_noise"]
        row["time_s"] = r["time_s"]
        row["wall_s"] = time.perf_counter() - t0
        rep = json.loads((work / f"out_{fam.replace('@', '_s')}_{seed}" / "report.json").read_text())
        row["shaped"] = r.get("shaped")
        row["outside"] = r.get("outside")
        row["stages_s"] = rep.get("elapsed_breakdown_s")
        row["cpu_s"] = rep.get("cpu_s")                       # the diagnosis's CPU time (one core: --jobs 1)
        row["substeps"], row["twin_substeps"] = rep.get("integrator_substeps"), rep.get("twin_substeps")
        if truth is not None:
            pd = truth.params_dict()
            row["calibrated_over_truth"] = {k: v["nominal_fit"] / pd[k]
                                            for k, v in rep["calibrated_parameters"].items() if pd.get(k)}
    if args.truth:
        rec, held = _recordings(fam, seed, truth, sensor_kw, truth_case(fam, seed, nameplate)[2], args, work,
                                nameplate)
        for n in args.substeps:
            row[f"truth_train_{n}"] = truth_residual(truth, sensor_kw, rec, n)
            row[f"truth_held_{n}"] = truth_residual(truth, sensor_kw, held, n)
    return row


def _recordings(fam, seed, truth, sensor_kw, rng, args, work, nameplate):
    """The proof's recording and held-out recording (record_and_diagnose's draws, without the diagnosis)."""
    from etb_gym.diagnose.synthetic import make_recording, nameplate_file_plant
    from etb_gym.plant import make_plant
    from etb_gym.plantfile import load_plant, save_plant
    closed = seed % 2 == 1
    noise = [0.01, 0.03][(seed // 2) % 2]
    colour = 0.5 if (seed // 4) % 2 else 0.0
    kw = dict(noise_deg=noise, colour=colour, **sensor_kw)
    rec_seed = int(rng.integers(1 << 30))
    ctrl, known = None, make_plant("3B")
    if nameplate == "random":
        pf = work / f"h_{fam}_{seed}_plant.toml"
        save_plant(nameplate_file_plant(truth, rng), pf)
        known = load_plant(pf)
        ctrl = PR._controller(known)
    kw["nameplate"] = known                     # as the proof: the excitation is scaled to the plant the tool is given
    rec = make_recording(truth, np.random.default_rng(rec_seed), duration_s=args.duration, closed=closed,
                         name=f"{fam}_{seed}.csv", controller=ctrl, **kw)
    held = make_recording(truth, np.random.default_rng(rec_seed + 1), duration_s=args.duration, closed=not closed,
                          name=f"{fam}_{seed}_heldout.csv", controller=ctrl, **kw)
    return rec, held


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0], epilog=__doc__.split("\n", 2)[2],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", required=True, help="family:seed, e.g. clean:0 sensor_delay:0")
    ap.add_argument("--nameplate", choices=("3B", "random"), default="3B")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--diagnose", action="store_true", help="run the diagnosis (the proof's row)")
    ap.add_argument("--truth", action="store_true", help="the truth's own residual on both recordings")
    ap.add_argument("--substeps", type=int, nargs="+", default=[20])
    ap.add_argument("--out", default=None, help="append one JSON line per case here")
    ap.add_argument("--keep", default=None, metavar="DIR",
                    help="work in DIR and keep its recordings and diagnosis outputs (default: a temporary folder)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as w:
        work = Path(args.keep) if args.keep else Path(w)
        work.mkdir(parents=True, exist_ok=True)
        for case in args.cases:
            try:
                row = run(case, args, work)
            except Exception as e:                       # one case's failure must not cost the others' rows
                row = {"case": case, "error": f"{type(e).__name__}: {e}"}
            line = json.dumps(row, default=float)
            print(line, flush=True)
            if args.out:
                with open(args.out, "a") as fh:
                    fh.write(line + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
