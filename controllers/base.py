"""The controller protocol, the velocity estimator, and the controller factory.

Protocol (used by the benchmark, the examples and the RL policy adapter)::

    ctrl.name: str            label used in tables
    ctrl.dt: float            control period [s] the controller was designed for
    ctrl.reset(seed=None)     forget all internal state (integrators, filters, previous samples)
    ctrl.act(observation)     -> duty in [-1, 1] for the next control period

A controller sees exactly what the env observes: the observation vector of
``etb_gym.envs.observation`` (sensed angle, reference, error, last duty, and the coil current only when
the env was made with ``observe_current=True``, the battery voltage with ``observe_supply=True``; a
controller declares what it reads in ``reads``). Nothing else: the plate velocity is *estimated* by
:class:`VelocityEstimator` from the sensed angle.

Factory::

    make_controller("pid")                      built-in names, see CONTROLLERS (register_controller)
    make_controller("smc", model="3B")          keyword arguments go to the constructor
    make_controller("my_pkg.ctrl:MyController") any importable class (or factory function)
    make_controller("rl:runs/ppo/model.zip")    a registered prefix (register_controller_prefix)
"""
from __future__ import annotations

import importlib
import math
from typing import Any, Callable, Protocol, runtime_checkable

from etb_gym.envs.observation import Measurement, decode


@runtime_checkable
class Controller(Protocol):
    """What the benchmark needs from a controller."""

    name: str
    dt: float

    def reset(self, seed: int | None = None) -> None: ...

    def act(self, observation) -> float: ...


def check_gain(owner: str, name: str, value, *, positive: bool = False, non_negative: bool = False,
               upper: float | None = None) -> float:
    """Validate one gain: finite (and > 0 / >= 0 / < upper when asked). Raises ValueError naming it."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.{name} = {value!r} is invalid: expected a number") from None
    if not math.isfinite(v):
        raise ValueError(f"{owner}.{name} = {value!r} is invalid: expected a finite number")
    if positive and not v > 0:
        raise ValueError(f"{owner}.{name} = {value!r} is invalid: expected a value > 0")
    if non_negative and not v >= 0:
        raise ValueError(f"{owner}.{name} = {value!r} is invalid: expected a value >= 0")
    if upper is not None and not v < upper:
        raise ValueError(f"{owner}.{name} = {value!r} is invalid: expected a value < {upper}")
    return v


class VelocityEstimator:
    """Filtered differentiator of the sensed angle (the velocity the controllers use).

        v_k = a * v_{k-1} + (1 - a) * (y_k - y_{k-1}) / T,      a = exp(-omega_f * T)

    i.e. a backward difference followed by a first-order low-pass with cut-off ``omega_f`` [rad/s]:

        V(z)/Y(z) = (1 - a) (1 - z^-1) / (T (1 - a z^-1))

    which is what :func:`transfer_function` returns for the loop design. With the default 12-bit sensor
    (0.022 deg steps, 0.01 deg noise) and omega_f = 300 rad/s the velocity noise stays below ~5 deg/s
    while the phase lag at the 60-100 rad/s loop crossover is only 12-18 degrees.
    """

    def __init__(self, dt: float, cutoff_rad_s: float = 300.0):
        self.dt = check_gain("VelocityEstimator", "dt", dt, positive=True)
        self.cutoff_rad_s = check_gain("VelocityEstimator", "cutoff_rad_s", cutoff_rad_s, positive=True)
        self.a = math.exp(-self.cutoff_rad_s * self.dt)
        self.reset()

    def reset(self, y0: float | None = None) -> None:
        self.y_prev = y0
        self.v = 0.0

    def update(self, y: float) -> float:
        if self.y_prev is None:
            self.y_prev = y
        self.v = self.a * self.v + (1.0 - self.a) * (y - self.y_prev) / self.dt
        self.y_prev = y
        return self.v

    def frequency_response(self, z):
        """D(z) evaluated at ``z`` (array of points on the unit circle): the one formula of the estimator."""
        a, T = self.a, self.dt
        return (1 - a) * (1 - 1 / z) / (T * (1 - a / z))

    def transfer_function(self):
        import control

        a, T = self.a, self.dt
        return control.tf([(1 - a) / T, -(1 - a) / T], [1.0, -a], T)


class BaseController:
    """Shared plumbing: decoding, degree/radian edge, duty clamping, NaN guard.

    ``reads`` declares the sensors the controller uses besides the reference and its last duty: "angle"
    always, "current" (env ``observe_current=True``) and "supply" (``observe_supply=True``). The benchmark
    builds each controller's env with exactly these, and the observation is decoded accordingly."""

    name = "controller"
    reads: tuple = ("angle",)

    def __init__(self, dt: float = 1e-3):
        self.dt = check_gain(type(self).__name__, "dt", dt, positive=True)

    def reset(self, seed: int | None = None) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def measure(self, observation) -> tuple[float, float, Measurement]:
        """Decode an observation; returns (angle_rad, reference_rad, measurement)."""
        m = observation if isinstance(observation, Measurement) else decode(
            observation, observe_current="current" in self.reads, observe_supply="supply" in self.reads)
        return math.radians(m.angle_deg), math.radians(m.reference_deg), m

    def act(self, observation) -> float:
        phi, ref, m = self.measure(observation)
        d = float(self.compute(phi, ref, m))
        if not math.isfinite(d):
            raise FloatingPointError(f"{self.name}: computed a non-finite duty ({d!r}) at angle "
                                     f"{m.angle_deg:.3f} deg, reference {m.reference_deg:.3f} deg")
        return min(1.0, max(-1.0, d))

    def compute(self, phi_rad: float, ref_rad: float, m: Measurement) -> float:  # pragma: no cover
        raise NotImplementedError

    def __repr__(self):
        return f"{type(self).__name__}(name={self.name!r}, dt={self.dt})"


