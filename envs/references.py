"""Reference signals (throttle-angle set points) for the ETB envs and the benchmark.

A reference is a small immutable object: ``ref(t_s)`` gives the set point in degrees for a scalar time
(returns a float) or an array of times (returns an array), and ``ref.to_dict()`` gives a plain description
that :func:`make_reference` turns back into an equal reference::

    >>> from etb_gym.envs.references import Step, make_reference
    >>> ref = Step(10.0, 80.0, 0.05)          # start at 10 deg, step to 80 deg at t = 0.05 s
    >>> ref(0.0), ref(0.1)
    (10.0, 80.0)
    >>> make_reference(**ref.to_dict()) == ref
    True

Random references (``random_steps``, ``pedal``) are *drawn* when they are made, from the generator passed
as ``rng`` (the env passes its seeded ``np_random``); what comes back is a deterministic :class:`Steps` or
:class:`PiecewiseLinear` whose ``to_dict()`` holds the drawn sequence, so an episode's reference can be
stored and replayed exactly. :func:`make_random_task` validates a random task's parameters once and
returns an object whose ``draw(rng)`` draws one reference (the env draws one per reset that way).

Names understood by :func:`make_reference` (``REFERENCES``): constant, step, steps, ramp, piecewise_linear,
sine, chirp, random_steps, pedal. Angles are degrees (0 = closed, 90 = fully open, limp-home 3 deg): the
reference is a documented edge of the package, the plant works in radians.
"""
from __future__ import annotations

import inspect
import math
from typing import Callable

import numpy as np

from etb_gym.jit import kernel

LIMP_HOME_DEG = 3.0


def _finite(owner, name, v):
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.{name} = {v!r} is invalid: expected a finite number") from None
    if not math.isfinite(f):
        raise ValueError(f"{owner}.{name} = {v!r} is invalid: expected a finite number")
    return f


def _positive(owner, name, v):
    f = _finite(owner, name, v)
    if f <= 0:
        raise ValueError(f"{owner}.{name} = {v!r} is invalid: expected a value > 0")
    return f


def _vector(owner, name, v, min_len=1):
    try:
        a = np.array(v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.{name} = {v!r} is invalid: expected a sequence of numbers") from None
    if a.size < min_len:
        raise ValueError(f"{owner}.{name} has {a.size} entries: expected at least {min_len}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{owner}.{name} = {v!r} is invalid: expected finite numbers")
    a.setflags(write=False)
    return a


class Reference:
    """Base class: subclasses set ``name`` and implement ``_eval(t: ndarray) -> ndarray`` (degrees)."""

    name = ""

    def __call__(self, t_s):
        if np.ndim(t_s) == 0:
            return float(self._eval(np.asarray(float(t_s)))[()])
        return self._eval(np.asarray(t_s, dtype=float))

    def _eval(self, t):  # pragma: no cover - abstract
        raise NotImplementedError

    def table(self, t_grid: np.ndarray) -> np.ndarray:
        """``self(t_grid)`` for an increasing time grid (the env's episode grid); subclasses may do it faster."""
        return self._eval(np.asarray(t_grid, dtype=float))

    def to_dict(self) -> dict:
        raise NotImplementedError

    def __eq__(self, other):
        if type(self) is not type(other):
            return NotImplemented
        a, b = self.to_dict(), other.to_dict()
        return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) if isinstance(a[k], list) else a[k] == b[k]
                                            for k in a)

    __hash__ = None

    def __repr__(self):
        d = self.to_dict()
        d.pop("name")
        return f"{type(self).__name__}({', '.join(f'{k}={v!r}' for k, v in d.items())})"


class Constant(Reference):
    """r(t) = value_deg."""

    name = "constant"

    def __init__(self, value_deg: float = 45.0):
        self.value_deg = _finite("Constant", "value_deg", value_deg)

    def _eval(self, t):
        return np.full(t.shape, self.value_deg)

    def to_dict(self):
        return {"name": self.name, "value_deg": self.value_deg}


class Step(Reference):
    """r(t) = initial_deg for t < at_s, final_deg for t >= at_s."""

    name = "step"

    def __init__(self, initial_deg: float = 10.0, final_deg: float = 80.0, at_s: float = 0.05):
        self.initial_deg = _finite("Step", "initial_deg", initial_deg)
        self.final_deg = _finite("Step", "final_deg", final_deg)
        self.at_s = _finite("Step", "at_s", at_s)

    def _eval(self, t):
        return np.where(t < self.at_s, self.initial_deg, self.final_deg)

    def to_dict(self):
        return {"name": self.name, "initial_deg": self.initial_deg, "final_deg": self.final_deg, "at_s": self.at_s}


