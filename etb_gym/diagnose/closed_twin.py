"""Closed loops: tables learned from the data kept only where the replay of the recorded voltage says they help.

On a closed-loop recording every fit of the diagnosis uses the observer residual (observer.py), which pulls the
model's angle towards the reading after every sample. A table (refine.py: an angle table, a sensor map) fitted
on it sees only the states the loop visited, and its knots beyond them are free to trade against the nominal
parameters without the observer residual noticing. The replay of the recorded voltage (model.replay_view: open
loop, going on from the model's own state) was fitted by neither the formula model nor the table model, so it
is a held-out check of the table: a table that does not lower its cost by more than the cost's noise is dropped
and the formula model (the greedy selection's fit) is the final model.

Measured (docs/diagnosis-history.md, "Closed loops: tables checked on the replay (round 20)"): backlash@2 random seed
15, an angle table around limp-home of which the loop visited one side only; the table held 0.03-0.09 N m on
the side the loop never reached (the preload moved against it), observer cost 4824 with the table and
4821 without; the twin replayed its training recording at 1.13x the noise, the formula model at 1.07x, and the
held-out open-loop recording at 14.1x against 2.5x.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.optimize import least_squares

from . import fit as F
from .model import Data, SimulationFailed, replay_view


def _replay_cost(fr: F.FitResult, rv: Data) -> tuple[float, int]:
    """Sum of squared replay residuals (noise units) of ``fr`` on ``rv`` and their number; (inf, 0) where the
    model cannot replay it."""
    try:
        r = F.evaluate(fr.spec, rv, fr.x)
    except (SimulationFailed, ValueError, FloatingPointError, np.linalg.LinAlgError):
        return math.inf, 0
    return (float(r @ r), int(r.size)) if r.size and np.all(np.isfinite(r)) else (math.inf, 0)


def _learned(shaped) -> list:
    """The kept tables of a refine.Outcome: angle/speed/current tables and sensor maps (family ids)."""
    if shaped is None:
        return []
    return ([f"{r.family_id} ({r.term.id})" for r in shaped.refinements if r.kept]
            + [f"{r.family_id} (sensor {r.kind})" for r in shaped.sensor_maps if r.kept])


def check_tables(formula: F.FitResult, final: F.FitResult, steps_before: list, steps: list, shaped, data: Data,
                 significant=None, note: dict | None = None) -> F.FitResult:
    """``final`` (refine's model: ``formula`` with learned tables) or ``formula`` (the selection's fit, the same
    effects without tables), for recordings that are all scored by the observer (closed loops).

    The tables are dropped (their refinements marked not kept, so the report shows no learned shape and the
    exported twin has none) when on the replay of the recorded voltage, which neither model was fitted on, the
    table model's cost is not lower than the formula model's by more than the noise of that cost (sqrt(2 n), n
    its residuals in noise units), unless the formula model leaves a significant mismatch (``significant``: the
    verdict's test) where the table model leaves none: the check changes the twin, not what the diagnosis says
    the final model accounts for. Applies only where refine kept the selection's effects (no effect dropped, not
    outside the catalogue). ``note`` (a dict) gets the figures (report.json ``replay_tables``)."""
    if not data.recs or not all(rd.residual == "observer" for rd in data.recs):
        return final
    tables = _learned(shaped)
    if not tables or final is formula or shaped.outside or shaped.dropped \
            or [s.id for s in steps] != [s.id for s in steps_before]:
        return final
    rv = replay_view(data)
    (c_tab, n_tab), (c_for, n_for) = _replay_cost(final, rv), _replay_cost(formula, rv)
    margin = math.sqrt(2 * max(n_tab, n_for))
    info = {"tables": tables, "replay_cost_tables": c_tab, "replay_cost_formula": c_for, "margin": margin,
            "kept": True}
    if math.isfinite(c_for) and not c_for - c_tab > margin:
        if significant is not None and significant(formula) and not significant(final):
            info["verdict_guard"] = "the formula model would leave a significant mismatch: tables kept"
        else:
            info["kept"] = False
            for r in shaped.refinements:
                r.kept = False
            for r in shaped.sensor_maps:
                r.kept = False
    if note is not None:
        note.update(info)
    return final if info["kept"] else formula


def _continued(total: np.ndarray, prof: np.ndarray, grid: np.ndarray, seen: np.ndarray, lh: float,
               hold: bool = False) -> np.ndarray:
    """The family's total (formula ``prof`` + table) on ``grid`` with the knots beyond the visited ones
    (``seen``: indices, increasing) continued from the edge along the slope of the visited interval next to the
    edge's (both its knots have data on either side; the edge knot only on one; where only two knots are visited,
    the edge's interval), but no further than the family's formula goes from the edge (and held where the slope and the formula part ways):
    between the hold and the formula's own continuation, the two the table could do before. A continuation does
    not cross limp-home (``lh``, rad; nan: none): the spring's contact changes the regime there, so the knots
    beyond it are held at the last continued value. With ``hold`` (a friction level over angle, HOLD_FAMILIES) a
    side without a visited interval next to its edge holds the edge's value (else that side is left as it is)."""
    out = total.copy()
    n = grid.size
    for side in (1, -1):
        e = seen[-1] if side == 1 else seen[0]
        a, b = (e - 2 * side, e - side) if e - 2 * side in seen else (e - side, e)
        if not (0 <= min(a, b) and max(a, b) < n) or a not in seen or b not in seen:
            if hold:            # no visited interval next to the edge: no slope, the edge's value held
                k = np.arange(e + 1, n) if side == 1 else np.arange(0, e)
                out[k] = total[e]
            continue
        slope = (total[b] - total[a]) / (grid[b] - grid[a])
        k = e + side
        while 0 <= k < n:
            if math.isfinite(lh) and (grid[k] - lh) * (grid[e] - lh) < 0:
                out[k] = out[k - side]
            else:
                lin, form = slope * (grid[k] - grid[e]), prof[k] - prof[e]
                step = math.copysign(min(abs(lin), abs(form)), lin) if lin * form > 0 else 0.0
                out[k] = total[e] + step
            k += side
    return out


