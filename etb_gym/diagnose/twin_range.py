"""Where the exported twin extrapolates: the part of the stroke its training recordings did not visit (issue 15).

A twin is fitted on the angles its recordings went through. Between the closed and the open stop the user may
drive it anywhere; beyond the visited angles each of its angle-dependent parts continues in its own way: a
family's formula by its law (a spring asymmetry's rate, an airflow polynomial), a learned table held at its edge
value (penalized.hold_rows) or continued along its slope (closed_twin.continue_tables), a Fourier series in angle by
its period, the generic tables of the unmodelled torque at 0 (the nominal model). None of this is evidence.

Measured (docs/diagnosis-history.md, round 24 h24opentwin): spring_asymmetry@2 random open seed 26 visited 5.8-87.4
deg of a 0.9-88.5 deg stroke; the closed held-out recording holds the plate down to 3.1 deg, where the truth's
closing spring hardens beyond the formula's straight continuation: 57 % of the held-out's time lies outside the
training's states and holds 99 % of its squared error (twin 17.6x the noise there, 2.6x elsewhere).

:func:`describe` gives report.json ``twin_range``: the visited angles (``EDGE_Q`` quantiles), the stroke, the
unvisited spans wider than ``MIN_SPAN_DEG``, and per span the twin's angle torque at rest minus the calibrated
nominal model's at the far end (the extrapolated correction, N m) and what carries it.

:func:`hold_airflow` (closed loops, after ``closed_twin.continue_tables``) sets how an airflow torque's table is
carried beyond the angles the loop reached: held at the data's edge above them, and, where the data never went
below limp-home, its level and straight slope at limp-home moved into the spring's preload and rate
(docs/diagnosis-shapes.md, round 33).

:func:`hold_friction` (both loop types, after :func:`hold_airflow`) holds a friction level over angle (the family's
formula + table) at the edge knot's value beyond the knots the slowly visited angles reach (docs/diagnosis-shapes.md,
round 34).
"""
from __future__ import annotations

import math

import numpy as np

AIRFLOW = ("airflow_torque",)   # families whose angle torque is held beyond the closed loop's reach (hold_airflow)
RATE_SPAN_DEG = 25.0     # hold_airflow: the straight part of an airflow total fitted over this span above limp-home,
#                          where the catalogue's x^2 law stays under a tenth of its value at the open stop
SLOW_OVER = 1.0           # a state whose fitted time constant exceeds this multiple of the longest recording is
#                           extrapolated in time (its settled value was never seen)
EDGE_Q = (0.1, 99.9)      # percentiles of the recorded angles taken as the visited range (round 14's quantiles)
MIN_SPAN_DEG = 1.0        # an unvisited span narrower than this is not reported
PASS_S_PER_DEG = 0.005    # inside the visited range, 1-deg bins where the training spent less than this (passing
#                           faster than 200 deg/s on average, never holding) ...
PASS_MIN_DEG = 5.0        # ... over at least this many consecutive degrees are reported as passed only at speed


def _static_torque(plant, phi_rad: np.ndarray) -> np.ndarray | None:
    """The summed torque [N m] of the plant's stateless components at rest (omega 0, current 0); None when it
    cannot be evaluated (a component's kernel fails)."""
    from .unmodelled import _stateless_torque
    try:
        t = _stateless_torque(plant, phi_rad, np.zeros(phi_rad.size), np.zeros(phi_rad.size))
    except (ValueError, ZeroDivisionError, FloatingPointError, OverflowError, TypeError, IndexError):
        return None
    return t if np.all(np.isfinite(t)) else None