# the default "steps" task: large steps and small ones around (and across) limp-home, 0.25 s each
DEFAULT_STEPS_DEG = (10.0, 80.0, 20.0, 45.0, 2.0, 5.0, 1.0, 8.0, 60.0, 3.5, 2.5, 30.0)


class Steps(Reference):
    """Piecewise constant: r(t) = values_deg[k] for times_s[k] <= t < times_s[k+1] (values_deg[0] before
    times_s[0]). Default: twelve 0.25 s plateaus with large steps (10 -> 80 -> 20 deg) and small ones that
    cross limp-home (2 -> 5 -> 1 -> 8, 3.5 -> 2.5 deg)."""

    name = "steps"

    def __init__(self, times_s=None, values_deg=DEFAULT_STEPS_DEG, dwell_s: float = 0.25):
        values = _vector("Steps", "values_deg", values_deg)
        if times_s is None:
            dwell = _positive("Steps", "dwell_s", dwell_s)
            times = np.arange(values.size) * dwell
            times.setflags(write=False)
        else:
            times = _vector("Steps", "times_s", times_s)
        if times.size != values.size:
            raise ValueError(f"Steps: times_s has {times.size} entries but values_deg has {values.size}: "
                             "expected one time per value")
        if np.any(np.diff(times) <= 0):
            raise ValueError(f"Steps.times_s = {times.tolist()} is invalid: expected strictly increasing times")
        self.times_s, self.values_deg = times, values

    def _eval(self, t):
        k = np.searchsorted(self.times_s, t, side="right") - 1
        return self.values_deg[np.maximum(k, 0)]

    def table(self, t_grid):
        # the values of _eval on an increasing grid, filled in one pass
        t = np.asarray(t_grid, dtype=float)
        out = np.empty(t.shape)
        fill_steps_table(self.times_s, self.values_deg, t, out)
        return out

    @classmethod
    def _trusted(cls, times_s, values_deg):
        """Build from arrays already known to be valid (finite, increasing): the random draws."""
        obj = cls.__new__(cls)
        times_s.setflags(write=False)
        values_deg.setflags(write=False)
        obj.times_s, obj.values_deg = times_s, values_deg
        return obj

    def to_dict(self):
        return {"name": self.name, "times_s": self.times_s.tolist(), "values_deg": self.values_deg.tolist()}


@kernel
def fill_steps_table(times_s, values_deg, t_grid, out):
    """out[k] = the value of the last plateau that started at or before t_grid[k] (the first value before
    times_s[0]), for an increasing t_grid: plateau j fills from the first t >= times_s[j] on."""
    n = t_grid.shape[0]
    end = n
    for j in range(times_s.shape[0] - 1, -1, -1):
        start = 0 if j == 0 else np.searchsorted(t_grid, times_s[j])
        out[start:end] = values_deg[j]
        end = min(end, start)


class PiecewiseLinear(Reference):
    """Linear interpolation between knots (times_s[k], values_deg[k]); constant outside the knots."""

    name = "piecewise_linear"

    def __init__(self, times_s, values_deg):
        times = _vector(type(self).__name__, "times_s", times_s)
        values = _vector(type(self).__name__, "values_deg", values_deg)
        if times.size != values.size:
            raise ValueError(f"{type(self).__name__}: times_s has {times.size} entries but values_deg has "
                             f"{values.size}: expected one time per value")
        if np.any(np.diff(times) <= 0):
            raise ValueError(f"{type(self).__name__}.times_s = {times.tolist()} is invalid: expected strictly "
                             "increasing times")
        self.times_s, self.values_deg = times, values

    def _eval(self, t):
        return np.interp(t, self.times_s, self.values_deg)

    def to_dict(self):
        return {"name": self.name, "times_s": self.times_s.tolist(), "values_deg": self.values_deg.tolist()}


class Ramp(PiecewiseLinear):
    """r = start_deg until at_s, then linear to end_deg over duration_s, then end_deg."""

    name = "ramp"

    def __init__(self, start_deg: float = 5.0, end_deg: float = 85.0, at_s: float = 0.1, duration_s: float = 1.0):
        self.start_deg = _finite("Ramp", "start_deg", start_deg)
        self.end_deg = _finite("Ramp", "end_deg", end_deg)
        self.at_s = _finite("Ramp", "at_s", at_s)
        self.duration_s = _positive("Ramp", "duration_s", duration_s)
        super().__init__([self.at_s, self.at_s + self.duration_s], [self.start_deg, self.end_deg])

    def to_dict(self):
        return {"name": self.name, "start_deg": self.start_deg, "end_deg": self.end_deg, "at_s": self.at_s,
                "duration_s": self.duration_s}


