"""Confusable angle-dependent torques: the table comparison of diagnose.discriminate on truths whose shapes are
not the candidates' formulas (a friction band, a torque-constant step), against their neighbour airflow_torque.
Prints a markdown table (docs/diagnosis.md, 3. Explain).

    .venv/bin/python scripts/discriminate_sweep.py --seeds 4
"""
from __future__ import annotations

import argparse
import math

import numpy as np

from etb_gym import make_plant
from etb_gym.components import effects as fx
from etb_gym.diagnose import discriminate as D
from etb_gym.diagnose import fit as F
from etb_gym.diagnose.model import Spec, prepare
from etb_gym.diagnose.synthetic import make_recording

PHI = np.radians(np.linspace(0.0, 90.0, 31))


def friction_band(centre_deg: float = 40.0) -> fx.AngleFrictionMap:
    """Extra friction in a Gaussian band (the candidate's is linear + quadratic in phi)."""
    lvl = 0.08 * np.exp(-0.5 * ((PHI - math.radians(centre_deg)) / math.radians(10.0)) ** 2)
    return fx.AngleFrictionMap(angle_rad=tuple(PHI), level_Nm=tuple(lvl), presliding_rad=1e-3)


def flux_step(centre_deg: float = 50.0) -> fx.TorqueConstantMap:
    """Torque constant falling in a logistic step (the candidate's is a power of phi)."""
    dk = -0.012 / (1.0 + np.exp(-(PHI - math.radians(centre_deg)) / math.radians(6.0)))
    return fx.TorqueConstantMap(angle_rad=tuple(PHI), delta_Nm_per_A=tuple(dk))


CASES = (("friction band 40 deg", friction_band, "airflow_torque", "angle_dependent_friction"),
         ("flux step 50 deg", flux_step, "airflow_torque", "shaft_flux_loss"))


def run(name, truth, neighbour, right, seed: int, duration_s: float) -> dict:
    rec = make_recording(make_plant("3B", substeps=40, effects=[truth()]), np.random.default_rng(seed),
                         duration_s=duration_s, name="rig.csv")
    data = prepare([rec], 12.0)
    nominal = F.fit(Spec(make_plant("3B", substeps=20)), data, max_nfev=40)
    return D.discriminate(nominal, data, [neighbour, right], log=lambda *a: None)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=4, help="seeds 0..N-1 per case (default 4)")
    ap.add_argument("--duration", type=float, default=3.0, help="recording length in s (default 3)")
    a = ap.parse_args(argv)
    if a.seeds < 1 or not a.duration > 0:
        ap.error("--seeds must be >= 1 and --duration > 0")
    print("| truth | seed | right family's table | neighbour's table | named |\n|---|---|---|---|---|")
    for name, truth, neighbour, right in CASES:
        for seed in range(a.seeds):
            ev = run(name, truth, neighbour, right, seed, a.duration)
            h = ev["heldout_table"]
            print(f"| {name} | {seed} | {right}: {h[right]:.3g} | {neighbour}: {h[neighbour]:.3g} | {ev['winner']} |",
                  flush=True)


if __name__ == "__main__":
    main()
