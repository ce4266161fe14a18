"""Round 21: the knots of a current table follow the currents the recordings visit (a closed loop's are nearly
all of one sign), and a torque-constant table over angle goes on along its last visited slope beyond the
angles the recordings reached (diagnose.shapes)."""
import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.components.effects_electrical import ShaftFluxLoss
from etb_gym.diagnose import shapes as S
from etb_gym.diagnose.model import Spec, prepare
from etb_gym.recordings import Recording


def test_current_knots_are_shared_by_extent_with_more_near_zero():
    g = S.signed_knots(-0.3, 6.0, 9)                       # a closed loop: the current hardly goes negative
    assert 0.0 in g and g[0] == -0.3 and g[-1] == 6.0
    pos = g[g > 0]
    assert np.max(np.diff(pos)) < 1.0                       # was 1.5 A with half the knots on each side
    near = [x for x in g if 0.0 < abs(x) < 0.1 * 6.0]
    assert len(near) >= 2                                   # the sign change resolved on both sides
    sym = S.signed_knots(-5.0, 5.0, 9)
    assert np.allclose(sym, -sym[::-1])                     # a symmetric range keeps a symmetric grid
    assert np.all(np.diff(S.signed_knots(-0.05, 0.1, 9)) > 0)


def _part_of_the_stroke():
    t = np.arange(3000) * 1e-3
    ang = 40.0 + 15.0 * np.sin(2 * np.pi * 0.5 * t)         # 25-55 deg
    rec = Recording(name="part.csv", t_s=t, voltage_V=np.full(t.size, 2.0), angle_deg=ang, current_A=None,
                    supply_V=None)
    return prepare([rec], 12.0)


@pytest.mark.parametrize("family", ["shaft_flux_loss", "torque_constant_error"])
def test_a_torque_constant_table_continues_its_last_visited_slope(family):
    """Beyond the visited angles the family's total (formula + table) goes on along the line through the last
    two visited knots (held, it missed a loss still growing past a closed loop's last angle)."""
    data = _part_of_the_stroke()
    base = make_plant("3B")
    term = S.family_term(family, base, data)
    assert term.extrapolate == "linear"
    assert S.family_term("angle_dependent_friction", base, data).extrapolate == "hold"
    formula = ShaftFluxLoss(loss_at_open_Nm_per_A=0.01, exponent=3.0)
    prof = S.formula_profile(formula, term)
    n = term.n_coef
    vis = S.visit_time_s(term, data) >= S.VISIT_MIN_S
    lo, hi = np.flatnonzero(vis)[[0, -1]]
    g = term.grid
    want = 0.5 - 2.0 * g                                    # the data ask for a ramp (normalized) where visited
    spec = Spec(base).with_candidate(term.candidate())
    pb = S.Problem.make(spec, np.zeros(len(Spec(base).params) + n), (term.id,), [term], data, formula=formula)
    d = S._solve(np.eye(n)[vis], -want[vis], pb, [1e-3])
    total = d * term.scale + prof
    assert np.allclose(d[vis], want[vis], atol=0.05)
    slope_hi = (total[hi] - total[hi - 1]) / (g[hi] - g[hi - 1])
    slope_lo = (total[lo + 1] - total[lo]) / (g[lo + 1] - g[lo])
    assert np.allclose(total[hi + 1:], total[hi] + slope_hi * (g[hi + 1:] - g[hi]), atol=2e-4), total
    assert np.allclose(total[:lo], total[lo] + slope_lo * (g[:lo] - g[lo]), atol=2e-4), total
    rows, b, held = S.hold_rows(vis.astype(float), prof / term.scale)   # without the grid: held, as before
    assert held.sum() == n - vis.sum() and np.all(np.abs(rows).sum(axis=1) == 2.0)
