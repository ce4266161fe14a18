"""Nonparametric effects: lookup tables learned from the data (docs/diagnosis-shapes.md).

Each map is an ordinary plant component (kind ``effect.<id>``, loadable from and written to plant files)
whose shape is a table on a knot grid, interpolated piecewise-linearly and held constant beyond the
first and last knot:

    angle_torque_map         T = f(phi)                                       (airflow, cogging, any torque over angle)
    torque_constant_map      k(phi) = c_M + dk(phi): torque dk(phi) i, back-EMF dk(phi) omega   (shaft flux loss)
    angle_friction_map       T = -g(phi) w,   dw/dt = (omega - |omega| w) / delta   (friction level over angle)
    speed_friction_map       T = -g(omega) w  (the same unit bristle; g over |omega|, one table per direction:
                             in steady sliding T = -g(omega) sign(omega), a friction curve over speed)
    current_voltage_map      drop u(i) in the coil loop (supply, bridge, contact losses of any shape)
    current_torque_constant_map   torque dk(i) i, back-EMF dk(i) omega   (a torque constant varying with current)
    current_inductance_map   L += dL(i)                                       (inductance over current)
    sensor_map               y = phi + d(phi): a reading error over angle (sensor side, not in the ODE)

w is a unit bristle (the presliding state of ``angle_dependent_friction``), so a map value may be negative
(less friction than the nominal level) without making the state equation singular.

Grids: angles in rad (the plant's own stroke), speeds in rad/s (>= 0, first knot 0), currents in A
(signed). Values carry their unit in the field name. The kernels use a binary search, O(log n) per
evaluation, and no allocation: cheap in the compiled stepper.
"""
from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np

from ..jit import kernel
from .base import Params, check, positive
from .effects_electrical import Effect
from .effects_friction import unit_bristle_advance, unit_bristle_friction


# ------------------------------------------------------------------------------------ table helpers
@kernel
def table_lookup(x, q, off, n, voff):
    """Piecewise-linear interpolation: knots q[off:off+n] (increasing), values q[voff:voff+n], clamped."""
    if x <= q[off]:
        return q[voff]
    if x >= q[off + n - 1]:
        return q[voff + n - 1]
    lo = 0
    hi = n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if q[off + mid] <= x:
            lo = mid
        else:
            hi = mid
    x0 = q[off + lo]
    f = (x - x0) / (q[off + lo + 1] - x0)
    return (1.0 - f) * q[voff + lo] + f * q[voff + lo + 1]


@kernel
def map_value(x, p, k):
    """Value table ``k`` (0: the first value field) of a packed map [n, grid (n), values (n) per field,
    scalars...] at ``x``."""
    n = int(p[0])
    return table_lookup(x, p, 1, n, 1 + (k + 1) * n)


def _shown(v):
    """A value as the error message shows it: plain floats, no numpy reprs."""
    try:
        return [float(x) for x in np.ravel(np.asarray(v, float))]
    except (TypeError, ValueError):
        return v


def _as_grid(owner: str, field: str, v, min_size: int = 2, lower=None) -> tuple:
    try:
        a = np.asarray(v, float)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.{field} = {v!r} is invalid: expected a list of numbers") from None
    v = _shown(v)
    check(owner, field, v, a.ndim == 1 and a.size >= min_size, f"a list of at least {min_size} numbers")
    check(owner, field, v, bool(np.all(np.isfinite(a))), "finite numbers")
    check(owner, field, v, bool(np.all(np.diff(a) > 0)), "strictly increasing knots")
    if lower is not None:
        check(owner, field, v, a[0] >= lower, f"knots >= {lower}")
    return tuple(float(x) for x in a)


def _as_values(owner: str, field: str, v, n: int, grid_field: str) -> tuple:
    try:
        a = np.asarray(v, float)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.{field} = {v!r} is invalid: expected a list of numbers") from None
    check(owner, field, f"a list of {a.size} values", a.ndim == 1 and a.size == n,
          f"one value per knot of {grid_field} ({n})")
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise ValueError(f"{owner}.{field}[{bad[0]}] = {float(a[bad[0]])!r} is invalid: expected a finite number")
    return tuple(float(x) for x in a)


