"""ECU-grade reference controllers: battery compensation, an inner current loop, bounded self-tuning, a
reference trajectory generator, and three outer position laws (PID, sliding mode, proximate time-optimal).

They read what an engine ECU measures (``reads = ("angle", "current", "supply")``): the sensed angle, the
coil current and the battery voltage. The chain, every control period (radians, volts, amperes, SI)::

    V_m    battery reading, low-passed (tau 3 ms)                         battery compensation:
    duty = u / V_m                                                           duty = commanded voltage / V_m
    u    = R_hat i_ref + k v_cmd + K_v (v_cmd - v_hat) + K_c (i_ref - i_m)   coil as a velocity source with
                                                                             current feedback (clamped at +-V_m)
    i_ref = T_load_hat / k                                                 load current
    T_load_hat = theta_s T_spring(phi_ff) + theta_f T_fr sat(e / e_fc)    limp-home + friction compensation
                 + sigma2 v_ref                                             (levels self-tuned, bounded)

The current feedback is the damping of the electro-mechanical mode: K_c acts as a virtual series resistance,
so the rotor no longer rings with the coil through the back-EMF as lightly (``etb-gym design``: at 13 deg
220 rad/s with damping 0.20 under voltage drive, 0.36 with K_c = 1.5 V/A; at 80 deg 0.28 -> 0.57). The
outer laws command a plate speed, the coil being a velocity source while the plate slides
(omega ~ (u - R i)/k):

* ``pid`` (:class:`CascadePID`): v_cmd = v_r + K_p e + I / k, I' = K_i e in a zone;
* ``smc`` (:class:`CascadeSMC`): v_cmd = v_r + K sat((lambda e + k_0 sigma)/Phi) with the conditional
  integrator sigma' = -k_0 sigma + Phi sat(...) of Seshagiri & Khalil (2005): zero steady-state error
  without wind-up;
* ``ptos`` (:class:`.ptos.PTOSController`, in :mod:`.ptos`): beyond 0.3 deg from the target, model-predictive time-optimal
  switching (:mod:`.predictive`: each period the duty whose predicted stop, on the plant's own compiled
  model from an observer's state, lands on the target); near it, the proximate time-optimal servo of Workman
  (1987) (Franklin, Powell & Workman, Digital Control of Dynamic Systems, 3rd ed., sec. 14.4), its switching
  curve written for a velocity source with a dead time: v_cmd = sgn(e) min(K_p |e|, sqrt((a t_d)^2 + 2 a |e|)
  - a t_d), a the braking deceleration (friction and the spring when it pulls back) times alpha.

``pid`` and ``smc`` follow a reference trajectory generator (:class:`TrajectoryGenerator`: time-optimal
rate/acceleration-limited profile, the speed limit from the measured battery: the back-EMF caps the
speed at (V - R i_load)/k), so a large step does not overshoot; ``ptos`` needs none (its switching curve
is the braking trajectory).

Self-tuning (:class:`SelfTuning`, in the spirit of Pavkovic et al. 2006) with projection onto fixed
boxes, so no estimate can wind up:

* coil resistance R_hat from voltage and current while the plate rests with a steady current
  (u = R i): first-order update, R_hat in [0.55, 1.8] R_20 (-110 .. +225 C of copper);
* friction level theta_f and spring/limp-home torque level theta_s from the torque balance while the plate
  slides, k i - J a - sigma2 v = theta_s T_spring(phi) + theta_f T_c sgn(v): normalized LMS, theta_f in
  [0.3, 2.0], theta_s in [0.6, 1.5];
* ``ptos`` only: the friction level also from the angle innovation of its predictor's observer while the plate
  moves slowly (:meth:`SelfTuning.update_from_innovation`; a 0.5 deg step never reaches the LMS's speed),
  the gain weighted down by the resting innovation's noise, same box.

Cost per act() (CPython, thread CPU time over four steps, load ~11 on the shared 2-core machine): ptos median
36 us, worst 455 us (the periods around the switch), pid 25 us, smc 25 us;
``tests/test_cascade.py::test_cascade_cost_per_step`` checks the 1 ms control period.
"""
from __future__ import annotations

import math

from .base import BaseController, VelocityEstimator, check_gain, register_controller
from .model import resolve_model


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else (hi if x > hi else x)


def _sat(x: float) -> float:
    return -1.0 if x < -1.0 else (1.0 if x > 1.0 else x)


