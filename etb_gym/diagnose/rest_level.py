"""The levels that set where a plate rests, fitted on the replay of the recorded voltage (docs/diagnosis.md,
"Friction families: the levels where a plate rests (round 16)").

A held plate rests where drive - spring = +-friction (the sign: the direction it came from), so an error dT of the
sliding friction level moves every rest by dT / k (k the spring's rate; 3B: 0.16 deg per mN m, 13x the noise), and
an error of the spring's preload moves every rest the same way. The fits see these levels through residuals that
restart at the readings (the restart view) or are corrected by an observer (closed loops), which pin the friction
level to 0.3-3.5 mN m; a twin replayed on another excitation needs it to ~0.2 mN m (round 15). The replay of the
recorded voltage (going on from the model's own state) sees it, but as a stick-slip landscape with many local
minima, where a gradient step from the fit's optimum stays put. So each level is *scanned* on that replay, coarse
to fine, one at a time (friction level, then preload, twice round), the other parameters held at their fitted
values:

    grid half-width  max(SPAN_SE x the fit's standard error, SPAN_REST x dT_rest)      dT_rest = k x noise [rad]
    steps            COARSE points over the grid, then REFINE-fold finer around the best, down to dT_rest

(dT_rest: the level change that moves a rest by one noise floor; without a spring, the standard error / REFINE).
Guarded by halves as run.polish_replay: scanned on the first half of every recording, the second half's cost must
fall by more than its noise (sqrt(2 n)), and the other way round; on recordings scored by the observer, the scan on
the whole replay must also not raise the observer residual's cost by more than its noise. No per-family constant.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from . import fit as F
from .model import Data, SimulationFailed, replay_view

LEVELS = ("friction.coulomb_Nm", "spring.preload_Nm")   # the nominal levels that set where a plate rests
SPAN_SE = 4.0        # the scan covers this many standard errors of the fit either side ...
SPAN_REST = 8.0      # ... and at least this many rest steps (dT_rest) either side
COARSE = 17          # points of the first grid (odd: the fit's own value is one)
REFINE = 4           # each finer grid has this many times smaller steps, over +-2 steps of the coarser one
SWEEPS = 2           # rounds over the levels (the second over a quarter of the first's span)


def _level_indices(fr: F.FitResult) -> list[int]:
    return [k for k, (o, p) in enumerate(fr.spec.params) if o == "nominal" and p.name in LEVELS]


def _has_friction_effect(fr: F.FitResult) -> bool:
    return any(getattr(c, "family", None) == "friction" for c in fr.spec.candidates)


def rest_steps(fr: F.FitResult, data: Data, idx: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Per level (``idx``): the finest step and the half-width of the scan, in normalized units."""
    vals = fr.spec.values(fr.x)
    k = vals.get("spring.rate_Nm_per_rad", 0.0)
    noise_rad = math.radians(min(rd.noise_deg for rd in data.recs))
    se = fr.stderr()
    names = fr.spec.names
    step, half = np.zeros(len(idx)), np.zeros(len(idx))
    for j, i in enumerate(idx):
        p = fr.spec.params[i][1]
        s = se.get(names[i], math.inf)
        d_rest = k * noise_rad if k > 0.0 else (s / REFINE if math.isfinite(s) else math.nan)
        if not (math.isfinite(d_rest) and d_rest > 0.0):
            step[j], half[j] = math.nan, math.nan
            continue
        w = max(SPAN_SE * s if math.isfinite(s) else 0.0, SPAN_REST * d_rest)
        step[j], half[j] = d_rest / p.scale, w / p.scale
    return step, half