# Families whose table's edge value is held where the slope rule would stop it (_continued's zero step) and the
# visited-knot rule would go on along the formula: a friction level over angle. Its formula (slope, curvature) is
# fitted together with the table, which takes its shape wherever the data are, so beyond them the formula's
# curvature is not the data's (angle_dependent_friction@1 3B closed s41: curvature -0.244 N m, the 90 deg knot
# 45 mN m below the truth's level against 5.6 mN m at the last reached knot, 84.4 deg; docs/diagnosis-history.md,
# round 31 h31adf). A friction's level does not follow a trend into the stop: a hold is the smaller extrapolation;
# where the interval next to the data's edge was not visited (no slope) the edge's value is held too (adf@1 random
# closed s41: the data from 3.0 deg, limp-home; the -0.85 deg knot at the formula's curvature -0.48 N m, 33 mN m
# under the truth's level).
HOLD_FAMILIES = ("friction",)


def _toward_edge(new: np.ndarray, old: np.ndarray, total: np.ndarray, seen: np.ndarray,
                 hold: bool = False) -> np.ndarray:
    """Knots beyond the data's edge (``seen``'s first / last): ``new``'s step from the edge knot's value where it
    is smaller than ``old``'s and goes the same way, else ``old``'s value: the smaller of the two extrapolations
    (as :func:`_continued` takes the smaller of the slope's and the formula's). With ``hold`` (a friction level
    over angle) a zero step, the edge's value held, counts as the smaller one too (:data:`HOLD_FAMILIES`)."""
    out = new.copy()
    for e, ks in ((seen[-1], range(seen[-1] + 1, total.size)), (seen[0], range(seen[0]))):
        for k in ks:
            dn, do = new[k] - total[e], old[k] - total[e]
            held = hold and dn == 0.0
            out[k] = total[e] + dn if (dn * do > 0 or held) and abs(dn) <= abs(do) else old[k]
    return out


