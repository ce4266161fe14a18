"""Round 33 (o33supply): a supply drop's table is also tried odd in the current, d(-i) = -d(i): one coefficient per
knot of the side the recordings reach further, mirrored onto the other (diagnose.shapes.smooth_current_term with
odd=True, odd_knots)."""
import numpy as np

from etb_gym import make_plant
from etb_gym.diagnose import shapes as S


def _current(low=-3.0):
    """An open loop's current: mostly positive (to 4 A), down to ``low`` only briefly."""
    t = np.arange(3000) * 1e-3
    return np.where(np.sin(2 * np.pi * 0.5 * t) > 0, 4.0 * np.sin(2 * np.pi * 0.5 * t),
                    -low * np.sin(2 * np.pi * 0.5 * t) ** 9)


def test_the_odd_table_mirrors_the_side_reached_further(still_plate_data):
    data = still_plate_data(_current())
    terms = S.family_terms("supply_drop", make_plant("3B"), data)
    lin, odd = terms[0], terms[-1]
    assert odd.id == "supply_drop_map_odd"
    pos = lin.grid[lin.grid > 0]
    assert pos[-1] > -lin.grid[0]                                      # the positive side reaches further
    assert odd.n_coef == pos.size and np.allclose(odd.coef_grid[odd.coef_grid > 0], pos)
    c = np.random.default_rng(1).normal(size=odd.n_coef)
    v = odd.values(c)
    assert np.allclose(np.interp(-odd.grid, odd.grid, v), -v, atol=1e-9)   # odd: d(-i) = -d(i), 0 at 0 A
    assert abs(np.interp(0.0, odd.grid, v)) < 1e-12
    assert np.allclose(v[np.searchsorted(odd.grid, pos)], c)           # through the coefficients at P
    assert odd.component(c).kind == lin.component(np.zeros(lin.n_coef)).kind   # an ordinary CurrentVoltageMap


def test_its_coefficients_see_both_directions_time_and_an_odd_line_is_not_rough(still_plate_data):
    data = still_plate_data(_current(low=-0.3))
    lin, smooth, odd = S.family_terms("supply_drop", make_plant("3B"), data)
    v_odd, v_lin = S.visit_time_s(odd, data), S.visit_time_s(lin, data)
    pos = lin.grid > 0
    assert np.all(v_odd >= v_lin[pos] - 1e-12)                         # the positive knot's time and its mirror's
    assert np.sum(v_odd) > np.sum(v_lin[pos])
    R = odd.roughness()
    assert R.shape == (odd.coef_grid.size - 2, odd.n_coef)
    s_pos = odd.coef_axis[odd.coef_grid > 0]
    assert np.allclose(R @ s_pos, 0.0)                                 # straight (and odd) on the warped axis
    assert np.linalg.norm(R @ (s_pos ** 2)) > 0.1                      # a bend through 0 A is rough


def test_a_symmetric_drop_on_one_side_is_the_drop_on_both(still_plate_data):
    data = still_plate_data(_current(low=-0.3))
    odd = S.family_terms("supply_drop", make_plant("3B"), data)[-1]
    drop = lambda i: 0.07 * np.arcsinh(i / 0.27) + 0.02 * i            # noqa: E731  the diode-like drop, odd
    P = odd.coef_grid[odd.coef_grid > 0]
    x = np.linspace(-3.9, 3.9, 1000)
    err = np.abs(np.interp(x, odd.grid, odd.values(drop(P))) - drop(x))
    assert err.max() < 0.01 and np.mean(err[x < -0.1]) < 0.003        # 10 mV at most, a few mV on the side unvisited


def test_the_odd_form_is_kept_unless_a_free_one_gains_min_gain():
    from types import SimpleNamespace

    from etb_gym.diagnose.family_table import MIN_GAIN, choose_form
    odd = SimpleNamespace(term=SimpleNamespace(preferred=True, id="supply_drop_map_odd"), kept=True)
    lin = SimpleNamespace(term=SimpleNamespace(preferred=False, id="supply_drop_map"), kept=True)
    smooth = SimpleNamespace(term=SimpleNamespace(preferred=False, id="supply_drop_map_smooth"), kept=True)
    best, why = choose_form([(lin, 1.03), (smooth, 1.15), (odd, 1.07)])       # s42 3B's folds: within MIN_GAIN
    assert best is odd and "kept over supply_drop_map" in why
    best, why = choose_form([(lin, 1.85), (smooth, 1.89), (odd, 1.97)])       # s38 3B's: the free one gains 6 %
    assert best is lin and why == ""
    best, _ = choose_form([(lin, 1.0), (odd, 1.0 / (1.0 - MIN_GAIN) - 1e-9)])  # just within: the odd one
    assert best is odd
    best, _ = choose_form([(lin, 2.0), (smooth, 1.5)])                        # no preferred form: the lowest
    assert best is smooth
    assert choose_form([]) == (None, "")
    odd.kept = lin.kept = False                      # the folds keep no form (s45 3B closed): the lowest goes on
    best, why = choose_form([(lin, 0.824), (smooth, 0.825), (odd, 0.838)])
    assert best is lin and why == ""
