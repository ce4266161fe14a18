"""Calibration, verdict and held-out twin (issue 15): the exact model must score at the noise floor, a clean
recording from a plant file that is off must be a `match`, and a named effect's twin must predict a recording
with another excitation (closed loop) at the noise."""
import math

import numpy as np
import pytest

from etb_gym.components import effects as fx
from etb_gym.diagnose import diagnose
from etb_gym.diagnose.locate import windows
from etb_gym.diagnose.measurement import SensorModel
from etb_gym.diagnose.model import RESTART_FROM, RESTART_FULL, angle_residuals_deg, prepare, restart_weight, simulate
from etb_gym.diagnose.synthetic import make_recording, nameplate_file_plant, random_nameplate
from etb_gym.plant import make_plant


def test_restart_weight_is_continuous_and_monotone():
    g = np.linspace(0.0, 6.0, 601)
    w = np.array([restart_weight(x) for x in g])
    assert w[0] == 0.0 and restart_weight(RESTART_FROM) == 0.0 and restart_weight(RESTART_FULL) == 1.0
    assert np.all(np.diff(w) >= 0.0) and np.max(np.abs(np.diff(w))) < 0.02


def _residual(plant, rec, sensor=SensorModel()):
    data = prepare([rec], plant.supply.voltage_V)
    rd = data.recs[0]
    r = angle_residuals_deg(simulate(plant, sensor, data), data)[0]
    return math.sqrt(float(np.mean(r ** 2))) / rd.noise_deg, windows(rec.t_s, r, rd.noise_deg, None)


@pytest.mark.parametrize("closed", [False, True])
def test_the_exact_model_scores_at_the_noise_floor(closed):
    """The truth's own replay residual (its parameters, a fine step) is the noise: re-starting every segment at
    the readings (a mean of five noisy samples, a guessed speed and bristle state) put it at 1.2x the floor
    with mismatch windows in open loop and 2.5x in closed loop (the proof's clean seeds 0, 1)."""
    truth = make_plant("3B", {"friction.coulomb_Nm": 0.21, "friction.static_Nm": 0.231}, substeps=40)
    rec = make_recording(truth, np.random.default_rng(5), duration_s=6.0, closed=closed, noise_deg=0.01)
    ratio, wins = _residual(truth.replace(substeps=20), rec)
    assert ratio < 1.1 and wins == []


def test_the_exact_model_with_a_delayed_sensor_scores_at_the_noise_floor():
    """With a sensor delay the readings show the plate a few samples late: whether the model's plate agrees
    with them at a segment start is judged on the model's angle as the sensor saw it (else a plate that has
    started to move looks off, is restarted at the late reading, and leaves a window)."""
    truth = make_plant("3B", substeps=40)
    rec = make_recording(truth, np.random.default_rng(7), duration_s=6.0, noise_deg=0.01, delay_steps=4)
    ratio, wins = _residual(truth.replace(substeps=20), rec, SensorModel(delay_s=0.004))
    assert ratio < 1.1 and wins == []


def test_clean_recording_from_a_plant_file_15_percent_off_is_a_match():
    """A rig of another nameplate, described by a plant file whose friction level and spring preload and rate
    are each 15 % off: the calibration finds them, no effect is claimed and the verdict is `match`."""
    rng = np.random.default_rng(23)
    truth = random_nameplate(rng, substeps=80)
    plant_file = nameplate_file_plant(truth, rng, low=0.15, high=0.15)
    pd, pf = truth.params_dict(), plant_file.params_dict()
    assert abs(pf["spring.preload_Nm"] / pd["spring.preload_Nm"] - 1.0) == pytest.approx(0.15)
    rec = make_recording(truth, np.random.default_rng(24), duration_s=6.0, name="rig.csv")
    res = diagnose([rec], plant=plant_file, jobs=1, progress=False, verbose=False, max_effects=1)
    assert res.report["effects"] == []
    assert res.verdict == "match"
    assert res.report["rms_before_deg"] < 1.2 * res.report["noise_floor_deg"]
    cal = res.report["calibrated_parameters"]
    assert cal["spring.preload_Nm"]["value"] == pytest.approx(pd["spring.preload_Nm"], rel=0.05)