def _carriers(plant, shaped, tables_note) -> list[str]:
    """What continues the twin's angle-dependent torque beyond the visited angles, in words."""
    out = []
    continued = {e["table"] for e in (tables_note or {}).get("beyond_visited", {}).get("tables", [])} \
        if (tables_note or {}).get("beyond_visited", {}).get("kept") else set()
    ab = (tables_note or {}).get("airflow_beyond") or {}
    held = {e["table"] for e in ab.get("tables", [])} if ab.get("kept") else set()
    for ref in getattr(shaped, "refinements", []) or []:
        if ref.kept and ref.term.cls.grid_field == "angle_rad":
            how = (", held above the recorded angles, its level and slope at limp-home in the spring (hold_airflow)"
                   if ref.term.id in held
                   else ", the table continued along its slope" if ref.term.id in continued else "")
            out.append(f"{ref.family_id}'s formula + learned table over angle{how}")
    g = getattr(shaped, "generic", None)
    if getattr(shaped, "outside", False) and g is not None:
        out.append("the Fourier series in angle (repeats its period)" if g.series is not None
                   else "the unmodelled tables (back to the nominal model)")
    named = [getattr(c, "effect_id", None) or c.__class__.__name__ for c in plant.components
             if getattr(c, "role", "") == "effect"]
    if not out and named:
        out.append("the effects' own laws (" + ", ".join(named) + ")")
    return out


def slow_states(plant, duration_s: float, over: float = SLOW_OVER) -> list[dict]:
    """The twin's effects whose fitted time constant (a ``*time_constant_s`` property of their parameters, e.g.
    coil_heating's C_th R_th) exceeds ``over`` times ``duration_s``, the longest training recording: the fit saw
    the start of the state's rise, not where it settles, so the settled value (e.g. the winding's steady temperature
    under a long hold) is an extrapolation of the one-time-constant law.

    Measured (round 25, l25closed): coil_heating@1 random closed seed 29 (the truth: winding and housing nodes),
    6 s recording; the twin's one node fitted tau = 20 s (3.33 J/K, 6.09 K/W) and predicts the open-loop held-out
    recording at 8.2x the noise; the one node fitted on that held-out recording has tau = 8.4 s (1.6x there, 3.4x
    on the training's replay): no single time constant fits both."""
    out = []
    if not duration_s > 0:
        return out
    for c in getattr(plant, "components", ()):
        if getattr(c, "role", "") != "effect":
            continue
        prm = getattr(c, "params", None)
        out += _slow_branches(c, prm, duration_s, over)
        for name in dir(type(prm)):
            if name.endswith("time_constant_s") and isinstance(getattr(type(prm), name, None), property):
                try:
                    tau = float(getattr(prm, name))
                except (TypeError, ValueError, ZeroDivisionError, OverflowError):
                    continue
                if math.isfinite(tau) and tau > over * duration_s:
                    out.append({"effect": getattr(c, "effect_id", None) or c.__class__.__name__, "parameter": name,
                                "tau_s": tau, "recording_s": duration_s})
    return out


def _slow_branches(c, prm, duration_s: float, over: float) -> list[dict]:
    """A learned network's branches (a tuple field ``time_constant_s`` on a grid, e.g. effect.thermal_network's
    Foster branches, whose slowest is 3x the recording by construction) that carry a nonzero value in any of the
    table's value fields and whose time constant exceeds ``over`` x ``duration_s``; the slowest such branch only."""
    taus = getattr(prm, "time_constant_s", None) if getattr(type(prm), "grid", None) == "time_constant_s" else None
    if not isinstance(taus, (tuple, list)):
        return []
    rows = [getattr(prm, f, ()) or () for f in getattr(type(prm), "values", ())]
    slow = [(float(tau), k) for k, tau in enumerate(taus)
            if math.isfinite(float(tau)) and float(tau) > over * duration_s
            and any(k < len(r) and abs(float(r[k])) > 0.0 for r in rows)]
    if not slow:
        return []
    tau, k = max(slow)
    return [{"effect": getattr(c, "effect_id", None) or c.__class__.__name__, "parameter": f"time_constant_s[{k}]",
             "tau_s": tau, "recording_s": duration_s}]


