"""The Stribeck table's direction form that follows the formula's drop (shapes.direction_drop_term;
docs/diagnosis-history.md, round 33 p33stribeck): opening m + d D, closing m - d D, D the fitted drop."""
from __future__ import annotations

import numpy as np

from diagnose_stubs import swing_data
from etb_gym import make_plant
from etb_gym.components import effects_friction as fx
from etb_gym.components import effects_maps as mx
from etb_gym.diagnose import shapes as S


def _speed_term(n=6):
    grid = np.concatenate([[0.0], np.geomspace(0.01, 10.0, n - 2), [30.0]])
    return S.MapTerm("stribeck_friction_map", "friction", mx.SpeedFrictionMap, grid, ("opening_Nm", "closing_Nm"),
                     0.005, "N m", (("presliding_rad", 2e-3),))


def _formula(stiction=0.03, ws=0.1):
    return fx.StribeckFriction(fx.StribeckFrictionParams(stiction_Nm=stiction, stribeck_velocity_rad_s=ws))


def test_the_direction_difference_is_the_formulas_drop_at_rest_and_none_at_speed():
    t = _speed_term()
    n = t.grid.size
    dt = S.direction_drop_term(t, _formula(ws=0.1))
    assert dt.n_coef == n + 1 and dt.id == "stribeck_friction_map_drop"
    m = np.linspace(0.0, 0.01, n) ** 2
    q = dt.component(np.r_[m, 0.004]).params
    drop = np.exp(-np.sqrt(t.grid / 0.1))
    diff = np.asarray(q.opening_Nm) - np.asarray(q.closing_Nm)
    assert np.allclose(diff, 2 * 0.004 * drop)
    assert diff[0] == 2 * 0.004 and diff[-1] < 1e-4          # the full difference at rest, ~none at 30 rad/s
    assert np.allclose(0.5 * (np.asarray(q.opening_Nm) + np.asarray(q.closing_Nm)), m)
    # d costs no roughness (its shape is the formula's), the shared shape costs what the split form's does
    R = dt.roughness()
    assert np.allclose(R[:, -1], 0.0)
    assert np.allclose(R[:, :-1], S.direction_split_term(t).roughness()[:, :-1])
    # the split form's offset stays constant over speed: the two forms differ
    qs = S.direction_split_term(t).component(np.r_[m, 0.004]).params
    assert np.allclose(np.asarray(qs.opening_Nm) - np.asarray(qs.closing_Nm), 0.008)


def test_stribeck_gets_the_drop_form_only_with_a_fitted_drop():
    data = swing_data(40.0, 20.0)
    base = make_plant("3B")
    assert [t.id for t in S.family_terms("stribeck_friction", base, data)] == \
        ["stribeck_friction_map", "stribeck_friction_map_split"]
    ids = [t.id for t in S.family_terms("stribeck_friction", base, data, _formula())]
    assert ids == ["stribeck_friction_map", "stribeck_friction_map_split", "stribeck_friction_map_drop"]
    assert [t.id for t in S.family_terms("stribeck_friction", base, data, _formula(stiction=0.0))] == ids[:2]
    adf = S.family_terms("angle_dependent_friction", base, data, _formula())
    assert [t.id for t in adf] == ["angle_dependent_friction_map", "angle_dependent_friction_direction_map"]
