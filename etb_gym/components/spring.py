"""Return springs and the limp-home discontinuity (paper sec. 3.2 and 5.1, eq. 19).

Two preloaded torsion springs of equal rate R_F hold the plate at limp-home phi_LH:

    T_sp = R_F*(phi - phi_LH) + T_SP0 * sat((phi - phi_LH) / eps) + c_LH*omega*[|phi - phi_LH| < eps]
                                                                         (torque on the shaft: -T_sp)

sat(x) = clip(x, -1, 1). With eps -> 0 this is eq. 19 (centred on phi_LH, see docs/model.md); eps is the
compliance of the limp-home contact between the two spring arms (default 3 mrad = 0.17 deg), which
keeps the discontinuity integrable at a fixed step: a physical stiffness of T_SP0/eps = 50 Nm/rad.
While the arms are in that contact band they also dissipate (c_LH, damping ratio ~0.5 of the contact),
as the arms of a real limp-home mechanism do when they meet; without it a frictionless plate (model 1)
rattles on the contact at 200 Hz.
"""
from __future__ import annotations

import dataclasses
import math

from ..jit import kernel
from .base import Component, Params, crossing, non_negative, positive


@dataclasses.dataclass(frozen=True)
class LimpHomeSpringParams(Params):
    limp_home_rad: float = math.radians(3.0)      # phi_LH
    preload_Nm: float = 0.15                      # T_SP0
    rate_Nm_per_rad: float = 0.36                 # R_F: printed 0.36 "Nmm/degree", read as 0.36 Nm/rad
    limp_home_compliance_rad: float = 3e-3        # eps
    limp_home_damping_Nm_s_per_rad: float = 0.039  # c_LH = 2*0.5*sqrt(J*T_SP0/eps)

    def validate(self):
        n = "LimpHomeSpringParams"
        non_negative(n, self, "preload_Nm", "rate_Nm_per_rad", "limp_home_damping_Nm_s_per_rad")
        positive(n, self, "limp_home_compliance_rad")


@kernel
def limp_home_spring_kernel(t, phi, omega, i, u, s, p, ds):
    # p = [phi_LH, T_SP0, R_F, eps, c_LH]
    d = phi - p[0]
    x = d / p[3]
    c = 0.0
    if x > 1.0:
        x = 1.0
    elif x < -1.0:
        x = -1.0
    else:
        c = p[4] * omega
    return -(p[2] * d + p[1] * x + c), 0.0, 0.0


@kernel
def limp_home_spring_edges(phi0, omega0, phi1, omega1, p):
    """The edges of the limp-home contact band, where its damping c_LH*omega switches on and off."""
    a = crossing(phi0, phi1, p[0] - p[3])
    b = crossing(phi0, phi1, p[0] + p[3])
    return a if a < b else b


class LimpHomeSpring(Component):
    kind = "spring.limp_home"
    role = "spring"
    Params = LimpHomeSpringParams
    kernel = staticmethod(limp_home_spring_kernel)
    edges = staticmethod(limp_home_spring_edges)
    description = "two preloaded return springs meeting at limp-home (eq. 19)"
