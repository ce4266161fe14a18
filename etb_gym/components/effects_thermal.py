"""Coil heating of any thermal dynamics: a Foster network learned from the data (docs/model.md, sec. "Thermal network").

The winding's temperature rise is a sum of first-order branches driven by the copper loss, each branch k with a
fixed time constant tau_k (a grid, log-spaced over the recordings) and a learned thermal resistance R_k:

    P      = R_0 (1 + alpha T) i^2                 copper loss [W]
    dT_k/dt = (R_k P + Q_k u^2 - T_k) / tau_k       branch k's temperature rise [K] (Q_k: losses that go with
                                                    the coil voltage u, not the current: PWM ripple; 0 by default)
    T      = sum_k T_k                             the winding's rise above the start of the recording [K]
    drop   = R_0 alpha T i                          the resistance's rise in the coil loop [V]

One thermal node (``coil_heating``: C_th, R_th) is a single branch (tau = C_th R_th, R = R_th); a winding and a
housing node, or a distributed housing, are sums of branches (the step response of any passive RC ladder is a
sum of exponentials with R_k >= 0). As a learned table beside ``coil_heating``'s formula (shapes.family_term) the
network is a correction, and a branch may then be negative (a formula whose time constant was too long: less of
the slow branch, more of a fast one).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..jit import kernel
from ..variants import COPPER_ALPHA_PER_K
from .base import check
from .effects_maps import _MapEffect, _MapParams


@dataclasses.dataclass(frozen=True)
class ThermalNetworkParams(_MapParams):
    time_constant_s: tuple = (1.0, 10.0)             # tau_k of the branches (increasing, > 0)
    thermal_resistance_K_per_W: tuple = (0.0, 0.0)   # R_k: branch k's settled rise per watt of copper loss
    voltage_rise_K_per_V2: tuple = ()                # Q_k: branch k's settled rise per V^2 of the coil voltage
                                                     # (losses that go with the voltage, not the current: PWM
                                                     # ripple, iron); () = zeros
    cold_resistance_ohm: float = 1.25                # R_0, the drive's resistance at the start temperature
    temperature_coefficient_per_K: float = COPPER_ALPHA_PER_K   # alpha of copper
    grid, values = "time_constant_s", ("thermal_resistance_K_per_W", "voltage_rise_K_per_V2")
    scalars, lower = ("cold_resistance_ohm", "temperature_coefficient_per_K"), 0.0

    def validate(self):
        if len(self.voltage_rise_K_per_V2) == 0:
            object.__setattr__(self, "voltage_rise_K_per_V2", (0.0,) * len(self.thermal_resistance_K_per_W))
        super().validate()
        check(type(self).__name__, "time_constant_s", list(self.time_constant_s), self.time_constant_s[0] >= 1e-3,
              "time constants >= 1 ms (thermal: the stepper's explicit rule needs them far above its substep)")


@kernel
def thermal_network_kernel(t, phi, omega, i, u, s, p, ds):
    # p = [n, tau (n), R (n), Q (n), R_0, alpha]; s = [branch rises (n)]
    n = int(p[0])
    T = 0.0
    for k in range(n):
        T += s[k]
    r0 = p[1 + 3 * n]
    alpha = p[2 + 3 * n]
    loss = r0 * (1.0 + alpha * T) * i * i
    u2 = u * u
    for k in range(n):
        ds[k] = (p[1 + n + k] * loss + p[1 + 2 * n + k] * u2 - s[k]) / p[1 + k]
    return 0.0, r0 * alpha * T * i, 0.0


class ThermalNetwork(_MapEffect):
    effect_id = "thermal_network"
    persistent_states = True
    Params = ThermalNetworkParams
    kernel = staticmethod(thermal_network_kernel)
    description = "coil resistance rises with winding temperature, a thermal network learned from the data"

    def __init__(self, params=None, /, **overrides):
        super().__init__(params, **overrides)
        n = len(self.params.time_constant_s)       # one state per branch
        self.state_names = tuple(f"branch{k}_temperature_rise_K" for k in range(n))
        self.state_units = ("K",) * n

    def step_response(self, t_s, loss_W: float = 1.0):
        """The winding's temperature rise [K] at times ``t_s`` after a constant loss ``loss_W`` starts (alpha's
        feedback on the loss left out): sum_k R_k P (1 - exp(-t / tau_k))."""
        q = self.params
        t = np.asarray(t_s, float)[..., None]
        return loss_W * np.sum(np.asarray(q.thermal_resistance_K_per_W) * (1.0 - np.exp(-t / np.asarray(
            q.time_constant_s))), axis=-1)