class Sine(Reference):
    """r(t) = offset_deg + amplitude_deg * sin(2 pi frequency_hz t + phase_rad)."""

    name = "sine"

    def __init__(self, offset_deg: float = 40.0, amplitude_deg: float = 30.0, frequency_hz: float = 1.0,
                 phase_rad: float = 0.0):
        self.offset_deg = _finite("Sine", "offset_deg", offset_deg)
        self.amplitude_deg = _finite("Sine", "amplitude_deg", amplitude_deg)
        self.frequency_hz = _finite("Sine", "frequency_hz", frequency_hz)
        self.phase_rad = _finite("Sine", "phase_rad", phase_rad)

    def _eval(self, t):
        return self.offset_deg + self.amplitude_deg * np.sin(2 * np.pi * self.frequency_hz * t + self.phase_rad)

    def to_dict(self):
        return {"name": self.name, "offset_deg": self.offset_deg, "amplitude_deg": self.amplitude_deg,
                "frequency_hz": self.frequency_hz, "phase_rad": self.phase_rad}


class Chirp(Reference):
    """Linear frequency sweep from f0_hz to f1_hz over duration_s (then continuing at f1_hz):

        r(t) = offset_deg + amplitude_deg * sin(2 pi (f0 t + (f1 - f0) t^2 / (2 T)))     for t <= T
    """

    name = "chirp"

    def __init__(self, offset_deg: float = 40.0, amplitude_deg: float = 20.0, f0_hz: float = 0.5,
                 f1_hz: float = 10.0, duration_s: float = 3.0):
        self.offset_deg = _finite("Chirp", "offset_deg", offset_deg)
        self.amplitude_deg = _finite("Chirp", "amplitude_deg", amplitude_deg)
        self.f0_hz = _finite("Chirp", "f0_hz", f0_hz)
        self.f1_hz = _finite("Chirp", "f1_hz", f1_hz)
        self.duration_s = _positive("Chirp", "duration_s", duration_s)

    def _eval(self, t):
        T, f0, f1 = self.duration_s, self.f0_hz, self.f1_hz
        tc = np.minimum(t, T)
        cycles = f0 * tc + (f1 - f0) * tc * tc / (2 * T) + f1 * (t - tc)
        return self.offset_deg + self.amplitude_deg * np.sin(2 * np.pi * cycles)

    def to_dict(self):
        return {"name": self.name, "offset_deg": self.offset_deg, "amplitude_deg": self.amplitude_deg,
                "f0_hz": self.f0_hz, "f1_hz": self.f1_hz, "duration_s": self.duration_s}


def _rng(rng, name):
    if rng is None:
        raise ValueError(f"reference {name!r} is drawn at random: pass rng= (a numpy Generator, e.g. env.np_random)")
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"reference {name!r}: rng must be a numpy.random.Generator, got {type(rng).__name__}")
    return rng


class RandomSteps:
    """The ``random_steps`` task with its parameters validated once; :meth:`draw` draws one :class:`Steps`.

    Random plateaus covering ``duration_s``: dwell times uniform in [min_dwell_s, max_dwell_s]; each new
    level is, with probability ``small_step_prob``, a small step near limp-home (uniform within
    +-``small_step_deg`` of 3 deg, so these steps often cross it), otherwise uniform in [low_deg, high_deg]."""

    name = "random_steps"

    def __init__(self, duration_s: float = 3.0, min_dwell_s: float = 0.1, max_dwell_s: float = 0.4,
                 low_deg: float = 0.5, high_deg: float = 85.0, small_step_prob: float = 0.3,
                 small_step_deg: float = 4.0):
        n = "random_steps"
        self.duration_s = _positive(n, "duration_s", duration_s)
        self.min_dwell_s = _positive(n, "min_dwell_s", min_dwell_s)
        self.max_dwell_s = _positive(n, "max_dwell_s", max_dwell_s)
        if self.max_dwell_s < self.min_dwell_s:
            raise ValueError(f"random_steps.max_dwell_s = {max_dwell_s!r} is invalid: expected >= min_dwell_s = {min_dwell_s}")
        self.low_deg, self.high_deg = _finite(n, "low_deg", low_deg), _finite(n, "high_deg", high_deg)
        if self.high_deg <= self.low_deg:
            raise ValueError(f"random_steps.high_deg = {high_deg!r} is invalid: expected > low_deg = {low_deg}")
        self.small_step_prob = _finite(n, "small_step_prob", small_step_prob)
        if not 0 <= self.small_step_prob <= 1:
            raise ValueError(f"random_steps.small_step_prob = {small_step_prob!r} is invalid: expected a probability in [0, 1]")
        self.small_step_deg = _positive(n, "small_step_deg", small_step_deg)
        self.bounds_deg = (self.low_deg, self.high_deg)          # every drawn level lies within
        self._n = int(math.ceil(self.duration_s / self.min_dwell_s)) + 1   # enough plateaus in the worst case

    def draw(self, rng: np.random.Generator) -> Steps:
        u = rng.random(4 * self._n)                         # one draw: dwell, kind, big level, small level
        times, values = np.empty(self._n), np.empty(self._n)
        n = draw_plateaus(u, self.duration_s, self.min_dwell_s, self.max_dwell_s - self.min_dwell_s, self.low_deg,
                          self.high_deg, self.small_step_prob, self.small_step_deg, times, values)
        return Steps._trusted(times[:n], values[:n])


