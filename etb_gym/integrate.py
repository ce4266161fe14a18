"""The fixed-rate stepper, its compiled fast path, and the solve_ivp reference.

(About 500 lines on purpose: the generated-source template is one piece with the functions it defines;
its composition-dependent fragments are in stepper_blocks.py, the builds and cache in kernel_cache.py.)

A plant is a list of components (see ``components/base.py``). From that list this module *generates*
the source of the stepper, written once and used in two builds:

    rhs(t, x, u, P, dx, aux)                        time derivatives of the full state (one evaluation)
    rhs_carried(t, x, u, P, dx, aux, c...)          the same, given the carried values c at x (below)
    rhs_stage(t, x, u, P, dx, c...)                 the same without recording torques in aux (first stage)
    relax(t, tau, x, u, P, c...)                    flow A over tau: the components' exact state updates
    substep(t, h, ha, x, u, P, dx, aux, c...) -> c  flow A over ha, then flow B over h (explicit midpoint)
    step(t, h, hp, r, x, ...) -> hp, c..., r        one substep, split at contact edges / cut in impacts
    control_step(x, duty, V, P, t0, dt, n, sw, f, aux)   one control period: PWM bridge + substeps
    control_step_dx(..., aux, dx)                   the same with caller-owned scratch dx (no allocation)
    simulate(x0, duty[], V[], P, ...)               many control periods
    observe(x0, duty[], V[], P, ..., y[], gain[], lag, X, A)   the same with output injection
    batch_step(X, duty[], V[], P[], ...)            N independent plants, one control period each (parallel)
    batch_step_serial(...)                          the same on the calling thread
    control_step_group(...)                         GROUP plants of a batch in lockstep (averaged PWM)

The *plain* build binds the components' pure-Python kernels (``kernel.py_func``) and runs in CPython;
the *fast* build binds the numba dispatchers and is compiled (the batch step in parallel over plants).
Modules: the composition-dependent blocks of the source are built in ``stepper_blocks.py``, the two builds and
numba's on-disk cache in ``kernel_cache.py``, the thread pool's configuration in ``threadpool.py``.
Both execute the same source, so they agree to floating-point rounding, and the batch step equals N
single control steps bit for bit (tests/test_fast_path.py). Where the time goes and what each speed
measure bought: docs/speed.md. The scheme and its accuracy: docs/model.md, sec. 9.

State vector x = [phi_rad, omega_rad_s, i_A, <component states in plant order>];
parameter vector P = [J_kg_m2, <component parameter vectors in plant order>].

Substeps: n = max(n_sub, ceil(dt / H_MAX_S)), h = dt / n (``substeps_for``; H_MAX_S = 333 us, 3 per ms).
Scheme (second order, Strang splitting): the states of components with an ``advance`` (bristles) form flow A,
updated exactly for a frozen shaft and coil state; everything else (phi, omega, i, the other states) forms flow B,
integrated by the explicit midpoint rule with the A states frozen:
    A(h/2) B(h) A(h/2),   B:  k1 = f(t, y),  y_m = y + h/2 k1,  y <- y + h f(t + h/2, y_m)
The A half-steps of neighbouring substeps meet at the same state and are applied as one A(h) (``hp`` is
the half step still owed); a control period begins with A(h/2) and ends with A(h/2).

Damping. A component whose torque damps the shaft strongly declares ``damping`` (LuGre: sigma1 (1 - sigma0
sign(omega) z / g) + sigma2, 2 sigma1 + sigma2 right after a velocity reversal: 2 sigma1 / J = 7333 1/s, beyond
the explicit midpoint's h |lambda| <= 2 at h > 273 us). With w = h D / J (D the sum of the dampings at the
start of flow B) above RHO_DAMP, omega takes the exponential midpoint step for the linear part -D omega / J:
    omega_m = omega + h/2 phi1(-w/2) f_omega(y)
    omega <- omega + h phi1(-w) f_omega(y_m) + (1 - e^-w) (omega_m - omega)
(phi1(z) = (e^z - 1)/z; exact on domega/dt = -D omega/J + const at any h, the explicit midpoint as w -> 0). At
w <= RHO_DAMP (every substep at n >= 5 per ms at the default parameters) it is the explicit midpoint to the bit.

Contacts. A component may declare ``edges`` (angles where its torque jumps: stops, limp-home band) and
``rate`` (sqrt(k/J) while an impact is under way). ``step`` redoes a substep that crosses an edge in pieces
split at the crossing, and cuts a substep in an impact into m = max(CONTACT_PIECES, ceil(h r / RHO_MAX))
pieces when h r > RHO_MIN (``resolve``, the rare path, not inlined). A negative rate -r marks a slow contact
as stiff (a plate pressed into a stop): where h r > RHO_STIFF the substep is cut into ceil(h r / RHO_STIFF)
pieces, which keeps the explicit midpoint rule stable on it (otherwise it is stepped as free flight). The rate
at the end of a substep is handed to the next one (``r``), so ``rates`` runs once per substep. ``physical``
checks after each control period that the state is finite and every component's ``plausible`` holds (no
garbage past divergence).

Carried values. A component may declare ``carry(phi, omega, i, p)``, a value of the shaft and coil state
that its kernel and its advance both need (LuGre: the Stribeck curve g(omega)); its kernel and advance
then take it as their last argument. The stepper computes it once per state at which it is needed (the
start of a period, the midpoint stage, the end of a substep) and hands it to the advance and the kernel
evaluation at that same state, so the value is the one they would compute, bit for bit. Without carries
the generated functions simply have no ``c`` arguments.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from . import threadpool
from .jit import HAVE_NUMBA
from .kernel_cache import borrow, build_fast, build_plain, is_jitted  # noqa: F401  (borrow: public name)
from .stepper_blocks import (Carries, contact_functions, damping_blocks, eval_blocks, flow_blocks, group_blocks,
                             step_blocks)
from .threadpool import configure_thread_pool, ensure_thread_pool  # noqa: F401  (public names)


def __getattr__(name):
    """``integrate.THREAD_POOL``: what threadpool.configure_thread_pool did (None until a parallel batch step)."""
    if name == "THREAD_POOL":
        return threadpool.THREAD_POOL
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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


H_MAX_S = 1e-3 / 3  # the longest substep [s] (3 per ms); accuracy bounds it now, not stability (docs/model.md sec. 9)
RHO_STIFF = 1.2    # a slow stiff contact (negative rate -r) with h r above this is cut into pieces of h r <= RHO_STIFF
RHO_DAMP = 1.75    # where h * (the components' damping) / J exceeds this, omega's damping is taken exponentially
GROUP = 2   # plants stepped in lockstep by batch_step (averaged PWM): -9 % CPU per plant-step, same bits


def generate_source(components, lay: Layout) -> str:
    """Python source of the stepper for this composition (kernels are bound as k0, k1, ..., advances as
    a0, ..., carries as g0, ...)."""
    n = len(components)
    ns = lay.n_states
    cv = Carries(components, lay)
    carried = cv.carried
    c_args, c_init, c_at = cv.args, cv.init, cv.at
    eval_block, stage_block = eval_blocks(components, lay, cv)

    def rhs_body(block):     # the body shared by rhs_carried and rhs_stage: sum the components, then dx
        return ("    phi = x[0]\n    omega = x[1]\n    i = x[2]\n    T = 0.0\n    E = 0.0\n    L = 0.0\n"
                f"{block}\n    dx[0] = omega\n    dx[1] = T / P[0]\n    dx[2] = (u - E) / L\n")

    relax_block, save_half, finish = flow_blocks(components, lay, cv)
    damp_set, damp_mid, damp_end = damping_blocks(components, lay, cv)
    edges_block, rate_block, plaus_block = contact_functions(components, lay)
    step_block, resolve_block = step_blocks(components, lay, cv)
    ret = ("    return " + ", ".join(f"c{k}" for k in carried) + "\n") if carried else ""
    hp_set = "hp, " + ", ".join(f"c{k}" for k in carried) + ", r = " if carried else "hp, r = "
    cm_args = "".join(f", m{k}" for k in carried)
    G = GROUP
    setup, hp0, steps, ends, oks = group_blocks(G, cv)
    return f'''# generated by etb_gym.integrate for: {", ".join(type(c).__name__ for c in components)}
import math
import numpy as np

N_AUX = {n}
N_STATES = {ns}
N_SCRATCH = {3 * ns}
GROUP = {G}
RHO_MIN = 0.01
RHO_MAX = 0.5
RHO_STIFF = {RHO_STIFF!r}
RHO_DAMP = {RHO_DAMP!r}
MAX_SPLITS = 4
CONTACT_PIECES = 3
MAX_PIECES = 64


def rhs(t, x, u, P, dx, aux):
{c_init("x", "P")}    rhs_carried(t, x, u, P, dx, aux{c_args()})


def rhs_carried(t, x, u, P, dx, aux{c_args()}):
    """rhs, given the components' carried values c<k> at the state x."""
{rhs_body(eval_block)}

