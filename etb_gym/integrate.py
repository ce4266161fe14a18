"""The fixed-rate stepper, its compiled fast path, and the solve_ivp reference.

A plant is a list of components (see ``components/base.py``). From that list this module *generates*
the source of the stepper, written once and used in two builds:

    rhs(t, x, u, P, dx, aux)                        time derivatives of the full state (one evaluation)
    rhs_carried(t, x, u, P, dx, aux, c...)          the same, given the carried values c at x (below)
    substep(t, h, x, u, P, dx, aux, c...) -> c...   one semi-implicit Euler substep
    control_step(x, duty, V, P, t0, dt, n, sw, f, aux)   one control period: PWM bridge + n substeps
    control_step_dx(..., aux, dx)                   the same with caller-owned scratch dx (no allocation)
    simulate(x0, duty[], V[], P, ...)               many control periods
    batch_step(X, duty[], V[], P[], ...)            N independent plants, one control period each (parallel)
    batch_step_serial(...)                          the same on the calling thread
    control_step_group(...)                         GROUP plants of a batch in lockstep (averaged PWM)

The *plain* build binds the components' pure-Python kernels (``kernel.py_func``) and runs in CPython;
the *fast* build binds the numba dispatchers and is compiled (the batch step in parallel over plants).
Both execute the same source, so they agree to floating-point rounding, and the batch step equals N
single control steps bit for bit (tests/test_fast_path.py). Where the time goes and what each speed
measure bought: docs/speed.md.

State vector x = [phi_rad, omega_rad_s, i_A, <component states in plant order>];
parameter vector P = [J_kg_m2, <component parameter vectors in plant order>].

Substep scheme (h = dt/n): all kernels are evaluated at the start of the substep, then
    i     <- i + h * (u - sum E) / sum L
    omega <- omega + h * sum T / J
    phi   <- phi + h * omega_new                     (symplectic Euler: stiff contacts stay bounded)
    c_k   <- carry_k(phi_new, omega_new, i_new, p_k)  if the component has a carry (see below)
    s_k   <- advance_k(h, ..., omega_new) if the component has one, else s_k + h * ds_k

Carried values. A component may declare ``carry(phi, omega, i, p)``, a value of the shaft and coil state
that its kernel and its advance both need (LuGre: the Stribeck curve g(omega)); its kernel and advance
then take it as their last argument. The stepper computes it once per substep, at the new state, and
hands it to the advance and, as a local ``c<k>`` of the generated code, to the kernel evaluation of the
next substep: that kernel sees exactly this state (x[0:3] are written from the same locals, P does not
change), so the value is the one it would compute, bit for bit. Each control period (and every ``rhs``
call) starts from the state: ``c<k> = carry_k(x[0], x[1], x[2], p_k)``. Without carries the generated
functions simply have no ``c`` arguments. (LuGre: one exp and one sqrt fewer per substep; docs/speed.md.)
"""
from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import math
import os
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .jit import HAVE_NUMBA, py_func


class FastPathUnavailableWarning(RuntimeWarning):
    """A component has no compiled kernel, so the plant runs on the (slow) plain path."""


@dataclass(frozen=True)
class Layout:
    """Where each component's states and parameters sit in x and P."""

    n_states: int
    n_params: int
    state_slices: tuple   # per component (start, stop) in x
    param_slices: tuple   # per component (start, stop) in P


def layout(components, param_vectors) -> Layout:
    s0, p0 = 3, 1
    ss, ps = [], []
    for c, pv in zip(components, param_vectors):
        ns = len(c.state_names)
        ss.append((s0, s0 + ns))
        ps.append((p0, p0 + len(pv)))
        s0 += ns
        p0 += len(pv)
    return Layout(s0, p0, tuple(ss), tuple(ps))


GROUP = 2   # plants stepped in lockstep by batch_step (averaged PWM): -9 % CPU per plant-step, same bits