class SelfTuning:
    """Bounded online estimates of the coil resistance, the friction level and the spring torque level.

    ``update`` is called once per control period with the measured current, the voltage applied in the
    previous period, the estimated velocity and acceleration, and the sensed angle."""

    R_BOUNDS = (0.55, 1.8)              # x R_20
    FRICTION_BOUNDS = (0.3, 2.0)        # x nominal friction levels
    SPRING_BOUNDS = (0.6, 1.5)          # x nominal spring preload and rate

    def __init__(self, model, dt: float, resistance_tau_s: float = 0.03, lms_gain: float = 0.02,
                 rest_speed_rad_s: float = 0.3, slide_speed_rad_s: float = 4.0, min_current_A: float = 0.8,
                 enabled: bool = True):
        self.m = model
        self.dt = dt
        self.g_R = dt / check_gain("SelfTuning", "resistance_tau_s", resistance_tau_s, positive=True)
        self.mu = check_gain("SelfTuning", "lms_gain", lms_gain, non_negative=True)
        self.rest_speed = rest_speed_rad_s
        self.slide_speed = slide_speed_rad_s
        self.min_current = min_current_A
        self.enabled = bool(enabled)
        self.reset()

    def reset(self) -> None:
        self.resistance_ohm = self.m.resistance_ohm
        self.friction_level = 1.0
        self.spring_level = 1.0
        self._i_prev = None

    def update_from_innovation(self, innovation_rad: float, v: float, sensitivity_rad: float,
                               gain: float, min_speed_rad_s: float, taper_speed_rad_s: float = math.inf,
                               spring_phi: float | None = None, spring_share: float = 1.0) -> None:
        """Friction level from a model-based observer's angle innovation while the plate moves faster than
        ``min_speed_rad_s`` (the LMS of :meth:`update` needs > ``slide_speed_rad_s``; above ``taper_speed_rad_s``
        the gain falls as 1/|v|: there the innovation holds more than friction): a plate that runs
        ahead of the prediction in its direction of motion meets less friction than modelled,

            theta_f <- clip(theta_f - gain sgn(v) innovation / sensitivity, FRICTION_BOUNDS)

        ``sensitivity_rad``: the angle one period of sliding loses per unit of friction level.

        ``spring_phi`` (the plate angle, rad) also learns the spring level: the residual load is split between
        the two regressors of the load opposing the motion, T_c (friction) and sgn(v) T_spring(phi) (springs),
        as a normalized LMS does (minimum-norm step). One move cannot tell them apart, but a spring error
        changes sign with the direction of motion and a friction error does not, so moves both ways separate
        them (a weaker spring looks like less friction opening and more friction closing). ``spring_share``
        scales the spring's part of the step (the friction's part is the normalized one)."""
        if not self.enabled or abs(v) < min_speed_rad_s or sensitivity_rad <= 0:
            return
        if abs(v) > taper_speed_rad_s:      # fast: the innovation holds more than friction (the LMS's range)
            gain *= taper_speed_rad_s / abs(v)
        sv = 1.0 if v > 0 else -1.0
        step = gain * sv * innovation_rad / sensitivity_rad
        if spring_phi is None:
            self.friction_level = _clip(self.friction_level - step, *self.FRICTION_BOUNDS)
            return
        # both regressors of the load opposing the motion, theta_f T_c + theta_s sgn(v) T_spring(phi): the
        # normalized update splits the residual between them (over moves both ways it separates them)
        tc = self.m.coulomb_Nm
        xs = sv * self.m.spring_torque_Nm(spring_phi)
        norm = tc * tc / (tc * tc + xs * xs)
        self.friction_level = _clip(self.friction_level - step * norm, *self.FRICTION_BOUNDS)
        self.spring_level = _clip(self.spring_level - spring_share * step * norm * xs / tc, *self.SPRING_BOUNDS)

    def update(self, i_m: float, u_applied: float, v: float, a: float, phi: float) -> None:
        if not self.enabled:
            return
        m = self.m
        steady = self._i_prev is not None and abs(i_m - self._i_prev) < 0.05
        self._i_prev = i_m
        if abs(v) < self.rest_speed and abs(i_m) > self.min_current and steady:
            r = u_applied / i_m
            lo, hi = self.R_BOUNDS
            self.resistance_ohm = _clip(self.resistance_ohm + self.g_R * (r - self.resistance_ohm),
                                        lo * m.resistance_ohm, hi * m.resistance_ohm)
        if abs(v) > self.slide_speed and self.mu > 0:
            k = m.torque_constant_Nm_per_A
            y = k * i_m - m.inertia_kg_m2 * a - m.viscous_Nm_s_per_rad * v
            x1 = m.spring_torque_Nm(phi)
            x2 = m.coulomb_Nm * (1.0 if v > 0 else -1.0)
            err = y - self.spring_level * x1 - self.friction_level * x2
            g = self.mu * err / (1e-4 + x1 * x1 + x2 * x2)
            self.spring_level = _clip(self.spring_level + g * x1, *self.SPRING_BOUNDS)
            self.friction_level = _clip(self.friction_level + g * x2, *self.FRICTION_BOUNDS)


