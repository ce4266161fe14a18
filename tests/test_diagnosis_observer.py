"""The observer residual on closed-loop recordings (etb_gym/diagnose/observer.py): a clean recording under a
stiff PID is a `match`, a concealed effect is still named, and the observer itself behaves as documented."""
import math
import warnings

import numpy as np
import pytest

from etb_gym.diagnose import observer as O
from etb_gym.diagnose.measurement import SensorModel
from etb_gym.diagnose.model import prepare, simulate
from etb_gym.diagnose.run import Options, diagnose
from etb_gym.diagnose.synthetic import make_recording
from etb_gym.plant import make_plant


def stiff_pid():
    from etb_gym.controllers.pid import PIDController
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return PIDController(crossover_rad_s=80.0, phase_margin_deg=35.0, friction_compensation=False)


def truth_3b(seed, effects=()):
    """3B with its friction and spring a little off the tool's nominal values (as the proof's truths)."""
    rng = np.random.default_rng(seed)
    c = 0.2 * rng.uniform(0.85, 1.15)
    p = make_plant("3B", {"friction.coulomb_Nm": c, "friction.static_Nm": 1.1 * c,
                          "spring.preload_Nm": 0.15 * rng.uniform(0.9, 1.1),
                          "spring.rate_Nm_per_rad": 0.36 * rng.uniform(0.9, 1.1)}, substeps=40)
    return p.replace(effects=tuple(effects)) if effects else p


def test_gain_corrects_the_angle_only_at_the_documented_rate():
    for dt in (5e-4, 1e-3, 2e-3):
        L = O.gains(dt, 5, 140.0)
        assert L.shape == (5,) and np.all(L[1:] == 0.0)
        assert L[0] == pytest.approx(1.0 - math.exp(-140.0 * dt), rel=1e-12)   # error x exp(-omega_o dt) per sample
    with pytest.raises(ValueError, match="bandwidth"):
        O.gains(1e-3, 5, -1.0)


def test_observer_without_gain_is_the_plain_simulation_and_its_correction_pulls_to_the_reading():
    plant = make_plant("3B", substeps=10)
    rec = make_recording(plant, np.random.default_rng(0), duration_s=1.0, closed=False, noise_deg=0.01)
    data = prepare([rec], 12.0, residual="observer")
    rd = data.recs[0]
    n = rec.n
    y = np.radians(rec.angle_deg)
    x0 = plant.initial_state(float(np.mean(y[:3])), current_A=float(np.mean(rec.current_A[:3])))
    fns = plant.engine.fns
    args = (rd.duty[:n - 1], rd.supply_V[:n - 1], plant.P, 0.0, plant.control_period_s, plant.substeps,
            plant.supply.switching, plant.supply.pwm_frequency_hz)
    X0, A0 = np.empty((n, plant.n_states)), np.empty((n, len(plant.components)))
    X1, A1 = np.empty_like(X0), np.empty_like(A0)
    assert fns.simulate(x0, *args, X0, A0) == n - 1
    assert fns.observe(x0, *args, y, np.zeros(plant.n_states), 0.0, X1, A1) == n - 1
    assert np.array_equal(X0, X1)
    # a model whose spring is 30 % off drifts in replay; with the observer its one-step error stays near the noise
    wrong = plant.with_params({"spring.preload_Nm": 0.7 * plant.params_dict()["spring.preload_Nm"]})
    rep = simulate(wrong, SensorModel(), prepare([rec], 12.0))[0][0] - rec.angle_deg
    obs = simulate(wrong, SensorModel(), data)[0][0] - rec.angle_deg
    assert np.sqrt(np.mean(obs ** 2)) < 0.2 * np.sqrt(np.mean(rep ** 2))


def test_clean_recording_under_a_stiff_pid_is_a_match_with_the_observer_residual():
    truth = truth_3b(2)
    rec = make_recording(truth, np.random.default_rng(102), duration_s=4.0, closed=True, noise_deg=0.01,
                         controller=stiff_pid(), name="stiff.csv")
    # this PID (roll-off, no friction compensation) filters the reading's noise; the earlier loop statistic
    # missed it, the Granger-type test (loop.py) detects it, so the default residual choice takes the observer
    res = diagnose([rec], options=Options(jobs=1, progress=False, verbose=False))
    rep = res.report
    assert rep["loop"]["stiff.csv"] == "closed" and rep["residual"]["stiff.csv"] == "observer"
    assert rep["observer"]["bandwidth_rad_s"] == O.OMEGA_O
    assert rep["effects"] == [] and rep["verdict"] == "match", (rep["verdict"], rep["rms_before_deg"],
                                                                 rep["noise_floor_deg"])


