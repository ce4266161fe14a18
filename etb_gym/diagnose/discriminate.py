"""Tell apart the effects that all act as an angle-dependent torque (docs/diagnosis.md, 3. Explain).

Four catalogue families add a torque that varies with the plate angle, and on a rig whose effect does not
follow the candidate's formula the formula that fits best may be a neighbour's:

    shaft_flux_loss           i * dk(phi)         proportional to the current (and a back-EMF term)
    angle_dependent_friction  -g(phi) sign(omega)  opposes the motion, held by the bristles at rest
    airflow_torque            a(phi)               a function of the opening alone
    spring_asymmetry          s(phi), one side     a function of the angle alone, on one side of limp-home

What separates them physically is what the torque multiplies: the current, the direction of motion, or
nothing. So the rivals are compared with their *shape left free*: each family's own regularized lookup table
in phi (``shapes.family_term``: TorqueConstantMap, AngleFrictionMap, AngleTorqueMap) is fitted on top of the
current model (calibrated nominal parameters refitted with it, roughness chosen by cross-validation) and
scored by its held-out angle error over the diagnosis's two folds (``penalized.heldout_error``). A torque
proportional to the current cannot be made by a friction table, nor an angle-only torque by a current table,
whatever shape the tables take; only the physics left in the data decides. The family whose table predicts
the held-out data best is named; airflow and spring asymmetry share one table (both are functions of the
angle alone), so between those two the formulas' order stands (the spring's support is one side of
limp-home, the airflow's the whole opening).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from . import fit as F
from . import shapes as S
from . import penalized as P
from .candidates import CANDIDATES
from .model import Data, open_loop

ANGLE_TORQUES = ("shaft_flux_loss", "angle_dependent_friction", "airflow_torque", "spring_asymmetry")
GROUP = ANGLE_TORQUES + ("torque_constant_error",)   # refined over angle, a current-proportional torque table
SIGNATURE = {"shaft_flux_loss": "proportional to the current",
             "torque_constant_error": "proportional to the current",
             "angle_dependent_friction": "opposes the motion (sign of the speed)",
             "stribeck_friction": "opposes the motion, a function of the speed",
             "airflow_torque": "a function of the opening alone",
             "spring_asymmetry": "a function of the angle alone",
             "supply_drop": "a voltage drop over the current (the current's residual, not the torque's)",
             "coil_heating": "a resistance that rises with the dissipated heat (the current's residual)",
             "inductance_saturation": "an inductance falling with the current (the current's transients)",
             "sensor_offset_gain": "a sensor map: shifts the reading at every angle"}
AGAINST_MOTION = ("angle_dependent_friction", "stribeck_friction")   # a torque whose sign follows the motion
DIRECTION_GROUP = ANGLE_TORQUES + ("stribeck_friction",)   # told apart by direction (open loops, direction_rivals)
MARGIN_SHARE = 0.5    # a rival is close when its screening RSS drop is at least this share of the leader's
TABLE_TIE = 0.02      # a closed loop's current and angle tables tie within this share of held-out (current_tie)
GN_ITER = 2           # Gauss-Newton iterations of each family's table fit
TRANSIT_KNOTS = True  # the tables' knots the plate passes through quickly stay free (table_heldout). Why: the
                      # twin's tables anchor a knot the recordings spent less than shapes.VISIT_MIN_S near to 0 (the
                      # twin falls back to the formula where the data did not go); but a torque proportional to the
                      # current is largest where the current is, in the fast passages of an open loop between the
                      # angles it dwells at, and a table held at 0 there cannot make it, so the family that acts
                      # there lost to one that mimics it where the plate dwells (shaft_flux_loss@2 3B open s46, a
                      # ramp from 29 deg, the plate dwelling below 48 deg: 17-27 samples per knot above; tables
                      # held-out 174 for the flux loss, 48.7 for airflow; left free 1.63 and 50.5)


def rivals(screened: list, ref_rss: float, leader: str) -> list[str]:
    """The group members of ``screened`` ((dbic, id, FitResult), ...) whose drop of the screening RSS below
    ``ref_rss`` is at least MARGIN_SHARE of ``leader``'s, leader first; [] when ``leader`` is not in the group
    or no second family (by table) is close."""
    if leader not in GROUP:
        return []
    rss = {c: fr.rss for _, c, fr in screened}
    if leader not in rss:
        return []
    lead_drop = ref_rss - rss[leader]
    if lead_drop <= 0:
        return []
    out = [leader] + [c for _, c, fr in screened if c in GROUP and c != leader
                      and ref_rss - fr.rss >= MARGIN_SHARE * lead_drop]
    return out if len({table_kind(c) for c in out}) >= 2 else []


def direction_rivals(screened: list, leader: str, bic_min: float) -> list[str]:
    """The DIRECTION_GROUP members of the other *direction* class than ``leader`` (a torque against the motion:
    AGAINST_MOTION, or one whose sign does not follow the motion: the rest) that screened significant
    (dBIC < -``bic_min``), best dBIC first; [] when ``leader`` is not in DIRECTION_GROUP.

    Why not only the close ones (:func:`rivals`): a family whose truth does not follow its candidate's formula
    screens by that formula's short fit, which can stop far short of a neighbour's (measured: a rational
    Stribeck curve with another level while closing screened at dBIC -13 against -81 for airflow, random
    nameplate s2; fitted to convergence, angle RMS x0.08 against x0.57). Whether the torque turns with the
    motion separates the two classes; explain._direction fits them to convergence and compares. (The family
    tables, fitted by two Gauss-Newton steps from zero, did not: a friction table's stick-slip needs a start;
    held-out 191-606 for the speed table against 60 for airflow's angle table on that recording.)"""
    if leader not in DIRECTION_GROUP:
        return []
    against = leader in AGAINST_MOTION
    return [c for d, c, _ in screened if c in DIRECTION_GROUP and (c in AGAINST_MOTION) != against and d < -bic_min]


def table_kind(cid: str) -> str:
    return {"airflow_torque": "angle", "spring_asymmetry": "angle", "torque_constant_error": "shaft_flux_loss"}.get(cid, cid)


def table_heldout(cur: F.FitResult, cid: str, data: Data, tables: dict | None = None) -> float:
    """Held-out mean square angle residual (noise units) of the current model plus ``cid``'s family table
    (shape free, roughness by cross-validation), nominal parameters refitted with it. ``tables``: the fitted
    table is stored there as ``tables[cid] = (grid, values)``."""
    term = S.family_term(cid, cur.spec.base, data)
    spec_m = cur.spec.with_candidate(term.candidate())
    # no dwell-time anchoring (Problem.make without data; TRANSIT_KNOTS): a knot the plate only passes through is
    # identified by the passage's timing, and left free there; knots the data do not see at all are still
    # anchored by their Jacobian (penalized.anchor_unidentified)
    pb = P.Problem.make(spec_m, np.concatenate([cur.x, np.zeros(term.n_coef)]), ("nominal", term.id), [term],
                        None if TRANSIT_KNOTS else data)
    pf = P.fit_penalized(pb, data, iters=GN_ITER)
    if tables is not None:
        vals = spec_m.values(pf.fit.x)
        tables[cid] = (np.asarray(term.grid), np.array([vals[f"{term.id}.c{k}"] for k in range(term.n_coef)]))
    return P.heldout_error(dataclasses.replace(pf.problem, x=pf.fit.x), data, pf.lams, pf.jac)


ANGLE_ONLY = ("airflow_torque", "spring_asymmetry")


def angle_pair(screened: list, ref_rss: float, leader: str) -> list[str]:
    """[leader, other] when ``leader`` is airflow or spring asymmetry and the other (the same angle-only table)
    is close in the screening (RSS drop at least MARGIN_SHARE of the leader's); else []."""
    if leader not in ANGLE_ONLY:
        return []
    rss = {c: fr.rss for _, c, fr in screened}
    other = ANGLE_ONLY[1 - ANGLE_ONLY.index(leader)]
    if leader not in rss or other not in rss or ref_rss - rss[leader] <= 0:
        return []
    return [leader, other] if ref_rss - rss[other] >= MARGIN_SHARE * (ref_rss - rss[leader]) else []


def discriminate(cur: F.FitResult, data: Data, ids: list[str], log=print) -> dict:
    """Compare the rival families ``ids`` (leader first) by their tables' held-out error; returns the
    evidence: {"rivals", "winner", "heldout_table" {id: error}, "rule", "signature" {id: sentence}}. A family
    whose table cannot be simulated is left out of the comparison (its reason under "failed")."""
    scores, failed = {}, {}
    done: dict = {}
    tables: dict = {}
    for c in ids:
        k = table_kind(c)
        if k in done:                       # airflow and spring share the angle table
            if done[k] is not None:
                scores[c] = done[k]
            continue
        try:
            done[k] = scores[c] = float(table_heldout(cur, c, data, tables))
        except (ValueError, TypeError, FloatingPointError, ZeroDivisionError, OverflowError,
                np.linalg.LinAlgError) as e:
            done[k] = None
            failed[c] = str(e) or type(e).__name__
    if scores:
        best = min(scores.values())
        winner = next(c for c in ids if scores.get(c) == best)   # ties (shared table): the formulas' order
    else:
        winner = ids[0]
    tie = current_tie(scores, winner, ids, open_loop(data))
    if tie is not None:
        winner = tie
    side = None
    others = [v for c, v in scores.items() if table_kind(c) != "angle"]
    if (winner in scores and table_kind(winner) == "angle" and all(c in ids for c in ANGLE_ONLY)
            and all(v > (1.0 + 1e-6) * scores[winner] for v in others)):
        # airflow or spring asymmetry (one table): where the learned angle torque acts decides
        from .unmodelled import _visited, angle_torque_family
        # (only when the angle table won outright: tables that all score the same have not moved)
        grid, tq = next(tables[c] for c in ANGLE_ONLY if c in tables)
        if np.any(np.abs(tq) > 0):
            side = winner = angle_torque_family(grid, tq, np.minimum(_visited(grid, data), 200.0),
                                                cur.spec.base.limp_home_rad)
    log("  angle-dependent torque rivals " + ", ".join(ids) + ": family tables held-out "
        + ", ".join(f"{c} {scores[c]:.3g}" if c in scores else f"{c} failed" for c in ids) + f" -> {winner}"
        + (" (a closed loop's tie: the current follows the angle torque; the angle-only torque)" if tie else ""))
    ev = {"rivals": [c for c in ids if c != winner], "winner": winner,
          "heldout_table": scores, "signature": {c: SIGNATURE[c] for c in ids},
          "rule": "each family's torque table in angle (current-proportional, opposing the motion, or angle only) "
                  "fitted with its shape free; the lowest held-out angle error names the family"}
    if side is not None:
        ev["side"] = (f"{side}: the learned angle torque acts " + ("below limp-home (the spring's closing side)"
                      if side == "spring_asymmetry" else "over the opening, not only below limp-home"))
    if tie is not None:
        ev["tie"] = (f"a closed loop's current table and angle table tie (within {TABLE_TIE:.0%}): the current "
                     "follows the angle torque there, the tables carry no evidence that the torque scales with the "
                     "current, and the angle-only torque is named")
    if failed:
        ev["failed"] = failed
    return ev


def current_tie(scores: dict, winner: str, ids: list[str], is_open: bool) -> str | None:
    """The angle-only family (first of ``ids`` with the angle table) that replaces ``winner``, a current-proportional
    family (table kind shaft_flux_loss), when the angle table's held-out error is within TABLE_TIE of the current
    table's in a closed loop (``is_open`` False); else None.

    Why. A closed loop holding its set points drives the current the plate's torques ask for: with an angle torque
    a(phi) the holding current is (spring + a(phi)) / k, a function of the angle, so a table i dk(phi) and a table
    a(phi) describe the same recording and score the same held-out (the torque-side test is degenerate). Only a
    recording where the current at one angle varies (an open loop through 0 A, an unpowered rest where a(phi) acts)
    shows the current scaling; when the tables tie the data do not show it, and the family that claims less (a
    torque of the angle alone, not one that also scales with the current) is named. An open loop is left to the
    scores (its current passes through zero: a tie there is evidence of its own). Measured: airflow_torque@1 3B
    closed s49 (a plateau of -0.0096 N m above 53 deg; the training visits it only at 1.5-5.8 A): tables held-out
    shaft_flux_loss 2.41, airflow 2.42; named shaft_flux_loss, twin 55x on the open held-out (its formula's loss
    growing as the angle squared, times the open loop's 5 A above the visited 67 deg)."""
    if is_open or winner not in scores or table_kind(winner) != "shaft_flux_loss":
        return None
    for c in ids:
        if table_kind(c) == "angle" and c in scores and scores[c] <= (1.0 + TABLE_TIE) * scores[winner]:
            return c
    return None


# ------------------------------------------------------------------------------------ voltage side or torque side
VOLTAGE_SIDE = ("supply_drop", "coil_heating", "inductance_saturation")   # act in the coil's voltage balance
CURRENT_MS_MIN = 4.0  # the current model's current residual stands above the noise (mean square in noise units:
                      # twice the noise in RMS; a clean recording leaves about 1.3)
CURRENT_SHARE = 0.25  # a voltage-side candidate accounts for at least this share of it ...
CURRENT_DOMINANCE = 2.0   # ... and for at least this many times what the leader accounts for
READING_WORSE = 0.1   # a reading map whose fit raises the current model's current residual by this share moves the
                      # motion away from what the current saw (reading_or_motion)
CURRENT_WORSE = 2.0   # a voltage-side leader whose fit leaves this many times the current model's current residual
                      # (and at least CURRENT_MS_MIN) buys the angle with the current: a torque-side rival goes first


def current_ms(fr: F.FitResult, data: Data) -> float | None:
    """Mean square of the current residual (recorded minus simulated current over the current's noise,
    ``RecData.current_sigma_A``) of fit ``fr`` over the recordings that carry a current; None when none does,
    inf when the model cannot be simulated."""
    from .model import _layout
    if data.current_weight <= 0:
        return None
    r = F.evaluate(fr.spec, data, fr.x, with_current=True)
    parts, at = [], 0
    for _, rd, _, kind in _layout(data, None, True):
        if kind == "current":
            parts.append(r[at:at + rd.rec.n])
        at += rd.rec.n
    if not parts:
        return None
    c = np.concatenate(parts)
    if np.any(np.abs(c) >= 0.5 * F.FAIL):
        return float("inf")
    c = c / data.current_weight
    return float(c @ c) / c.size


def voltage_side(ref: F.FitResult, screened: list, leader: str, data: Data, bic_min: float,
                 log=print) -> dict | None:
    """Is the mismatch on the voltage side? ``leader`` (the first candidate of the round: the best dBIC of those that pass the held-out gain) is a torque- or
    sensor-side candidate, and a voltage-side candidate (VOLTAGE_SIDE) screened significant (dBIC <
    -``bic_min``). An effect on the plate or the sensor changes the current only through the back-EMF of the
    motion it changes; an effect in the coil's voltage balance (a supply or bridge drop, a resistance, an
    inductance) changes the current itself, before the torque. So when the current model (``ref``) leaves a
    current residual above the noise (mean square >= CURRENT_MS_MIN) and a voltage-side candidate's screening
    fit accounts for at least CURRENT_SHARE of it and for CURRENT_DOMINANCE times what the leader's accounts
    for, the voltage side is where the effect acts: that candidate (best dBIC first) is named. Returns the
    evidence (as :func:`discriminate`'s, with ``current_ms`` per model) or None.

    Measured (random nameplate s0, a diode-like supply drop a asinh(i/i_0) + R_s i; open loop): a drop against
    the drive looks like a friction against the motion in an open loop that opens while it pushes, and the
    angle's held-out error had named angle-dependent friction; its fit left the current residual at 59.0 of
    59.3, the supply drop's at 28.8 (docs/diagnosis.md, "Voltage side or torque side")."""
    if leader in VOLTAGE_SIDE:
        return torque_side(ref, screened, leader, data, bic_min, log)
    volts = [c for d, c, _ in screened if c in VOLTAGE_SIDE and d < -bic_min]
    got = _current_shares(ref, screened, leader, volts, data)
    if got is None:
        return None
    ms, share = got
    ok = [c for c in volts if share(c) >= CURRENT_SHARE and share(c) >= CURRENT_DOMINANCE * max(share(leader), 0.0)]
    return _side_evidence("voltage or torque side", leader, ok, ms, "a torque on the plate or a sensor error",
                          "an effect on the plate changes the current only through the back-EMF: a voltage-side "
                          f"candidate that accounts for at least {CURRENT_SHARE:.0%} of the current model's current "
                          f"residual (above the noise) and {CURRENT_DOMINANCE:g}x what the leader accounts for is "
                          "named", log)


def _current_shares(ref: F.FitResult, screened: list, leader: str, rivals: list, data: Data):
    """(ms, share) for :func:`voltage_side` / :func:`reading_or_motion`: the current residuals (mean square, noise
    units) of the current model ``ref``, the leader's and each rival's screening fit (``screened``: (dbic, id,
    FitResult), ...), and share(c), the part of the current model's current residual that c's fit accounts for
    (-inf where c's cannot be computed); None when there is no rival, the leader was not screened, the current
    model's current residual is not above the noise (CURRENT_MS_MIN) or no recording carries a current."""
    fits = {c: fr for _, c, fr in screened}
    if leader not in fits or not rivals:
        return None
    m0 = current_ms(ref, data)
    if m0 is None or not m0 >= CURRENT_MS_MIN:
        return None
    ms = {"current model": m0, leader: current_ms(fits[leader], data)}
    for c in rivals:
        ms[c] = current_ms(fits[c], data)

    def share(c):
        return (m0 - ms[c]) / m0 if ms[c] is not None and math.isfinite(ms[c]) else -math.inf
    return ms, share


def _side_evidence(title: str, leader: str, ok: list, ms: dict, other: str, rule: str, log) -> dict | None:
    """:func:`voltage_side` / :func:`torque_side`'s log line and evidence: the current residuals ``ms``, the first
    of ``ok`` named over ``leader`` (None when ``ok`` is empty); ``other``: the signature of a family SIGNATURE
    does not describe."""
    log(f"  {title}: current residual (mean square, noise units) "
        + ", ".join(f"{c} {v:.3g}" for c, v in ms.items()) + (f" -> {ok[0]}" if ok else f" -> {leader} stands"))
    if not ok:
        return None
    return {"rivals": [leader], "winner": ok[0], "current_ms": ms,
            "signature": {c: SIGNATURE.get(c, other) for c in (leader, ok[0])}, "rule": rule}


def torque_side(ref: F.FitResult, screened: list, leader: str, data: Data, bic_min: float,
                log=print) -> dict | None:
    """The other way round: ``leader`` is a voltage-side candidate (a supply drop, a resistance, an inductance),
    and its screening fit leaves the current residual CURRENT_WORSE times the current model's (``ref``) or more,
    at least CURRENT_MS_MIN, while a torque-side candidate (a plate or drive-torque effect: neither VOLTAGE_SIDE
    nor a sensor) screened significant and does not (its current residual below the leader's / CURRENT_WORSE).
    An effect in the coil's voltage balance changes the current first, before the torque: a fit that moves the
    plate by a voltage drop the recorded current does not show (the current was within the noise with no drop)
    is a torque in disguise, and the torque-side rival, best dBIC first, is named. Returns the evidence or None.

    Measured (angle_dependent_friction@1 random s18, open loop, a Gaussian band of friction in angle; round 21):
    supply_drop led the screening (dBIC -184 against -80, held-out +51 % against +52 %) and was named; the current
    model's current residual was 2.42 (mean square, noise units; 1.28 where the plate rests), the supply drop's fit
    left 25.7 (22.6 at rest), the angle-dependent friction's 2.96."""
    fits = {c: fr for _, c, fr in screened}
    if leader not in fits:
        return None
    m0 = current_ms(ref, data)
    if m0 is None:
        return None
    ml = current_ms(fits[leader], data)
    if ml is None or not (ml >= CURRENT_MS_MIN and ml >= CURRENT_WORSE * max(m0, 1.0)):
        return None
    torques = [c for d, c, _ in screened if c not in VOLTAGE_SIDE and c in CANDIDATES and not CANDIDATES[c].sensor
               and d < -bic_min]
    ms = {"current model": m0, leader: ml}
    for c in torques:
        ms[c] = current_ms(fits[c], data)
    ok = [c for c in torques if ms[c] is not None and ms[c] * CURRENT_WORSE <= ml]
    return _side_evidence("torque or voltage side", leader, ok, ms, "a torque on the plate",
                          "an effect in the coil's voltage balance changes the current first: a voltage-side leader "
                          f"whose fit leaves {CURRENT_WORSE:g}x the current model's current residual or more (and at "
                          f"least {CURRENT_MS_MIN:g}) yields to a torque-side candidate whose fit does not", log)


def reading_or_motion(ref: F.FitResult, screened: list, leader: str, data: Data, bic_min: float,
                      log=print) -> dict | None:
    """In the reading or in the motion? ``leader`` is a sensing candidate (a reading map: CANDIDATES[...].sensor)
    and a motion-side candidate (a torque on the plate or the drive: neither a sensor nor VOLTAGE_SIDE) screened
    significant (dBIC < -``bic_min``). In an open loop the voltage is the input and the coil's current follows
    L di/dt = u - R i - k(phi) omega: the electrical equation sees the *true* motion (its back-EMF), never the
    reading. A reading map changes only what the sensor reports, so its fit moves the current only as far as it
    puts the calibrated nominal parameters back; a torque changes the motion and with it the back-EMF (a flux
    loss changes k(phi) itself). So when the current model (``ref``) leaves a current residual above the noise
    (mean square >= CURRENT_MS_MIN) and a motion-side candidate's screening fit accounts for at least
    CURRENT_SHARE of it and for CURRENT_DOMINANCE times what the reading map's accounts for, the mismatch lives
    in the motion: that candidate (best dBIC first) is named. Returns the evidence (as :func:`voltage_side`'s)
    or None.

    Measured (tests/test_diagnosis.py::test_proof_finds_two_concealed_effects_at_once, shaft flux loss + coil
    heating, open loop, with the reading map's bow): the bowed map led the screening (dBIC -57 against -52 for
    the flux loss; held-out +76 % against +91 %) and its fit left the current residual at 47.1 of the current
    model's 37.9 (docs/diagnosis-history.md, round 27 t27bow)."""
    if leader not in CANDIDATES or not CANDIDATES[leader].sensor:
        return None
    motion = [c for d, c, _ in screened if c in CANDIDATES and not CANDIDATES[c].sensor and c not in VOLTAGE_SIDE
              and d < -bic_min]
    got = _current_shares(ref, screened, leader, motion, data)
    if got is None:
        return None
    ms, share = got
    lead = share(leader)
    # the rival accounts for the current; or the map's fit takes the current away from the recording (a reading map
    # moves the current only through the nominal parameters its fit moves: right, it moves them towards the true
    # motion) while the rival's does not
    ok = [c for c in motion if (share(c) >= CURRENT_SHARE and share(c) >= CURRENT_DOMINANCE * max(lead, 0.0))
          or (lead <= -READING_WORSE and share(c) >= 0.0)]
    return _side_evidence("in the reading or in the motion", leader, ok, ms, "a torque that changes the motion",
                          "the coil's current sees the true motion (its back-EMF), not the reading: a motion-side "
                          f"candidate that accounts for at least {CURRENT_SHARE:.0%} of the current model's current "
                          f"residual (above the noise) and {CURRENT_DOMINANCE:g}x what the reading map accounts for "
                          "is named", log)


# ------------------------------------------------------------------------------------ where the gain lives
# A family with a *region of action* changes the plate's torque only at some angles (beyond what the nominal
# parameters it is fitted with can take up); a family without one (a sensor map, an airflow polynomial, a torque
# constant) acts at every angle. The regions, as functions of the effect's parameters (its Params object, the
# tied plant fields included) and the plate angle [rad]:
#   end_stop_compliance  in contact with a stop: phi beyond the nearer of the fitted and the nominal stop angle
#   spring_asymmetry     below limp-home (its kernel acts there only)
#   backlash             within the play and its contact band, -r b - eps <= phi - phi_LH <= b + eps: outside it the play
#                        acts as a lower preload (-R_F b sign d), which the calibrated preload takes up
REGION = {
    "end_stop_compliance": lambda q, phi: ((phi <= max(q.closed_rad, q.nominal_closed_rad))
                                           | (phi >= min(q.open_rad, q.nominal_open_rad))),
    "spring_asymmetry": lambda q, phi: phi < q.limp_home_rad,
    "backlash": lambda q, phi: ((phi - q.limp_home_rad <= q.play_rad + q.limp_home_compliance_rad)
                                & (q.limp_home_rad - phi <= q.closing_ratio * q.play_rad + q.limp_home_compliance_rad)),
}
REGION_SHARE = 0.5    # the local family's gain lies at least this much inside its region (it explains where it acts)
PART_GAP_RAD = math.radians(10.0)   # parts of a region: its samples' angles split where they are this far apart
PART_MIN = 30         # samples a part needs to count
SHIFT_MIN = 2.0       # a uniform shift: its mean change of the angle in each part, noise units, at least this ...
SHIFT_SPREAD = 0.25   # ... the parts' means within this share of each other, every sample's change within 2x of it


def uniform_shift(delta: np.ndarray, phi: np.ndarray, inside: np.ndarray, log=None) -> dict | None:
    """Is a local family's action in its region a uniform shift of the angle? ``delta``: its model's angle minus
    the current model's (noise units) per sample, ``phi`` the angle [rad], ``inside`` its region. The region's
    samples are split into parts where their angles lie PART_GAP_RAD apart (a stop's contact: the closed and the
    open stop). A uniform shift: at least two parts of PART_MIN samples, each part's mean change at least SHIFT_MIN
    noise units, of one sign, the means within SHIFT_SPREAD of each other and the samples' spread (std) within
    SHIFT_SPREAD of the mean too. That is what a reading offset does at every angle; a mechanical effect acting in
    physically different places (two stops are two parts) does not move them by one amount (a stop's compliance
    follows the pressing torque). Returns the parts' means and spreads, or None (``log``: told why)."""
    idx = np.flatnonzero(inside)
    if idx.size < 2 * PART_MIN:
        if log:
            log(f"  uniform shift: {idx.size} samples in the region, fewer than two parts of {PART_MIN}")
        return None
    order = idx[np.argsort(phi[idx])]
    cuts = np.flatnonzero(np.diff(phi[order]) > PART_GAP_RAD) + 1
    parts = [p for p in np.split(order, cuts) if p.size >= PART_MIN]
    if len(parts) < 2:
        if log:
            log(f"  uniform shift: {len(parts)} part(s) of at least {PART_MIN} samples in the region: no evidence")
        return None
    means = np.array([float(delta[p].mean()) for p in parts])
    spreads = np.array([float(delta[p].std()) for p in parts])
    ref = float(np.min(np.abs(means)))
    ok = (ref >= SHIFT_MIN and (np.all(means > 0) or np.all(means < 0))
          and float(means.max() - means.min()) <= SHIFT_SPREAD * ref and float(spreads.max()) <= SHIFT_SPREAD * ref)
    if log and not ok:
        log("  uniform shift: not one amount in every part: "
            + ", ".join(f"{m:+.1f} (sd {sd:.1f}, {p.size} samples)" for m, sd, p in zip(means, spreads, parts)))
    return {"means": means.tolist(), "spreads": spreads.tolist(), "samples": [int(p.size) for p in parts]} if ok else None


def effect_params(fr: F.FitResult, cid: str):
    """The Params of effect ``cid`` in ``fr``'s model (tied plant fields filled in), or None."""
    plant, _ = fr.spec.build(fr.x)
    return next((e.params for e in plant.effects if getattr(e, "effect_id", None) == cid), None)


def angle_parts(fr: F.FitResult, data: Data) -> tuple[np.ndarray, np.ndarray]:
    """(normalized angle residual, the model's angle [rad]: the recorded angle plus its residual) of ``fr`` over
    all recordings, stacked."""
    r = F.evaluate(fr.spec, data, fr.x, with_current=False)
    rec = np.concatenate([rd.rec.angle_deg for rd in data.recs])
    noise = np.concatenate([np.full(rd.rec.n, rd.noise_deg) for rd in data.recs])
    return r, np.radians(rec + r * noise)


def _failed(r: np.ndarray) -> bool:
    """A residual of a model that could not be simulated (fit.make_fun's FAIL)."""
    return bool(np.any(np.abs(r) >= 0.5 * F.FAIL))


def region_choice(ref: F.FitResult, screened: list, leader: str, data: Data, passing: list[str], bic_min: float,
                  log=print) -> dict | None:
    """A near tie between a family that acts at every angle (G) and a family with a region of action (L, REGION):
    where does the gain live? Either may lead. ``passing``: the candidates that passed the held-out gain; a rival
    is close when it passes too and its screening RSS drop is at least MARGIN_SHARE of the leader's.

    For L (its region M, on its own fitted model's angle) and G, both screening fits against the current model's
    refit ``ref`` (angle residuals only), with z = m_out / tau ln(RSS_out(L) / RSS_out(G)) outside M (tau: G's
    residual's integrated time):
      - G leads: L is named when it explains where it acts (at least REGION_SHARE of L's RSS drop lies inside
        M) and G explains nothing outside M that L does not (z < ``bic_min``): the physics that acts only there
        accounts for all the data say, and G's claim about the other angles is not supported;
      - L leads: G is named when it explains significantly more outside M than L does (z >= ``bic_min``): what
        the data say away from L's region (a sensor map shifts the reading at rest at limp-home and in free
        motion, where a stop's compliance acts on nothing) L cannot account for.
    Otherwise the leader stands. (Outside M, L still gains through what its torque did to the motion that
    follows: a replay carries a contact's timing on; both fits carry that alike, which is why the comparison is
    L against G outside M and not G's outside gain against zero.)
    Measured: end_stop_compliance@2, random nameplate, open loop, seed 2 (a soft exponential bumper before the
    open stop): sensor map dBIC -182, stop compliance -160, both +85 % held-out; 76 % of the stop's drop inside
    its contact region, outside it RSS 7501 (sensor map) against 7551 (stop) over 5668 samples."""
    rss = {c: fr.rss for _, c, fr in screened}
    fits = {c: fr for _, c, fr in screened}
    if leader not in rss or ref.rss - rss[leader] <= 0:
        return None
    local_leads = leader in REGION
    close = [c for c in passing if c != leader and c in rss and (c in REGION) != local_leads
             and ref.rss - rss[c] >= MARGIN_SHARE * (ref.rss - rss[leader])]
    if not close:
        return None
    r0, _ = angle_parts(ref, data)
    rl_cache: dict = {}
    if _failed(r0):
        return None
    for c in close:
        loc, glob = (leader, c) if local_leads else (c, leader)
        q = effect_params(fits[loc], loc)
        if q is None:
            continue
        rl, phi = angle_parts(fits[loc], data)
        if glob not in rl_cache:
            rl_cache[glob] = angle_parts(fits[glob], data)
        rg, _ = rl_cache[glob]
        if _failed(rl) or _failed(rg):
            continue
        inside = np.asarray(REGION[loc](q, phi), bool)
        drop = r0 ** 2 - rl ** 2
        total = float(drop.sum())
        share = float(drop[inside].sum()) / total if total > 0 else 0.0
        out_l, out_g = float(rl[~inside] @ rl[~inside]), float(rg[~inside] @ rg[~inside])
        tau = max(fits[glob].tau_int, 1.0)
        m_out = int(np.count_nonzero(~inside)) / tau
        z = m_out * math.log(max(out_l, 1e-300) / max(out_g, 1e-300)) if m_out > 0 else 0.0
        shift = None
        if z < bic_min and CANDIDATES[glob].component is None and (local_leads or share >= REGION_SHARE):
            shift = uniform_shift(rl - r0, phi, inside, log)            # a reading map: does L only shift it?
            if shift is not None and uniform_shift(rg - r0, phi, inside) is None:
                shift = None                                             # the map does not do the same there
        if local_leads:
            ok, winner, loser = z >= bic_min or shift is not None, glob, loc
        else:                   # the map leads: the local family is not named for a shift the map makes too
            ok, winner, loser = share >= REGION_SHARE and z < bic_min and shift is None, loc, glob
        log(f"  where the gain lives: {loc} {share:.0%} of its drop inside its region ({int(inside.sum())} samples); "
            f"outside, RSS {glob} {out_g:.0f} against {loc} {out_l:.0f} (dBIC-like {z:+.1f}) -> "
            + (f"{loc} moves the angle by one amount in each part of its region "
               + ", ".join(f"{m:+.1f} (sd {sd:.1f}, {k} samples)" for m, sd, k in
                           zip(shift["means"], shift["spreads"], shift["samples"])) + ": a shift of the reading; "
               if shift else "")
            + (winner if ok else f"{leader} stands"))
        if ok:
            rule = (f"a near tie between a family acting at every angle and one with a region of action: when at "
                    f"least {REGION_SHARE:.0%} of the local family's gain lies inside its region and the other "
                    "explains nothing outside it that the local one does not, the local one is named; when the "
                    "other explains significantly more outside that region, it is; a reading map is named too when "
                    "the local family's fit only shifts the angle by one amount in every part of its region (both "
                    "stops), as the map does")
            return {"rivals": [loser], "winner": winner,
                    "region": {"share_inside": share, "samples_inside": int(inside.sum()),
                               "rss_outside": {glob: out_g, loc: out_l}, "outside_dbic": z,
                               **({"uniform_shift": shift} if shift else {})},
                    "signature": {glob: SIGNATURE.get(glob, "acts at every angle"), loc: REGION_SIGNATURE[loc]},
                    "rule": rule}
    return None


REGION_SIGNATURE = {"end_stop_compliance": "acts only in contact with a stop",
                    "spring_asymmetry": "acts only below limp-home",
                    "backlash": "acts only within the free play around limp-home"}


# ------------------------------------------------------------------------------------ a drop read from the current
CURRENT_PINNED = ("supply_drop",)   # voltage-side families whose levels (CANDIDATES[c].off) enter the coil's voltage
                                     # balance linearly: one Gauss-Newton step on the current residual pins them
KNEE_FACTORS = (3.0, 10.0)          # open loops: the drop's knee (its ``ref="current_A"`` parameter) read at its start
                                     # and at these multiples of it (3B: 0.05, 0.15, 0.5 A; its range 0.005-1 A)


def observer_view(data: Data) -> Data:
    """``data`` with every recording scored by the observer (model.simulate: the one-step prediction along the
    recorded angle); ``data`` itself where all already are."""
    if all(rd.residual == "observer" for rd in data.recs):
        return data
    return dataclasses.replace(data, recs=[dataclasses.replace(rd, residual="observer") for rd in data.recs])


def current_start(spec, data: Data, x0: np.ndarray, n_old: int, diff_step: float = 0.03, log=None) -> np.ndarray:
    """A screening start for a CURRENT_PINNED candidate (the last of ``spec``, its parameters from index ``n_old`` of
    ``x0``): its levels read from the current, the calibration's parameters re-balanced to them.

    Why. A loop hides a supply drop in the angle, not in the current: the drive's voltage balance
    u = R i + L di/dt + k omega + drop(i) is the same whatever the controller does, and the observer's current
    (driven by the recorded voltage) shows the drop as a current it did not have to apply. The calibration of
    the nominal model took up the extra torque of that current in the spring's preload and rate, so at the
    candidate's start (its nameplate levels) the model's current is right but the plate's torques are not, and
    a screening fit of a few evaluations stays there (measured: supply_drop@1 3B closed s41, RSS 12342 for the
    nominal model, 251689 at the start, 15421 after the screening's 12 evaluations: dBIC +21, not screened,
    while the current model's current residual stood at 12 noise units squared with a persistent z 3167).
    So: (1) one Gauss-Newton step of the levels (the ``off`` parameters: the drop switched off at zero) on the
    current residual alone (the voltage balance: a direct reading of the missing voltage); (2) one of the
    calibration's parameters (the first ``n_old`` - ``len(spec.nominal)`` are the nominal ones) on all of it, the
    torques re-balanced to the current the drop leaves. Returned only where its cost is below ``x0``'s (else
    ``x0`` itself); the screening (explain._screen) fits from both starts and keeps the fit that ends lower, so
    the likelihood decides as before (s41: 34379 at this start, 6346 after 12 evaluations).

    Open loops (round 32). The same balance, read along the recorded motion: step (1) scores the current by the
    observer (:func:`observer_view`) on every recording, because the replay's current carries the back-EMF of the
    model's own plate, and where the calibration has moved that plate (the drop's torque taken up in the spring)
    the replayed current misreads the drop (supply_drop@1 random open s42: the replay read 0.12 ohm and -0.03 V,
    0.09 V at 1 A against the truth's 0.16 V; the observer read 0.079 ohm and 0.061 V, 0.14 V). And the knee (the
    current over which the forward drop builds up) is read too: an open loop's excitation passes through 0 A, so
    the current below and above the knee is recorded (a closed loop holding 2-6 A does not see it: there the
    nameplate's knee stays); the levels are read at the knee's start and at KNEE_FACTORS times it, and the start
    that costs least after the re-balance is kept (s42, knees 0.05 / 0.15 / 0.5 A: 69957 / 63107 / 29113; after the
    screening's 12 evaluations 30683 / 31277 / 12965; the nominal model 162993)."""
    from .model import _layout
    cand = spec.candidates[-1]
    if cand.id not in CURRENT_PINNED or data.current_weight <= 0 or not any(
            rd.rec.current_A is not None for rd in data.recs):
        return x0
    levels = [n_old + k for k, p in enumerate(cand.fit) if p.name in dict(cand.off)]
    if not levels:
        return x0
    nom = list(range(len(spec.nominal)))
    read = observer_view(data)             # the voltage balance read along the recorded motion (docstring)
    cur = np.concatenate([np.full(rd.rec.n, kind == "current") for _, rd, _, kind in _layout(read, None, True)])
    fun, fun_read = F.make_fun(spec, data), F.make_fun(spec, read)
    lo, hi = spec.bounds()

    def run(f, x):
        r = f(x)
        ok = f.failure is None and np.all(np.isfinite(r))
        f.failure = None
        return r if ok else None

    def step(f, x, r, idx, rows):          # one Gauss-Newton step of ``idx`` on the residual's ``rows``
        J = F.profile_jacobian(f, x, r, idx, lo, hi, diff_step)
        f.failure = None
        return None if J is None else F.profile_step(J[rows], r[rows], x, idx, lo, hi)

    def read_at(xs):                       # (1) the levels on the current, (2) the calibration on everything
        q0 = run(fun_read, xs)
        x1 = None if q0 is None else step(fun_read, xs, q0, levels, cur)
        r1 = None if x1 is None else run(fun, x1)
        x2 = None if r1 is None else step(fun, x1, r1, nom, np.ones(r1.size, bool))
        r2 = None if x2 is None else run(fun, x2)
        return None if r2 is None else (float(r2 @ r2), x2)

    r0 = run(fun, x0)
    if r0 is None:
        return x0
    starts = [x0]
    knee = [n_old + k for k, p in enumerate(cand.fit) if p.ref == "current_A"]
    if knee and read is not data:          # open loops: the knee read too (docstring)
        p = spec.params[knee[0]][1]
        v0 = spec.values(x0)[spec.names[knee[0]]]
        for f in KNEE_FACTORS:
            xs = x0.copy()
            xs[knee[0]] = min(max((f * v0 - p.init) / p.scale, lo[knee[0]] + 1e-9), hi[knee[0]] - 1e-9)
            if not np.allclose(xs, x0):
                starts.append(xs)
    got = [g for g in (read_at(xs) for xs in starts) if g is not None]
    if not got or not min(got, key=lambda g: g[0])[0] < float(r0 @ r0):
        return x0
    c2, x2 = min(got, key=lambda g: g[0])
    if log is not None:
        log(f"  {cand.id}: starts from its levels read from the current (the voltage balance), the calibration "
            f"re-balanced: cost {float(r0 @ r0):.0f} -> {c2:.0f}"
            + (f" (knee {spec.values(x2)[spec.names[knee[0]]]:.3g} A)" if len(starts) > 1 else ""))
    return x2