def reached_knots(grid: np.ndarray, visit_s: np.ndarray, angles_rad: np.ndarray) -> np.ndarray:
    """The knots of an angle table (``grid``, increasing) that the recordings identify: hat-weighted time near
    the knot (``visit_s``) at least shapes.VISIT_MIN_S, and the recorded angles (``angles_rad``) reaching past the
    middle of the interval next to it on the side beyond the data. A knot the data approach to less than half its
    interval is set by the few samples next to its neighbour: its hat weight counts their time, but its value is
    the roughness penalty's and the formula's extrapolation (docs/diagnosis-history.md, round 16: shaft_flux_loss@2
    3B seed 13 trained to 69.3 deg, its 73.1 deg knot counted as visited; round 30: seed 37 trained to 85.1 deg,
    the 90 deg knot at the formula's steep continuation, 1.6 mN m/A past the truth's loss)."""
    from .shapes import VISIT_MIN_S
    ok = np.asarray(visit_s, float) >= VISIT_MIN_S
    if angles_rad.size:
        lo, hi = float(np.min(angles_rad)), float(np.max(angles_rad))
        mid = 0.5 * (grid[1:] + grid[:-1])
        ok[1:] &= ~((grid[1:] > hi) & (mid > hi))      # beyond the top: the data stop short of the interval's middle
        ok[:-1] &= ~((grid[:-1] < lo) & (mid < lo))    # below the bottom, the same
    return np.flatnonzero(ok)


