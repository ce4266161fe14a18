"""Explain a mismatch: add each candidate to the calibrated model, refit, score, keep the best, repeat.

One round:
  1. screen   every remaining candidate is added and all parameters (nominal + effects) refitted from the
              current estimate (a bounded number of evaluations, after a coarse scan of the candidate's main
              parameter picks its start: fit.scan_start); dBIC = m_eff ln(RSS_c/RSS) + dp ln(m_eff)
              with m_eff = m / tau_int of the candidate's residual. Screening is a ranking, so it runs at the
              coarser integrator step SCREEN_SUBSTEPS (the current model is refitted there too, for a fair
              RSS); validation and the accepted fit run at the diagnosis's own step
  2. validate the TOP_K candidates with dBIC < -BIC_MIN are cross-validated over two folds of alternating
              time blocks (fit on one, score the other); the current model is cross-validated the same way
  2a/2a'/2b   open loops: a voltage-side candidate first when it accounts for the current's residual
              (_current_side); a torque before a leading reading map when the current (which sees the true
              motion, not the reading) sides with it (_current_side too); a friction vs a torque that does not turn with the motion compared by converged
              fits (_direction); close angle-torque rivals by their tables (_tell_apart, both loops); a near
              tie between a family acting at every angle and one with a region of action, by where the gain
              lives (_region, both loops)
  3. accept   of the candidates whose held-out error beats the current model's by at least CV_MIN_GAIN,
              the first in order of dBIC (after the physics' choice of 2a/2a'/2b/2c; the two-fold held-out gain
              gates, the likelihood on all the data ranks: measured, an angle-dependent friction at dBIC -629
              and +42 % held-out lost to an inductance saturation at dBIC -80 and +57 % on a closed loop), if,
              refitted on all the data, it lowers the RMS angle residual over the recordings by at least
              RMS_MIN_GAIN (a closed loop's replay drifts through stick-slip episodes; a candidate that bends to
              such drift wins a little held-out error on a clean recording but barely changes its RMS), or, in
              open loop, halves the angle residual's excess over the noise floor (_excess_down: near the noise
              floor no model lowers the RMS by RMS_MIN_GAIN); in every case only if its own effect carries at
              least FOOTPRINT_SHARE of the gain that accepts it (the footprint guard, _accept: its effect switched
              off, or the current model refitted, gives that much back); a refused candidate whose refit of the
              current model fits better starts the round again from that refit;
              closed loops whose mismatch lives in local windows only (no persistent structure), one holding
              the plate's first move from rest (the loop's engagement, which neither the recording's RMS nor
              the two folds can see): the
              cross-validated shortlist again by dBIC, the first whose full fit halves the excess over the noise
              inside those windows (local_windows, _window_down), with the footprint guard on that statistic;
              otherwise stop: nothing in the library explains it
Rounds repeat (two or more concurrent effects) while the remaining residual is significant.

Closed loops (``persistent``: disturbance.py). A loop hides an effect in the angle, not in the current it had
to apply, so a coil heating or a flux loss can leave the angle's held-out error and RMS as they were while the
current residual carries a persistent structure (a torque on the plate only, a detent: the angle innovation
over steady motion; disturbance.deciding_z takes the larger). Where the current model has one and no candidate passes the
held-out gain, the screened candidates (dBIC < -BIC_MIN) are tried in order of dBIC, and one is accepted when
its full fit accounts for the structure (disturbance.resolved: the same statistic that found it, at most
RESOLVE_SHARE = half of its z left). While such a structure stands, a candidate that accounts for it is accepted
without the angle's RMS gain (the loop keeps the angle where it was), and the next candidates are tried
when one does not (those that pass the held-out gain first, then the others by dBIC). The screening's own
likelihood (the observer's one-step residual, which the loop keeps near the noise) can miss an effect whose
fit accounts for the structure: such screened candidates (``_structural``) join the shortlist. Every z here is
on the nominal model's yardstick (disturbance.py, "One yardstick").
Candidates run in a process pool (fork) when ``jobs > 1``.
"""
from __future__ import annotations

import dataclasses
import math
import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from ..plant import Plant
from . import discriminate as D
from . import disturbance
from . import fit as F
from . import locate as L
from .candidates import CANDIDATES
from .model import Data, Spec, open_loop

BIC_MIN = 10.0
CV_MIN_GAIN = 0.10
RMS_MIN_GAIN = 0.10
EXCESS_MIN_GAIN = 0.5    # open loops: ... or the angle residual's excess over the noise floor halved (_excess_down)
TOP_K = 3
SCREEN_NFEV = 12
RIVAL_CV_SHARE = 0.5     # rivals for the discrimination: formula held-out gain >= this share of the leader's
SCREEN_SUBSTEPS = 10     # second-order stepper: 10 substeps beat the first-order stepper's 20 (docs/model.md)
FULL_NFEV = 40
FOOTPRINT_SHARE = 0.5    # the accepted gain's share that the effect itself must carry (_accept, own_share)
WINDOW_EXCESS_GAIN = 0.5  # closed loops: the local windows' excess over the noise halved (local_windows, _window_down)

_CTX: dict = {}


def _spec(base_dict, nominal, ids) -> Spec:
    key = (repr(base_dict), ids)
    cache = _CTX.setdefault("plants", {})
    if key not in cache:
        cache[key] = Plant.from_dict(base_dict)
    return Spec(cache[key], tuple(CANDIDATES[c] for c in ids), nominal)


class Skipped(str):
    """A task's result when its model could not be simulated (or built): the reason, a sentence."""


