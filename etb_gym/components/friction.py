"""Friction models of the mechanical subsystem (paper sec. 5): 1 viscous, 2 Dahl, 3 LuGre.

    1 viscous (eq. 21)    T_f = sigma2 * omega
    2 Dahl (eqs. 23-25)   T_f = sigma0 * z,  dz/dt = omega - sigma0*|omega|*z / T_c
    3 LuGre (eqs. 26-28)  T_f = sigma0*z + sigma1*dz/dt + sigma2*omega
                          dz/dt = omega - sigma0*|omega|*z / g(omega)
                          g(omega) = T_c + (T_s - T_c) * exp(-sqrt(|omega / omega_s|))

T_f opposes motion: the kernel returns -T_f as its torque on the shaft. z is the bristle deflection [rad].

Fixed-step update of z (``advance``): for the velocity of the step frozen, dz/dt = omega - a*z with
a = sigma0*|omega|/g is linear in z and is solved exactly, z <- z_ss + (z - z_ss)*exp(-a*h) with
z_ss = omega/a, so the stiff bristle state stays bounded at any speed and any step. LuGre's g(omega) is
its *carry* (components/base.py): the stepper evaluates it once per substep, at the new velocity, for the
bristle update and for the next substep's kernel, which sees that same velocity (the same bits as
evaluating it in both).

LuGre's bristle damping sigma1*dz/dt is the stiffest decaying mode of the shaft (2 sigma1/J = 7333 1/s right
after a velocity reversal); it declares it as its ``damping`` (components/base.py), which the stepper takes
exponentially where the substep is too long for the explicit rule (integrate.py, "Damping").
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..jit import kernel
from .base import Component, Params, check, non_negative, positive

NMM = 1e-3  # N*mm in N*m


@dataclasses.dataclass(frozen=True)
class ViscousFrictionParams(Params):
    # paper: sigma2 = 0.017 "Nms/degree"; read as N*mm*s/degree = 9.74e-4 N*m*s/rad (docs/model.md)
    viscous_Nm_s_per_rad: float = 0.017 * NMM * 180.0 / math.pi

    def validate(self):
        non_negative("ViscousFrictionParams", self, "viscous_Nm_s_per_rad")


@kernel
def viscous_friction_kernel(t, phi, omega, i, u, s, p, ds):
    return -p[0] * omega, 0.0, 0.0


class ViscousFriction(Component):
    kind = "friction.viscous"
    role = "friction"
    Params = ViscousFrictionParams
    kernel = staticmethod(viscous_friction_kernel)
    description = "1: viscous friction sigma2*omega (sec. 5.1, eq. 21)"


@dataclasses.dataclass(frozen=True)
class DahlFrictionParams(Params):
    coulomb_Nm: float = 0.2                    # T_c = T_s (eq. 25)
    bristle_stiffness_Nm_per_rad: float = 100.0  # sigma0 (not given by the paper)
    viscous_Nm_s_per_rad: float = 0.0          # the paper's Dahl model has no viscous term

    def validate(self):
        n = "DahlFrictionParams"
        positive(n, self, "coulomb_Nm", "bristle_stiffness_Nm_per_rad")
        non_negative(n, self, "viscous_Nm_s_per_rad")


@kernel
def bristle_rate(z, omega, sigma0, g):
    """dz/dt = omega - sigma0*|omega|*z/g: the bristle (presliding) state of every friction model with one
    (Dahl: g = T_c; LuGre: g = the Stribeck curve; the diagnosis' unit bristles: sigma0 = 1, g = delta)."""
    return omega - sigma0 * abs(omega) * z / g


@kernel
def dahl_friction_kernel(t, phi, omega, i, u, s, p, ds):
    # p = [T_c, sigma0, sigma2]
    z = s[0]
    ds[0] = bristle_rate(z, omega, p[1], p[0])
    return -(p[1] * z + p[2] * omega), 0.0, 0.0


@kernel
def bristle_advance(z, omega, h, sigma0, g):
    """Exact update of dz/dt = bristle_rate(z, omega, sigma0, g) over h for frozen omega."""
    a = sigma0 * abs(omega) / g
    ah = a * h
    if ah < 1e-12:
        return z + h * omega
    zss = omega / a
    return zss + (z - zss) * math.exp(-ah)


@kernel
def dahl_friction_advance(h, t, phi, omega, i, u, s, p):
    s[0] = bristle_advance(s[0], omega, h, p[1], p[0])


class DahlFriction(Component):
    kind = "friction.dahl"
    role = "friction"
    Params = DahlFrictionParams
    state_names = ("z_rad",)
    state_units = ("rad",)
    kernel = staticmethod(dahl_friction_kernel)
    advance = staticmethod(dahl_friction_advance)
    description = "2: Dahl friction (sec. 5.2, eqs. 23-25)"

    def rest_state(self, s, held_torque_Nm):
        q = self.params
        return np.array([np.clip(held_torque_Nm, -q.coulomb_Nm, q.coulomb_Nm) / q.bristle_stiffness_Nm_per_rad])


@dataclasses.dataclass(frozen=True)
class LuGreFrictionParams(Params):
    coulomb_Nm: float = 0.2                     # T_c
    static_Nm: float = 0.22                     # T_s
    stribeck_velocity_rad_s: float = 0.05       # omega_s (not given by the paper)
    bristle_stiffness_Nm_per_rad: float = 100.0  # sigma0 (not given)
    bristle_damping_Nm_s_per_rad: float = 0.11  # sigma1 (not given): critical damping 2*sqrt(sigma0*J)
    viscous_Nm_s_per_rad: float = 0.017 * NMM * 180.0 / math.pi  # sigma2

    def validate(self):
        n = "LuGreFrictionParams"
        positive(n, self, "coulomb_Nm", "static_Nm", "stribeck_velocity_rad_s", "bristle_stiffness_Nm_per_rad")
        non_negative(n, self, "bristle_damping_Nm_s_per_rad", "viscous_Nm_s_per_rad")
        check(n, "static_Nm", self.static_Nm, self.static_Nm >= self.coulomb_Nm,
              f"T_s >= T_c = coulomb_Nm = {self.coulomb_Nm}")


@kernel
def stribeck_curve(omega, Tc, Ts, ws, delta):
    """g(omega) = T_c + (T_s - T_c) exp(-|omega / omega_s|^delta): eq. 28 with the Stribeck exponent delta (the
    paper's square root is delta = 0.5; the literature's exponential 1 and Gaussian 2, Armstrong-Helouvry 1994,
    Olsson et al. 1998). delta = 0.5 and 1 take sqrt and abs, so a plant without an exponent keeps its bits."""
    x = abs(omega / ws)
    if delta == 0.5:
        y = math.sqrt(x)
    elif delta == 1.0:
        y = x
    else:
        y = x ** delta
    return Tc + (Ts - Tc) * math.exp(-y)


@kernel
def lugre_stribeck(phi, omega, i, p):
    """The carried value of LuGre (components/base.py): g(omega), which the kernel and the advance share."""
    return stribeck_curve(omega, p[0], p[1], p[2], 0.5)


@kernel
def lugre_friction_kernel(t, phi, omega, i, u, s, p, ds, g):
    # p = [T_c, T_s, omega_s, sigma0, sigma1, sigma2]; g = lugre_stribeck(phi, omega, i, p)
    z = s[0]
    dz = bristle_rate(z, omega, p[3], g)
    ds[0] = dz
    return -(p[3] * z + p[4] * dz + p[5] * omega), 0.0, 0.0


@kernel
def lugre_friction_advance(h, t, phi, omega, i, u, s, p, g):
    s[0] = bristle_advance(s[0], omega, h, p[3], g)


@kernel
def lugre_damping(phi, omega, i, s, p, g):
    """The damping of LuGre's torque for z frozen (components/base.py, ``damping``): -dT_f/domega =
    sigma1*(1 - sigma0*sign(omega)*z/g) + sigma2 (g' neglected; sigma1 + sigma2 at omega = 0): 2 sigma1 + sigma2
    right after a reversal (the bristles still deflected the old way), about sigma2 in steady sliding."""
    sg = 0.0
    if omega > 0.0:
        sg = 1.0
    elif omega < 0.0:
        sg = -1.0
    return p[4] * (1.0 - p[3] * sg * s[0] / g) + p[5]


class LuGreFriction(Component):
    kind = "friction.lugre"
    role = "friction"
    Params = LuGreFrictionParams
    state_names = ("z_rad",)
    state_units = ("rad",)
    kernel = staticmethod(lugre_friction_kernel)
    advance = staticmethod(lugre_friction_advance)
    carry = staticmethod(lugre_stribeck)     # g(omega), computed once per substep (components/base.py)
    damping = staticmethod(lugre_damping)    # the bristle damping, up to 2 sigma1 (integrate.py, "Damping")
    description = "3: LuGre friction (sec. 5.3, eqs. 26-28)"

    def rest_state(self, s, held_torque_Nm):
        q = self.params
        return np.array([np.clip(held_torque_Nm, -q.static_Nm, q.static_Nm) / q.bristle_stiffness_Nm_per_rad])


FRICTIONS = {"1": ViscousFriction, "2": DahlFriction, "3": LuGreFriction}