def continue_tables(final: F.FitResult, shaped, data: Data, note: dict | None = None,
                    significant=None) -> F.FitResult:
    """``final`` with each kept family table over angle (one value per knot, with the family's formula in the
    model) continued beyond the angles the recordings visited (:func:`_continued`), for recordings that are all
    scored by the observer (closed loops); kept only where the replay of the recorded voltage (model.replay_view)
    does not get worse by more than its noise (sqrt(2 n)) and, for the data's reach, where the verdict's test
    (``significant``) finds no mismatch after it that it did not find before (shaft_flux_loss@2 3B seed 13: the
    73.1 deg knot of a loop trained to 69.3 deg continued, held-out 41.3x -> 5.2x, but the training's angle RMS
    0.0146 -> 0.0173 deg, `explained` -> `partly_explained`: refused, main's edit kept).

    Why: a closed loop visits the angles its set points need; the exported twin is used over the whole stroke.
    Beyond the visited knots the table held the family's total at its value at the last one (penalized.hold_rows):
    a total that was still changing at the edge stops there. Measured (docs/diagnosis-history.md, round 23):
    shaft_flux_loss@2 random seed 25, trained 3.7-64.6 deg, held-out to 83 deg: the total held at -0.0108 N m/A
    from 67.5 deg on, the held-out twin 22.8x the noise; the slope of the interval next to the edge's continued
    2.71x (of the edge's own 3.35x); the formula's own continuation (exponent at its bound) 79.7x. The knots are
    edited after the fits, which never saw them: the fitted model inside the visited range is unchanged. ``note`` gets the figures (report.json
    ``replay_tables.beyond_visited``)."""
    from .family_table import _formula_component
    from .penalized import formula_profile
    from .shapes import VISIT_MIN_S, data_angles_rad, visit_time_s
    if shaped is None or not data.recs or not all(rd.residual == "observer" for rd in data.recs):
        return final
    angles = data_angles_rad(data)

    def edit(by_edge: bool):
        x, edited = final.x.copy(), []
        for ref in shaped.refinements:
            term = ref.term
            idx = [k for k, (o, _) in enumerate(final.spec.params) if o == term.id]
            if not ref.kept or term.cls.grid_field != "angle_rad" or len(term.value_fields) != 1 \
                    or len(idx) != term.grid.size:
                continue
            prof, vis = formula_profile(_formula_component(final, ref.family_id), term), visit_time_s(term, data)
            if prof is None or vis is None:
                continue
            grid, vis = np.asarray(term.grid, float), np.asarray(vis[:term.grid.size])
            visited = np.flatnonzero(vis >= VISIT_MIN_S)
            seen = reached_knots(grid, vis, angles) if by_edge else visited
            if seen.size < 2:
                continue
            ps = [final.spec.params[k][1] for k in idx]
            table = np.array([p.init + p.scale * x[k] for p, k in zip(ps, idx)])
            total = prof + table
            lh = float(final.spec.base.limp_home_rad)
            hold = getattr(term, "family", None) in HOLD_FAMILIES
            new = _continued(total, prof, grid, seen, lh, hold=hold and by_edge)
            if by_edge:     # no further from the data's edge than the visited knots' rule (round 23) goes
                new = _toward_edge(new, _continued(total, prof, grid, visited, lh) if visited.size >= 2 else total,
                                   total, seen, hold=hold)
            if np.allclose(new, total, rtol=0.0, atol=1e-12):
                continue
            for p, k, v in zip(ps, idx, new - prof):
                x[k] = (v - p.init) / p.scale
            edited.append({"table": term.id, "visited_deg": [float(np.degrees(grid[seen[0]])),
                                                               float(np.degrees(grid[seen[-1]]))],
                           "knots_by": "data edge" if by_edge else "visit time",
                           "total_before": total.tolist(), "total_after": new.tolist()})
        return x, edited

    rv, info = None, None
    lo, hi = final.spec.bounds()
    tried = []
    for by_edge in (True, False):     # the knots the data reach; where the replay refuses that, the visited ones
        x, edited = edit(by_edge)
        if not edited or any(t == [e["total_after"] for e in edited] for t in tried):
            continue
        tried.append([e["total_after"] for e in edited])
        x = np.clip(x, lo, hi)
        if rv is None:
            rv = replay_view(data)
            c0, n0 = _replay_cost(final, rv)
            margin = math.sqrt(2 * max(n0, 1))
        c1, _ = _replay_cost(dataclasses.replace(final, x=x), rv)
        kept = bool(math.isfinite(c1) and c1 <= c0 + margin)
        guard = None
        if kept and by_edge and significant is not None and not significant(final):
            # a knot the data reach to less than half its interval still shapes the fit next to it: the edit may
            # not leave a significant mismatch where the final model left none (the verdict's test)
            kept = not significant(dataclasses.replace(final, x=x))
            guard = "passed" if kept else "the edit would leave a significant mismatch"
        info = {"tables": edited, "replay_cost_before": c0, "replay_cost_after": c1, "margin": margin, "kept": kept,
                **({"verdict_guard": guard} if guard else {}), **({"refused": info} if info is not None else {})}
        if kept:
            break
    if info is None:
        return final
    if note is not None:
        note["beyond_visited"] = info
    if not info["kept"]:
        return final
    for ref in shaped.refinements:        # the report draws the exported table
        if any(e["table"] == ref.term.id for e in edited) and ref.fit.spec.params == final.spec.params:
            ref.fit = dataclasses.replace(ref.fit, x=x)
    return dataclasses.replace(final, x=x)


def halves_folds(fr: F.FitResult, view: Data, refit) -> list[dict]:
    """A two-fold check in time on ``view`` (the replay): ``refit(masks)`` (-> parameters) fitted on the first half of
    every recording, the second half's cost before (``fr.x``) and after, and the other way round; each fold with its
    margin, the cost's noise sqrt(2 n). Used by run.polish_replay and :func:`refit_weak`."""
    A = [rd.rec.t_s - rd.rec.t_s[0] < 0.5 * (rd.rec.t_s[-1] - rd.rec.t_s[0]) for rd in view.recs]
    B = [~a for a in A]
    folds = []
    for fit_m, test_m in ((A, B), (B, A)):
        x1 = refit(fit_m)
        r0, r1 = (F.evaluate(fr.spec, view, x, masks=test_m) for x in (fr.x, x1))
        folds.append({"held_cost_before": float(r0 @ r0), "held_cost_after": float(r1 @ r1),
                      "margin": math.sqrt(2 * r0.size)})
    return folds