def _task(args):
    kind, base_dict, nominal, ids, x0, nfev, *scan = args
    data = _CTX["data"]
    try:
        spec = _spec(base_dict, nominal, ids)
        if kind == "fit":
            fr = F.fit(spec, data, x0, max_nfev=nfev, scan=scan[0] if scan else None)
            return fr.x, fr.rss, fr.m, fr.jac, fr.nfev, fr.tau_int, fr.block_scores
        return F.cross_validate(spec, data, x0, max_nfev=nfev)
    except (ValueError, TypeError, FloatingPointError, ZeroDivisionError, OverflowError, np.linalg.LinAlgError) as e:
        return Skipped(str(e) or type(e).__name__)


@dataclasses.dataclass
class Step:
    id: str
    fit: F.FitResult
    dbic: float
    cv_gain: float
    discrimination: dict | None = None      # evidence when angle-dependent torque rivals were told apart


class Runner:
    """Runs fits here or in a forked process pool sharing the data."""

    def __init__(self, data: Data, jobs: int = 1):
        _CTX["data"] = data
        self.data = data
        self.pool = None
        if jobs > 1 and "fork" in mp.get_all_start_methods():
            self.pool = ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("fork"))

    def map(self, tasks, progress=None):
        it = self.pool.map(_task, tasks) if self.pool is not None else map(_task, tasks)
        out = []
        for r in it:
            out.append(r)
            if progress is not None:
                progress.update(1)
        return out

    def close(self):
        if self.pool is not None:
            self.pool.shutdown()


def dbic(new: F.FitResult, old: F.FitResult) -> float:
    me = new.m / max(new.tau_int, 1.0)
    return me * math.log(max(new.rss, 1e-300) / max(old.rss, 1e-300)) + (len(new.x) - len(old.x)) * math.log(me)


def angle_rms_ratio(new: F.FitResult, old: F.FitResult, data: Data) -> float:
    """RMS angle residual (in noise-floor units) of ``new`` over that of ``old``, on all recorded samples."""
    a = F.evaluate(new.spec, data, new.x, with_current=False)
    b = F.evaluate(old.spec, data, old.x, with_current=False)
    return math.sqrt(float(a @ a) / max(float(b @ b), 1e-300))


def extend(x_old: np.ndarray, spec: Spec, data: Data | None = None, model_deg: list | None = None) -> np.ndarray:
    """``x_old`` with the new candidate's parameters at their start (0: the nameplate's values); with ``data`` and
    ``model_deg`` (the current model's angle per recording, deg), a stop's angle (a parameter measured from a
    stop, ``ref`` a stop angle) that neither the readings nor the model's plate reach starts where the readings
    went furthest instead (:func:`reached_stop`)."""
    x = np.concatenate([x_old, np.zeros(len(spec.params) - len(x_old))])
    if data is not None and model_deg is not None:
        for k in range(len(x_old), len(spec.params)):
            v = reached_stop(spec.params[k][1], spec.base, data, model_deg)
            if v is not None:
                x[k] = v
    return x


def model_angles(fr: F.FitResult, data: Data) -> list:
    """The model ``fr``'s angle per recording [deg] (the reading plus the normalized residual times the noise)."""
    r = F.evaluate(fr.spec, data, fr.x, with_current=False)
    out, k = [], 0
    for rd in data.recs:
        out.append(np.asarray(rd.rec.angle_deg, float) + r[k:k + rd.rec.n] * rd.noise_deg)
        k += rd.rec.n
    return out


STOP_REFS = ("open_stop_rad", "closed_stop_rad")


def reached_stop(p, base: Plant, data: Data, model_deg: list) -> float | None:
    """The normalized start of a stop-angle parameter ``p`` (its ``ref`` the open or the closed stop) at the
    open-loop recordings' furthest reading on that side, when neither those readings nor the current model's plate
    (``model_deg``, per recording) reach the nameplate's stop (the parameter's start), and the furthest reading
    lies inside the parameter's bound and nearer the stop than limp-home (the plate was driven past limp-home
    toward the stop, not resting there); None otherwise (the start stays).
    Why: a stop's angle acts only on a plate in contact with it, so where the model's plate never reaches it the fit
    has no gradient and stays at the nameplate's stop whatever the data say (end_stop_compliance@2 3B open s26, a
    contact from 88.4 deg before the nominal 90 that the calibrated model's plate never reaches either: screening
    dBIC +12 from 90 deg; from the furthest reading, 88.5 deg, -5219; docs/diagnosis-history.md, round 24 g24naming).
    Open loops only: their excitation drives the plate to both stops, so a plate stopped short of the nameplate's
    stop is what the stop's fit should start from; a closed loop's furthest reading is where its reference went
    (seed index 7: 3 of 7 closed-loop cases stay 2.1-2.9 deg above or 6 deg below a stop, none of the open ones)."""
    if p.ref not in STOP_REFS:
        return None
    use = [k for k, rd in enumerate(data.recs) if rd.rec.n and rd.residual == "replay" and k < len(model_deg)]
    if not use:
        return None
    rec = [np.asarray(data.recs[k].rec.angle_deg, float) for k in use]
    mod = [np.asarray(model_deg[k], float) for k in use]
    lh = math.degrees(base.limp_home_rad)
    stop, lo, hi = math.degrees(p.init), math.degrees(p.lower), math.degrees(p.upper)
    if p.ref == "open_stop_rad":
        v = max(float(np.max(a)) for a in rec)
        m = max(float(np.max(a)) for a in mod)
        ok = lo < v < stop and m < stop and v > 0.5 * (lh + stop)
    else:
        v = min(float(np.min(a)) for a in rec)
        m = min(float(np.min(a)) for a in mod)
        ok = stop < v < hi and m > stop and v < 0.5 * (lh + stop)
    return (math.radians(v) - p.init) / p.scale if ok and math.isfinite(v) and math.isfinite(m) else None


