"""The friction-over-angle table's knots (shapes.FRICTION_ANGLE_KNOTS; docs/diagnosis-history.md, round 27 r27friction):
a plate at rest sticks where drive - spring = friction, so the table must carry a friction band a few degrees wide
between its knots to a fraction of a mN m."""
from __future__ import annotations

import math

import numpy as np

from diagnose_stubs import swing_data
from etb_gym import make_plant
from etb_gym.diagnose import shapes as S


def _band(phi, centre_deg=42.0, width_deg=4.7, level=-0.010):
    return level * np.exp(-0.5 * ((phi - math.radians(centre_deg)) / math.radians(width_deg)) ** 2)


def test_the_friction_table_over_angle_adds_midpoints_where_the_recordings_dwelt():
    """PROFILE_KNOTS over the stroke always; a midpoint between two of them where the recordings spent
    VISIT_MIN_S near it (hat-weighted on the fine grid), none where they only passed or never went."""
    base = make_plant("3B")
    data = swing_data(40.0, 20.0)                   # the plate swings about 40 deg, +-20 deg
    g = S.family_term("angle_dependent_friction", base, data).grid
    coarse = S.angle_grid(base, data, S.PROFILE_KNOTS)
    fine = S.angle_grid(base, data, S.FRICTION_ANGLE_KNOTS)
    assert np.allclose(fine[::2], coarse)
    assert all(np.isclose(g, c).any() for c in coarse)          # every profile knot is still a knot
    mids = np.degrees([x for x in g if not np.isclose(coarse, x).any()])
    assert mids.size > 0 and np.all(mids > 15.0) and np.all(mids < 65.0)
    assert S.PROFILE_KNOTS < g.size < S.FRICTION_ANGLE_KNOTS
    assert S.family_term("shaft_flux_loss", base, data).grid.size == S.PROFILE_KNOTS   # profiles keep theirs


def test_a_narrow_friction_band_between_the_knots_is_carried_to_a_fraction_of_a_mN_m():
    """The best a piecewise-linear table can do (least squares over the stroke) on a 10 mN m band of 4.7 deg
    (angle_dependent_friction@1 3B s32's scale): 5.6 deg knots miss it by up to 1 mN m, 2.8 deg knots by a third of that."""
    base = make_plant("3B")
    data = swing_data(40.0, 20.0)
    fine = S.angle_grid(base, data, S.FRICTION_ANGLE_KNOTS)
    coarse = S.angle_grid(base, data, S.PROFILE_KNOTS)
    x = np.linspace(fine[0], fine[-1], 3001)

    def worst(g):
        A = np.column_stack([np.interp(x, g, np.eye(g.size)[j]) for j in range(g.size)])
        v = np.linalg.lstsq(A, _band(x), rcond=None)[0]
        return float(np.max(np.abs(A @ v - _band(x))))
    assert worst(coarse) > 0.8e-3
    assert worst(fine) < 0.35e-3
