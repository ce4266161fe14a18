"""The composition-dependent pieces of the generated stepper's source (``integrate.generate_source`` pastes them
into its template): the right-hand-side evaluation, the two flows of the splitting, the contact functions, the
substep with its contact handling, and the lockstep group of the batch step.

Each function returns source text indented for a function body in the template. Names bound in the generated
module: k<k> kernel, a<k> advance, g<k> carry, d<k> edges, b<k> plausible, r<k> rate of component k.
"""
from __future__ import annotations


class Carries:
    """How the carried values c<k> (components/base.py, integrate.py "Carried values") appear in the source."""

    def __init__(self, components, lay):
        self.carried = [k for k, c in enumerate(components) if c.carry is not None]
        self.lay = lay

    def args(self, g=""):
        """The carried values as trailing arguments: ", c1" (plant g of a group: ", c1g0")."""
        return "".join(f", c{k}{g}" for k in self.carried)

    def set(self, g=""):
        """The left-hand side that receives them from substep: "c1 = " ("" without carries)."""
        return ", ".join(f"c{k}{g}" for k in self.carried) + " = " if self.carried else ""

    def init(self, x, P, g="", ind="    "):
        """The carried values at the state x (start of a period, rhs)."""
        return "".join(f"{ind}c{k}{g} = g{k}({x}[0], {x}[1], {x}[2], {P}[{self.lay.param_slices[k][0]}:"
                       f"{self.lay.param_slices[k][1]}])\n" for k in self.carried)

    def at(self, pre, a, b, c_, ind="    "):
        """The carried values at the shaft/coil state (a, b, c_), named pre<k>."""
        return "".join(f"{ind}{pre}{k} = g{k}({a}, {b}, {c_}, P[{self.lay.param_slices[k][0]}:"
                       f"{self.lay.param_slices[k][1]}])\n" for k in self.carried)

    def names(self, suffix=""):
        """", c1n" style: the carried values with a suffix, as trailing tuple items."""
        return "".join(f", c{k}{suffix}" for k in self.carried)


def eval_blocks(components, lay, cv: Carries):
    """The kernel calls of one right-hand-side evaluation: with the torques recorded in aux (rhs_carried) and
    without (rhs_stage, the first stage of a substep)."""
    body = []
    for k, c in enumerate(components):
        (s0, s1), (p0, p1) = lay.state_slices[k], lay.param_slices[k]
        ck = f", c{k}" if k in cv.carried else ""
        body.append(f"    tq, e, l = k{k}(t, phi, omega, i, u, x[{s0}:{s1}], P[{p0}:{p1}], dx[{s0}:{s1}]{ck})")
        body.append(f"    aux[{k}] = tq")
        body.append("    T += tq")
        body.append("    E += e")
        body.append("    L += l")
    return "\n".join(body), "\n".join(line for line in body if not line.startswith("    aux["))


def flow_blocks(components, lay, cv: Carries):
    """Flow A (relax: the components' own exact updates, bristles) and the parts of flow B (explicit midpoint)
    for the states of components without an advance: (relax_block, save_half, finish)."""
    ns = lay.n_states
    relax, euler = [], []
    for k, c in enumerate(components):
        (s0, s1), (p0, p1) = lay.state_slices[k], lay.param_slices[k]
        if s1 == s0:
            continue
        if c.advance is not None:
            ck = f", c{k}" if k in cv.carried else ""
            relax.append(f"    a{k}(h, t, phi, omega, i, u, x[{s0}:{s1}], P[{p0}:{p1}]{ck})")
        else:
            euler.extend(range(s0, s1))
    relax_block = "\n".join(["    phi = x[0]", "    omega = x[1]", "    i = x[2]"] + relax) if relax else "    pass"
    if not euler:
        return relax_block, "", ""
    e_lo, e_hi = min(euler), max(euler) + 1
    assert euler == list(range(e_lo, e_hi))
    save_half = (f"    for j in range({e_lo}, {e_hi}):\n        dx[{ns} + j] = x[j]\n"
                 f"        x[j] = x[j] + hh * dx[j]\n")
    finish = f"    for j in range({e_lo}, {e_hi}):\n        x[j] = dx[{ns} + j] + h * dx[j]\n"
    return relax_block, save_half, finish


