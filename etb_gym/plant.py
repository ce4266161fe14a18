"""A throttle plant composed of components; builds the paper's nine models "1A".."3C" by name.

    >>> from etb_gym import make_plant
    >>> plant = make_plant("3B")                       # LuGre friction + nonlinear-inductance drive
    >>> traj = plant.simulate(voltage=np.full(500, 5.0), angle_deg=3.0)   # 0.5 s at 5 V
    >>> traj.angle_deg[-1]

Model names follow Table 3 of the paper: the digit is the friction model (1 viscous, 2 Dahl, 3 LuGre),
the letter the electric drive (A linear, B nonlinear inductance, C extended flux model).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Iterable, Mapping

import numpy as np

from .components.base import Component, show
from .components.drive import DRIVES
from .components.rotor import RotorParams
from .components.supply import SUPPLY_RANGE_V, SupplyParams
from .integrate import Engine, ensure_thread_pool, solve_ivp_reference
from .plant_description import CORE_ROLES, MODELS, PLANT_SCHEMA, model_components, plant_arguments

__all__ = ["CORE_ROLES", "MODELS", "PLANT_SCHEMA", "Plant", "Trajectory", "make_plant"]


@dataclass
class Trajectory:
    """Arrays sampled at the control period; index 0 is the initial state."""

    t_s: np.ndarray
    states: np.ndarray            # (n+1, n_states), see Plant.state_names
    duty: np.ndarray              # (n+1,) duty applied during the period that *ends* at t (duty[0] = nan)
    voltage_V: np.ndarray         # (n+1,) bridge voltage averaged over that period
    torques_Nm: dict              # component name -> (n+1,) torque on the shaft at the end of the period
    state_names: tuple

    @property
    def angle_rad(self):
        return self.states[:, 0]

    @property
    def angle_deg(self):
        return np.degrees(self.states[:, 0])

    @property
    def velocity_rad_s(self):
        return self.states[:, 1]

    @property
    def current_A(self):
        return self.states[:, 2]

    def state(self, name: str) -> np.ndarray:
        return self.states[:, self.state_names.index(name)]


class Plant:
    """An ETB plant: rotor + drive + components + supply/bridge, integrated at a fixed control rate.

    Parameters
    ----------
    drive, friction, spring, stops : Component
        The physics. ``friction``/``spring``/``stops`` may be ``None`` (e.g. the drive-only experiment
        of sec. 4.4).
    effects : iterable of Component
        Extra physics (the diagnosis tool's effects): any registered component.
    rotor : RotorParams
    supply : SupplyParams
        Battery voltage, PWM frequency and PWM mode ("averaged" or "switching").
    control_period_s : float
        The period at which the duty is updated (default 1 ms).
    substeps : int
        Fixed integrator substeps per control period (default 20, i.e. 50 us at 1 ms).
    """

    def __init__(self, drive: Component, friction: Component | None = None, spring: Component | None = None,
                 stops: Component | None = None, effects: Iterable[Component] = (),
                 rotor: RotorParams = RotorParams(), supply: SupplyParams = SupplyParams(),
                 control_period_s: float = 1e-3, substeps: int = 20, model: str | None = None):
        if drive is None or getattr(drive, "role", None) != "drive":
            raise ValueError(f"Plant.drive must be a drive component ({', '.join(c.__name__ for c in DRIVES.values())}), "
                             f"got {type(drive).__name__}")
        for role, c in (("friction", friction), ("spring", spring), ("stops", stops)):
            if c is not None and not isinstance(c, Component):
                raise ValueError(f"Plant.{role} must be a Component or None, got {type(c).__name__}")
        if isinstance(control_period_s, bool) or not (isinstance(control_period_s, (int, float))
                                                      and math.isfinite(control_period_s) and control_period_s > 0):
            raise ValueError(f"Plant.control_period_s = {control_period_s!r} is invalid: expected a finite value > 0 s")
        if isinstance(substeps, bool) or not (isinstance(substeps, (int, np.integer)) and substeps >= 1):
            raise ValueError(f"Plant.substeps = {substeps!r} is invalid: expected an integer >= 1")
        if not isinstance(rotor, RotorParams):
            raise ValueError(f"Plant.rotor must be RotorParams, got {type(rotor).__name__}")
        if not isinstance(supply, SupplyParams):
            raise ValueError(f"Plant.supply must be SupplyParams, got {type(supply).__name__}")
        self.drive, self.friction, self.spring, self.stops = drive, friction, spring, stops
        self.effects = tuple(effects)
        for e in self.effects:
            if not isinstance(e, Component):
                raise ValueError(f"Plant.effects must hold Components, got {type(e).__name__}")
        self.rotor, self.supply = rotor, supply
        self.control_period_s = float(control_period_s)
        self.substeps = int(substeps)
        self.model = model
        if stops is not None and spring is not None:
            lh = spring.params.limp_home_rad
            lo, hi = stops.params.closed_rad, stops.params.open_rad
            if not lo < lh < hi:
                raise ValueError(f"LimpHomeSpringParams.limp_home_rad = {lh!r} is invalid: expected an angle "
                                 f"strictly between the end stops ({lo} rad, {hi} rad)")
        if self.supply.switching:
            n = self.control_period_s * self.supply.pwm_frequency_hz
            if abs(n - round(n)) > 1e-6 or round(n) < 1:
                raise ValueError(f"SupplyParams.pwm_frequency_hz = {self.supply.pwm_frequency_hz!r} is invalid in "
                                 f"switching mode: expected a whole number of PWM periods per control period "
                                 f"({self.control_period_s} s), got {n:.4g}")
        self.components = tuple(c for c in (drive, friction, spring, stops) if c is not None) + self.effects
        names = [self._name(c) for c in self.components]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f"Plant: two components share the name(s) {sorted(dup)}")
        self.component_names = tuple(names)
        vecs = [np.asarray(c.param_vector(), float) for c in self.components]
        self.engine = Engine(self.components, vecs)
        self.P = np.concatenate([[rotor.inertia_kg_m2], *vecs])
        self.state_names = ("angle_rad", "velocity_rad_s", "current_A") + tuple(
            f"{n}.{s}" for n, c in zip(names, self.components) for s in c.state_names)
        self._lock_from_stops()

    # ------------------------------------------------------------------------------ pickling
    def __getstate__(self):
        """Everything but the compiled engine (its generated functions live in a module made at run time);
        ``__setstate__`` rebuilds it from the components, from the kernel cache when it was compiled before."""
        state = dict(self.__dict__)
        state.pop("engine", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self.engine = Engine(self.components, [np.asarray(c.param_vector(), float) for c in self.components])

    # ------------------------------------------------------------------------------ introspection
    def _name(self, c):
        for role in CORE_ROLES:
            if getattr(self, role, None) is c:
                return role
        return getattr(c, "name", None) or c.kind.split(".")[-1] or type(c).__name__

    def _lock_from_stops(self):
        self.angle_min_rad = self.stops.params.closed_rad if self.stops is not None else -math.inf
        self.angle_max_rad = self.stops.params.open_rad if self.stops is not None else math.inf

    @property
    def n_states(self):
        return self.engine.layout.n_states

    @property
    def fast(self) -> bool:
        """True when this plant runs on the compiled fast path."""
        return self.engine.fast

    @property
    def state_slices(self) -> tuple:
        """``(start, stop)`` of each component's own states in the state vector, in ``components`` order."""
        return self.engine.layout.state_slices

    def stepper(self, path: str = "fast"):
        """The generated stepper of this composition, for callers that run their own loops (the envs):
        ``rhs(t, x, u, P, dx, aux)``, ``control_step(x, d, V, P, t0, dt, substeps, switching, f_pwm, aux) -> ok``,
        ``simulate``, ``batch_step``, ``batch_step_serial``. ``path``: "fast" (compiled when available) or
        "plain" (pure Python, the same operations). The methods of this class are the checked way in."""
        if path not in ("fast", "plain"):
            raise ValueError(f"path = {path!r}: expected 'fast' or 'plain'")
        return self.engine.fns if path == "fast" else self.engine.plain

    @property
    def limp_home_rad(self):
        return self.spring.params.limp_home_rad if self.spring is not None else 0.0

    def component(self, name: str) -> Component:
        if name not in self.component_names:
            raise KeyError(f"no component {name!r}; this plant has {list(self.component_names)}")
        return self.components[self.component_names.index(name)]

    def __repr__(self):
        parts = ", ".join(f"{n}={type(c).__name__}" for n, c in zip(self.component_names, self.components))
        return f"Plant({self.model or 'custom'}: {parts}, supply={self.supply.voltage_V} V {self.supply.pwm_mode})"

    # ------------------------------------------------------------------------------ variants
    def replace(self, **kw) -> "Plant":
        """A copy with some constructor arguments replaced (drive=, friction=, effects=, supply=, ...)."""
        args = dict(drive=self.drive, friction=self.friction, spring=self.spring, stops=self.stops,
                    effects=self.effects, rotor=self.rotor, supply=self.supply,
                    control_period_s=self.control_period_s, substeps=self.substeps, model=self.model)
        unknown = sorted(set(kw) - set(args))
        if unknown:
            raise ValueError(f"Plant.replace: unknown argument(s) {unknown}; valid: {sorted(args)}")
        args.update(kw)
        return Plant(**args)

    def with_params(self, overrides: Mapping[str, float] | None = None, **kw) -> "Plant":
        """A copy with parameters changed, keyed "component.field" (e.g. "friction.coulomb_Nm",
        "supply.voltage_V", "rotor.inertia_kg_m2", "drive.resistance_ohm")."""
        changes = dict(overrides or {})
        changes.update(kw)
        if not changes:
            return self
        groups = self.parse_overrides(changes)
        new = {}
        effects = list(self.effects)
        for comp, fields in groups.items():
            if comp == "rotor":
                new["rotor"] = self.rotor.replace(**fields)
            elif comp == "supply":
                new["supply"] = self.supply.replace(**fields)
            elif comp in CORE_ROLES and getattr(self, comp) is not None:
                new[comp] = getattr(self, comp).with_params(**fields)
            else:
                k = self.component_names.index(comp) - sum(getattr(self, r) is not None for r in CORE_ROLES)
                effects[k] = effects[k].with_params(**fields)
                new["effects"] = effects
        return self.replace(**new)

    def parse_overrides(self, overrides: Mapping, *, supply: bool = True) -> dict[str, dict]:
        """The one "component.field" parser: {"friction.coulomb_Nm": 0.1} -> {"friction": {"coulomb_Nm": 0.1}}.
        Errors name the key and list the valid components or fields; values are type-checked by the
        components' parameter classes when applied."""
        valid = {"rotor": RotorParams, **({"supply": SupplyParams} if supply else {})}
        valid.update({n: c.Params for n, c in zip(self.component_names, self.components)})
        groups: dict[str, dict] = {}
        for key, val in overrides.items():
            if not isinstance(key, str) or key.count(".") < 1 or not all(key.split(".", 1)):
                raise ValueError(f"parameter override {show(key)}: expected 'component.field' with component one of "
                                 f"{sorted(valid)}")
            comp, field = key.split(".", 1)
            if comp not in valid:
                hint = " (the supply is not part of P; pass supply_V to step()/simulate())" if comp == "supply" else ""
                raise ValueError(f"parameter override {key!r}: unknown component {comp!r}{hint}; valid: {sorted(valid)}")
            fields = [f.name for f in dataclasses.fields(valid[comp])]
            if field not in fields:
                raise ValueError(f"parameter override {key!r}: unknown parameter {field!r} of {comp} ({valid[comp].__name__}); "
                                 f"valid: {fields}")
            groups.setdefault(comp, {})[field] = val
        return groups

    def param_vector(self, overrides: Mapping[str, float] | None = None) -> np.ndarray:
        """The packed parameter vector P, optionally with "component.field" overrides applied and
        validated, without building a new plant. For per-episode randomization: the result can be
        stepped by this plant's engine (same layout) via ``step(..., P=...)`` or ``step_batch``."""
        if not overrides:
            return self.P.copy()
        rotor = self.rotor
        comps = list(self.components)
        for comp, fields in self.parse_overrides(overrides, supply=False).items():
            if comp == "rotor":
                rotor = rotor.replace(**fields)
            else:
                k = self.component_names.index(comp)
                comps[k] = comps[k].with_params(**fields)
        vecs = [np.asarray(c.param_vector(), float) for c in comps]
        P = np.concatenate([[rotor.inertia_kg_m2], *vecs])
        if P.shape != self.P.shape:
            raise ValueError("these overrides change the parameter layout (e.g. an inductance table); "
                             "build a new plant with with_params() instead")
        return P

    def params_dict(self) -> dict:
        """Flat {"component.field": value} of all scalar parameters."""
        out = {f"rotor.{k}": v for k, v in self.rotor.to_dict().items()}
        out.update({f"supply.{k}": v for k, v in self.supply.to_dict().items()})
        for n, c in zip(self.component_names, self.components):
            for k, v in c.params.to_dict().items():
                if isinstance(v, (int, float)) and not isinstance(v, bool):
                    out[f"{n}.{k}"] = v
        return out

    def to_dict(self) -> dict:
        """A plain description of the plant (the plant-file format, see docs/plant-file.md)."""
        d = {"schema": PLANT_SCHEMA, "model": self.model, "control_period_s": self.control_period_s,
             "substeps": self.substeps, "rotor": self.rotor.to_dict(), "supply": self.supply.to_dict()}
        for role in CORE_ROLES:
            c = getattr(self, role)
            d[role] = None if c is None else c.to_dict()
        d["effects"] = [dict(e.to_dict(), name=self._name(e)) for e in self.effects]
        return d

    @classmethod
    def from_dict(cls, d: Mapping) -> "Plant":
        """Build a plant from its plain description (a parsed plant file, docs/plant-file.md). Every error names
        the key (``rotor.inertia_kg_m2``, ``effects[1].params.gain``) and what was expected
        (etb_gym/plant_description.py)."""
        return cls(**plant_arguments(d))

    # ------------------------------------------------------------------------------ states
    def initial_state(self, angle_rad: float | None = None, velocity_rad_s: float = 0.0, current_A: float = 0.0,
                      at_rest: bool = True) -> np.ndarray:
        """A full state vector. ``angle_rad`` defaults to limp-home.

        With ``at_rest`` the friction states are set to hold whatever torque acts on the resting plate,
        as far as static friction can, so a plate placed at an angle behaves like one that stopped there.
        """
        phi = self.limp_home_rad if angle_rad is None else float(angle_rad)
        for nm, v in (("angle_rad", phi), ("velocity_rad_s", velocity_rad_s), ("current_A", current_A)):
            if not math.isfinite(v):
                raise ValueError(f"initial {nm} = {show(v)}: expected a finite number")
        if not (self.angle_min_rad - 1e-9 <= phi <= self.angle_max_rad + 1e-9):
            raise ValueError(f"initial angle_rad = {phi!r} is outside the end stops "
                             f"[{self.angle_min_rad}, {self.angle_max_rad}] rad")
        x = np.zeros(self.n_states)
        x[0], x[1], x[2] = phi, velocity_rad_s, current_A
        lay = self.engine.layout
        for k, c in enumerate(self.components):
            s0, s1 = lay.state_slices[k]
            x[s0:s1] = c.initial_state()
        if at_rest and velocity_rad_s == 0.0:
            dx = np.empty(self.n_states)
            aux = np.zeros(len(self.components))
            self.engine.fns.rhs(0.0, x, 0.0, read_only(self.P), dx, aux)
            held = float(np.sum(aux))
            for k, c in enumerate(self.components):
                s0, s1 = lay.state_slices[k]
                if s1 > s0:
                    x[s0:s1] = c.rest_state(x[s0:s1].copy(), held)
        return x

    # ------------------------------------------------------------------------------ stepping
    def _inputs(self, n, duty, voltage, supply_V):
        V = self.supply.voltage_V if supply_V is None else supply_V
        Vs = np.broadcast_to(np.asarray(V, float), (n,)).copy() if np.ndim(V) == 0 else np.asarray(V, float)
        if Vs.shape != (n,):
            raise ValueError(f"supply_V has shape {Vs.shape}: expected a scalar or shape ({n},)")
        lo, hi = SUPPLY_RANGE_V
        bad = ~np.isfinite(Vs) | (Vs < lo) | (Vs > hi)
        if bad.any():
            k = int(np.argmax(bad))
            raise ValueError(f"supply_V[{k}] = {show(Vs[k])} is invalid: expected a voltage in [{lo:g}, {hi:g}] V")
        if (duty is None) == (voltage is None):
            raise ValueError("give exactly one of duty= (H-bridge duty in [-1, 1]) or voltage= (V)")
        if duty is not None:
            d = np.asarray(duty, float).reshape(-1)
            bad = ~np.isfinite(d)
            if bad.any():
                k = int(np.argmax(bad))
                raise ValueError(f"duty[{k}] = {show(d[k])}: expected a finite duty cycle in [-1, 1]")
            out = np.abs(d) > 1 + 1e-12
            if out.any():
                k = int(np.argmax(out))
                raise ValueError(f"duty[{k}] = {show(d[k])}: expected a duty cycle in [-1, 1]")
            return np.clip(d, -1, 1), Vs
        v = np.asarray(voltage, float).reshape(-1)
        bad = ~np.isfinite(v)
        if bad.any():
            k = int(np.argmax(bad))
            raise ValueError(f"voltage[{k}] = {show(v[k])}: expected a finite voltage")
        if v.shape != (n,):
            raise ValueError(f"voltage has shape {v.shape}: expected ({n},)")
        over = np.abs(v) > Vs * (1 + 1e-12)
        if over.any():
            k = int(np.argmax(over))
            raise ValueError(f"voltage[{k}] = {show(v[k])} V exceeds the supply ({Vs[k]} V): the H-bridge can only "
                             f"apply voltages in [-supply, +supply]")
        return np.clip(v / Vs, -1, 1), Vs

    def simulate(self, duty=None, *, voltage=None, x0=None, angle_deg: float | None = None,
                 supply_V=None, t0: float = 0.0, path: str = "fast") -> Trajectory:
        """Simulate a sequence of control periods.

        Give ``duty`` (H-bridge duty in [-1, 1] per control period) or ``voltage`` (V per period, at most
        the supply voltage). Start from ``x0`` (a full state) or a plate at rest at ``angle_deg``
        (default limp-home). ``path``: "fast" (compiled when available) or "plain" (pure Python).
        """
        seq = duty if duty is not None else voltage
        if seq is None:
            raise ValueError("give exactly one of duty= (H-bridge duty in [-1, 1]) or voltage= (V)")
        n = int(np.size(seq))
        if n < 1:
            raise ValueError("simulate needs at least one control period of input")
        d, Vs = self._inputs(n, duty, voltage, supply_V)
        if x0 is None:
            x0 = self.initial_state(None if angle_deg is None else math.radians(angle_deg))
        else:
            x0 = self.check_state(x0)
        if path not in ("fast", "plain"):
            raise ValueError(f"path = {path!r}: expected 'fast' or 'plain'")
        fns = self.engine.fns if path == "fast" else self.engine.plain
        X = np.empty((n + 1, self.n_states))
        A = np.empty((n + 1, len(self.components)))
        done = fns.simulate(x0, d, Vs, self.P, float(t0), self.control_period_s, self.substeps,
                            self.supply.switching, self.supply.pwm_frequency_hz, X, A)
        if done < n:
            raise FloatingPointError(self.divergence_message(X[done + 1], t0 + (done + 1) * self.control_period_s))
        return self._trajectory(X, A, d, Vs, t0)

    def _trajectory(self, X, A, d, Vs, t0):
        n = len(d)
        t = t0 + self.control_period_s * np.arange(n + 1)
        duty = np.concatenate([[np.nan], d])
        volt = np.concatenate([[np.nan], d * Vs])
        torques = {nm: A[:, k] for k, nm in enumerate(self.component_names)}
        return Trajectory(t, X, duty, volt, torques, self.state_names)

    def reference(self, duty=None, *, voltage=None, x0=None, angle_deg=None, supply_V=None, t0=0.0,
                  method="LSODA", rtol=1e-9) -> Trajectory:
        """The same simulation with scipy's adaptive ``solve_ivp`` (the accuracy reference)."""
        seq = duty if duty is not None else voltage
        n = int(np.size(seq))
        d, Vs = self._inputs(n, duty, voltage, supply_V)
        x0 = self.initial_state(None if angle_deg is None else math.radians(angle_deg)) if x0 is None \
            else self.check_state(x0)
        P = read_only(self.P)
        X = solve_ivp_reference(self.engine, P, x0, d, Vs, self.control_period_s, t0=t0,
                                switching=self.supply.switching, f_pwm=self.supply.pwm_frequency_hz,
                                method=method, rtol=rtol)
        A = np.zeros((n + 1, len(self.components)))
        dx = np.empty(self.n_states)
        for k in range(n + 1):
            self.engine.fns.rhs(t0 + k * self.control_period_s, X[k], d[max(k - 1, 0)] * Vs[max(k - 1, 0)],
                                P, dx, A[k])
        return self._trajectory(X, A, d, Vs, t0)

    def check_state(self, x) -> np.ndarray:
        x = np.array(x, dtype=float).reshape(-1)
        if x.shape != (self.n_states,):
            raise ValueError(f"state has {x.size} entries: expected {self.n_states} {self.state_names}")
        bad = ~np.isfinite(x)
        if bad.any():
            k = int(np.argmax(bad))
            raise ValueError(f"state {self.state_names[k]} = {show(x[k])}: expected a finite number")
        return x

    def step_batch(self, X: np.ndarray, duty: np.ndarray, supply_V: np.ndarray, P: np.ndarray,
                   t0: np.ndarray, aux: np.ndarray, parallel: bool | None = None) -> np.ndarray:
        """Advance N plants (rows of X, P) by one control period in one compiled, parallel call.

        X (N, n_states) and aux (N, n_components) are updated in place; duty, supply_V, t0 are (N,).
        Duties must already be finite and inside [-1, 1] (the vector env checks them). Returns a bool
        array: False where a plant's state became non-finite. ``parallel`` (default: N > 1) False runs
        the same loop on the calling thread, saving the thread-pool launch (~2 us) when it cannot pay."""
        n = X.shape[0]
        ok = np.empty(n, dtype=np.bool_)
        fns = self.engine.fns
        if n > 1 if parallel is None else parallel:
            ensure_thread_pool()          # once per process: numba's pool sleeps, not spins (integrate.py)
            fn = fns.batch_step
        else:
            fn = fns.batch_step_serial
        fn(X, duty, supply_V, P, t0, self.control_period_s, self.substeps, self.supply.switching,
           self.supply.pwm_frequency_hz, aux, ok)
        return ok

    def step(self, x: np.ndarray, duty: float, supply_V: float | None = None, t0: float = 0.0,
             aux: np.ndarray | None = None, P: np.ndarray | None = None) -> np.ndarray:
        """Advance state ``x`` (updated in place and returned) by one control period at ``duty``.

        ``P`` optionally replaces the plant's parameter vector (see :meth:`param_vector`)."""
        if not math.isfinite(duty):
            raise ValueError(f"duty = {duty!r}: expected a finite duty cycle in [-1, 1]")
        d = min(1.0, max(-1.0, float(duty)))
        V = self.supply.voltage_V if supply_V is None else float(supply_V)
        if aux is None:
            aux = np.zeros(len(self.components))
        ok = self.engine.fns.control_step(x, d, V, self.P if P is None else P, float(t0), self.control_period_s, self.substeps,
                                          self.supply.switching, self.supply.pwm_frequency_hz, aux)
        if not ok:
            raise FloatingPointError(self.divergence_message(x, float(t0) + self.control_period_s))
        return x

    def divergence_message(self, x, t_s: float) -> str:
        """The sentence a caller raises when the stepper reports a state that is not physical."""
        state = ", ".join(f"{n} = {float(v):.6g}" for n, v in zip(self.state_names, x))
        return (f"the simulation diverged at t = {t_s:.6f} s: the state left the physical range (not finite, the "
                f"plate more than 29 deg beyond an end stop, or a coil current beyond 4 x supply / resistance): "
                f"{state}. The parameters are outside what the fixed-rate stepper is stable for "
                f"(docs/model.md, sec. 9)")


def read_only(P: np.ndarray) -> np.ndarray:
    """A read-only view of the parameter vector P, for calls of the generated ``rhs`` from Python: numba compiles a
    function once per argument type, and the envs hand it their read-only P, so a writable P here compiled rhs
    (the whole right-hand side, inlined) a second time for every composition stepped by both."""
    v = P.view()
    v.setflags(write=False)
    return v


def make_plant(model: str = "3B", overrides: Mapping[str, float] | None = None, *,
               pwm_mode: str | None = None, supply_V: float | None = None, control_period_s: float = 1e-3,
               substeps: int = 20, effects: Iterable[Component] = ()) -> Plant:
    """Build one of the paper's nine models ("1A".."3C") with the documented default parameters.

    ``overrides`` changes parameters by "component.field" (see :meth:`Plant.with_params`).
    """
    core = model_components(model)
    supply = SupplyParams()
    if pwm_mode is not None:
        supply = supply.replace(pwm_mode=pwm_mode)
    if supply_V is not None:
        supply = supply.replace(voltage_V=supply_V)
    plant = Plant(**core, effects=effects, supply=supply, control_period_s=control_period_s, substeps=substeps)
    return plant.with_params(overrides) if overrides else plant