def passed_only(data, lo: float, hi: float) -> list[dict]:
    """Spans of the visited range ``lo``-``hi`` [deg] that the training recordings only passed at speed: 1-deg bins
    with less than PASS_S_PER_DEG of recorded time each, over at least PASS_MIN_DEG consecutive degrees. The twin's
    torque there was learned from the motion's dynamics (inertia, friction, back-EMF dominate), never from a rest,
    where a closed loop may hold the plate. Measured (round 27, s27openangle): shaft_flux_loss@2 3B open seed 32
    spent 57 of 6000 samples at 70-90 deg; its twin's torque at 5 A is 1.4-2.7 mN m off the truth's at 76-85 deg
    and misses the closed held-out's moves there by 11-12x the noise (training 1.2x). Empty when the recordings
    carry no time base."""
    secs, edges = None, np.arange(math.floor(lo), math.ceil(hi) + 1.0, 1.0)
    if edges.size < 2:
        return []
    for rd in data.recs:
        t = getattr(rd.rec, "t_s", None)
        if t is None or len(t) < 2:
            return []
        dt = float(np.median(np.diff(np.asarray(t, float))))
        h = np.histogram(np.asarray(rd.rec.angle_deg, float), bins=edges)[0] * dt
        secs = h if secs is None else secs + h
    thin = secs < PASS_S_PER_DEG
    out, k = [], 0
    while k < thin.size:
        if not thin[k]:
            k += 1
            continue
        j = k
        while j < thin.size and thin[j]:
            j += 1
        if edges[j] - edges[k] >= PASS_MIN_DEG:
            out.append({"from_deg": float(edges[k]), "to_deg": float(edges[j]),
                        "s_per_deg": float(secs[k:j].sum() / (edges[j] - edges[k]))})
        k = j
    return out


def _duration_s(data) -> float:
    d = 0.0
    for rd in data.recs:
        t = getattr(rd.rec, "t_s", None)
        if t is not None and len(t) > 1:
            d = max(d, float(t[-1] - t[0]))
    return d


def describe(plant, nominal_plant, data, shaped=None, tables_note=None) -> dict:
    """report.json ``twin_range`` (see the module's docstring). ``plant``: the exported twin; ``nominal_plant``:
    the calibrated nominal model; ``data``: the training recordings (model.Data)."""
    a = np.concatenate([rd.rec.angle_deg for rd in data.recs])
    lo, hi = (float(v) for v in np.percentile(a, EDGE_Q))
    stroke = [math.degrees(plant.angle_min_rad), math.degrees(plant.angle_max_rad)]
    out = {"visited_deg": [lo, hi], "stroke_deg": stroke, "beyond": [], "words": ""}
    spans = []
    if math.isfinite(stroke[0]) and lo - stroke[0] > MIN_SPAN_DEG:
        spans.append(("below", stroke[0], lo))
    if math.isfinite(stroke[1]) and stroke[1] - hi > MIN_SPAN_DEG:
        spans.append(("above", hi, stroke[1]))
    carriers = _carriers(plant, shaped, tables_note)
    words = []
    for side, s0, s1 in spans:
        far, edge = (s0, s1) if side == "below" else (s1, s0)
        phi = np.radians(np.array([far, edge]))
        tw, tn = _static_torque(plant, phi), _static_torque(nominal_plant, phi)
        corr = None if tw is None or tn is None else [float(tw[0] - tn[0]), float(tw[1] - tn[1])]
        out["beyond"].append({"side": side, "from_deg": s0, "to_deg": s1,
                              "correction_Nm_far": corr[0] if corr else None,
                              "correction_Nm_edge": corr[1] if corr else None})
        w = f"{s0:.1f}-{s1:.1f} deg"
        if corr is not None:
            w += (f" (the twin's torque at rest differs from the calibrated nominal model's by {corr[1]:+.3f} N m at "
                  f"the visited edge, {corr[0]:+.3f} N m at the stop)")
        words.append(w)
    out["carriers"] = carriers
    if words:
        out["words"] = (f"the training recordings visited {lo:.1f}-{hi:.1f} deg of the stroke "
                        f"{stroke[0]:.1f}-{stroke[1]:.1f} deg; the twin extrapolates over " + " and ".join(words)
                        + (", continued there by " + "; ".join(carriers) if carriers else "")
                        + ": not evidence, check it on a recording that goes there")
    else:
        out["words"] = f"the training recordings visited {lo:.1f}-{hi:.1f} deg: the whole stroke"
    out["passed_only"] = passed_only(data, lo, hi)
    if out["passed_only"]:
        out["words"] += ("; it passed " + " and ".join(
            f"{p['from_deg']:.0f}-{p['to_deg']:.0f} deg" for p in out["passed_only"]) + " only at speed ("
            + ", ".join(f"{1e3 * p['s_per_deg']:.1f} ms per degree" for p in out["passed_only"])
            + ", no hold): the twin's torque there is learned from the motion, not from a rest")
    out["slow_states"] = slow_states(plant, _duration_s(data))
    if out["slow_states"]:
        out["words"] += ("; in time, " + ", ".join(
            f"{s['effect']}'s fitted time constant {s['tau_s']:.1f} s exceeds the {s['recording_s']:.1f} s recording"
            for s in out["slow_states"]) + ": the state's settled level (under a longer hold) is extrapolated by "
            "its fitted exponential law, not evidence")
    return out


