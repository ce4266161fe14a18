"""Model-based braking prediction: where does the plate stop if the controller brakes now?

The time-optimal input of a large ETB step (``etb_gym.bound``) is full drive, a short full reverse that
empties the coil (L = 20 mH: the current cannot fall faster), then the holding voltage; the springs and the
friction stop the plate. Where to switch depends on all three states (angle, speed, coil current) and on
the coil's saturating inductance, the angle-dependent torque constant, the springs and the friction. Rather
than an approximate third-order switching surface, :class:`StopPredictor` integrates **the plant's own
compiled model** (``Plant.stepper().control_step``, the equations the simulator integrates, the same
substeps) a few control periods ahead from the controller's state estimate, under

    policy B (brake):  d_0 this period, then   d = -s        while s (i - i_hold) > 0   (empty the coil)
                                               d = u_hold/V  afterwards                  (hold at the target)

with s the direction of the move, V the measured battery voltage, i_hold and u_hold the current and voltage
holding the plate at the target against the springs, and reports the farthest angle in the direction of the
move before the plate stops (or turns). The controller picks the duty d_0 of this period whose predicted
stop lands on the target (a bisection: the predicted stop is monotone in d_0) -- full drive while even full
drive this period still stops short, a fractional duty in the period that contains the switch, full
reverse while braking. This is the switching surface of the third-order plant, evaluated numerically.

The model is the controller's nominal plant with the self-tuned coil resistance, friction level and spring
level (``etb_gym.variants.PlantVariant`` applied to it, rebuilt only when an estimate moved by more than
2 %), and the battery voltage measured by the ECU.

Cost: one predicted control period is one compiled ``control_step`` (~7 us); a prediction is at most
``horizon`` periods (stops when the plate stops), a bisection ``iterations`` predictions, done only in
the periods around the switch.
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from etb_gym.variants import COPPER_ALPHA_PER_K, RESISTANCE_REFERENCE_C, PlantVariant


@lru_cache(maxsize=256)
def kalman_gains(dt: float, inertia_kg_m2: float, noise_var_rad2: float, torque_var_Nm2: float) -> tuple:
    """Steady-state Kalman gains of the observer on (angle, speed, load torque), the plate a double integrator
    driven by an unknown load torque that walks randomly (variance ``torque_var_Nm2`` per period), the angle
    measured with noise of variance ``noise_var_rad2``:

        x+ = A x,  A = [[1, T, T^2/2J], [0, 1, T/J], [0, 0, 1]],  y = phi + n:   P from the discrete Riccati
        equation P = A P A' - A P H' (H P H' + R)^-1 H P A' + Q, K = P H' / (H P H' + R)

    solved by the structure-preserving doubling algorithm (Chu, Fan & Lin 2005; quadratic convergence, a few
    3x3 solves: ~0.1-0.3 ms, where scipy's ``solve_discrete_are`` took 8 ms under load, too slow for a 1 ms
    control period). Returned dimensionless as :meth:`StopPredictor.observe` takes them:
    (K_phi, K_omega T, K_tau T^2 / J)."""
    T, J = dt, inertia_kg_m2
    A = np.array([[1.0, T, T * T / (2 * J)], [0.0, 1.0, T / J], [0.0, 0.0, 1.0]])
    H = np.array([[1.0, 0.0, 0.0]])
    # the filter Riccati equation is the control one for (A', H'): X = F' X (I + G X)^-1 F + Q, F = A'
    F, G, X = A.T.copy(), H.T @ H / noise_var_rad2, np.diag([0.0, 0.0, torque_var_Nm2])
    eye = np.eye(3)
    for _ in range(60):
        W = np.linalg.solve(eye + G @ X, np.hstack([F, G]))       # (I + G X)^-1 [F, G]
        WF, WG = W[:, :3], W[:, 3:]
        X_new = X + F.T @ X @ WF
        G = G + F @ WG @ F.T
        F = F @ WF
        if np.max(np.abs(X_new - X)) <= 1e-13 * np.max(np.abs(X_new)):
            X = X_new
            break
        X = X_new
    K = (X @ H.T / (H @ X @ H.T + noise_var_rad2)).ravel()
    return float(K[0]), float(K[1] * T), float(K[2] * T * T / J)


class StopPredictor:
    """Predict the stopping angle of policy B (module docstring) on the controller's nominal plant."""

    REBUILD_TOLERANCE = 0.02

    def __init__(self, model, horizon: int = 12, iterations: int = 5):
        self.m = model
        self.plant = model.plant
        fns = self.plant.stepper()
        self._step = fns.control_step
        self._nsub = self.plant.substeps
        self._switching = self.plant.supply.switching
        self._fpwm = self.plant.supply.pwm_frequency_hz
        self.dt = self.plant.control_period_s
        self.horizon = int(horizon)
        self.iterations = int(iterations)
        self._aux = np.zeros(len(self.plant.components))
        self._x = self.plant.initial_state(model.limp_home_rad)
        self._x0 = self._x.copy()
        self._nominal = self.plant.params_dict()
        self.names = self.plant.state_names
        self._z = self.names.index("friction.z_rad") if "friction.z_rad" in self.names else -1
        fp = self.plant.friction.params if self.plant.friction is not None else None
        self._sigma0 = float(getattr(fp, "bristle_stiffness_Nm_per_rad", 0.0)) if fp is not None else 0.0
        self.levels = None
        self.P = self.plant.P
        self._xo = None
        self._ys = [0.0, 0.0, 0.0]
        self.rest_band_rad = 0.0
        self.rest_speed = 1.0
        self.innovation = 0.0
        self.load_torque = 0.0
        self.stop_angle(0.0, 1.0, self.plant.supply.voltage_V, 0.0, 0.0)     # load the compiled step once, here

    def update_levels(self, resistance_ohm: float, friction_level: float, spring_level: float) -> None:
        """Rebuild the parameter vector when a self-tuned estimate moved by more than 2 %."""
        lv = (resistance_ohm / self.m.resistance_ohm, friction_level, spring_level)
        if self.levels is not None and all(abs(a - b) <= self.REBUILD_TOLERANCE * abs(b)
                                           for a, b in zip(lv, self.levels)):
            return
        self.levels = lv
        temp = RESISTANCE_REFERENCE_C + (lv[0] - 1.0) / COPPER_ALPHA_PER_K
        var = PlantVariant(coil_temperature_C=max(temp, -200.0), friction_scale=lv[1], spring_scale=lv[2])
        self.P = self.plant.param_vector(var.overrides(self._nominal))

    def reset(self) -> None:
        self._xo = None
        self.innovation = 0.0
        self.load_torque = 0.0

    def set_state(self, phi: float, v: float, i: float) -> None:
        """Start the predictions from this plate state (angle rad, speed rad/s, current A), the LuGre bristles
        (if any) at their sliding deflection."""
        x = self._x0
        x[0], x[1], x[2] = phi, v, i
        if self._z >= 0 and self._sigma0 > 0:
            lv = self.levels[1] if self.levels else 1.0
            x[self._z] = math.copysign(lv * self.m.coulomb_Nm / self._sigma0, v) if abs(v) > 0.05 else 0.0

    def observe(self, y: float, i_m: float, d_prev: float, V: float, gain_angle: float = 0.5,
                gain_speed: float = 0.25, gain_torque: float = 0.0) -> None:
        """Observer of the plate state on the same model: the previous estimate stepped over the last period
        with the duty applied, corrected by the sensed angle (gains on the angle innovation: ``gain_angle``
        on the angle, ``gain_speed``/T on the speed) and the measured current (taken as is).

        Rest check (``rest_band_rad`` > 0): when the sensed angle has stayed within ``rest_band_rad`` over the
        last two periods and the estimate's speed exceeds ``rest_speed``, the speed is replaced by the sensed
        one (the mean over the two periods). A model whose load is wrong (weaker springs, friction learnt low)
        otherwise believes a stuck plate is running away -- each period the model accelerates it and the speed
        correction cannot keep up -- and the landing law brakes a plate that is not moving."""
        xo = self._xo
        ys = self._ys
        ys[0], ys[1], ys[2] = ys[1], ys[2], y
        if xo is None:
            xo = self._xo = self._x0.copy()
            xo[0], xo[1], xo[2] = y, 0.0, i_m
            if self._z >= 0:
                xo[self._z] = 0.0
            ys[0] = ys[1] = y
        else:
            self._step(xo, d_prev, V, self.P, 0.0, self.dt, self._nsub, self._switching, self._fpwm, self._aux)
            if self.load_torque != 0.0:
                a = self.load_torque / self.m.inertia_kg_m2
                xo[0] += 0.5 * a * self.dt * self.dt
                xo[1] += a * self.dt
            eps = y - xo[0]
            self.innovation = eps
            xo[0] += gain_angle * eps
            xo[1] += gain_speed * eps / self.dt
            if gain_torque > 0.0:
                lim = self.m.static_Nm
                self.load_torque = max(-lim, min(lim, self.load_torque
                                                 + gain_torque * eps * self.m.inertia_kg_m2 / (self.dt * self.dt)))
            xo[2] = i_m
            # rest check: a plate the sensor has shown still for two periods is not moving fast, whatever the
            # model says (a model whose load is wrong, e.g. weaker springs and friction learnt low, otherwise
            # believes the stuck plate runs away and brakes it where it sticks)
            if self.rest_band_rad > 0 and max(ys) - min(ys) < self.rest_band_rad and abs(xo[1]) > self.rest_speed:
                xo[1] = (ys[2] - ys[0]) / (2.0 * self.dt)
        self._x0[:] = xo

    def level_sensitivity(self) -> float:
        """Angle (rad) one control period of sliding moves the plate less per unit of friction level (the
        nominal Coulomb torque's deceleration over one period, T_c T^2 / (2 J))."""
        return self.m.coulomb_Nm * self.dt * self.dt / (2.0 * self.m.inertia_kg_m2)

    @property
    def angle(self) -> float:
        return float(self._x0[0])

    @property
    def speed(self) -> float:
        return float(self._x0[1])

    def stop_angle(self, d0: float, s: float, V: float, i_hold: float, u_hold: float) -> float:
        """Farthest angle (rad) in direction s before the plate stops, under policy B from the set state."""
        x = self._x
        x[:] = self._x0
        step, P, aux = self._step, self.P, self._aux
        far = x[0]
        d = d0
        hold = max(-1.0, min(1.0, u_hold / V))
        for k in range(self.horizon):
            step(x, d, V, P, 0.0, self.dt, self._nsub, self._switching, self._fpwm, aux)
            if s * (x[0] - far) > 0:
                far = x[0]
            if s * x[1] <= 0.0:
                break
            d = -s if s * (x[2] - i_hold) > 0 else hold
        return far

    def duty_for_current(self, i_goal: float, V: float) -> float:
        """The duty of this period whose current at its end (the compiled model from the set state: the
        saturating inductance, the back-EMF) is ``i_goal`` A; the end current is affine in the duty over one
        period to the model's accuracy, so two predictions (full reverse, full drive) interpolate it. Not clipped."""
        x, P, aux = self._x, self.P, self._aux
        ends = []
        for d in (-1.0, 1.0):
            x[:] = self._x0
            self._step(x, d, V, P, 0.0, self.dt, self._nsub, self._switching, self._fpwm, aux)
            ends.append(float(x[2]))
        lo, hi = ends
        if hi - lo <= 1e-12:
            return 0.0
        return -1.0 + 2.0 * (i_goal - lo) / (hi - lo)

    def stop_angle_from(self, phi: float, v: float, i: float, d0: float, s: float, V: float, i_hold: float,
                        u_hold: float) -> float:
        """:meth:`stop_angle` from the given plate state (angle rad, speed rad/s, current A; bristles as in
        :meth:`set_state`) instead of the observer's; the observer's state is left as it was."""
        saved = self._x0.copy()
        try:
            self.set_state(phi, v, i)
            return self.stop_angle(d0, s, V, i_hold, u_hold)
        finally:
            self._x0[:] = saved

    def angle_after(self, d: float, n: int, V: float) -> float:
        """Angle (rad) of the plate after ``n`` periods at duty ``d`` from the set state."""
        x = self._x
        x[:] = self._x0
        for _ in range(n):
            self._step(x, d, V, self.P, 0.0, self.dt, self._nsub, self._switching, self._fpwm, self._aux)
        return float(x[0])

    def duty_to_reach(self, target: float, n: int, V: float, tolerance: float = 2e-5) -> float:
        """The duty which, held for ``n`` periods from the set state, puts the plate on ``target`` (rad) at
        their end (full drive or full reverse when none does): the angle is monotone in the duty, so the same
        regula falsi as :meth:`duty_to_land`, within ``tolerance`` rad."""
        return _monotone_root(lambda d: self.angle_after(d, n, V) - target, tolerance, self.iterations)

    def duty_to_land(self, target: float, s: float, V: float, i_hold: float, u_hold: float,
                     tolerance: float = 2e-4) -> float:
        """The duty of this period whose predicted stop lands on ``target`` (within ``tolerance`` rad; full
        drive or full reverse when none does): regula falsi (Illinois) on the predicted stop, which is monotone
        in the duty, at most ``iterations`` predictions after the two ends."""
        return s * _monotone_root(lambda d: s * (self.stop_angle(s * d, s, V, i_hold, u_hold) - target),
                                  tolerance, self.iterations)


def _monotone_root(f, tolerance: float, iterations: int) -> float:
    """The d in [-1, 1] with f(d) = 0 for an increasing f: 1 when f(1) <= 0, -1 when f(-1) >= 0, else regula
    falsi (Illinois) from the two ends until |f| < ``tolerance`` or after ``iterations`` evaluations."""
    f_hi = f(1.0)
    if f_hi <= 0:
        return 1.0
    f_lo = f(-1.0)
    if f_lo >= 0:
        return -1.0
    lo, hi = -1.0, 1.0                     # lo: f < 0, hi: f > 0
    side = 0
    d = lo
    for _ in range(iterations):
        d = (lo * f_hi - hi * f_lo) / (f_hi - f_lo)
        fd = f(d)
        if abs(fd) < tolerance:
            break
        if fd > 0:
            hi, f_hi = d, fd
            if side == 1:
                f_lo *= 0.5
            side = 1
        else:
            lo, f_lo = d, fd
            if side == -1:
                f_hi *= 0.5
            side = -1
    return d