@dataclasses.dataclass
class _Ctx:
    """What every round of :func:`select` shares."""

    data: Data
    runner: Runner
    base: Plant
    base_dict: dict
    nominal: tuple
    progress: object
    log: object
    skip: object                      # skip(candidate id, round index, reason)

    def describe(self, text):
        if self.progress is not None:
            self.progress.set_description(text)


def _screen(ctx: _Ctx, cur: F.FitResult, remaining: list, rnd: int):
    """Step 1: every remaining candidate added and refitted at SCREEN_SUBSTEPS (the current model refitted there
    too). A supply drop is fitted from a second start too, its levels (and in open loops its knee) read from the current
    (discriminate.current_start), and the fit that ends lower is kept. Returns (the current model's refit,
    [(dBIC, id, FitResult)] best first), or None when the current model cannot be refitted at the screening step."""
    active = tuple(c.id for c in cur.spec.candidates)
    screen_dict = dict(ctx.base_dict, substeps=min(SCREEN_SUBSTEPS, ctx.base.substeps))
    tasks = [("fit", screen_dict, ctx.nominal, active, cur.x, SCREEN_NFEV)]
    extra: list = []                        # (candidate, task) of a second start (discriminate.current_start)
    stops = any(p.ref in STOP_REFS for c in remaining for p in CANDIDATES[c].fit)
    model_deg = model_angles(cur, ctx.data) if stops else None     # where a stop's angle starts (reached_stop)
    for c in remaining:
        spec = cur.spec.with_candidate(CANDIDATES[c])
        x0 = extend(cur.x, spec, ctx.data, model_deg)
        moved = [k for k in range(len(cur.x), len(x0)) if x0[k] != 0.0]
        if moved:
            vals = spec.values(x0)
            ctx.log(f"  {c}: starts at " + ", ".join(f"{spec.params[k][1].name} {math.degrees(vals[spec.names[k]]):.2f} deg"
                                                     for k in moved)
                    + ", where the readings went furthest (neither they nor the model's plate reach the nameplate's stop)")
        tasks.append(("fit", screen_dict, ctx.nominal, active + (c,), x0, SCREEN_NFEV, len(cur.x)))
        if c in D.CURRENT_PINNED:           # a drop read from the current (discriminate.current_start),
            xc = D.current_start(_spec(screen_dict, ctx.nominal, active + (c,)), ctx.data, x0, len(cur.x),
                                 log=ctx.log)               # a second start: the better screening fit is kept
            if xc is not x0:
                extra.append((c, ("fit", screen_dict, ctx.nominal, active + (c,), xc, SCREEN_NFEV, len(cur.x))))
    n_main = len(tasks)
    tasks += [t for _, t in extra]          # after every candidate's own start: res[1 + k] is remaining[k]'s
    ctx.describe(f"round {rnd + 1}: screening {len(tasks) - 1} candidates")
    res = ctx.runner.map(tasks, ctx.progress)
    if isinstance(res[0], Skipped):         # the current model failed at the screening step: stop here
        ctx.log(f"  the current model cannot be refitted at {SCREEN_SUBSTEPS} substeps ({res[0]}): selection stops")
        return None
    ref = F.FitResult(cur.spec, *res[0])
    main = {c: k + 1 for k, c in enumerate(remaining)}
    for j, (c, _) in enumerate(extra):      # the second start's fit where it ends lower (or the first failed)
        r0, r1 = res[main[c]], res[n_main + j]
        if not isinstance(r1, Skipped) and (isinstance(r0, Skipped) or r1[1] < r0[1]):
            ctx.log(f"  {c}: the start read from the current fits better: RSS "
                    + ("failed" if isinstance(r0, Skipped) else f"{r0[1]:.0f}") + f" -> {r1[1]:.0f}")
            res[main[c]] = r1
    screened = []
    for c, r in zip(remaining, res[1:1 + len(remaining)]):
        if isinstance(r, Skipped):
            ctx.skip(c, rnd, r)
            continue
        spec = cur.spec.with_candidate(CANDIDATES[c])
        fr = F.FitResult(spec, *r)
        screened.append((dbic(fr, ref), c, fr))
    screened.sort(key=lambda s: s[0])
    ctx.log("  screening: " + ", ".join(f"{c} dBIC {d:+.0f}" for d, c, _ in screened[:5]))
    return ref, screened


def _structural(ctx: _Ctx, ref: F.FitResult, rest: list, z_cur: float, persistent) -> list:
    """Step 1b (closed loops): the screened candidates outside the dBIC shortlist whose screening fit already
    accounts for the persistent structure ``z_cur`` of the current model (disturbance.resolved), best first,
    among those that fit at least as well as the current model (``ref``: its refit at the screening step): a
    fit that went astray is no evidence (measured: a Stribeck screening fit at dBIC +870 read z 113.8 -> 23.2 on
    its own yardstick, the structure drowned in its larger residual).

    Why: the screening's likelihood is the observer's one-step residual, which a loop keeps near the noise; an
    effect the loop compensates can leave the dBIC near zero while its fit removes most of the structure that
    made the recording significant (docs/diagnosis.md, "Closed loop: one yardstick, and screening by the
    structure accounted for (round 12)"). One observer simulation per candidate."""
    out = []
    for s in rest:
        if not s[2].rss <= ref.rss:
            continue
        z = persistent(s[2])
        if disturbance.resolved(z_cur, z):
            out.append((z, s))
    out.sort(key=lambda t: t[0])
    if out:
        ctx.log("  screened by the structure they account for: "
                + ", ".join(f"{s[1]} z {z_cur:.1f} -> {z:.1f} (dBIC {s[0]:+.0f})" for z, s in out))
    return [s for _, s in out[:TOP_K]]