def generate_source(components, lay: Layout) -> str:
    """Python source of the stepper for this composition (kernels are bound as k0, k1, ..., advances as
    a0, ..., carries as g0, ...)."""
    n = len(components)
    carried = [k for k, c in enumerate(components) if c.carry is not None]

    def c_args(g=""):    # the carried values as trailing arguments: ", c1" (plant g of a group: ", c1g0")
        return "".join(f", c{k}{g}" for k in carried)

    def c_set(g=""):     # the left-hand side that receives them from substep: "c1 = " ("" without carries)
        return ", ".join(f"c{k}{g}" for k in carried) + " = " if carried else ""

    def c_init(x, P, g="", ind="    "):   # the carried values at the state x (start of a period, rhs)
        return "".join(f"{ind}c{k}{g} = g{k}({x}[0], {x}[1], {x}[2], {P}[{lay.param_slices[k][0]}:"
                       f"{lay.param_slices[k][1]}])\n" for k in carried)

    body = []
    for k, c in enumerate(components):
        (s0, s1), (p0, p1) = lay.state_slices[k], lay.param_slices[k]
        ck = f", c{k}" if k in carried else ""
        body.append(f"    tq, e, l = k{k}(t, phi, omega, i, u, x[{s0}:{s1}], P[{p0}:{p1}], dx[{s0}:{s1}]{ck})")
        body.append(f"    aux[{k}] = tq")
        body.append("    T += tq")
        body.append("    E += e")
        body.append("    L += l")
    eval_block = "\n".join(body)
    adv = [f"    c{k} = g{k}(phi, omega, i, P[{lay.param_slices[k][0]}:{lay.param_slices[k][1]}])"
           for k in carried]
    for k, c in enumerate(components):
        (s0, s1), (p0, p1) = lay.state_slices[k], lay.param_slices[k]
        if s1 == s0:
            continue
        if c.advance is not None:
            ck = f", c{k}" if k in carried else ""
            adv.append(f"    a{k}(h, t, phi, omega, i, u, x[{s0}:{s1}], P[{p0}:{p1}]{ck})")
        else:
            adv.append(f"    for j in range({s0}, {s1}):\n        x[j] += h * dx[j]")
    if carried:
        adv.append("    return " + ", ".join(f"c{k}" for k in carried))
    adv_block = "\n".join(adv) if adv else "    pass"
    G = GROUP
    setup = "".join(f"    xg{g} = X[b0 + {g}]\n    Pg{g} = P[b0 + {g}]\n    ag{g} = AUX[b0 + {g}]\n"
                    f"    dg{g} = DX[b0 + {g}]\n    ug{g} = duty[b0 + {g}] * supply_V[b0 + {g}]\n"
                    f"    tg{g} = T0[b0 + {g}]\n" + c_init(f"xg{g}", f"Pg{g}", f"g{g}") for g in range(G))
    steps = "\n".join(f"        {c_set(f'g{g}')}substep(tg{g} + k * h, h, xg{g}, ug{g}, Pg{g}, dg{g}, ag{g}"
                      f"{c_args(f'g{g}')})" for g in range(G))
    oks = "\n".join(f"    OK[b0 + {g}] = _finite(xg{g})" for g in range(G))
    return f'''# generated by etb_gym.integrate for: {", ".join(type(c).__name__ for c in components)}
import math
import numpy as np

N_AUX = {n}
N_STATES = {lay.n_states}
GROUP = {G}


def rhs(t, x, u, P, dx, aux):
{c_init("x", "P")}    rhs_carried(t, x, u, P, dx, aux{c_args()})


def rhs_carried(t, x, u, P, dx, aux{c_args()}):
    """rhs, given the components' carried values c<k> at the state x."""
    phi = x[0]
    omega = x[1]
    i = x[2]
    T = 0.0
    E = 0.0
    L = 0.0
{eval_block}
    dx[0] = omega
    dx[1] = T / P[0]
    dx[2] = (u - E) / L


def substep(t, h, x, u, P, dx, aux{c_args()}):
    """One substep from x, given the carried values at x; returns those at the new x."""
    rhs_carried(t, x, u, P, dx, aux{c_args()})
    i = x[2] + h * dx[2]
    omega = x[1] + h * dx[1]
    phi = x[0] + h * omega
    x[0] = phi
    x[1] = omega
    x[2] = i
{adv_block}


def control_step_dx(x, duty, supply_V, P, t0, dt, n_sub, switching, f_pwm, aux, dx):
    """One control period, with ``dx`` (N_STATES,) as scratch. Returns True if the state is finite afterwards."""
    x = borrow(x)
    P = borrow(P)
    aux = borrow(aux)
    dx = borrow(dx)
{c_init("x", "P")}    hmax = dt / n_sub
    if not switching:
        u = duty * supply_V
        h = dt / n_sub
        for k in range(n_sub):
            {c_set()}substep(t0 + k * h, h, x, u, P, dx, aux{c_args()})
    else:
        n_per = int(round(dt * f_pwm))
        if n_per < 1:
            n_per = 1
        Tp = dt / n_per
        a = abs(duty)
        von = supply_V if duty >= 0.0 else -supply_V
        t = t0
        for j in range(n_per):
            ton = a * Tp
            toff = Tp - ton
            if ton > 0.0:
                m = int(math.ceil(ton / hmax - 1e-9))
                if m < 1:  # an interval far shorter than a substep (duty a hair from 0 or +-1)
                    m = 1
                h = ton / m
                for k in range(m):
                    {c_set()}substep(t, h, x, von, P, dx, aux{c_args()})
                    t += h
            if toff > 0.0:
                m = int(math.ceil(toff / hmax - 1e-9))
                if m < 1:  # an interval far shorter than a substep (duty a hair from 0 or +-1)
                    m = 1
                h = toff / m
                for k in range(m):
                    {c_set()}substep(t, h, x, 0.0, P, dx, aux{c_args()})
                    t += h
    ok = True
    for j in range(N_STATES):
        if not math.isfinite(x[j]):
            ok = False
    return ok


def control_step(x, duty, supply_V, P, t0, dt, n_sub, switching, f_pwm, aux):
    """One control period. Returns True if the state is finite afterwards."""
    dx = np.empty(N_STATES)
    return control_step_dx(x, duty, supply_V, P, t0, dt, n_sub, switching, f_pwm, aux, dx)


def simulate(x0, duty, supply_V, P, t0, dt, n_sub, switching, f_pwm, X, A):
    """Steps len(duty) control periods from x0; X[k+1], A[k+1] after period k (X[0] = x0).

    Returns the number of periods completed with a finite state."""
    x = x0.copy()
    aux = np.zeros(N_AUX)
    dx = np.empty(N_STATES)
    rhs(t0, x, duty[0] * supply_V[0], P, dx, aux)
    X[0, :] = x
    A[0, :] = aux
    for k in range(duty.shape[0]):
        ok = control_step_dx(x, duty[k], supply_V[k], P, t0 + k * dt, dt, n_sub, switching, f_pwm, aux, dx)
        X[k + 1, :] = x
        A[k + 1, :] = aux
        if not ok:
            return k
    return duty.shape[0]


def _finite(x):
    ok = True
    for j in range(N_STATES):
        if not math.isfinite(x[j]):
            ok = False
    return ok


def control_step_group(X, duty, supply_V, P, T0, AUX, DX, OK, b0, dt, n_sub):
    """Plants b0 .. b0+GROUP-1 through one averaged-PWM control period in lockstep: each plant's operations
    are exactly those of control_step_dx, but the independent chains interleave, which lets the CPU
    overlap them (a substep is one long dependency chain of exp, sqrt and divisions). X, P, AUX
    come borrowed from batch_step; DX is borrowed here (all are the caller's arguments or locals that
    outlive this call)."""
    DX = borrow(DX)
    h = dt / n_sub
{setup}    for k in range(n_sub):
{steps}
{oks}


def batch_step(X, duty, supply_V, P, t0, dt, n_sub, switching, f_pwm, AUX, OK):
    """N plants (rows of X, P, AUX), one control period each, in parallel over plants."""
    n = X.shape[0]
    DX = np.empty((n, N_STATES))
    Xb = borrow(X)
    Pb = borrow(P)
    Ab = borrow(AUX)
    if switching:
        for b in prange(n):
            OK[b] = control_step_dx(Xb[b], duty[b], supply_V[b], Pb[b], t0[b], dt, n_sub, switching, f_pwm,
                                    Ab[b], DX[b])
    else:
        ng = n // GROUP
        for j in prange(ng + n - ng * GROUP):
            if j < ng:
                control_step_group(Xb, duty, supply_V, Pb, t0, Ab, DX, OK, j * GROUP, dt, n_sub)
            else:
                b = ng * GROUP + j - ng
                OK[b] = control_step_dx(Xb[b], duty[b], supply_V[b], Pb[b], t0[b], dt, n_sub, switching, f_pwm,
                                        Ab[b], DX[b])


def batch_step_serial(X, duty, supply_V, P, t0, dt, n_sub, switching, f_pwm, AUX, OK):
    """batch_step on the calling thread (no thread-pool launch: for one plant or one thread)."""
    n = X.shape[0]
    DX = np.empty((n, N_STATES))
    Xb = borrow(X)
    Pb = borrow(P)
    Ab = borrow(AUX)
    b0 = 0
    if not switching:
        while b0 + GROUP <= n:
            control_step_group(Xb, duty, supply_V, Pb, t0, Ab, DX, OK, b0, dt, n_sub)
            b0 += GROUP
    for b in range(b0, n):
        OK[b] = control_step_dx(Xb[b], duty[b], supply_V[b], Pb[b], t0[b], dt, n_sub, switching, f_pwm,
                                Ab[b], DX[b])
'''


