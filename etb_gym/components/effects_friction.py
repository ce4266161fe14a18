"""Candidate friction effects (diagnosis library, docs/diagnosis.md): extra friction with its own bristle.

    stribeck_friction         extra stiction dT_s that vanishes with speed (the Stribeck drop):
                              g(omega) = dT_s exp(-|omega/omega_s|^delta)  (friction.stribeck_curve with T_c = 0;
                              the exponent delta defaults to 0.5, exp(-sqrt), the form before it was a field)
                              dz/dt = omega - sigma0 |omega| z / g,   T = -sigma0 z
    angle_dependent_friction  Coulomb friction that varies along the stroke, x = phi / (pi/2):
                              dT(x) = a1 (x - 1/2) + a2 ((x - 1/2)^2 - 1/12)   (zero mean over the stroke:
                              the mean level is the nominal friction the calibration fits)
                              dw/dt = (omega - |omega| w) / delta,   T = -dT(x) w   (w in [-1, 1], presliding delta)

Both states are updated exactly for the frozen velocity of a substep (friction.bristle_advance).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..jit import kernel
from .base import non_negative, positive
from .base import Params
from .effects_electrical import Effect
from .friction import bristle_advance, bristle_rate, stribeck_curve

G_MIN_NM = 1e-12


# ------------------------------------------------------------------------------------ Stribeck
@dataclasses.dataclass(frozen=True)
class StribeckFrictionParams(Params):
    stiction_Nm: float = 0.0                    # dT_s: breakaway torque beyond the nominal friction
    stribeck_velocity_rad_s: float = 0.05       # omega_s of the extra stiction
    bristle_stiffness_Nm_per_rad: float = 100.0  # sigma0 of the extra bristle
    exponent: float = 0.5                       # delta: the drop's shape (0.5 exp(-sqrt), 1 exponential, 2 Gaussian)

    def validate(self):
        n = "StribeckFrictionParams"
        non_negative(n, self, "stiction_Nm")
        positive(n, self, "stribeck_velocity_rad_s", "bristle_stiffness_Nm_per_rad", "exponent")


@kernel
def stribeck_level(omega, p):
    """g(omega) of the extra stiction (kept above G_MIN_NM so the bristle equation stays regular)."""
    g = stribeck_curve(omega, 0.0, p[0], p[1], p[3])
    if g < G_MIN_NM:
        g = G_MIN_NM
    return g


@kernel
def stribeck_friction_kernel(t, phi, omega, i, u, s, p, ds):
    ds[0] = bristle_rate(s[0], omega, p[2], stribeck_level(omega, p))
    return -p[2] * s[0], 0.0, 0.0


@kernel
def stribeck_friction_advance(h, t, phi, omega, i, u, s, p):
    s[0] = bristle_advance(s[0], omega, h, p[2], stribeck_level(omega, p))


class StribeckFriction(Effect):
    kind = "effect.stribeck_friction"
    effect_id = "stribeck_friction"
    Params = StribeckFrictionParams
    state_names = ("z_rad",)
    state_units = ("rad",)
    kernel = staticmethod(stribeck_friction_kernel)
    advance = staticmethod(stribeck_friction_advance)
    description = "stiction and Stribeck drop beyond the nominal friction"


# ------------------------------------------------------------------------------------ angle-dependent
@dataclasses.dataclass(frozen=True)
class AngleDependentFrictionParams(Params):
    slope_Nm: float = 0.0                       # a1: change of the Coulomb level from closed to open
    curvature_Nm: float = 0.0                   # a2
    presliding_rad: float = 2e-3                # delta

    def validate(self):
        positive("AngleDependentFrictionParams", self, "presliding_rad")


@kernel
def angle_friction_level(phi, a1, a2):
    x = phi / (0.5 * np.pi) - 0.5
    return a1 * x + a2 * (x * x - 1.0 / 12.0)


@kernel
def unit_bristle_friction(level, omega, s, ds, delta):
    """A friction level ``level`` [N m] acting through a unit bristle w (presliding distance ``delta``):
    dw/dt = (omega - |omega| w) / delta, torque -level w. Returns the torque, writes dw/dt to ``ds[0]``."""
    ds[0] = bristle_rate(s[0], omega, 1.0, delta)
    return -level * s[0] / delta


@kernel
def unit_bristle_advance(h, t, phi, omega, i, u, s, p):
    """The exact update of a unit bristle; its presliding distance is the last parameter of every
    unit-bristle component (angle_dependent_friction and the friction maps)."""
    s[0] = bristle_advance(s[0], omega, h, 1.0, p[p.size - 1])


@kernel
def angle_dependent_friction_kernel(t, phi, omega, i, u, s, p, ds):
    return unit_bristle_friction(angle_friction_level(phi, p[0], p[1]), omega, s, ds, p[2]), 0.0, 0.0


class AngleDependentFriction(Effect):
    kind = "effect.angle_dependent_friction"
    effect_id = "angle_dependent_friction"
    Params = AngleDependentFrictionParams
    state_names = ("z_rad",)
    state_units = ("rad",)
    kernel = staticmethod(angle_dependent_friction_kernel)
    advance = staticmethod(unit_bristle_advance)
    description = "friction that varies with plate angle"