class TrajectoryGenerator:
    """Time-optimal second-order reference profile with speed limit ``v_max`` and acceleration ``a_max``:

        v_des = sgn(e) min(v_max, sqrt(a^2 T^2 / 4 + 2 a |e|) - a T / 2),   e = r - p
        v <- v + sat(v_des - v, a T),   p <- p + v T                    (lands on r without overshoot)
    """

    def __init__(self, dt: float, a_max: float):
        self.dt = dt
        self.a_max = a_max
        self.reset()

    def reset(self) -> None:
        self.p = None
        self.v = 0.0
        self.a = 0.0

    def update(self, r: float, v_max: float) -> tuple[float, float, float]:
        if self.p is None:
            self.p, self.v, self.a = r, 0.0, 0.0
            return r, 0.0, 0.0
        T, A = self.dt, self.a_max
        e = r - self.p
        vd = math.sqrt(A * A * T * T / 4 + 2 * A * abs(e)) - A * T / 2
        vd = math.copysign(min(v_max, vd), e)
        dv = _clip(vd - self.v, -A * T, A * T)
        v_new = self.v + dv
        p_new = self.p + v_new * T
        if (r - p_new) * e <= 0 or abs(r - p_new) < 1e-9:          # would pass the target: land on it
            p_new, v_new = r, 0.0
        self.a = (v_new - self.v) / T
        self.p, self.v = p_new, v_new
        return self.p, self.v, self.a