def _kernel_digest(components) -> str:
    h = hashlib.sha256()
    for c in components:
        for fn in (c.kernel, c.advance, c.carry):
            if fn is None:
                continue
            f = py_func(fn)
            try:
                h.update(inspect.getsource(inspect.getmodule(f)).encode())
            except (OSError, TypeError):
                h.update(repr(f).encode())
    return h.hexdigest()


def _cache_dir() -> Path:
    d = os.environ.get("ETB_GYM_CACHE")
    return Path(d) if d else Path.home() / ".cache" / "etb_gym" / "kernels"


def _is_jitted(fn) -> bool:
    return fn is not None and hasattr(fn, "py_func") and hasattr(fn, "signatures")


def _importable(fn) -> bool:
    f = py_func(fn)
    mod = sys.modules.get(f.__module__)
    return mod is not None and f.__module__ != "__main__" and getattr(mod, f.__name__, None) is fn \
        and "<locals>" not in f.__qualname__


def _identity(a):
    return a


if HAVE_NUMBA:
    import numba as _nb
    from numba.extending import intrinsic as _intrinsic
    from numba.np.arrayobj import make_array as _make_array

    @_intrinsic
    def borrow(typingctx, arr):
        """A view of array argument ``arr`` without a reference count (meminfo NULL).

        Slicing a numba array increments and decrements its reference count atomically; the stepper
        slices x, P and dx for every kernel call of every substep, and in the parallel batch step all
        rows share one count, so the threads fought over one cache line. Views of a borrowed array
        skip the count. Only ever borrow a *function argument* (its caller keeps it alive), never a
        local temporary."""
        if not isinstance(arr, _nb.types.Array):
            return None

        def codegen(context, builder, sig, args):
            src = _make_array(arr)(context, builder, value=args[0])
            dst = _make_array(arr)(context, builder)
            for f in ("nitems", "itemsize", "data", "shape", "strides"):
                setattr(dst, f, getattr(src, f))
            dst.meminfo = context.get_constant_null(_nb.types.MemInfoPointer(arr.dtype))
            dst.parent = context.get_constant_null(_nb.types.pyobject)
            return dst._getvalue()

        return arr(arr), codegen
