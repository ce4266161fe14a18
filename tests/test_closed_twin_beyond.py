"""closed_twin._continued: a closed loop's family table over angle beyond the visited knots (round 23)."""
import math

import numpy as np

from etb_gym.diagnose.closed_twin import _continued

GRID = np.radians(np.arange(0.0, 91.0, 10.0))       # knots 0..90 deg


def test_the_edges_slope_is_continued_where_the_formula_goes_further():
    prof = -0.001 * np.arange(GRID.size) ** 2        # the formula steepens
    total = np.zeros(GRID.size)
    total[:7] = [0, 0, 0, 0, -0.002, -0.004, -0.006]  # visited 0..60 deg, still falling at the edge
    total[7:] = -0.006                               # held (penalized.hold_rows)
    out = _continued(total, prof, GRID, np.arange(7), math.nan)
    np.testing.assert_allclose(out[7:], [-0.008, -0.010, -0.012])
    np.testing.assert_array_equal(out[:7], total[:7])  # the visited knots are untouched


def test_the_continuation_goes_no_further_than_the_formula_and_holds_where_they_part():
    total = np.zeros(GRID.size)
    total[:7] = [0, 0, 0, 0, -0.002, -0.004, -0.006]
    total[7:] = -0.006
    flat = np.full(GRID.size, -0.01)
    flat[8:] = -0.0105                               # the formula saturates beyond 70 deg
    out = _continued(total, flat, GRID, np.arange(7), math.nan)
    np.testing.assert_allclose(out[7:], [-0.006, -0.0065, -0.0065])
    rising = np.linspace(0.0, 0.01, GRID.size)       # the formula goes the other way: held
    np.testing.assert_allclose(_continued(total, rising, GRID, np.arange(7), math.nan)[7:], -0.006)


def test_the_continuation_does_not_cross_limp_home():
    prof = -0.001 * np.arange(GRID.size)[::-1] ** 2    # the formula steepens towards 0 deg
    total = np.zeros(GRID.size)
    total[3:] = [-0.006, -0.004, -0.002, 0, 0, 0, 0]   # visited 30..90 deg
    total[:3] = -0.006
    out = _continued(total, prof, GRID, np.arange(3, 10), math.radians(15.0))
    np.testing.assert_allclose(out[:3], [-0.008, -0.008, -0.008])   # 20 deg continued, held below 15 deg
