"""Candidate mechanical effects (diagnosis library, docs/diagnosis.md): torques added to the shaft.

The spring and stop corrections reuse the core kernels (spring.py, stops.py), so the equation of a
spring or a stop exists once; their ``nominal_*``/tied fields repeat the plant's own spring/stop
parameters (the diagnosis keeps them equal when it refits the nominal parameters):

    spring_asymmetry     below limp-home (d = phi - phi_LH < 0) the closing spring has preload
                         T_SP0 + dT_SP0 and rate R_F + dR_F:  T += spring_kernel(phi; dT_SP0, dR_F) for d < 0
    backlash             free play between the spring arms around limp-home, b above it and r*b below it
                         (r = 1: symmetric; the lever need not rest in the play's middle): the springs act as
                         if at d' = d - b (d > b) or d + r b (d < -r b), not at all within the play:
                         T += spring_kernel(phi_LH + d') - spring_kernel(phi)
    end_stop_compliance  stops at other angles / stiffness: T += stops_kernel(new) - stops_kernel(nominal)
    airflow_torque       T = c2 x^2 + c3 x^3,  x = phi / (pi/2)  (aerodynamic torque of the air flow)

The spring and stop corrections declare the angles where their torque jumps (a contact's damping switching
on) as ``edges`` and the compliant stop its impact ``rate``, so the stepper splits a substep at the crossing
and cuts impacts into pieces as it does for the plant's own stops and limp-home band (integrate.py, "Contacts").
"""
from __future__ import annotations

import dataclasses
import math

from ..jit import kernel
from .base import Params, crossing, non_negative, positive
from .effects_electrical import Effect
from .spring import limp_home_spring_edges, limp_home_spring_kernel
from .stops import end_stops_edges, end_stops_kernel, end_stops_rate


# ------------------------------------------------------------------------------------ spring asymmetry
@dataclasses.dataclass(frozen=True)
class SpringAsymmetryParams(Params):
    # field order = the spring kernel's vector [phi_LH, T_SP0, R_F, eps, c_LH]
    limp_home_rad: float = math.radians(3.0)         # tied: spring.limp_home_rad
    closing_preload_delta_Nm: float = 0.0            # dT_SP0 below limp-home
    closing_rate_delta_Nm_per_rad: float = 0.0       # dR_F below limp-home
    limp_home_compliance_rad: float = 3e-3           # tied: spring.limp_home_compliance_rad
    closing_damping_delta_Nm_s_per_rad: float = 0.0

    def validate(self):
        positive("SpringAsymmetryParams", self, "limp_home_compliance_rad")


@kernel
def spring_asymmetry_kernel(t, phi, omega, i, u, s, p, ds):
    # the extra closing spring acts below limp-home only
    if phi >= p[0]:
        return 0.0, 0.0, 0.0
    tq, e, l = limp_home_spring_kernel(t, phi, omega, i, u, s, p, ds)
    return tq, 0.0, 0.0


@kernel
def spring_asymmetry_edges(phi0, omega0, phi1, omega1, p):
    """Where the torque jumps: at phi_LH (the extra spring's damping switches off above it) and phi_LH - eps.
    None with all deltas zero: a zero-magnitude effect changes nothing, not even the substep split."""
    if p[1] == 0.0 and p[2] == 0.0 and p[4] == 0.0:
        return 2.0
    a = crossing(phi0, phi1, p[0])
    b = crossing(phi0, phi1, p[0] - p[3])
    return a if a < b else b


class SpringAsymmetry(Effect):
    kind = "effect.spring_asymmetry"
    effect_id = "spring_asymmetry"
    Params = SpringAsymmetryParams
    kernel = staticmethod(spring_asymmetry_kernel)
    edges = staticmethod(spring_asymmetry_edges)
    description = "spring preload or rate differs below and above limp-home"


# ------------------------------------------------------------------------------------ backlash
@dataclasses.dataclass(frozen=True)
class BacklashParams(Params):
    play_rad: float = 0.0                            # b: the free play above limp-home (opening)
    limp_home_rad: float = math.radians(3.0)         # tied to the plant's spring
    preload_Nm: float = 0.15
    rate_Nm_per_rad: float = 0.36
    limp_home_compliance_rad: float = 3e-3
    limp_home_damping_Nm_s_per_rad: float = 0.039
    closing_ratio: float = 1.0                       # r: the play below limp-home (closing) is r*b

    def validate(self):
        n = "BacklashParams"
        non_negative(n, self, "play_rad", "preload_Nm", "rate_Nm_per_rad", "limp_home_damping_Nm_s_per_rad",
                     "closing_ratio")
        positive(n, self, "limp_home_compliance_rad")