def rhs_stage(t, x, u, P, dx{c_args()}):
    """rhs_carried without recording the torques in aux: the first stage of a substep, whose torques the
    midpoint stage overwrites."""
{rhs_body(stage_block)}

def relax(t, h, x, u, P{c_args()}):
    """Flow A over h: the components' exact state updates (bristles) with phi, omega, i frozen."""
{relax_block}


def substep(t, h, ha, x, u, P, dx, aux{c_args()}):
    """Flow A over ha, then flow B over h (explicit midpoint, the A states frozen), given the carried values
    at x; returns those at the new x. dx holds N_SCRATCH values."""
    relax(t, ha, x, u, P{c_args()})
    phi = x[0]
    omega = x[1]
    i = x[2]
    rhs_stage(t, x, u, P, dx{c_args()})
    hh = 0.5 * h
{damp_set}{save_half}    x[0] = phi + hh * dx[0]
    {damp_mid}
    x[2] = i + hh * dx[2]
{c_at("m", "x[0]", "x[1]", "x[2]")}    rhs_carried(t + hh, x, u, P, dx, aux{cm_args})
    phi = phi + h * dx[0]
    {damp_end}
    i = i + h * dx[2]
    x[0] = phi
    x[1] = omega
    x[2] = i
{finish}{c_at("c", "phi", "omega", "i")}{ret}

