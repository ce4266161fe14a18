"""Controllers: protocol, factory, gain validation, designed gains, closed loop on the core plant."""
import math

import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.components.sensor import PositionSensor
from etb_gym.controllers import CONTROLLERS, VelocityEstimator, make_controller, register_controller_prefix
from etb_gym.controllers.design import design_pid, linearize
from etb_gym.envs.observation import encode


def closed_loop(ctrl, a0, a1, n=700, at=250, seed=0, params=None):
    plant = make_plant("3B", params)
    sensor = PositionSensor()
    rng = np.random.default_rng(seed)
    x = plant.initial_state(math.radians(a0))
    sensor.reset(x[0])
    aux = np.zeros(len(plant.components))
    ctrl.reset(seed)
    d, out = 0.0, []
    for k in range(n):
        r = a0 if k < at else a1
        y = math.degrees(sensor.read(x[0], rng))
        d = ctrl.act(encode(y, r, d))
        assert -1.0 <= d <= 1.0
        plant.step(x, d, None, k * 1e-3, aux)
        out.append(math.degrees(x[0]))
    return np.array(out)


@pytest.fixture(scope="module")
def pid():
    return make_controller("pid-plain")          # the voltage-mode references: angle-only observations


@pytest.fixture(scope="module")
def smc():
    return make_controller("smc-plain")


def test_protocol_and_names(pid, smc):
    for c in (pid, smc):
        assert isinstance(c.name, str) and c.dt == pytest.approx(1e-3)
        c.reset(seed=1)
        d_open = c.act(encode(10.0, 20.0, 0.0))
        assert 0.0 < d_open <= 1.0          # positive error opens
        c.reset(seed=1)
        d_close = c.act(encode(30.0, 20.0, 0.0))
        assert d_close < d_open


def test_unknown_controller_lists_valid_names():
    with pytest.raises(ValueError) as e:
        make_controller("pdi")
    for name in CONTROLLERS:
        assert name in str(e.value)
    with pytest.raises(ValueError, match="cannot import"):
        make_controller("no_such_module_xyz:Ctrl")


@pytest.mark.parametrize("spec, kw, field", [("pid-plain", {"kp": -1.0}, "kp"),
                                             ("pid-plain", {"ki": float("nan")}, "ki"),
                                             ("smc-plain", {"lambda_rad_s": 0.0}, "lambda_rad_s"),
                                             ("smc-plain", {"K_V": "x"}, "K_V"),
                                             ("pid-plain", {"crossover_rad_s": 0}, "crossover_rad_s"),
                                             ("pid", {"position_gain_rad_s": -3}, "position_gain_rad_s"),
                                             ("smc", {"K_rad_s": float("inf")}, "K_rad_s"),
                                             ("ptos", {"alpha": 2.0}, "alpha")])
def test_invalid_gains_raise_naming_the_gain(spec, kw, field):
    with pytest.raises(ValueError, match=field):
        make_controller(spec, **kw)


def test_module_class_and_prefix_registry():
    c = make_controller("etb_gym.controllers.pid:PIDController", kp=5.0, ki=50.0, kd=0.05)
    assert c.kp_table.tolist() == [5.0]
    seen = {}

    def loader(arg, **kw):
        seen["arg"] = arg
        return make_controller("pid-plain", **kw)

    register_controller_prefix("testprefix", loader)
    c2 = make_controller("testprefix:some/path.zip")
    assert seen["arg"] == "some/path.zip" and c2.name == "pid-plain"
    with pytest.raises(ValueError, match="prefix"):
        register_controller_prefix("bad.prefix", loader)


def test_velocity_estimator_tracks_a_ramp():
    est = VelocityEstimator(1e-3, 300.0)
    v = [est.update(0.5 * k * 1e-3) for k in range(200)]
    assert v[-1] == pytest.approx(0.5, rel=1e-6)
    tf = est.transfer_function()
    assert abs(complex(tf(1.0 + 0j))) < 1e-12          # no DC gain: a differentiator


def test_linearization_matches_physics():
    lin = linearize(None, math.radians(40.0), "sliding")
    poles = lin.poles()
    assert np.all(poles.real < 0)
    # DC gain angle/voltage = (k/R) / (R_F + 0) in the sliding model: spring rate only
    tf = lin.tf()
    dc = float(np.real(tf(0)))
    k, R, RF = 0.132, 1.25, 0.36
    assert dc == pytest.approx(k / R / RF, rel=1e-3)
    pre = linearize(None, math.radians(40.0), "presliding").tf()
    assert float(np.real(pre(0))) == pytest.approx(k / R / (RF + 100.0), rel=1e-3)


def test_pid_design_meets_its_specification():
    d = design_pid(phi0_rad=math.radians(40.0), crossover_rad_s=50.0, phase_margin_deg=50.0)
    assert d.closed_loop_stable
    assert d.gain_crossover_rad_s == pytest.approx(50.0, rel=0.05)
    assert d.phase_margin_deg >= 50.0 - 0.5
    assert 20 * math.log10(d.gain_margin) > 6.0
    assert d.kp_V_per_rad > 0 and d.ki_V_per_rad_s > 0
    with pytest.raises(ValueError, match="phase margin"):
        design_pid(crossover_rad_s=400.0, phase_margin_deg=85.0)


@pytest.mark.parametrize("spec", ["pid", "smc"])
def test_closed_loop_positions_the_plate(spec, request):
    ctrl = request.getfixturevalue(spec)
    a = closed_loop(ctrl, 20.0, 40.0)
    assert abs(a[-1] - 40.0) < 0.25
    assert np.max(a) < 40.0 + 0.1 * 20.0                 # no gross overshoot


def test_pid_compensation_helps_small_steps(pid):
    plain = make_controller("pid-nocomp")
    tail = slice(-80, None)
    e_comp = np.mean(np.abs(closed_loop(pid, 40.0, 40.5)[tail] - 40.5))
    e_plain = np.mean(np.abs(closed_loop(plain, 40.0, 40.5)[tail] - 40.5))
    assert e_comp < 0.1 and e_comp < e_plain


def test_smc_designs_on_random_nameplates():
    """Seeds 2 and 8 gave a loop with |L| >= 1 up to Nyquist at small layer gains: the margin screen took
    log10(0) and raised a bare 'math domain error' instead of moving on to larger gains."""
    import numpy as np

    from etb_gym.controllers.smc import SlidingModeController
    from etb_gym.diagnose.synthetic import random_nameplate
    for seed in (2, 8):
        c = SlidingModeController(model=random_nameplate(np.random.default_rng(seed)))
        assert c.layer_gain > 0 and np.isfinite(c.layer_gain)
