"""A named family's formula refined by a learned table, kept or not (docs/diagnosis-shapes.md).

:func:`refine_family` builds the family's map terms (:func:`.shapes.family_terms`), fits each with the calibrated
nominal parameters by the penalized Gauss-Newton (:mod:`.penalized`), and compares the held-out error of formula
and formula + table over the diagnosis's two folds. A refined map is kept (in the twin and the exported plant
file, where it sits beside the family's formula as a correction) only when its held-out error is lower than the
formula's by MIN_GAIN. :func:`split_start` starts the torque constant apart from the back-EMF constant;
:func:`plot_table` draws a kept table for the report.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from . import fit as F
from .model import Data, Spec
from .penalized import Problem, fit_penalized, heldout_error
from .shapes import LOG_GRIDS, MapTerm, family_terms


MIN_GAIN = 0.05          # a map replaces the formula only if the held-out error falls by at least this fraction


# torque constant and back-EMF constant apart (torque_emf_term, split_start): the grid's steps, shares of c_M
SPLIT_TORQUE = (-0.02, -0.01, -0.005, 0.0, 0.005, 0.01, 0.02)   # the torque constant's (spring, friction co-scaled)
SPLIT_EMF = (-0.005, -0.0025, 0.0, 0.0025, 0.005)                # the back-EMF constant's (the torque unchanged)
SPLIT_NFEV = 40          # the local fit from the grid's best point


def split_start(spec: Spec, x0: np.ndarray, cid: str, term: MapTerm, data: Data) -> np.ndarray:
    """The start of a :func:`torque_emf_term` fit: the best point of a grid over the torque constant (SPLIT_TORQUE,
    shares of the nameplate's c_M, every nominal torque co-scaled as fit.coscale_point does: the calibration
    balanced the plate's rests with the old constant) and the back-EMF constant (SPLIT_EMF: the formula's delta
    moved, the offset moved back, the torque unchanged), then a local fit from there (SPLIT_NFEV). From the
    formula's optimum the offset alone only raises the residual: the spring and friction levels must follow the
    torque, and the back-EMF the other way (3B s33 closed: Gauss-Newton and a free local fit stayed at offset 0,
    observer cost 6033 / 5953; from the grid's best point 5610, the truth's point 5628). ``x0``: the formula's
    optimum with the term's coefficients (the last) at 0; the grid moves them together (a direction the recordings
    did not drive the current in is pulled back to 0 by the penalized fit's anchoring). Returns x0 where the grid
    finds nothing lower."""
    names = list(spec.values(np.zeros(len(spec.params))))
    k_d, k_c = names.index(f"{cid}.delta_Nm_per_A"), np.arange(len(x0) - term.n_coef, len(x0))
    p_d = spec.params[k_d][1]
    c_m = float(getattr(spec.base.drive.params, "torque_constant_Nm_per_A", 0.0) or 0.0)
    d0 = p_d.init + p_d.scale * float(x0[k_d])
    kt0 = c_m + d0
    if not (c_m > 0.0 and kt0 > 0.0):
        return x0
    lo, hi = spec.bounds()
    fun = F.make_fun(spec, data)
    r0 = fun(x0)
    if fun.failure is not None:
        return x0
    best_c, best_x = float(r0 @ r0), x0
    for s in SPLIT_TORQUE:
        kf = (kt0 + s * c_m) / kt0
        for e in SPLIT_EMF:
            if s == 0.0 and e == 0.0:
                continue
            x = x0.copy()
            x[k_c] = (s - e) * c_m / term.scale
            x[k_d] = x0[k_d] + e * c_m / p_d.scale
            for i, q in enumerate(spec.nominal):
                if q.unit.startswith("N m"):
                    x[i] = ((q.init + q.scale * float(x0[i])) * kf - q.init) / q.scale
            if np.any(x <= lo) or np.any(x >= hi):
                continue
            r = fun(x)
            if fun.failure is None and float(r @ r) < best_c:
                best_c, best_x = float(r @ r), x
    fun.failure = None
    if best_x is x0:
        return x0
    try:
        res = F.local_fit(fun, best_x, lo, hi, 0.03, SPLIT_NFEV)
    except (ValueError, FloatingPointError, np.linalg.LinAlgError):
        return best_x
    return res.x if 2.0 * float(res.cost) < best_c else best_x


# ------------------------------------------------------------------------------------ refinement of a family
@dataclasses.dataclass
class Refinement:
    family_id: str                # the catalogue candidate whose shape was refined
    term: MapTerm
    fit: F.FitResult              # the model with the map (formula kept, map as a correction)
    lam_rel: float
    heldout_formula: float
    heldout_map: float
    kept: bool
    problem: Problem | None = None  # the table's penalized problem and its chosen absolute roughness weights
    lams: tuple = ()                # (run.polish refits on the continuous replay with the same penalty)

    def table(self) -> dict:
        """The learned table: grid and values (physical units)."""
        vals = self.fit.spec.values(self.fit.x)
        coef = np.array([vals[f"{self.term.id}.c{k}"] for k in range(self.term.n_coef)])
        comp = self.term.component(coef)
        d = comp.params.to_dict()
        return {"component": comp.kind, **{k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}}


def _formula_component(fr: F.FitResult, cid: str):
    """The fitted formula component of candidate ``cid`` in ``fr``'s model (None if it has none)."""
    plant, _ = fr.spec.build(fr.x)
    return next((e for e in plant.effects if getattr(e, "effect_id", None) == cid), None)


