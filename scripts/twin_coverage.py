"""Why the exported twin misses held-out recordings (issue 15): where its held-out error sits.

For each proof case (``etb_gym.diagnose.proof.run_case``: the same truth, recordings, plant file and diagnosis) the
script keeps the truth, both recordings, the twin and the calibrated nominal model (a pickle per case under
--work, reused on a re-run), then reports

  * the twin's held-out RMS / true noise, and the truth's own replay of the held-out (the best any twin can do),
  * how the twin's held-out error splits between states the training recording covered and states it did not
    (``etb_gym.diagnose.envelope``: time the training recording spent per angle bin, split into "held" -- the plate
    nearly still -- and "passing"; a held-out sample is covered when the training recording dwelt in its state),
  * the calibrated nominal parameters over the truth's (does the calibration absorb the effect?).

    nice -n 10 .venv/bin/python scripts/twin_coverage.py --cases shaft_flux_loss@2:2:random backlash:1:3B \\
        --work /tmp/twin_cov --out docs/figures/diagnosis/twin_round12/rows.jsonl
    .venv/bin/python scripts/twin_coverage.py --summary docs/figures/diagnosis/twin_round12/rows.jsonl

A case is ``FAMILY[@K]:SEED:NAMEPLATE`` (K: the family's truth shape, 0 = the candidate's formula; NAMEPLATE 3B or
random); even seeds record open loop (held-out closed), odd seeds closed loop (held-out open).
"""
from __future__ import annotations

import argparse
import json
import pickle
import sys
import tempfile
from pathlib import Path

import numpy as np

from etb_gym.diagnose import envelope as EV
from etb_gym.diagnose import proof as PR
from etb_gym.diagnose.model import angle_residuals_deg, prepare, simulate
from etb_gym.diagnose.proof_truth import effect_footprint, sensor_model


def parse_case(case: str) -> tuple[str, int, str]:
    parts = case.split(":")
    if len(parts) != 3 or not parts[1].isdigit() or parts[2] not in ("3B", "random"):
        raise SystemExit(f"--cases: {case!r} is not FAMILY[@K]:SEED:3B|random (e.g. shaft_flux_loss@2:2:random)")
    return parts[0], int(parts[1]), parts[2]


def collect(case: str, duration: float, work: Path) -> dict:
    """Run the proof's case once and keep what the analysis needs (pickled under ``work``)."""
    pk = work / (case.replace(":", "_").replace("@", "_s") + ".pkl")
    if pk.exists():
        return pickle.loads(pk.read_bytes())
    fam, seed, nameplate = parse_case(case)
    args = PR._parser().parse_args(["--duration", str(duration), "--jobs", "1", "--nameplate", nameplate])
    kept = {}
    orig = PR.record_and_diagnose

    def spy(name, seed_, rng, truth, sensor_kw, args_, workdir):
        out = orig(name, seed_, rng, truth, sensor_kw, args_, workdir)
        rec, held, res = out[:3]
        nom_plant, nom_sensor = res.nominal_fit.spec.build(res.nominal_fit.x)
        kept.update(truth=truth, sensor_kw=sensor_kw, rec=rec, held=held, twin=res.plant, twin_sensor=res.sensor,
                    nominal=nom_plant, nominal_sensor=nom_sensor, report=res.report,
                    final_fit=res.final_fit, nominal_fit=res.nominal_fit, data=res.data)   # for twin_polish.py
        return out

    PR.record_and_diagnose = spy
    try:
        case_dir = work / "runs"
        case_dir.mkdir(parents=True, exist_ok=True)
        row, _ = PR.run_case(fam, seed, args, str(case_dir))
    finally:
        PR.record_and_diagnose = orig
    kept["row"] = row
    pk.write_bytes(pickle.dumps(kept))
    return kept


MEMORY_S = (0.0, 0.25)          # the split without and with a replay's memory of an uncovered state


def _over(x, sig):
    return None if x is None else x / sig


def _resid(plant, sensor, rec) -> np.ndarray:
    data = prepare([rec], 12.0)                 # as proof.score_heldout: a replay of the recorded voltage
    pred = simulate(plant, sensor, data)
    if pred is None:
        raise RuntimeError(f"{rec.name}: the simulation failed")
    r = angle_residuals_deg(pred, data)[0]
    if r.size != rec.n:
        raise RuntimeError(f"{rec.name}: {r.size} residual samples for {rec.n} recorded ones")
    return r