@kernel
def backlash_kernel(t, phi, omega, i, u, s, p, ds):
    # p = [b, phi_LH, T_SP0, R_F, eps, c_LH, r]; p[1:6] is the spring's own vector
    q = p[1:6]
    d = phi - p[1]
    b = p[0]
    bc = p[6] * b
    if d > b:
        shifted = phi - b
    elif d < -bc:
        shifted = phi + bc
    else:
        shifted = p[1]
    t1, e1, l1 = limp_home_spring_kernel(t, shifted, omega, i, u, s, q, ds)
    t0, e0, l0 = limp_home_spring_kernel(t, phi, omega, i, u, s, q, ds)
    return t1 - t0, 0.0, 0.0


@kernel
def backlash_edges(phi0, omega0, phi1, omega1, p):
    """Where the torque jumps (integrate.py "Contacts"): the shifted spring damps (c_LH*omega) while
    -r b - eps < phi - phi_LH < b + eps (the play and its contact band), the subtracted spring at phi_LH +- eps."""
    a = crossing(phi0, phi1, p[1] - (p[6] * p[0] + p[4]))     # grouped as before r: r = 1 steps bit for bit
    b = crossing(phi0, phi1, p[1] + (p[0] + p[4]))
    c = limp_home_spring_edges(phi0, omega0, phi1, omega1, p[1:6])
    if b < a:
        a = b
    return a if a < c else c


class Backlash(Effect):
    kind = "effect.backlash"
    effect_id = "backlash"
    Params = BacklashParams
    kernel = staticmethod(backlash_kernel)
    edges = staticmethod(backlash_edges)
    description = "free play around limp-home (the return springs engage late)"


# ------------------------------------------------------------------------------------ end stops
@dataclasses.dataclass(frozen=True)
class EndStopComplianceParams(Params):
    closed_rad: float = 0.0                          # true stop positions and contact
    open_rad: float = math.radians(90.0)
    stiffness_Nm_per_rad: float = 1000.0
    damping_Nm_s_per_rad: float = 0.1
    nominal_closed_rad: float = 0.0                  # tied: the plant's stops
    nominal_open_rad: float = math.radians(90.0)
    nominal_stiffness_Nm_per_rad: float = 1000.0
    nominal_damping_Nm_s_per_rad: float = 0.1

    def validate(self):
        n = "EndStopComplianceParams"
        positive(n, self, "stiffness_Nm_per_rad", "nominal_stiffness_Nm_per_rad")
        non_negative(n, self, "damping_Nm_s_per_rad", "nominal_damping_Nm_s_per_rad")


@kernel
def end_stop_compliance_kernel(t, phi, omega, i, u, s, p, ds):
    t1, e1, l1 = end_stops_kernel(t, phi, omega, i, u, s, p[0:4], ds)
    t0, e0, l0 = end_stops_kernel(t, phi, omega, i, u, s, p[4:8], ds)
    return t1 - t0, 0.0, 0.0


@kernel
def end_stop_compliance_edges(phi0, omega0, phi1, omega1, p):
    """Where the torque jumps: the true stops (added) and the nominal ones (subtracted)."""
    a = end_stops_edges(phi0, omega0, phi1, omega1, p[0:4])
    b = end_stops_edges(phi0, omega0, phi1, omega1, p[4:8])
    return a if a < b else b


@kernel
def end_stop_compliance_rate(phi, omega, J, p):
    """The true stops' impact rate sqrt(k/J) (the nominal contact it removes is the plant's EndStops')."""
    return end_stops_rate(phi, omega, J, p[0:4])


class EndStopCompliance(Effect):
    kind = "effect.end_stop_compliance"
    effect_id = "end_stop_compliance"
    Params = EndStopComplianceParams
    kernel = staticmethod(end_stop_compliance_kernel)
    edges = staticmethod(end_stop_compliance_edges)
    rate = staticmethod(end_stop_compliance_rate)
    description = "end stops softer or at other angles than modelled"


# ------------------------------------------------------------------------------------ airflow
@dataclasses.dataclass(frozen=True)
class AirflowTorqueParams(Params):
    quadratic_Nm: float = 0.0                        # c2 (opening positive)
    cubic_Nm: float = 0.0                            # c3


@kernel
def airflow_torque_kernel(t, phi, omega, i, u, s, p, ds):
    x = phi / (0.5 * math.pi)
    if x < 0.0:
        x = 0.0
    return x * x * (p[0] + p[1] * x), 0.0, 0.0


class AirflowTorque(Effect):
    kind = "effect.airflow_torque"
    effect_id = "airflow_torque"
    Params = AirflowTorqueParams
    kernel = staticmethod(airflow_torque_kernel)
    description = "aerodynamic torque of the air flow on the plate"