# ------------------------------------------------------------------------------------------------ factory
CONTROLLERS: dict[str, str] = {}                 # name -> one-line description (filled by register_controller)
_FACTORIES: dict[str, Callable[..., Any]] = {}


def register_controller(name: str, factory: Callable[..., Any], description: str) -> None:
    """Make ``make_controller(name, **kw)`` call ``factory(**kw)``. The built-in controllers register
    themselves when their module is imported (``etb_gym.controllers`` imports them all)."""
    if not isinstance(name, str) or not name or ":" in name:
        raise ValueError(f"controller name {name!r} is invalid: expected a non-empty name without ':'")
    if not callable(factory):
        raise ValueError(f"controller {name!r}: factory must be callable, got {type(factory).__name__}")
    _FACTORIES[name] = factory
    CONTROLLERS[name] = str(description)


_PREFIXES: dict[str, Callable[..., Any]] = {}


def register_controller_prefix(prefix: str, loader: Callable[..., Any]) -> None:
    """Make ``make_controller("<prefix>:<rest>", **kw)`` call ``loader(rest, **kw)``.

    Example (the RL issue): ``register_controller_prefix("rl", lambda path, **kw: PolicyController(path, **kw))``.
    A prefix must be a short identifier (no dots), so it never collides with a "module:Class" spec."""
    if not isinstance(prefix, str) or not prefix.isidentifier() or "." in prefix:
        raise ValueError(f"controller prefix {prefix!r} is invalid: expected an identifier like 'rl'")
    if not callable(loader):
        raise ValueError(f"controller prefix {prefix!r}: loader must be callable, got {type(loader).__name__}")
    _PREFIXES[prefix] = loader


def controller_prefixes() -> dict[str, Callable[..., Any]]:
    return dict(_PREFIXES)


def _autoregister_prefixes() -> None:
    """Let other parts of the package register their prefix on first use (e.g. "rl" by the RL module)."""
    for mod in ("etb_gym.rl", "etb_gym.controllers.rl", "etb_gym.controllers.policy"):
        try:
            importlib.import_module(mod)
        except ImportError:
            pass


def _valid_specs() -> str:
    pre = sorted(set(_PREFIXES))
    return (f"built-in names {sorted(CONTROLLERS)}, 'module:Class'"
            + (f", or a prefix spec {[p + ':...' for p in pre]}" if pre else ""))


def make_controller(spec, **kw):
    """Build a controller from a spec: a built-in name, "module:Class", "<prefix>:<arg>", or an instance
    (returned as is). Keyword arguments go to the constructor / loader (unknown ones raise TypeError)."""
    if not isinstance(spec, str):
        if isinstance(spec, Controller):
            return spec
        raise ValueError(f"controller spec {spec!r} is invalid: expected a string ({_valid_specs()}) "
                         "or an object with name, dt, reset(seed) and act(observation)")
    s = spec.strip()
    if s in _FACTORIES:
        ctrl = _FACTORIES[s](**kw)
    elif ":" in s:
        head, rest = s.split(":", 1)
        if head not in _PREFIXES and "." not in head:
            _autoregister_prefixes()
        if head in _PREFIXES:
            ctrl = _PREFIXES[head](rest, **kw)
        else:
            try:
                mod = importlib.import_module(head)
            except ImportError as exc:
                raise ValueError(f"controller spec {spec!r}: cannot import module {head!r} ({exc}); "
                                 f"valid: {_valid_specs()}") from None
            obj = mod
            for part in rest.split("."):
                if not hasattr(obj, part):
                    raise ValueError(f"controller spec {spec!r}: module {head!r} has no attribute {rest!r}")
                obj = getattr(obj, part)
            if not callable(obj):
                raise ValueError(f"controller spec {spec!r}: {rest!r} is not a class or factory")
            ctrl = obj(**kw)
    else:
        raise ValueError(f"unknown controller {spec!r}: valid are {_valid_specs()}")
    missing = [a for a in ("name", "dt", "reset", "act") if not hasattr(ctrl, a)]
    if missing:
        raise ValueError(f"controller spec {spec!r} built a {type(ctrl).__name__} without {missing}: "
                         "a controller needs name, dt, reset(seed) and act(observation)")
    return ctrl
