"""The fixed-rate stepper, its compiled fast path, and the solve_ivp reference.

A plant is a list of components (see ``components/base.py``). From that list this module *generates*
the source of the stepper, written once and used in two builds:

    rhs(t, x, u, P, dx, aux)                        time derivatives of the full state (one evaluation)
    rhs_carried(t, x, u, P, dx, aux, c...)          the same, given the carried values c at x (below)
    relax(t, tau, x, u, P, c...)                    flow A over tau: the components' exact state updates
    substep(t, h, ha, x, u, P, dx, aux, c...) -> c  flow A over ha, then flow B over h (explicit midpoint)
    step(t, h, hp, x, ...) -> hp, c...              one substep, split at contact edges / cut in impacts
    control_step(x, duty, V, P, t0, dt, n, sw, f, aux)   one control period: PWM bridge + substeps
    control_step_dx(..., aux, dx)                   the same with caller-owned scratch dx (no allocation)
    simulate(x0, duty[], V[], P, ...)               many control periods
    batch_step(X, duty[], V[], P[], ...)            N independent plants, one control period each (parallel)
    batch_step_serial(...)                          the same on the calling thread
    control_step_group(...)                         GROUP plants of a batch in lockstep (averaged PWM)

The *plain* build binds the components' pure-Python kernels (``kernel.py_func``) and runs in CPython;
the *fast* build binds the numba dispatchers and is compiled (the batch step in parallel over plants).
Both execute the same source, so they agree to floating-point rounding, and the batch step equals N
single control steps bit for bit (tests/test_fast_path.py). Where the time goes and what each speed
measure bought: docs/speed.md. The scheme and its accuracy: docs/model.md, sec. 9.

State vector x = [phi_rad, omega_rad_s, i_A, <component states in plant order>];
parameter vector P = [J_kg_m2, <component parameter vectors in plant order>].

Substeps: n = max(n_sub, ceil(dt / H_MAX_S)), h = dt / n (``substeps_for``; H_MAX_S = 200 us, the stability
bound). Scheme (second order, Strang splitting): the states of components with an ``advance`` (bristles)
form flow A, updated exactly for a frozen shaft and coil state; everything else (phi, omega, i, the other
states) forms flow B, integrated by the explicit midpoint rule with the A states frozen:
    A(h/2) B(h) A(h/2),   B:  k1 = f(t, y),  y_m = y + h/2 k1,  y <- y + h f(t + h/2, y_m)
The A half-steps of neighbouring substeps meet at the same state and are applied as one A(h) (``hp`` is
the half step still owed); a control period begins with A(h/2) and ends with A(h/2).

Contacts. A component may declare ``edges`` (angles where its torque jumps: stops, limp-home band) and
``rate`` (sqrt(k/J) while an impact is under way). ``step`` redoes a substep that crosses an edge in pieces
split at the crossing, and cuts a substep in an impact into m = max(CONTACT_PIECES, ceil(h r / RHO_MAX))
pieces when h r > RHO_MIN (``resolve``, the rare path, not inlined). ``physical`` checks after each control
period that the state is finite and every component's ``plausible`` holds (no garbage past divergence).

Carried values. A component may declare ``carry(phi, omega, i, p)``, a value of the shaft and coil state
that its kernel and its advance both need (LuGre: the Stribeck curve g(omega)); its kernel and advance
then take it as their last argument. The stepper computes it once per state at which it is needed (the
start of a period, the midpoint stage, the end of a substep) and hands it to the advance and the kernel
evaluation at that same state, so the value is the one they would compute, bit for bit. Without carries
the generated functions simply have no ``c`` arguments.
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


H_MAX_S = 2e-4   # the longest substep [s]: the scheme's stability limit on the end-stop contact is ~270 us
GROUP = 2   # plants stepped in lockstep by batch_step (averaged PWM): -9 % CPU per plant-step, same bits


def generate_source(components, lay: Layout) -> str:
    """Python source of the stepper for this composition (kernels are bound as k0, k1, ..., advances as
    a0, ..., carries as g0, ...)."""
    n = len(components)
    ns = lay.n_states
    carried = [k for k, c in enumerate(components) if c.carry is not None]

    def c_args(g=""):    # the carried values as trailing arguments: ", c1" (plant g of a group: ", c1g0")
        return "".join(f", c{k}{g}" for k in carried)

    def c_set(g=""):     # the left-hand side that receives them from substep: "c1 = " ("" without carries)
        return ", ".join(f"c{k}{g}" for k in carried) + " = " if carried else ""

    def c_init(x, P, g="", ind="    "):   # the carried values at the state x (start of a period, rhs)
        return "".join(f"{ind}c{k}{g} = g{k}({x}[0], {x}[1], {x}[2], {P}[{lay.param_slices[k][0]}:"
                       f"{lay.param_slices[k][1]}])\n" for k in carried)

    def c_at(pre, a, b, c_, ind="    "):   # carried values at the shaft/coil state (a, b, c_), named pre<k>
        return "".join(f"{ind}{pre}{k} = g{k}({a}, {b}, {c_}, P[{lay.param_slices[k][0]}:"
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
    stage_block = "\n".join(line for line in body if not line.startswith("    aux["))
    # A: the components' own exact updates (bristles) for the frozen shaft and coil state
    relax = []
    # B: explicit midpoint for phi, omega, i and the states of components without an advance
    euler = []
    for k, c in enumerate(components):
        (s0, s1), (p0, p1) = lay.state_slices[k], lay.param_slices[k]
        if s1 == s0:
            continue
        if c.advance is not None:
            ck = f", c{k}" if k in carried else ""
            relax.append(f"    a{k}(h, t, phi, omega, i, u, x[{s0}:{s1}], P[{p0}:{p1}]{ck})")
        else:
            euler.extend(range(s0, s1))
    relax_block = "\n".join(["    phi = x[0]", "    omega = x[1]", "    i = x[2]"] + relax) if relax else "    pass"
    if euler:
        e_lo, e_hi = min(euler), max(euler) + 1
        assert euler == list(range(e_lo, e_hi))
        save_half = (f"    for j in range({e_lo}, {e_hi}):\n        dx[{ns} + j] = x[j]\n"
                     f"        x[j] = x[j] + hh * dx[j]\n")
        finish = f"    for j in range({e_lo}, {e_hi}):\n        x[j] = dx[{ns} + j] + h * dx[j]\n"
    else:
        save_half = finish = ""
    ret = ("    return " + ", ".join(f"c{k}" for k in carried) + "\n") if carried else ""
    edged = [k for k, c in enumerate(components) if c.edges is not None]
    edge_lines = []
    for k in edged:
        p0, p1 = lay.param_slices[k]
        edge_lines += [f"    e = d{k}(phi0, omega0, phi1, omega1, P[{p0}:{p1}])", "    if e < th:", "        th = e"]
    edges_block = "\n".join(["    th = 2.0"] + edge_lines + ["    return th"])
    plaus = []
    for k, c in enumerate(components):
        if c.plausible is not None:
            p0, p1 = lay.param_slices[k]
            plaus += [f"    if not b{k}(x[0], x[1], x[2], V, P[{p0}:{p1}]):", "        ok = False"]
    plaus_block = "\n".join(plaus)
    cs = ", ".join(f"c{k}" for k in carried)
    hp_ret = lambda h: f"    return {h}" + (f", {cs}" if carried else "") + ", r"
    hp_set = "hp, " + cs + ", r = " if carried else "hp, r = "
    rated = [k for k, c in enumerate(components) if c.rate is not None]
    rate_lines = []
    for k in rated:
        p0, p1 = lay.param_slices[k]
        rate_lines += [f"    r = r{k}(x[0], x[1], P[0], P[{p0}:{p1}])", "    if r > rmax:", "        rmax = r"]
    rate_block = "\n".join(["    rmax = 0.0"] + rate_lines + ["    return rmax"])
    if edged or rated:
        save = "".join(f"    s{j} = x[{j}]\n" for j in range(ns))
        restore = "".join(f"    x[{j}] = s{j}\n" for j in range(ns))
        step_block = f"""    if h * r > RHO_MIN:      # in a stiff contact: straight to the careful path
        return resolve(t, h, hp, r, x, u, P, dx, aux{c_args()})
{save}    {c_set("n")}substep(t, h, hp + 0.5 * h, x, u, P, dx, aux{c_args()})
    th = edges(s0, s1, x[0], x[1], P)
    r1 = rates(x, P)
    if th >= 1.0 and h * r1 <= RHO_MIN:
        return 0.5 * h{"".join(f", c{k}n" for k in carried)}, r1
{restore}    return resolve(t, h, hp, r1, x, u, P, dx, aux{c_args()})"""
        resolve_block = f"""    m = 1
    if h * r > RHO_MIN:
        m = int(math.ceil(h * r / RHO_MAX - 1e-9))
        if m < CONTACT_PIECES:
            m = CONTACT_PIECES
    if m > MAX_PIECES:
        m = MAX_PIECES
    hs = h / m
    ha = hp
    rem = hs
    for piece in range(m):
        tp = t + piece * hs
        rem = hs
        for split in range(MAX_SPLITS + 1):
            for j in range({ns}):
                dx[{2 * ns} + j] = x[j]
            phi0 = x[0]
            omega0 = x[1]
            {c_set("n")}substep(tp, rem, ha + 0.5 * rem, x, u, P, dx, aux{c_args()})
            if split == MAX_SPLITS:
                break
            th = edges(phi0, omega0, x[0], x[1], P)
            if th >= 1.0:
                break
            for j in range({ns}):    # an edge was crossed: redo up to it, then on
                x[j] = dx[{2 * ns} + j]
            h1 = th * rem
            {c_set()}substep(tp, h1, ha + 0.5 * h1, x, u, P, dx, aux{c_args()})
            ha = 0.5 * h1
            tp = tp + h1
            rem = rem - h1
        {"".join(f"c{k} = c{k}n; " for k in carried)}ha = 0.5 * rem
    return 0.5 * rem{"".join(f", c{k}" for k in carried)}, rates(x, P)
