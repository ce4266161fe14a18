"""Round 30 (e30supply): a supply drop's table over current is also tried as a cubic spline through the same
coefficients on a log-warped current axis, exported on a finer grid (diagnose.shapes.smooth_current_term)."""
import numpy as np

from etb_gym import make_plant
from etb_gym.diagnose import shapes as S


def _current():
    t = np.arange(3000) * 1e-3
    return 0.5 + 3.5 * np.sin(2 * np.pi * 0.5 * t)                     # -3 .. 4 A


def test_supply_drop_gets_the_smooth_table_beside_the_linear_one(still_plate_data):
    data = still_plate_data(_current())
    terms = S.family_terms("supply_drop", make_plant("3B"), data)
    lin, smooth = terms[0], terms[1]
    assert smooth.id == "supply_drop_map_smooth" and smooth.n_coef == lin.n_coef
    assert np.allclose(smooth.coef_grid, lin.grid) and smooth.grid.size > 4 * lin.grid.size
    c = np.random.default_rng(0).normal(size=lin.n_coef)
    vals = smooth.values(c)
    at = np.searchsorted(smooth.grid, lin.grid)
    assert np.allclose(vals[at], c)                                   # the spline passes through the coefficients
    assert smooth.component(c).kind == lin.component(c).kind          # an ordinary CurrentVoltageMap
    # visit time and roughness are over the coefficients' knots, not the exported ones
    assert np.allclose(S.visit_time_s(smooth, data), S.visit_time_s(lin, data))
    R = smooth.roughness()
    assert R.shape == (lin.n_coef - 2, lin.n_coef)
    assert np.allclose(R @ smooth.coef_axis, 0.0)                     # straight on the warped axis: not rough


def test_the_spline_follows_a_log_like_drop_closer_than_straight_lines(still_plate_data):
    data = still_plate_data(_current())
    lin, smooth = S.family_terms("supply_drop", make_plant("3B"), data)[:2]
    drop = lambda i: 0.1 * np.sign(i) * np.log1p(np.abs(i) / 0.05) + 0.05 * i      # noqa: E731  a diode + a wire
    g = lin.grid
    x = np.linspace(-2.9, 3.9, 2000)
    err_lin = np.abs(np.interp(x, g, drop(g)) - drop(x))
    err_smooth = np.abs(np.interp(x, smooth.grid, smooth.values(drop(g))) - drop(x))
    assert err_smooth.max() < 0.5 * err_lin.max()
    assert np.mean(err_smooth) < 0.25 * np.mean(err_lin)
