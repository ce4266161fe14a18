"""The ``ptos`` reference controller: model-predictive time-optimal switching far from the target and the
proximate time-optimal servo of Workman (1987) near it, on the ECU cascade of :mod:`.cascade` (battery
compensation, current loop, bounded self-tuning). The chain and its self-tuning are described in
:mod:`.cascade`'s docstring; this module holds the outer law, its observer and its guards
(:class:`PTOSController`), and registers ``ptos``.
"""
from __future__ import annotations

import math

from .base import check_gain, register_controller
from .cascade import CascadeController, _clip
from .predictive import StopPredictor, kalman_gains
from .selftest import BreakawaySelfTest


class PTOSController(CascadeController):
    """Model-predictive time-optimal switching (:class:`.predictive.StopPredictor`) beyond ``engage_deg`` from
    the target, then the proximate time-optimal servo below as the capture law (until the error exceeds
    ``relaunch_deg`` again or the reference moves). The capture law, on the coil as a velocity source:

    The speed command follows the braking curve of a plate that decelerates at ``alpha`` a_max after a dead
    time t_d (the current's fall and one control period), capped by the battery's speed limit, and a linear
    zone K_p e near the target (C1 at the joint):

        v_cmd = sgn(e) min(v_max, K_p |e|, sqrt((a t_d)^2 + 2 a |e|) - a t_d),      a = alpha a_max

    u = R_hat i_load + k v_cmd + K_v (v_cmd - v_hat) + K_c (i_load - i_m); a conditional integral (V) inside
    ``integral_zone_deg`` (3x that while the plate rests) removes the friction mismatch.

    Friction level from the observer's innovation (:meth:`SelfTuning.update_from_innovation`), within
    ``innovation_zone_deg`` of the target, after the observer's first ``innovation_settle_s``, above
    ``innovation_speed_rad_s`` (tapered above ``innovation_taper_rad_s``), gain ``innovation_gain`` times
    min(1, (``innovation_noise_deg``)^2 / mean square of the resting innovation); 0 turns it off. Outside
    the zone (large moves, where the LMS learns) it lets the landing of a large step alone: with it there,
    springs -20 % 80->10 deg limit-cycled around the target (6.7x its bound, one seed of two). While the
    reference moves (ramps, pedal) it learns the spring level too (``innovation_springs``, the spring's part
    of the normalized step times ``innovation_spring_share``; moves both ways separate the two): with the
    friction level alone, the pedal profile at springs -20 % learnt the weaker spring as less friction on its
    opening ramps and lagged 8 deg on the next closing ramp (1.38 deg RMS).

    A reference moving at a steady rate is followed where it will be at the end of the period the duty acts
    over (``reference_preview_periods`` periods of its rate ahead; the env shows it at the start): without
    this a 140 deg/s ramp was tracked 0.14 deg behind. While it moves away with little voltage headroom (the
    voltage that carries the plate along it above 1 - ``follow_headroom`` of the battery) the landing law does
    not brake the coil below the springs plus ``follow_current_floor`` of the friction (:meth:`follow_floor_duty`).
    Near the battery's limit (the following voltage above 1 - ``tracking_headroom`` of it) a plate that moves
    with the reference is steered onto it instead (:meth:`tracking_duty`: the duty that puts the predicted plate
    on the reference ``tracking_horizon_periods`` on, never below the current carrying the springs plus
    ``tracking_current_floor`` of the friction; ``tracking_zone_deg`` = 0 turns it off).
    The observer's speed gain (``observer_speed_gain``) falls as 1/RMS of the resting innovation beyond
    ``innovation_noise_deg`` (``observer_noise_schedule``): the sensor noise measured at rest.
    While the reference moves at a steady rate (ramps, pedal moves) the speed gain is
    max(``observer_speed_gain`` q, ``observer_tracking_speed_gain`` q^2), q that schedule: following a slow ramp
    the plate's speed swings with the friction (more process noise than at rest), so a Kalman-style gain is
    higher there, and falls with the measurement noise's variance (the noisy sensor keeps the resting gain).

    On a sensor noisier than ``innovation_noise_deg`` (``noisy_sensor_filter``; the noise read at rest from
    the sensed angle's second difference, :meth:`measure_noise`) the observer carries a load torque and takes
    the steady-state Kalman gains of (angle, speed, load torque) for that noise
    (:func:`.predictive.kalman_gains`, the torque a random walk of ``observer_torque_noise_Nm`` per period,
    ``observer_tracking_torque_noise_Nm`` while the reference moves at a steady rate: steady sliding, a slowly
    changing load), and the laws act on its angle instead of the sensed one.

    A plate ahead of a reference that moves towards it waits (``wait_for_reference``, :meth:`wait_duty`): the
    landing law's reverse is never deeper than the duty whose end current holds the springs at the plate.

    The predictor's observer has a rest check (``rest_band_deg``, ``rest_check_speed_rad_s``): when the sensed
    angle has stayed within the band for two periods, an observer speed above the check speed is replaced by
    the sensed one (see :meth:`.predictive.StopPredictor.observe`). After a landing the capture law keeps the
    plate until the error exceeds ``relaunch_deg``; then a new predicted move starts."""

    name = "ptos"
    use_generator = False

    def __init__(self, model=None, params: dict | None = None, *, position_gain_rad_s: float = 300.0,
                 velocity_gain_V_s_per_rad: float = 0.014, alpha: float = 0.56, dead_time_s: float = 0.0004,
                 integral_V_per_rad_s: float = 3300.0, integral_zone_deg: float = 1.0, integral_limit_V: float = 3.0,
                 predictive: bool = True, engage_deg: float = 0.3, aim_short_deg: float = 0.0,
                 relaunch_deg: float = 0.2, innovation_gain: float = 0.1, innovation_speed_rad_s: float = 1.0,
                 innovation_noise_deg: float = 0.02, innovation_taper_rad_s: float = 4.0,
                 innovation_settle_s: float = 0.02, innovation_zone_deg: float = 1.0, rest_band_deg: float = 0.05,
                 rest_check_speed_rad_s: float = 2.0, innovation_springs: bool = True,
                 innovation_spring_share: float = 0.3, self_test: bool = True,
                 self_test_ramp_A_per_s: float = 100.0, hold_band: float = 0.7,
                 reference_feedforward: float = 1.0, reference_preview_periods: float = 1.0,
                 observer_angle_gain: float = 0.5, observer_speed_gain: float = 0.25,
                 observer_tracking_speed_gain: float = 0.55,
                 observer_noise_schedule: bool = True, follow_current_floor: float = 0.8,
                 follow_headroom: float = 0.5, noisy_sensor_filter: bool = True,
                 observer_torque_noise_Nm: float = 3.2e-4, observer_tracking_torque_noise_Nm: float = 2.5e-4,
                 tracking_zone_deg: float = 0.3,
                 tracking_headroom: float = 0.3, tracking_current_floor: float = 0.9,
                 tracking_horizon_periods: int = 2, wait_for_reference: bool = True,
                 tracking_headroom_per_friction: bool = True, **kw):
        own = type(self).__name__
        self.track_zone = math.radians(check_gain(own, "tracking_zone_deg", tracking_zone_deg, non_negative=True))
        self.track_headroom = check_gain(own, "tracking_headroom", tracking_headroom, non_negative=True, upper=1.0001)
        self.track_floor = check_gain(own, "tracking_current_floor", tracking_current_floor, non_negative=True,
                                      upper=1.0001)
        if isinstance(tracking_horizon_periods, bool) or not isinstance(tracking_horizon_periods, int) \
                or tracking_horizon_periods < 1:
            raise ValueError(f"{own}.tracking_horizon_periods = {tracking_horizon_periods!r} is invalid: expected an "
                             "integer >= 1")
        self.track_h = tracking_horizon_periods
        if not isinstance(wait_for_reference, bool):
            raise ValueError(f"{own}: wait_for_reference = {wait_for_reference!r} is invalid: expected True or False")
        self.wait_for_reference = wait_for_reference
        if not isinstance(tracking_headroom_per_friction, bool):
            raise ValueError(f"{own}: tracking_headroom_per_friction = {tracking_headroom_per_friction!r} is invalid: "
                             "expected True or False")
        self.track_per_friction = tracking_headroom_per_friction
        self.noise_settle = 0.02
        if not isinstance(noisy_sensor_filter, bool):
            raise ValueError(f"{own}: noisy_sensor_filter = {noisy_sensor_filter!r} is invalid: expected True or False")
        self.noisy_filter = noisy_sensor_filter
        self.torque_noise = check_gain(own, "observer_torque_noise_Nm", observer_torque_noise_Nm, positive=True)
        self.tracking_torque_noise = check_gain(own, "observer_tracking_torque_noise_Nm",
                                                observer_tracking_torque_noise_Nm, positive=True)
        self.observer_angle_gain = check_gain(own, "observer_angle_gain", observer_angle_gain, non_negative=True,
                                              upper=1.0001)
        self.observer_speed_gain = check_gain(own, "observer_speed_gain", observer_speed_gain, non_negative=True,
                                              upper=1.0001)
        if not isinstance(observer_noise_schedule, bool):
            raise ValueError(f"{own}: observer_noise_schedule = {observer_noise_schedule!r} is invalid: expected True "
                             "or False")
        self.speed_schedule = observer_noise_schedule
        self.tracking_speed_gain = check_gain(own, "observer_tracking_speed_gain", observer_tracking_speed_gain,
                                              non_negative=True, upper=1.0001)
        self.follow_floor = check_gain(own, "follow_current_floor", follow_current_floor, non_negative=True,
                                       upper=1.0001)
        self.follow_headroom = check_gain(own, "follow_headroom", follow_headroom, non_negative=True, upper=1.0001)
        self.preview = check_gain(own, "reference_preview_periods", reference_preview_periods, non_negative=True)
        self.ff = check_gain(own, "reference_feedforward", reference_feedforward, non_negative=True, upper=1.0001)
        kw.setdefault("friction_compensation", 1.0)      # full nominal friction level, linear within 0.12 deg
        kw.setdefault("friction_zone_deg", 0.12)
        self.Kp = check_gain(own, "position_gain_rad_s", position_gain_rad_s, positive=True)
        self.Kv = check_gain(own, "velocity_gain_V_s_per_rad", velocity_gain_V_s_per_rad, non_negative=True)
        self.alpha = check_gain(own, "alpha", alpha, positive=True, upper=1.0001)
        self.t_d = check_gain(own, "dead_time_s", dead_time_s, non_negative=True)
        self.Ki = check_gain(own, "integral_V_per_rad_s", integral_V_per_rad_s, non_negative=True)
        self.i_zone = math.radians(check_gain(own, "integral_zone_deg", integral_zone_deg, positive=True))
        self.i_lim = check_gain(own, "integral_limit_V", integral_limit_V, non_negative=True)
        self.predictive = bool(predictive)
        self.engage = math.radians(check_gain(own, "engage_deg", engage_deg, positive=True))
        self.aim_short = math.radians(check_gain(own, "aim_short_deg", aim_short_deg, non_negative=True))
        self.relaunch = math.radians(check_gain(own, "relaunch_deg", relaunch_deg, positive=True))
        self.innovation_gain = check_gain(own, "innovation_gain", innovation_gain, non_negative=True, upper=1.0)
        self.innovation_speed = check_gain(own, "innovation_speed_rad_s", innovation_speed_rad_s, non_negative=True)
        self.innovation_taper = check_gain(own, "innovation_taper_rad_s", innovation_taper_rad_s, positive=True)
        self.innovation_settle = check_gain(own, "innovation_settle_s", innovation_settle_s, non_negative=True)
        self.innovation_zone = math.radians(check_gain(own, "innovation_zone_deg", innovation_zone_deg, positive=True))
        self.innovation_ref = math.radians(check_gain(own, "innovation_noise_deg", innovation_noise_deg, positive=True))
        self.innovation_springs = bool(innovation_springs)
        self.spring_share = check_gain(own, "innovation_spring_share", innovation_spring_share, non_negative=True,
                                       upper=1.0001)
        super().__init__(model, params, **kw)
        self._g_noise = min(1.0, self.dt / 0.05)     # mean square of the resting innovation over 50 ms
        self.predictor = StopPredictor(self.model) if self.predictive and self.model.plant is not None else None
        if self.predictor is not None:
            self.predictor.rest_band_rad = math.radians(check_gain(own, "rest_band_deg", rest_band_deg, non_negative=True))
            self.predictor.rest_speed = check_gain(own, "rest_check_speed_rad_s", rest_check_speed_rad_s, positive=True)
        self.hold_band = check_gain(own, "hold_band", hold_band, non_negative=True, upper=1.0001)
        if not isinstance(self_test, bool):
            raise ValueError(f"{own}: self_test = {self_test!r} is invalid: expected True or False")
        self.selftest = BreakawaySelfTest(self.model, self.dt, ramp_A_per_s=self_test_ramp_A_per_s) \
            if self_test and self.predictor is not None and self.model.plant.friction is not None else None

    def reset_outer(self) -> None:
        self.I = 0.0
        self.landing = False
        self.landed_at = None
        self.innovation_ms = getattr(self, "innovation_ref", 0.0) ** 2
        self.observed_periods = 0
        self.noise_var = 0.0
        self._y3 = [None, None, None]
        self._r_noise = None
        self._still = 0
        self.r_prev = None
        self.dr_prev = 0.0
        self.r_rate = 0.0
        self.tracking_now = False
        if getattr(self, "predictor", None) is not None:
            self.predictor.reset()
        if getattr(self, "selftest", None) is not None:
            self.selftest.reset()

    def reference_rate(self, r_target: float) -> float:
        """The reference's rate (rad/s) while it moves at a steady rate (ramps, the pedal profile's tip-in and
        tip-out): the last change, when it agrees with the one before within 20 %; 0 otherwise (a step is a
        single change: no rate)."""
        dr = 0.0 if self.r_prev is None else r_target - self.r_prev
        steady = dr != 0.0 and abs(dr - self.dr_prev) <= 0.2 * abs(dr)
        self.dr_prev = dr
        return dr / self.dt if steady else 0.0

    def noise_ratio(self) -> float:
        """q = min(1, reference innovation RMS / the resting innovation's RMS measured so far)."""
        return min(1.0, self.innovation_ref / math.sqrt(max(self.innovation_ms, 1e-30))) if self.speed_schedule else 1.0

    def observe(self, y: float, meas) -> None:
        """One period of the predictor's observer, at the self-tuned levels."""
        st, p = self.tuning, self.predictor
        p.update_levels(st.resistance_ohm, st.friction_level, st.spring_level)
        self.v_pred = p.speed                       # the speed the innovation's period started from
        # the observer's speed gain on the angle innovation, scheduled on the sensor noise the controller measured
        # at rest (the resting innovation's mean square, e.g. during the key-on hold): full up to the reference
        # innovation RMS, falling as 1/RMS beyond (each period's speed correction is gain x innovation / T: on a
        # noisy sensor the full gain turns the noise into speed errors the landing law brakes and drives on)
        q = self.noise_ratio()
        self.speed_gain_now = self.observer_speed_gain * q
        if self.r_rate != 0.0:
            self.speed_gain_now = max(self.speed_gain_now, self.tracking_speed_gain * q * q)
        ga, gt = self.observer_angle_gain, 0.0
        if self.noisy_filter and self.noisy:
            ga, self.speed_gain_now, gt = self.noisy_gains()
        p.observe(y, meas.current_A, meas.last_duty, self.V_now, ga, self.speed_gain_now, gt)
        self.observed_periods += 1
        self.observed_now = True

    def noisy_gains(self) -> tuple:
        """Steady-state Kalman gains (angle, speed, load torque) for the sensor noise variance measured at rest
        (:meth:`measure_noise`), rounded to 5 % steps so each Riccati solution is computed once."""
        var = math.exp(round(math.log(max(self.noise_var, 1e-30)) * 20.0) / 20.0)
        q = self.tracking_torque_noise if self.r_rate != 0.0 else self.torque_noise
        return kalman_gains(self.dt, self.model.inertia_kg_m2, var, q ** 2)

    def measure_noise(self, y: float, r: float) -> None:
        """The angle sensor's noise variance, from the second difference of the sensed angle while the reference
        stands still and the plate has rested for 20 ms (white noise of variance s^2 gives 6 s^2; a resting or creeping plate's
        own motion hardly any, unlike the innovation, which a wrong load model also fills), mean over 50 ms."""
        ys = self._y3
        ys[0], ys[1], ys[2] = ys[1], ys[2], y
        still = r == self._r_noise and ys[0] is not None and abs(self.predictor.speed) < self.rest_speed
        self._r_noise = r
        self._still = self._still + 1 if still else 0
        if self._still * self.dt >= self.noise_settle:
            d2 = ys[2] - 2.0 * ys[1] + ys[0]
            self.noise_var += self._g_noise * (d2 * d2 / 6.0 - self.noise_var)

    @property
    def noisy(self) -> bool:
        """The sensor is noisier than ``innovation_noise_deg`` (RMS, measured at rest)."""
        return self.noise_var > self.innovation_ref ** 2

    def control_angle(self, y: float, meas, V: float) -> float:
        self.observed_now = False
        self.y_control = y
        if not self.noisy_filter or self.predictor is None or meas.current_A is None:
            return y
        self.measure_noise(y, self.r_seen)
        if not self.noisy:
            return y
        self.V_now = V
        self.observe(y, meas)
        self.y_control = float(self.predictor.angle)
        return self.y_control

    def compute(self, y: float, r_target: float, meas) -> float:
        self.r_rate = self.ff * self.reference_rate(r_target)
        r_seen = self.r_seen = r_target
        # the duty acts over the coming period and the plate is judged against the reference at its end: a
        # reference moving at a steady rate is followed where it will be then (without this, a ramp is tracked
        # one period behind: 0.14 deg at 140 deg/s)
        r_target = r_seen + self.preview * self.r_rate * self.dt
        duty = super().compute(y, r_target, meas)
        if self.predictor is None or meas.current_A is None:
            return duty
        if not self.observed_now:
            self.observe(y, meas)
        y = self.y_control
        e = r_target - y
        m, st = self.model, self.tuning
        p = self.predictor
        v_pred = self.v_pred
        d_test = None
        if self.selftest is not None and self.selftest.phase != self.selftest.DONE:
            d_test = self.selftest.update(y, r_seen, meas.current_A, meas.last_duty, self.V_now, st.resistance_ohm,
                                          self.Kc, p.speed, self.innovation_ms, self.landing)
            if self.selftest.result is not None:        # identified: the levels the next move lands with
                st.friction_level, st.spring_level = self.selftest.result
                self.I = 0.0
            if d_test is not None:
                self.I = 0.0
                self.r_prev = r_seen
                return d_test
        if self.innovation_gain > 0 and self.observed_periods * self.dt > self.innovation_settle \
                and abs(e) < self.innovation_zone:
            eps = p.innovation
            if abs(v_pred) < self.rest_speed:       # at rest the innovation is sensor noise: its mean square
                self.innovation_ms += self._g_noise * (eps * eps - self.innovation_ms)
            # noise-weighted gain (as a Kalman gain falls with the measurement noise): full gain up to the
            # reference innovation RMS, 1/variance beyond, so sensor noise cannot drive the estimate
            g = self.innovation_gain * min(1.0, self.innovation_ref ** 2 / max(self.innovation_ms, 1e-30))
            tracking = self.r_prev is not None and abs(r_seen - self.r_prev) > 1e-7
            st.update_from_innovation(eps, v_pred, p.level_sensitivity(), g, self.innovation_speed,
                                      self.innovation_taper,
                                      spring_phi=y if tracking and self.innovation_springs else None,
                                      spring_share=self.spring_share)
        self.r_prev = r_seen
        s = 1.0 if e > 0 else -1.0
        if self.landed_at is not None and abs(r_target - self.landed_at) > 1e-4:
            self.landed_at = None                   # a new target: a new move
        self.tracking_now = False
        if self.track_zone > 0 and self.r_rate != 0.0:
            d = self.tracking_duty(e, y, r_target)
            if d is not None:
                return d
        far = abs(e) > (self.engage if self.landed_at is None else self.relaunch)
        if far or (self.landing and s * p.speed > self.rest_speed):
            i_hold = st.spring_level * m.spring_torque_Nm(r_target) / m.torque_constant_Nm_per_A
            self.landing = True
            self.I = 0.0
            aim = r_target - s * self.aim_short
            if s * self.r_rate > 0:
                # a reference moving away at a steady rate: the landing law trails it by the stop distance of
                # a plate that follows it; aim beyond it by that distance (policy B braking now from the
                # reference's angle and speed with the current that carries the load there)
                aim += s * self.tracking_lead(r_target, s, i_hold, st.resistance_ohm * i_hold)
            d = p.duty_to_land(aim, s, self.V_now, i_hold, st.resistance_ohm * i_hold)
            if self.hold_band < 1.0 and s * d < 0 and abs(e) < self.engage:
                # friction-aware landing: the plate stops and stays only if the coil still holds it against
                # the springs, |k i - T_spring| < theta_f T_s; a full reverse that would empty the coil below
                # that band (the plate ran ahead of the prediction: less friction or a weaker spring than
                # modelled) lets it stop on the target and slide back. Brake no further than hold_band of the
                # band's half-width below the holding current (the current at the end of this period under d)
                k, L = m.torque_constant_Nm_per_A, m.inductance_H
                R = st.resistance_ohm
                i_next = meas.current_A + (d * self.V_now - R * meas.current_A - k * p.speed) * self.dt / L
                edge = self.hold_band * st.friction_level * m.static_Nm / k
                if s * (i_next - i_hold) < -edge:
                    i_goal = i_hold - s * edge
                    d_edge = (R * meas.current_A + k * p.speed + L * (i_goal - meas.current_A) / self.dt) / self.V_now
                    d = max(-1.0, min(1.0, d_edge)) if s * d_edge > s * d else d
            if s * self.r_rate > 0 and self.follow_floor > 0:
                d = self.follow_floor_duty(d, s, y, i_hold)
            elif s * self.r_rate < 0:
                d = self.wait_duty(d, s, y)
            return d
        if self.landing:                            # the predicted move has ended: the capture law finishes
            self.landed_at = r_target
        self.landing = False
        return duty

    def tracking_duty(self, e: float, y: float, r_target: float) -> float | None:
        """The tracking mode (None outside it): following a reference that moves at a steady rate with little
        voltage headroom -- the voltage that carries the plate along it, u_follow (:meth:`follow_voltage`), above
        1 - ``tracking_headroom`` of the battery -- while the plate moves with it (|e| and the distance the speed
        difference makes over the horizon, |r' - v| h T, both within ``tracking_zone_deg``): the duty which, held
        for h = ``tracking_horizon_periods`` periods, puts the predicted plate (the compiled model from the
        observer's state) on the reference at their end (:meth:`.predictive.StopPredictor.duty_to_reach`), raised
        to the duty whose end current carries the springs plus ``tracking_current_floor`` of the friction.

        Why: the landing law plans to *stop* the plate at an aim beyond the reference; on a plate slightly ahead it
        brakes, the plate (J = 3e-5 kg m^2 against the friction) stops within a period and sticks, and the coil
        regains the current to break it away only at (V - u_follow) / L -- with 0.5 V of headroom 25 A/s, against
        a fall at (V + u_follow) / L. Near the battery's limit the cost of braking is that asymmetric, so there the
        plate is steered onto the reference and never braked below the load it carries.

        With ``tracking_headroom_per_friction`` the headroom threshold is ``tracking_headroom`` times the learnt
        friction level: a plate that stopped needs the coil to regain the static friction's share of the current,
        theta_f times the nominal, at (V - u_follow) / L, so the time a stop costs grows with the friction as it
        does with a smaller headroom (friction +50 %: the mode from 55 % of the battery instead of 70 %)."""
        p, st, m = self.predictor, self.tuning, self.model
        h = self.track_h
        if abs(e) >= self.track_zone or abs(self.r_rate - p.speed) * h * self.dt >= self.track_zone:
            return None
        sr = 1.0 if self.r_rate > 0 else -1.0
        i_hold = st.spring_level * m.spring_torque_Nm(r_target) / m.torque_constant_Nm_per_A
        headroom = self.track_headroom * (st.friction_level if self.track_per_friction else 1.0)
        if self.follow_voltage(sr, i_hold) <= (1.0 - headroom) * self.V_now:
            return None
        self.landing = True                         # when the reference stops, the landing law brings it to rest
        self.I = 0.0
        self.tracking_now = True
        d = p.duty_to_reach(r_target + self.r_rate * (h - 1) * self.dt, h, self.V_now)
        return self.current_floor_duty(d, sr, y, self.track_floor)

    def wait_duty(self, d: float, s: float, y: float) -> float:
        """The plate ahead of a reference that moves towards it (the landing law's direction s against the
        reference's rate): ``d``, raised against s to the duty whose current at the end of the period holds the
        springs at ``y`` (``wait_for_reference``; :meth:`current_floor_duty` with no friction share). The landing
        law plans a move back to a fixed target and reverses the coil; the reference, though, arrives by itself
        (1 deg at 6 rad/s in 3 ms), and an emptied coil lets the springs pull the plate back, where it sticks and
        needs the break-away current again (ETB-2B pedal at 9 V, seed 0: a tip-in overshot 1.1 deg, full reverse
        drove the plate back at 4.6 rad/s, 2 deg behind the reference). Holding the springs, the plate stops on
        its own friction and waits."""
        return self.current_floor_duty(d, -s, y, 0.0) if self.wait_for_reference else d

    def follow_voltage(self, s: float, i_hold: float) -> float:
        """s u_follow: the voltage (V) that carries the plate along the reference moving in direction s at its
        rate, u_follow = R_hat (i_hold + s theta_f T_c / k) + k r', signed so that it is positive when the battery
        has to supply it."""
        m, st = self.model, self.tuning
        k = m.torque_constant_Nm_per_A
        return s * (st.resistance_ohm * (i_hold + s * st.friction_level * m.coulomb_Nm / k) + k * self.r_rate)

    def current_floor_duty(self, d: float, s: float, y: float, floor: float) -> float:
        """``d``, raised (in direction s) to the duty whose current at the end of the period (the compiled model,
        :meth:`.predictive.StopPredictor.duty_for_current`) holds the springs at ``y`` plus ``floor`` of the
        friction."""
        m, st = self.model, self.tuning
        i_goal = (st.spring_level * m.spring_torque_Nm(y) + s * floor * st.friction_level * m.coulomb_Nm) \
            / m.torque_constant_Nm_per_A
        d_floor = self.predictor.duty_for_current(i_goal, self.V_now)
        return max(-1.0, min(1.0, d_floor)) if s * d_floor > s * d else d

    def follow_floor_duty(self, d: float, s: float, y: float, i_hold: float) -> float:
        """Following a reference that moves away (direction s) with little voltage headroom: the landing law
        plans to stop the plate at its aim, and on a plate slightly ahead it brakes the coil below the current
        that carries the load; with this rotor's inertia the plate stops within a period and sticks, and
        restarting it needs the break-away current, which the coil reaches only at (V - u_follow) / L. So when
        the voltage that carries the plate along the reference, u_follow = R_hat (i_hold + theta_f T_c / k)
        + k r_rate, exceeds (1 - ``follow_headroom``) of the battery, the duty is kept at least at the one whose
        current at the end of the period (the compiled model, :meth:`.predictive.StopPredictor.duty_for_current`)
        holds the springs plus ``follow_current_floor`` of the friction at the plate: it may slow the plate
        (at most (1 - floor) theta_f T_c / J) but not stop it."""
        if self.follow_voltage(s, i_hold) <= (1.0 - self.follow_headroom) * self.V_now:
            return d
        return self.current_floor_duty(d, s, y, self.follow_floor)

    def tracking_lead(self, r: float, s: float, i_hold: float, u_hold: float) -> float:
        """Distance (rad) a plate following the reference (at r, the reference's rate, the current holding the
        springs plus the friction and viscous torque of that speed) travels before it stops under policy B."""
        m, st = self.model, self.tuning
        i = i_hold + s * (st.friction_level * m.coulomb_Nm + m.viscous_Nm_s_per_rad * abs(self.r_rate)) \
            / m.torque_constant_Nm_per_A
        return abs(self.predictor.stop_angle_from(r, self.r_rate, i, -s, s, self.V_now, i_hold, u_hold) - r)

    def braking_accel(self, e: float, y: float, V: float) -> float:
        """a_max: deceleration of a motion towards the target (sign of e) once the drive current is gone:
        friction plus the spring when it pulls back (J: the rotor)."""
        m, st = self.model, self.tuning
        t_spring = m.spring_torque_Nm(y) * st.spring_level * (1.0 if e > 0 else -1.0)
        t = st.friction_level * m.coulomb_Nm + max(t_spring, 0.0)
        return t / m.inertia_kg_m2

    def outer(self, e, y, v, r, v_r, a_r):
        V = self.V_now
        a = self.alpha * self.braking_accel(e, y, V)
        x = abs(e)
        curve = math.sqrt((a * self.t_d) ** 2 + 2 * a * x) - a * self.t_d
        v_cmd = math.copysign(min(self.Kp * x, curve), e) + self.r_rate
        if x < self.i_zone * (3.0 if abs(v) < self.rest_speed else 1.0) and not getattr(self, "saturated", False):
            self.I = _clip(self.I + self.Ki * self.dt * e, -self.i_lim, self.i_lim)
        elif x >= 3.0 * self.i_zone:
            self.I = 0.0
        return v_cmd + self.I / self.model.torque_constant_Nm_per_A

register_controller("ptos", PTOSController, "proximate time-optimal servo (Workman) on the current loop, "
                    "battery compensation, self-tuning (controllers/ptos.py)")
