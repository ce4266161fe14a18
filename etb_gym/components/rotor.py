"""The rotating mass: throttle plate, shaft and armature (paper eq. 17), and Newton's law (eq. 16).

    J * d(omega)/dt = sum of the components' torques,   d(phi)/dt = omega
"""
from __future__ import annotations

import dataclasses

from .base import Params, positive


@dataclasses.dataclass(frozen=True)
class RotorParams(Params):
    inertia_kg_m2: float = 30e-6  # J, eq. 17

    def validate(self):
        positive("RotorParams", self, "inertia_kg_m2")