def _validate(ctx: _Ctx, cur: F.FitResult, top: list, rnd: int):
    """Step 2: the current model and the ``top`` screened candidates cross-validated. Returns (the current
    model's held-out error, [(held-out gain, dBIC, id, FitResult)] of those that could be simulated), or None
    when the current model cannot be cross-validated."""
    active = tuple(c.id for c in cur.spec.candidates)
    ctx.describe(f"round {rnd + 1}: cross-validating {len(top)} + current")
    cv_tasks = [("cv", ctx.base_dict, ctx.nominal, active, cur.x, SCREEN_NFEV)]
    cv_tasks += [("cv", ctx.base_dict, ctx.nominal, active + (c,), fr.x, SCREEN_NFEV) for _, c, fr in top]
    cvs = ctx.runner.map(cv_tasks, ctx.progress)
    cv0 = cvs[0]
    if isinstance(cv0, Skipped):
        ctx.log(f"  the current model cannot be cross-validated ({cv0}): selection stops")
        return None
    gains = []
    for cv, (d, c, fr) in zip(cvs[1:], top):
        if isinstance(cv, Skipped):
            ctx.skip(c, rnd, cv)
        else:
            gains.append((1.0 - cv / cv0 if cv0 > 0 else 0.0, d, c, fr))
    ctx.log("  held-out: " + ", ".join(f"{c} {g:+.0%}" for g, _, c, _ in gains))
    return cv0, gains


def _direction(ctx: _Ctx, cur: F.FitResult, ref: F.FitResult, screened: list, gains: list, cv0: float, rnd: int):
    """Step 2a' (open loops): a torque against the motion or not? The other direction class's families that
    screened significant but not close to the leader (discriminate.direction_rivals) and the leader are fitted
    to convergence (FULL_NFEV, from their screening fits, as the accepted fit is); the one whose fit lowers the
    angle RMS most is tried first. Why: the screening's SCREEN_NFEV evaluations are about two Jacobians, enough
    for a torque linear in its parameters (airflow's polynomial) and not for a friction's stick-slip (measured:
    a rational Stribeck curve screened at dBIC -13 against airflow's -81; fitted to convergence, angle RMS x0.08
    against x0.57). Returns the evidence (None when the leader stays first) and reorders ``gains``."""
    if not open_loop(ctx.data):
        return None
    leader = gains[0][2]
    close = D.rivals(screened, ref.rss, leader)          # close ones: the tables' job (_tell_apart)
    ids = [leader] + [c for c in D.direction_rivals(screened, leader, BIC_MIN) if c not in close]
    if len(ids) < 2:
        return None
    ctx.describe(f"round {rnd + 1}: against the motion or not ({len(ids)} fits)")
    active = tuple(c.id for c in cur.spec.candidates)
    fits = {c: fr for _, c, fr in screened}
    res = ctx.runner.map([("fit", ctx.base_dict, ctx.nominal, active + (c,), fits[c].x, FULL_NFEV, len(cur.x))
                          for c in ids])
    full, ratio = {}, {}
    for c, r in zip(ids, res):
        if not isinstance(r, Skipped):
            full[c] = F.FitResult(fits[c].spec, *r)
            ratio[c] = angle_rms_ratio(full[c], cur, ctx.data)
    ctx.log("  against the motion or not: angle RMS of the converged fits "
            + ", ".join(f"{c} x{v:.2f}" for c, v in ratio.items()))
    if leader not in ratio:
        return None
    w = min(ratio, key=ratio.get)
    if w == leader:
        return None
    _winner_first(ctx, cur, ref, screened, gains, cv0, w)
    if gains[0][2] != w:                                # its cross-validation could not be simulated
        return None
    g, d, _, _ = gains[0]
    gains[0] = (g, d, w, full[w])                       # the acceptance's fit starts from the converged one
    return {"rivals": [c for c in ids if c != w], "winner": w, "rms_ratio": ratio,
            "signature": {c: D.SIGNATURE[c] for c in ids},
            "rule": "a torque against the motion or not: the families of the other direction class that screened "
                    "significant, fitted to convergence with the leader; the lowest angle RMS is tried first"}


def _tell_apart(ctx: _Ctx, cur: F.FitResult, ref: F.FitResult, screened: list, gains: list, cv_gain: dict,
                cv0: float, rnd: int):
    """Step 2b: when angle-dependent torque families are close, compare them by physics (discriminate.py);
    returns the evidence (None when no rivals are close) and reorders ``gains`` (the physics' choice first)."""
    ids = D.rivals(screened, ref.rss, gains[0][2])
    # a rival whose own formula was cross-validated and fell far behind the leader's is not close: the
    # tables only break near-ties the formulas cannot (an angle-only table can mimic a current-scaled
    # torque when the holding current follows the angle). A rival of the other direction class (a friction
    # against a torque that does not turn with the motion) stays: no table of one class makes the other's
    # torque, and a friction whose shape is not its formula's gains little by the formula (round 23:
    # angle_dependent_friction@1 random open s26, +4 % against +69 % for torque_constant_error; tables 45.5
    # against 87.8 held-out)
    lead_against = gains[0][2] in D.AGAINST_MOTION
    ids = [c for c in ids if c == gains[0][2] or cv_gain.get(c, gains[0][0]) >= RIVAL_CV_SHARE * gains[0][0]
           or (c in D.AGAINST_MOTION) != lead_against]
    if len(ids) < 2 or len({D.table_kind(c) for c in ids}) < 2:
        # airflow and spring asymmetry alone: one table, told apart by where its torque acts
        ids = D.angle_pair(screened, ref.rss, gains[0][2])
        if not ids:
            return None
    screened_ids = {c for _, c, _ in screened}
    for a, b in (D.ANGLE_ONLY, D.ANGLE_ONLY[::-1]):      # the other angle-only family shares the table: free
        if a in ids and b not in ids and b in screened_ids:
            ids = ids + [b]
    ctx.describe(f"round {rnd + 1}: telling {len(ids)} angle-dependent torques apart")
    evidence = D.discriminate(cur, ctx.data, ids, ctx.log)
    _winner_first(ctx, cur, ref, screened, gains, cv0, evidence["winner"])
    return evidence


