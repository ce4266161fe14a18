"""The coil heating's thermal network (components/effects_thermal.py): one branch is coil_heating's one node, the
fixed-rate stepper against a tight-tolerance solve_ivp solution, the plant file round trip, parameter errors, and
the table form of coil_heating in diagnose.shapes (grid, roughness over log tau)."""
import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.components import effects as fx
from etb_gym.plantfile import load_plant, save_plant

VOLT = np.concatenate([np.full(1500, 6.0), np.full(800, -4.0), np.full(700, 2.0), np.full(1000, 7.0)])
NET = dict(time_constant_s=(0.3, 2.0, 40.0), thermal_resistance_K_per_W=(1.0, 3.0, 6.0),
           voltage_rise_K_per_V2=(0.0, 0.05, 0.02), cold_resistance_ohm=1.25)


def test_one_branch_is_coil_heating_one_node():
    one = fx.CoilHeating(heat_capacity_J_per_K=2.0, thermal_resistance_K_per_W=5.0)
    net = fx.ThermalNetwork(time_constant_s=(10.0, 100.0), thermal_resistance_K_per_W=(5.0, 0.0),
                            cold_resistance_ohm=one.params.cold_resistance_ohm)
    a = make_plant("3B", effects=[one]).simulate(voltage=VOLT)
    b = make_plant("3B", effects=[net]).simulate(voltage=VOLT)
    np.testing.assert_allclose(b.state("thermal_network.branch0_temperature_rise_K"),
                               a.state("coil_heating.temperature_rise_K"), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(b.angle_deg, a.angle_deg, atol=1e-12)


def test_thermal_network_matches_solve_ivp_and_heats_like_its_step_response():
    p = make_plant("3B", effects=[fx.ThermalNetwork(**NET)])
    fast = p.simulate(voltage=VOLT)
    ref = p.reference(voltage=VOLT, method="LSODA", rtol=1e-9)
    err = np.degrees(fast.angle_rad - ref.angle_rad)
    assert np.sqrt(np.mean(err ** 2)) < 0.005 and np.abs(err).max() < 0.05
    for k in range(3):
        name = f"thermal_network.branch{k}_temperature_rise_K"
        np.testing.assert_allclose(fast.state(name), ref.state(name), rtol=1e-4, atol=1e-6)
    T = sum(fast.state(f"thermal_network.branch{k}_temperature_rise_K") for k in range(3))
    assert T[1500] > 5.0 and fast.current_A[1499] < fast.current_A[200]     # hotter coil, less current
    # under a constant loss (alpha's feedback aside) the rise is the step response sum R_k (1 - exp(-t/tau_k))
    s = fx.ThermalNetwork(**{**NET, "voltage_rise_K_per_V2": ()}).step_response([0.0, 1e3])
    assert s[0] == 0.0 and s[1] == pytest.approx(10.0, rel=1e-9)


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_thermal_network_round_trips_through_the_plant_file(tmp_path, suffix):
    p = make_plant("3B", effects=[fx.ThermalNetwork(**NET)])
    q = load_plant(save_plant(p, tmp_path / f"twin{suffix}"))
    assert q.to_dict() == p.to_dict()
    assert q.state_names == p.state_names
    np.testing.assert_array_equal(q.simulate(voltage=VOLT).states, p.simulate(voltage=VOLT).states)


@pytest.mark.parametrize("bad, match", [
    (dict(time_constant_s=(0.0, 1.0)), "time_constant_s"),
    (dict(time_constant_s=(1e-4, 1.0)), "time constants >= 1 ms"),
    (dict(time_constant_s=(2.0, 1.0)), "strictly increasing"),
    (dict(thermal_resistance_K_per_W=(1.0, 2.0, 3.0)), "one value per knot"),
    (dict(cold_resistance_ohm=-1.0), "cold_resistance_ohm"),
])
def test_thermal_network_params_errors_name_the_field(bad, match):
    with pytest.raises(ValueError, match=match):
        fx.ThermalNetwork(**bad)


def test_coil_heating_has_a_table_form_over_log_spaced_time_constants():
    from diagnose_stubs import swing_data
    from etb_gym.diagnose import shapes as S
    from etb_gym.diagnose import penalized as P
    data = swing_data(30.0, 20.0)                 # 3 s
    t = S.family_term("coil_heating", make_plant("3B"), data)
    assert t.cls is fx.ThermalNetwork and t.grid.size == S.THERMAL_BRANCHES
    assert t.grid[0] == pytest.approx(S.THERMAL_TAU_MIN) and t.grid[-1] == pytest.approx(S.THERMAL_SPAN * 2.999)
    np.testing.assert_allclose(np.diff(np.log(t.grid)), np.log(t.grid[1] / t.grid[0]))
    R = t.roughness()                              # plain second differences over log tau
    np.testing.assert_allclose(R[0, :3], [1.0, -2.0, 1.0])
    comp = t.component(np.arange(t.n_coef, dtype=float))
    assert comp.params.cold_resistance_ohm == make_plant("3B").drive.params.resistance_ohm
    assert len(comp.state_names) == t.grid.size and comp.params.voltage_rise_K_per_V2 == (0.0,) * t.grid.size
    v = [u for u in S.family_terms("coil_heating", make_plant("3B"), data) if u.id == "coil_heating_voltage_map"]
    assert len(v) == 1 and v[0].n_coef == 2 * t.grid.size          # the loss that goes with u^2: the folds decide
    # the folds score the current's rows too where a current was recorded (here none: the angle alone)
    assert not t.score_current and not P.Problem.make(*_spec_x(t), ("nominal", t.id), [t], data).score_current


def _spec_x(term):
    from etb_gym.diagnose.model import Spec
    spec = Spec(make_plant("3B")).with_candidate(term.candidate())
    return spec, spec.x_from_values({})


def test_the_folds_score_the_current_rows_of_a_heating_table():
    from etb_gym.diagnose import shapes as S
    from etb_gym.diagnose import penalized as P
    from etb_gym.diagnose.model import prepare
    from etb_gym.recordings import Recording
    t = np.arange(2000) * 1e-3
    rec = Recording(name="r.csv", t_s=t, voltage_V=np.full(t.size, 2.0), angle_deg=20.0 + 5.0 * np.sin(t),
                    current_A=np.full(t.size, 1.0), supply_V=None)
    data = prepare([rec], 12.0)
    fold, scored = P._row_info(data)
    fold_c, scored_c = P._row_info(data, current=True)
    assert scored.sum() == t.size and scored_c.sum() == 2 * t.size and np.array_equal(fold, fold_c)
    term = S.family_term("coil_heating", make_plant("3B"), data)
    assert term.score_current and P.Problem.make(*_spec_x(term), ("nominal", term.id), [term], data).score_current
