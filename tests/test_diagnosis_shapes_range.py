"""Round 21: the knots of a family's current table follow the currents the recordings visit (a closed loop's
are nearly all of one sign), with more near the current's sign change (diagnose.shapes)."""
import numpy as np

from etb_gym.diagnose import shapes as S
from etb_gym.diagnose import family_table as FT


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
    tables = [t for t in terms if t.cls in (fx.CurrentTorqueConstantMap, fx.CurrentTorqueMap) and not t.split_start]
    assert len(tables) == 2 and np.allclose(tables[0].grid, tables[1].grid)


def test_a_torque_constant_error_gets_a_torque_constant_apart_from_the_back_emf_constant():
    """Round 27: a torque per ampere added for each direction of the current with the back-EMF unchanged, its fit
    started from a grid over the torque and the back-EMF constants (family_table.split_start)."""
    from etb_gym.components import effects as fx
    from etb_gym.diagnose.model import prepare
    from etb_gym.recordings import Recording
    t = np.arange(2000) * 1e-3
    cur = 5.0 * np.sin(2 * np.pi * t)
    rec = Recording(name="r.csv", t_s=t, voltage_V=2.0 * cur, angle_deg=np.full(t.size, 40.0), current_A=cur,
                    supply_V=None)
    term = S.torque_emf_term("torque_constant_error", prepare([rec], 12.0))
    assert term.cls is fx.CurrentTorqueMap and term.n_coef == 2 and term.split_start
    assert np.allclose(term.grid, [-0.1, 0.1], atol=1e-3)            # -+2 % of the largest current
    comp = term.component(np.array([0.3, 0.5]))
    for i, k in ((-3.0, 0.3), (0.0, 0.4), (4.0, 0.5)):
        tq, emf, _ = comp.kernel(0.0, 0.5, 30.0, i, 5.0, np.zeros(1), comp.param_vector(), np.zeros(1))
        assert np.isclose(tq, k * i) and emf == 0.0
    assert term.roughness().shape[0] == 0


def test_the_split_start_finds_a_torque_constant_and_a_back_emf_constant_the_formula_ties(monkeypatch):
    """From the formula's optimum (offset 0) the grid and the local fit reach the split the residual asks for;
    a residual whose minimum is the formula's own leaves the start as it is. A stand-in residual, no simulation."""
    from etb_gym import make_plant
    from etb_gym.diagnose import fit as F
    from etb_gym.diagnose.candidates import CANDIDATES
    from etb_gym.diagnose.model import Spec
    cid = "torque_constant_error"
    term = S.torque_emf_term(cid)
    spec = Spec(make_plant("3B")).with_candidate(CANDIDATES[cid]).with_candidate(term.candidate())
    n = len(spec.params)
    x0 = np.zeros(n)
    target = x0.copy()
    k_d = spec.names.index(f"{cid}.delta_Nm_per_A")
    c_m = make_plant("3B").drive.params.torque_constant_Nm_per_A
    target[k_d] = -0.003 * c_m / spec.params[k_d][1].scale         # back-EMF 0.3 % lower ...
    target[-2:] = 0.013 * c_m / term.scale                          # ... torque 1 % higher
    for i, q in enumerate(spec.nominal):
        if q.unit.startswith("N m"):
            target[i] = ((q.init + q.scale * x0[i]) * (c_m * 1.01) / c_m - q.init) / q.scale

    def fake_fun(goal):
        def fun(x):
            return 100.0 * (np.asarray(x, float) - goal)
        fun.failure = None
        return fun
    monkeypatch.setattr(F, "make_fun", lambda spec_, data_: fake_fun(target))
    x = FT.split_start(spec, x0.copy(), cid, term, None)
    assert np.allclose(x, target, atol=1e-3)
    monkeypatch.setattr(F, "make_fun", lambda spec_, data_: fake_fun(x0))
    assert np.allclose(FT.split_start(spec, x0.copy(), cid, term, None), x0)
