"""A friction twin's steady friction over speed, by direction, against the truth's (analysis only; round 28).

Takes the pickles that ``scripts/twin_coverage.py --work DIR`` keeps per proof case and prints, per speed, the
steady friction torque (every component but drive, spring and stops, at i = 0, its bristles settled) while
opening and while closing, twin and truth [mN m], and the twin's effects. The truth is read for the comparison
only, never by the diagnosis. Then ``scripts/friction_levels.py`` on the same pickle splits the held-out error.

    nice -n 5 .venv/bin/python scripts/twin_coverage.py --cases stribeck_friction@2:34:3B --work out/cov
    nice -n 5 .venv/bin/python scripts/friction_speed_curve.py out/cov/stribeck_friction_s2_34_3B.pkl
"""
from __future__ import annotations

import argparse
import pickle
import sys

import numpy as np

SPEEDS = (0.001, 0.003, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 3.0, 10.0)      # |omega| [rad/s]
SETTLE_RAD, SETTLE_STEPS = 0.05, 50   # each bristle's exact update at a frozen speed: steps over this travel


def steady_friction(plant, omega: float, phi: float = 0.6) -> float:
    """The steady torque against the motion [N m] of the plant's friction and effects at speed ``omega``."""
    tot = 0.0
    for c in plant.components:
        if c.role in ("drive", "spring", "stops") or c.kernel is None:
            continue
        p = np.asarray(c.param_vector(), float)
        s, ds = np.zeros(len(c.state_names)), np.zeros(len(c.state_names))
        carry = getattr(c, "carry", None)
        g = (carry(phi, omega, 0.0, p),) if carry is not None else ()
        args = (0.0, phi, omega, 0.0, 0.0, s, p)
        h = SETTLE_RAD / max(abs(omega), 1e-6) / SETTLE_STEPS     # 25 presliding distances of 2e-3 rad
        for _ in range(SETTLE_STEPS):
            if c.advance is not None:
                c.advance(h, *args, *g)
            else:
                c.kernel(*args, ds, *g)
                s += h * ds
        tq = float(c.kernel(*args, ds, *g)[0])
        tot += -tq if omega >= 0 else tq
    return tot


def analyse(path: str) -> None:
    k = pickle.loads(open(path, "rb").read())
    tw, tr, row = k["twin"], k["truth"], k["row"]
    print(f"== {path}: {row['verdict']}, {row['effects']}, held-out twin {row['heldout_rms_after'] / row['true_noise']:.2f}x")
    for label, plant in (("twin", tw), ("truth", tr)):
        for e in plant.effects:
            print(f"  {label} {type(e).__name__}: {e.params}")
    print("  |omega| rad/s | opening: twin truth twin-truth | closing: twin truth twin-truth   [mN m]")
    for w in SPEEDS:
        a = [1e3 * steady_friction(p, v) for v in (w, -w) for p in (tw, tr)]
        print(f"  {w:13.3f} | {a[0]:7.1f} {a[1]:7.1f} {a[0] - a[1]:+6.1f} | {a[2]:7.1f} {a[3]:7.1f} {a[2] - a[3]:+6.1f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pickles", nargs="+", help="case pickles of scripts/twin_coverage.py --work")
    for p in ap.parse_args(argv).pickles:
        analyse(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