else:  # pragma: no cover
    borrow = _identity


def configure_thread_pool() -> str:
    """Make numba's parallel batch step sleep, not spin, while it waits (called once at import).

    numba's default OpenMP layer busy-waits between parallel regions (libgomp's default spin). On a
    machine whose cores are shared (CI, several jobs, an RL learner stepping its envs) the spinning
    thread steals the core its partner needs: measured on a loaded 2-core machine, the 1024-plant
    batch step took 5.6-7.8 us of CPU per plant-step with spinning vs 1.4 us with sleeping
    (docs/speed.md). So, unless the user chose (``OMP_WAIT_POLICY``, ``GOMP_SPINCOUNT`` or
    ``NUMBA_THREADING_LAYER`` set), set ``OMP_WAIT_POLICY=PASSIVE`` before libgomp loads, or, if an
    OpenMP runtime is already loaded (torch imported first), pick numba's sleeping ``workqueue``
    layer. Returns what it did."""
    if not HAVE_NUMBA:
        return "no numba"
    env = os.environ
    if any(k in env for k in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "NUMBA_THREADING_LAYER")):
        return "user setting kept"
    import numba

    try:
        with open("/proc/self/maps") as fh:
            gomp_loaded = "libgomp" in fh.read()
    except OSError:
        gomp_loaded = False
    if not gomp_loaded:
        env["OMP_WAIT_POLICY"] = "PASSIVE"
        return "OMP_WAIT_POLICY=PASSIVE"
    if numba.config.THREADING_LAYER == "default":
        try:
            numba.threading_layer()          # raises until a parallel region ran
            return "thread pool already running"
        except ValueError:
            numba.config.THREADING_LAYER = "workqueue"
            return "numba threading layer workqueue"
    return "user setting kept"


