"""twin_range.hold_friction: a friction level over angle held beyond the angles visited slowly (round 34, v34adf)."""
from types import SimpleNamespace

import numpy as np

from etb_gym.diagnose.twin_range import FRICTION_LEVEL, friction_total, hold_friction, slow_range_deg

# a friction total (formula + table) over knots whose fitted curvature falls on past the data (knots 2-5 identified)
TOTAL = np.array([0.172, 0.171, 0.170, 0.160, 0.150, 0.149, 0.146, 0.141, 0.135])


def _data(a, t):
    return SimpleNamespace(recs=[SimpleNamespace(rec=SimpleNamespace(angle_deg=np.asarray(a, float), t_s=t))])


def test_a_friction_total_is_held_at_the_edge_knots_beyond_the_identified_ones():
    new = friction_total(TOTAL, np.arange(2, 6))
    np.testing.assert_allclose(new[6:], TOTAL[5])           # not the curvature's 0.146 ... 0.135
    np.testing.assert_allclose(new[:2], TOTAL[2])           # the other side too
    np.testing.assert_allclose(new[2:6], TOTAL[2:6])        # the identified knots unchanged
    np.testing.assert_allclose(friction_total(TOTAL, np.arange(TOTAL.size)), TOTAL)   # the whole grid identified


def test_the_slow_range_leaves_out_fast_passes_and_the_stops():
    t = np.arange(0.0, 6.0, 1e-3)
    a = np.where(t < 2.5, 20.0 + 8.0 * t, 0.0)    # a slow sweep 20 -> 40 deg (125 ms per degree) ...
    fast = (t >= 2.5) & (t < 2.64)                 # ... one pass 40 -> 82 deg at 300 deg/s ...
    a[fast] = 40.0 + 300.0 * (t[fast] - 2.5)
    a[t >= 2.64] = 82.0                            # ... and a rest against the open stop (82 deg)
    lo, hi = slow_range_deg(_data(a, t), (-1.0, 82.0))
    assert 19.0 <= lo <= 20.0 and 40.0 <= hi <= 41.5
    lo, hi = slow_range_deg(_data(a, t), (-1.0, 95.0))   # a stop far away: the rest at 82 deg is a slow visit
    assert hi >= 82.0
    assert slow_range_deg(_data(np.full(10, 30.0), None), (-1.0, 82.0)) is None   # no time base


def test_only_a_friction_level_is_held():
    assert FRICTION_LEVEL == ("angle_dependent_friction",)
    final = object()
    assert hold_friction(final, None, _data([1.0], np.arange(1.0))) is final      # nothing refined
