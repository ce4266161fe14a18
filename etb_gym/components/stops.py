"""End stops at closed and fully open as stiff, damped, one-sided contacts (no state clipping).

    penetration  d_lo = phi_min - phi,  d_hi = phi - phi_max
    T_stop = +max(0, k*d_lo - c*omega)   if d_lo > 0      (pushes open)
             -max(0, k*d_hi + c*omega)   if d_hi > 0      (pushes closed)

The max(0, .) keeps the contact from pulling the plate back into the stop as it leaves.
Defaults: k = 1000 Nm/rad (0.075 deg penetration at rest under the full 1.3 Nm stall torque; an impact at
100-160 rad/s penetrates up to ~0.8 deg for a fraction of a millisecond), c = 0.1 Nm*s/rad
(damping ratio ~0.3 with J = 30e-6 kg m^2, coefficient of restitution ~0.37).
"""
from __future__ import annotations

import dataclasses
import math

from ..integrate import RHO_STIFF
from ..jit import kernel
from .base import Component, Params, check, crossing, non_negative, positive


@dataclasses.dataclass(frozen=True)
class EndStopsParams(Params):
    closed_rad: float = 0.0
    open_rad: float = math.radians(90.0)
    stiffness_Nm_per_rad: float = 1000.0
    damping_Nm_s_per_rad: float = 0.1

    def validate(self):
        n = "EndStopsParams"
        positive(n, self, "stiffness_Nm_per_rad")
        non_negative(n, self, "damping_Nm_s_per_rad")
        check(n, "open_rad", self.open_rad, self.open_rad > self.closed_rad,
              f"open stop > closed stop ({self.closed_rad} rad)")


@kernel
def end_stops_kernel(t, phi, omega, i, u, s, p, ds):
    # p = [phi_min, phi_max, k, c]
    d = p[0] - phi
    if d > 0.0:
        f = p[2] * d - p[3] * omega
        return (f if f > 0.0 else 0.0), 0.0, 0.0
    d = phi - p[1]
    if d > 0.0:
        f = p[2] * d + p[3] * omega
        return -(f if f > 0.0 else 0.0), 0.0, 0.0
    return 0.0, 0.0, 0.0


@kernel
def end_stops_edges(phi0, omega0, phi1, omega1, p):
    """Where the contact force jumps (by c*omega, the damping, as the plate enters or leaves a stop)."""
    a = crossing(phi0, phi1, p[0])
    b = crossing(phi0, phi1, p[1])
    return a if a < b else b


FAR_BEYOND_RAD = 0.5   # a plate this far beyond a stop (29 deg; an impact penetrates < 1 deg) is not physical


@kernel
def end_stops_plausible(phi, omega, i, supply_V, p):
    return p[0] - FAR_BEYOND_RAD <= phi <= p[1] + FAR_BEYOND_RAD


IMPACT_ENERGY_J = 1e-3   # a contact with more energy than this is an impact: integrated in pieces


@kernel
def end_stops_rate(phi, omega, J, p):
    """sqrt(k/J) during an impact (in a stop with kinetic + elastic energy above IMPACT_ENERGY_J: a plate at
    100 rad/s carries 0.15 J); -sqrt(k/J) in a slow contact that presses (a plate resting in a stop: smooth, but
    as stiff as an impact: a substep too long for it is cut into pieces, integrate.py "Contacts"); else 0."""
    d = p[0] - phi
    s = -1.0                     # the sign of the damping term in the contact force: -c omega closed, +c omega open
    if d <= 0.0:
        d = phi - p[1]
        s = 1.0
    if d > 0.0:
        if J * omega * omega + p[2] * d * d > 2.0 * IMPACT_ENERGY_J:
            return math.sqrt(p[2] / J)
        if p[2] * d + s * p[3] * omega > 0.0:
            return -slow_contact_rate(p[2], p[3], J)
    return 0.0


@kernel
def slow_contact_rate(k, c, J):
    """The rate a slow stiff contact reports (integrate.py, "Contacts"): sqrt(k/J), raised where its damping ratio
    zeta = c / (2 sqrt(k J)) is light. The explicit midpoint rule grows an oscillation of h sqrt(k/J) = y by
    about y^4/8 per step and its damping takes zeta*y off, so it is stable only for y^3 < 8 zeta; the stepper's
    pieces have y <= RHO_STIFF, so the rate is raised by RHO_STIFF / (8 zeta)^(1/3) where that exceeds 1
    (zeta < 0.216: from 0.1 to 0.02 Nm s/rad at the default k and J). zeta is floored at 1e-3 (an undamped
    contact: pieces of y <= 0.2)."""
    r = math.sqrt(k / J)
    zeta = c / (2.0 * math.sqrt(k * J))
    if zeta < 1e-3:
        zeta = 1e-3
    f = RHO_STIFF / (8.0 * zeta) ** (1.0 / 3.0)
    if f > 1.0:
        return r * f
    return r


class EndStops(Component):
    kind = "stops.contact"
    role = "stops"
    Params = EndStopsParams
    kernel = staticmethod(end_stops_kernel)
    edges = staticmethod(end_stops_edges)
    plausible = staticmethod(end_stops_plausible)
    rate = staticmethod(end_stops_rate)
    description = "end stops at closed and fully open (stiff damped contacts)"