def damping_blocks(components, lay, cv: Carries):
    """omega's update in substep's midpoint rule, (damp_set, damp_mid, damp_end): with components that declare a
    ``damping`` D (components/base.py), the exponential midpoint step for the linear part -D*omega/J where
    w = h D / J > RHO_DAMP (factors fa = phi1(-w/2), fb = phi1(-w), fq = 1 - exp(-w), phi1(z) = (e^z - 1)/z:
    exact on domega/dt = -D omega / J + const); elsewhere fa = fb = 1, fq = 0, the plain explicit midpoint to the
    bit (x * 1.0 and x + 0.0 are exact). Without dampings: the plain explicit midpoint."""
    plain = ("x[1] = omega + hh * dx[1]", "omega = omega + h * dx[1]")
    terms = []
    for k, c in enumerate(components):
        if c.damping is None:
            continue
        (s0, s1), (p0, p1) = lay.state_slices[k], lay.param_slices[k]
        ck = f", c{k}" if k in cv.carried else ""
        terms.append(f"v{k}(phi, omega, i, x[{s0}:{s1}], P[{p0}:{p1}]{ck})")
    if not terms:
        return ("",) + plain
    damp_set = (f"    wd = h * ({' + '.join(terms)}) / P[0]\n"
                "    fa = 1.0\n    fb = 1.0\n    fq = 0.0\n"
                "    if wd > RHO_DAMP:\n"
                "        ea = math.exp(-0.5 * wd)\n"
                "        fq = 1.0 - ea * ea\n"
                "        fa = (1.0 - ea) / (0.5 * wd)\n"
                "        fb = fq / wd\n")
    return (damp_set, "dm = hh * fa * dx[1]\n    x[1] = omega + dm",
            "omega = omega + h * fb * dx[1] + fq * dm")


def contact_functions(components, lay):
    """Bodies of edges (the first edge crossing), rates (the largest impact rate; else the most negative rate, that
    of the stiffest slow contact) and physical's plausibility checks: (edges_block, rate_block, plaus_block)."""
    edge_lines, rate_lines, plaus = [], [], []
    for k, c in enumerate(components):
        p0, p1 = lay.param_slices[k]
        if c.edges is not None:
            edge_lines += [f"    e = d{k}(phi0, omega0, phi1, omega1, P[{p0}:{p1}])", "    if e < th:",
                           "        th = e"]
        if c.rate is not None:
            rate_lines += [f"    r = r{k}(x[0], x[1], P[0], P[{p0}:{p1}])", "    if r > rmax:", "        rmax = r",
                           "    elif r < rmin:", "        rmin = r"]
        if c.plausible is not None:
            plaus += [f"    if not b{k}(x[0], x[1], x[2], V, P[{p0}:{p1}]):", "        ok = False"]
    return ("\n".join(["    th = 2.0"] + edge_lines + ["    return th"]),
            "\n".join(["    rmax = 0.0", "    rmin = 0.0"] + rate_lines
                      + ["    if rmax > 0.0:", "        return rmax", "    return rmin"]),
            "\n".join(plaus))