def airflow_total(total: np.ndarray, top: int | None, kl: int | None, grid: np.ndarray | None = None,
                  reached: np.ndarray | None = None) -> tuple[np.ndarray, float, float]:
    """An airflow torque's total (formula + table) on its knots carried beyond the data (see :func:`hold_airflow`).

    With ``kl`` (limp-home's knot, where the data never went below limp-home; None otherwise), ``grid`` (rad) and
    ``reached`` (the reached knots' indices): the straight line fitted through the reached knots within
    RATE_SPAN_DEG above limp-home is taken out (its slope returned, N m/rad, for the spring's rate) and the knots
    below limp-home are held at limp-home's value. Then the total above knot ``top`` (the first knot at or beyond
    the highest recorded angle: its interval still holds data, so it keeps its value; None: the data reach the
    last knot) is held at its value there, and with ``kl`` the level at limp-home is taken out (returned, N m,
    for the spring's preload). Returns (total, level, slope)."""
    new = np.asarray(total, float).copy()
    slope = 0.0
    if kl is not None and grid is not None and reached is not None:
        g = np.asarray(grid, float)
        m = reached[(g[reached] >= g[kl]) & (g[reached] <= g[kl] + math.radians(RATE_SPAN_DEG))]
        if m.size >= 3:
            slope = float(np.polyfit(g[m] - g[kl], new[m], 1)[0])
            new -= slope * (g - g[kl])
            new[:kl] = new[kl]
    if top is not None:
        new[top + 1:] = new[top]
    level = 0.0
    if kl is not None:
        level = float(new[kl])
        new -= level
    return new, level, slope


def _airflow_edit(final, ref, data, angles) -> dict | None:
    """The edit of one airflow table (see :func:`hold_airflow`): new normalized parameters and the figures."""
    from .closed_twin import reached_knots
    from .family_table import _formula_component
    from .penalized import formula_profile
    from .shapes import visit_time_s
    term = ref.term
    idx = [k for k, (o, _) in enumerate(final.spec.params) if o == term.id]
    if term.cls.grid_field != "angle_rad" or len(term.value_fields) != 1 or len(idx) != term.grid.size:
        return None
    prof, vis = formula_profile(_formula_component(final, ref.family_id), term), visit_time_s(term, data)
    if prof is None or vis is None:
        return None
    grid = np.asarray(term.grid, float)
    seen = reached_knots(grid, np.asarray(vis[:grid.size]), angles)
    if seen.size < 2:
        return None
    ps = [final.spec.params[k][1] for k in idx]
    x = final.x.copy()
    total = prof + np.array([p.init + p.scale * x[k] for p, k in zip(ps, idx)])
    lh = float(final.spec.base.limp_home_rad)
    jp = [k for k, (o, p) in enumerate(final.spec.params) if o == "nominal" and p.name == "spring.preload_Nm"]
    kl = int(np.argmin(np.abs(grid - lh))) if math.isfinite(lh) and jp else None
    if kl is not None and not (abs(grid[kl] - lh) < 1e-9 and grid[0] < lh):
        kl = None                                   # no knot on limp-home (angle_torque_term puts one there)
    if kl is not None and seen[0] < kl:
        kl = None                                   # the data went below limp-home: the table is identified there
    above = np.flatnonzero(grid >= float(np.max(angles)))
    new, moved, slope = airflow_total(total, int(above[0]) if above.size else None, kl, grid, seen)
    if moved:
        p = final.spec.params[jp[0]][1]
        x[jp[0]] -= moved / p.scale                 # T_SP0 - level: the torque above limp-home unchanged
    jr = [k for k, (o, p) in enumerate(final.spec.params) if o == "nominal" and p.name == "spring.rate_Nm_per_rad"]
    if slope and jr:
        x[jr[0]] -= slope / final.spec.params[jr[0]][1].scale    # R_F - slope: the same torque above limp-home
    elif slope:
        return None
    if np.allclose(new, total, rtol=0.0, atol=1e-12):
        return None
    for p, k, v in zip(ps, idx, new - prof):
        x[k] = (v - p.init) / p.scale
    return {"x": x, "table": term.id, "data_deg": [float(np.degrees(np.min(angles))), float(np.degrees(np.max(angles)))],
            "total_before": total.tolist(), "total_after": new.tolist(), "preload_moved_Nm": -moved,
            "rate_moved_Nm_per_rad": -slope}