def edges(phi0, omega0, phi1, omega1, P):
    """The first fraction of a substep at which the angle, moving from phi0 to phi1, crosses a contact edge."""
{edges_block}


def rates(x, P):
    """The largest rate [1/s] of a stiff contact the state x is in (0 outside every contact)."""
{rate_block}


def resolve(t, h, hp, r, x, u, P, dx, aux{c_args()}):
    """The careful path of step, for a substep from x that crosses an edge or is in a stiff contact of rate r:
    m equal pieces, each split where it crosses an edge (at most MAX_SPLITS times): m = 1 if h r <= RHO_MIN (the contact is resolved
    by h itself), else CONTACT_PIECES, or more if needed for h r / m <= RHO_MAX (at most MAX_PIECES).
    Returns what step returns."""
    x = borrow(x)
    P = borrow(P)
    dx = borrow(dx)
    aux = borrow(aux)
{resolve_block}

def step(t, h, hp, r, x, u, P, dx, aux{c_args()}):
    """One substep of length h, with hp of flow A still owed and r = rates(x, P); split where a contact edge is
    crossed. Returns the flow A now owed, the carried values at the new x and rates(x, P) there."""
{step_block}

def control_step_dx(x, duty, supply_V, P, t0, dt, n_sub, switching, f_pwm, aux, dx):
    """One control period, with ``dx`` (N_SCRATCH,) as scratch. Returns physical(x): the state is finite and plausible afterwards."""
    x = borrow(x)
    P = borrow(P)
    aux = borrow(aux)
    dx = borrow(dx)
{c_init("x", "P")}    r = rates(x, P)
    n = substeps_for(dt, n_sub)
    hmax = dt / n
    n_per = 1
    if switching:
        n_per = int(round(dt * f_pwm))
        if n_per < 1:
            n_per = 1
    Tp = dt / n_per
    a = abs(duty)
    von = supply_V if duty >= 0.0 else -supply_V
    t = t0
    hp = 0.0          # the half substep of flow A still owed by the previous substep
    u = 0.0
    # One loop over the intervals of constant voltage, so that step (inlined) appears once in the compiled
    # function: without switching one interval of n substeps at duty * supply_V; with switching, the on and the
    # off interval of each of the n_per PWM periods, each cut into the fewest substeps not longer than dt / n.
    for j in range(2 * n_per):
        if switching:
            ton = a * Tp
            span = ton if j % 2 == 0 else Tp - ton
            if not span > 0.0:
                continue
            m = int(math.ceil(span / hmax - 1e-9))
            if m < 1:  # an interval far shorter than a substep (duty a hair from 0 or +-1)
                m = 1
            h = span / m
            u = von if j % 2 == 0 else 0.0
        else:
            if j > 0:
                break
            m = n
            h = dt / n
            u = duty * supply_V
        for k in range(m):
            tk = t if switching else t0 + k * h
            {hp_set}step(tk, h, hp, r, x, u, P, dx, aux{c_args()})
            t += h
    relax(t if switching else t0 + dt, hp, x, u, P{c_args()})
    return physical(x, supply_V, P)