"""
    else:
        step_block = f"""    {c_set()}substep(t, h, hp + 0.5 * h, x, u, P, dx, aux{c_args()})
{hp_ret("0.5 * h")}"""
        resolve_block = "    return 0.5 * h" + "".join(f", c{k}" for k in carried) + ", r\n"
    cm_args = "".join(f", m{k}" for k in carried)
    G = GROUP
    setup = "".join(f"    xg{g} = X[b0 + {g}]\n    Pg{g} = P[b0 + {g}]\n    ag{g} = AUX[b0 + {g}]\n"
                    f"    dg{g} = DX[b0 + {g}]\n    ug{g} = duty[b0 + {g}] * supply_V[b0 + {g}]\n"
                    f"    tg{g} = T0[b0 + {g}]\n" + c_init(f"xg{g}", f"Pg{g}", f"g{g}") for g in range(G))
    def hp_c_set(g):    # "hp0, c1g0, rg0 = " (with carries) or "hp0, rg0 = "
        return f"hp{g}, " + "".join(f"c{k}g{g}, " for k in carried) + f"rg{g} = "

    steps = "\n".join(f"        {hp_c_set(g)}step(tg{g} + k * h, h, hp{g}, rg{g}, xg{g}, ug{g}, Pg{g}, dg{g}, ag{g}"
                      f"{c_args(f'g{g}')})" for g in range(G))
    hp0 = "".join(f"    hp{g} = 0.0\n    rg{g} = rates(xg{g}, Pg{g})\n" for g in range(G))
    ends = "\n".join(f"    relax(tg{g} + dt, hp{g}, xg{g}, ug{g}, Pg{g}{c_args(f'g{g}')})" for g in range(G))
    oks = "\n".join(f"    OK[b0 + {g}] = physical(xg{g}, supply_V[b0 + {g}], Pg{g})" for g in range(G))
    return f'''# generated by etb_gym.integrate for: {", ".join(type(c).__name__ for c in components)}
import math
import numpy as np

N_AUX = {n}
N_STATES = {ns}
N_SCRATCH = {3 * ns}
GROUP = {G}
RHO_MIN = 0.01
RHO_MAX = 0.5
MAX_SPLITS = 4
CONTACT_PIECES = 3
MAX_PIECES = 64


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


def rhs_stage(t, x, u, P, dx{c_args()}):
    """rhs_carried without recording the torques in aux: the first stage of a substep, whose torques the
    midpoint stage overwrites."""
    phi = x[0]
    omega = x[1]
    i = x[2]
    T = 0.0
    E = 0.0
    L = 0.0
{stage_block}
    dx[0] = omega
    dx[1] = T / P[0]
    dx[2] = (u - E) / L


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
{save_half}    x[0] = phi + hh * dx[0]
    x[1] = omega + hh * dx[1]
    x[2] = i + hh * dx[2]
{c_at("m", "x[0]", "x[1]", "x[2]")}    rhs_carried(t + hh, x, u, P, dx, aux{cm_args})
    phi = phi + h * dx[0]
    omega = omega + h * dx[1]
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
    if not switching:
        u = duty * supply_V
        h = dt / n
        hp = 0.0
        for k in range(n):
            {hp_set}step(t0 + k * h, h, hp, r, x, u, P, dx, aux{c_args()})
        relax(t0 + dt, hp, x, u, P{c_args()})
    else:
        n_per = int(round(dt * f_pwm))
        if n_per < 1:
            n_per = 1
        Tp = dt / n_per
        a = abs(duty)
        von = supply_V if duty >= 0.0 else -supply_V
        t = t0
        hp = 0.0          # the half substep of flow A still owed by the previous substep
        u = 0.0
        for j in range(n_per):
            ton = a * Tp
            toff = Tp - ton
            if ton > 0.0:
                m = int(math.ceil(ton / hmax - 1e-9))
                if m < 1:  # an interval far shorter than a substep (duty a hair from 0 or +-1)
                    m = 1
                h = ton / m
                u = von
                for k in range(m):
                    {hp_set}step(t, h, hp, r, x, u, P, dx, aux{c_args()})
                    t += h
            if toff > 0.0:
                m = int(math.ceil(toff / hmax - 1e-9))
                if m < 1:  # an interval far shorter than a substep (duty a hair from 0 or +-1)
                    m = 1
                h = toff / m
                u = 0.0
                for k in range(m):
                    {hp_set}step(t, h, hp, r, x, u, P, dx, aux{c_args()})
                    t += h
        relax(t, hp, x, u, P{c_args()})
    return physical(x, supply_V, P)


def physical(x, V, P):
    """True if the state is finite and every component finds it plausible (supply V)."""
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
    return control_step_dx(x, duty, supply_V, P, t0, dt, n_sub, switching, f_pwm, aux, dx)


def simulate(x0, duty, supply_V, P, t0, dt, n_sub, switching, f_pwm, X, A):
    """Steps len(duty) control periods from x0; X[k+1], A[k+1] after period k (X[0] = x0).

    Returns the number of periods completed with a physical state (finite and plausible)."""
    x = x0.copy()
    aux = np.zeros(N_AUX)
    dx = np.empty(N_SCRATCH)
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



def control_step_group(X, duty, supply_V, P, T0, AUX, DX, OK, b0, dt, n_sub):
    """Plants b0 .. b0+GROUP-1 through one averaged-PWM control period in lockstep: each plant's operations
    are exactly those of control_step_dx, but the independent chains interleave, which lets the CPU
    overlap them (a substep is one long dependency chain of exp, sqrt and divisions). X, P, AUX
    come borrowed from batch_step; DX is borrowed here (all are the caller's arguments or locals that
    outlive this call)."""
    DX = borrow(DX)
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
    DX = np.empty((n, N_SCRATCH))
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


def substeps_used(dt: float, n_sub: int) -> int:
    """The substeps the stepper takes per control period dt when asked for n_sub: raised so that no substep
    is longer than H_MAX_S (the generated ``substeps_for``, in Python)."""
    return max(int(n_sub), int(math.ceil(dt / H_MAX_S - 1e-9)))


def _kernel_digest(components) -> str:
    h = hashlib.sha256()
    for c in components:
        for fn in (c.kernel, c.advance, c.carry, c.edges, c.plausible, c.rate):
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
    """Make numba's parallel batch step sleep, not spin, while it waits (:func:`ensure_thread_pool` calls it
    once, just before the first parallel batch step of the process; importing the package changes nothing).

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