@dataclasses.dataclass(frozen=True)
class _MapParams(Params):
    """A grid field (``grid``, knots >= ``lower`` when set) and value fields of the same length (``values``),
    then scalar fields (``scalars``, each > 0): set by subclasses as plain class attributes."""

    grid: ClassVar[str] = ""
    values: ClassVar[tuple] = ()
    scalars: ClassVar[tuple] = ()
    lower: ClassVar[float | None] = None

    def validate(self):
        owner = type(self).__name__
        g = _as_grid(owner, self.grid, getattr(self, self.grid), lower=self.lower)
        object.__setattr__(self, self.grid, g)
        for f in self.values:
            object.__setattr__(self, f, _as_values(owner, f, getattr(self, f), len(g), self.grid))
        positive(owner, self, *self.scalars)

    def __hash__(self):
        return hash(tuple(getattr(self, f.name) for f in dataclasses.fields(self)))


class _MapEffect(Effect):
    """Packs [n, grid..., values..., scalars...] for the kernel; ``kind``, ``grid_field``, ``value_fields`` and
    ``scalar_fields`` follow from ``effect_id`` and the Params class."""

    grid_field = ""
    value_fields: tuple = ()
    scalar_fields: tuple = ()

    def __init_subclass__(cls, **kw):
        if cls.effect_id:          # a concrete map (not an intermediate base)
            cls.kind = "effect." + cls.effect_id
            cls.grid_field, cls.value_fields = cls.Params.grid, cls.Params.values
            cls.scalar_fields = cls.Params.scalars
        super().__init_subclass__(**kw)

    def param_vector(self):
        q = self.params
        g = np.asarray(getattr(q, self.grid_field))
        parts = [[float(g.size)], g] + [np.asarray(getattr(q, f)) for f in self.value_fields]
        parts.append([float(getattr(q, f)) for f in self.scalar_fields])
        return np.concatenate(parts)

    def evaluate(self, x, field: str | None = None) -> np.ndarray:
        """The table (``field``, default the first value field) interpolated at ``x`` (numpy, vectorized)."""
        q = self.params
        g = np.asarray(getattr(q, self.grid_field))
        v = np.asarray(getattr(q, field or self.value_fields[0]))
        return np.interp(np.asarray(x, float), g, v)


class _UnitBristleMap(_MapEffect):
    """A friction map acting through a unit bristle (effects_friction.unit_bristle_friction)."""

    state_names = ("z_rad",)
    state_units = ("rad",)
    advance = staticmethod(unit_bristle_advance)


# ------------------------------------------------------------------------------------ torque over angle
@dataclasses.dataclass(frozen=True)
class AngleTorqueMapParams(_MapParams):
    angle_rad: tuple = (0.0, math.radians(90.0))     # knots over the plant's stroke
    torque_Nm: tuple = (0.0, 0.0)                    # opening positive
    grid, values = "angle_rad", ("torque_Nm",)


@kernel
def angle_torque_map_kernel(t, phi, omega, i, u, s, p, ds):
    return map_value(phi, p, 0), 0.0, 0.0


class AngleTorqueMap(_MapEffect):
    effect_id = "angle_torque_map"
    Params = AngleTorqueMapParams
    kernel = staticmethod(angle_torque_map_kernel)
    description = "torque over plate angle, a table learned from the data"


# ------------------------------------------------------------------------------------ torque constant over angle
@dataclasses.dataclass(frozen=True)
class TorqueConstantMapParams(_MapParams):
    angle_rad: tuple = (0.0, math.radians(90.0))
    delta_Nm_per_A: tuple = (0.0, 0.0)               # dk(phi): true torque constant minus the model's
    grid, values = "angle_rad", ("delta_Nm_per_A",)


@kernel
def torque_constant_map_kernel(t, phi, omega, i, u, s, p, ds):
    dk = map_value(phi, p, 0)
    return dk * i, dk * omega, 0.0


