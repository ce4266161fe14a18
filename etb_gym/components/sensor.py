"""Position (and current) sensing: gain, offset, noise, quantization, delay. Not part of the ODE.

    measured = q * round((gain * phi(t - delay) + offset + n) / q),    n ~ N(0, sigma^2)

A twin's reading model (the diagnosis, a plant file's ``[sensor]`` section) may add two terms learned from the
data, between the delay and the gain:

    phi_c[k] = phi_d[k] + d(phi_d[k])            reading curve  (effects_maps.SensorMapParams: a table over angle)
    phi_f[k] = sum_j w_j phi_c[k - j]            reading filter (:class:`ReadingFilterParams`, :func:`fir_series`)
    measured = gain * phi_f + offset (+ n, quantized)

with q the resolution (0 = none). The delay is a whole number of control periods (``delay_steps``); a twin's
``delay_s`` may leave a fraction f of a period, read as ``(1 - f) phi[k - n] + f phi[k - n - 1]`` (linear
interpolation between samples). The current sensor adds N(0, sigma_i^2) noise and its own quantization.
Angles are radians inside; the env and the recording files present degrees (documented edges).

The equation and the delay line are written once, as kernels: :func:`sense` (one reading) and
:func:`delay_push` (one step of the delay line, a ring buffer); the twin's maps for one control period as
:func:`shape_reading` (the fractional delay, the curve via effects_maps.table_lookup, the filter via
:func:`fir_push`, which :func:`fir_series` also streams over a series). :class:`PositionSensor` (streaming and
array readings), the single env and the native vector env's compiled loop call them; the envs call
:func:`shape_reading` between the delay line and :func:`sense` when a plant file has a ``[sensor]`` section.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..jit import kernel, py_func
from .base import Params, check, non_negative
from .effects_maps import table_lookup


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


@dataclasses.dataclass(frozen=True)
class ReadingFilterParams(Params):
    """The reading's dynamics as a causal FIR kernel over control periods: ``weights[j]`` multiplies the angle
    ``j`` periods old (newest first). Unit DC gain (the weights sum to 1): at rest the reading is the angle, the
    static map is ``gain``/``offset`` and the reading curve. A pure delay of d periods is a 1 at index d; a
    first-order lag a decaying exponential; a moving average N equal weights."""

    weights: tuple = (1.0,)

    def validate(self):
        n = "ReadingFilterParams"
        try:
            w = np.asarray(self.weights, float)
        except (TypeError, ValueError):
            raise ValueError(f"{n}.weights = {self.weights!r} is invalid: expected a list of numbers") from None
        shown = [float(x) for x in np.ravel(w)]
        check(n, "weights", shown, w.ndim == 1 and 1 <= w.size <= MAX_FILTER_TAPS,
              f"a list of 1 to {MAX_FILTER_TAPS} weights (one per control period, newest first)")
        check(n, "weights", shown, bool(np.all(np.isfinite(w))), "finite numbers")
        check(n, "weights", shown, abs(float(np.sum(w)) - 1.0) <= 1e-6,
              f"weights that sum to 1 (unit gain at rest; they sum to {float(np.sum(w))!r})")
        object.__setattr__(self, "weights", tuple(float(x) for x in w))

    @property
    def mean_lag_periods(self) -> float:
        """The kernel's centre of mass in control periods (a pure delay's length)."""
        return float(np.dot(np.arange(len(self.weights)), self.weights))


MAX_FILTER_TAPS = 64


@kernel
def fir_push(buf, pos, value, w, woff, m):
    """One control period of the causal FIR kernel ``w[woff:woff + m]`` (newest first) over the ring buffer
    ``buf[1:1 + m]`` (next slot ``pos``; ``buf[0]`` is not used here, see :func:`shape_reading`): stores
    ``value`` and returns ``(sum_j w[woff + j] * the value j periods old, the next pos)``."""
    buf[1 + pos] = value
    tot = 0.0
    for j in range(m):
        i = pos - j
        if i < 0:
            i += m
        tot += w[woff + j] * buf[1 + i]
    pos += 1
    if pos == m:
        pos = 0
    return tot, pos


@kernel
def fir_series(values, weights):
    """A sampled series through the causal FIR kernel ``weights`` (newest first); before the start the input
    holds ``values[0]`` (a plate at rest), as :func:`delay_series`. Streams :func:`fir_push`."""
    n = values.shape[0]
    out = np.empty_like(values)
    m = weights.shape[0]
    buf = np.full(m + 1, values[0] if n else 0.0)
    pos = 0
    for k in range(n):
        out[k], pos = fir_push(buf, pos, values[k], weights, 0, m)
    return out


# ---------------------------------------------------------------- a twin's reading shape, streamed (the envs)
@kernel
def shape_reading(value, line, pos, shape):
    """The twin's reading maps for one control period, between the whole-period delay line (:func:`delay_push`)
    and :func:`sense`: the fractional part of the delay, the reading curve, the reading filter (the module
    docstring's order). ``value``: the angle after the whole-period delay; ``shape``: the constants packed by
    :func:`pack_reading_shape`; ``line``: this reader's state (``line[0]`` the previous delayed angle,
    ``line[1:]`` the filter's ring buffer, next slot ``pos``), filled by :func:`shape_reset`. Returns ``(the
    shaped angle, the next pos)``; with no maps (``shape = [0, 0, 0]``) the angle is returned untouched.

    Fractional delay f (periods): ``(1 - f) * a[k] + f * a[k - 1]``, the linear interpolation of the twin's
    ``delay_s`` between samples. Curve: ``a + d(a)`` (effects_maps.table_lookup, held beyond the knots)."""
    f = shape[0]
    if f > 0.0:
        prev = line[0]
        line[0] = value
        value = (1.0 - f) * value + f * prev
    nc = int(shape[1])
    if nc > 0:
        value = value + table_lookup(value, shape, 2, nc, 2 + nc)
    o = 2 + 2 * nc
    m = int(shape[o])
    if m > 0:
        value, pos = fir_push(line, pos, value, shape, o + 1, m)
    return value, pos


@kernel
def shape_reset(line, shape, angle):
    """Fill a reader's :func:`shape_reading` state for a plate at rest at ``angle`` (the delay line's start):
    the previous delayed angle is ``angle``, the filter's past inputs the curve's reading of it. Returns the
    next pos (0)."""
    line[0] = angle
    nc = int(shape[1])
    c = angle + table_lookup(angle, shape, 2, nc, 2 + nc) if nc > 0 else angle
    for k in range(1, line.shape[0]):
        line[k] = c
    return 0


def pack_reading_shape(fraction: float = 0.0, curve=None, filter=None) -> np.ndarray:
    """:func:`shape_reading`'s constants: ``[fraction, n_c, curve angle_rad (n_c), curve error_rad (n_c), m,
    filter weights (m)]`` (n_c = 0: no curve, m = 0: no filter). ``curve``: effects_maps.SensorMapParams,
    ``filter``: :class:`ReadingFilterParams`; ``fraction`` in [0, 1) periods."""
    if not 0.0 <= fraction < 1.0:
        raise ValueError(f"fraction = {fraction!r} is invalid: expected a fractional delay in [0, 1) periods")
    c = [] if curve is None else [len(curve.angle_rad), *curve.angle_rad, *curve.error_rad]
    w = [] if filter is None else [len(filter.weights), *filter.weights]
    return np.array([float(fraction), *(c or [0]), *(w or [0])], float)


def shape_line_length(shape: np.ndarray) -> int:
    """The length of a :func:`shape_reading` state for the packed ``shape``: 1 + the filter's taps."""
    nc = int(shape[1])
    return 1 + int(shape[2 + 2 * nc])


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