def test_twin_of_a_named_effect_predicts_a_closed_loop_recording_at_the_noise():
    """A concealed torque-constant error, diagnosed from an open-loop recording: the exported twin replayed on a
    closed-loop recording (another excitation) lands within 1.3x the noise the truth added (its physics at a
    fine step; as exported, at the diagnosis's step, as close as the truth's own physics at that step), where
    the calibrated nominal model (no effect) is far off. Before the twin was fitted on restarted segments and
    polished on the continuous replay it stopped at 7x the truth's cost and scored 9x the noise here."""
    truth = make_plant("3B", {"friction.coulomb_Nm": 0.19, "friction.static_Nm": 0.209, "spring.preload_Nm": 0.16},
                       substeps=80).replace(effects=[fx.TorqueConstantError(delta_Nm_per_A=-0.012)])
    rec = make_recording(truth, np.random.default_rng(31), duration_s=6.0, name="train.csv", noise_deg=0.01)
    held = make_recording(truth, np.random.default_rng(32), duration_s=6.0, closed=True, name="held.csv",
                          noise_deg=0.01)
    res = diagnose([rec], jobs=1, progress=False, verbose=False, max_effects=1,
                   candidates=("torque_constant_error", "shaft_flux_loss", "supply_drop", "sensor_offset_gain"))
    assert [e["id"] for e in res.report["effects"]] == ["torque_constant_error"]
    true_noise = math.sqrt(0.01 ** 2 + (90.0 / 4096) ** 2 / 12.0)
    hd = prepare([held], 12.0)
    rms = lambda plant, sensor: math.sqrt(float(np.mean(angle_residuals_deg(simulate(plant, sensor, hd), hd)[0] ** 2)))
    n = res.plant.substeps
    assert rms(res.plant.replace(substeps=80), res.sensor) < 1.3 * true_noise
    assert rms(res.plant, res.sensor) < 1.1 * rms(truth.replace(substeps=n), SensorModel())
    assert rms(*res.nominal_fit.spec.build(res.nominal_fit.x)) > 3.0 * true_noise


def _rig_and_closed_loop_recording():
    """Another nameplate (rng 5) fitted at 5 substeps on its open-loop recording: the truth, the plant file its
    diagnosis is given, a 4 s open-loop recording and a 4 s closed-loop one (the held-out)."""
    from etb_gym.diagnose.proof import _controller
    rng = np.random.default_rng(5)
    truth = random_nameplate(rng, substeps=80)
    plant_file = nameplate_file_plant(truth, rng)
    rec = make_recording(truth, np.random.default_rng(6), duration_s=4.0, name="rig.csv", noise_deg=0.01)
    held = make_recording(truth, np.random.default_rng(7), duration_s=4.0, closed=True, name="held.csv",
                          noise_deg=0.01, controller=_controller(plant_file))
    return truth, plant_file, rec, held


def test_the_exported_twin_gets_an_integrator_step_fine_enough_for_a_closed_loop():
    """The diagnosis chooses its step on the recordings it is given; a closed loop's voltage changes every sample
    and needs a finer one. On this nameplate the open-loop recording picks 5 substeps, at which even the truth
    replays a closed-loop recording at 1.6x the noise; the exported twin's step (twin_substeps: also probed on the
    plant's own closed and open loop) brings it to the noise."""
    from etb_gym.diagnose.run import choose_substeps, twin_substeps
    truth, plant_file, rec, held = _rig_and_closed_loop_recording()
    data = prepare([rec], 12.0)
    n = choose_substeps(truth, data)
    n_twin = twin_substeps(truth.replace(substeps=n), SensorModel(), data)
    assert n_twin > n
    hd = prepare([held], 12.0)
    score = lambda k: math.sqrt(float(np.mean(angle_residuals_deg(
        simulate(truth.replace(substeps=k), SensorModel(), hd), hd)[0] ** 2))) / hd.recs[0].noise_deg
    assert score(n) > 1.3
    assert score(n_twin) < 1.1


def test_the_twin_is_refitted_at_its_own_finer_step():
    """A clean rig whose open-loop recording is fitted at 5 substeps and whose twin needs 20: the levels fitted at
    the coarse step carry its integration error (here 1e-4 of their value; 0.4 % and a held-out miss of 1.70x the
    noise on the proof's clean random s14), the refit at the twin's step (run.refit_at_twin_step) takes them to
    the truth's, and the twin replays a closed-loop recording as the truth does at that step."""
    truth, plant_file, rec, held = _rig_and_closed_loop_recording()
    res = diagnose([rec], plant=plant_file, jobs=1, progress=False, verbose=False, max_effects=1)
    assert res.verdict == "match"
    note, n = res.report["twin_step_refit"], res.plant.substeps
    assert note["kept"] and note["substeps"] == n > res.final_fit.spec.base.substeps
    assert note["cost_after"] < note["cost_before"]
    pd, fitted = truth.params_dict(), res.final_fit.spec.values(res.final_fit.x)
    twin = res.plant.params_dict()
    off = lambda v: max(abs(v[p] / pd[p] - 1.0) for p in fitted)
    assert off(twin) < 0.3 * off(fitted)
    hd = prepare([held], 12.0)
    rms = lambda plant, sensor: math.sqrt(float(np.mean(angle_residuals_deg(simulate(plant, sensor, hd), hd)[0] ** 2)))
    coarse = res.final_fit.spec.build(res.final_fit.x)[0].replace(substeps=n)
    assert rms(res.plant, res.sensor) < rms(coarse, res.sensor)
    assert rms(res.plant, res.sensor) < 1.01 * rms(truth.replace(substeps=n), SensorModel())