COULOMB = "friction.coulomb_Nm"      # the nominal friction level (the static level follows it by ratio)


def _second_start(pf, h, spec_m, free, term: MapTerm, view: Data, data: Data, comp):
    """A friction level over angle (``term.second_start``) fitted again from the first fit, its table's mean over
    the recorded angles (each knot weighted by the time the recordings spent near it, :func:`.shapes.visit_time_s`)
    moved into the nominal Coulomb level and the table set to 0: the same friction on average where the plate
    went, carried by the level rather than the table. Returns (fit, held-out error): the second fit's where it
    lowers the first's error ``h`` by MIN_GAIN, else the first's.

    Why: the nominal Coulomb level and the table's mean trade (a direction the data leave nearly flat), and the
    first fit starts from the calibration's level, which absorbed the band's mean (adf@1 3B open s40: 0.226 N m
    against the truth's 0.216): from there the folds chose a heavy roughness (3.2) at every linearization, which
    anchors the knots the training only passed to the formula at that weight; the table ended 2.4-3.7 mN m high
    over 54-66 deg, held-out 49, the twin 9.3x the noise. From the second start the folds chose roughness 3e-3,
    held-out 18.9, the twin 5.2x (docs/diagnosis-history.md, round 32 l32adf). The second fit replaces the first
    only when it lowers the held-out error by MIN_GAIN, the margin a table must beat the formula by: two fits of
    one model that the folds cannot tell apart keep the first (adf@1 3B closed s39: 0.860 -> 0.859 taken, the twin
    1.27x -> 1.42x)."""
    from .shapes import visit_time_s
    names = spec_m.names
    k_c = np.array([k for k, (o, _) in enumerate(spec_m.params) if o == term.id], int)
    vis = visit_time_s(term, data)
    if COULOMB not in names or vis is None or not np.sum(vis) > 0:
        return pf, h
    kc = names.index(COULOMB)
    ps = [spec_m.params[k][1] for k in k_c]
    table = np.array([p.init + p.scale * pf.fit.x[k] for p, k in zip(ps, k_c)])
    x2 = pf.fit.x.copy()
    x2[k_c] = [-p.init / p.scale for p in ps]
    x2[kc] += float(np.sum(vis * table) / np.sum(vis)) / spec_m.params[kc][1].scale
    lo, hi = spec_m.bounds()
    return _refit_from(pf, h, Problem.make(spec_m, np.clip(x2, lo, hi), free, [term], data, formula=comp), view,
                       data)


def _refit_from(pf, h, pb2, view: Data, data: Data):
    """(fit, held-out error) of the table fitted again from the problem ``pb2``'s start where it lowers the first
    fit's error ``h`` by MIN_GAIN, else the first fit ``pf`` and ``h`` (also where the second fit fails)."""
    try:
        pf2 = fit_penalized(pb2, view, log=None)
        h2 = heldout_error(dataclasses.replace(pf2.problem, x=pf2.fit.x), data, pf2.lams,
                           pf2.jac if view is data else None)
    except (ValueError, FloatingPointError, np.linalg.LinAlgError):
        return pf, h
    return (pf2, h2) if h2 < (1.0 - MIN_GAIN) * h else (pf, h)


STEP_AT_KINK = ("spring_asymmetry",)   # formulas with a step at limp-home: the table is also fitted with them off