def hold_airflow(final, shaped, data, note: dict | None = None, significant=None):
    """``final`` with each kept airflow-torque table over angle (:data:`AIRFLOW`) carried beyond the angles a
    closed loop reached by the family's physics instead of a table's tail; recordings all scored by the observer
    only (closed loops), kept where the replay of the recorded voltage gets no worse than its noise (sqrt(2 n),
    as ``closed_twin.continue_tables``) and the verdict's test (``significant``) finds no new mismatch.

    * Above the highest reached knot the family's total (formula + table) is held at its value there, undoing the
      slope continuation of ``continue_tables``: a flow torque on the plate levels off with the opening (and on a
      butterfly valve falls again towards the edge-on plate); the slope where the data end is the rise into that
      level, not a trend. Measured (round 33, r33angle): airflow_torque@1 3B closed s45 (a plateau of -15.5 mN m
      at 48.5 deg), reached 3-62 deg; the slope continued put the total 14 mN m lower at 90 deg (twin 7.9 mN m
      under the truth at 88 deg), the held-out open recording 20.6x the noise; held 8.8x.
    * Where the data never went below limp-home (the lowest reached knot is limp-home's), the total's level at
      limp-home moves into the spring's preload T_SP0 (the table shifted by it): the flow torque is x^2-small at
      the nearly closed plate, and above limp-home the data see only -T_SP0 + table (one sum), while below it the
      preload acts with the other sign, the table with the same; the torque above limp-home is unchanged to
      rounding. Measured: airflow_torque@1 random closed s41, reached 5.3 (limp-home) - 86 deg; table -4.8 mN m at
      limp-home, preload 4.3 % low, the twin 8.4 mN m under the truth at 4 deg, 91 % of the held-out's squared
      error there; twin 29.1x -> 3.5x.
    * With it, the straight line through the reached knots within RATE_SPAN_DEG above limp-home moves into the
      spring's rate R_F (R_F - s, the total - s (phi - phi_LH), the knots below limp-home held at 0): the x^2 law
      has no slope at the nearly closed plate, and over the recorded angles a table's ramp and the rate are one
      straight line, so the fit trades them; beyond the data the held table leaves the rate to carry the torque,
      and a traded rate is off by the ramp there. Measured: s45 above, rate -3.9 %, the total's ramp -0.26 mN m/deg
      over 3-28 deg where the truth's plateau is < 2 % of its level; moved, the total reads 0 to 36 deg and
      -15.4 mN m from 66 deg (the truth's -15.5): 8.7x -> 2.4x; s41 (rate +8.5 %) 3.5x -> 2.2x.

    ``note`` (report.json ``replay_tables``) gets ``airflow_beyond``."""
    from .shapes import data_angles_rad
    import dataclasses
    if shaped is None or not data.recs or not all(rd.residual == "observer" for rd in data.recs):
        return final
    angles = data_angles_rad(data)
    x, edited = final.x, []
    for ref in getattr(shaped, "refinements", []) or []:
        if not ref.kept or ref.family_id not in AIRFLOW:
            continue
        e = _airflow_edit(dataclasses.replace(final, x=x), ref, data, angles)
        if e is not None:
            x = e.pop("x")
            edited.append(e)
    return _keep_edit(final, x, edited, shaped, data, significant, note, "airflow_beyond")


