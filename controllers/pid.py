"""Discrete PID with limp-home and friction compensation, in the spirit of Deur et al. (2004).

Voltage law (radians inside, volts out, duty = u / V_nominal clamped to [-1, 1]):

    e      = r - y                                        (y: sensed angle, r: reference)
    v      = filtered differentiator of y                 (VelocityEstimator, derivative on measurement)
    u_pid  = F_r(z) [Kp(r) e + I - Kd(r) v]              F_r: 2nd-order roll-off from the design
    u_lh   = (R/k) T_spring(r)                            limp-home compensation: spring rate + preload,
                                                          T_SP0 sat((r - phi_LH)/eps) from the core kernel
    u_fc   = (R/k) T_fc sat(e / e_fc)                     friction compensation (Coulomb level, static
                                                          while the plate rests)
    u      = u_lh + u_fc + u_pid

    I_{k+1} = I_k + T [Ki(r) e + (u_sat - u) / T_t]      back-calculation anti-windup (T_t = sqrt(Ti Td))
              only while |e| < integral_zone or the plate  (conditional integration: the large-step
              rests (|v| < rest_speed)                    transient is left to P, D and the compensators,
                                                          a plate stuck far from the target still winds up)

Gains: designed by :func:`etb_gym.controllers.design.design_pid` on the numerically linearized core plant
at the scheduling angles (default 1.5 deg below limp-home and 13, 40, 80 deg above: holding current and
thus the drive-B inductance change along the travel), interpolated linearly in the reference angle.

Friction compensator: its amplitude is the nominal Coulomb level T_c while the plate slides and the static
level T_s while it rests (|v| below ``rest_speed_rad_s``): a resting plate breaks away as soon as the
error leaves the linear zone. The linear zone e_fc is sized from the presliding linearization: the
compensator's slope T_fc R / (k e_fc) stays below half the largest gain that the plate stuck in its
bristles (stiffness sigma0) tolerates, so the compensated loop does not limit-cycle around the target.
"""
from __future__ import annotations

import math

import numpy as np

from .base import BaseController, VelocityEstimator, check_gain, register_controller
from .design import presliding_gain_limit, rolloff_tf, scheduled_pid_designs
from .model import model_key, resolve_model


class Biquad:
    """Direct-form-II-transposed second-order filter y = (b0 + b1 z^-1 + b2 z^-2)/(1 + a1 z^-1 + a2 z^-2) x."""

    def __init__(self, b, a):
        self.b = [float(x) / a[0] for x in b]
        self.a = [float(x) / a[0] for x in a]
        self.reset()

    def reset(self, y0: float = 0.0):
        b0, b1, b2 = self.b
        _, a1, a2 = self.a
        g = (b0 + b1 + b2) / (1 + a1 + a2)
        x0 = y0 / g if g else 0.0
        # steady state of the transposed form for a constant input x0
        self.s2 = b2 * x0 - a2 * y0
        self.s1 = b1 * x0 - a1 * y0 + self.s2

    def __call__(self, x: float) -> float:
        b0, b1, b2 = self.b
        _, a1, a2 = self.a
        y = b0 * x + self.s1
        self.s1 = b1 * x - a1 * y + self.s2
        self.s2 = b2 * x - a2 * y
        return y


def rolloff_biquad(cutoff_rad_s: float, dt: float, damping: float = 0.7) -> Biquad | None:
    if not math.isfinite(cutoff_rad_s):
        return None
    tf = rolloff_tf(cutoff_rad_s, dt, damping)
    num = np.asarray(tf.num[0][0], float)
    den = np.asarray(tf.den[0][0], float)
    num = np.concatenate([np.zeros(3 - num.size), num])
    return Biquad(num, den)


