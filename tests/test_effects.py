import math

import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.components import REGISTRY
from etb_gym.components import effects as fx
from etb_gym.excitation import rich_excitation
from etb_gym.plantfile import load_plant, save_plant

DUTY = rich_excitation(1.0)


@pytest.fixture(scope="module")
def nominal():
    return make_plant("3B").simulate(duty=DUTY).angle_deg


ZERO = {  # an effect at zero magnitude must leave the plant unchanged
    fx.CoilHeating: dict(temperature_coefficient_per_K=0.0),
    fx.SupplyDrop: {}, fx.TorqueConstantError: {}, fx.InductanceSaturation: {}, fx.ShaftFluxLoss: {},
    fx.SpringAsymmetry: {}, fx.Backlash: {}, fx.EndStopCompliance: {}, fx.AirflowTorque: {},
    fx.StribeckFriction: {}, fx.AngleDependentFriction: {},
}
ACTIVE = {
    fx.CoilHeating: dict(heat_capacity_J_per_K=2.0), fx.SupplyDrop: dict(forward_drop_V=0.5),
    fx.TorqueConstantError: dict(delta_Nm_per_A=-0.01), fx.InductanceSaturation: dict(inductance_drop_H=0.004),
    fx.ShaftFluxLoss: dict(loss_at_open_Nm_per_A=0.03), fx.SpringAsymmetry: dict(closing_preload_delta_Nm=0.1),
    fx.Backlash: dict(play_rad=0.02), fx.EndStopCompliance: dict(open_rad=math.radians(85.0)),
    fx.AirflowTorque: dict(quadratic_Nm=-0.1), fx.StribeckFriction: dict(stiction_Nm=0.1),
    fx.AngleDependentFriction: dict(slope_Nm=0.1),
}


def test_library_covers_contract_ids():
    ids = set(fx.ODE_EFFECTS)
    assert ids == {"coil_heating", "supply_drop", "torque_constant_error", "inductance_saturation", "shaft_flux_loss",
                   "spring_asymmetry", "backlash", "end_stop_compliance", "airflow_torque", "stribeck_friction",
                   "angle_dependent_friction"}
    for C in fx.ODE_EFFECTS.values():
        assert REGISTRY[C.kind] is C


@pytest.mark.parametrize("C", list(ZERO), ids=lambda C: C.effect_id)
def test_zero_magnitude_is_neutral_and_active_changes_angle(C, nominal):
    p0 = make_plant("3B", effects=[C(**ZERO[C])])
    assert p0.fast
    np.testing.assert_allclose(p0.simulate(duty=DUTY).angle_deg, nominal, atol=1e-9)
    p1 = make_plant("3B", effects=[C(**ACTIVE[C])])
    assert np.max(np.abs(p1.simulate(duty=DUTY).angle_deg - nominal)) > 0.05


def test_plant_file_round_trip_with_effects(tmp_path):
    p = make_plant("3B", effects=[fx.ShaftFluxLoss(loss_at_open_Nm_per_A=0.02), fx.CoilHeating()])
    f = save_plant(p, tmp_path / "cal.toml")
    q = load_plant(f)
    assert q.component_names[-2:] == ("shaft_flux_loss", "coil_heating")
    np.testing.assert_allclose(q.simulate(duty=DUTY).angle_deg, p.simulate(duty=DUTY).angle_deg)


def test_coil_heating_raises_resistance_with_current():
    p = make_plant("3B", effects=[fx.CoilHeating(heat_capacity_J_per_K=5.0, thermal_resistance_K_per_W=10.0)])
    tr = p.simulate(voltage=np.full(3000, 6.0))
    T = tr.state("coil_heating.temperature_rise_K")
    assert T[-1] > T[1000] > 1.0
    assert tr.current_A[-1] < tr.current_A[1000]     # hotter coil, less current at the same voltage


def test_effect_params_validate():
    with pytest.raises(ValueError, match="ShaftFluxLossParams.exponent"):
        fx.ShaftFluxLoss(exponent=0.1)
    with pytest.raises(ValueError, match="StribeckFrictionParams.stiction_Nm"):
        fx.StribeckFriction(stiction_Nm=-1.0)