def _formula_off_start(pf, h, spec_m, free, term: MapTerm, view: Data, data: Data, cid: str, comp):
    """The family's table fitted again with the family's formula switched off (its ``off`` values) and the
    formula's torque on the knots (:func:`.penalized.formula_profile`) moved into the table: the same torque where
    the knots can carry it, now carried by the table alone. Returns (fit, held-out error): the second fit's where it
    lowers the first's error ``h`` by MIN_GAIN, else the first's.

    Why (spring asymmetry only, STEP_AT_KINK): its formula is a second preload and rate below limp-home, so a
    preload change is a step at limp-home, where the plate rests, and the table's knots (a few degrees apart)
    cannot cancel a step between two of them. When the truth's change is not a preload and rate (a closing spring
    that softens or hardens with the angle, zero at limp-home), the formula's fit takes a preload step anyway:
    spring_asymmetry@2 3B open s48 (-0.13 N m at the closed stop, 0 at limp-home 3 deg) fitted the closing rate
    at its bound (-0.3 N m/rad) and a preload step of -0.034 N m; the table on top chose roughness 1e3, held-out
    36.5, while airflow's smooth formula with the same table took the spring's torque at 2.13 (the table -0.128
    N m at 0 deg and a line above limp-home: the spring's signature) and was named. Airflow's formula is smooth,
    its table corrects it: not refitted. (docs/diagnosis-history.md, round 34 z34spring)"""
    from .candidates import CANDIDATES
    from .penalized import formula_profile
    off = dict(CANDIDATES[cid].off)
    k_f = [k for k, (o, p) in enumerate(spec_m.params) if o == cid and p.name in off]
    k_c = np.array([k for k, (o, _) in enumerate(spec_m.params) if o == term.id], int)
    prof = formula_profile(comp, term)
    if not k_f or prof is None or any(isinstance(off[spec_m.params[k][1].name], str) for k in k_f):
        return pf, h
    x2 = pf.fit.x.copy()
    for k in k_f:
        p = spec_m.params[k][1]
        x2[k] = (float(off[p.name]) - p.init) / p.scale
    x2[k_c] += prof / term.scale
    lo, hi = spec_m.bounds()
    x2 = np.clip(x2, lo, hi)
    plant, _ = spec_m.build(x2)
    comp2 = next((e for e in plant.effects if getattr(e, "effect_id", None) == cid), None)
    return _refit_from(pf, h, Problem.make(spec_m, x2, free, [term], data, formula=comp2), view, data)


def refine_family(final: F.FitResult, cid: str, data: Data, log=print, split: bool = True) -> Refinement | None:
    """Refine accepted candidate ``cid`` of ``final`` by its table (None: no table form for the family); with
    several table forms (:func:`family_terms`) the one with the lowest held-out error. ``split`` False: without
    the torque-constant split (:func:`torque_emf_term`), for refine's test whether the first effect with its table
    replaces the later ones: the split's two extra constants beat torque_constant_error + inductance_saturation on
    the folds (held-out 3.06 against 4.91) and displaced the saturation, twin 1.23x -> 6.05x
    (torque_constant_error@2 3B s20 open, round 27)."""
    terms = [t for t in family_terms(cid, final.spec.base, data) if split or not t.split_start]
    if not terms:
        return None
    pb_formula = Problem.make(final.spec, final.x, ("nominal", cid))
    h_formula = heldout_error(pb_formula, data)
    # the table is fitted, and its roughness chosen, on the fit's view (every replay segment restarted at the
    # readings) and, on an open-loop recording, also on the replay that goes on from the model's own state
    # (model.Data.continuity): over restarted segments a wrong shape costs little, the spring's rate and preload
    # can absorb it, and the cross-validation keeps the formula (docs/diagnosis-history.md, round 13). The fit with the
    # lower held-out error (on the fit's view, as the formula's) is taken.
    views = [data]
    if not data.continuity and any(rd.residual == "replay" for rd in data.recs):
        views.append(dataclasses.replace(data, continuity=True))
    comp = _formula_component(final, cid)
    h_cur = None                # the formula's held-out error with the current's rows scored too (once)
    scored = []                 # (Refinement, the score that decides) per form
    for term in terms:
        spec_m = final.spec.with_candidate(term.candidate())
        x0 = np.concatenate([final.x, np.zeros(term.n_coef)])
        if term.split_start:
            x0 = split_start(spec_m, x0, cid, term, data)
        # a smooth current table (shapes.smooth_current_term) is fitted with the formula's parameters free: with
        # them held, the formula's fitted knee is a feature the spline has to cancel (supply_drop@1 3B s36 open:
        # twin 7.29x held, 3.47x free; docs/diagnosis-history.md, round 30 e30supply)
        free = ("nominal", cid, term.id) if term.split_start or term.coef_grid is not None else ("nominal", term.id)
        pb = Problem.make(spec_m, x0, free, [term], data, formula=comp)
        h_map, pf = math.inf, None
        # a heating's states persist over the restarted segments (Effect.persistent_states): the fit's view sees
        # its history already, and on the continuous replay the refitted nominal parameters alone passed the
        # folds (coil_heating@1 3B s24 open: the network ~0, kept at held-out 1.03 -> 0.93, the twin 2.31x -> 2.72x)
        for view in (views[:1] if term.score_current or term.split_start else views):
            pf_v = fit_penalized(pb, view, log=None)
            h_v = heldout_error(dataclasses.replace(pf_v.problem, x=pf_v.fit.x), data, pf_v.lams,
                                pf_v.jac if view is data else None)
            if term.second_start:
                pf_v, h_v = _second_start(pf_v, h_v, spec_m, free, term, view, data, comp)
            if cid in STEP_AT_KINK and comp is not None:
                pf_v, h_v = _formula_off_start(pf_v, h_v, spec_m, free, term, view, data, cid, comp)
            if pf is None or h_v < h_map:
                h_map, pf, cont = h_v, pf_v, view is not data
        d_formula, d_map = h_formula, h_map          # the scores that decide
        if term.score_current:
            # a term of the coil's voltage balance (the heating) is scored on the current's rows too: in a closed
            # loop the angle hides it, the current shows it (a two-node heating's one-node fit: held-out angle at
            # the noise, the twin 8.2x on the other loop type; docs/diagnosis-history.md, round 26 o26thermal). The
            # Refinement keeps the angle's held-out errors, which refine compares with other models'.
            if h_cur is None:
                h_cur = heldout_error(dataclasses.replace(pb_formula, score_current=True), data)
            d_formula = h_cur
            d_map = heldout_error(dataclasses.replace(pf.problem, x=pf.fit.x), data, pf.lams, pf.jac)
            h_map = heldout_error(dataclasses.replace(pf.problem, x=pf.fit.x, score_current=False), data, pf.lams,
                                  pf.jac)
        kept = d_map < (1.0 - MIN_GAIN) * d_formula
        log(f"  shape of {cid}: {term.id} over {term.cls.grid_field} ({term.grid.size} knots, {term.n_coef} "
            f"coefficients, roughness weight "
            f"{pf.lams_rel[0]:.2g}{', fitted on the continuous replay' if cont else ''}): held-out "
            f"{'(angle and current) ' if term.score_current else ''}{d_formula:.3g} -> "
            f"{d_map:.3g} ({'kept' if kept else 'not kept'})")
        scored.append((Refinement(cid, term, pf.fit, pf.lams_rel[0], h_formula, h_map, kept, pf.problem,
                                  tuple(pf.lams)), d_map))
    best, why = choose_form(scored)
    if why:
        log(f"  shape of {cid}: {why}")
    return best