def test_concealed_effect_in_closed_loop_is_still_named_with_the_observer_residual():
    """A torque constant 10 mN m/A high (about 7 %) under the default PID: the observer leaves it visible,
    it is named first and the final model accounts for it down to the noise."""
    from etb_gym.components import effects as fx
    truth = truth_3b(5, [fx.TorqueConstantError(delta_Nm_per_A=0.01)])
    rec = make_recording(truth, np.random.default_rng(105), duration_s=4.0, closed=True, noise_deg=0.01,
                         name="kc.csv")
    res = diagnose([rec], options=Options(jobs=1, progress=False, verbose=False, max_effects=1,
                                          candidates=("torque_constant_error", "shaft_flux_loss", "airflow_torque",
                                                      "supply_drop", "spring_asymmetry")))
    rep = res.report
    assert rep["loop"]["kc.csv"] == "closed" and rep["residual"]["kc.csv"] == "observer"   # the default PID
    assert [e["id"] for e in rep["effects"]][:1] == ["torque_constant_error"], rep["effects"]
    assert rep["verdict"] == "explained", (rep["verdict"], rep["rms_after_deg"], rep["noise_floor_deg"])
    # the twin of an explained closed loop replays its own recording open loop near the noise (run.twin_replay)
    assert rep["twin_replay"]["kc.csv"]["over_noise"] < 2.0, rep["twin_replay"]
    # ... better than the calibrated nominal model does (else report.md would say so)
    tr = rep["twin_replay"]["kc.csv"]
    assert tr["nominal_over_noise"] > tr["over_noise"] and not tr["worse_than_nominal"], tr


def test_proof_footprint_of_a_closed_loop_effect_as_the_observer_sees_it():
    """proof_truth.effect_footprint(residual="observer"): what the closed-loop residual can see of a concealed
    effect (the proof's effect_size_observer). The replay of a closed loop's voltage overstates it (the replayed
    plate leaves the path the controller held it on), so the observer's footprint is the smaller one; a
    sensor effect (no plate effect to take out) has none."""
    from etb_gym.components import effects as fx
    from etb_gym.diagnose.locate import moving_rms
    from etb_gym.diagnose.proof_truth import effect_footprint
    effects = [fx.TorqueConstantError(delta_Nm_per_A=0.01)]
    truth = truth_3b(5, effects)
    rec = make_recording(truth, np.random.default_rng(105), duration_s=2.0, closed=True, noise_deg=0.01,
                         name="kc.csv")
    size = {}
    for residual in ("replay", "observer"):
        a, b = effect_footprint(truth, rec, effects, {}, residual=residual)
        assert a.shape == b.shape == rec.angle_deg.shape and np.all(np.isfinite(a)) and np.all(np.isfinite(b))
        size[residual] = float(np.max(moving_rms(a - b, 100)))
    assert 0.0 < size["observer"] < size["replay"], size
    assert effect_footprint(truth, rec, [], {}, residual="observer") is None


def test_persistent_structure_statistic_is_null_on_noise_and_large_on_a_feature_shaped_bias():
    """disturbance.structure: z about 0 on white noise, large on a small bias shaped like one feature group
    (0.3 of the noise, which no moving-RMS window shows); the group carrying it is the hint."""
    from etb_gym.diagnose import disturbance as D
    rng = np.random.default_rng(0)
    n = 4000
    t = np.arange(n) * 1e-3
    groups = {"offset": np.ones((n, 1)), "drift": ((t - t.mean()) / t.std())[:, None],
              "angle": D._hats(30.0 + 20.0 * np.sin(2 * np.pi * 0.7 * t), 8)}
    noise = rng.standard_normal(n)
    null = D.structure(noise, groups, "current")
    assert abs(null.z) < 4.0 and not null.significant
    biased = D.structure(noise + 0.3 * groups["drift"][:, 0], groups, "current")
    assert biased.z > 3 * D.Z_DETECT and biased.significant and biased.hint == "drift"
    assert not D.structure(noise + 0.3 * groups["drift"][:, 0], groups, "angle").significant   # a hint only
    # accounted for: nothing significant left, or at most RESOLVE_SHARE of the structure the model extends
    assert D.resolved(178.0, 74.0) and D.resolved(14.4, 5.0) and D.resolved(9.0, D.Z_DETECT)
    assert not D.resolved(178.0, 100.0) and not D.resolved(20.0, 20.0)
    assert D.structure(noise[:100], {k: g[:100] for k, g in groups.items()}, "current") is None   # too short
    with pytest.raises(ValueError, match="samples"):
        D.structure(noise[:100], groups, "current")