def _region(ctx: _Ctx, cur: F.FitResult, ref: F.FitResult, screened: list, gains: list, cv0: float, rnd: int):
    """Step 2c: a near tie between a leader acting at every angle and a family with a region of action (a stop's
    contact, limp-home's free play, one side of limp-home): the local family is named when its gain lies inside
    its region and the leader explains nothing outside it that the local one does not (discriminate.region_choice).
    Returns the evidence and puts its choice first in ``gains``, or None."""
    passing = [c for g, _, c, _ in gains if g >= CV_MIN_GAIN]
    if len(passing) < 2:
        return None
    ctx.describe(f"round {rnd + 1}: where the gain lives")
    try:
        evidence = D.region_choice(ref, screened, gains[0][2], ctx.data, passing, BIC_MIN, ctx.log)
    except (ValueError, TypeError, FloatingPointError, ZeroDivisionError, OverflowError) as e:
        ctx.log(f"  where the gain lives: not compared ({e or type(e).__name__})")
        return None
    if evidence is not None:
        _winner_first(ctx, cur, ref, screened, gains, cv0, evidence["winner"])
    return evidence


def _winner_first(ctx: _Ctx, cur: F.FitResult, ref: F.FitResult, screened: list, gains: list, cv0: float, w: str):
    """The physics' choice ``w`` first in ``gains`` (cross-validated and added if it was not there)."""
    active = tuple(c.id for c in cur.spec.candidates)
    if w not in [c for _, _, c, _ in gains]:
        fr_w = next(fr for _, c, fr in screened if c == w)
        cv = ctx.runner.map([("cv", ctx.base_dict, ctx.nominal, active + (w,), fr_w.x, SCREEN_NFEV)])[0]
        if not isinstance(cv, Skipped):
            gains.append((1.0 - cv / cv0 if cv0 > 0 else 0.0, dbic(fr_w, ref), w, fr_w))
    gains.sort(key=lambda s: (s[2] != w, s[1]))              # the physics' choice first, then by dBIC


def _current_side(ctx: _Ctx, test: str, cur: F.FitResult, ref: F.FitResult, screened: list, gains: list, cv0: float,
                  rnd: int):
    """Step 2a (open loops), where the coil's current decides: ``test`` "voltage_side" (is the mismatch in the
    coil's voltage balance rather than on the plate?) or "reading_or_motion" (a reading map leads: the current
    sees the true motion, not the reading); the function of that name in discriminate. Returns the evidence and
    puts its choice first in ``gains``, or None."""
    if not open_loop(ctx.data):
        return None
    ctx.describe(f"round {rnd + 1}: " + {"voltage_side": "voltage or torque side",
                                         "reading_or_motion": "in the reading or in the motion"}[test])
    evidence = getattr(D, test)(ref, screened, gains[0][2], ctx.data, BIC_MIN, ctx.log)
    if evidence is not None:
        _winner_first(ctx, cur, ref, screened, gains, cv0, evidence["winner"])
    return evidence


def _excess_down(new: F.FitResult, old: F.FitResult, data: Data) -> bool:
    """Open loops: ``new`` takes the angle residual's excess over the noise floor down by EXCESS_MIN_GAIN,
    ms_new - 1 <= (1 - EXCESS_MIN_GAIN) (ms_old - 1), ms the mean square in noise units over all samples (1: a
    model that leaves only the noise). Why: a replay's RMS is the noise and the mismatch added in quadrature, so
    where the current model is already within 1.27x the noise (ms < 1.61) no model, not even the truth, lowers the
    RMS by RMS_MIN_GAIN (measured: an asymmetric free play, backlash@2 3B seed 6, open loop, RMS 0.0343 deg at a
    noise floor of 0.0303: the free play's fit, +26 % held-out, lowered it x0.91 and was refused at <= 0.90, its
    excess went 0.28 -> 0.06). Above 1.27x the noise the RMS_MIN_GAIN route is the looser one, so only
    recordings near the noise floor are affected. A closed loop's observer residual stays near the noise
    whatever the model (the loop corrects it), so there the RMS gain alone counts."""
    if not open_loop(data):
        return False
    a = F.evaluate(new.spec, data, new.x, with_current=False)
    b = F.evaluate(old.spec, data, old.x, with_current=False)
    ms_new, ms_old = float(a @ a) / max(a.size, 1), float(b @ b) / max(b.size, 1)
    return ms_old > 1.0 and ms_new - 1.0 <= (1.0 - EXCESS_MIN_GAIN) * (ms_old - 1.0)


