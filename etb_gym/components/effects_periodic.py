"""A torque periodic in angle, learned from the data as a truncated Fourier series (docs/diagnosis-shapes.md).

    periodic_angle_torque   T = sum_h [(a_h + c_h i) cos(h theta) + (b_h + d_h i) sin(h theta)],
                            theta = 2 pi phi / P,  h = 1 .. H

The part a_h, b_h [N m] is a torque of the angle alone (a detent or cogging torque, a notched cam); the part
c_h, d_h [N m/A] scales with the coil current (a torque ripple of the commutation or of the magnet's poles).
The phase reference is the plant's angle 0 (the closed stop's side of the stroke), so the series holds at
every angle, also those the recordings that taught it never visited: unlike a lookup table
(``effects_maps.AngleTorqueMap``), it carries the period on over the whole stroke. It drops no voltage
(a torque ripple with a back-EMF of its own would add c_h omega, d_h omega to the coil loop; the diagnosis
does not fit that). Either part may be all zeros. A periodic torque has zero mean over a period: a torque
offset or trend belongs to the spring, not here.

Parameters carry their unit in the field name; the four coefficient lists hold one value per harmonic
(the same length H >= 1, harmonic 1 first).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..jit import kernel
from .base import Params, check, positive
from .effects_electrical import Effect

COEFFICIENT_FIELDS = ("cos_Nm", "sin_Nm", "cos_Nm_per_A", "sin_Nm_per_A")


@dataclasses.dataclass(frozen=True)
class PeriodicAngleTorqueParams(Params):
    period_rad: float = math.radians(15.0)           # P
    cos_Nm: tuple = (0.0,)                           # a_h: torque of the angle alone, cosine terms
    sin_Nm: tuple = (0.0,)                           # b_h: ... sine terms
    cos_Nm_per_A: tuple = (0.0,)                     # c_h: torque per ampere of coil current, cosine terms
    sin_Nm_per_A: tuple = (0.0,)                     # d_h: ... sine terms

    def validate(self):
        owner = "PeriodicAngleTorqueParams"
        positive(owner, self, "period_rad")
        n = None
        for f in COEFFICIENT_FIELDS:
            v = getattr(self, f)
            try:
                a = np.asarray(v, float)
            except (TypeError, ValueError):
                raise ValueError(f"{owner}.{f} = {v!r} is invalid: expected a list of numbers, one per "
                                 "harmonic") from None
            check(owner, f, v, a.ndim == 1 and a.size >= 1, "a list of at least one number (one per harmonic)")
            check(owner, f, v, bool(np.all(np.isfinite(a))), "finite numbers")
            if n is None:
                n = a.size
            check(owner, f, v, a.size == n, f"one value per harmonic, as many as cos_Nm ({n})")
            object.__setattr__(self, f, tuple(float(x) for x in a))

    def __hash__(self):
        return hash(tuple(getattr(self, f.name) for f in dataclasses.fields(self)))

    @property
    def harmonics(self) -> int:
        return len(self.cos_Nm)


@kernel
def periodic_angle_torque_kernel(t, phi, omega, i, u, s, p, ds):
    # p = [H, P, a_1..a_H, b_1..b_H, c_1..c_H, d_1..d_H]
    n = int(p[0])
    th = 2.0 * math.pi * phi / p[1]
    tq = 0.0
    for h in range(1, n + 1):
        c = math.cos(h * th)
        sn = math.sin(h * th)
        tq += (p[1 + h] + i * p[1 + 2 * n + h]) * c + (p[1 + n + h] + i * p[1 + 3 * n + h]) * sn
    return tq, 0.0, 0.0


class PeriodicAngleTorque(Effect):
    kind = "effect.periodic_angle_torque"
    effect_id = "periodic_angle_torque"
    Params = PeriodicAngleTorqueParams
    kernel = staticmethod(periodic_angle_torque_kernel)
    description = "torque periodic in angle (optionally proportional to current), a Fourier series learned from the data"

    def param_vector(self):
        q = self.params
        return np.concatenate([[float(q.harmonics), q.period_rad]] + [np.asarray(getattr(q, f), float)
                                                                        for f in COEFFICIENT_FIELDS])

    def torque(self, phi_rad, current_A=0.0) -> np.ndarray:
        """T [N m] at the angles ``phi_rad`` and currents ``current_A`` (numpy, broadcast)."""
        q = self.params
        th = 2.0 * math.pi * np.asarray(phi_rad, float) / q.period_rad
        i = np.asarray(current_A, float)
        out = np.zeros(np.broadcast(th, i).shape)
        for h in range(1, q.harmonics + 1):
            out = out + (q.cos_Nm[h - 1] + i * q.cos_Nm_per_A[h - 1]) * np.cos(h * th) \
                + (q.sin_Nm[h - 1] + i * q.sin_Nm_per_A[h - 1]) * np.sin(h * th)
        return out