THREAD_POOL: str | None = None      # what configure_thread_pool did, once a parallel batch step was asked for


def ensure_thread_pool() -> str:
    """Configure the thread pool once per process (before numba's first parallel region loads libgomp)."""
    global THREAD_POOL
    if THREAD_POOL is None:
        THREAD_POOL = configure_thread_pool()
    return THREAD_POOL


# numba options of the generated functions. rhs and substep are inlined at numba-IR level into their
# callers: LLVM then keeps the state in registers across substeps and prunes the reference counting of
# the kernels' slices (measured: -35 % CPU per plant-step for 3B, docs/speed.md). No fastmath: it would
# change rounding against the plain path (contract -> FMA) or fold away the finiteness check (nnan/ninf).
JIT_OPTIONS = {
    "rhs": {"inline": "always"},
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
    "physical": {},
    "control_step_group": {},
    "batch_step": {"parallel": True},
    "batch_step_serial": {},
}
STEPPER_REVISION = "6"   # bump when borrow() or JIT_OPTIONS change: part of the kernel-cache digest


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
                                      ("b", c.plausible), ("r", c.rate))
                      if fn is not None}
        self.fast = HAVE_NUMBA and all(_is_jitted(f) for f in self.bound.values())
        if HAVE_NUMBA and not self.fast:
            names = [type(c).__name__ for c in components
                     if not all(f is None or _is_jitted(f)
                                for f in (c.kernel, c.advance, c.carry, c.edges, c.plausible, c.rate))]
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