class TorqueConstantMap(_MapEffect):
    effect_id = "torque_constant_map"
    Params = TorqueConstantMapParams
    kernel = staticmethod(torque_constant_map_kernel)
    description = "torque / back-EMF constant over plate angle, a table learned from the data"


# ------------------------------------------------------------------------------------ friction over angle
@dataclasses.dataclass(frozen=True)
class AngleFrictionMapParams(_MapParams):
    angle_rad: tuple = (0.0, math.radians(90.0))
    level_Nm: tuple = (0.0, 0.0)                     # g(phi): extra Coulomb level (may be negative)
    presliding_rad: float = 2e-3                     # delta of the unit bristle
    grid, values, scalars = "angle_rad", ("level_Nm",), ("presliding_rad",)


@kernel
def angle_friction_map_kernel(t, phi, omega, i, u, s, p, ds):
    return unit_bristle_friction(map_value(phi, p, 0), omega, s, ds, p[p.size - 1]), 0.0, 0.0


class AngleFrictionMap(_UnitBristleMap):
    effect_id = "angle_friction_map"
    Params = AngleFrictionMapParams
    kernel = staticmethod(angle_friction_map_kernel)
    description = "friction level over plate angle, a table learned from the data"


# ------------------------------------------------------------------------------------ friction over speed
@dataclasses.dataclass(frozen=True)
class SpeedFrictionMapParams(_MapParams):
    speed_rad_s: tuple = (0.0, 1.0)                  # knots over |omega|, first 0
    opening_Nm: tuple = (0.0, 0.0)                   # g(|omega|) while opening (omega >= 0)
    closing_Nm: tuple = (0.0, 0.0)                   # g(|omega|) while closing
    presliding_rad: float = 2e-3
    grid, values, scalars, lower = "speed_rad_s", ("opening_Nm", "closing_Nm"), ("presliding_rad",), 0.0


@kernel
def speed_friction_map_kernel(t, phi, omega, i, u, s, p, ds):
    g = map_value(abs(omega), p, 0 if omega >= 0.0 else 1)
    return unit_bristle_friction(g, omega, s, ds, p[p.size - 1]), 0.0, 0.0


class SpeedFrictionMap(_UnitBristleMap):
    effect_id = "speed_friction_map"
    Params = SpeedFrictionMapParams
    kernel = staticmethod(speed_friction_map_kernel)
    description = "friction level over speed and direction, a table learned from the data"

    def friction_curve(self, omega) -> np.ndarray:
        """Steady sliding torque -g(omega) sign(omega) [N m] at the speeds ``omega`` [rad/s]."""
        w = np.asarray(omega, float)
        up = self.evaluate(np.abs(w), "opening_Nm")
        dn = self.evaluate(np.abs(w), "closing_Nm")
        return -np.where(w >= 0, up, dn) * np.sign(w)


# ------------------------------------------------------------------------------------ voltage over current
@dataclasses.dataclass(frozen=True)
class CurrentVoltageMapParams(_MapParams):
    current_A: tuple = (-1.0, 1.0)                   # signed knots
    drop_V: tuple = (0.0, 0.0)                       # extra voltage drop in the coil loop
    grid, values = "current_A", ("drop_V",)


@kernel
def current_voltage_map_kernel(t, phi, omega, i, u, s, p, ds):
    return 0.0, map_value(i, p, 0), 0.0


class CurrentVoltageMap(_MapEffect):
    effect_id = "current_voltage_map"
    Params = CurrentVoltageMapParams
    kernel = staticmethod(current_voltage_map_kernel)
    description = "voltage drop over current, a table learned from the data"


# ------------------------------------------------------------------------------------ over current
@dataclasses.dataclass(frozen=True)
class CurrentTorqueConstantMapParams(_MapParams):
    current_A: tuple = (-1.0, 1.0)                   # signed knots
    delta_Nm_per_A: tuple = (0.0, 0.0)               # dk(i): torque dk(i) i, back-EMF dk(i) omega
    grid, values = "current_A", ("delta_Nm_per_A",)


