"""Sliding-mode controller for the ETB: boundary layer + conditional integrator, model-based equivalent control.

Surface (e = r - y, rates from the filtered differentiator; radians)::

    s = de/dt + lambda * e                    on s = 0 the error decays as exp(-lambda t)

Nominal model with the coil quasi-static (L di/dt neglected, i = (u - k omega)/R)::

    J phi'' = (k/R) u - (k^2/R + sigma2) phi' - T_spring(phi) - T_fric

Equivalent control (ds/dt = 0 for the nominal model)::

    u_eq = (R/k) [T_spring(r) + T_f_hat sat(s / Phi_f)] + (k + sigma2 R/k) r' + (R J / k) (r'' + lambda de/dt)

* the spring (rate + limp-home preload, the core kernel) is evaluated at the reference, not at the noisy
  measurement, so the preload discontinuity at limp-home is not toggled by sensor noise;
* friction estimate T_f_hat: the static level T_s while the plate rests, the Coulomb level T_c while it
  slides, in the direction of the error: sat(lambda e / Phi_f) (default, ``friction_on_error=True``); the
  classical direction sat(s / Phi_f) is available with ``friction_on_error=False``, but s carries the
  differentiated sensor noise and toggles the compensation at every sample (measured: stair-case
  stick-slip on large steps and 3x the duty total variation);
* the back-EMF is compensated along the *reference* velocity r'. Compensating the measured velocity
  would cancel the coil's electrical damping k^2/R, the only damping of the plant's electro-mechanical
  mode (L with J, ~220 rad/s, see controllers/design.py), and the linearized loop loses its margins.

Switching part with the conditional integrator of Seshagiri & Khalil (2005)::

    u_sw   = K sat((s + k0 sigma) / Phi)
    sigma' = -k0 sigma + Phi sat((s + k0 sigma) / Phi)          |sigma| <= Phi/k0: cannot wind up

Inside the layer sigma integrates s (zero steady-state error against the friction/spring mismatch);
outside, u_sw = +-K (the reaching phase). Chattering is handled by the layer: inside it the law is linear.

Gains (derived, see docs/controllers.md):

* K from the reaching condition s ds/dt <= -eta |s| with the uncertainty of the robustness grid:
  K = (R/k) (dT_max + eta_Nm) / g_min, dT_max = 0.5 T_c + 0.2 (T_SP0 + R_F (80 deg - phi_LH)),
  g_min = 9/12 (duty-to-voltage gain at a 9 V battery).
* In the layer u = (K/Phi)(de/dt + lambda e) + integral: a PD+I loop around the linearized plant. lambda
  is the stated surface bandwidth; the layer gain G = K/Phi is the largest one whose discrete loop keeps a
  gain margin >= ``gain_margin_db`` and phase margin >= ``phase_margin_deg`` (controllers/design.py);
  Phi = K/G; k0 = lambda / 2 (integral gain in the layer G k0 lambda).
"""
from __future__ import annotations

import math

from .base import BaseController, VelocityEstimator, check_gain, register_controller
from .design import smc_layer_gain
from .model import model_key, resolve_model