def test_a_tables_penalty_as_residual_rows_is_the_penalty():
    """run.polish_shaped refits a model with a learned table by least squares with the table's penalty appended as
    rows (penalized.Problem.penalty_rows): |S theta - c|^2 must equal theta^T P theta - 2 pull^T theta up to one
    constant, for roughness, ridge, anchored knots, knots held at targets and a nameplate prior alike."""
    from etb_gym.diagnose.penalized import Problem
    rng = np.random.default_rng(3)
    n = 6                                             # two nominal parameters, then a 4-knot table
    D = np.zeros((2, n))
    D[0, 2:5], D[1, 3:6] = (1.0, -2.0, 1.0), (1.0, -2.0, 1.0)
    ridge = np.r_[0.0, 0.0, 1.0, 1.0, 1.0, 1.0]
    anchor = np.r_[0.0, 0.0, 1.0, 0.0, 0.0, -1.0]     # knot 0 anchored to 0, knot 3 held
    H = np.zeros((1, n))
    H[0, 5], H[0, 4] = 1.0, -1.0
    pb = Problem(None, np.zeros(n), np.arange(n), [(D, ridge, anchor, (H, np.array([0.7])))],
                 prior=np.r_[0.5, 0.5, 0.0, 0.0, 0.0, 0.0])
    assert pb.holds()
    lams = [2.5]
    S, c = pb.penalty_rows(lams)
    P, q = pb.penalty(lams), pb.pull(lams)
    thetas = rng.normal(size=(5, n)) * 3.0
    pen = np.array([float(t @ P @ t - 2.0 * q @ t) for t in thetas])
    rows = np.array([float(np.sum((S @ t - c) ** 2)) for t in thetas])
    assert np.ptp(rows - pen) < 1e-9 * np.max(np.abs(pen)), rows - pen
    assert not Problem(None, np.zeros(n), np.arange(n), [(D, ridge, anchor, (H[:0], np.zeros(0)))]).holds()


def test_a_model_with_a_table_is_polished_on_the_continuous_replay_with_its_penalty():
    """run.polish of a model whose family got a table (family_table.refine_family) on an open-loop recording: refitted on
    the continuous replay with the table's penalty (round 15), so that replay's cost falls; an angle family's
    table holds knots at targets made from its formula, so the formula's parameters stay where they were."""
    from etb_gym.diagnose import fit as F
    from etb_gym.diagnose import family_table as FT
    from etb_gym.diagnose.candidates import CANDIDATES
    from etb_gym.diagnose.model import Spec, restart_view
    from etb_gym.diagnose.refine import Outcome
    from etb_gym.diagnose.run import polish
    from etb_gym.diagnose.shapes_eval import AngleShape
    bump = AngleShape(peak_Nm=-0.06, centre_rad=math.radians(45.0), width_rad=math.radians(12.0))
    truth = make_plant("3B", substeps=40, effects=[bump])
    data = prepare([make_recording(truth, np.random.default_rng(5), duration_s=4.0, name="bump.csv")], 12.0)
    spec = Spec(make_plant("3B", substeps=20)).with_candidate(CANDIDATES["airflow_torque"])
    formula = F.fit(spec, restart_view(data), max_nfev=30)
    ref = FT.refine_family(formula, "airflow_torque", restart_view(data), log=lambda *a: None)
    assert ref.kept and ref.problem.holds()
    out = polish(ref.fit, data, Outcome(refinements=[ref]))
    assert out is not ref.fit
    cost = lambda x: float(np.sum(F.evaluate(ref.fit.spec, data, x) ** 2))   # noqa: E731
    assert cost(out.x) < cost(ref.fit.x)
    owners = [o for o, _ in ref.fit.spec.params]
    formula_idx = [k for k, o in enumerate(owners) if o == "airflow_torque"]
    assert np.array_equal(out.x[formula_idx], ref.fit.x[formula_idx])