def analyse(case: str, k: dict, truth_substeps: int = 50) -> dict:
    row, rec, held, truth = k["row"], k["rec"], k["held"], k["truth"]
    sig = row["true_noise"]
    sm = sensor_model({a: b for a, b in k["sensor_kw"].items() if a != "resolution_deg"}, rec.dt_s)
    tr = truth.replace(substeps=truth_substeps)
    reading = k["sensor_kw"].get("reading") is not None
    out = {"case": case, "family": row["family"], "seed": row["seed"], "nameplate": row["nameplate"],
           "closed": row["closed"], "verdict": row["verdict"], "effects": row["effects"],
           "effect_size": row.get("effect_size"), "true_noise": sig}
    env = EV.from_recordings([rec])
    out["envelope"] = env.as_dict()
    for tag, r in (("train", rec), ("held", held)):
        rt = _resid(k["twin"], k["twin_sensor"], r)
        rn = _resid(k["nominal"], k["nominal_sensor"], r)
        if reading:       # the truth's reading (a shape with no SensorModel form): its replay read through it
            rx = r.angle_deg - effect_footprint(truth, r, (), k["sensor_kw"])[0]
        else:
            rx = _resid(tr, sm, r)
        out[f"{tag}_twin"] = float(np.sqrt(np.mean(rt ** 2))) / sig
        out[f"{tag}_nominal"] = float(np.sqrt(np.mean(rn ** 2))) / sig
        out[f"{tag}_truth"] = float(np.sqrt(np.mean(rx ** 2))) / sig
        if tag == "held":
            for mem in MEMORY_S[1:]:              # the same split, samples after an uncovered state counted outside
                cm = env.covered(r.t_s, r.angle_deg, memory_s=mem)
                s = EV.split_rms(rt, cm)
                out[f"held_m{mem:g}"] = {"time_uncovered": s["time_uncovered"],
                                          "sq_error_uncovered": s["sq_error_uncovered"],
                                          "twin_covered": _over(s["rms_covered_deg"], sig),
                                          "twin_uncovered": _over(s["rms_uncovered_deg"], sig)}
            cov = env.covered(r.t_s, r.angle_deg)
            s = EV.split_rms(rt, cov)
            out["held_time_uncovered"] = s["time_uncovered"]
            out["held_twin_sq_uncovered"] = s["sq_error_uncovered"]
            out["held_twin_covered"] = s["rms_covered_deg"] / sig if s["rms_covered_deg"] is not None else None
            out["held_twin_uncovered"] = s["rms_uncovered_deg"] / sig if s["rms_uncovered_deg"] is not None else None
            st = EV.split_rms(rx, cov)
            out["held_truth_covered"] = _over(st["rms_covered_deg"], sig)
            m = EV.motion_index(EV.speed_deg_s(r.t_s, r.angle_deg))
            out["held_time_by_motion"] = {n: float(np.mean(m == i)) for i, n in enumerate(EV.MOTIONS)}
            out["held_twin_by_motion"] = {n: (float(np.sqrt(np.mean(rt[m == i] ** 2))) / sig if np.any(m == i)
                                              else None) for i, n in enumerate(EV.MOTIONS)}
    pd = truth.params_dict()
    cal = k["report"]["calibrated_parameters"]
    out["nominal_over_truth"] = {p: v["nominal_fit"] / pd[p] for p, v in cal.items() if pd.get(p)}
    out["final_over_truth"] = {p: v["value"] / pd[p] for p, v in cal.items() if pd.get(p)}
    return out


def summary(rows: list) -> str:
    hdr = ("| case | loop | verdict | fit | held twin | held truth | time outside | sq. error outside | "
           "twin inside | twin outside | largest nominal error | largest final error |")
    lines = [hdr, "| --- |" + " --- |" * 11]
    for r in rows:
        big = max(r["nominal_over_truth"].items(), key=lambda kv: abs(kv[1] - 1.0), default=("-", 1.0))
        fin = max(r["final_over_truth"].items(), key=lambda kv: abs(kv[1] - 1.0), default=("-", 1.0))

        def f(x):
            return "-" if x is None else f"{x:.2f}"
        lines.append(f"| {r['case']} | {'closed' if r['closed'] else 'open'} | {r['verdict']} | {f(r['train_twin'])} "
                     f"| {f(r['held_twin'])} | {f(r['held_truth'])} | {r['held_time_uncovered']:.0%} | "
                     f"{r['held_twin_sq_uncovered']:.0%} | {f(r['held_twin_covered'])} | {f(r['held_twin_uncovered'])} "
                     f"| `{big[0]}` {big[1] - 1:+.1%} | `{fin[0]}` {fin[1] - 1:+.1%} |")
    lines += ["", "fit, held twin/truth, twin inside/outside: RMS angle error / the noise the truth added; outside: "
              "held-out samples in states the training recording did not cover (etb_gym.diagnose.envelope); nominal / "
              "final error: the calibrated nominal parameter furthest from the truth's, nominal-only fit / final model"]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0], epilog=__doc__.split("\n", 2)[2],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", help="FAMILY[@K]:SEED:3B|random, e.g. shaft_flux_loss@2:2:random")
    ap.add_argument("--duration", type=float, default=6.0, help="recording length [s] (default 6, as the surveys)")
    ap.add_argument("--work", default=None, help="keep each case's pickle here and reuse it (default: a temporary "
                                                 "folder)")
    ap.add_argument("--out", default=None, help="append one JSON line per case here")
    ap.add_argument("--summary", nargs="+", metavar="ROWS", help="print the table of these row files and exit")
    a = ap.parse_args(argv)
    if a.summary:
        print(summary([json.loads(line) for f in a.summary for line in Path(f).read_text().splitlines() if line]))
        return 0
    if not a.cases:
        ap.error("--cases is required (or --summary)")
    if not a.duration > 0:
        ap.error(f"--duration = {a.duration} is invalid: expected a positive length in seconds")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(a.work or tmp)
        work.mkdir(parents=True, exist_ok=True)
        for case in a.cases:
            row = analyse(case, collect(case, a.duration, work))
            line = json.dumps(row, default=float)
            print(line, flush=True)
            if a.out:
                with open(a.out, "a") as fh:
                    fh.write(line + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
