"""Supply (battery) and H-bridge: duty cycle in [-1, 1] to coil voltage.

The bridge is driven sign-magnitude (unipolar, edge-aligned): for duty d the coil sees sign(d)*V_supply
during the first |d|*T_pwm of every PWM period and 0 V (both low-side switches on, current freewheels)
for the rest. The bridge can therefore never apply more than the supply voltage.

    averaged   u = d * V_supply over the whole control period (fast)
    switching  the integrator splits each PWM period at its edges and integrates each interval with
               its own substeps, so the current ripple appears.
"""
from __future__ import annotations

import dataclasses

from .base import Params, check, positive

PWM_MODES = ("averaged", "switching")
SUPPLY_RANGE_V = (1.0, 60.0)   # accepted battery voltages: up to a 48 V board net's maximum (docs/model.md sec. 7)


@dataclasses.dataclass(frozen=True)
class SupplyParams(Params):
    voltage_V: float = 12.0             # nominal battery voltage seen by the bridge
    pwm_frequency_hz: float = 5000.0    # production ETB bridges run 1-20 kHz
    pwm_mode: str = "averaged"

    def validate(self):
        positive("SupplyParams", self, "voltage_V", "pwm_frequency_hz")
        lo, hi = SUPPLY_RANGE_V
        check("SupplyParams", "voltage_V", self.voltage_V, lo <= self.voltage_V <= hi, f"a voltage in [{lo}, {hi}] V")
        check("SupplyParams", "pwm_mode", self.pwm_mode, self.pwm_mode in PWM_MODES, f"one of {PWM_MODES}")

    @property
    def switching(self) -> bool:
        return self.pwm_mode == "switching"