# ------------------------------------------------------------------------------------ a plant file's [sensor]
SENSOR_SECTION_KEYS = ("offset_rad", "gain", "delay_s", "curve", "filter")


def sensor_section(d) -> dict:
    """A plant file's ``[sensor]`` section (docs/plant-file.md) checked: ``{"offset_rad", "gain", "delay_s",
    "curve": SensorMapParams | None, "filter": ReadingFilterParams | None}``. Errors name the key
    (``sensor.curve.error_rad``), its value and what was expected."""
    from .effects_maps import SensorMapParams
    if not isinstance(d, dict):
        raise ValueError(f"sensor = {d!r} is invalid: expected a table with some of {', '.join(SENSOR_SECTION_KEYS)}")
    bad = sorted(set(d) - set(SENSOR_SECTION_KEYS))
    if bad:
        raise ValueError(f"sensor: unknown key(s) {bad}; valid: {list(SENSOR_SECTION_KEYS)}")
    out = {}
    for k, default, ok, expected in (("offset_rad", 0.0, lambda v: True, "a finite angle [rad]"),
                                     ("gain", 1.0, lambda v: v > 0, "a finite gain > 0"),
                                     ("delay_s", 0.0, lambda v: v >= 0, "a finite delay >= 0 s")):
        v = d.get(k, default)
        num = isinstance(v, (int, float)) and not isinstance(v, bool)
        check("sensor", k, v, num and math.isfinite(float(v)) and ok(float(v)), expected)
        out[k] = float(v)
    for k, cls in (("curve", SensorMapParams), ("filter", ReadingFilterParams)):
        v = d.get(k)
        if v is None:
            out[k] = None
            continue
        if not isinstance(v, dict):
            raise ValueError(f"sensor.{k} = {v!r} is invalid: expected a table of {cls.__name__} fields")
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(v) - names)
        if unknown:
            raise ValueError(f"sensor.{k}: unknown key(s) {unknown}; valid: {sorted(names)}")
        try:
            out[k] = cls(**v)
        except ValueError as e:
            raise ValueError(f"sensor.{k}: {e}") from None
    return out


def sensor_section_dict(offset_rad: float, gain: float, delay_s: float, curve=None, filter=None) -> dict:
    """The ``[sensor]`` section for a plant file (the inverse of :func:`sensor_section`)."""
    d = {"offset_rad": float(offset_rad), "gain": float(gain), "delay_s": float(delay_s)}
    if curve is not None:
        d["curve"] = {k: list(v) for k, v in curve.to_dict().items()}
    if filter is not None:
        d["filter"] = {"weights": list(filter.weights)}
    return d