def physical(x, V, P):
    """True if the state is finite and every component finds it plausible (supply V)."""
    x = borrow(x)
    P = borrow(P)
    ok = True
    for j in range(N_STATES):
        if not math.isfinite(x[j]):
            ok = False
{plaus_block}
    return ok


def substeps_for(dt, n_sub):
    """The substeps of a control period: n_sub, raised so that no substep exceeds H_MAX_S."""
    n = n_sub
    m = int(math.ceil(dt / {H_MAX_S!r} - 1e-9))
    if m > n:
        n = m
    return n


def control_step(x, duty, supply_V, P, t0, dt, n_sub, switching, f_pwm, aux):
    """One control period. Returns physical(x): the state is finite and plausible afterwards."""
    dx = np.empty(N_SCRATCH)
    return control_step_dx(x, duty, supply_V, borrow(P, True), t0, dt, n_sub, switching, f_pwm, aux, dx)


def simulate(x0, duty, supply_V, P, t0, dt, n_sub, switching, f_pwm, X, A):
    """Steps len(duty) control periods from x0; X[k+1], A[k+1] after period k (X[0] = x0).

    Returns the number of periods completed with a physical state (finite and plausible)."""
    x = x0.copy()
    aux = np.zeros(N_AUX)
    dx = np.empty(N_SCRATCH)
    Pr = borrow(P, True)    # read-only type: control_step_dx compiles once, whatever the caller's P (borrow)
    rhs(t0, x, duty[0] * supply_V[0], Pr, dx, aux)     # called, not inlined: the rhs Plant.initial_state compiled
    for j in range(N_STATES):
        X[0, j] = x[j]
    for j in range(N_AUX):
        A[0, j] = aux[j]
    for k in range(duty.shape[0]):
        ok = control_step_dx(x, duty[k], supply_V[k], Pr, t0 + k * dt, dt, n_sub, switching, f_pwm, aux, dx)
        for j in range(N_STATES):
            X[k + 1, j] = x[j]
        for j in range(N_AUX):
            A[k + 1, j] = aux[j]
        if not ok:
            return k
    return duty.shape[0]