def step_blocks(components, lay, cv: Carries):
    """Bodies of step (one substep; to resolve when it crosses an edge, is in an impact or in a slow contact too
    stiff for it) and resolve (pieces, splits at edges): (step_block, resolve_block). Without edges or rates, step
    is the plain substep."""
    ns = lay.n_states
    if not any(c.edges is not None or c.rate is not None for c in components):
        step_block = (f"    {cv.set()}substep(t, h, hp + 0.5 * h, x, u, P, dx, aux{cv.args()})\n"
                      f"    return 0.5 * h{cv.names()}, r")
        return step_block, f"    return 0.5 * h{cv.names()}, r\n"
    save = "".join(f"    s{j} = x[{j}]\n" for j in range(ns))
    restore = "".join(f"    x[{j}] = s{j}\n" for j in range(ns))
    step_block = f"""    if h * r > RHO_MIN or h * r < -RHO_STIFF:      # in a stiff contact: straight to the careful path
        return resolve(t, h, hp, r, x, u, P, dx, aux{cv.args()})
{save}    {cv.set("n")}substep(t, h, hp + 0.5 * h, x, u, P, dx, aux{cv.args()})
    th = edges(s0, s1, x[0], x[1], P)
    r1 = rates(x, P)
    if th >= 1.0 and -RHO_STIFF <= h * r1 <= RHO_MIN:
        return 0.5 * h{cv.names("n")}, r1
{restore}    return resolve(t, h, hp, r1, x, u, P, dx, aux{cv.args()})"""
    # One substep call in the loop (substep is inlined: a second call site compiled it a second time). A try
    # over the rest of the piece that crosses an edge is undone and followed by the substep up to the edge
    # ("to_edge"), after which the rest is tried again (at most MAX_SPLITS times).
    resolve_block = f"""    m = 1
    if h * r > RHO_MIN:
        m = int(math.ceil(h * r / RHO_MAX - 1e-9))
        if m < CONTACT_PIECES:
            m = CONTACT_PIECES
    elif h * r < -RHO_STIFF:
        m = int(math.ceil(-h * r / RHO_STIFF - 1e-9))
    if m > MAX_PIECES:
        m = MAX_PIECES
    hs = h / m
    ha = hp
    rem = hs
    for piece in range(m):
        tp = t + piece * hs
        rem = hs
        hk = hs
        to_edge = False
        split = 0
        while True:
            for j in range({ns}):
                dx[{2 * ns} + j] = x[j]
            phi0 = x[0]
            omega0 = x[1]
            {cv.set("n")}substep(tp, hk, ha + 0.5 * hk, x, u, P, dx, aux{cv.args()})
            if to_edge:             # the substep up to the edge: on from there with the rest
                {"".join(f"c{k} = c{k}n; " for k in cv.carried)}ha = 0.5 * hk
                tp = tp + hk
                rem = rem - hk
                hk = rem
                to_edge = False
                continue
            if split == MAX_SPLITS:
                break
            th = edges(phi0, omega0, x[0], x[1], P)
            if th >= 1.0:
                break
            for j in range({ns}):    # an edge was crossed: undo, then up to it
                x[j] = dx[{2 * ns} + j]
            hk = th * rem
            to_edge = True
            split += 1
        {"".join(f"c{k} = c{k}n; " for k in cv.carried)}ha = 0.5 * rem
    return 0.5 * rem{cv.names()}, rates(x, P)
"""
    return step_block, resolve_block


def group_blocks(G: int, cv: Carries):
    """The lockstep group of control_step_group, GROUP plants g: (setup, hp0, steps, ends, oks)."""
    setup = "".join(f"    xg{g} = X[b0 + {g}]\n    Pg{g} = P[b0 + {g}]\n    ag{g} = AUX[b0 + {g}]\n"
                    f"    dg{g} = DX[b0 + {g}]\n    ug{g} = duty[b0 + {g}] * supply_V[b0 + {g}]\n"
                    f"    tg{g} = T0[b0 + {g}]\n" + cv.init(f"xg{g}", f"Pg{g}", f"g{g}") for g in range(G))
    steps = "\n".join(f"        hp{g}, " + "".join(f"c{k}g{g}, " for k in cv.carried) + f"rg{g} = "
                      f"step(tg{g} + k * h, h, hp{g}, rg{g}, xg{g}, ug{g}, Pg{g}, dg{g}, ag{g}{cv.args(f'g{g}')})"
                      for g in range(G))
    hp0 = "".join(f"    hp{g} = 0.0\n    rg{g} = rates(xg{g}, Pg{g})\n" for g in range(G))
    ends = "\n".join(f"    relax(tg{g} + dt, hp{g}, xg{g}, ug{g}, Pg{g}{cv.args(f'g{g}')})" for g in range(G))
    oks = "\n".join(f"    OK[b0 + {g}] = physical(xg{g}, supply_V[b0 + {g}], Pg{g})" for g in range(G))
    return setup, hp0, steps, ends, oks