def choose_form(scored: list) -> tuple:
    """The refinement to keep among a family's table forms, ``scored`` = [(Refinement, held-out score), ...] in
    the order tried: the lowest score (the first of equals), except that a preferred form
    (``MapTerm.preferred``: the odd supply-drop table, shapes.smooth_current_term) that the folds keep (its held-out
    error MIN_GAIN below the formula's) is replaced by another only where that lowers the held-out error by MIN_GAIN
    too. Where the folds keep no form, the lowest goes on as before (a closed loop's replay_rescue may keep it:
    supply_drop@1 3B s45 closed, the linear table rescued, twin 1.08x; the odd one, not kept by the folds and not
    below the formula, 1.37x). The folds see little of a current direction an open loop drives
    only briefly, and there the free tables' unidentified knots fall back to the formula alone (supply_drop@1 3B s42
    open: free 1.03, odd 1.07 on the folds; the free table kept left the formula's knee 10-13 mV short at -0.1 to
    -0.5 A, where the closed held-out recording brakes, twin 1.58x; the odd one 1.02x; docs/diagnosis-history.md,
    round 33 o33supply). Returns (Refinement or None, a log line where the preference decided, else "")."""
    best, best_score = None, math.inf
    for ref, d in scored:
        if d < best_score:
            best, best_score = ref, d
    pref = next(((ref, d) for ref, d in scored if ref.term.preferred and ref.kept and d < math.inf), None)
    if best is not None and pref is not None and best is not pref[0] and not best_score < (1.0 - MIN_GAIN) * pref[1]:
        return pref[0], (f"{pref[0].term.id} kept over {best.term.id} (held-out {pref[1]:.3g} against "
                         f"{best_score:.3g}, within MIN_GAIN)")
    return best, ""


def plot_table(ax, term: MapTerm, table: dict, title: str):
    """Draw a learned table on a matplotlib axis (grid in deg, rad/s or A)."""
    g = np.asarray(table[term.cls.grid_field], float)
    x = np.degrees(g) if term.cls.grid_field == "angle_rad" else g
    xl = {"angle_rad": "angle [deg]", "speed_rad_s": "speed |omega| [rad/s]", "current_A": "current [A]",
          "time_constant_s": "branch time constant [s]"}
    if term.cls.grid_field in LOG_GRIDS:
        ax.set_xscale("log")
    for f in term.value_fields:
        ax.plot(x, table[f], marker=".", lw=1.0, label=f)
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_xlabel(xl.get(term.cls.grid_field, term.cls.grid_field))
    ax.set_ylabel(term.unit)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