class CascadeController(BaseController):
    """The shared ECU chain of the module docstring; subclasses supply :meth:`outer` (a plate speed [rad/s])."""

    reads = ("angle", "current", "supply")
    use_generator = True
    Kv = 0.0

    def __init__(self, model=None, params: dict | None = None, *, dt: float | None = None,
                 current_gain_V_per_A: float = 1.5,
                 velocity_cutoff_rad_s: float = 400.0, friction_zone_deg: float = 0.17,
                 rest_speed_rad_s: float = 0.5, speed_fraction: float = 0.85, accel_limit_rad_s2: float = 15000.0,
                 friction_filter_s: float = 0.00035, friction_compensation: float = 0.85, self_tuning: bool = True,
                 battery_compensation: bool = True,
                 name: str | None = None):
        self.model = m = resolve_model(model, params)
        super().__init__(m.control_period_s if dt is None else dt)
        own = type(self).__name__
        if name is not None:
            self.name = str(name)
        self.Kc = check_gain(own, "current_gain_V_per_A", current_gain_V_per_A, non_negative=True)
        self.friction_zone = math.radians(check_gain(own, "friction_zone_deg", friction_zone_deg, positive=True))
        self.rest_speed = check_gain(own, "rest_speed_rad_s", rest_speed_rad_s, non_negative=True)
        self.g_f = min(1.0, self.dt / max(check_gain(own, "friction_filter_s", friction_filter_s, non_negative=True), 1e-12))
        self.speed_fraction = check_gain(own, "speed_fraction", speed_fraction, positive=True, upper=1.0001)
        self.battery_compensation = bool(battery_compensation)
        self.friction_fraction = check_gain(own, "friction_compensation", friction_compensation, non_negative=True)
        self.estimator = VelocityEstimator(self.dt, check_gain(own, "velocity_cutoff_rad_s", velocity_cutoff_rad_s,
                                                               positive=True))
        self.tuning = SelfTuning(m, self.dt, enabled=self_tuning)
        self.generator = TrajectoryGenerator(self.dt, check_gain(own, "accel_limit_rad_s2", accel_limit_rad_s2,
                                                                 positive=True))
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        self.estimator.reset()
        self.tuning.reset()
        self.generator.reset()
        self.V = None
        self.e_f = None
        self.moving = False
        self.v_prev = 0.0
        self.reset_outer()

    def reset_outer(self) -> None:
        pass

    def control_angle(self, y: float, meas, V: float) -> float:
        """The angle the laws act on (rad): the sensed one (subclasses may filter it)."""
        return y

    def outer(self, e: float, y: float, v: float, r: float, v_r: float, a_r: float) -> float:  # pragma: no cover
        raise NotImplementedError

    # ------------------------------------------------------------------------------------------ pieces
    def supply(self, meas) -> float:
        """Battery voltage the duty is computed for: the low-passed reading (or the nominal one)."""
        if not self.battery_compensation or meas.supply_V is None:
            return self.model.supply_V
        Vm = meas.supply_V
        self.V = Vm if self.V is None else self.V + min(1.0, self.dt / 0.003) * (Vm - self.V)
        return max(self.V, 1.0)

    def load_torque(self, phi_ff: float, e: float, v: float, v_r: float) -> float:
        m, st = self.model, self.tuning
        level = m.static_Nm if abs(v) < self.rest_speed else m.coulomb_Nm
        # the friction compensator acts on the error low-passed over ``friction_filter_s`` (sensor noise and
        # quantization would toggle it at every sample through the current loop's gain)
        self.e_f = e if self.e_f is None else self.e_f + self.g_f * (e - self.e_f)
        return (st.spring_level * m.spring_torque_Nm(phi_ff)
                + self.friction_fraction * st.friction_level * level * _sat(self.e_f / self.friction_zone)
                + m.viscous_Nm_s_per_rad * v_r)

    def speed_limit(self, V: float, phi: float) -> float:
        """Highest plate speed the battery sustains against the back-EMF at the present load (x fraction)."""
        m = self.model
        i_load = (abs(m.spring_torque_Nm(phi)) + m.coulomb_Nm) / m.torque_constant_Nm_per_A
        return self.speed_fraction * max(V - self.tuning.resistance_ohm * i_load, 0.2 * V) / m.torque_constant_Nm_per_A

    # ------------------------------------------------------------------------------------------ law
    def compute(self, y: float, r_target: float, meas) -> float:
        m = self.model
        k = m.torque_constant_Nm_per_A
        V = self.supply(meas)
        y = self.control_angle(y, meas, V)
        v = self.estimator.update(y)
        a_hat = (v - self.v_prev) / self.dt
        self.v_prev = v
        i_m = meas.current_A if meas.current_A is not None else 0.0
        self.tuning.update(i_m, meas.last_duty * V, v, a_hat, y)
        if self.use_generator:
            r, v_r, a_r = self.generator.update(r_target, self.speed_limit(V, r_target))
        else:
            r, v_r, a_r = r_target, 0.0, 0.0
        e = r - y
        phi_ff = r if abs(r_target - y) < math.radians(1.0) else y
        self.moving = abs(r_target - r) > math.radians(1.0)     # the trajectory is still far from the target
        self.V_now = V
        R = self.tuning.resistance_ohm
        i_max = V / R
        # the coil as a velocity source (u = R i + k omega): the outer law commands a plate speed
        v_cmd = self.outer(e, y, v, r, v_r, a_r)
        i_ref = _clip(self.load_torque(phi_ff, r_target - y, v, v_cmd) / k, -i_max, i_max)
        u = R * i_ref + k * v_cmd + self.Kv * (v_cmd - v) + self.Kc * (i_ref - i_m)
        u_sat = _clip(u, -V, V)
        self.saturated = u != u_sat
        return u_sat / V