THREAD_POOL = configure_thread_pool()


# numba options of the generated functions. rhs and substep are inlined at numba-IR level into their
# callers: LLVM then keeps the state in registers across substeps and prunes the reference counting of
# the kernels' slices (measured: -35 % CPU per plant-step for 3B, docs/speed.md). No fastmath: it would
# change rounding against the plain path (contract -> FMA) or fold away the finiteness check (nnan/ninf).
JIT_OPTIONS = {
    "rhs": {"inline": "always"},
    "rhs_carried": {"inline": "always"},
    "substep": {"inline": "always"},
    "control_step_dx": {},
    "control_step": {},
    "simulate": {},
    "_finite": {},
    "control_step_group": {},
    "batch_step": {"parallel": True},
    "batch_step_serial": {},
}
STEPPER_REVISION = "4"   # bump when borrow() or JIT_OPTIONS change: part of the kernel-cache digest


class Engine:
    """The compiled (or plain) stepper of one plant composition."""

    _cache: dict = {}
    _plain_cache: dict = {}

    def __init__(self, components, param_vectors):
        self.layout = layout(components, param_vectors)
        self.source = generate_source(components, self.layout)
        # the functions the generated source calls: k<k> kernel, a<k> advance, g<k> carry of component k
        self.bound = {f"{pre}{k}": fn for k, c in enumerate(components)
                      for pre, fn in (("k", c.kernel), ("a", c.advance), ("g", c.carry)) if fn is not None}
        self.fast = HAVE_NUMBA and all(_is_jitted(f) for f in self.bound.values())
        if HAVE_NUMBA and not self.fast:
            names = [type(c).__name__ for c in components
                     if not all(f is None or _is_jitted(f) for f in (c.kernel, c.advance, c.carry))]
            warnings.warn(f"component(s) {names} have no compiled kernel (decorate them with "
                          "etb_gym.jit.kernel); this plant runs on the plain Python path, ~100x slower",
                          FastPathUnavailableWarning, stacklevel=3)
        self.plain = self._build_plain()
        self.fns = self._build_fast(components) if self.fast else self.plain

    def _key(self):
        return (self.source, tuple(self.bound.items()))

    def _build_plain(self):
        fns = Engine._plain_cache.get(self._key())
        if fns is None:        # once per composition: plants of one composition share their stepper
            ns = {name: py_func(f) for name, f in self.bound.items()}
            ns["prange"] = range
            ns["borrow"] = _identity
            exec(compile(self.source, "<etb_gym plain stepper>", "exec"), ns)
            fns = Engine._plain_cache[self._key()] = _Fns(ns)
        return fns

    def _build_fast(self, components):
        key = self._key()
        if key in Engine._cache:
            return Engine._cache[key]
        import numba

        fns = None
        if all(_importable(f) for f in self.bound.values()):
            try:
                fns = self._load_cached_module(components)
            except OSError:
                fns = None
        if fns is None:  # kernels defined somewhere numba cannot cache from: compile in memory
            ns = dict(self.bound)
            ns["prange"] = numba.prange
            ns["borrow"] = borrow
            exec(compile(self.source, "<etb_gym fast stepper>", "exec"), ns)
            for name, opts in JIT_OPTIONS.items():
                ns[name] = numba.njit(**opts)(ns[name])
            fns = _Fns(ns)
        Engine._cache[key] = fns
        return fns

    def _load_cached_module(self, components):
        imports = [f"from {py_func(f).__module__} import {py_func(f).__name__} as {name}"
                   for name, f in self.bound.items()]
        src = self.source.replace("import numpy as np\n", "import numpy as np\nfrom numba import njit, prange\n"
                                  "from etb_gym.integrate import borrow\n"
                                  + "\n".join(imports) + "\n", 1)
        for name, opts in JIT_OPTIONS.items():
            args = ", ".join(f"{k}={v!r}" for k, v in dict(opts, cache=True).items())
            src = src.replace(f"\ndef {name}(", f"\n@njit({args})\ndef {name}(", 1)
        import numba

        digest = hashlib.sha256((src + _kernel_digest(components) + numba.__version__ + STEPPER_REVISION)
                                .encode()).hexdigest()[:20]
        d = _cache_dir()
        d.mkdir(parents=True, exist_ok=True)
        path = d / f"etb_kernel_{digest}.py"
        if not path.exists():
            from .io import write_atomic
            write_atomic(path, src, fsync=False)
        modname = f"etb_gym_kernels.k_{digest}"
        if modname in sys.modules:
            mod = sys.modules[modname]
        else:
            spec = importlib.util.spec_from_file_location(modname, path)
            mod = importlib.util.module_from_spec(spec)
            sys.modules[modname] = mod
            spec.loader.exec_module(mod)
        return _Fns(vars(mod))


