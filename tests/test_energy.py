"""Conservation and equilibrium checks against analytic results (not against the model itself)."""

import numpy as np
import pytest

from etb_gym import Plant, make_plant
from etb_gym.components import FluxDrive, LinearDrive


@pytest.mark.parametrize("Drive", [LinearDrive, FluxDrive])
def test_power_balance_of_the_drive(Drive):
    """Electrical energy in = copper loss + magnetic energy + kinetic energy (drive + rotor only).

    Holds only with the back-EMF opposing the voltage and the torque and back-EMF sharing k(phi)."""
    p = Plant(drive=Drive(), control_period_s=1e-4, substeps=10)
    u = np.concatenate([np.full(300, 3.0), np.full(200, -2.0), np.full(300, 1.0)])
    tr = p.reference(voltage=u, angle_deg=10.0, rtol=1e-10)
    i, w = tr.current_A, tr.velocity_rad_s
    R, L, J = p.drive.params.resistance_ohm, p.drive.params.inductance_H, p.rotor.inertia_kg_m2
    dt = p.control_period_s
    e_in = np.sum(u * 0.5 * (i[1:] + i[:-1])) * dt
    e_cu = np.sum(R * 0.5 * (i[1:] ** 2 + i[:-1] ** 2)) * dt
    e_store = 0.5 * L * (i[-1] ** 2 - i[0] ** 2) + 0.5 * J * (w[-1] ** 2 - w[0] ** 2)
    scale = np.sum(np.abs(u * 0.5 * (i[1:] + i[:-1]))) * dt
    assert abs(e_in - e_cu - e_store) < 2e-3 * scale, (e_in, e_cu, e_store)


def test_rest_at_limp_home_is_an_equilibrium():
    for m in ("1A", "2B", "3B", "3C"):
        p = make_plant(m)
        tr = p.simulate(np.zeros(500))
        assert np.abs(tr.angle_deg - 3.0).max() < 1e-9
        assert np.abs(tr.current_A).max() < 1e-12


@pytest.mark.parametrize("volts", [4.0, 5.0, 6.0])
def test_viscous_plant_settles_at_the_analytic_equilibrium(volts):
    """Model 1A: k*u/R = T_SP0 + R_F*(phi - phi_LH) at rest (no Coulomb friction)."""
    p = make_plant("1A")
    tr = p.simulate(voltage=np.full(3000, volts))
    k, R = p.drive.params.torque_constant_Nm_per_A, p.drive.params.resistance_ohm
    s = p.spring.params
    phi = s.limp_home_rad + (k * volts / R - s.preload_Nm) / s.rate_Nm_per_rad
    assert abs(tr.angle_rad[-1] - phi) < 1e-4
    assert abs(tr.current_A[-1] - volts / R) < 1e-6