class PIDController(BaseController):
    """Designed PID with limp-home and friction compensation (see the module docstring).

    Parameters
    ----------
    model : str | Plant | NominalModel
        The nominal plant the controller is designed on (default "3B", the env's default).
    params : dict
        "component.field" overrides of the nominal plant.
    crossover_rad_s, phase_margin_deg, integral_ratio, derivative_cutoff_rad_s :
        Design specification passed to ``design_pid`` at every scheduling angle.
    schedule_deg : tuple of float
        Reference angles of the gain schedule (one design each); ``gain_scheduling=False`` uses the design
        at the second entry (13 deg) everywhere.
    kp, ki, kd : float, optional
        Override the designed gains (V/rad, V/(rad s), V s/rad); then no schedule is used.
    friction_compensation, limp_home_compensation : bool
    friction_level : float
        Compensated fraction of the nominal Coulomb/static friction (1 = all of it).
    """

    name = "pid"

    def __init__(self, model=None, params: dict | None = None, *, dt: float | None = None,
                 crossover_rad_s: float = 50.0, phase_margin_deg: float = 50.0, integral_ratio: float = 4.0,
                 derivative_cutoff_rad_s: float = 600.0, schedule_deg=(1.5, 13.0, 40.0, 80.0),
                 gain_scheduling: bool = True, kp: float | None = None, ki: float | None = None,
                 kd: float | None = None, friction_compensation: bool = True, limp_home_compensation: bool = True,
                 friction_level: float = 1.0, friction_zone_rad: float | None = None,
                 rest_speed_rad_s: float = 0.5, integral_zone_rad: float = math.radians(10.0),
                 supply_V: float | None = None, name: str | None = None):
        self.model = resolve_model(model, params)
        super().__init__(self.model.control_period_s if dt is None else dt)
        own = "PIDController"
        if name is not None:
            self.name = str(name)
        self.supply_V = self.model.supply_V if supply_V is None else check_gain(own, "supply_V", supply_V, positive=True)
        self.friction_level = check_gain(own, "friction_level", friction_level, non_negative=True)
        self.rest_speed_rad_s = check_gain(own, "rest_speed_rad_s", rest_speed_rad_s, non_negative=True)
        self.integral_zone_rad = check_gain(own, "integral_zone_rad", integral_zone_rad, positive=True)
        self.friction_compensation = bool(friction_compensation)
        self.limp_home_compensation = bool(limp_home_compensation)
        check_gain(own, "crossover_rad_s", crossover_rad_s, positive=True)
        check_gain(own, "phase_margin_deg", phase_margin_deg, positive=True, upper=90.0)
        check_gain(own, "derivative_cutoff_rad_s", derivative_cutoff_rad_s, positive=True)
        angles = tuple(float(check_gain(own, "schedule_deg", a)) for a in schedule_deg)
        if not angles or list(angles) != sorted(angles):
            raise ValueError(f"{own}.schedule_deg = {schedule_deg!r} is invalid: expected increasing angles")
        key = model_key(self.model)
        designs = scheduled_pid_designs(key, float(crossover_rad_s), float(phase_margin_deg), float(integral_ratio),
                           float(derivative_cutoff_rad_s), angles)
        self.designs = designs
        if not gain_scheduling:
            mid = designs[min(1, len(designs) - 1)]
            designs, angles = (mid,), (angles[min(1, len(angles) - 1)],)
        self.schedule_rad = np.radians(angles)
        self.kp_table = np.array([d.kp_V_per_rad for d in designs])
        self.ki_table = np.array([d.ki_V_per_rad_s for d in designs])
        self.kd_table = np.array([d.kd_V_s_per_rad for d in designs])
        if kp is not None or ki is not None or kd is not None:
            self.kp_table = np.array([check_gain(own, "kp", kp if kp is not None else self.kp_table.mean(), non_negative=True)])
            self.ki_table = np.array([check_gain(own, "ki", ki if ki is not None else self.ki_table.mean(), non_negative=True)])
            self.kd_table = np.array([check_gain(own, "kd", kd if kd is not None else self.kd_table.mean(), non_negative=True)])
            self.schedule_rad = np.array([self.model.limp_home_rad])
        self.rolloff_rad_s = designs[0].rolloff_rad_s
        self.derivative_cutoff_rad_s = float(derivative_cutoff_rad_s)
        # friction compensator linear zone from the presliding stability limit (module docstring)
        m = self.model
        if friction_zone_rad is None:
            kmax = min(presliding_gain_limit(key, a) for a in angles) if m.bristle_stiffness_Nm_per_rad > 0 else math.inf
            slope_max = 0.5 * kmax
            fz = m.volts_per_Nm * m.static_Nm * max(self.friction_level, 1e-9) / slope_max if math.isfinite(slope_max) else 0.0
            # never narrower than two sensor quantization steps (12 bit over 90 deg)
            friction_zone_rad = max(fz, 2 * math.radians(90.0 / 4096))
        self.friction_zone_rad = check_gain(own, "friction_zone_rad", friction_zone_rad, positive=True)
        self.estimator = VelocityEstimator(self.dt, self.derivative_cutoff_rad_s)
        self._rolloff = rolloff_biquad(self.rolloff_rad_s, self.dt)
        self.reset()

    # ---------------------------------------------------------------------------------------------- state
    def reset(self, seed: int | None = None) -> None:
        self.integral_V = 0.0
        self.estimator.reset()
        if self._rolloff is not None:
            self._rolloff.reset(0.0)
        self._u_prev = 0.0

    def gains(self, ref_rad: float) -> tuple[float, float, float]:
        s = self.schedule_rad
        return (float(np.interp(ref_rad, s, self.kp_table)), float(np.interp(ref_rad, s, self.ki_table)),
                float(np.interp(ref_rad, s, self.kd_table)))

    def feedforward_V(self, ref_rad: float) -> float:
        return self.model.volts_per_Nm * self.model.spring_torque_Nm(ref_rad) if self.limp_home_compensation else 0.0

    def friction_V(self, e: float, v: float) -> float:
        if not self.friction_compensation:
            return 0.0
        m = self.model
        level = m.static_Nm if abs(v) < self.rest_speed_rad_s else m.coulomb_Nm
        return m.volts_per_Nm * self.friction_level * level * max(-1.0, min(1.0, e / self.friction_zone_rad))

    # ---------------------------------------------------------------------------------------------- law
    def compute(self, y: float, r: float, m) -> float:
        e = r - y
        v = self.estimator.update(y)
        kp, ki, kd = self.gains(r)
        raw = kp * e + self.integral_V - kd * v
        u_pid = self._rolloff(raw) if self._rolloff is not None else raw
        u = self.feedforward_V(r) + self.friction_V(e, v) + u_pid
        Vs = self.supply_V
        u_sat = min(Vs, max(-Vs, u))
        if ki > 0 and (abs(e) < self.integral_zone_rad or abs(v) < self.rest_speed_rad_s):
            ti = kp / ki if ki > 0 else math.inf
            td = kd / kp if kp > 0 else 0.0
            tt = math.sqrt(ti * td) if td > 0 else ti
            self.integral_V += self.dt * (ki * e + (u_sat - u) / tt)
        self._u_prev = u_sat
        return u_sat / Vs


register_controller("pid-plain", lambda **kw: PIDController(**{"name": "pid-plain", **kw}),
                    "voltage-mode discrete PID, designed gains, limp-home + friction compensation, gain scheduling "
                    "(controllers/pid.py; the reference before the ECU cascade)")
register_controller("pid-nocomp", lambda **kw: PIDController(**{"friction_compensation": False,
                                                               "limp_home_compensation": False,
                                                               "gain_scheduling": False, "name": "pid-nocomp", **kw}),
                    "pid-plain without limp-home/friction compensation and scheduling (ablation)")