def test_a_closed_loop_final_model_is_refitted_on_the_replay_only_where_held_out_folds_gain():
    """run.polish_replay (round 15b): on a closed-loop recording (observer residual) a final model whose torque
    constant is off is refitted on the replay of the recorded voltage, since fitted on either time fold the other
    fold's replay cost falls by more than its noise; the refit's own optimum is not refitted again (the folds
    gain nothing there), and without ``final`` (the nominal model) nothing is refitted."""
    import dataclasses

    from etb_gym.diagnose import fit as F
    from etb_gym.diagnose.candidates import CANDIDATES
    from etb_gym.diagnose.model import Spec, replay_view
    from etb_gym.diagnose.run import polish
    truth = make_plant("3B", {"friction.coulomb_Nm": 0.19, "friction.static_Nm": 0.209, "spring.preload_Nm": 0.16},
                       substeps=80).replace(effects=[fx.TorqueConstantError(delta_Nm_per_A=-0.012)])
    data = prepare([make_recording(truth, np.random.default_rng(33), duration_s=4.0, closed=True, name="c.csv",
                                   noise_deg=0.01)], 12.0, residual="auto")
    assert data.recs[0].residual == "observer"
    spec = Spec(make_plant("3B", substeps=10)).with_candidate(CANDIDATES["torque_constant_error"])
    fr = F.fit(spec, data, max_nfev=30)
    k = [o for o, _ in spec.params].index("torque_constant_error")
    x_off = fr.x.copy()
    x_off[k] = spec.x0()[k]                          # the torque constant at its nameplate value
    off = dataclasses.replace(fr, x=x_off, rss=float(np.sum(F.evaluate(spec, data, x_off) ** 2)))
    assert polish(off, data) is off
    note = {}
    out = polish(off, data, final=True, note=note)
    assert note["kept"] and out is not off
    assert all(f["held_cost_before"] - f["held_cost_after"] > f["margin"] for f in note["folds"])
    replay = lambda x: float(np.sum(F.evaluate(spec, replay_view(data), x) ** 2))   # noqa: E731
    assert replay(out.x) < replay(off.x)
    note2 = {}
    assert polish(out, data, final=True, note=note2) is out
    assert not note2["kept"]
    # the verdict's test (round 16): a refit that would leave a significant mismatch where the model left none
    note3 = {}
    assert polish(off, data, final=True, note=note3, significant=lambda f: f is not off) is off
    assert not note3["kept"] and note3["verdict_guard"].startswith("the refit would leave")


def test_the_replay_refits_observer_allowance_is_its_noise_or_the_share_the_unseen_halves_gained():
    """run.observer_allowance (round 16): a closed-loop replay refit whose unseen halves gained 98 % and 82 % may
    raise the observer cost by 82 % of it (sensor_delay@2 3B seed 13: +8.6 %, refused by the noise bound alone);
    halves that gained 0.1 % leave the noise bound sqrt(2 n)."""
    from etb_gym.diagnose.run import observer_allowance
    big = [{"held_cost_before": 422060.0, "held_cost_after": 6491.0}, {"held_cost_before": 109019.0,
                                                                        "held_cost_after": 20000.0}]
    small = [{"held_cost_before": 1000.0, "held_cost_after": 999.0}, {"held_cost_before": 1000.0,
                                                                       "held_cost_after": 990.0}]
    cost, n = 23936.0, 12000
    assert observer_allowance(big, cost, n) == pytest.approx((1.0 - 20000.0 / 109019.0) * cost)
    assert observer_allowance(big, cost, n) > 25985.0 - cost > math.sqrt(2 * n)
    assert observer_allowance(small, cost, n) == pytest.approx(math.sqrt(2 * n))


