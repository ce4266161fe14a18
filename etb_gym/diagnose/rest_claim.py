"""Closed loops: a reading offset named from the unpowered rest before the loop engages.

A closed loop holds the READING at its set points, so above limp-home a reading offset o and gain g trade exactly
with the spring's preload and rate: the spring torque P + R (phi - phi_LH) at the plate's angle (r - o) / g is the
same for P' = P + R (o' - o) / g (docs/diagnosis-history.md, round 33 q33gain). The calibration absorbs the offset
into the nominal spring (within its 10-20 % nameplate error), the observer residual is left within the noise and
the verdict was `match`: nothing for the screening to find. The one reading such a recording holds that does not
trade is the plate at rest before the loop engages: unpowered, the springs hold it at limp-home (the fail-safe
position, within the limp-home compliance), so the rest reads r(phi_LH) = g phi_LH + o, and its departure from the
model's reading of limp-home is the offset, read directly.

Measured (docs/diagnosis-history.md, round 34 w34gain): sensor_offset_gain@1 3B closed s47 (truth offset +0.215 deg,
bow -0.166 deg): the rest read 3.196 deg against limp-home 3.000 (+6.5 noise levels of 0.03 deg, the mean of 200
samples); the calibrated preload 0.14906 N m against the truth's 0.14985 (the offset partly absorbed); verdict
`match`. Clean closed recordings (3B and random nameplates, seeds 41-47) read within 0.15 noise levels of limp-home.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

from . import fit as F
from .model import Data, SimulationFailed, residual_blocks

REST_CLAIM_K = 3.0      # the rest's departure from limp-home that names an offset: this many noise levels (or steps)
REST_CLAIM_NFEV = 60    # the refit of the other parameters with the offset held at the rest's


def _design(spec, x: np.ndarray, cols: np.ndarray, r0: np.ndarray, data: Data, h: float = 0.03) -> np.ndarray:
    fun = F.make_fun(spec, data)
    J = np.empty((r0.size, cols.size))
    for j, k in enumerate(cols):
        xx = x.copy()
        xx[k] += h
        J[:, j] = (fun(xx) - r0) / h
    return J


def rest_evidence(rests: list, r_lh: float, noises: list) -> dict:
    """The rests' (``rests``: arrays of readings [deg], noise levels ``noises``) evidence for a reading offset
    d = their mean - ``r_lh`` (the model's reading of limp-home): ``dbic`` the change of the rests' chi-square (in
    noise units) from reading limp-home to reading limp-home + d, plus ln n for the one parameter; ``heldout_gain``
    the two-fold check (each half's mean predicts the other half's readings: 1 - their mean square against the
    limp-home reading's)."""
    y = np.concatenate(rests)
    w = np.concatenate([np.full(r.size, 1.0 / max(s, 1e-9)) for r, s in zip(rests, noises)])
    d = float(np.mean(y)) - r_lh
    c0 = float(np.sum(((y - r_lh) * w) ** 2))
    c1 = float(np.sum(((y - r_lh - d) * w) ** 2))
    before = after = 0.0
    for r in rests:
        h = r.size // 2
        for fit_part, test_part in ((r[:h], r[h:]), (r[h:], r[:h])):
            if fit_part.size and test_part.size:
                before += float(np.sum((test_part - r_lh) ** 2))
                after += float(np.sum((test_part - float(np.mean(fit_part))) ** 2))
    return {"offset_deg": d, "dbic": c1 - c0 + math.log(max(y.size, 2)),
            "heldout_gain": 1.0 - after / before if before > 0 else 0.0, "samples": int(y.size)}


def dead_band_deg(plant) -> float:
    """Half-width [deg] of the angles around limp-home where a released, unpowered plate of ``plant`` stays put:
    (T_s - T_SP0) / R where the static friction T_s (LuGre's ``static_Nm``, else the Coulomb level) exceeds the
    preload T_SP0, else 0 (the springs return it onto limp-home, within the contact compliance)."""
    fp = getattr(plant.friction, "params", None)
    ts = getattr(fp, "static_Nm", getattr(fp, "coulomb_Nm", 0.0)) if fp is not None else 0.0
    sp = plant.spring.params
    rate = float(sp.rate_Nm_per_rad)
    return math.degrees(max(float(ts) - float(sp.preload_Nm), 0.0) / rate) if rate > 0 else math.inf


def rest_claim(nominal: F.FitResult, data: Data, candidates, significant=None, note: dict | None = None):
    """(the final model, its steps) with ``sensor_offset_gain`` named from the recordings' unpowered rest, or None.

    For a closed loop (every recording scored by the observer) whose calibrated nominal model ``nominal`` leaves
    no significant mismatch: where the rests before the loop engages (closed_twin.start_rest_samples) read more
    than REST_CLAIM_K noise levels (and resolution steps) away from the model's reading of limp-home, the offset
    is set to that departure, the preload moved along its trade (R d / g), and the other parameters (friction,
    preload, rate, the reading's bow) refitted on the observer residual with the offset (and the gain, which the
    loop trades with the rate) held. Kept where the observer's cost does not rise by more than its noise
    (sqrt(2 n)) and the verdict's test (``significant``) finds no mismatch: the rest is then read by the model
    and nothing the loop saw contradicts it. ``note`` (a dict) gets the figures (report.json
    ``replay_tables.rest_claim``).

    Why REST_CLAIM_K = 3 noise levels: the proof's own line for a detectable effect (proof_tables.DETECTABLE), far
    above what a still rest's mean can miss by (the noise over sqrt(n) of >= 20 samples, half a resolution step
    where the noise does not dither the reading). The premise: the unpowered rest marks limp-home, as a throttle
    body's fail-safe springs are built to return a released plate there and a recording started at rest on
    limp-home has it; then only a reading offset (or a limp-home angle other than the nameplate's, which the
    catalogue does not fit) moves the rest's reading. Where the static friction exceeds the preload (the paper's
    nominal 3B) a released plate may stop within :func:`dead_band_deg` of limp-home; the caller skips this rule
    (and closed_twin.rest_offset) where ``Options.rest_at_limp_home`` is False (``--rest-not-at-limp-home``)."""
    from .candidates import CANDIDATES
    from .closed_twin import _replay_cost, start_rest_samples
    if "sensor_offset_gain" not in candidates or nominal.spec.candidates or not data.recs \
            or not all(rd.residual == "observer" for rd in data.recs):
        return None
    lh = float(nominal.spec.base.limp_home_rad)
    pairs = [(y, rd) for y, rd in ((start_rest_samples(rd), rd) for rd in data.recs) if y is not None]
    plant, sensor = nominal.spec.build(nominal.x)
    if not pairs or plant.spring is None or not math.isfinite(lh):
        return None
    r_lh = float(sensor.apply(np.zeros(1), np.array([math.degrees(lh)]))[0])
    ev = rest_evidence([y for y, _ in pairs], r_lh, [rd.noise_deg for _, rd in pairs])
    d = ev["offset_deg"]
    step = max(max(rd.noise_deg, rd.resolution_deg) for _, rd in pairs)
    info = {"rest_reading_deg": r_lh + d, "limp_home_reading_deg": r_lh, "offset_deg": d, "step_deg": step,
            "threshold_deg": REST_CLAIM_K * step, **{k: ev[k] for k in ("dbic", "heldout_gain", "samples")},
            "kept": False}
    # reported, not a gate: where the static friction exceeds the preload (the paper's 3B: 0.22 against 0.15 N m) a
    # released plate stops anywhere within (T_s - T_SP0) / R of limp-home (docs/model.md, "dead band"); the rule
    # assumes the rest marks limp-home (the proof's plate starts there; Options.rest_at_limp_home turns it off)
    info["dead_band_deg"] = dead_band_deg(plant)
    if note is not None:
        note["rest_claim"] = info
    if not abs(d) > REST_CLAIM_K * step:
        info["rule"] = "the rest reads limp-home"
        return None
    spec = nominal.spec.with_candidate(CANDIDATES["sensor_offset_gain"])
    x = np.concatenate([nominal.x, np.zeros(len(spec.params) - nominal.x.size)])
    vals = spec.values(x)
    vals["sensor_offset_gain.offset_deg"] = d
    vals["spring.preload_Nm"] += float(plant.spring.params.rate_Nm_per_rad) * math.radians(d)
    lo, hi = spec.bounds()
    x = np.clip(spec.x_from_values(vals), lo, hi)
    held = ("sensor_offset_gain.offset_deg", "sensor_offset_gain.gain")
    cols = np.array([k for k, n in enumerate(spec.names) if n not in held], int)
    try:
        fun = F.make_fun(spec, data)

        def point(th):
            xx = x.copy()
            xx[cols] = th
            return np.clip(xx, lo, hi)

        out = least_squares(lambda th: fun(point(th)), x[cols], bounds=(lo[cols], hi[cols]), method="trf",
                            diff_step=0.03, max_nfev=REST_CLAIM_NFEV)
        x1 = point(out.x)
        r1 = F.evaluate(spec, data, x1)
        J = _design(spec, x1, np.arange(x1.size), r1, data)
    except (SimulationFailed, ValueError, FloatingPointError, np.linalg.LinAlgError) as e:
        info["rule"] = f"the refit failed: {e}"
        return None
    c0, n0 = _replay_cost(nominal, data)
    c1 = float(r1 @ r1)
    margin = math.sqrt(2 * max(n0, 1))
    fr = F.FitResult(spec, x1, c1, r1.size, J, int(out.nfev), F.integrated_time(r1),
                     F.block_scores(J, r1, residual_blocks(data, F.BLOCK_S)))
    info.update(cost_before=c0, cost_after=c1, margin=margin)
    if not (math.isfinite(c1) and c1 <= c0 + margin):
        info["rule"] = "the observer's cost rose"
        return None
    if significant is not None and significant(fr):
        info["rule"] = "the claimed model would leave a significant mismatch"
        return None
    info.update(kept=True, rule="kept", values={n: float(v) for n, v in spec.values(x1).items()})
    from .explain import Step
    return fr, [Step("sensor_offset_gain", fr, ev["dbic"], ev["heldout_gain"])]