def local_windows(fr: F.FitResult, data: Data) -> list | None:
    """Closed loops: per recording, the boolean mask of the samples inside the verdict's local windows
    (locate.windows: a 0.1 s moving RMS above 3x the floor) of model ``fr``'s angle residual on the recordings
    scored by the observer that hold the plate's first move from rest (:func:`first_move`); None when there are
    none (or the data hold an open loop). Windows elsewhere (a stop's contact, a sweep) are not this event: there
    the held-out and RMS gates stand (measured: end_stop_compliance@2 3B closed s45, a window away from the first
    move taken by airflow_torque's formula at dBIC -1473 against the stop's -1227 had it counted).

    Why. A closed loop's mismatch can live in one short event only: the loop's first engagement from rest,
    where the motor takes up what holds the plate (measured: backlash@2 3B closed s45 and s39, the plate still
    at rest while the current rises 0 -> 3.5 A, one window 0.17-0.26 s of a 6 s recording, 2.7-2.8x the noise
    there and 0.99-1.03x over the whole recording, the structure's z 4.1 / 6.4). Neither gate sees it: the
    whole-recording RMS cannot drop by RMS_MIN_GAIN (1.5 % of the samples: a model that leaves only the noise
    there lowers it x0.91-0.93) and the held-out gain's alternating 0.1 s blocks give the event to one fold only
    (the other fold's fit cannot see the parameter it sets: the free play +6 % held-out on s45)."""
    if open_loop(data):
        return None
    r = F.evaluate(fr.spec, data, fr.x, with_current=False)
    out, k, found = [], 0, False
    for rd in data.recs:
        rr = r[k:k + rd.rec.n]
        k += rd.rec.n
        m = np.zeros(rd.rec.n, bool)
        if rd.residual == "observer":
            t = np.asarray(rd.rec.t_s, float)
            t_move = first_move(rd)
            for a, b in L.windows(t, rr * rd.noise_deg, rd.noise_deg, rd.tol_deg):
                if t_move is not None and a <= t_move <= b:
                    m |= (t >= a) & (t <= b)
        found |= bool(m.any())
        out.append(m)
    return out if found else None


MOVE_NOISE_K = 10.0   # first_move: the plate has left its rest when the reading is this many noise floors away


def first_move(rd) -> float | None:
    """The time the plate first leaves the angle it rests at when the recording starts (the reading more than
    MOVE_NOISE_K x the noise floor from its first sample), or None when it never does."""
    y = np.asarray(rd.rec.angle_deg, float)
    k = np.flatnonzero(np.abs(y - y[0]) > MOVE_NOISE_K * rd.noise_deg)
    return float(np.asarray(rd.rec.t_s, float)[k[0]]) if k.size else None


def _window_ms(fr: F.FitResult, data: Data, masks: list) -> float:
    """The mean square of ``fr``'s angle residual (noise units) inside the windows ``masks`` (local_windows)."""
    r = F.evaluate(fr.spec, data, fr.x, with_current=False)
    m = np.concatenate(masks)
    return float(np.mean(r[m] ** 2)) if m.any() else 0.0


def _window_down(new: F.FitResult, old: F.FitResult, data: Data, masks: list) -> bool:
    """``new`` takes the excess over the noise inside the windows ``masks`` down by WINDOW_EXCESS_GAIN
    (the closed loop's counterpart of _excess_down, on the samples where the mismatch lives)."""
    ms_old, ms_new = _window_ms(old, data, masks), _window_ms(new, data, masks)
    return ms_old > 1.0 and ms_new - 1.0 <= (1.0 - WINDOW_EXCESS_GAIN) * (ms_old - 1.0)


def switched_off(spec: Spec, x, cid: str) -> tuple[Spec, np.ndarray]:
    """The model (``spec``, ``x``) with candidate ``cid``'s effect switched off and everything else kept: its
    fitted parameters moved to, and its fixed fields overridden by, the values of ``Candidate.off`` (a plant key
    there takes the plant's own value: a stop's compliance is off at the nominal stop); the other parameters,
    nominal ones included, stay at ``x``. The composition is kept (the effect's states, the segment restarts and
    the observer's structure), so what changes is the effect's own action and nothing else."""
    c = next((k for k in spec.candidates if k.id == cid), None)
    if c is None or not c.off:
        raise ValueError(f"switched_off: {cid!r} is not an active candidate that declares its 'off' values "
                         f"(active: {', '.join(k.id for k in spec.candidates) or 'none'})")
    pd = spec.base.params_dict()
    vals = {f: float(pd[v]) if isinstance(v, str) else float(v) for f, v in c.off}
    x = np.array(x, float, copy=True)
    for k, (owner, p) in enumerate(spec.params):
        if owner == cid and p.name in vals:
            x[k] = (vals[p.name] - p.init) / p.scale
    fitted = {p.name for p in c.fit}
    fixed = tuple((f, v) for f, v in vals.items() if f not in fitted)
    if fixed:
        c_off = dataclasses.replace(c, fixed=tuple(c.fixed) + fixed)
        spec = Spec(spec.base, tuple(c_off if k is c else k for k in spec.candidates), spec.nominal)
    return spec, x


def own_share(before: float, full: float, off: float) -> float:
    """The share of a gain that the effect carries itself: a statistic (lower is better) went ``before`` ->
    ``full`` when the candidate was added and refitted, and comes back to ``off`` when its effect alone is
    switched off in the full fit (:func:`switched_off`). 1: its removal gives the whole gain back (or more: the
    refitted nominal parameters lean on it); 0: the gain was the refitted nominal parameters' or the
    composition's. No gain: 0."""
    gain = before - full
    return (off - full) / gain if gain > 0.0 else 0.0


def _angle_ms(fr: F.FitResult, data: Data) -> float:
    a = F.evaluate(fr.spec, data, fr.x, with_current=False)
    return float(a @ a) / max(a.size, 1)