class _Fns:
    def __init__(self, ns):
        self.rhs = ns["rhs"]
        self.substep = ns["substep"]
        self.control_step = ns["control_step"]
        self.simulate = ns["simulate"]
        self.batch_step = ns["batch_step"]
        self.batch_step_serial = ns["batch_step_serial"]
        self.control_step_dx = ns["control_step_dx"]


def solve_ivp_reference(engine: Engine, P, x0, duty, supply_V, dt, t0=0.0, switching=False, f_pwm=5000.0,
                        method="LSODA", rtol=1e-9, atol=None):
    """Integrate the same equations with scipy's adaptive solver, restarting at every input change.

    Returns X with X[k] the state after k control periods (X[0] = x0)."""
    from scipy.integrate import solve_ivp

    fns = engine.fns
    nx = engine.layout.n_states
    aux = np.zeros(len(engine.layout.state_slices))
    P = np.ascontiguousarray(P, float)
    if atol is None:
        atol = np.full(nx, 1e-10)
        atol[2] = 1e-9

    def f(t, x, u):
        dx = np.empty(nx)
        fns.rhs(t, np.array(x, float), u, P, dx, aux)
        return dx

    X = np.empty((len(duty) + 1, nx))
    X[0] = x = np.array(x0, float)
    for k in range(len(duty)):
        ta = t0 + k * dt
        if switching:
            n_per = max(1, int(round(dt * f_pwm)))
            Tp = dt / n_per
            a = abs(duty[k])
            von = supply_V[k] if duty[k] >= 0 else -supply_V[k]
            pieces = []
            for j in range(n_per):
                if a > 0:
                    pieces.append((ta + j * Tp, ta + j * Tp + a * Tp, von))
                if a < 1:
                    pieces.append((ta + j * Tp + a * Tp, ta + (j + 1) * Tp, 0.0))
        else:
            pieces = [(ta, ta + dt, duty[k] * supply_V[k])]
        for (a_, b_, u) in pieces:
            sol = solve_ivp(f, (a_, b_), x, method=method, rtol=rtol, atol=atol, args=(u,))
            if not sol.success:
                raise RuntimeError(f"solve_ivp failed at t = {a_:.6f} s: {sol.message}")
            x = sol.y[:, -1]
        X[k + 1] = x
    return X