WEAK_NFEV = 30          # evaluations of each refit in the observer's weak directions (refit_weak)
WEAK_MAX_DIRS = 4       # at most this many weak directions are refitted


def weak_directions(fr: F.FitResult, data: Data, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The directions in ``fr``'s parameters ``cols`` (normalized units) along which the observer residual does
    not pin the model: eigenvectors of its Fisher information J^T J (J: the observer residual's Jacobian, forward
    differences) whose eigenvalue is below sqrt(2 n), i.e. a move of one parameter scale along them (10 % of a
    spring or friction level) changes the observer's cost by less than that cost's noise. Returns (the directions
    as columns over ``cols``, all eigenvalues, sqrt(2 n))."""
    fun = F.make_fun(fr.spec, data)
    r0 = fun(fr.x)
    h = 0.03
    J = np.empty((r0.size, cols.size))
    for j, k in enumerate(cols):
        x = fr.x.copy()
        x[k] += h
        J[:, j] = (fun(x) - r0) / h
    if not np.all(np.isfinite(J)):
        raise ValueError("the observer residual's Jacobian is not finite")
    w, V = np.linalg.eigh(J.T @ J)
    noise = math.sqrt(2 * r0.size)
    return V[:, w < noise][:, :WEAK_MAX_DIRS], w, noise


def refit_weak(fr: F.FitResult, data: Data, significant=None, note: dict | None = None) -> F.FitResult:
    """``fr`` (a closed loop's final model whose replay refit run.polish_replay did not keep) refitted on the
    replay of the recorded voltage in the directions the observer residual does not identify
    (:func:`weak_directions`, over the nominal levels and the effects' formula parameters; a table's knots keep
    their values), kept only where that refit generalizes in time: fitted on the first half of the replay the
    second half's cost falls by more than its noise (sqrt(2 n)), and the other way round; and where the refit on
    the whole replay raises the observer's cost by no more than its noise and (``significant``: the verdict's
    test) leaves no significant mismatch where ``fr`` left none. ``note``: run.polish_replay's note (its ``kept``
    says whether the whole replay refit was kept); the figures are added as ``note["weak"]``.

    Why: a closed loop that holds the plate sees the sum of the spring's torque and an effect's there, so the
    observer fit trades a nominal level against the effect along a direction it barely sees; the replay, which
    drifts where the model's static torques are off, does see it. The whole-replay refit moves every parameter,
    including those the observer pins, and was refused by its halves on such cases; restricted to the weak
    directions the observer's optimum is kept where it is identified (report.json ``replay_refit.weak``)."""
    if not data.recs or not all(rd.residual == "observer" for rd in data.recs):
        return fr
    if note is not None and note.get("kept"):
        return fr
    from .candidates import CANDIDATES          # a table's knots and a learned term are not refitted here
    cols = np.array([k for k, (o, _) in enumerate(fr.spec.params) if o == "nominal" or o in CANDIDATES], int)
    if cols.size == 0:
        return fr
    info: dict = {"kept": False}
    try:
        V, w, noise = weak_directions(fr, data, cols)
        info.update(eigenvalues=[float(v) for v in w], noise=noise, directions=int(V.shape[1]))
        if V.shape[1] == 0:
            raise _Skip
        rv = replay_view(data)
        lo, hi = fr.spec.bounds()

        def point(th):
            x = fr.x.copy()
            x[cols] += V @ th
            return np.clip(x, lo, hi)

        def refit(masks=None):
            fun = F.make_fun(fr.spec, rv, masks)
            out = least_squares(lambda th: fun(point(th)), np.zeros(V.shape[1]), method="trf", diff_step=0.03,
                                max_nfev=WEAK_NFEV)
            return point(out.x)

        info["folds"] = halves_folds(fr, rv, refit)
        if not all(f["held_cost_before"] - f["held_cost_after"] > f["margin"] for f in info["folds"]):
            info["rule"] = "halves refuse"
            raise _Skip
        x1 = refit()
        o0, o1 = (F.evaluate(fr.spec, data, x) for x in (fr.x, x1))
        p0, p1 = (F.evaluate(fr.spec, rv, x) for x in (fr.x, x1))
        info["observer_cost"] = [float(o0 @ o0), float(o1 @ o1), math.sqrt(2 * o0.size)]
        info["replay_cost"] = [float(p0 @ p0), float(p1 @ p1), math.sqrt(2 * p0.size)]
        info["kept"] = bool(o1 @ o1 - o0 @ o0 <= info["observer_cost"][2])
        info["rule"] = "kept" if info["kept"] else "the observer's cost rose"
        if info["kept"] and significant is not None and not significant(fr):
            info["kept"] = not significant(dataclasses.replace(fr, x=x1))
            if not info["kept"]:
                info["rule"] = "the refit would leave a significant mismatch"
    except _Skip:
        pass
    except (SimulationFailed, ValueError, FloatingPointError, np.linalg.LinAlgError) as e:
        info["failed"] = str(e)
    if note is not None:
        note["weak"] = info
    if not info["kept"]:
        return fr
    return dataclasses.replace(fr, x=x1, rss=info["observer_cost"][1])


