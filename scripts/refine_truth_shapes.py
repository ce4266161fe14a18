"""Shape refinement (method step 3b) on the proof's truth shapes that are not the candidates' formulas, without
the selection: the family's own candidate is fitted (its formula), then refined by its table(s)
(family_table.refine_family), and both twins predict a held-out recording with the other excitation.

Per case (family, shape, seed): truth = 3B (friction and spring perturbed) with proof_truth.truth_for(family,
shape) at magnitude ``--scale``; an open-loop training recording and a closed-loop held-out one (``--duration``
s, 0.01 deg noise, 12 bits). Rows: the formula's and the table's cross-validated held-out error on the
training recording (noise units, as the diagnosis decides), whether the table is kept, and the held-out
recording's RMS over the true noise for the calibrated nominal model, the formula twin and the refined twin.

    python scripts/refine_truth_shapes.py --families backlash end_stop_compliance --shapes 1 2 --out rows.jsonl
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np


def run(family: str, shape: int, seed: int, scale: float, duration: float, substeps: int) -> dict:
    from etb_gym import make_plant
    from etb_gym.diagnose import fit as F
    from etb_gym.diagnose import family_table as FT
    from etb_gym.diagnose.candidates import CANDIDATES
    from etb_gym.diagnose.measurement import SensorModel
    from etb_gym.diagnose.model import Spec, angle_residuals_deg, prepare, simulate
    from etb_gym.diagnose.proof_truth import FAMILIES, truth_for, truth_plant
    from etb_gym.diagnose.synthetic import make_recording

    rng = np.random.default_rng(10_000 * (FAMILIES.index(family) + 1) + 1_000_000 * shape + seed)
    effects, sensor_kw, _, _ = truth_for(family, rng, scale, shape)
    truth = truth_plant(rng, effects, substeps=100)
    rec = make_recording(truth, np.random.default_rng(seed), duration_s=duration, name="train.csv", **sensor_kw)
    held = make_recording(truth, np.random.default_rng(seed + 1), duration_s=duration, closed=True, name="held.csv",
                          **sensor_kw)
    noise = math.sqrt(0.01 ** 2 + (90.0 / 4096) ** 2 / 12.0)
    data = prepare([rec], 12.0)
    hd = prepare([held], 12.0)
    base = make_plant("3B", substeps=substeps)
    t0 = time.perf_counter()
    nominal = F.fit(Spec(base), data, max_nfev=30)
    formula = F.fit(Spec(base).with_candidate(CANDIDATES[family]), data, max_nfev=30)
    ref = FT.refine_family(formula, family, data, log=lambda *a: None)
    rms = lambda fr: float(np.sqrt(np.mean(angle_residuals_deg(simulate(*fr.spec.build(fr.x), hd), hd)[0] ** 2))) / noise
    row = {"family": family, "shape": shape, "seed": seed, "scale": scale,
           "heldout_nominal": rms(nominal), "heldout_formula_twin": rms(formula),
           "heldout_truth": float(np.sqrt(np.mean(angle_residuals_deg(simulate(truth, SensorModel(), hd), hd)[0] ** 2))) / noise,
           "time_s": time.perf_counter() - t0}
    if ref is not None:
        row.update(table=ref.term.cls.effect_id, cv_formula=ref.heldout_formula,
                   cv_map=ref.heldout_map, kept=ref.kept,
                   heldout_refined_twin=rms(ref.fit) if ref.kept else rms(formula))
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--families", nargs="+", required=True)
    ap.add_argument("--shapes", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--scale", type=float, default=0.6, help="magnitude in [0, 1] (default 0.6)")
    ap.add_argument("--duration", type=float, default=4.0)
    ap.add_argument("--substeps", type=int, default=20)
    ap.add_argument("--out", type=Path, required=True, help="rows (JSON lines, appended)")
    a = ap.parse_args(argv)
    for seed in range(a.seeds):
        for f in a.families:
            for k in a.shapes:
                r = run(f, k, seed, a.scale, a.duration, a.substeps)
                with open(a.out, "a") as fh:
                    fh.write(json.dumps(r) + "\n")
                print(json.dumps(r), flush=True)


if __name__ == "__main__":
    main()