class CascadePID(CascadeController):
    """PI position loop commanding the plate speed, along the trajectory generator's reference:

        v_cmd = v_r + K_p e + I / k,    I' = K_i e  within ``integral_zone_deg`` (3x while resting, anywhere once the plate has been stuck for 10 ms; clamped, frozen while the
                                                    voltage saturates: no wind-up)

    the derivative action is the inner speed feedback K_v (v_cmd - v_hat) of the velocity-source chain."""

    name = "pid"

    def __init__(self, model=None, params: dict | None = None, *, position_gain_rad_s: float = 118.0,
                 velocity_gain_V_s_per_rad: float = 0.0032, integral_V_per_rad_s: float = 1860.0,
                 integral_zone_deg: float = 1.0, integral_limit_V: float = 3.0, speed_fraction: float = 0.69,
                 accel_limit_rad_s2: float = 5750.0, **kw):
        own = type(self).__name__
        kw.update(speed_fraction=speed_fraction, accel_limit_rad_s2=accel_limit_rad_s2)
        self.Kp = check_gain(own, "position_gain_rad_s", position_gain_rad_s, positive=True)
        self.Kv = check_gain(own, "velocity_gain_V_s_per_rad", velocity_gain_V_s_per_rad, non_negative=True)
        self.Ki = check_gain(own, "integral_V_per_rad_s", integral_V_per_rad_s, non_negative=True)
        self.i_zone = math.radians(check_gain(own, "integral_zone_deg", integral_zone_deg, positive=True))
        self.i_lim = check_gain(own, "integral_limit_V", integral_limit_V, non_negative=True)
        super().__init__(model, params, **kw)

    def reset_outer(self) -> None:
        self.I = 0.0
        self.rest_count = 0

    def outer(self, e, y, v, r, v_r, a_r):
        self.rest_count = self.rest_count + 1 if abs(v) < self.rest_speed else 0
        stuck = self.rest_count >= 10           # a plate stuck anywhere for 10 ms (springs, friction): integrate
        if (abs(e) < self.i_zone * (3.0 if self.rest_count else 1.0) or stuck) and not self.moving \
                and not getattr(self, "saturated", False):
            self.I = _clip(self.I + self.Ki * self.dt * e, -self.i_lim, self.i_lim)
        return v_r + self.Kp * e + self.I / self.model.torque_constant_Nm_per_A


class CascadeSMC(CascadeController):
    """Sliding mode with boundary layer and conditional integrator (Seshagiri & Khalil 2005) commanding the
    plate speed (the coil as a velocity source makes the error dynamics first order, de/dt = v_r - v):

        s = e + k_0 sigma / lambda ... in speed units:  s = lambda e,   v_cmd = v_r + K sat((s + k_0 sigma)/Phi)
        sigma' = -k_0 sigma + Phi sat((s + k_0 sigma)/Phi)          |sigma| <= Phi / k_0: cannot wind up

    ``lambda_rad_s``: inside the layer the loop gain is lambda K / Phi; K [rad/s]: the switching speed (the
    reaching phase); ``k0_rad_s``: conditional-integrator rate (zero steady-state error)."""

    name = "smc"

    def __init__(self, model=None, params: dict | None = None, *, lambda_rad_s: float = 109.0,
                 K_rad_s: float = 25.7, layer_rad_s: float | None = 18.3, k0_rad_s: float = 139.0,
                 velocity_gain_V_s_per_rad: float = 0.02, speed_fraction: float = 0.73,
                 accel_limit_rad_s2: float = 4660.0, **kw):
        own = type(self).__name__
        kw.update(speed_fraction=speed_fraction, accel_limit_rad_s2=accel_limit_rad_s2)
        self.lam = check_gain(own, "lambda_rad_s", lambda_rad_s, positive=True)
        self.K = check_gain(own, "K_rad_s", K_rad_s, positive=True)
        self.Phi = check_gain(own, "layer_rad_s", self.K if layer_rad_s is None else layer_rad_s, positive=True)
        self.k0 = check_gain(own, "k0_rad_s", k0_rad_s, positive=True)
        self.Kv = check_gain(own, "velocity_gain_V_s_per_rad", velocity_gain_V_s_per_rad, non_negative=True)
        super().__init__(model, params, **kw)

    def reset_outer(self) -> None:
        self.sigma = 0.0

    def outer(self, e, y, v, r, v_r, a_r):
        s = self.lam * e
        sat = _sat((s + self.k0 * self.sigma) / self.Phi)
        if not self.moving and not getattr(self, "saturated", False):     # frozen during large moves
            self.sigma += self.dt * (-self.k0 * self.sigma + self.Phi * sat)
        return v_r + self.K * sat


register_controller("pid", CascadePID, "cascade PID: battery compensation, current loop, self-tuning, trajectory "
                    "generator (controllers/cascade.py)")
register_controller("smc", CascadeSMC, "cascade sliding mode with conditional integrator: battery compensation, "
                    "current loop, self-tuning, trajectory generator (controllers/cascade.py)")