class _Skip(Exception):
    """refit_weak: nothing to refit, or the halves refuse."""


REPLAY_TABLE_GAIN = 0.2     # replay_rescue: the share of the replay's cost a table below the folds' MIN_GAIN must take off


def replay_rescue(cur: F.FitResult, ref, data: Data, log=print) -> bool:
    """Closed loops (every recording scored by the observer): is ``ref`` (family_table.refine_family's best table for a
    family of ``cur``, not kept because its folds' held-out error fell by less than family_table.MIN_GAIN) kept after
    all? Yes where the folds still gain (its held-out error below the formula's), the continuous replay of the
    recorded voltage (model.replay_view: neither model was fitted on it) costs less by more than its noise
    (sqrt(2 n)) and by at least REPLAY_TABLE_GAIN of the formula model's cost, and the observer residual's cost
    does not rise by more than its own noise.

    Why: the observer pulls the model's angle to the reading every sample, so a torque level the table corrects by
    1-2 % of c_M shows in its one-step error only as a small innovation, and the folds' gain of a 2-coefficient
    term can stay below MIN_GAIN; the replay of the same voltage integrates that torque, as the open-loop twin
    does. Measured (round 28): torque_constant_error@2 3B s35 closed, the torque-constant split
    (torque_constant_error_torque_offset): folds 0.977 -> 0.942 (3.6 %, not kept), replay cost 11387 -> 5546
    (noise 155), observer 5866 -> 5757; held-out twin 1.61x -> 1.01x the noise."""
    if ref is None or ref.kept or not data.recs or not all(rd.residual == "observer" for rd in data.recs):
        return False
    if not ref.heldout_map < ref.heldout_formula:
        return False
    rv = replay_view(data)
    if not rv.continuity:            # refine's view restarts every segment; the twin goes on from its own state
        rv = dataclasses.replace(rv, continuity=True)
    (c0, n0), (c1, _) = _replay_cost(cur, rv), _replay_cost(ref.fit, rv)
    (o0, m0), (o1, _) = _replay_cost(cur, data), _replay_cost(ref.fit, data)     # the observer residual's cost
    if not all(math.isfinite(v) for v in (c0, c1, o0, o1)):
        return False
    margin, o_margin = math.sqrt(2 * max(n0, 1)), math.sqrt(2 * max(m0, 1))
    ok = bool(c0 - c1 > margin and c1 <= (1.0 - REPLAY_TABLE_GAIN) * c0 and o1 - o0 <= o_margin)
    log(f"  closed loop: {ref.term.id} on the replay of the recorded voltage: cost {c0:.0f} -> {c1:.0f} (noise "
        f"{margin:.0f}), observer {o0:.0f} -> {o1:.0f} ({'kept' if ok else 'not kept'})")
    return ok