def _refit_without(ctx: _Ctx, cur: F.FitResult, full: F.FitResult) -> F.FitResult | None:
    """The current model (without the candidate) refitted as long as the candidate's full fit (FULL_NFEV) from
    that fit's values of its own parameters (the nominal ones and the effects already accepted); None if it
    cannot be simulated."""
    active = tuple(c.id for c in cur.spec.candidates)
    r = ctx.runner.map([("fit", ctx.base_dict, ctx.nominal, active, full.x[:len(cur.x)], FULL_NFEV)])[0]
    return None if isinstance(r, Skipped) else F.FitResult(cur.spec, *r)


def _footprint(ctx: _Ctx, c: str, cur: F.FitResult, full: F.FitResult, route: str, persistent,
               refit: F.FitResult | None, windows=None) -> float:
    """The share of the gain that accepted ``c`` (route "angle": the angle residual's mean square; "structure":
    the closed loop's persistent z) that its own effect carries (:func:`own_share`). Without the effect the
    statistic is the better of two models: the full fit with the effect switched off (:func:`switched_off`:
    the composition and the refitted nominal parameters kept) and ``refit`` (:func:`_refit_without`: the
    nominal parameters free to take back what they had leaned on the effect for)."""
    spec_off, x_off = switched_off(full.spec, full.x, c)
    models = [cur, full, F.FitResult(spec_off, x_off, full.rss, full.m, None, 0)] + ([refit] if refit else [])
    stat = (persistent if route == "structure" else (lambda fr: _window_ms(fr, ctx.data, windows))
            if route == "window" else (lambda fr: _angle_ms(fr, ctx.data)))
    v = [stat(m) for m in models]
    share = own_share(v[0], v[1], min(v[2:]))
    name = {"structure": "persistent z", "window": "mean square in the local windows (noise units)"}.get(
        route, "angle mean square (noise units)")
    ctx.log(f"  {c}: footprint: {name} {v[0]:.3f} -> {v[1]:.3f}; without its effect {v[2]:.3f} (switched off)"
            + (f", {v[3]:.3f} (the current model refitted)" if refit else "") + f": its own share {share:.0%}")
    return share


def _accept(ctx: _Ctx, cur: F.FitResult, gains: list, evidence, rnd: int, resolves=None, structure_only=(),
            persistent=None, windows=None):
    """Step 3: the best candidate whose full fit simulates and lowers the angle RMS by RMS_MIN_GAIN, or, with
    ``resolves`` (FitResult -> bool: a closed loop's persistent structure accounted for), passes ``resolves``.
    A candidate of ``structure_only`` (tried for the structure only: it did not pass the held-out gain) is
    accepted by ``resolves`` alone: the angle's RMS gain without the held-out gain is no evidence (measured: a
    sensor offset with a held-out error 19x the current model's lowered the angle's RMS by more than 10 % on a
    closed loop, docs/diagnosis-history.md round 12).
    Footprint guard: the gain that accepts a candidate must be its effect's. With the effect switched off in
    its full fit (:func:`switched_off`: the nominal parameters as refitted, the composition kept) at least
    FOOTPRINT_SHARE of the gain must come back (:func:`own_share`, on the statistic of the rule that accepted
    it); a candidate whose own removal costs nothing explained nothing (measured: a clean closed loop, 3B seed
    17, "explained" by a coil heating at its bounds, C_th 2000 J/K and R_th 0.2 K/W, a few hundredths of a
    kelvin in 6 s; docs/diagnosis-history.md round 15). Without the effect means the better of the full fit with the
    effect switched off and the current model refitted from the full fit's values (_footprint: a fit that leans
    its nominal parameters on a sensor offset gives the gain back when the offset alone is switched off, and not
    when the nominal parameters may move back). ``persistent``: the z of a model (needed with ``resolves``).
    Returns (its id, held-out gain, full fit); (None, None, the current model refitted) when a candidate was
    refused by the footprint guard and that refit fits better than the current model (the round's candidates
    were all judged against a model short of its own optimum: the selection starts the round again from the
    refit); or None."""
    active = tuple(c.id for c in cur.spec.candidates)
    for g, d, c, fr in gains:
        r = ctx.runner.map([("fit", ctx.base_dict, ctx.nominal, active + (c,), fr.x, FULL_NFEV, len(cur.x))])[0]
        if isinstance(r, Skipped):
            ctx.skip(c, rnd, r)
            continue
        full = F.FitResult(fr.spec, *r)
        ratio = angle_rms_ratio(full, cur, ctx.data)

        def routes():          # the rules that accept it, each checked when the one before did not
            if windows is not None:     # the closed loop's local windows alone (select's last try)
                if _window_down(full, cur, ctx.data, windows):
                    yield "window", (f"angle RMS x{ratio:.2f}, but it takes the excess over the noise in the "
                                     "closed loop's local windows down by half")
                return
            if c not in structure_only and ratio <= 1.0 - RMS_MIN_GAIN:
                yield "angle", f"angle RMS x{ratio:.2f}"
            elif c not in structure_only and _excess_down(full, cur, ctx.data):
                yield "angle", f"angle RMS x{ratio:.2f}, near the noise floor; its excess over the noise halved"
            if resolves is not None and resolves(full):
                yield "structure", (f"angle RMS x{ratio:.2f}, but it accounts for the persistent structure of the "
                                    "closed loop's residuals (current, steady motion)")
        refused, refit = [], None
        for route, why in routes():
            if not refused:
                refit = _refit_without(ctx, cur, full)
            if _footprint(ctx, c, cur, full, route, persistent, refit, windows) >= FOOTPRINT_SHARE:
                ctx.log(f"  {c}: {why}: accepted")
                return c, g, full
            refused.append(why)
        if refused:
            ctx.log(f"  {c}: {'; '.join(refused)}; but its own effect carries less than {FOOTPRINT_SHARE:.0%} of "
                    "that gain (the refitted nominal parameters or the composition do): not accepted")
            if refit is not None and refit.rss < cur.rss:
                return None, None, refit    # every candidate was judged against a model short of its optimum
        else:
            ctx.log(f"  {c}: angle RMS x{ratio:.2f} over the recordings (needs <= {1.0 - RMS_MIN_GAIN:.2f})"
                    + (" and the persistent structure stays" if resolves is not None else "") + ": not accepted")
        if resolves is None and windows is None and not (evidence is not None and c == evidence["winner"]):
            return None                     # (the physics' choice falling short lets the next one try)
    return None