@kernel
def draw_plateaus(u, duration_s, min_dwell_s, span_dwell_s, low_deg, high_deg, small_step_prob, small_step_deg,
                  times, values):
    """The plateaus of :class:`RandomSteps` from uniform draws ``u`` (four per plateau: dwell, kind, big level,
    small level), written to ``times``/``values``; returns how many cover ``duration_s``."""
    t = 0.0
    n = 0
    for k in range(0, u.shape[0], 4):
        if t >= duration_s:
            break
        if u[k + 1] < small_step_prob:
            v = min(max(LIMP_HOME_DEG + small_step_deg * (2.0 * u[k + 3] - 1.0), low_deg), high_deg)
        else:
            v = low_deg + (high_deg - low_deg) * u[k + 2]
        times[n] = t
        values[n] = v
        n += 1
        t += min_dwell_s + span_dwell_s * u[k]
    return n


def random_steps(rng: np.random.Generator = None, duration_s: float = 3.0, min_dwell_s: float = 0.1,
                 max_dwell_s: float = 0.4, low_deg: float = 0.5, high_deg: float = 85.0,
                 small_step_prob: float = 0.3, small_step_deg: float = 4.0) -> Steps:
    """Random plateaus covering ``duration_s`` (see :class:`RandomSteps`), drawn from ``rng``."""
    rng = _rng(rng, "random_steps")
    return RandomSteps(duration_s, min_dwell_s, max_dwell_s, low_deg, high_deg, small_step_prob,
                       small_step_deg).draw(rng)


class Pedal:
    """The ``pedal`` task with its parameters validated once; :meth:`draw` draws one :class:`PiecewiseLinear`.

    A pedal-like driving profile: the driver holds a pedal position for a while (uniform in
    [min_hold_s, max_hold_s]), then moves to the next one at a finite rate (up to ``max_rate_deg_s``,
    tip-in and tip-out). Positions mix idle (``idle_deg``, near limp-home), part load (uniform 5..40 deg),
    and occasional wide-open throttle (``max_deg``)."""

    name = "pedal"
    PART_LOAD_DEG = (5.0, 40.0)

    def __init__(self, duration_s: float = 3.0, idle_deg: float = 4.0, max_deg: float = 85.0,
                 min_hold_s: float = 0.15, max_hold_s: float = 0.6, max_rate_deg_s: float = 400.0):
        self.duration_s = _positive("pedal", "duration_s", duration_s)
        self.idle_deg = _finite("pedal", "idle_deg", idle_deg)
        self.max_deg = _finite("pedal", "max_deg", max_deg)
        self.min_hold_s = _positive("pedal", "min_hold_s", min_hold_s)
        self.max_hold_s = _positive("pedal", "max_hold_s", max_hold_s)
        if self.max_hold_s < self.min_hold_s:
            raise ValueError(f"pedal.max_hold_s = {max_hold_s!r} is invalid: expected >= min_hold_s = {min_hold_s}")
        self.max_rate_deg_s = _positive("pedal", "max_rate_deg_s", max_rate_deg_s)
        part_lo, part_hi = self.PART_LOAD_DEG
        self.bounds_deg = (min(self.idle_deg, part_lo, self.max_deg), max(self.idle_deg, part_hi, self.max_deg))
        self._n = int(math.ceil(self.duration_s / self.min_hold_s)) + 1

    def draw(self, rng: np.random.Generator) -> PiecewiseLinear:
        n, rate, idle = self._n, self.max_rate_deg_s, self.idle_deg
        hold = rng.uniform(self.min_hold_s, self.max_hold_s, n)
        kind = rng.random(n)
        part = rng.uniform(*self.PART_LOAD_DEG, n)
        speed = rng.uniform(0.3, 1.0, n) * rate
        levels = np.where(kind < 0.3, idle, np.where(kind < 0.85, part, self.max_deg))
        levels[0] = idle
        times, values, t = [0.0], [levels[0]], 0.0
        for k in range(1, n):
            t += hold[k - 1]
            times.append(t)
            values.append(levels[k - 1])
            t += max(abs(levels[k] - levels[k - 1]) / speed[k], 1e-3)
            times.append(t)
            values.append(levels[k])
            if t >= self.duration_s:
                break
        times, values = np.array(times), np.array(values)
        keep = np.concatenate([[True], np.diff(times) > 0])     # drop the zero-length hold at t = 0
        return PiecewiseLinear(times[keep], values[keep])