FRICTION_LEVEL = ("angle_dependent_friction",)   # families whose angle table is a friction level (hold_friction)
STOP_MARGIN_DEG = 1.0    # hold_friction: samples this close to a stop do not identify a friction level (the stop holds
#                          the plate; nothing slides)


def slow_range_deg(data, stops_deg: tuple[float, float]) -> tuple[float, float] | None:
    """The angles [deg] the recordings visited slowly: the lowest and highest 1-deg bins with at least
    PASS_S_PER_DEG of recorded time (as :func:`passed_only`), samples within STOP_MARGIN_DEG of a stop
    (``stops_deg``) left out. None without a time base or where no bin qualifies."""
    a0, a1 = stops_deg
    secs, edges = None, None
    for rd in data.recs:
        t = getattr(rd.rec, "t_s", None)
        if t is None or len(t) < 2:
            return None
        a = np.asarray(rd.rec.angle_deg, float)
        a = a[(a > a0 + STOP_MARGIN_DEG) & (a < a1 - STOP_MARGIN_DEG)] if math.isfinite(a0 + a1) else a
        if edges is None:
            lo = math.floor(min(a0, float(np.min(rd.rec.angle_deg)))) if math.isfinite(a0) else -10.0
            hi = math.ceil(max(a1, float(np.max(rd.rec.angle_deg)))) if math.isfinite(a1) else 100.0
            edges = np.arange(lo - 1.0, hi + 2.0, 1.0)
        h = np.histogram(a, bins=edges)[0] * float(np.median(np.diff(np.asarray(t, float))))
        secs = h if secs is None else secs + h
    ok = np.flatnonzero(secs >= PASS_S_PER_DEG)
    if ok.size == 0:
        return None
    return float(edges[ok[0]]), float(edges[ok[-1] + 1])


