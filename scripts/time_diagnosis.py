"""Wall time of one diagnosis per stage (issue 15: <= 2 min median, <= 4 min worst per 10 s recording, one core).

Cases (10 s recordings of model 3B with friction +-15 % / spring +-10 %, 0.01 deg noise, 12 bit):
    clean_open, clean_closed      no effect
    coil_heating                  a catalogue effect (coil heats up, open loop)
    cogging                       a detent torque (period 20 deg): physics outside the catalogue

Every case is diagnosed once with jobs=1 (``--jobs``); the report's ``elapsed_breakdown_s`` gives the time of
each stage, so the time without the refine stage (shapes, outside the catalogue) is the total minus ``refine``
from the same run. One JSON line per case (appended to ``--out``) with the times and what the diagnosis found.

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

CASES = ("clean_open", "clean_closed", "coil_heating", "cogging")


def recording(case: str, seed: int = 0, duration_s: float = 10.0):
    from etb_gym.components import effects as fx
    from etb_gym.diagnose.shapes_eval import Cogging, truth_plant
    from etb_gym.diagnose.synthetic import make_recording
    rng = np.random.default_rng(1_000 + 17 * CASES.index(case) + seed)
    effect = {"clean_open": None, "clean_closed": None,
              "coil_heating": fx.CoilHeating(heat_capacity_J_per_K=10.0, thermal_resistance_K_per_W=8.0),
              "cogging": Cogging(amplitude_Nm=0.015, period_rad=math.radians(20.0), phase_rad=0.1, waveform=0.0)}[case]
    truth = truth_plant(rng, effect)
    return make_recording(truth, np.random.default_rng(int(rng.integers(1 << 30))), duration_s=duration_s,
                          closed=case == "clean_closed", noise_deg=0.01, name=f"{case}.csv")


def run(case: str, jobs: int = 1, seed: int = 0, duration_s: float = 10.0) -> dict:
    from etb_gym.diagnose.run import Options, diagnose
    rec = recording(case, seed, duration_s)
    with tempfile.TemporaryDirectory() as tmp:
        t0, c0 = time.perf_counter(), time.process_time()
        res = diagnose([rec], out=Path(tmp) / "out", options=Options(model="3B", jobs=jobs, progress=False,
                                                                       verbose=False))
        total = time.perf_counter() - t0
        cpu = time.process_time() - c0
    rep = res.report
    st = rep.get("elapsed_breakdown_s", {})
    outside = [u for u in rep["unexplained"] if u.get("outside_catalogue")]
    per = outside[0]["shape"]["angle"] if outside else {}
    return {"case": case, "seed": seed, "jobs": jobs, "time_s": total, "cpu_s": cpu, "stages_s": st,
            "time_without_refine_s": total - st.get("refine", 0.0),
            "verdict": rep["verdict"], "effects": [e["id"] for e in rep["effects"]],
            "shaped": [e["id"] for e in rep["effects"] if "shape" in e],
            "outside": outside[0]["id"] if outside else None,
            "period_deg": per.get("period_deg") if per.get("periodic") else None}


def main(argv=None):
    ap = argparse.ArgumentParser(description="Time the diagnosis per stage on a few 10 s recordings.")
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--out", type=Path, required=True, help="JSON-lines file (appended)")
    a = ap.parse_args(argv)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    for c in a.cases:
        row = run(c, a.jobs, a.seed, a.duration)
        with open(a.out, "a") as fh:
            fh.write(json.dumps(row) + "\n")
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    sys.exit(main())