def pedal(rng: np.random.Generator = None, duration_s: float = 3.0, idle_deg: float = 4.0,
          max_deg: float = 85.0, min_hold_s: float = 0.15, max_hold_s: float = 0.6,
          max_rate_deg_s: float = 400.0) -> PiecewiseLinear:
    """A pedal-like driving profile (see :class:`Pedal`), drawn from ``rng``."""
    rng = _rng(rng, "pedal")
    return Pedal(duration_s, idle_deg, max_deg, min_hold_s, max_hold_s, max_rate_deg_s).draw(rng)


REFERENCES: dict[str, Callable] = {
    "constant": Constant,
    "step": Step,
    "steps": Steps,
    "ramp": Ramp,
    "piecewise_linear": PiecewiseLinear,
    "sine": Sine,
    "chirp": Chirp,
    "random_steps": random_steps,
    "pedal": pedal,
}
RANDOM_REFERENCES = ("random_steps", "pedal")
RANDOM_TASKS = {"random_steps": RandomSteps, "pedal": Pedal}


def _params_of(fn):
    target = fn.__init__ if isinstance(fn, type) else fn
    return [p for p in inspect.signature(target).parameters if p not in ("self", "rng")]


_PARAMS = {name: _params_of(fn) for name, fn in REFERENCES.items()}


def _check_params(name, params):
    if name not in REFERENCES:
        raise ValueError(f"unknown reference {name!r}: expected one of {sorted(REFERENCES)}")
    valid = _PARAMS[name]
    unknown = [k for k in params if k not in valid]
    if unknown:
        raise ValueError(f"reference {name!r}: unknown parameter(s) {unknown}; valid: {valid}")


def make_reference(name: str, rng: np.random.Generator | None = None, **params) -> Reference:
    """Build a reference by name (see ``REFERENCES``) with keyword parameters; the random ones are drawn
    from ``rng``. Unknown names or parameters raise ValueError listing the valid choices."""
    _check_params(name, params)
    if name in RANDOM_REFERENCES:
        return REFERENCES[name](rng=rng, **params)
    return REFERENCES[name](**params)


def make_random_task(name: str, **params):
    """A random reference task (``random_steps`` or ``pedal``) with its parameters validated now:
    ``task.draw(rng)`` draws one reference, ``task.bounds_deg`` bounds every value it can draw."""
    _check_params(name, params)
    if name not in RANDOM_TASKS:
        raise ValueError(f"reference {name!r} is not random: expected one of {list(RANDOM_TASKS)}")
    return RANDOM_TASKS[name](**params)


def as_reference(spec, rng: np.random.Generator | None = None) -> Reference:
    """A reference from a name, a dict ``{"name": ..., **params}`` or a Reference (returned as is)."""
    if isinstance(spec, Reference):
        return spec
    if isinstance(spec, str):
        return make_reference(spec, rng=rng)
    if isinstance(spec, dict):
        if "name" not in spec:
            raise ValueError(f"reference {spec!r}: a dict needs a 'name' key, one of {sorted(REFERENCES)}")
        params = dict(spec)
        return make_reference(params.pop("name"), rng=rng, **params)
    raise ValueError(f"reference {spec!r}: expected a name (one of {sorted(REFERENCES)}), a dict "
                     "{'name': ..., **params} or a Reference object")
