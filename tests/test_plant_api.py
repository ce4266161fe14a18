"""Plant API, plain vs fast path, bad input (issue 2, items 6 and 9)."""
import math

import numpy as np
import pytest

from etb_gym import MODELS, Plant, make_plant
from etb_gym.components import (InductanceTable, NonlinearInductanceDrive)
from etb_gym.components.base import Component, Params
from etb_gym.integrate import FastPathUnavailableWarning


@pytest.mark.parametrize("model", MODELS)
def test_plain_and_fast_paths_agree(model, rich_duty):
    p = make_plant(model)
    d = rich_duty[:300]
    a = p.simulate(d, path="fast")
    b = p.simulate(d, path="plain")
    np.testing.assert_allclose(a.states, b.states, rtol=1e-9, atol=1e-9)


def test_state_names_and_get_set_state():
    p = make_plant("3B")
    assert p.state_names == ("angle_rad", "velocity_rad_s", "current_A", "friction.z_rad")
    x = p.initial_state(math.radians(30))
    x2 = p.step(x.copy(), 0.4)
    tr = p.simulate([0.4], x0=x)
    np.testing.assert_allclose(tr.states[-1], x2)
    assert set(tr.torques_Nm) == {"drive", "friction", "spring", "stops"}


def test_overrides_and_roundtrip_dict():
    p = make_plant("3B", {"friction.coulomb_Nm": 0.1, "supply.voltage_V": 14.0})
    assert p.friction.params.coulomb_Nm == 0.1 and p.supply.voltage_V == 14.0
    q = Plant.from_dict(p.to_dict())
    assert q.params_dict() == p.params_dict()
    np.testing.assert_array_equal(q.P, p.P)


def test_inductance_table_replaces_map():
    ci = np.linspace(0, 10, 11)
    ap = np.radians([0, 45, 90])
    L = 0.02 / (1 + (ci[:, None] / 3) ** 2) + 0.004 + 0 * ap[None, :]
    tab = InductanceTable(ci, ap, L)
    d = NonlinearInductanceDrive(inductance_table=tab)
    assert abs(float(d.inductance(1.5, 0.3)) - (0.02 / (1 + 0.25) + 0.004)) < 1e-3
    p = make_plant("3B").replace(drive=d)
    tr = p.simulate(voltage=np.full(100, 5.0))
    assert np.all(np.isfinite(tr.states))
    assert Plant.from_dict(p.to_dict()).drive.params.inductance_table == tab


@pytest.mark.parametrize("bad, field", [
    ({"rotor.inertia_kg_m2": 0.0}, "inertia_kg_m2"),
    ({"drive.resistance_ohm": -1.0}, "resistance_ohm"),
    ({"drive.inductance_H": 0.0}, "inductance_H"),
    ({"friction.bristle_stiffness_Nm_per_rad": 0.0}, "bristle_stiffness_Nm_per_rad"),
    ({"friction.coulomb_Nm": -0.1}, "coulomb_Nm"),
    ({"friction.static_Nm": 0.1}, "static_Nm"),
    ({"spring.limp_home_rad": 2.0}, "limp_home_rad"),
    ({"drive.resistance_ohm": float("nan")}, "resistance_ohm"),
])
def test_nonphysical_parameters_fail_at_build(bad, field):
    with pytest.raises(ValueError, match=field):
        make_plant("3B", bad)


@pytest.mark.parametrize("kw, msg", [
    (dict(current_A=[0, 1], angle_rad=[0, 1], inductance_H=[[0.01, 0.01]]), "shape"),
    (dict(current_A=[1, 0], angle_rad=[0, 1], inductance_H=[[0.01, 0.01], [0.01, 0.01]]), "increasing"),
    (dict(current_A=[0, 1], angle_rad=[0, 1], inductance_H=[[0.01, -0.01], [0.01, 0.01]]), r"inductance_H\[0\]\[1\]"),
])
def test_malformed_inductance_table(kw, msg):
    with pytest.raises(ValueError, match=msg):
        InductanceTable(**kw)


def test_bad_inputs_raise():
    p = make_plant("3B")
    with pytest.raises(ValueError, match="unknown model"):
        make_plant("4D")
    with pytest.raises(ValueError, match=r"duty\[1\]"):
        p.simulate([0.1, float("nan")])
    with pytest.raises(ValueError, match="exceeds the supply"):
        p.simulate(voltage=[20.0])
    with pytest.raises(ValueError, match=r"duty\[0\]"):
        p.simulate([1.5])
    with pytest.raises(ValueError, match="finite"):
        p.step(p.initial_state(), float("inf"))
    with pytest.raises(ValueError, match="unknown component"):
        p.with_params({"gearbox.ratio": 2.0})
    with pytest.raises(ValueError, match="unknown parameter"):
        p.with_params({"friction.mu": 2.0})
    with pytest.raises(ValueError, match="outside the end stops"):
        p.initial_state(math.radians(120))


def test_new_component_without_kernel_falls_back_visibly():
    import dataclasses

    @dataclasses.dataclass(frozen=True)
    class ConstantTorqueParams(Params):
        torque_Nm: float = 0.5

    def plain_kernel(t, phi, omega, i, u, s, p, ds):
        return p[0], 0.0, 0.0

    class ConstantTorque(Component):
        Params = ConstantTorqueParams
        kernel = staticmethod(plain_kernel)

    with pytest.warns(FastPathUnavailableWarning):
        p = make_plant("3B", effects=[ConstantTorque()])
    assert not p.fast
    base = make_plant("3B")
    a = p.simulate(np.zeros(200), angle_deg=3.0)
    b = base.simulate(np.zeros(200), angle_deg=3.0)
    assert p.component_names[-1] == "ConstantTorque"
    assert a.torques_Nm["ConstantTorque"][-1] == 0.5
    assert not np.allclose(a.angle_rad, b.angle_rad)
