"""Position (and current) sensing: gain, offset, noise, quantization, delay. Not part of the ODE.

    measured = q * round((gain * phi(t - delay) + offset + n) / q),    n ~ N(0, sigma^2)

with q the resolution (0 = none). The delay is a whole number of control periods. The current sensor
adds N(0, sigma_i^2) noise and its own quantization. Angles are radians inside; the env and the
recording files present degrees (documented edges).

The equation and the delay line are written once, as kernels: :func:`sense` (one reading) and
:func:`delay_push` (one step of the delay line, a ring buffer). :class:`PositionSensor` (streaming and array
readings), the single env and the native vector env's compiled loop all call them.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..jit import kernel, py_func
from .base import Params, check, non_negative


@dataclasses.dataclass(frozen=True)
class PositionSensorParams(Params):
    noise_std_rad: float = math.radians(0.01)          # white noise of the angle reading
    resolution_rad: float = math.radians(90.0 / 4096)  # 12 bits over 90 deg = 0.022 deg
    offset_rad: float = 0.0
    gain: float = 1.0
    delay_steps: int = 0                               # transport delay in control periods
    current_noise_std_A: float = 0.01
    current_resolution_A: float = 0.0
    supply_noise_std_V: float = 0.05                   # battery voltage reading (env observe_supply=True)
    supply_resolution_V: float = 20.0 / 1024           # 10-bit ADC over 0..20 V

    def validate(self):
        n = "PositionSensorParams"
        non_negative(n, self, "noise_std_rad", "resolution_rad", "current_noise_std_A", "current_resolution_A",
                     "supply_noise_std_V", "supply_resolution_V")
        check(n, "gain", self.gain, self.gain > 0, "a gain > 0")
        check(n, "delay_steps", self.delay_steps, isinstance(self.delay_steps, int) and self.delay_steps >= 0,
              "a whole number of control periods >= 0")


def _quantize(x, q):
    return x if q <= 0 else q * np.round(np.asarray(x) / q)


@kernel
def sense(value, gain, offset, noise, resolution):
    """One sensor reading: ``resolution * round((gain * value + offset + noise) / resolution)`` (resolution 0:
    not quantized). :meth:`PositionSensor.transform` in scalar form, for the angle and (gain 1, offset 0) the
    current and the supply voltage; tested equal to it."""
    v = gain * value + offset + noise
    if resolution > 0.0:
        v = resolution * round(v / resolution)
    return v


@kernel
def delay_push(buf, pos, value):
    """One control period of the delay line ``buf`` (a ring buffer, next slot ``pos``): stores ``value`` and
    returns ``(the value stored len(buf) periods ago, the next pos)``. An empty buffer is no delay. (The
    plain function also runs on a list, as the single env keeps its line.)"""
    n = len(buf)
    if n == 0:
        return value, pos
    old = buf[pos]
    buf[pos] = value
    pos += 1
    if pos == n:
        pos = 0
    return old, pos


@kernel
def delay_series(values, n):
    """A whole sampled series through a delay line of ``n`` periods that starts filled with ``values[0]``."""
    out = np.empty_like(values)
    buf = np.full(n, values[0] if values.shape[0] else 0.0)
    pos = 0
    for k in range(values.shape[0]):
        v, pos = delay_push(buf, pos, values[k])
        out[k] = v
    return out


_delay_push = py_func(delay_push)      # one scalar step: the plain function beats a compiled call's dispatch


class PositionSensor:
    """Streaming and batch reading of the plate angle and coil current."""

    def __init__(self, params: PositionSensorParams | None = None, **overrides):
        p = params or PositionSensorParams()
        self.params = p.replace(**overrides) if overrides else p
        self._buf = np.zeros(self.params.delay_steps)     # the delay line (delay_push)
        self._pos = 0
        self._filled = False                              # by reset(), else with the first reading

    # the one equation, shared by the streaming and the array reading
    def transform(self, angle_rad, noise):
        p = self.params
        return _quantize(p.gain * np.asarray(angle_rad, float) + p.offset_rad + noise, p.resolution_rad)

    def reset(self, angle_rad: float) -> None:
        self._buf[:] = float(angle_rad)
        self._pos = 0
        self._filled = True

    def read(self, angle_rad: float, rng: np.random.Generator) -> float:
        """Push the true angle of this control period, return the (delayed, noisy) reading."""
        if not self._filled:
            self.reset(angle_rad)
        delayed, self._pos = _delay_push(self._buf, self._pos, float(angle_rad))
        noise = rng.normal(0.0, self.params.noise_std_rad) if self.params.noise_std_rad > 0 else 0.0
        return float(self.transform(delayed, noise))

    def measure(self, angle_rad: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Readings of a whole sampled trajectory (the first ``delay_steps`` samples repeat the start)."""
        a = np.asarray(angle_rad, float)
        delayed = delay_series(np.ascontiguousarray(a.reshape(-1)), self.params.delay_steps).reshape(a.shape) \
            if self.params.delay_steps and a.size else a
        noise = rng.normal(0.0, self.params.noise_std_rad, a.size) if self.params.noise_std_rad > 0 else 0.0
        return self.transform(delayed, noise)

    def measure_current(self, current_A: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        p = self.params
        c = np.asarray(current_A, float)
        n = rng.normal(0.0, p.current_noise_std_A, c.size) if p.current_noise_std_A > 0 else 0.0
        return _quantize(c + n, p.current_resolution_A)