def test_a_structure_is_measured_on_the_reference_yardstick_so_a_noisier_fit_cannot_drown_it():
    """disturbance.structure(yardstick=(s^2, tau)): the explained sum of squares scaled by a reference model's
    left variance and correlation time. The same bias under four times the noise reads a small z on its own
    yardstick (drowned) and the same large z on the reference's; half the bias on the reference's yardstick
    reads about a quarter of its z above the null (the energy of what is left)."""
    from etb_gym.diagnose import disturbance as D
    rng = np.random.default_rng(1)
    n = 4000
    t = np.arange(n) * 1e-3
    groups = {"offset": np.ones((n, 1)), "drift": ((t - t.mean()) / t.std())[:, None]}
    noise = rng.standard_normal(n)
    bias = 0.3 * groups["drift"][:, 0]
    ref = D.structure(noise + bias, groups, "current")
    assert ref.significant and len(ref.yardstick) == 2
    assert D.structure(noise + bias, groups, "current", ref.yardstick).z == pytest.approx(ref.z)
    drowned = D.structure(4.0 * noise + bias, groups, "current")
    kept = D.structure(4.0 * noise + bias, groups, "current", ref.yardstick)
    assert drowned.z < ref.z / 4 and kept.z > 0.8 * ref.z
    half = D.structure(noise + 0.5 * bias, groups, "current", ref.yardstick)
    assert 0.15 * ref.z < half.z < 0.35 * ref.z and D.resolved(ref.z, half.z)


def test_closed_loop_current_residual_structure_tells_a_wrong_resistance_from_the_exact_model():
    """disturbance.persistent_mismatch on a closed loop (default PID): a model whose resistance is 5 % off
    leaves a persistent structure in its current residual, one whose spring preload is 8 % off in the angle
    innovation over steady motion (not in the current), the truth's own model none; a replayed (open-loop)
    recording is left to the replay's tests."""
    from etb_gym.diagnose import disturbance as D
    truth = truth_3b(5)
    rec = make_recording(truth, np.random.default_rng(109), duration_s=2.0, closed=True, noise_deg=0.01,
                         name="c.csv")
    data = prepare([rec], 12.0, residual="observer")
    own = D.persistent_mismatch(data, truth, SensorModel())
    # (on this recording the whole angle innovation of the truth's own model reads z 21: a stick-slip transient;
    # over steady motion it is within the null)
    assert [s.kind for s in own] == ["angle", "motion", "current"] and not D.detected(own), [s.as_dict() for s in own]
    R = truth.params_dict()["drive.resistance_ohm"]
    off = {s.kind: s for s in D.persistent_mismatch(data, truth.with_params({"drive.resistance_ohm": 1.05 * R}),
                                                    SensorModel())}
    assert off["current"].significant and off["current"].z > D.Z_DETECT, {k: s.as_dict() for k, s in off.items()}
    assert D.deciding_z(off.values()) == max(off["current"].z, off["motion"].z)
    # on the yardstick of the exact model's residuals (run.diagnose: the nominal's): still significant, and
    # the exact model measured on its own yardstick reads what it read
    on_own = {s.kind: s for s in D.persistent_mismatch(data, truth.with_params({"drive.resistance_ohm": 1.05 * R}),
                                                       SensorModel(), ref=own)}
    assert on_own["current"].significant
    assert [s.z for s in D.persistent_mismatch(data, truth, SensorModel(), ref=own)] == pytest.approx([s.z for s in own])
    # a torque the current does not see (the spring's preload 8 % off): the loop holds the plate, the current
    # residual stays within its null, the angle innovation over steady motion carries it
    P = truth.params_dict()["spring.preload_Nm"]
    spring = {s.kind: s for s in D.persistent_mismatch(data, truth.with_params({"spring.preload_Nm": 1.08 * P}),
                                                       SensorModel())}
    assert spring["motion"].significant and not spring["current"].significant, \
        {k: s.as_dict() for k, s in spring.items()}
    assert D.persistent_mismatch(prepare([rec], 12.0, residual="replay"), truth, SensorModel()) == []