def test_a_closed_loops_learned_table_is_kept_only_where_the_replay_gains(monkeypatch):
    """closed_twin.check_tables (round 20): on closed-loop recordings a kept table (and a sensor map) is dropped,
    and the selection's formula model is the final one, when its replay cost is not lower than the formula's by
    more than sqrt(2 n) (backlash@2 random seed 15: 1.13x vs 1.07x the noise on the replay, held-out 14.1x vs
    2.5x); kept when it gains more, when the formula model would leave a significant mismatch the table model
    does not, and on open-loop recordings."""
    from types import SimpleNamespace as NS

    from etb_gym.diagnose import closed_twin as CT

    n = 5000
    cost = {"formula": 1.07 ** 2 * n, "table": 1.13 ** 2 * n}
    monkeypatch.setattr(CT, "replay_view", lambda data: data)
    monkeypatch.setattr(CT, "_replay_cost", lambda fr, rv: (cost[fr], n))

    def outcome():
        return NS(refinements=[NS(kept=True, family_id="backlash", term=NS(id="backlash_map"))],
                  sensor_maps=[NS(kept=True, family_id="backlash", kind="filter")], outside=False, dropped=())

    closed = NS(recs=[NS(residual="observer")])
    steps = [NS(id="backlash")]
    note, sh = {}, outcome()
    assert CT.check_tables("formula", "table", steps, steps, sh, closed, note=note) == "formula"
    assert note["kept"] is False and note["margin"] == pytest.approx(math.sqrt(2 * n))
    assert not sh.refinements[0].kept and not sh.sensor_maps[0].kept
    # the formula model would leave a significant mismatch where the table model leaves none: kept
    note, sh = {}, outcome()
    assert CT.check_tables("formula", "table", steps, steps, sh, closed, lambda fr: fr == "formula", note) == "table"
    assert note["kept"] and "verdict_guard" in note and sh.refinements[0].kept
    # a table that gains more than the noise on the replay: kept
    cost["table"] = cost["formula"] - 1.01 * math.sqrt(2 * n)
    note, sh = {}, outcome()
    assert CT.check_tables("formula", "table", steps, steps, sh, closed, note=note) == "table" and note["kept"]
    # an open loop, or a refine that changed the effects: untouched
    cost["table"] = 2 * cost["formula"]
    note, sh = {}, outcome()
    assert CT.check_tables("formula", "table", steps, steps, sh, NS(recs=[NS(residual="replay")]), note=note) == "table"
    assert CT.check_tables("formula", "table", steps, [NS(id="airflow_torque")], sh, closed, note=note) == "table"
    assert not note and sh.refinements[0].kept


def test_a_closed_loop_replay_refit_refused_by_the_halves_is_kept_where_both_residuals_gain():
    """run.both_gain (round 22): where a fit on half of a closed loop does not carry to the other half, the whole
    replay refit is kept only when it lowers the replay's cost and the observer residual's own cost, each by more
    than its noise (detent_torque 3B s23: replay 16635 -> 5519, observer 5595 -> 5315, noise 155: kept); a refit
    that gains on the replay alone is refused (supply_drop@1 3B s23: observer 5034 -> 5058)."""
    from etb_gym.diagnose.run import both_gain
    assert both_gain([16635.0, 5519.0, 155.0], [5595.0, 5315.0, 155.0])
    assert not both_gain([8477.0, 6374.0, 155.0], [5034.0, 5058.0, 155.0])
    assert not both_gain([8477.0, 6374.0, 155.0], [5034.0, 4900.0, 155.0])    # within the observer's noise
    assert not both_gain([8477.0, 8400.0, 155.0], [5034.0, 4000.0, 155.0])    # within the replay's noise


def test_a_closed_loop_replay_refit_whose_halves_gain_together_is_kept_within_the_observers_allowance():
    """run.folds_gain (round 24): where one half's refit gains on the other half and the other does not, the
    two halves are one two-fold check: their held-out costs summed must fall by more than the sum's noise
    (sensor_delay@2 random s27: 13763 -> 25133 and 43520 -> 6387, summed 57283 -> 31520: gains; the whole refit
    took the held-out twin 8.27x -> 1.28x); halves whose sum rises do not (backlash-like -14 % / +2 %)."""
    from etb_gym.diagnose.run import folds_gain, folds_total, observer_allowance
    m = 109.5
    split = [{"held_cost_before": 13763.0, "held_cost_after": 25133.0, "margin": m},
             {"held_cost_before": 43520.0, "held_cost_after": 6387.0, "margin": m}]
    assert folds_gain(split)
    t = folds_total(split)
    assert t["held_cost_before"] == pytest.approx(57283.0) and t["margin"] == pytest.approx(m * math.sqrt(2))
    assert observer_allowance([t], 9843.7, 12000) == pytest.approx((1 - 31520.0 / 57283.0) * 9843.7)
    worse = [{"held_cost_before": 5000.0, "held_cost_after": 5700.0, "margin": m},
             {"held_cost_before": 5000.0, "held_cost_after": 4900.0, "margin": m}]
    assert not folds_gain(worse)
    tiny = [{"held_cost_before": 5000.0, "held_cost_after": 5100.0, "margin": m},
            {"held_cost_before": 5000.0, "held_cost_after": 4780.0, "margin": m}]
    assert not folds_gain(tiny)          # 120 below the sum's noise 155
