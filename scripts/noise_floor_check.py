#!/usr/bin/env python
"""The noise floor (``measurement.noise_floor``) of this tree against a baseline revision's, on the proof's own
recordings (the diagnosed and the held-out recording of each case; no diagnosis is run).

    python scripts/noise_floor_check.py --baseline 97022f5 --families clean backlash@2 --seeds 0 1 2 3

Prints each recording whose floor changed by more than --tol, then the count and the ratio's median and range.
"""
from __future__ import annotations

import argparse
import importlib.util
import math
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np


def baseline_module(rev: str):
    src = subprocess.run(["git", "show", f"{rev}:etb_gym/diagnose/measurement.py"], capture_output=True, text=True,
                         check=True, cwd=Path(__file__).resolve().parents[1]).stdout
    f = Path(tempfile.mkdtemp()) / "measurement_baseline.py"
    f.write_text(src)
    name = "etb_gym.diagnose.measurement_baseline"
    spec = importlib.util.spec_from_file_location(name, f)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def recordings(family: str, seed: int, nameplate: str, duration_s: float):
    """The case's two recordings as the proof makes them (proof.run_case / record_and_diagnose)."""
    from etb_gym.diagnose import proof as P
    from etb_gym.diagnose.proof_truth import FAMILIES, truth_for, truth_plant
    from etb_gym.diagnose.synthetic import make_recording
    from etb_gym.plant import make_plant
    from etb_gym.plantfile import load_plant, save_plant
    fam, shape = P.family_shape(family)
    rng = np.random.default_rng(10_000 * (FAMILIES.index(fam) + 1) + 1_000_000 * shape + seed)
    scale = rng.uniform(0.0, 1.0)
    effects, sensor_kw, _, _ = truth_for(fam, rng, scale, shape)
    truth = truth_plant(rng, effects, substeps=40, nameplate=nameplate)
    closed = seed % 2 == 1
    noise = [0.01, 0.03][(seed // 2) % 2]
    kw = dict(noise_deg=noise, colour=0.5 if (seed // 4) % 2 else 0.0, **sensor_kw)
    rec_seed = int(rng.integers(1 << 30))
    ctrl, known = None, make_plant("3B")
    if nameplate == "random":
        f = Path(tempfile.mkdtemp()) / "plant.toml"
        save_plant(P.nameplate_file_plant(truth, rng), f)
        known = load_plant(f)
        ctrl = P._controller(known)
    kw["nameplate"] = known
    for cl, rs in ((closed, rec_seed), (not closed, rec_seed + 1)):
        yield ("closed" if cl else "open"), make_recording(truth, np.random.default_rng(rs), duration_s=duration_s,
                                                           closed=cl, controller=ctrl, **kw)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", required=True, help="git revision whose measurement.py is the baseline")
    ap.add_argument("--families", nargs="+", default=["clean", "backlash@2", "sensor_delay@2"],
                    help="proof families (FAMILY@SHAPE)")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3])
    ap.add_argument("--nameplates", nargs="+", default=["3B", "random"], choices=["3B", "random"])
    ap.add_argument("--duration", type=float, default=6.0, help="recording length [s] (the proof's: 6)")
    ap.add_argument("--tol", type=float, default=0.02, help="relative change that is reported (default 0.02)")
    a = ap.parse_args(argv)
    from etb_gym.diagnose.measurement import detect_resolution, noise_floor
    old = baseline_module(a.baseline)
    warnings.simplefilter("ignore")
    ratios = []
    for fam in a.families:
        for seed in a.seeds:
            for nameplate in a.nameplates:
                for loop, rec in recordings(fam, seed, nameplate, a.duration):
                    q = detect_resolution(rec.angle_deg)
                    new_s, old_s = noise_floor(rec.t_s, rec.angle_deg, q)[0], old.noise_floor(rec.t_s, rec.angle_deg, q)[0]
                    ratios.append(new_s / old_s)
                    if abs(new_s / old_s - 1.0) > a.tol:
                        print(f"{fam} s{seed} {nameplate} {loop}: {old_s:.5f} -> {new_s:.5f} deg", flush=True)
    r = np.array(ratios)
    print(f"{int(np.sum(np.abs(r - 1.0) > a.tol))}/{r.size} recordings changed by more than {a.tol:.0%}; "
          f"new/old median {np.median(r):.4f}, range {r.min():.3f}-{r.max():.3f}")
    return 0 if math.isfinite(float(np.median(r))) else 1


if __name__ == "__main__":
    sys.exit(main())
