"""What every physical component is made of: a frozen parameter dataclass and a kernel.

A component contributes to the plant through one scalar *kernel* with the signature::

    kernel(t, phi, omega, i, u, s, p, ds) -> (torque_Nm, voltage_drop_V, inductance_H)

``t`` time [s], ``phi`` plate angle [rad] (0 = closed, opening positive), ``omega`` angular velocity
[rad/s], ``i`` coil current [A], ``u`` bridge output voltage at the coil terminals [V], ``s`` the
component's own states (a slice of the plant state), ``p`` its packed parameters (``param_vector()``),
``ds`` where it writes the time derivatives of its own states.

It returns the torque it applies to the shaft (opening positive), the voltage it drops in the coil loop
(the drive's ``R*i + e_back``, a bridge loss, ...) and the inductance it adds to the coil loop. The plant
sums all contributions:  J*domega/dt = sum(torque),  sum(L)*di/dt = u - sum(voltage_drop).

A component whose states need a special update at the integrator's fixed step (stiff friction bristles)
also provides ``advance(h, t, phi, omega, i, u, s, p)`` which updates ``s`` in place; otherwise the
integrator applies explicit Euler with ``ds``. Adding a component never means editing the integrator:
the integrator composes whatever kernels the plant holds (see ``etb_gym/integrate.py``).

A component whose kernel and advance both need the same costly value of the shaft and coil state (LuGre:
the Stribeck curve g(omega)) may declare ``carry(phi, omega, i, p) -> float``; its kernel and advance then
take that value as an extra last argument ``c``. The integrator computes it once per substep, at the new
state, and hands it to the advance and to the next substep's kernel, which sees exactly that state; so
a carry must depend on nothing but (phi, omega, i, p), never on t, u or the component's own states.

A component whose torque or voltage *jumps* at fixed angles (a contact that starts to damp: the end stops,
the limp-home contact) declares ``edges(phi0, omega0, phi1, omega1, p) -> theta``: the fraction theta in
(0, 1) of a substep at which the angle (or velocity), moving from phi0 to phi1 (omega0 to omega1), first
crosses one of those values (``crossing``), or 2.0 if it crosses none. The stepper then splits the substep
there, so that the scheme's order is not lost to the jump (etb_gym/integrate.py, "Contacts").

A stiff contact declares ``rate(phi, omega, J, p) -> 1/s``: the natural frequency sqrt(k/J) of the contact
while an impact is under way at (phi, omega) (J the inertia), 0 otherwise. The stepper cuts a substep that would be
too long for it into pieces of at most RHO_MAX / rate (integrate.py, "Contacts"), so an
impact is integrated accurately at any substep. A contact as stiff but slow (a plate pressed into a stop) may
return -sqrt(k/J): the stepper then cuts a substep only where h sqrt(k/J) > RHO_STIFF, into pieces the explicit
midpoint rule is stable on (integrate.py, "Contacts").

A component whose torque damps the shaft strongly (LuGre's bristle damping) declares
``damping(phi, omega, i, s, p) -> N m s/rad`` (with a carry: ``c`` as the last argument): -dT/domega of its
torque at (phi, omega, i) with its own states s frozen, on the side of the current direction of motion. Where
h * (sum of the dampings) / J > RHO_DAMP the stepper integrates omega with an exponential midpoint step for that
linear damping (exact on it at any h), elsewhere with the plain explicit midpoint (integrate.py, "Damping"). It
must be the damping, not a bound on it: the exponential weights assume it (a D far above the true damping
makes the step inaccurate, docs/model.md sec. 9).

A component that knows where its physics ends declares ``plausible(phi, omega, i, supply_V, p) -> bool``
(the end stops: the plate is not far beyond a stop; a drive: the coil current is not far beyond what the
supply can drive). The stepper checks it at the end of every control period and reports False as it
reports a non-finite state, so a diverging integration raises at its first non-physical state instead of
returning garbage.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar

import numpy as np

from ..jit import kernel

REGISTRY: dict[str, type["Component"]] = {}


def show(value: Any) -> str:
    """A value as a user typed it: numpy scalars without their type wrapper (``nan``, not ``np.float64(nan)``)."""
    if isinstance(value, np.generic):
        value = value.item()
    return repr(value)


def check(owner: str, field: str, value: Any, ok: bool, expected: str) -> None:
    """Raise a ValueError that names the parameter, its value and what was expected."""
    if not ok:
        raise ValueError(f"{owner}.{field} = {show(value)} is invalid: expected {expected}")


def check_types(owner: str, obj: Any) -> None:
    """Fields annotated float/int must hold numbers (not bool, not text); str fields must hold text."""
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        t = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
        if t in ("float", "int"):
            ok = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
            if t == "int" and ok:
                ok = float(v) == int(v) if math.isfinite(float(v)) else False
            if not ok:
                raise ValueError(f"{owner}.{f.name} = {show(v)} is invalid: expected "
                                 f"{'a number' if t == 'float' else 'a whole number'}, got {type(v).__name__}")
        elif t == "str" and not isinstance(v, str):
            raise ValueError(f"{owner}.{f.name} = {show(v)} is invalid: expected text, got {type(v).__name__}")


def check_finite(owner: str, obj: Any) -> None:
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if isinstance(v, (bool, str)) or v is None:
            continue
        if isinstance(v, (int, float)):
            check(owner, f.name, v, math.isfinite(v), "a finite number")


def positive(owner, obj, *names):
    for n in names:
        v = getattr(obj, n)
        check(owner, n, v, v > 0, "a value > 0")


def non_negative(owner, obj, *names):
    for n in names:
        v = getattr(obj, n)
        check(owner, n, v, v >= 0, "a value >= 0")


@kernel
def crossing(phi0, phi1, edge):
    """The fraction in (0, 1) of the way from phi0 to phi1 at which the angle ``edge`` is crossed (linear in
    between), or 2.0 if it is not crossed strictly."""
    a = phi0 - edge
    b = phi1 - edge
    if (a < 0.0 and b > 0.0) or (a > 0.0 and b < 0.0):
        return a / (a - b)
    return 2.0


@dataclasses.dataclass(frozen=True)
class Params:
    """Base of all parameter dataclasses: finite numbers, validated on construction."""

    def __post_init__(self):
        check_types(type(self).__name__, self)
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                object.__setattr__(self, f.name, float(v) if f.type in ("float", float) else v)
        check_finite(type(self).__name__, self)
        self.validate()

    def validate(self) -> None:  # overridden by subclasses
        pass

    def replace(self, **changes) -> "Params":
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - names)
        if unknown:
            raise ValueError(
                f"{type(self).__name__}: unknown parameter(s) {unknown}; valid: {sorted(names)}"
            )
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


class Component:
    """Base class. Subclasses set ``kind``, ``role``, ``Params``, ``kernel`` and optionally states."""

    kind: ClassVar[str] = ""          # registry id used in plant files, e.g. "friction.lugre"
    role: ClassVar[str] = "effect"    # drive | friction | spring | stops | effect
    Params: ClassVar[type[Params]]
    state_names: ClassVar[tuple[str, ...]] = ()
    state_units: ClassVar[tuple[str, ...]] = ()
    kernel: ClassVar[Any] = None      # set as staticmethod(kernel_fn) so instances return the dispatcher
    advance: ClassVar[Any] = None
    carry: ClassVar[Any] = None       # optional carry(phi, omega, i, p): see the module docstring
    edges: ClassVar[Any] = None       # optional edges(phi0, omega0, phi1, omega1, p) -> theta: see the module docstring
    plausible: ClassVar[Any] = None   # optional plausible(phi, omega, i, supply_V, p) -> bool: see the module docstring
    rate: ClassVar[Any] = None        # optional rate(phi, omega, J, p) -> 1/s: see the module docstring
    damping: ClassVar[Any] = None     # optional damping(phi, omega, i, s, p) -> N m s/rad: see the module docstring
    description: ClassVar[str] = ""

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        if cls.kind:
            REGISTRY[cls.kind] = cls

    def __init__(self, params: Params | None = None, /, **overrides):
        if params is None:
            params = self.Params()
        elif not isinstance(params, self.Params):
            raise TypeError(f"{type(self).__name__} expects {self.Params.__name__}, got {type(params).__name__}")
        if overrides:
            params = params.replace(**overrides)
        self.params = params

    # -- packing -------------------------------------------------------------------------------
    def param_vector(self) -> np.ndarray:
        """Parameters packed for the kernel (SI floats, order documented by the subclass)."""
        return np.array([float(getattr(self.params, f.name)) for f in dataclasses.fields(self.params)])

    def initial_state(self) -> np.ndarray:
        return np.zeros(len(self.state_names))

    def rest_state(self, s: np.ndarray, held_torque_Nm: float) -> np.ndarray:
        """States of this component for a plate at rest with ``held_torque_Nm`` acting on it.

        Friction components with presliding states override this so that a plate placed at an angle
        stays there if the static friction can hold it. Default: unchanged.
        """
        return s

    def with_params(self, **changes) -> "Component":
        new = type(self)(self.params.replace(**changes))
        if "name" in self.__dict__:
            new.name = self.name
        return new

    def to_dict(self) -> dict:
        return {"kind": self.kind, "params": self.params.to_dict()}

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.params!r})"

    def __eq__(self, other):
        return type(self) is type(other) and self.params == other.params

    def __hash__(self):
        return hash((type(self), self.params))
