"""Coarse scan before the local fit (fit.scan_start): the diagnosis with and without the scan, side by side.

Cases:
  offset-closed  a 4 s closed-loop recording of 3B under the default PID whose reference closes the plate to
                 the stop three times for 0.3 s, sensor offset 0.5 deg, noise 0.01 deg (docs/diagnosis.md,
                 closed-loop sensor offset); the diagnosis with ``--candidates`` (default: five)
  FAMILY:SEED    a proof case rebuilt by scripts/twin_harness.py (e.g. backlash:0, clean:0, sensor_delay:0)

Each case is diagnosed with the scan off (fit.SCAN_POINTS = 0, the local fit from the default start) and on,
in one process, one after the other; the time of each is printed next to the verdict.

    nice -n 10 .venv/bin/python scripts/scan_start_cases.py --cases offset-closed backlash:0 clean:0 --jobs 1
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

from etb_gym.diagnose import fit as F
from etb_gym.diagnose.run import Options, diagnose
from etb_gym.diagnose.synthetic import QUIET_S, closed_loop
from etb_gym.components.sensor import PositionSensor, PositionSensorParams
from etb_gym.plant import make_plant
from etb_gym.recordings import Recording

OFFSET_CANDIDATES = ("sensor_offset_gain", "sensor_delay", "backlash", "stribeck_friction", "end_stop_compliance")


def offset_closed_recording(duration_s: float = 4.0, offset_deg: float = 0.5, noise_deg: float = 0.01,
                            seed: int = 0) -> Recording:
    """Closed loop under the default PID; the reference holds 20-60 deg and three times asks for 1 deg below
    the closed stop for 0.3 s, so the plate rests on the stop (where the physics pins the angle down)."""
    truth = make_plant("3B")
    rng = np.random.default_rng(seed)
    dt = truth.control_period_s
    nq = int(round(QUIET_S / dt))
    n = nq + int(round((duration_s - QUIET_S) / dt))
    closed_deg = math.degrees(truth.angle_min_rad) - 1.0
    seg = (n - nq) // 6
    ref = []
    for k in range(6):
        ref.append(np.full(seg, closed_deg if k % 2 == 1 else float(rng.uniform(20.0, 60.0))))
    ref = np.concatenate(ref)
    ref = np.concatenate([ref, np.full(n - nq - ref.size, ref[-1])])
    # the closing requests last 0.3 s; the rest of each odd segment holds the previous opening
    hold = int(round(0.3 / dt))
    for k in range(1, 6, 2):
        ref[k * seg + hold:(k + 1) * seg] = ref[(k - 1) * seg]
    sensor = PositionSensor(PositionSensorParams(noise_std_rad=0.0, resolution_rad=math.radians(90.0 / 4096),
                                                 offset_rad=math.radians(offset_deg), gain=1.0, delay_steps=0,
                                                 current_noise_std_A=0.01))
    noise = math.radians(noise_deg) * rng.normal(0.0, 1.0, n)
    lh = math.degrees(truth.limp_home_rad)
    sensor.reset(truth.limp_home_rad + noise[0])

    def read(k, phi):
        return math.degrees(sensor.read(phi + noise[k], rng))

    duty, X, y = closed_loop(truth, np.concatenate([np.full(nq, lh), ref]), read, enable_k=nq)
    t = np.arange(n) * dt
    V = truth.supply.voltage_V
    return Recording(name="offset_closed.csv", t_s=t, voltage_V=duty * V, angle_deg=y,
                     current_A=sensor.measure_current(X[:, 2], rng), supply_V=None)


def run_offset(args) -> dict:
    rec = offset_closed_recording(args.duration)
    t0 = time.perf_counter()
    res = diagnose([rec], options=Options(plant=make_plant("3B"), jobs=args.jobs, progress=False, verbose=False,
                                          candidates=tuple(args.candidates)))
    rep = res.report
    eff = rep["effects"]
    return {"verdict": rep["verdict"], "effects": [e["id"] for e in eff],
            "fit": rep["rms_after_deg"] / rep["noise_floor_deg"], "fit0": rep["rms_before_deg"] / rep["noise_floor_deg"],
            "params": {k: v for e in eff for k, v in (e.get("parameters") or {}).items()},
            "time_s": round(time.perf_counter() - t0, 1)}


def run_proof(case: str, args, work: Path) -> dict:
    sys.path.insert(0, str(Path(__file__).parent))
    import twin_harness as TH
    ns = argparse.Namespace(jobs=args.jobs, nameplate="3B", duration=10.0, diagnose=True, truth=False,
                            substeps=[20])
    t0 = time.perf_counter()
    row = TH.run(case, ns, work)
    keep = ("verdict", "effects", "named", "fit", "fit0", "ho")
    out = {k: row.get(k) for k in keep}
    out["time_s"] = round(time.perf_counter() - t0, 1)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0], epilog=__doc__.split("\n", 2)[2],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=["offset-closed"], help="offset-closed and/or FAMILY:SEED")
    ap.add_argument("--candidates", nargs="+", default=list(OFFSET_CANDIDATES), help="offset-closed only")
    ap.add_argument("--duration", type=float, default=4.0, help="offset-closed recording length [s]")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--modes", nargs="+", choices=("off", "on"), default=["off", "on"])
    ap.add_argument("--out", default=None, help="append one JSON line per case and mode here")
    args = ap.parse_args(argv)
    points = F.SCAN_POINTS
    with tempfile.TemporaryDirectory() as w:
        for case in args.cases:
            for mode in args.modes:
                F.SCAN_POINTS = points if mode == "on" else 0
                row = run_offset(args) if case == "offset-closed" else run_proof(case, args, Path(w) / mode)
                row = {"case": case, "scan": mode, **row}
                line = json.dumps(row, default=float)
                print(line, flush=True)
                if args.out:
                    with open(args.out, "a") as fh:
                        fh.write(line + "\n")
    F.SCAN_POINTS = points
    return 0


if __name__ == "__main__":
    sys.exit(main())