def unseen_closing_play(final: F.FitResult, data: Data, note: dict | None = None) -> F.FitResult:
    """``final`` with a fitted ``backlash``'s closing side (the play below limp-home, ``closing_ratio`` r times the
    opening play b) moved to the middle of what the recordings allow, where they never reached its edge: every
    recorded angle above phi_LH - r b, so the fit saw no contact there and r kept its start (1, the mirror of the
    opening side; no gradient). The data then bound the closing play only from below, by how far they reached below
    limp-home (``reach`` = phi_LH - the lowest recorded angle, 0 if none); the twin takes the middle between that
    and the mirror, r' = (reach / b + r) / 2: an edge anywhere between "no play beyond what was seen" and the
    symmetric play is then at most half the play off, where either end can be off by all of it. Kept only where
    the fit's own residual (``data``: the observer on closed loops) does not rise by more than its noise
    (sqrt(2 n)); it cannot rise where no recorded state reaches the edit. ``note`` gets the figures
    (report.json ``replay_tables.unseen_closing_play``).

    Why (docs/diagnosis-history.md, round 31): closed loops hold set points at or above limp-home and never push the
    plate onto the closing spring; the held-out open-loop recording does (17-33 % of its time below limp-home on
    backlash@2 3B s33/s37/s39). On s37 (truth b 0.0144 rad, closing 0.0044) the fit kept r = 1: 49 % of the twin's
    squared held-out error sat 0.2-0.5 deg below limp-home, inside the mirrored play the truth does not have; the
    twin's held-out 5.72x the noise, 3.10x with r = 0.5, 2.82x with the truth's r. This changes only the exported
    twin and the report's fitted values, not the residual the verdict was drawn from."""
    idx = {p.name: k for k, (o, p) in enumerate(final.spec.params) if o == "backlash"}
    if "play_rad" not in idx or "closing_ratio" not in idx or not data.recs:
        return final
    pb, pr = final.spec.params[idx["play_rad"]][1], final.spec.params[idx["closing_ratio"]][1]
    b = pb.init + pb.scale * final.x[idx["play_rad"]]
    r = pr.init + pr.scale * final.x[idx["closing_ratio"]]
    lh = float(final.spec.base.limp_home_rad)
    from .shapes import data_angles_rad
    angles = data_angles_rad(data)
    if not (b > 0 and math.isfinite(lh) and angles.size):
        return final
    reach = max(0.0, lh - float(np.min(angles)))
    if reach >= r * b:               # the recordings passed the closing edge: r was fitted on data
        return final
    r1 = 0.5 * (reach / b + r)
    x = final.x.copy()
    lo, hi = final.spec.bounds()
    k = idx["closing_ratio"]
    x[k] = float(np.clip((r1 - pr.init) / pr.scale, lo[k], hi[k]))
    info = {"play_rad": float(b), "closing_ratio_fitted": float(r), "reach_below_limp_home_rad": reach,
            "closing_ratio": float(r1)}
    c0, n0 = _replay_cost(final, data)
    c1, _ = _replay_cost(dataclasses.replace(final, x=x), data)
    margin = math.sqrt(2 * max(n0, 1))
    info.update(cost_before=c0, cost_after=c1, margin=margin, kept=bool(math.isfinite(c1) and c1 <= c0 + margin))
    if note is not None:
        note["unseen_closing_play"] = info
    return dataclasses.replace(final, x=x) if info["kept"] else final


REST_START_MIN_S = 0.02     # rest_offset: the unpowered rest before the loop engages, at least this long


def start_rest_samples(rd) -> np.ndarray | None:
    """The readings [deg] of a recording's unpowered rest before its loop engages: the samples from the start up
    to the first non-zero voltage, at least REST_START_MIN_S long and still (their readings within 6 noise levels
    and two resolution steps); None if it has none."""
    v = np.asarray(rd.rec.voltage_V, float)
    y = np.asarray(rd.rec.angle_deg, float)
    on = np.flatnonzero(np.abs(v) > 0.0)
    k = int(on[0]) if on.size else v.size
    if k * rd.rec.dt_s < REST_START_MIN_S:
        return None
    span = float(np.ptp(y[:k]))
    if span > 6.0 * rd.noise_deg + 2.0 * rd.resolution_deg:
        return None
    return y[:k]


