"""Truth shapes that are NOT the candidates' formulas (issue 15, item 6): for every family of the catalogue
at least two physically plausible functional forms of the same physics, as proof truths
(:func:`.proof_truth.truth_for` with ``shape`` 1 or 2; shape 0 is the candidate's own formula, or for
airflow the Gaussian map). Each is a component with a frozen Params dataclass whose field names carry the
units and a @kernel, like :class:`.proof_truth.AirflowMap`; none of them is registered as a candidate.

Plate effects (kernel(t, phi, omega, i, u, s, p, ds) -> (torque, voltage drop, inductance), as every plant
component; x = phi / (pi/2)):

    TorqueConstantProfile   shaft flux loss with another angle profile: dk(phi) = -k sigma((phi - phi_0)/w)
                            (a logistic onset, profile 0) or -k max(0, (phi - phi_0)/(pi/2 - phi_0)) (a kink
                            and a straight ramp, profile 1); torque dk i, back-EMF dk omega
    CurrentTorqueConstant   torque-constant error that varies with the current: dk(i) = d (i/i_s)^2/(1+(i/i_s)^2)
                            (the constant saturating at high current, profile 0), or d_+ / d_- by current
                            direction, blended by tanh(i/i_s) (profile 1); back-EMF dk(0)-like mean term
    ThermalNetwork          coil heating with two thermal nodes (winding C_w, R_wh -> housing C_h, R_ha):
                            two time constants; heat R(T_w) i^2 + k_r u^2 (k_r: PWM ripple / eddy loss)
    SpringShape             spring asymmetry below limp-home as a smooth change of rate,
                            dT = -dR d sigma(-d/w) (profile 0), or a hardening closing spring dT = c d^2 for
                            d < 0 (profile 1); d = phi - phi_LH
    AngleTorqueProfile      airflow torque: a logistic plateau a sigma((phi - phi_c)/w) (profile 0) or a map
                            that changes sign, a sin(pi x) (1 - x/x_0) (profile 1)
    StribeckShape           Stribeck stiction with another curve on its own bristle: g = dT_s exp(-(omega/w_s)^2)
                            (exponent 2, profile 0) or dT_s / (1 + |omega/w_s|) with a different level
                            while closing (profile 1)
    SupplyShape             supply/bridge drop: a diode-like a asinh(i / i_0) + R_s i (profile 0), or a battery
                            with polarization: R_s i + v_p, tau dv_p/dt = R_p i - v_p (profile 1)
    SoftBacklash            free play with soft contact: the springs act at d - b tanh(d/b) (profile 0), or
                            asymmetric play b_open / b_close, hard contact (profile 1)
    AngleFrictionProfile    friction over angle on a unit bristle: a Gaussian band a exp(-((phi-phi_c)/w)^2/2)
                            (profile 0) or a step a sigma((phi - phi_c)/w) (a seal that rubs beyond an angle,
                            profile 1)
    InductanceShape         inductance falling with current: past a knee, dL max(0,|i|-i_k)/(max(0,|i|-i_k)+i_w)
                            (profile 0), or with a linear onset dL (1 - exp(-|i|/i_s)) (profile 1)
    ProgressiveStop         the open stop meets a soft contact before the drawn stop, Hunt-Crossley damped:
                            T = -k d (d/d_ref)^(n-1) (1 + c omega) (Hertz-like, profile 0) or
                            -k w (exp(d/w) - 1) (1 + c omega) (a rubber bumper, profile 1), d = phi - phi_b > 0

Sensor shapes (reading side; ``reading_kernel(phi, noise, p, s) -> value`` [rad], before the recording's
PositionSensor; ``s`` the shape's own state, called once per sample in time order):

    SensorCurve      a static reading error: y = phi + o + b sin(pi x) (a bowed characteristic, profile 0)
                     or two slopes with a knee at phi_k (profile 1)
    SensorFilter     the reading low-pass filtered: first order, time constant tau (profile 0), or the
                     moving average of the last N samples (profile 1); not a pure delay
    SensorCodes      quantization that is not a uniform grid: every other code width (1 +- e) q (differential
                     nonlinearity, profile 0), or a grid with hysteresis (the code changes only when the angle
                     passes the next code by h q, profile 1)

Outside the catalogue (no candidate describes it):

    CurrentRipple    a torque ripple proportional to the current and periodic in angle,
                     T = a i sin(2 pi phi / P + psi)  (commutation ripple; the detent torque of
                     shapes_eval.Cogging is the other outside-the-catalogue truth)
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..components.base import Component, Params, check, non_negative, positive
from ..components.effects_electrical import Effect
from ..components.friction import bristle_advance, bristle_rate
from ..components.spring import limp_home_spring_kernel
from ..jit import kernel


@kernel
def sigmoid(x):
    if x > 40.0:
        return 1.0
    if x < -40.0:
        return 0.0
    return 1.0 / (1.0 + math.exp(-x))


def _profile(owner, obj, n):
    check(owner, "profile", obj.profile, obj.profile in tuple(float(k) for k in range(n)),
          f"one of {', '.join(str(k) for k in range(n))}")


# ------------------------------------------------------------------------------------ shaft flux loss
@dataclasses.dataclass(frozen=True)
class TorqueConstantProfileParams(Params):
    loss_Nm_per_A: float = 0.01             # k: torque constant lost where the profile is 1
    onset_rad: float = math.radians(50.0)   # phi_0: centre of the logistic onset / start of the ramp
    width_rad: float = math.radians(8.0)    # w: width of the logistic onset
    profile: float = 0.0                    # 0 logistic, 1 kink + straight ramp to the open end

    def validate(self):
        positive("TorqueConstantProfileParams", self, "width_rad")
        check("TorqueConstantProfileParams", "onset_rad", self.onset_rad, self.onset_rad < 0.5 * math.pi - 0.05,
              "an angle below 87 deg")
        _profile("TorqueConstantProfileParams", self, 2)


@kernel
def torque_constant_profile_kernel(t, phi, omega, i, u, s, p, ds):
    if p[3] < 0.5:
        dk = -p[0] * sigmoid((phi - p[1]) / p[2])
    else:
        r = (phi - p[1]) / (0.5 * math.pi - p[1])
        dk = -p[0] * (r if r > 0.0 else 0.0)
    return dk * i, dk * omega, 0.0


class TorqueConstantProfile(Component):
    kind = "truth.torque_constant_profile"
    role = "effect"
    Params = TorqueConstantProfileParams
    kernel = staticmethod(torque_constant_profile_kernel)


# ------------------------------------------------------------------------------------ torque-constant error
@dataclasses.dataclass(frozen=True)
class CurrentTorqueConstantParams(Params):
    delta_Nm_per_A: float = -0.01           # d: the error at high current (profile 0) / while driving opening
    closing_delta_Nm_per_A: float = 0.0     # d_-: the error at negative current (profile 1)
    current_scale_A: float = 1.5            # i_s
    profile: float = 0.0                    # 0 saturating with |i|, 1 by current direction

    def validate(self):
        positive("CurrentTorqueConstantParams", self, "current_scale_A")
        _profile("CurrentTorqueConstantParams", self, 2)


@kernel
def current_torque_constant_kernel(t, phi, omega, i, u, s, p, ds):
    if p[3] < 0.5:
        x = i / p[2]
        dk = p[0] * x * x / (1.0 + x * x)
        return dk * i, dk * omega, 0.0
    w = 0.5 * (1.0 + math.tanh(i / p[2]))
    dk = w * p[0] + (1.0 - w) * p[1]
    return dk * i, 0.5 * (p[0] + p[1]) * omega, 0.0


class CurrentTorqueConstant(Component):
    kind = "truth.current_torque_constant"
    role = "effect"
    Params = CurrentTorqueConstantParams
    kernel = staticmethod(current_torque_constant_kernel)


# ------------------------------------------------------------------------------------ coil heating
@dataclasses.dataclass(frozen=True)
class ThermalNetworkParams(Params):
    cold_resistance_ohm: float = 1.25
    temperature_coefficient_per_K: float = 0.00393
    winding_capacity_J_per_K: float = 5.0          # C_w
    winding_to_housing_K_per_W: float = 3.0        # R_wh
    housing_capacity_J_per_K: float = 60.0         # C_h
    housing_to_ambient_K_per_W: float = 6.0        # R_ha
    ripple_loss_W_per_V2: float = 0.0              # k_r: heat k_r u^2 besides the copper loss

    def validate(self):
        n = "ThermalNetworkParams"
        positive(n, self, "cold_resistance_ohm", "winding_capacity_J_per_K", "winding_to_housing_K_per_W",
                 "housing_capacity_J_per_K", "housing_to_ambient_K_per_W")
        non_negative(n, self, "temperature_coefficient_per_K", "ripple_loss_W_per_V2")


@kernel
def thermal_network_kernel(t, phi, omega, i, u, s, p, ds):
    # s = [winding rise, housing rise] [K]
    dR = p[0] * p[1] * s[0]
    q = (s[0] - s[1]) / p[3]
    ds[0] = ((p[0] + dR) * i * i + p[6] * u * u - q) / p[2]
    ds[1] = (q - s[1] / p[5]) / p[4]
    return 0.0, dR * i, 0.0


class ThermalNetwork(Effect):
    kind = "truth.thermal_network"
    persistent_states = True
    Params = ThermalNetworkParams
    state_names = ("winding_rise_K", "housing_rise_K")
    state_units = ("K", "K")
    kernel = staticmethod(thermal_network_kernel)


# ------------------------------------------------------------------------------------ spring asymmetry
@dataclasses.dataclass(frozen=True)
class SpringShapeParams(Params):
    limp_home_rad: float = math.radians(3.0)       # tied to the truth plant's spring
    rate_delta_Nm_per_rad: float = 0.5             # dR (profile 0)
    blend_rad: float = math.radians(0.5)           # w: how smoothly the change sets in below limp-home
    hardening_Nm_per_rad2: float = 10.0            # c (profile 1)
    profile: float = 0.0                           # 0 smooth change of rate, 1 hardening closing spring

    def validate(self):
        positive("SpringShapeParams", self, "blend_rad")
        _profile("SpringShapeParams", self, 2)


@kernel
def spring_shape_kernel(t, phi, omega, i, u, s, p, ds):
    d = phi - p[0]
    if p[4] < 0.5:
        return -p[1] * d * sigmoid(-d / p[2]), 0.0, 0.0
    if d >= 0.0:
        return 0.0, 0.0, 0.0
    return p[3] * d * d, 0.0, 0.0


class SpringShape(Component):
    kind = "truth.spring_shape"
    role = "effect"
    Params = SpringShapeParams
    kernel = staticmethod(spring_shape_kernel)


# ------------------------------------------------------------------------------------ airflow
@dataclasses.dataclass(frozen=True)
class AngleTorqueProfileParams(Params):
    level_Nm: float = -0.04
    centre_rad: float = math.radians(45.0)         # phi_c (profile 0); x_0 = centre / (pi/2) (profile 1)
    width_rad: float = math.radians(10.0)
    profile: float = 0.0                           # 0 logistic plateau, 1 sign-changing map

    def validate(self):
        positive("AngleTorqueProfileParams", self, "width_rad", "centre_rad")
        _profile("AngleTorqueProfileParams", self, 2)


@kernel
def angle_torque_profile_kernel(t, phi, omega, i, u, s, p, ds):
    if p[3] < 0.5:
        return p[0] * sigmoid((phi - p[1]) / p[2]), 0.0, 0.0
    x = phi / (0.5 * math.pi)
    if x < 0.0:
        x = 0.0
    if x > 1.0:
        x = 1.0
    return p[0] * math.sin(math.pi * x) * (1.0 - x / (p[1] / (0.5 * math.pi))), 0.0, 0.0


class AngleTorqueProfile(Component):
    kind = "truth.angle_torque_profile"
    role = "effect"
    Params = AngleTorqueProfileParams
    kernel = staticmethod(angle_torque_profile_kernel)


# ------------------------------------------------------------------------------------ Stribeck
@dataclasses.dataclass(frozen=True)
class StribeckShapeParams(Params):
    stiction_Nm: float = 0.03                      # dT_s (while opening)
    stribeck_velocity_rad_s: float = 0.05          # w_s
    closing_factor: float = 1.0                    # the level while closing, relative (profile 1)
    profile: float = 0.0                           # 0 Gaussian exponent, 1 rational drop by direction
    bristle_stiffness_Nm_per_rad: float = 100.0    # sigma0 of its bristle

    def validate(self):
        n = "StribeckShapeParams"
        positive(n, self, "stiction_Nm", "stribeck_velocity_rad_s", "closing_factor", "bristle_stiffness_Nm_per_rad")
        _profile(n, self, 2)


@kernel
def stribeck_shape_level(omega, p):
    v = omega / p[1]
    if p[3] < 0.5:
        g = p[0] * math.exp(-v * v)
    else:
        g = p[0] * (1.0 if omega >= 0.0 else p[2]) / (1.0 + abs(v))
    return g if g > 1e-12 else 1e-12


@kernel
def stribeck_shape_kernel(t, phi, omega, i, u, s, p, ds):
    ds[0] = bristle_rate(s[0], omega, p[4], stribeck_shape_level(omega, p))
    return -p[4] * s[0], 0.0, 0.0


@kernel
def stribeck_shape_advance(h, t, phi, omega, i, u, s, p):
    s[0] = bristle_advance(s[0], omega, h, p[4], stribeck_shape_level(omega, p))


class StribeckShape(Component):
    kind = "truth.stribeck_shape"
    role = "effect"
    Params = StribeckShapeParams
    state_names = ("z_rad",)
    state_units = ("rad",)
    kernel = staticmethod(stribeck_shape_kernel)
    advance = staticmethod(stribeck_shape_advance)


# ------------------------------------------------------------------------------------ supply drop
@dataclasses.dataclass(frozen=True)
class SupplyShapeParams(Params):
    series_resistance_ohm: float = 0.0             # R_s
    diode_drop_V: float = 0.1                      # a (profile 0)
    knee_current_A: float = 0.1                    # i_0 (profile 0)
    polarization_resistance_ohm: float = 0.1       # R_p (profile 1)
    polarization_time_s: float = 0.5               # tau (profile 1)
    profile: float = 0.0                           # 0 diode-like, 1 battery with polarization

    def validate(self):
        n = "SupplyShapeParams"
        positive(n, self, "knee_current_A", "polarization_time_s")
        non_negative(n, self, "series_resistance_ohm", "diode_drop_V", "polarization_resistance_ohm")
        _profile(n, self, 2)


@kernel
def supply_shape_kernel(t, phi, omega, i, u, s, p, ds):
    if p[5] < 0.5:
        ds[0] = 0.0
        return 0.0, p[0] * i + p[1] * math.asinh(i / p[2]), 0.0
    ds[0] = (p[3] * i - s[0]) / p[4]
    return 0.0, p[0] * i + s[0], 0.0


class SupplyShape(Effect):
    kind = "truth.supply_shape"
    persistent_states = True
    Params = SupplyShapeParams
    state_names = ("polarization_V",)
    state_units = ("V",)
    kernel = staticmethod(supply_shape_kernel)


# ------------------------------------------------------------------------------------ backlash
@dataclasses.dataclass(frozen=True)
class SoftBacklashParams(Params):
    play_rad: float = 0.005                         # b (profile 0) / play while opening (profile 1)
    closing_play_rad: float = 0.005                 # play below limp-home (profile 1)
    profile: float = 0.0                            # 0 soft contact, 1 asymmetric play
    # the spring's own vector [phi_LH, T_SP0, R_F, eps, c_LH], tied to the truth plant's spring
    limp_home_rad: float = math.radians(3.0)
    preload_Nm: float = 0.15
    rate_Nm_per_rad: float = 0.36
    limp_home_compliance_rad: float = 3e-3
    limp_home_damping_Nm_s_per_rad: float = 0.039

    def validate(self):
        n = "SoftBacklashParams"
        positive(n, self, "play_rad", "limp_home_compliance_rad")
        non_negative(n, self, "closing_play_rad", "preload_Nm", "rate_Nm_per_rad", "limp_home_damping_Nm_s_per_rad")
        _profile(n, self, 2)


@kernel
def soft_backlash_kernel(t, phi, omega, i, u, s, p, ds):
    q = p[3:8]
    d = phi - p[3]
    if p[2] < 0.5:
        shifted = p[3] + d - p[0] * math.tanh(d / p[0])
    elif d > p[0]:
        shifted = phi - p[0]
    elif d < -p[1]:
        shifted = phi + p[1]
    else:
        shifted = p[3]
    t1, e1, l1 = limp_home_spring_kernel(t, shifted, omega, i, u, s, q, ds)
    t0, e0, l0 = limp_home_spring_kernel(t, phi, omega, i, u, s, q, ds)
    return t1 - t0, 0.0, 0.0


class SoftBacklash(Component):
    kind = "truth.soft_backlash"
    role = "effect"
    Params = SoftBacklashParams
    kernel = staticmethod(soft_backlash_kernel)


# ------------------------------------------------------------------------------------ angle-dependent friction
@dataclasses.dataclass(frozen=True)
class AngleFrictionProfileParams(Params):
    level_Nm: float = 0.03                         # a (may be negative: less friction there)
    centre_rad: float = math.radians(40.0)
    width_rad: float = math.radians(6.0)
    profile: float = 0.0                           # 0 Gaussian band, 1 logistic step
    presliding_rad: float = 2e-3                   # last: the unit bristle's presliding distance

    def validate(self):
        positive("AngleFrictionProfileParams", self, "width_rad", "presliding_rad")
        _profile("AngleFrictionProfileParams", self, 2)


@kernel
def angle_friction_profile_kernel(t, phi, omega, i, u, s, p, ds):
    x = (phi - p[1]) / p[2]
    g = p[0] * (math.exp(-0.5 * x * x) if p[3] < 0.5 else sigmoid(x))
    ds[0] = bristle_rate(s[0], omega, 1.0, p[4])
    return -g * s[0] / p[4], 0.0, 0.0


@kernel
def angle_friction_profile_advance(h, t, phi, omega, i, u, s, p):
    s[0] = bristle_advance(s[0], omega, h, 1.0, p[4])


class AngleFrictionProfile(Component):
    kind = "truth.angle_friction_profile"
    role = "effect"
    Params = AngleFrictionProfileParams
    state_names = ("w",)
    state_units = ("rad",)
    kernel = staticmethod(angle_friction_profile_kernel)
    advance = staticmethod(angle_friction_profile_advance)


# ------------------------------------------------------------------------------------ inductance saturation
@dataclasses.dataclass(frozen=True)
class InductanceShapeParams(Params):
    inductance_drop_H: float = 0.002               # dL
    knee_current_A: float = 1.0                    # i_k (profile 0) / i_s (profile 1)
    spread_A: float = 0.5                          # i_w (profile 0)
    profile: float = 0.0                           # 0 knee, 1 linear onset

    def validate(self):
        n = "InductanceShapeParams"
        non_negative(n, self, "inductance_drop_H")
        positive(n, self, "knee_current_A", "spread_A")
        _profile(n, self, 2)


@kernel
def inductance_shape_kernel(t, phi, omega, i, u, s, p, ds):
    a = abs(i)
    if p[3] < 0.5:
        e = a - p[1]
        if e < 0.0:
            e = 0.0
        return 0.0, 0.0, -p[0] * e / (e + p[2])
    return 0.0, 0.0, -p[0] * (1.0 - math.exp(-a / p[1]))


class InductanceShape(Component):
    kind = "truth.inductance_shape"
    role = "effect"
    Params = InductanceShapeParams
    kernel = staticmethod(inductance_shape_kernel)


# ------------------------------------------------------------------------------------ end stop
@dataclasses.dataclass(frozen=True)
class ProgressiveStopParams(Params):
    contact_rad: float = math.radians(88.0)        # phi_b: where the soft contact starts
    stiffness_Nm_per_rad: float = 300.0            # k (secant stiffness at d_ref for profile 0)
    reference_depth_rad: float = math.radians(1.0)  # d_ref (profile 0) / w (profile 1)
    exponent: float = 1.5                          # n (profile 0)
    damping_s_per_rad: float = 0.5                 # c (Hunt-Crossley)
    profile: float = 0.0                           # 0 Hertz-like power, 1 exponential bumper

    def validate(self):
        n = "ProgressiveStopParams"
        positive(n, self, "stiffness_Nm_per_rad", "reference_depth_rad")
        non_negative(n, self, "damping_s_per_rad")
        check(n, "exponent", self.exponent, self.exponent >= 1.0, "an exponent >= 1")
        _profile(n, self, 2)


@kernel
def progressive_stop_kernel(t, phi, omega, i, u, s, p, ds):
    d = phi - p[0]
    if d <= 0.0:
        return 0.0, 0.0, 0.0
    if p[5] < 0.5:
        f = p[1] * d * (d / p[2]) ** (p[3] - 1.0)
    else:
        z = d / p[2]
        f = p[1] * p[2] * (math.exp(z if z < 30.0 else 30.0) - 1.0)
    c = 1.0 + p[4] * omega
    return -f * (c if c > 0.0 else 0.0), 0.0, 0.0


class ProgressiveStop(Component):
    kind = "truth.progressive_stop"
    role = "effect"
    Params = ProgressiveStopParams
    kernel = staticmethod(progressive_stop_kernel)


# ------------------------------------------------------------------------------------ outside the catalogue
@dataclasses.dataclass(frozen=True)
class CurrentRippleParams(Params):
    amplitude_Nm_per_A: float = 0.004              # a
    period_rad: float = math.radians(15.0)         # P
    phase_rad: float = 0.0                         # psi

    def validate(self):
        positive("CurrentRippleParams", self, "period_rad")


@kernel
def current_ripple_kernel(t, phi, omega, i, u, s, p, ds):
    return p[0] * i * math.sin(2.0 * math.pi * phi / p[1] + p[2]), 0.0, 0.0


class CurrentRipple(Component):
    kind = "truth.current_ripple"
    role = "effect"
    Params = CurrentRippleParams
    kernel = staticmethod(current_ripple_kernel)


# ------------------------------------------------------------------------------------ sensor shapes
class SensorShape(Component):
    """A reading-side truth: ``reading_kernel(phi, noise, p, s)`` -> the value [rad] the recording's
    PositionSensor then reads (its gain, offset, delay and quantization as configured). ``s``: the shape's
    own state; :meth:`stream` calls the kernel sample by sample (closed loop), :meth:`apply` on a series."""

    role = "sensor"
    n_state = 0
    resolution_deg = None          # the grid step the shape itself reads with (SensorCodes), else None

    def reset(self, phi0: float = 0.0) -> None:
        self._s = np.full(max(self.n_state, 1), float("nan"))
        self._p = self.param_vector()

    def stream(self, phi: float, noise: float) -> float:
        if not hasattr(self, "_s"):
            self.reset()
        return float(self.reading(float(phi), float(noise), self._p, self._s))

    def apply(self, phi, noise=None) -> np.ndarray:
        phi = np.asarray(phi, float)
        noise = np.zeros_like(phi) if noise is None else np.asarray(noise, float)
        self.reset()
        return np.array([self.stream(a, b) for a, b in zip(phi, noise)])


@dataclasses.dataclass(frozen=True)
class SensorCurveParams(Params):
    offset_rad: float = 0.0                        # o
    bow_rad: float = math.radians(0.2)             # b (profile 0)
    knee_rad: float = math.radians(45.0)           # phi_k (profile 1)
    gain_below: float = 1.0                        # slope of the reading below the knee (profile 1)
    gain_above: float = 1.01                       # and above it
    profile: float = 0.0                           # 0 bowed, 1 two slopes

    def validate(self):
        n = "SensorCurveParams"
        positive(n, self, "gain_below", "gain_above")
        _profile(n, self, 2)


@kernel
def sensor_curve_kernel(phi, noise, p, s):
    if p[5] < 0.5:
        return phi + p[0] + p[1] * math.sin(math.pi * phi / (0.5 * math.pi)) + noise
    if phi < p[2]:
        return p[0] + p[3] * phi + noise
    return p[0] + p[3] * p[2] + p[4] * (phi - p[2]) + noise


class SensorCurve(SensorShape):
    kind = "truth.sensor_curve"
    Params = SensorCurveParams
    reading = staticmethod(sensor_curve_kernel)


@dataclasses.dataclass(frozen=True)
class SensorFilterParams(Params):
    time_constant_s: float = 0.002                 # tau (profile 0)
    average_samples: int = 4                       # N (profile 1)
    sample_time_s: float = 1e-3
    profile: float = 0.0                           # 0 first-order low-pass, 1 moving average

    def validate(self):
        n = "SensorFilterParams"
        positive(n, self, "time_constant_s", "sample_time_s")
        check(n, "average_samples", self.average_samples, 1 <= self.average_samples <= 64, "1 to 64 samples")
        _profile(n, self, 2)


@kernel
def sensor_filter_kernel(phi, noise, p, s):
    # s[0]: filter state (nan before the first sample); s[1:]: ring buffer of the last N angles, s[-1] its slot
    if p[3] < 0.5:
        if s[0] != s[0]:
            s[0] = phi
        a = 1.0 - math.exp(-p[2] / p[0])
        s[0] = s[0] + a * (phi - s[0])
        return s[0] + noise
    n = int(p[1])
    if s[0] != s[0]:
        for k in range(1, n + 1):
            s[k] = phi
        s[0] = 0.0
        s[n + 1] = 0.0
    slot = int(s[n + 1])
    s[1 + slot] = phi
    s[n + 1] = float((slot + 1) % n)
    tot = 0.0
    for k in range(1, n + 1):
        tot += s[k]
    return tot / n + noise


class SensorFilter(SensorShape):
    kind = "truth.sensor_filter"
    Params = SensorFilterParams
    reading = staticmethod(sensor_filter_kernel)

    @property
    def n_state(self):
        return int(self.params.average_samples) + 2


@dataclasses.dataclass(frozen=True)
class SensorCodesParams(Params):
    resolution_rad: float = math.radians(90.0 / 1024)   # q: the mean code width
    nonlinearity: float = 0.4                      # e: every other code is (1 + e) q wide, the next (1 - e) q
    hysteresis: float = 0.5                        # h (profile 1), in codes
    profile: float = 0.0                           # 0 uneven codes, 1 hysteresis

    def validate(self):
        n = "SensorCodesParams"
        positive(n, self, "resolution_rad")
        check(n, "nonlinearity", self.nonlinearity, 0.0 <= self.nonlinearity < 0.9, "a value in [0, 0.9)")
        check(n, "hysteresis", self.hysteresis, 0.0 <= self.hysteresis <= 1.0, "a value in [0, 1]")
        _profile(n, self, 2)


@kernel
def sensor_codes_kernel(phi, noise, p, s):
    q = p[0]
    v = phi + noise
    if p[3] < 0.5:
        # pairs of codes 2q wide; inside a pair the boundary sits at (1 + e) q instead of q
        pair = math.floor(v / (2.0 * q))
        r = v - pair * 2.0 * q
        k = 2.0 * pair + (0.0 if r < (1.0 + p[1]) * q else 1.0)
        return (k + 0.5) * q
    if s[0] != s[0]:
        s[0] = q * round(v / q)
    if v > s[0] + (0.5 + p[2]) * q or v < s[0] - (0.5 + p[2]) * q:
        s[0] = q * round(v / q)
    return s[0]


class SensorCodes(SensorShape):
    kind = "truth.sensor_codes"
    Params = SensorCodesParams
    reading = staticmethod(sensor_codes_kernel)
    n_state = 1

    @property
    def resolution_deg(self):
        return math.degrees(self.params.resolution_rad)


SPRING_TIED = ("limp_home_rad", "preload_Nm", "rate_Nm_per_rad", "limp_home_compliance_rad",
               "limp_home_damping_Nm_s_per_rad")


def tie_to_spring(effect, plant):
    """``effect`` with its copies of the spring's parameters set to ``plant``'s (truth shapes that reuse the
    spring kernel or act relative to limp-home)."""
    sp = plant.spring.params.to_dict() if plant.spring is not None else {}
    names = {f.name for f in dataclasses.fields(effect.params)}
    over = {k: sp[k] for k in SPRING_TIED if k in names and k in sp}
    return effect.with_params(**over) if over else effect