class SlidingModeController(BaseController):
    """Boundary-layer sliding mode with conditional integrator (see the module docstring).

    Parameters: ``model``/``params`` (nominal plant, default "3B"), ``lambda_rad_s`` (surface slope),
    ``K_V`` (switching amplitude; default derived), ``layer_gain_V_s_per_rad`` (K/Phi; default designed),
    ``k0_rad_s`` (conditional integrator rate; default lambda/2), ``friction_level`` (fraction of the
    nominal friction in the equivalent control), ``gain_margin_db``/``phase_margin_deg`` for the layer design.
    """

    name = "smc"

    def __init__(self, model=None, params: dict | None = None, *, dt: float | None = None,
                 lambda_rad_s: float = 50.0, K_V: float | None = None, layer_gain_V_s_per_rad: float | None = None,
                 k0_rad_s: float | None = None, friction_level: float = 1.0, eta_Nm: float = 0.05,
                 friction_layer_rad_s: float | None = None, rest_speed_rad_s: float = 0.5,
                 derivative_cutoff_rad_s: float = 600.0, gain_margin_db: float = 6.0, phase_margin_deg: float = 45.0,
                 friction_on_error: bool = True, supply_V: float | None = None, name: str | None = None):
        self.model = m = resolve_model(model, params)
        self.friction_on_error = bool(friction_on_error)
        super().__init__(m.control_period_s if dt is None else dt)
        own = "SlidingModeController"
        if name is not None:
            self.name = str(name)
        self.lambda_rad_s = check_gain(own, "lambda_rad_s", lambda_rad_s, positive=True)
        self.friction_level = check_gain(own, "friction_level", friction_level, non_negative=True)
        self.eta_Nm = check_gain(own, "eta_Nm", eta_Nm, non_negative=True)
        self.rest_speed_rad_s = check_gain(own, "rest_speed_rad_s", rest_speed_rad_s, non_negative=True)
        wf = check_gain(own, "derivative_cutoff_rad_s", derivative_cutoff_rad_s, positive=True)
        gm = check_gain(own, "gain_margin_db", gain_margin_db, positive=True)
        pm = check_gain(own, "phase_margin_deg", phase_margin_deg, positive=True, upper=90.0)
        self.supply_V = m.supply_V if supply_V is None else check_gain(own, "supply_V", supply_V, positive=True)
        if K_V is None:
            travel = math.radians(80.0) - m.limp_home_rad
            dT = 0.5 * m.coulomb_Nm + 0.2 * (m.preload_Nm + m.spring_rate_Nm_per_rad * travel)
            K_V = m.volts_per_Nm * (dT + self.eta_Nm) / (9.0 / 12.0)
        self.K_V = check_gain(own, "K_V", K_V, positive=True)
        if layer_gain_V_s_per_rad is None:
            layer_gain_V_s_per_rad = smc_layer_gain(model_key(m), self.lambda_rad_s, wf, gm, pm)
        self.layer_gain = check_gain(own, "layer_gain_V_s_per_rad", layer_gain_V_s_per_rad, positive=True)
        self.phi_layer = self.K_V / self.layer_gain                 # Phi [rad/s]
        self.k0 = check_gain(own, "k0_rad_s", self.lambda_rad_s / 2 if k0_rad_s is None else k0_rad_s, positive=True)
        # friction sign smoothing: the velocity-equivalent of two sensor quantization steps on the surface
        if friction_layer_rad_s is None:
            friction_layer_rad_s = self.lambda_rad_s * 2 * math.radians(90.0 / 4096)
        self.friction_layer = check_gain(own, "friction_layer_rad_s", friction_layer_rad_s, positive=True)
        self.estimator = VelocityEstimator(self.dt, wf)
        self.ref_rate = VelocityEstimator(self.dt, wf)
        self.ref_acc = VelocityEstimator(self.dt, wf)
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        self.sigma = 0.0
        self.estimator.reset()
        self.ref_rate.reset()
        self.ref_acc.reset()

    def surface(self, e: float, de: float) -> float:
        return de + self.lambda_rad_s * e

    def compute(self, y: float, r: float, meas) -> float:
        m = self.model
        v = self.estimator.update(y)
        rd = self.ref_rate.update(r)
        rdd = self.ref_acc.update(rd)
        e = r - y
        de = rd - v
        s = self.surface(e, de)
        level = m.static_Nm if abs(v) < self.rest_speed_rad_s else m.coulomb_Nm
        arg = (e * self.lambda_rad_s if self.friction_on_error else s) / self.friction_layer
        t_f = self.friction_level * level * max(-1.0, min(1.0, arg))
        k = m.torque_constant_Nm_per_A
        rj_k = m.resistance_ohm * m.inertia_kg_m2 / k
        u_eq = (m.volts_per_Nm * (m.spring_torque_Nm(r) + t_f)
                + (k + m.viscous_Nm_s_per_rad * m.resistance_ohm / k) * rd
                + rj_k * (rdd + self.lambda_rad_s * de))
        phi = self.phi_layer
        si = s + self.k0 * self.sigma
        sat = max(-1.0, min(1.0, si / phi))
        u = u_eq + self.K_V * sat
        self.sigma += self.dt * (-self.k0 * self.sigma + phi * sat)
        return u / self.supply_V


register_controller("smc-plain", lambda **kw: SlidingModeController(**{"name": "smc-plain", **kw}),
                    "voltage-mode boundary-layer sliding mode with conditional integrator and model-based "
                    "equivalent control (controllers/smc.py; the reference before the ECU cascade)")