def friction_total(total: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """A friction level's total (formula + table) on its knots with the knots beyond the identified ones
    (``seen``: indices, increasing) held at the edge knot's value on either side (see :func:`hold_friction`)."""
    new = np.asarray(total, float).copy()
    if seen.size:
        new[:seen[0]] = new[seen[0]]
        new[seen[-1] + 1:] = new[seen[-1]]
    return new


def hold_friction(final, shaped, data, note: dict | None = None, significant=None):
    """``final`` with each kept friction level over angle (:data:`FRICTION_LEVEL`: the family's formula, a slope
    and a curvature over the stroke, plus its table) held beyond the angles the recordings visited slowly, on
    either loop type: a friction level is a non-negative Coulomb force against the motion, with no trend of its own
    beyond the data; outside the identified angles the honest level is the one at the nearest identified angle, not
    the formula's slope and curvature continued (they were fitted together with the table, which takes the shape
    where the data are). Identified: the knots the slowly visited range reaches (:func:`slow_range_deg`: 1-deg
    bins with PASS_S_PER_DEG or more, the stops' margins left out, since a plate against a stop does not slide;
    :func:`.closed_twin.reached_knots`). A span passed only at speed is not: there inertia and the back-EMF dominate
    the torque balance and the table's knots are anchored to the formula by the roughness penalty.

    Measured (round 34, v34adf): angle_dependent_friction@1 random open s46 (a band -23 mN m at 59 deg), the
    training visited 5-65 deg slowly, passed 66-80 deg at 3 ms per degree and rested at the open stop; the twin's
    formula (slope -0.054, curvature -0.12 N m) fell on past the band to 18 mN m under the truth at 71.5 deg, where
    the closed held-out recording holds the plate (90 % of its squared error there), 54 mN m under at 90 deg; held
    at the 61 deg knot's level (the last one the slow visits reach) the training's own replay improves (cost 42876
    -> 27652: its fast passes saw no falling level) and the twin goes 12.8x -> 8.9x; the rest is the band's far
    flank, which no slow visit saw (the nominal Coulomb level there instead: 5.4x on the held-out, but the
    training's replay worse than the hold's, 2.54x against 2.03x the noise).

    Kept where the replay of the recorded voltage gets no worse than its noise (sqrt(2 n)) and the verdict's test
    (``significant``) finds no new mismatch (as :func:`hold_airflow`). ``note`` (report.json ``replay_tables``)
    gets ``friction_beyond``."""
    from .closed_twin import reached_knots
    from .family_table import _formula_component
    from .penalized import formula_profile
    from .shapes import visit_time_s
    if shaped is None or not data.recs:
        return final
    base = final.spec.base
    stops = (math.degrees(base.angle_min_rad), math.degrees(base.angle_max_rad))
    rng = slow_range_deg(data, stops)
    if rng is None:
        return final
    x, edited = final.x.copy(), []
    for ref in getattr(shaped, "refinements", []) or []:
        term = ref.term
        idx = [k for k, (o, _) in enumerate(final.spec.params) if o == term.id]
        if not ref.kept or ref.family_id not in FRICTION_LEVEL or term.cls.grid_field != "angle_rad" \
                or len(term.value_fields) != 1 or len(idx) != term.grid.size:
            continue
        prof, vis = formula_profile(_formula_component(final, ref.family_id), term), visit_time_s(term, data)
        if prof is None or vis is None:
            continue
        grid = np.asarray(term.grid, float)
        seen = reached_knots(grid, np.asarray(vis[:grid.size]), np.radians(np.asarray(rng)))
        if seen.size < 2:
            continue
        ps = [final.spec.params[k][1] for k in idx]
        total = prof + np.array([p.init + p.scale * x[k] for p, k in zip(ps, idx)])
        new = friction_total(total, seen)
        if np.allclose(new, total, rtol=0.0, atol=1e-12):
            continue
        for p, k, v in zip(ps, idx, new - prof):
            x[k] = (v - p.init) / p.scale
        edited.append({"table": term.id, "slow_deg": list(rng),
                       "identified_deg": [float(np.degrees(grid[seen[0]])), float(np.degrees(grid[seen[-1]]))],
                       "total_before": total.tolist(), "total_after": new.tolist()})
    return _keep_edit(final, x, edited, shaped, data, significant, note, "friction_beyond")


def _keep_edit(final, x, edited: list, shaped, data, significant, note, key: str):
    """``final`` with its tables edited to ``x`` (``edited``: what changed, per table), kept where the replay of the
    training recordings does not cost more than its noise (sqrt(2 n)) and, for a final model the verdict's test
    passes, still passes it; ``note[key]`` gets the figures. The report's refinements draw the kept tables."""
    import dataclasses

    from .closed_twin import _replay_cost
    from .model import replay_view
    if not edited:
        return final
    lo, hi = final.spec.bounds()
    x = np.clip(x, lo, hi)
    rv = replay_view(data)
    c0, n0 = _replay_cost(final, rv)
    margin = math.sqrt(2 * max(n0, 1))
    cand = dataclasses.replace(final, x=x)
    c1, _ = _replay_cost(cand, rv)
    kept = bool(math.isfinite(c1) and c1 <= c0 + margin)
    guard = None
    if kept and significant is not None and not significant(final):
        kept = not significant(cand)
        guard = "passed" if kept else "the edit would leave a significant mismatch"
    if note is not None:
        note[key] = {"tables": edited, "replay_cost_before": c0, "replay_cost_after": c1, "margin": margin,
                     "kept": kept, **({"verdict_guard": guard} if guard else {})}
    if not kept:
        return final
    for ref in shaped.refinements:        # the report draws the exported table
        if any(e["table"] == ref.term.id for e in edited) and ref.fit.spec.params == final.spec.params:
            ref.fit = dataclasses.replace(ref.fit, x=x)
    return cand
