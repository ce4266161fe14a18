"""Wall time of one diagnosis per stage (issue 15: <= 2 min median, <= 4 min worst per 10 s recording, one core).

Cases (10 s recordings of model 3B with friction +-15 % / spring +-10 %, 0.01 deg noise, 12 bit):
    clean_open, clean_closed      no effect
    coil_heating                  a catalogue effect (coil heats up, open loop)
    cogging                       a detent torque (period 20 deg): physics outside the catalogue
    airflow_rig                   a random nameplate (synthetic.random_nameplate) in closed loop under a PID designed on
                                  its plant file (friction and spring 10-20 % off), with a Gaussian airflow-like bump
                                  (-0.04 N m at 45 deg, 15 deg wide): not the candidate's polynomial

Every case also gets a held-out recording of the same truth with the other loop type (seed 99; closed loop under the
PID designed on the plant file, or on the truth without its effect), on which the exported twin is scored
(``heldout_over_noise``: its RMS over the held-out file's noise floor, proof.score_heldout).

Every case is diagnosed once with jobs=1 (``--jobs``); the report's ``elapsed_breakdown_s`` gives the time of
each stage, so the time without the refine stage (shapes, outside the catalogue) is the total minus ``refine``
from the same run. One JSON line per case (appended to ``--out``) with the times and what the diagnosis found;
``--profile DIR`` also writes a cProfile dump per case (DIR/<case>.prof).

    nice -n 10 .venv/bin/python scripts/time_diagnosis.py --out out/time_diagnosis.jsonl [--cases cogging ...]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CASES = ("clean_open", "clean_closed", "coil_heating", "cogging", "airflow_rig")


def rig(seed: int = 0, duration_s: float = 10.0, truth_out: list | None = None):
    """(recording, plant file's plant) of the airflow_rig case (``truth_out`` gets the truth and the controller)."""
    from etb_gym.diagnose.proof import _controller
    from etb_gym.diagnose.shapes_eval import AngleShape
    from etb_gym.diagnose.synthetic import make_recording, nameplate_file_plant, random_nameplate
    rng = np.random.default_rng(3 + seed)
    truth = random_nameplate(rng, substeps=80)
    plant_file = nameplate_file_plant(truth, rng)
    truth = truth.replace(effects=(AngleShape(peak_Nm=-0.04, centre_rad=math.radians(45.0),
                                              width_rad=math.radians(15.0), step=0.0),))
    ctrl = _controller(plant_file)
    rec = make_recording(truth, np.random.default_rng(5 + seed), duration_s=duration_s, closed=True, noise_deg=0.01,
                         name="airflow_rig.csv", controller=ctrl)
    if truth_out is not None:
        truth_out += [truth, ctrl]
    return rec, plant_file


def recording(case: str, seed: int = 0, duration_s: float = 10.0, truth_out: list | None = None):
    from etb_gym.components import effects as fx
    from etb_gym.diagnose.shapes_eval import Cogging, truth_plant
    from etb_gym.diagnose.synthetic import make_recording
    rng = np.random.default_rng(1_000 + 17 * CASES.index(case) + seed)
    effect = {"clean_open": None, "clean_closed": None,
              "coil_heating": fx.CoilHeating(heat_capacity_J_per_K=10.0, thermal_resistance_K_per_W=8.0),
              "cogging": Cogging(amplitude_Nm=0.015, period_rad=math.radians(20.0), phase_rad=0.1, waveform=0.0)}[case]
    truth = truth_plant(rng, effect)
    if truth_out is not None:
        truth_out += [truth, None]
    return make_recording(truth, np.random.default_rng(int(rng.integers(1 << 30))), duration_s=duration_s,
                          closed=case == "clean_closed", noise_deg=0.01, name=f"{case}.csv")


def run(case: str, jobs: int = 1, seed: int = 0, duration_s: float = 10.0, profile: Path | None = None) -> dict:
    from etb_gym.diagnose.run import Options, diagnose
    from etb_gym.diagnose.proof import _controller, score_heldout
    from etb_gym.diagnose.synthetic import make_recording
    plant = None
    truth = []
    if case == "airflow_rig":
        rec, plant = rig(seed, duration_s, truth)
    else:
        rec = recording(case, seed, duration_s, truth)
    truth, ctrl = truth
    closed = case in ("clean_closed", "airflow_rig")
    if not closed and ctrl is None:
        ctrl = _controller(plant or truth.replace(effects=()))
    held = make_recording(truth, np.random.default_rng(99), duration_s=duration_s, closed=not closed, noise_deg=0.01,
                          name="heldout.csv", controller=ctrl if not closed else None)
    opts = Options(model="3B", plant=plant, jobs=jobs, progress=False, verbose=False)
    prof = None
    if profile is not None:
        import cProfile
        prof = cProfile.Profile()
    with tempfile.TemporaryDirectory() as tmp:
        t0, c0 = time.perf_counter(), time.process_time()
        if prof is not None:
            prof.enable()
        res = diagnose([rec], out=Path(tmp) / "out", options=opts)
        if prof is not None:
            prof.disable()
            profile.mkdir(parents=True, exist_ok=True)
            prof.dump_stats(str(profile / f"{case}.prof"))
        total = time.perf_counter() - t0
        cpu = time.process_time() - c0
    rep = res.report
    st = rep.get("elapsed_breakdown_s", {})
    outside = [u for u in rep["unexplained"] if u.get("outside_catalogue")]
    per = outside[0]["shape"]["angle"] if outside else {}
    row = {"case": case, "seed": seed, "jobs": jobs, "time_s": total, "cpu_s": cpu, "stages_s": st,
            "time_without_refine_s": total - st.get("refine", 0.0),
            "verdict": rep["verdict"], "rms_after_deg": rep.get("rms_after_deg"),
            "noise_floor_deg": rep.get("noise_floor_deg"), "effects": [e["id"] for e in rep["effects"]],
            "shaped": [e["id"] for e in rep["effects"] if "shape" in e],
            "outside": outside[0]["id"] if outside else None,
            "period_deg": per.get("period_deg") if per.get("periodic") else None}
    score_heldout(row, res, held)
    row["heldout_over_noise"] = row["heldout_rms_after"] / row["heldout_noise"]
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description="Time the diagnosis per stage on a few 10 s recordings.")
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--out", type=Path, required=True, help="JSON-lines file (appended)")
    ap.add_argument("--profile", type=Path, default=None, help="directory for a cProfile dump per case")
    a = ap.parse_args(argv)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    for c in a.cases:
        row = run(c, a.jobs, a.seed, a.duration, a.profile)
        with open(a.out, "a") as fh:
            fh.write(json.dumps(row) + "\n")
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    sys.exit(main())