@kernel
def current_torque_constant_map_kernel(t, phi, omega, i, u, s, p, ds):
    dk = map_value(i, p, 0)
    return dk * i, dk * omega, 0.0


class CurrentTorqueConstantMap(_MapEffect):
    effect_id = "current_torque_constant_map"
    Params = CurrentTorqueConstantMapParams
    kernel = staticmethod(current_torque_constant_map_kernel)
    description = "torque / back-EMF constant over current, a table learned from the data"


@dataclasses.dataclass(frozen=True)
class CurrentTorqueMapParams(_MapParams):
    current_A: tuple = (-1.0, 1.0)                   # signed knots
    delta_Nm_per_A: tuple = (0.0, 0.0)               # dk(i): torque dk(i) i only; the back-EMF constant unchanged
    grid, values = "current_A", ("delta_Nm_per_A",)


@kernel
def current_torque_map_kernel(t, phi, omega, i, u, s, p, ds):
    return map_value(i, p, 0) * i, 0.0, 0.0


class CurrentTorqueMap(_MapEffect):
    """The torque per ampere over current, the back-EMF left to the motor's constant: a torque constant that
    depends on the current's direction or size (armature reaction, saturation by the coil's own field) while the
    voltage the turning magnet induces does not (it is there with no current)."""
    effect_id = "current_torque_map"
    Params = CurrentTorqueMapParams
    kernel = staticmethod(current_torque_map_kernel)
    description = "torque per ampere over current (back-EMF unchanged), a table learned from the data"


@dataclasses.dataclass(frozen=True)
class CurrentInductanceMapParams(_MapParams):
    current_A: tuple = (-1.0, 1.0)                   # signed knots
    delta_H: tuple = (0.0, 0.0)                      # dL(i): inductance added to the coil loop
    grid, values = "current_A", ("delta_H",)


@kernel
def current_inductance_map_kernel(t, phi, omega, i, u, s, p, ds):
    return 0.0, 0.0, map_value(i, p, 0)


class CurrentInductanceMap(_MapEffect):
    effect_id = "current_inductance_map"
    Params = CurrentInductanceMapParams
    kernel = staticmethod(current_inductance_map_kernel)
    description = "inductance over current, a table learned from the data"


# ------------------------------------------------------------------------------------ sensor over angle
@dataclasses.dataclass(frozen=True)
class SensorMapParams(_MapParams):
    angle_rad: tuple = (0.0, math.radians(90.0))
    error_rad: tuple = (0.0, 0.0)                    # d(phi): reading minus true angle
    grid, values = "angle_rad", ("error_rad",)


@dataclasses.dataclass(frozen=True, eq=False)
class SensorMap:
    """A reading error over angle, y = phi + d(phi) (sensor side: applied to the simulated angle, not
    part of the ODE). ``apply`` and ``invert`` work in degrees like ``diagnose.measurement.SensorModel``."""

    params: SensorMapParams = SensorMapParams()
    kind = "sensor.map"

    def apply_deg(self, phi_deg):
        q = self.params
        phi = np.radians(np.asarray(phi_deg, float))
        return np.degrees(phi + np.interp(phi, q.angle_rad, q.error_rad))

    def invert_deg(self, y_deg):
        """The angle whose reading is ``y_deg`` (fixed-point iteration; d is small and smooth)."""
        y = np.asarray(y_deg, float)
        phi = y.copy()
        for _ in range(6):
            phi = y - (self.apply_deg(phi) - phi)
        return phi

    def to_dict(self):
        return {"kind": self.kind, "params": self.params.to_dict()}


MAP_EFFECTS = {c.effect_id: c for c in (AngleTorqueMap, TorqueConstantMap, AngleFrictionMap, SpeedFrictionMap,
                                        CurrentVoltageMap, CurrentTorqueConstantMap, CurrentTorqueMap,
                                        CurrentInductanceMap)}
