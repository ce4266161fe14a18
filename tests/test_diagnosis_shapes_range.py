"""Round 21: the knots of a family's current table follow the currents the recordings visit (a closed loop's
are nearly all of one sign), with more near the current's sign change (diagnose.shapes)."""
import numpy as np

from etb_gym.diagnose import shapes as S


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


def test_family_current_tables_use_the_shared_grid_and_the_generic_one_does_not():
    from etb_gym import make_plant
    from etb_gym.diagnose.model import prepare
    from etb_gym.recordings import Recording
    t = np.arange(3000) * 1e-3
    cur = 3.0 + 3.0 * np.sin(2 * np.pi * 0.5 * t) - 0.3 * (t < 0.1)        # -0.3 .. 6 A, nearly all positive
    rec = Recording(name="closed.csv", t_s=t, voltage_V=1.25 * cur, angle_deg=np.full(t.size, 40.0),
                    current_A=cur, supply_V=None)
    data = prepare([rec], 12.0)
    base = make_plant("3B")
    for fam in ("supply_drop", "inductance_saturation"):
        g = S.family_term(fam, base, data).grid
        inside = g[(g > 0) & (g <= cur.max() + 1e-9)]
        assert np.max(np.diff(inside)) < 1.0, (fam, g)
    gen = S.current_grid(data, base, 7)                                      # unmodelled_voltage: as before
    assert np.max(np.diff(gen[(gen > 0) & (gen <= cur.max() + 1e-9)])) > 1.5


def test_a_torque_constant_error_gets_a_current_table_for_the_torque_alone():
    """Round 23: besides the current table whose back-EMF follows it, a torque-constant error is refined by a
    table of the torque per ampere alone (effect.current_torque_map: back-EMF unchanged)."""
    from etb_gym import make_plant
    from etb_gym.components import effects as fx
    from etb_gym.diagnose.model import prepare
    from etb_gym.recordings import Recording
    m = fx.CurrentTorqueMap(current_A=(-2.0, 0.0, 2.0), delta_Nm_per_A=(0.001, 0.0, 0.004))
    tq, emf, _ = m.kernel(0.0, 0.5, 30.0, 2.0, 5.0, np.zeros(1), m.param_vector(), np.zeros(1))
    assert np.isclose(tq, 0.008) and emf == 0.0                    # torque dk(i) i, no back-EMF at 30 rad/s
    t = np.arange(2000) * 1e-3
    cur = 2.0 * np.sin(2 * np.pi * t)
    rec = Recording(name="r.csv", t_s=t, voltage_V=2.0 * cur, angle_deg=np.full(t.size, 40.0), current_A=cur,
                    supply_V=None)
    terms = S.family_terms("torque_constant_error", make_plant("3B"), prepare([rec], 12.0))
    kinds = [t.cls for t in terms]
    assert fx.CurrentTorqueConstantMap in kinds and fx.CurrentTorqueMap in kinds
    assert np.allclose(terms[-1].grid, terms[-2].grid)
