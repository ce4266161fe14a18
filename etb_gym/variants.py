"""Plant variants: one description of "the same plant, but hotter / weaker battery / more friction".

Used by the env's per-episode randomization (``gym.make(..., randomize=True)``) and by the benchmark's
robustness grid, so both change a plant in exactly the same way:

    supply_V              battery voltage seen by the H-bridge [V] (None: the plant's)
    coil_temperature_C    R(T) = R_20 (1 + alpha_Cu (T - 20 C)),  alpha_Cu = 0.00393 1/K (copper)
    friction_scale        multiplies every friction torque level (T_c, T_s, sigma2)
    spring_scale          multiplies the limp-home spring preload and rate
    inertia_scale         multiplies the rotor inertia J
    sensor_noise_std_deg  white noise of the angle sensor [deg] (None: the sensor's)

:meth:`PlantVariant.overrides` turns the plant-parameter part into ``"component.field"`` overrides relative to
given nominal values (a plant's ``params_dict()``), on top of other overrides.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Mapping

COPPER_ALPHA_PER_K = 0.00393          # temperature coefficient of copper resistance
RESISTANCE_REFERENCE_C = 20.0         # the temperature of the plants' nominal resistance
FRICTION_FIELDS = ("coulomb_Nm", "static_Nm", "viscous_Nm_s_per_rad")
SPRING_FIELDS = ("preload_Nm", "rate_Nm_per_rad")
MIN_COIL_TEMPERATURE_C = RESISTANCE_REFERENCE_C - 1.0 / COPPER_ALPHA_PER_K    # R -> 0 here


def copper_resistance_ohm(resistance_20C_ohm: float, temperature_C: float) -> float:
    """R(T) = R_20 (1 + alpha_Cu (T - 20 C))."""
    return resistance_20C_ohm * (1.0 + COPPER_ALPHA_PER_K * (temperature_C - RESISTANCE_REFERENCE_C))


@dataclasses.dataclass(frozen=True)
class PlantVariant:
    """A change of operating conditions / plant parameters relative to a nominal plant (module docstring)."""

    supply_V: float | None = None
    coil_temperature_C: float | None = None
    friction_scale: float = 1.0
    spring_scale: float = 1.0
    inertia_scale: float = 1.0
    sensor_noise_std_deg: float | None = None

    QUANTITIES = ("supply_V", "coil_temperature_C", "friction_scale", "spring_scale", "inertia_scale",
                  "sensor_noise_std_deg")

    def __post_init__(self):
        for f in self.QUANTITIES:
            v = getattr(self, f)
            if v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"PlantVariant.{f} = {v!r} is invalid: expected a finite number")
        for f in ("supply_V", "inertia_scale"):
            v = getattr(self, f)
            if v is not None and v <= 0:
                raise ValueError(f"PlantVariant.{f} = {v!r} is invalid: expected a value > 0")
        for f in ("friction_scale", "spring_scale", "sensor_noise_std_deg"):
            v = getattr(self, f)
            if v is not None and v < 0:
                raise ValueError(f"PlantVariant.{f} = {v!r} is invalid: expected a value >= 0")
        T = self.coil_temperature_C
        if T is not None and T <= MIN_COIL_TEMPERATURE_C:
            raise ValueError(f"PlantVariant.coil_temperature_C = {T!r} is invalid: expected a temperature above "
                             f"{MIN_COIL_TEMPERATURE_C:.0f} C (copper resistance > 0)")

    @classmethod
    def from_draws(cls, draws: Mapping[str, float]) -> "PlantVariant":
        """A variant from a dict of quantities (the env's randomization draws); unknown keys raise."""
        bad = sorted(set(draws) - set(cls.QUANTITIES))
        if bad:
            raise ValueError(f"PlantVariant: unknown quantity {bad}; valid: {list(cls.QUANTITIES)}")
        return cls(**{k: float(v) for k, v in draws.items()})

    def overrides(self, nominal: Mapping[str, float], base: Mapping[str, float] | None = None) -> dict:
        """``"component.field"`` overrides applying this variant to a plant whose parameters are ``nominal``
        (``Plant.params_dict()``), on top of ``base`` (returned together with it). Fields the plant lacks
        (e.g. a friction model without a static level) are left alone."""
        out = dict(base or {})

        def cur(key):
            return float(out.get(key, nominal[key]))

        if self.coil_temperature_C is not None and "drive.resistance_ohm" in nominal:
            out["drive.resistance_ohm"] = copper_resistance_ohm(cur("drive.resistance_ohm"), self.coil_temperature_C)
        for scale, role, fields in ((self.friction_scale, "friction", FRICTION_FIELDS),
                                    (self.spring_scale, "spring", SPRING_FIELDS)):
            if scale != 1.0:
                for f in fields:
                    key = f"{role}.{f}"
                    if key in nominal:
                        out[key] = cur(key) * scale
        if self.inertia_scale != 1.0 and "rotor.inertia_kg_m2" in nominal:
            out["rotor.inertia_kg_m2"] = cur("rotor.inertia_kg_m2") * self.inertia_scale
        return out

    def apply(self, plant):
        """The plant with this variant's parameters and supply (the sensor part is the env's business)."""
        p = plant.with_params(self.overrides(plant.params_dict()))
        if self.supply_V is not None:
            p = p.replace(supply=p.supply.replace(voltage_V=float(self.supply_V)))
        return p