def observe(x0, duty, supply_V, P, t0, dt, n_sub, switching, f_pwm, y, gain, lag, X, A):
    """simulate with output injection (a fixed-gain state observer, diagnose/observer.py): X[k+1], A[k+1] are
    the one-step predictions after period k; then x += gain * (y[k+1] - angle predicted for sample k+1 - lag),
    y the measured angle [rad] (nan: no correction), lag >= 0 the sensor delay in periods (interpolated)."""
    x = x0.copy()
    aux = np.zeros(N_AUX)
    dx = np.empty(N_SCRATCH)
    Pr = borrow(P, True)    # read-only type: control_step_dx compiles once, whatever the caller's P (borrow)
    rhs(t0, x, duty[0] * supply_V[0], Pr, dx, aux)     # called, not inlined: the rhs Plant.initial_state compiled
    for j in range(N_STATES):
        X[0, j] = x[j]
    for j in range(N_AUX):
        A[0, j] = aux[j]
    m = int(lag)
    f = lag - m
    for k in range(duty.shape[0]):
        ok = control_step_dx(x, duty[k], supply_V[k], Pr, t0 + k * dt, dt, n_sub, switching, f_pwm, aux, dx)
        for j in range(N_STATES):
            X[k + 1, j] = x[j]
        for j in range(N_AUX):
            A[k + 1, j] = aux[j]
        if not ok:
            return k
        j = k + 1 - m
        pred = X[j, 0] if j >= 1 else X[0, 0]
        if f > 0.0 and j >= 1:
            pred = (1.0 - f) * pred + f * X[j - 1, 0]
        e = y[k + 1] - pred
        if e == e:
            for s in range(gain.shape[0]):
                x[s] += gain[s] * e
    return duty.shape[0]



def control_step_group(X, duty, supply_V, P, T0, AUX, DX, OK, b0, dt, n_sub):
    """Plants b0 .. b0+GROUP-1 through one averaged-PWM control period in lockstep: each plant's operations
    are exactly those of control_step_dx, but the independent chains interleave, which lets the CPU
    overlap them (a substep is one long dependency chain of exp, sqrt and divisions). Every array is borrowed
    here again (all are the caller's arguments or locals that outlive this call): that the caller borrowed them
    is a runtime fact this function's compilation cannot see, so without it every slice a kernel call takes
    would call NRT_incref/NRT_decref (a real function call that spills the live registers, on the null count of
    the borrowed view; ~30 % of 1A's substep, docs/speed.md "Round 4")."""
    X = borrow(X)
    duty = borrow(duty)
    supply_V = borrow(supply_V)
    P = borrow(P)
    T0 = borrow(T0)
    AUX = borrow(AUX)
    DX = borrow(DX)
    OK = borrow(OK)
    n = substeps_for(dt, n_sub)
    h = dt / n
{setup}{hp0}    for k in range(n):
{steps}
{ends}
{oks}


def batch_step(X, duty, supply_V, P, t0, dt, n_sub, switching, f_pwm, AUX, OK):
    """N plants (rows of X, P, AUX), one control period each, in parallel over plants."""
    n = X.shape[0]
    DX = np.empty((n, N_SCRATCH))
    Xb = borrow(X)
    Pb = borrow(P, True)
    Ab = borrow(AUX)
    ng = 0              # switching PWM: every plant on its own (the lockstep group averages the PWM)
    if not switching:
        ng = n // GROUP
    # One parallel loop for both PWM modes: numba lowers each prange into a gufunc of its own (two cost ~2 s more
    # compile per composition); the plants run exactly the operations they ran in the two loops.
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
    DX = np.empty((n, N_SCRATCH))
    Xb = borrow(X)
    Pb = borrow(P, True)
    Ab = borrow(AUX)
    ng = 0
    if not switching:
        ng = n // GROUP
        for j in range(ng):     # j * GROUP, not a counter from 0: a literal 0 would compile the group twice
            control_step_group(Xb, duty, supply_V, Pb, t0, Ab, DX, OK, j * GROUP, dt, n_sub)
    for b in range(ng * GROUP, n):
        OK[b] = control_step_dx(Xb[b], duty[b], supply_V[b], Pb[b], t0[b], dt, n_sub, switching, f_pwm,
                                Ab[b], DX[b])