def start_rest_reading(rd) -> float | None:
    """The mean of :func:`start_rest_samples` (None if the recording has no unpowered rest)."""
    y = start_rest_samples(rd)
    return None if y is None else float(np.mean(y))


def rest_offset(final: F.FitResult, data: Data, note: dict | None = None) -> F.FitResult:
    """``final`` with a named ``sensor_offset_gain``'s offset moved along its trade with the spring's preload to
    where the recordings' unpowered rest reads limp-home: o' = o + (r_rest - r_LH), r_LH the model's reading of
    the limp-home angle, and the preload P' = P + R (o' - o) / g (R the spring's rate, g the reading's gain, the
    offset in rad), the same spring torque at every reading above limp-home. Kept only where the fit's own
    residual (``data``: the observer on closed loops) does not rise by more than its noise (sqrt(2 n)): where the
    recordings pin the offset otherwise (the closing spring, a stop), the move is refused. ``note`` gets the
    figures (report.json ``replay_tables.rest_offset``). A shift within the readings' resolution step or noise
    level is left: the rest's mean does not resolve it.

    Why (docs/diagnosis-history.md, round 33 q33gain): a closed loop holds the reading at its set points, so above
    limp-home a reading offset o and the preload trade exactly (the spring torque P + R (phi - phi_LH) at the
    reading's angle (r - o) / g); the fit settles anywhere along that line. The held-out open-loop recording rests
    on limp-home and the closed stop, where the offset is read directly: sensor_offset_gain@1 3B s45 closed, truth
    o -0.349 deg, fitted -0.574 deg with the preload 1.3 mN m low (twin 10.1x the noise on the held-out
    recording; 1.29x with the truth's offset and preload). The one reading that pins the offset in such a loop is
    the plate at rest before the loop engages: unpowered, it sits at limp-home (the springs' fail-safe position),
    within the limp-home compliance. This changes only the exported twin and the report's fitted values."""
    names = final.spec.names
    if "sensor_offset_gain.offset_deg" not in names or "spring.preload_Nm" not in names or not data.recs \
            or not all(rd.residual == "observer" for rd in data.recs):
        return final
    plant, sensor = final.spec.build(final.x)
    lh = float(final.spec.base.limp_home_rad)
    rests = [r for r in (start_rest_reading(rd) for rd in data.recs) if r is not None]
    if not rests or plant.spring is None or not math.isfinite(lh):
        return final
    r_lh = float(sensor.apply(np.zeros(1), np.array([math.degrees(lh)]))[0])
    d_off = float(np.mean(rests)) - r_lh
    # a quantized reading at rest resolves its mean to about one step where the noise does not dither it: a shift
    # below the step (or the noise) is not read from the rest (sensor_offset_gain@1 3B s37 closed: -0.014 deg
    # against a 0.022 deg step, the twin 4.12x -> 4.41x moved)
    step = max(max(rd.noise_deg, rd.resolution_deg) for rd in data.recs)
    if abs(d_off) <= step:
        return final
    vals = final.spec.values(final.x)
    rate = float(plant.spring.params.rate_Nm_per_rad)
    vals["sensor_offset_gain.offset_deg"] += d_off
    vals["spring.preload_Nm"] += rate * math.radians(d_off) / sensor.gain
    lo, hi = final.spec.bounds()
    x = np.clip(final.spec.x_from_values(vals), lo, hi)
    c0, n0 = _replay_cost(final, data)
    c1, _ = _replay_cost(dataclasses.replace(final, x=x), data)
    margin = math.sqrt(2 * max(n0, 1))
    info = {"rest_reading_deg": float(np.mean(rests)), "limp_home_reading_deg": r_lh, "offset_shift_deg": d_off,
            "cost_before": c0, "cost_after": c1, "margin": margin,
            "kept": bool(math.isfinite(c1) and c1 <= c0 + margin)}
    if note is not None:
        note["rest_offset"] = info
    return dataclasses.replace(final, x=x, rss=c1) if info["kept"] else final
