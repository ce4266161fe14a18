"""Sensor-side maps learned from the data once a sensing family is named (issue 15 item 3; docs/diagnosis.md,
"A sensor-side map in the twin").

The catalogue's sensing candidates are an offset and gain (``sensor_offset_gain``) and a pure delay
(``sensor_delay``). A rig's reading may follow a nonlinear curve over angle or a reading filter that is not a
delay; the twin then cannot represent it and misses held-out recordings although the family was named. So
after the selection the named family's map is learned from the data:

    sensor_offset_gain  ->  curve   y = g (phi + d(phi)) + o      d: a table over angle (effects_maps.SensorMapParams)
    sensor_delay        ->  filter  y = g sum_j w_j phi[k-j] + o   w: a causal FIR kernel, sum 1 (ReadingFilterParams)

Given the selected model's simulated angle (a replay of the recorded voltage whose segments restart at the
readings: the observer residual of a closed loop would pull the model towards readings read through the wrong
sensor; but the filter, in a closed loop, on the observer's angle with non-negative weights: :func:`_view`), both
are linear in their unknowns: the curve's knot values (piecewise-linear hat functions over CURVE_KNOTS knots
spanning the visited angles), the filter's weights w_1..w_{N-1} (w_0 = 1 - sum: unit gain at rest; N = FILTER_SPAN_S of samples, at most MAX_TAPS). They are found by penalized least squares

    minimize |W (z - X c)|^2 + lambda |D c|^2        D: second differences (the roughness), W: 1/noise per recording

with lambda chosen by two-fold cross-validation over alternating FOLD_BLOCK_S blocks of time (as the torque
tables, shapes.py). The map is kept when its cross-validated error is MIN_GAIN below the current sensor's
(the zero map); the model's nominal and effect parameters are then refitted with the map held
(REFIT_NFEV evaluations), the map is fitted once more on the refitted model's angle, and the result is kept
when it replays the recordings (segments restarted at the readings) better than the model without the map. The map then lives in
``Spec.sensor_map``: every later simulation (polish, report, the exported twin) reads through it, and the
plant file's ``[sensor]`` section carries it (docs/plant-file.md).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.optimize import lsq_linear

from ..components.effects_maps import SensorMapParams
from ..components.sensor import MAX_FILTER_TAPS, ReadingFilterParams
from . import fit as F
from .model import Data, SimulationFailed, replay_view, restart_view, simulate
from .observer import observe
from .shapes import hat_weights

SENSING_MAPS = {"sensor_offset_gain": "curve", "sensor_delay": "filter"}
CURVE_KNOTS = 16              # knots of the reading curve over the visited angles
FILTER_SPAN_S = 0.03          # the filter kernel's length (a 6 ms lag decays to 1 % in 28 ms)
MAX_TAPS = 32                 # ... at most this many samples (<= components.sensor.MAX_FILTER_TAPS)
LAMBDAS = tuple(10.0 ** e for e in np.arange(-6.0, 4.01, 1.0))   # roughness weights (relative) tried
FOLD_BLOCK_S = 0.5            # the cross-validation's alternating time blocks
MIN_GAIN = 0.05               # the map's cross-validated error must be this fraction below the zero map's
REFIT_NFEV = 20               # evaluations of the refit of the model's parameters with the map held
RIDGE = 1e-9                  # keeps the normal equations regular (relative to the design's scale)
PASSES = {"curve": 8}         # refit / learn-again passes at most (1 for the filter, as before round 21) ...
PASS_GAIN = 0.02              # ... while the replay's sum of squares falls by this fraction per pass. Why: the
                              # calibrated spring and friction absorb part of a reading's bow (a static map over
                              # angle), so each pass learns a little more of it (measured: sensor_offset_gain@1
                              # 3B s18 open, the curve's depth at 45 deg -0.08, -0.10, -0.11, -0.12 deg over four
                              # passes, held-out 9.6, 6.7, 5.7, 4.6; docs/diagnosis-history.md, round 21)

assert MAX_TAPS <= MAX_FILTER_TAPS


@dataclasses.dataclass
class SensorRefinement:
    """What :func:`refine_sensor` learned: the map (``params``), its roughness weight, the cross-validated
    errors of the zero map and of the map (sum of squares in noise units), and whether it was kept."""

    family_id: str
    kind: str                       # "curve" or "filter"
    params: object                  # SensorMapParams or ReadingFilterParams
    roughness_weight: float
    cv_without: float
    cv_with: float
    kept: bool
    fit: object = None              # the refitted FitResult (kept only)

    def entry(self) -> dict:
        """The report's description of the map (report.json: the family's ``sensor_map``)."""
        d = {"kind": self.kind, "roughness_weight": self.roughness_weight, "cv_error_without": self.cv_without,
             "cv_error_with": self.cv_with, "kept": self.kept}
        if self.kind == "curve":
            d.update(angle_rad=list(self.params.angle_rad), error_rad=list(self.params.error_rad),
                     description="the reading's error over the true angle, learned from the data "
                                 "(plant file [sensor.curve])")
        else:
            d.update(weights=list(self.params.weights), mean_lag_periods=self.params.mean_lag_periods,
                     description="the reading's dynamics as a causal FIR kernel over samples, learned from the data "
                                 "(plant file [sensor.filter])")
        return d


def _second_differences(p: int) -> np.ndarray:
    D = np.zeros((max(p - 2, 0), p))
    for k in range(p - 2):
        D[k, k:k + 3] = (1.0, -2.0, 1.0)
    return D


def penalized_fit(X: np.ndarray, z: np.ndarray, fold: np.ndarray, D: np.ndarray, lambdas=LAMBDAS,
                  nonneg: bool = False):
    """(coefficients on all rows at the chosen weight, relative weight, CV error of the zero map, CV error of
    the map): two-fold cross-validation (``fold`` 0/1 per row) of ``minimize |z - X c|^2 + lam |D c|^2`` over
    ``lambdas`` (relative to the design's mean squared column norm); ``nonneg``: with 0 <= c <= 1 (scipy's
    bounded least squares on the penalized rows)."""
    p = X.shape[1]
    scale = max(float(np.sum(X * X)) / max(p, 1), 1e-300)
    parts = [(fold == k) for k in (0, 1)]
    if nonneg:
        def solve(k, lam):                  # k: the fold fitted (0, 1) or None for all rows
            m = parts[k] if k is not None else np.ones(z.size, bool)
            A = np.vstack([X[m], math.sqrt(scale) * np.vstack([math.sqrt(lam) * D, math.sqrt(RIDGE) * np.eye(p)])])
            return lsq_linear(A, np.concatenate([z[m], np.zeros(D.shape[0] + p)]), bounds=(0.0, 1.0), method="bvls").x
    else:
        P = D.T @ D
        grams = [(X[m].T @ X[m], X[m].T @ z[m]) for m in parts] + [(X.T @ X, X.T @ z)]

        def solve(k, lam):
            G, b = grams[k if k is not None else 2]
            return np.linalg.solve(G + scale * (lam * P + RIDGE * np.eye(p)), b)
    best = (math.inf, None)
    for lam in lambdas:
        err = 0.0
        for k in (0, 1):
            m = parts[1 - k]
            e = z[m] - X[m] @ solve(k, lam)
            err += float(e @ e)
        if err < best[0]:
            best = (err, lam)
    cv1, lam = best
    return solve(None, lam), float(lam), float(z @ z), float(cv1)


def _view(data: Data, kind: str) -> Data:
    """The view a ``kind`` map is learned and judged on: the replay whose segments restart at the readings, but
    for the filter the closed-loop recordings keep their observer residual. Why: in a closed loop the recorded
    voltage is the controller's reaction to the rig's plate, so a replay drifts wherever the model places a
    stick-slip event a little differently (degrees within a 0.5 s segment), and the filter's regression would
    read a plate angle that is not the one the sensor saw (sensor_delay@2 random s41 closed, a 12-sample moving
    average: the restart replay's reference error 225 noise units squared per sample, no filter kept, twin 197x).
    The observer holds the model's angle to the readings, compared at the sensor's lag, so its angle follows
    the plate's timing while its shape is the model's physics. The curve keeps the replay: the observer's pull
    towards readings read through the wrong static map would hide part of the map."""
    v = restart_view(replay_view(data))
    if kind != "filter":
        return v
    return dataclasses.replace(v, recs=[dataclasses.replace(r, residual=rd.residual) for rd, r in zip(data.recs, v.recs)])


def _angles(spec, x, data: Data, undelayed: bool = False, kind: str = "curve"):
    """(per recording (reading [deg], the model's angle as its sensor saw it before gain and offset [deg],
    1/noise, time [s]), the model's sensor) on the ``kind`` map's view (:func:`_view`: on a replay whose
    segments restart at the readings the sensor's delay does not move the plate, so ``undelayed`` reads the
    plate's own angle; the observer injects the readings at the sensor's lag and ``undelayed`` reads its angle
    without the delay); None where it cannot be simulated."""
    view = _view(data, kind)
    plant, sensor = spec.build(x)
    read = dataclasses.replace(sensor, delay_s=0.0) if undelayed else sensor
    out = []
    for rd in view.recs:
        if rd.residual == "observer":
            got, _ = observe(plant, sensor, rd, read=read)
        else:
            got = simulate(plant, read, dataclasses.replace(view, recs=[rd]))
            got = None if got is None else got[0]
        if got is None:
            return None
        u = (got[0] - sensor.offset_deg) / sensor.gain
        if not np.all(np.isfinite(u)):
            return None
        out.append((np.asarray(rd.rec.angle_deg, float), u, 1.0 / rd.noise_deg, np.asarray(rd.rec.t_s, float)))
    return out, sensor


def replay_rss(spec, x, data: Data, kind: str = "curve") -> float:
    """The model's sum of squared residuals on the ``kind`` map's view (:func:`_view`; on an open-loop recording
    the fit's own residual)."""
    r = F.evaluate(spec, _view(data, kind), x)
    return float(r @ r)


def _folds(t: np.ndarray) -> np.ndarray:
    return (np.floor((t - t[0]) / FOLD_BLOCK_S).astype(np.int64) % 2)


def hat_basis(x: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """Piecewise-linear interpolation as a design matrix: row k holds the weights of ``x[k]`` on the knots
    (held constant beyond the first and last knot, as SensorMap)."""
    j, f = hat_weights(x, knots)
    B = np.zeros((x.size, knots.size))
    rows = np.arange(x.size)
    B[rows, j] = 1.0 - f
    B[rows, j + 1] = f
    return B


def fit_curve(readings, sensor):
    """The reading curve d(phi) on the angles ``readings`` visited: (SensorMapParams, lam, cv0, cv1)."""
    us = np.concatenate([u for _, u, _, _ in readings])
    lo, hi = float(np.percentile(us, 0.2)), float(np.percentile(us, 99.8))
    if not hi - lo > 1.0:                       # less than a degree visited: no curve to learn
        return None
    knots = np.linspace(lo, hi, CURVE_KNOTS)
    X, z, fold = [], [], []
    for y, u, w, t in readings:
        X.append(w * hat_basis(u, knots))
        z.append(w * ((y - sensor.offset_deg) / sensor.gain - u))
        fold.append(_folds(t))
    c, lam, cv0, cv1 = penalized_fit(np.vstack(X), np.concatenate(z), np.concatenate(fold),
                                     _second_differences(knots.size))
    params = SensorMapParams(angle_rad=tuple(np.radians(knots)), error_rad=tuple(np.radians(c)))
    return params, lam, cv0, cv1


def fit_filter(readings, sensor, dt_s: float, nonneg: bool = False):
    """The reading filter's FIR kernel (replacing the model's delay) on ``readings`` whose model angle is the
    plate's own (no delay): (ReadingFilterParams, lam, cv1). ``nonneg``: every weight in [0, 1] (the closed
    loop's observer view, :func:`learn`)."""
    n = int(min(MAX_TAPS, max(3, round(FILTER_SPAN_S / dt_s))))
    X, z, fold = [], [], []
    for y, u, w, t in readings:             # u: the plate's own angle (no delay)
        lagged = np.empty((u.size, n - 1))
        for j in range(1, n):
            lagged[:, j - 1] = np.concatenate([np.full(min(j, u.size), u[0]), u[:max(u.size - j, 0)]]) - u
        X.append(w * lagged)
        z.append(w * ((y - sensor.offset_deg) / sensor.gain - u))
        fold.append(_folds(t))
    X, z, fold = np.vstack(X), np.concatenate(z), np.concatenate(fold)
    # the zero map of this fit is "no delay"; the model's own delay is the reference the filter must beat
    c, lam, _, cv1 = penalized_fit(X, z, fold, _second_differences(n - 1), nonneg=nonneg)
    if nonneg and np.sum(c) > 1.0:          # the newest angle's weight 1 - sum(c) below 0: none instead
        c = c / np.sum(c)
    w_all = np.concatenate([[1.0 - float(np.sum(c))], c])
    return ReadingFilterParams(weights=tuple(w_all)), lam, cv1


def _reference_error(readings, sensor) -> float:
    """The current sensor's sum of squared reading errors (noise units): the zero map."""
    return float(sum(np.sum((w * ((y - sensor.offset_deg) / sensor.gain - u)) ** 2) for y, u, w, _ in readings))


def learn(spec, x, data: Data, kind: str):
    """One fit of the ``kind`` map ("curve", "filter") on the model (``spec``, ``x``): (params, lam, cv0, cv1)
    or None (nothing to learn: the model cannot be replayed, too small a range)."""
    got = _angles(spec, x, data, kind=kind)
    if got is None:
        return None
    readings, sensor = got
    if kind == "curve":
        return fit_curve(readings, sensor)
    plate = _angles(spec, x, data, undelayed=True, kind=kind)
    if plate is None:
        return None
    # in a closed loop's observer view (:func:`_view`) the observer's angle carries the readings it was pulled
    # to, so a free kernel also fits the loop's feedback: alternating weights at its far end (sensor_delay@2
    # random s41 closed, a 12-sample moving average: taps 24-29 +0.26, +0.13, -0.77, +0.47, the twin 10.5x
    # where the true average gives 4.6x). A reading filter averages past angles (a moving average, a first-order
    # lag, a delay between two samples), so there its weights are held non-negative.
    closed = any(rd.residual == "observer" for rd in _view(data, kind).recs)
    params, lam, cv1 = fit_filter(plate[0], sensor, data.dt_s, nonneg=closed)
    return params, lam, _reference_error(readings, sensor), cv1


def held(kind: str, params) -> dict:
    """``Spec.sensor_map`` for a learned map (the filter replaces the fitted delay)."""
    return {"curve": params} if kind == "curve" else {"filter": params, "delay_s": 0.0}


def refine_sensor(cur: F.FitResult, family_id: str, data: Data, log=print) -> SensorRefinement | None:
    """Learn the sensor-side map of the named sensing family ``family_id`` on the model ``cur`` (module
    docstring). None where the family has no map or nothing could be learned."""
    kind = SENSING_MAPS.get(family_id)
    if kind is None or cur.spec.sensor_map:
        return None
    try:
        got = learn(cur.spec, cur.x, data, kind)
    except (SimulationFailed, ValueError, np.linalg.LinAlgError) as e:
        log(f"  {family_id}: no sensor {kind} learned ({e})")
        return None
    if got is None:
        return None
    params, lam, cv0, cv1 = got
    # with passes (PASSES) the first curve only has to gain out of fold: the calibrated model has absorbed part of
    # the bow, which the passes take back; the result must then replay MIN_GAIN better (below)
    passes = PASSES.get(kind, 1)
    gate = 1.0 if passes > 1 else 1.0 - MIN_GAIN
    ref = SensorRefinement(family_id, kind, params, lam, cv0, cv1, kept=cv1 < gate * cv0)
    log(f"  {family_id}: sensor {kind} learned from the data, cross-validated error {cv1:.4g} against {cv0:.4g} "
        f"(roughness {lam:g}){'' if ref.kept else ': not kept'}")
    if not ref.kept:
        return ref
    spec = dataclasses.replace(cur.spec, sensor_map=held(kind, params))
    x, prev = cur.x, None
    for k in range(passes):
        try:
            fr = F.fit(spec, data, x, max_nfev=REFIT_NFEV)
            again = learn(dataclasses.replace(spec, sensor_map=None), fr.x, data, kind)
        except (SimulationFailed, ValueError, np.linalg.LinAlgError) as e:
            if k:                               # the passes before stand
                break
            log(f"  {family_id}: the model with the sensor {kind} cannot be refitted ({e}): not kept")
            ref.kept = False
            return ref
        if again is None or not again[3] < again[2]:
            break
        ref.params, ref.roughness_weight = again[0], again[1]
        spec = dataclasses.replace(spec, sensor_map=held(kind, again[0]))
        fr = dataclasses.replace(fr, spec=spec, rss=float(np.sum(F.evaluate(spec, data, fr.x) ** 2)))
        x = fr.x
        now = replay_rss(spec, x, data, kind) if passes > 1 else None
        if k and now is not None and not now < (1.0 - PASS_GAIN) * prev:
            break
        prev = now
    if passes > 1 and k:
        log(f"  {family_id}: sensor {kind} and the model's parameters alternated {k + 1} times")
    # judged on the view the map was learned on (a closed loop's observer residual hides the reading's dynamics:
    # sensor_delay@2 3B s7 closed, CV error -11 %, observer rss not lower); the refit (on the fit's residual, the
    # observer's in a closed loop) may move away from that view, so there the map on the selected model's
    # parameters competes with it (3B s7: the refitted model replayed worse than the one without the map)
    before = replay_rss(cur.spec, cur.x, data, kind)
    held_spec = dataclasses.replace(cur.spec, sensor_map=held(kind, ref.params))
    tries = [(replay_rss(fr.spec, fr.x, data, kind), fr)]
    if any(rd.residual == "observer" for rd in data.recs):
        tries.append((replay_rss(held_spec, cur.x, data, kind), dataclasses.replace(cur, spec=held_spec)))
    after, fr = min(tries, key=lambda a: a[0])
    if fr.spec is held_spec:
        fr = dataclasses.replace(fr, rss=float(np.sum(F.evaluate(held_spec, data, fr.x) ** 2)))
    if not after < (1.0 - MIN_GAIN if passes > 1 else 1.0) * before:
        log(f"  {family_id}: the model with the sensor {kind} does not replay the recordings better (rss {after:.4g} "
            f"against {before:.4g}): not kept")
        ref.kept = False
        return ref
    ref.fit = fr
    return ref


def replaces_later(steps: list, final: F.FitResult, data: Data, log=print) -> SensorRefinement | None:
    """When the first accepted effect is a sensing family and later effects were added: its map learned on the
    model of the first step alone, kept if that model predicts held-out data (penalized.heldout_error) as well as
    the model with every step (within family_table.MIN_GAIN), else None. Why: the offset-and-gain formula cannot bend;
    a reading curve's bow (a few tenths of a degree over the stroke) is then what the next round sees, and a
    torque family whose effect grows with the angle (a flux loss, an open stop's contact) absorbs part of it
    (measured: sensor_offset_gain@1 seed 18, 3B and random nameplates, named with shaft_flux_loss /
    end_stop_compliance, twin 2.4x / 3.3x the noise, no better than the nominal model's)."""
    from .family_table import MIN_GAIN as SHAPE_GAIN
    from .penalized import Problem, heldout_error
    if len(steps) < 2 or steps[0].id not in SENSING_MAPS:
        return None
    sref = refine_sensor(steps[0].fit, steps[0].id, data, log)
    if sref is None or not sref.kept:
        return None
    first = sref.fit
    h_first = heldout_error(Problem.make(first.spec, first.x, ("nominal",) + tuple(c.id for c in first.spec.candidates)),
                            data)
    h_all = heldout_error(Problem.make(final.spec, final.x, ("nominal",) + tuple(c.id for c in final.spec.candidates)),
                          data)
    keep = h_first <= (1.0 + SHAPE_GAIN) * h_all
    log(f"  {steps[0].id} with its sensor {sref.kind}: held-out {h_first:.3g} against {h_all:.3g} with "
        f"{', '.join(st.id for st in steps[1:])} added: " + ("the later effects are dropped" if keep else "kept all"))
    return sref if keep else None


def plot(ax, ref: SensorRefinement, title: str) -> None:
    """The learned map on a matplotlib axis: the reading error over the true angle [deg], or the FIR kernel."""
    if ref.kind == "curve":
        a = np.degrees(np.asarray(ref.params.angle_rad))
        e = np.degrees(np.asarray(ref.params.error_rad))
        ax.plot(a, e, "o-", ms=3)
        ax.set_xlabel("true angle [deg]")
        ax.set_ylabel("reading - angle [deg]")
    else:
        w = np.asarray(ref.params.weights)
        ax.bar(np.arange(w.size), w, width=0.8)
        ax.set_xlabel("age of the angle [samples]")
        ax.set_ylabel("weight")
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set_title(title, fontsize=9)
