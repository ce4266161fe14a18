"""A friction level that differs by direction of motion: the nested table forms of every friction family
(shapes.direction_split_term, shapes.direction_offset_term; docs/diagnosis-history.md, round 24 e24friction)."""
from __future__ import annotations

import numpy as np
import pytest

from diagnose_stubs import swing_data
from etb_gym import make_plant
from etb_gym.components import effects_maps as mx
from etb_gym.diagnose import shapes as S


def _speed_term(n=6):
    grid = np.concatenate([[0.0], np.geomspace(0.01, 10.0, n - 2), [30.0]])
    return S.MapTerm("stribeck_friction_map", "friction", mx.SpeedFrictionMap, grid, ("opening_Nm", "closing_Nm"),
                     0.005, "N m", (("presliding_rad", 2e-3),))


def _data():
    return swing_data(40.0, 20.0)


def test_the_split_table_is_a_shared_shape_plus_a_direction_offset():
    """Coefficients (m_0..m_n-1, d): opening m + d, closing m - d; the offset costs no roughness, the shape does
    (counted on both branches), and d = 0 is the symmetric table."""
    t = _speed_term()
    sp = S.direction_split_term(t)
    n = t.grid.size
    assert sp.n_coef == n + 1 and sp.id == "stribeck_friction_map_split"
    m = np.linspace(0.0, 0.01, n) ** 2
    q = sp.component(np.r_[m, 0.004]).params
    assert np.allclose(q.opening_Nm, m + 0.004) and np.allclose(q.closing_Nm, m - 0.004)
    R = sp.roughness()
    assert np.allclose(R[:, -1], 0.0)
    assert np.allclose(R[:, :-1], np.vstack([t.roughness()[: n - 2, :n], t.roughness()[: n - 2, :n]]))
    sym = sp.component(np.r_[m, 0.0]).params
    assert sym.opening_Nm == sym.closing_Nm
    # steady sliding friction: the level of the direction of motion, against it
    c = sp.component(np.r_[np.zeros(n), 0.003])
    assert np.allclose(c.friction_curve(np.array([0.5, -0.5])), [-0.003, -0.003])


def test_every_friction_family_gets_a_direction_form_and_other_families_do_not():
    data = _data()
    base = make_plant("3B")
    ids = [t.id for t in S.family_terms("stribeck_friction", base, data)]
    assert ids == ["stribeck_friction_map", "stribeck_friction_map_split"]
    adf = S.family_terms("angle_dependent_friction", base, data)
    assert [t.id for t in adf] == ["angle_dependent_friction_map", "angle_dependent_friction_direction_map"]
    off = adf[1]
    assert off.n_coef == 1 and off.roughness().shape == (0, 1)
    q = off.component([0.002]).params
    assert q.opening_Nm == (0.002, 0.002) and q.closing_Nm == (-0.002, -0.002)
    assert [t.id for t in S.family_terms("airflow_torque", base, data)] == ["airflow_torque_map"]


def test_a_coefficient_is_visited_where_any_knot_it_moves_is():
    """The shared shape's knot counts both directions' time near it, the offset all of it; the anchored outer
    knot (never visited) stays anchored."""
    data = _data()
    t = S.family_term("stribeck_friction", make_plant("3B"), data)
    v = S.visit_time_s(t, data)
    n = t.grid.size
    vs = S.visit_time_s(S.direction_split_term(t), data)
    assert np.allclose(vs[:n], v[:n] + v[n:])
    assert vs[n] == pytest.approx(np.sum(v))
    assert vs[n - 1] < S.VISIT_MIN_S <= vs[n]
    off = S.direction_offset_term("angle_dependent_friction")
    plain = S.visit_time_s(S.MapTerm("x", "friction", mx.SpeedFrictionMap, off.grid, off.value_fields, 0.005, "N m",
                                     off.fixed), data)
    assert S.visit_time_s(off, data)[0] == pytest.approx(np.sum(plain))
