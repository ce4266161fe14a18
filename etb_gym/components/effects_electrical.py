"""Candidate effects of the coil loop (diagnosis library, docs/diagnosis.md): components that add to the ODE.

Each adds a torque, a coil-loop voltage drop or an inductance to the nominal drive (see base.py):

    coil_heating            C_th dT/dt = R(T) i^2 - T/R_th,  R(T) = R_0 (1 + alpha T);  drop R_0 alpha T i
                            (T: winding temperature rise above the start of the recording [K])
    supply_drop             drop R_s i + V_f tanh(i / i_f)       (wiring/bridge resistance, switch forward drop)
    torque_constant_error   torque dk i, drop dk omega            (k = c_M + dk for torque and back-EMF alike)
    inductance_saturation   L += -dL x^2 / (1 + x^2),  x = i / i_sat   (iron saturating beyond the nominal map)
    shaft_flux_loss         k(phi) = c_M - k_loss (phi / (pi/2))^n  for torque and back-EMF
                            (the non-magnetic shaft in the armature, paper secs. 4.4 and 7)
"""
from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

from ..jit import kernel
from ..variants import COPPER_ALPHA_PER_K
from .base import Component, Params, check, non_negative, positive


class Effect(Component):
    """A diagnosis effect: an extra component of the plant. ``persistent_states``: its states are slow
    (e.g. a temperature) and carry over when the diagnosis re-initializes a segment from the measured angle."""

    role = "effect"
    effect_id: ClassVar[str] = ""
    persistent_states: ClassVar[bool] = False


# ------------------------------------------------------------------------------------ coil heating
@dataclasses.dataclass(frozen=True)
class CoilHeatingParams(Params):
    cold_resistance_ohm: float = 1.25           # R_0, the drive's resistance at the start temperature
    temperature_coefficient_per_K: float = COPPER_ALPHA_PER_K   # alpha of copper
    heat_capacity_J_per_K: float = 10.0         # C_th of the winding
    thermal_resistance_K_per_W: float = 5.0     # R_th winding -> housing

    def validate(self):
        n = "CoilHeatingParams"
        positive(n, self, "cold_resistance_ohm", "heat_capacity_J_per_K", "thermal_resistance_K_per_W")
        non_negative(n, self, "temperature_coefficient_per_K")

    @property
    def thermal_time_constant_s(self) -> float:
        return self.heat_capacity_J_per_K * self.thermal_resistance_K_per_W


@kernel
def coil_heating_kernel(t, phi, omega, i, u, s, p, ds):
    # p = [R_0, alpha, C_th, R_th]; s = [temperature rise K]
    dR = p[0] * p[1] * s[0]
    ds[0] = ((p[0] + dR) * i * i - s[0] / p[3]) / p[2]
    return 0.0, dR * i, 0.0


class CoilHeating(Effect):
    kind = "effect.coil_heating"
    effect_id = "coil_heating"
    persistent_states = True
    Params = CoilHeatingParams
    state_names = ("temperature_rise_K",)
    state_units = ("K",)
    kernel = staticmethod(coil_heating_kernel)
    description = "coil resistance rises with winding temperature"


# ------------------------------------------------------------------------------------ supply drop
@dataclasses.dataclass(frozen=True)
class SupplyDropParams(Params):
    series_resistance_ohm: float = 0.0      # R_s: wiring, connector, switch on-resistance
    forward_drop_V: float = 0.0             # V_f: switch/diode forward voltage
    forward_current_A: float = 0.05         # i_f: current over which V_f builds up (smooth sign)

    def validate(self):
        positive("SupplyDropParams", self, "forward_current_A")


@kernel
def supply_drop_kernel(t, phi, omega, i, u, s, p, ds):
    return 0.0, p[0] * i + p[1] * math.tanh(i / p[2]), 0.0


class SupplyDrop(Effect):
    kind = "effect.supply_drop"
    effect_id = "supply_drop"
    Params = SupplyDropParams
    kernel = staticmethod(supply_drop_kernel)
    description = "supply or H-bridge voltage loss under current"


# ------------------------------------------------------------------------------------ torque constant
@dataclasses.dataclass(frozen=True)
class TorqueConstantErrorParams(Params):
    delta_Nm_per_A: float = 0.0             # dk: true c_M minus the model's


@kernel
def torque_constant_error_kernel(t, phi, omega, i, u, s, p, ds):
    return p[0] * i, p[0] * omega, 0.0


class TorqueConstantError(Effect):
    kind = "effect.torque_constant_error"
    effect_id = "torque_constant_error"
    Params = TorqueConstantErrorParams
    kernel = staticmethod(torque_constant_error_kernel)
    description = "torque / back-EMF constant differs from the model"


# ------------------------------------------------------------------------------------ inductance saturation
@dataclasses.dataclass(frozen=True)
class InductanceSaturationParams(Params):
    inductance_drop_H: float = 0.0          # dL: inductance lost at high current (beyond the nominal map)
    saturation_current_A: float = 1.5       # i_sat: current at which half of dL is lost

    def validate(self):
        positive("InductanceSaturationParams", self, "saturation_current_A")


@kernel
def inductance_saturation_kernel(t, phi, omega, i, u, s, p, ds):
    x = i / p[1]
    return 0.0, 0.0, -p[0] * x * x / (1.0 + x * x)


class InductanceSaturation(Effect):
    kind = "effect.inductance_saturation"
    effect_id = "inductance_saturation"
    Params = InductanceSaturationParams
    kernel = staticmethod(inductance_saturation_kernel)
    description = "inductance falling with current"


# ------------------------------------------------------------------------------------ shaft flux loss
@dataclasses.dataclass(frozen=True)
class ShaftFluxLossParams(Params):
    loss_at_open_Nm_per_A: float = 0.0      # k_loss: torque constant lost at 90 deg
    exponent: float = 2.0                   # n: how late in the stroke the loss sets in

    def validate(self):
        check("ShaftFluxLossParams", "exponent", self.exponent, self.exponent >= 0.5, "an exponent >= 0.5")


@kernel
def shaft_flux_loss_kernel(t, phi, omega, i, u, s, p, ds):
    x = phi / (0.5 * math.pi)
    if x < 0.0:
        x = 0.0
    dk = -p[0] * x ** p[1]
    return dk * i, dk * omega, 0.0


class ShaftFluxLoss(Effect):
    kind = "effect.shaft_flux_loss"
    effect_id = "shaft_flux_loss"
    Params = ShaftFluxLossParams
    kernel = staticmethod(shaft_flux_loss_kernel)
    description = "torque constant falling with angle (non-magnetic shaft in the armature)"