'''


def substeps_used(dt: float, n_sub: int) -> int:
    """The substeps the stepper takes per control period dt when asked for n_sub: raised so that no substep
    is longer than H_MAX_S (the generated ``substeps_for``, in Python)."""
    return max(int(n_sub), int(math.ceil(dt / H_MAX_S - 1e-9)))


# numba options of the generated functions. rhs and substep are inlined at numba-IR level into their
# callers: LLVM then keeps the state in registers across substeps and prunes the reference counting of
# the kernels' slices (measured: -35 % CPU per plant-step for 3B, docs/speed.md). No fastmath: it would
# change rounding against the plain path (contract -> FMA) or fold away the finiteness check (nnan/ninf).
JIT_OPTIONS = {
    "rhs": {},            # called once per simulate/observe: the compiled rhs of Plant.initial_state (read-only P)
    "rhs_carried": {"inline": "always"},
    "rhs_stage": {"inline": "always"},
    "substep": {"inline": "always"},
    "relax": {"inline": "always"},
    "edges": {"inline": "always"},
    "step": {"inline": "always"},
    "resolve": {},
    "rates": {"inline": "always"},
    "substeps_for": {"inline": "always"},
    "control_step_dx": {},
    "control_step": {},
    "simulate": {},
    "observe": {},
    "physical": {},
    "control_step_group": {},
    "batch_step": {"parallel": True},
    "batch_step_serial": {},
}
STEPPER_REVISION = "9"   # bump when kernel_cache.borrow() or JIT_OPTIONS change: part of the kernel-cache digest


class Engine:
    """The compiled (or plain) stepper of one plant composition."""

    _cache: dict = {}
    _plain_cache: dict = {}

    def __init__(self, components, param_vectors):
        self.layout = layout(components, param_vectors)
        self.source = generate_source(components, self.layout)
        # the functions the generated source calls: k<k> kernel, a<k> advance, g<k> carry of component k
        self.bound = {f"{pre}{k}": fn for k, c in enumerate(components)
                      for pre, fn in (("k", c.kernel), ("a", c.advance), ("g", c.carry), ("d", c.edges),
                                      ("b", c.plausible), ("r", c.rate), ("v", c.damping))
                      if fn is not None}
        self.fast = HAVE_NUMBA and all(is_jitted(f) for f in self.bound.values())
        if HAVE_NUMBA and not self.fast:
            names = [type(c).__name__ for c in components
                     if not all(f is None or is_jitted(f)
                                for f in (c.kernel, c.advance, c.carry, c.edges, c.plausible, c.rate, c.damping))]
            warnings.warn(f"component(s) {names} have no compiled kernel (decorate them with "
                          "etb_gym.jit.kernel); this plant runs on the plain Python path, ~100x slower",
                          FastPathUnavailableWarning, stacklevel=3)
        key = (self.source, tuple(self.bound.items()))
        if key not in Engine._plain_cache:   # once per composition: plants of one composition share their stepper
            Engine._plain_cache[key] = _Fns(build_plain(self.source, self.bound))
        self.plain = Engine._plain_cache[key]
        if self.fast and key not in Engine._cache:
            Engine._cache[key] = _Fns(build_fast(self.source, self.bound, components, JIT_OPTIONS, STEPPER_REVISION))
        self.fns = Engine._cache[key] if self.fast else self.plain

class _Fns:
    def __init__(self, ns):
        self.rhs = ns["rhs"]
        self.substep = ns["substep"]
        self.control_step = ns["control_step"]
        self.simulate = ns["simulate"]
        self.observe = ns["observe"]
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