def test_steady_motion_drops_slow_samples_and_those_near_a_reversal():
    """disturbance.steady_motion: a sample counts when the speed stayed above w_min (the friction's transition
    speed x MOTION_STRIBECK, or the speed estimate's noise x MOTION_NOISE) from MOTION_SETTLE_S before it to
    MOTION_AFTER_S after it."""
    from types import SimpleNamespace

    from etb_gym.diagnose import disturbance as D
    dt = 1e-3
    t = np.arange(3000) * dt
    y = 40.0 + 30.0 * np.sin(2 * np.pi * 0.5 * t)                  # reversals at t = 0.5, 1.5, 2.5 s
    rec = SimpleNamespace(angle_deg=y, t_s=t, dt_s=dt)
    m = D.steady_motion(rec, 0.01, 0.05)
    w_min = D.MOTION_STRIBECK * math.degrees(0.05)
    speed = np.abs(30.0 * 2 * np.pi * 0.5 * np.cos(2 * np.pi * 0.5 * t))
    inner = slice(100, -100)
    assert np.all(speed[inner][m[inner]] > w_min)
    settle = int(D.MOTION_SETTLE_S / dt)
    k_leave = np.flatnonzero((speed[:-1] > w_min) & (speed[1:] <= w_min))[0]      # slowing towards t = 0.5 s
    k_back = np.flatnonzero((speed[:-1] <= w_min) & (speed[1:] > w_min))[0] + 1    # moving again
    assert not m[k_back: k_back + settle - 2].any() and m[k_back + settle + 2]
    assert not m[k_leave - int(D.MOTION_AFTER_S / dt) + 2] and m[k_leave - int(D.MOTION_AFTER_S / dt) - 2]
    # a noisier reading raises w_min: 5 x noise / (15 dt)
    noisy = D.steady_motion(rec, 1.0, 0.0)
    assert noisy.sum() < m.sum() and np.all(speed[inner][noisy[inner]] > D.MOTION_NOISE * 1.0 / (D.SPEED_SMOOTH * dt))


def test_generic_tables_are_kept_on_a_closed_loop_structure_only_when_they_account_for_it():
    """refine._accounts: the generic tables replace the catalogue model on a closed loop when the catalogue
    model leaves a significant persistent structure and the tables leave at most disturbance.resolved's share."""
    from etb_gym.diagnose import disturbance as D
    from etb_gym.diagnose.refine import _accounts
    z = {"catalogue": 20.0, "tables": 9.0}
    log = []
    assert _accounts(z.get, "catalogue", "tables", log.append) and "accounted for" in log[-1]
    z["tables"] = 15.0                                      # most of it left
    assert not _accounts(z.get, "catalogue", "tables", log.append)
    z["catalogue"], z["tables"] = D.Z_DETECT - 0.5, 0.0    # nothing significant to account for
    assert not _accounts(z.get, "catalogue", "tables", log.append)
    assert not _accounts(None, "catalogue", "tables", log.append)


def test_structures_are_measured_without_the_models_own_integration_error():
    """disturbance.predict: the observer's predictions at n and 2n substeps, Richardson-extrapolated. The
    statistic averages over thousands of samples, so at a coarse step the exact model's own integration error
    of the current reads as a structure (proof clean s23, random nameplate: z 9.5 at 10 substeps, 1.8 at 40);
    measured on the extrapolation it reads what the model at a fine step reads."""
    from etb_gym.diagnose import disturbance as D
    from etb_gym.diagnose.proof import _controller
    from etb_gym.diagnose.synthetic import random_nameplate
    truth = random_nameplate(np.random.default_rng(3), substeps=40)
    rec = make_recording(truth, np.random.default_rng(103), duration_s=3.0, closed=True, noise_deg=0.01,
                         name="c.csv", controller=_controller(truth))
    data = prepare([rec], 12.0, residual="observer")
    rd = data.recs[0]

    def current_z(pred):
        return D.structure((pred[1] - rec.current_A) / rd.current_sigma_A, D.features(rec)["current"], "current").z

    coarse, fine = truth.replace(substeps=5), truth.replace(substeps=80)
    z_coarse = current_z(simulate(coarse, SensorModel(), data)[0])
    z_fine = current_z(simulate(fine, SensorModel(), data)[0])
    z_pred = current_z(D.predict(coarse, SensorModel(), data)[0])
    assert z_coarse > z_fine + 3.0, (z_coarse, z_fine)          # the 5-substep stepper's own error: a structure
    assert abs(z_pred - z_fine) < 0.5, (z_pred, z_fine)
    by_kind = {s.kind: s.z for s in D.persistent_mismatch(data, coarse, SensorModel())}
    assert by_kind["current"] == pytest.approx(z_pred)
    err = [float(np.sqrt(np.mean((p[1] - simulate(fine, SensorModel(), data)[0][1]) ** 2)))
           for p in (simulate(coarse, SensorModel(), data)[0], D.predict(coarse, SensorModel(), data)[0])]
    assert err[1] < 0.25 * err[0], err