def scan_levels(fr: F.FitResult, view: Data, idx: list[int], step, half, masks=None) -> tuple[np.ndarray, int]:
    """The levels ``idx`` of ``fr.x`` scanned coarse to fine on ``view`` (angle residual, ``masks``): returns x
    and the number of simulations."""
    fun = F.make_fun(fr.spec, view, masks, with_current=False)
    lo, hi = fr.spec.bounds()
    x = fr.x.copy()
    cache: dict = {}

    def cost(xx):
        key = tuple(np.round(xx[idx], 12))
        if key not in cache:
            r = fun(xx)
            cache[key] = float(r @ r)
        return cache[key]

    best = cost(x)
    for sweep in range(SWEEPS):
        for j, i in enumerate(idx):
            if not math.isfinite(step[j]):
                continue
            w = half[j] / (4.0 ** sweep)
            h = 2.0 * w / (COARSE - 1)
            centre, offsets = x[i], np.linspace(-w, w, COARSE)
            while True:
                for o in offsets:
                    v = centre + o
                    if not lo[i] < v < hi[i]:
                        continue
                    xt = x.copy()
                    xt[i] = v
                    c = cost(xt)
                    if c < best:
                        best, x = c, xt
                if h <= step[j]:
                    break
                centre, h = x[i], h / REFINE
                offsets = h * np.arange(-2 * REFINE, 2 * REFINE + 1)
    return x, len(cache)


def _shift(fr: F.FitResult, x, names) -> dict:
    """The physical change of each level from ``fr.x`` to ``x``."""
    v0, v1 = fr.spec.values(fr.x), fr.spec.values(x)
    return {nm: v1[nm] - v0[nm] for nm in names}


def fit_rest_levels(fr: F.FitResult, data: Data, note: dict | None = None) -> F.FitResult:
    """``fr`` (a final model with a friction effect) with its friction level and spring preload scanned on the
    replay of the recorded voltage, kept only where the halves guard passes (module doc). ``note`` gets the
    figures (report.json ``rest_levels``). Otherwise, or on failure: ``fr``."""
    idx = _level_indices(fr)
    if not idx or not _has_friction_effect(fr) or not data.continuity:
        return fr
    observer = any(rd.residual == "observer" for rd in data.recs)
    rv = replay_view(data) if observer else data
    step, half = rest_steps(fr, data, idx)
    names = [fr.spec.names[i] for i in idx]
    info = {"levels": names, "folds": [], "kept": False, "simulations": 0}
    try:
        A = [rd.rec.t_s - rd.rec.t_s[0] < 0.5 * (rd.rec.t_s[-1] - rd.rec.t_s[0]) for rd in rv.recs]
        B = [~a for a in A]
        for fit_m, test_m in ((A, B), (B, A)):
            x_part, n = scan_levels(fr, rv, idx, step, half, fit_m)
            info["simulations"] += n
            r0, r1 = (F.evaluate(fr.spec, rv, x, masks=test_m, with_current=False) for x in (fr.x, x_part))
            info["folds"].append({"held_cost_before": float(r0 @ r0), "held_cost_after": float(r1 @ r1),
                                  "margin": math.sqrt(2 * r0.size),
                                  "shift": _shift(fr, x_part, names)})
        if all(f["held_cost_before"] - f["held_cost_after"] > f["margin"] for f in info["folds"]):
            x, n = scan_levels(fr, rv, idx, step, half)
            info["simulations"] += n
            info["shift"] = _shift(fr, x, names)
            if observer:
                o0, o1 = (F.evaluate(fr.spec, data, xx) for xx in (fr.x, x))
                info["observer_cost"] = [float(o0 @ o0), float(o1 @ o1), math.sqrt(2 * o0.size)]
                info["kept"] = bool(o1 @ o1 - o0 @ o0 <= math.sqrt(2 * o0.size))
            else:
                info["kept"] = True
    except (SimulationFailed, ValueError, FloatingPointError, np.linalg.LinAlgError) as e:
        info["failed"] = str(e)
    if note is not None:
        note.update(info)
    if not info["kept"]:
        return fr
    r = F.evaluate(fr.spec, data, x)
    # the Jacobian (standard errors, block scores) stays the final fit's, taken near x
    return dataclasses.replace(fr, x=x, rss=float(r @ r))