def select(cur: F.FitResult, data: Data, runner: Runner, candidate_ids, significant, max_effects: int = 3,
           progress=None, log=print, skipped: list | None = None, persistent=None,
           refused: list | None = None) -> tuple[F.FitResult, list]:
    """Greedy forward selection of effects; returns the final fit and the accepted steps in order.
    ``persistent`` (FitResult -> float): the z of the persistent structure a model leaves in a closed loop's
    current residual (module docstring, "Closed loops"); None: the angle's held-out and RMS gains alone decide.
    A candidate whose model cannot be simulated is left out and appended to ``skipped`` as
    {"id", "round", "reason"} (the report says so). ``refused`` (a list, filled): the screening's leader of the
    round where the selection stopped because no shortlisted candidate was accepted."""
    steps = []
    skipped = [] if skipped is None else skipped
    dropped: set = set()

    def skip(c, rnd, why):
        dropped.add(c)
        skipped.append({"id": c, "round": rnd + 1, "reason": str(why)})
        log(f"  {c}: skipped ({why})")

    ctx = _Ctx(data, runner, cur.spec.base, cur.spec.base.to_dict(), cur.spec.nominal, progress, log, skip)
    for rnd in range(max_effects):
        if not significant(cur):
            break
        active = tuple(c.id for c in cur.spec.candidates)
        remaining = [c for c in candidate_ids if c not in active and c not in dropped and CANDIDATES[c].fit]
        if not remaining:
            break
        screen = _screen(ctx, cur, remaining, rnd)
        if screen is None:
            break
        ref, screened = screen
        top = [s for s in screened[:TOP_K] if s[0] < -BIC_MIN]
        z_cur = persistent(cur) if persistent is not None else 0.0
        structural = []
        if z_cur > disturbance.Z_DETECT:        # a closed loop's structure: screened by what it accounts for too
            structural = _structural(ctx, ref, [s for s in screened if s not in top], z_cur, persistent)
            top = top + structural
        if not top:
            break
        val = _validate(ctx, cur, top, rnd)
        if val is None:
            break
        cv0, gains = val
        cv_gain = {c: g for g, _, c, _ in gains}
        passing = [g for g in gains if g[0] >= CV_MIN_GAIN]
        resolves = None
        if z_cur > disturbance.Z_DETECT:        # a closed loop's current residual: its structure can decide
            def resolves(fr, z=z_cur):
                z_new = persistent(fr)
                ctx.log(f"  the closed loop's persistent structure: z {z:.1f} -> {z_new:.1f}")
                return disturbance.resolved(z, z_new)
        if passing:
            passing.sort(key=lambda s: s[1])     # the held-out gain gates, the likelihood on all data ranks
            evidence = (_current_side(ctx, "voltage_side", cur, ref, screened, passing, cv0, rnd)
                        or _current_side(ctx, "reading_or_motion", cur, ref, screened, passing, cv0, rnd)
                        or _direction(ctx, cur, ref, screened, passing, cv0, rnd)
                        or _tell_apart(ctx, cur, ref, screened, passing, cv_gain, cv0, rnd)
                        or _region(ctx, cur, ref, screened, passing, cv0, rnd))
            if resolves is not None:            # the others may still account for the structure
                passing += sorted([g for g in gains if g not in passing], key=lambda s: s[1])
        elif resolves is not None:
            passing = sorted(gains, key=lambda s: s[1])          # by dBIC: the current's fit decides
            evidence = None
        else:
            passing = []
            evidence = None
        structure_only = {c for g, _, c, _ in passing if g < CV_MIN_GAIN and not (evidence and c == evidence["winner"])}
        gains = passing
        acc = _accept(ctx, cur, gains, evidence, rnd, resolves, structure_only, persistent) if gains else None
        wins = local_windows(cur, data) if acc is None and resolves is None else None
        if wins is not None:
            # a closed loop whose mismatch lives in local windows only (local_windows: an engagement from rest
            # that neither the whole-recording RMS nor the two folds can see): the cross-validated shortlist by
            # dBIC, the windows' excess halved accepts, the footprint guard on the same statistic
            log("  the closed loop's mismatch lives in its engagement from rest only (local windows): the shortlist "
                "by dBIC, judged there")
            acc = _accept(ctx, cur, sorted(val[1], key=lambda s: s[1]), None, rnd, persistent=persistent,
                          windows=wins)
        if acc is None:
            if refused is not None and screened:
                refused.append(screened[0][1])
            break
        c, g, full = acc
        if c is None:       # the gain was the current model's own, refitted: take the refit, claim nothing
            log(f"  the current model refitted from the refused fit's values: RSS {cur.rss:.1f} -> {full.rss:.1f}; "
                "the selection goes on from it")
            cur = full
            continue
        if evidence is not None and evidence["winner"] != c:
            evidence = dict(evidence, note=f"the formula of {evidence['winner']} did not pass the fit on all the "
                                           f"data; {c} taken")
        steps.append(Step(c, full, dbic(full, cur), g, evidence))
        cur = full
    return cur, steps
