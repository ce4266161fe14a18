"""twin_range.hold_airflow: an airflow torque's table beyond the angles a closed loop reached (round 33)."""
import math

import numpy as np

from etb_gym.components.spring import limp_home_spring_kernel
from etb_gym.diagnose.twin_range import AIRFLOW, airflow_total, hold_airflow

GRID = np.radians([0.0, 3.0, 6.0, 12.0, 18.0, 24.0, 30.0, 36.0, 42.0])
# a plateau's rise where the data end (knots 1-6 reached) and the slope continued beyond them (continue_tables)
TOTAL = np.array([0.002, 0.002, 0.001, 0.0, -0.004, -0.010, -0.014, -0.018, -0.022])


def test_an_airflow_total_is_held_above_the_first_knot_beyond_the_data():
    # the data end between knots 6 and 7: knot 7's interval holds data, it keeps its value; beyond it held
    new, level, slope = airflow_total(TOTAL, 7, None)
    np.testing.assert_allclose(new[8:], TOTAL[7])          # not the slope's -0.022
    np.testing.assert_allclose(new[:8], TOTAL[:8])
    assert level == 0.0 and slope == 0.0
    np.testing.assert_allclose(airflow_total(TOTAL, None, None)[0], TOTAL)   # the data reach the last knot


def test_the_level_at_limp_home_moves_out_where_the_data_never_went_below_it():
    new, level, _ = airflow_total(TOTAL, None, 1)           # limp-home is knot 1, the data never below it
    assert level == TOTAL[1]
    assert new[1] == 0.0 and new[0] == TOTAL[0] - TOTAL[1]
    np.testing.assert_allclose(np.diff(new), np.diff(TOTAL))  # a level moved, the shape kept


def test_the_straight_part_above_limp_home_moves_out_for_the_spring_rate():
    # a rate traded into the table (a ramp of 0.01 N m/rad from limp-home) under a plateau that rises at 30 deg
    g = np.radians([0.0, 3.0, 6.0, 12.0, 18.0, 24.0, 30.0, 36.0, 42.0, 48.0, 54.0])
    plateau = np.where(g > np.radians(33.0), -0.015, 0.0)
    total = 0.002 + 0.01 * (g - g[1]) + plateau
    total[0] = total[1]
    new, level, slope = airflow_total(total, 8, 1, g, np.arange(1, 9))
    assert abs(slope - 0.01) < 1e-9 and abs(level - 0.002) < 1e-12
    np.testing.assert_allclose(new, np.where(np.arange(g.size) > 8, -0.015, plateau), atol=1e-12)
    # fewer than three reached knots within RATE_SPAN_DEG above limp-home: no slope taken
    assert airflow_total(total, 8, 1, g, np.array([1, 2, 7, 8]))[2] == 0.0


def test_the_preload_takes_the_level_with_the_torque_above_limp_home_unchanged():
    # spring p = [phi_LH, T_SP0, R_F, eps, c_LH]; the table's level L moves out: T_SP0 - L, table - L
    lh, p0, rate, level = math.radians(3.0), 0.15, 0.35, -0.0048
    p = np.array([lh, p0, rate, 3e-3, 0.0])
    q = np.array([lh, p0 - level, rate, 3e-3, 0.0])
    for deg, change in ((20.0, 0.0), (1.0, -2.0 * level)):
        before = limp_home_spring_kernel(0.0, math.radians(deg), 0.0, 0.0, 0.0, None, p, None)[0] + level
        after = limp_home_spring_kernel(0.0, math.radians(deg), 0.0, 0.0, 0.0, None, q, None)[0]
        assert abs(after - before - change) < 1e-12
    # the rate takes a ramp s (phi - phi_LH): R_F - s, the table - s (phi - phi_LH); above limp-home unchanged,
    # below it the table is held (flat), so the spring's rate carries the torque there
    s = 0.004
    r = np.array([lh, p0, rate - s, 3e-3, 0.0])
    for deg in (10.0, 40.0):
        d = math.radians(deg) - lh
        before = limp_home_spring_kernel(0.0, math.radians(deg), 0.0, 0.0, 0.0, None, p, None)[0] + s * d
        after = limp_home_spring_kernel(0.0, math.radians(deg), 0.0, 0.0, 0.0, None, r, None)[0]
        assert abs(after - before) < 1e-12


def test_only_closed_loops_and_airflow_tables_are_edited():
    assert AIRFLOW == ("airflow_torque",)

    class Rd:
        residual = "angle"

    class D:
        recs = [Rd()]
    final = object()
    assert hold_airflow(final, object(), D()) is final       # an open loop: the fit's own hold stands
