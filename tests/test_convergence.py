"""The stepper is second order and its contacts converge monotonically (issue 12); it is stable at every
accepted timing and says so clearly when parameters make it diverge (issue 16, item 1).

The full table (nine models, both PWM modes, 5..80 substeps) is docs/model.md sec. 9, made by
``python -m etb_gym.accuracy``; these are its short versions."""
import math

import gymnasium as gym
import numpy as np
import pytest

import etb_gym  # noqa: F401  (registers the ids)
from etb_gym import MODELS, integrate, make_plant
from etb_gym.accuracy import case_inputs, errors, main, monotone, observed_order
from etb_gym.components.effects_mechanical import Backlash, EndStopCompliance
from etb_gym.excitation import rich_excitation
from etb_gym.integrate import H_MAX_S, substeps_used


@pytest.mark.parametrize("model, case", [("3B", "rich"), ("2B", "rich"), ("1A", "release"), ("3C", "release")])
def test_second_order_on_smooth_cases(model, case):
    r = errors(model, "averaged", case, substeps=(10, 20, 40))
    assert all(o >= 1.8 for o in r["order"]), r
    assert r["rms_deg"][1] <= 0.005 and r["max_deg"][1] <= 0.05, r       # the 20-substep targets


@pytest.mark.parametrize("model", MODELS)
def test_release_from_90_deg_converges_monotonically(model):
    """Observation (a): impacts on the closed stop, bounces, stiction. Every model: the error falls with
    every doubling of the substeps from 5 to 80, and is within 0.05 deg RMS at the default 20."""
    r = errors(model, "averaged", "release")
    assert monotone(r["rms_deg"]), r
    assert r["rms_deg"][2] <= 0.05, r


def test_observed_order_formula():
    assert observed_order([10, 20, 40], [4.0, 1.0, 0.25]) == [2.0, 2.0]
    assert monotone([3, 2, 1]) and not monotone([3, 3.5, 1])


def test_accuracy_cli_rejects_substeps_the_stepper_would_raise(capsys):
    """--substeps 2 at 1 ms would run 3 (h_max) and print it as "2"."""
    with pytest.raises(SystemExit):
        main(["--models", "3B", "--substeps", "2", "4"])
    assert "at least 3 substeps per 1 ms" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------ stability
def test_substeps_follow_from_the_maximum_substep():
    assert substeps_used(1e-3, 20) == 20
    assert substeps_used(1e-3, 1) == round(1e-3 / H_MAX_S)
    assert substeps_used(0.01, 20) == round(0.01 / H_MAX_S)
    assert substeps_used(1.0, 20) * H_MAX_S == pytest.approx(1.0)


@pytest.mark.parametrize("model", ["3B", "1A", "2C"])
def test_long_control_period_is_stable(model):
    """Issue 16: control_period_s = 0.01 with the default 20 substeps (0.5 ms each) used to return garbage
    within a few steps; the stepper now takes substeps of at most H_MAX_S (333 us) and the plate stays between the stops."""
    env = gym.make(f"ETB-{model}-v0", control_period_s=0.01, episode_s=2.0)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    angles = []
    for a in rng.choice([-1.0, 1.0, 0.0, 0.4], 150):
        _, r, term, trunc, info = env.step(np.array([a], np.float32))
        angles.append(info["angle_deg"])
        assert math.isfinite(r)
    assert -1.0 < min(angles) and max(angles) < 91.0
    assert np.ptp(angles) > 30.0


@pytest.mark.parametrize("cp", [1e-6, 1e-4, 1.0])
def test_control_period_range_ends(cp):
    env = gym.make("ETB-3B-v0", control_period_s=cp, episode_s=max(3 * cp, 1e-3))
    env.reset(seed=1)
    for a in (1.0, -1.0, 0.3):
        _, r, _, _, info = env.step(np.array([a], np.float32))
        assert math.isfinite(r) and -1.0 < info["angle_deg"] < 91.0


@pytest.mark.parametrize("bad", [True, False, 0.0, 2.0, -1e-3, float("nan")])
def test_control_period_outside_its_range_or_not_a_number_is_rejected(bad):
    with pytest.raises(ValueError, match="control_period_s"):
        gym.make("ETB-3B-v0", control_period_s=bad)


def test_supply_range_ends():
    for V in (1.0, 60.0):
        p = make_plant("3B", supply_V=V)
        tr = p.simulate(np.concatenate([np.full(300, 1.0), np.full(300, -1.0)]))
        a = tr.angle_deg
        assert -5.0 < a.min() and a.max() < 95.0               # impacts at 60 V (~300 rad/s) penetrate ~3 deg
        if V == 60.0:                                          # held at the stops within the contact's compliance
            assert 89.0 < a[300] < 90.5 and -0.5 < a[-1] < 1.0
        env = gym.make("ETB-3B-v0", supply_V=V)
        env.reset(seed=0)
        env.step(np.array([1.0], np.float32))
    for bad in (1000.0, 0.5, True):
        with pytest.raises(ValueError, match="supply_V|voltage_V"):
            gym.make("ETB-3B-v0", supply_V=bad)
        with pytest.raises(ValueError, match="voltage_V"):
            make_plant("3B", supply_V=bad if bad is not True else 1000.0)
    with pytest.raises(ValueError, match=r"supply_V\[0\]"):
        make_plant("3B").simulate(np.zeros(3), supply_V=np.full(3, 1000.0))


def test_divergence_raises_at_the_first_nonphysical_state():
    """Parameters far outside what the stepper is stable for (a stop 10^5 times stiffer): a clear error at the
    first control period that ends in a non-physical state, never garbage steps first."""
    p = make_plant("1A", {"stops.stiffness_Nm_per_rad": 1e9, "stops.damping_Nm_s_per_rad": 0.0})
    duty = np.full(400, -1.0)
    with pytest.raises(FloatingPointError, match="diverged at t = .* s: the state left the physical range") as e:
        p.simulate(duty)
    assert "np.float64" not in str(e.value)
    k = round(float(str(e.value).split("t = ")[1].split(" s")[0]) / p.control_period_s)
    tr = p.simulate(duty[:k - 1])                                  # every period before it is physical
    assert np.all(np.isfinite(tr.states)) and tr.angle_deg.min() > -0.5 * 180 / math.pi
    x = p.initial_state()
    with pytest.raises(FloatingPointError, match="diverged"):
        for _ in range(400):
            p.step(x, -1.0)


# ------------------------------------------------------------------------------------ contacts of effects
def test_bounce_in_an_effects_contact_converges_monotonically_at_second_order():
    """The diagnosis effects that move contacts (backlash: the limp-home band widened by the play; a compliant
    end stop: other angle and stiffness) declare their edges and impact rate, so a release from 90 deg through
    them converges monotonically at second order (without the edges: order ~1 for the backlash). One 2C plant
    carries both: released from 90 deg it falls through the play (0.02 rad about limp-home) onto the softer closed
    stop (0.86 deg; down to 0.79 deg) and comes back into the play; one composition instead of one per effect."""
    effects = [Backlash(play_rad=0.02), EndStopCompliance(closed_rad=0.015, stiffness_Nm_per_rad=300.0)]
    plant = make_plant("2C", pwm_mode="averaged", effects=effects)
    duty, x0 = case_inputs(plant, "release")
    angle = plant.simulate(duty[:round(0.8 / plant.control_period_s)], x0=x0).angle_deg
    assert angle.min() < math.degrees(0.015) < angle[0], "the release must reach the softer stop"
    r = errors("2C", "averaged", "release", substeps=(5, 10, 20, 40), effects=effects, duration_s=0.8)
    assert monotone(r["rms_deg"]), r
    assert all(o >= 1.7 for o in r["order"][1:]), r


def test_plate_resting_in_a_stop_at_the_longest_substep_does_not_chatter():
    """At h = H_MAX_S (3 substeps of 333 us at 1 ms) a plate pressed into a stop is a stiff contact (h sqrt(k/J) =
    1.92) that the explicit midpoint rule alone grows on when the stop's damping is light: with c = 0.02 Nm s/rad
    it chattered at 0.11 deg peak to peak at 250 us (0.44 deg RMS against solve_ivp). The slow-contact pieces
    (RHO_STIFF, with the rate raised for the light damping: pieces of 0.64 instead of 0.96, on which it drifted
    0.05 deg in 50 ms) keep it at rest as the reference does. (The RMS is the light stop's bounces, 0.28 deg.)"""
    p = make_plant("1A", {"stops.damping_Nm_s_per_rad": 0.02}, substeps=3)
    assert substeps_used(p.control_period_s, 1) == 3
    d = np.concatenate([np.full(150, 1.0), np.full(150, -1.0)])    # into the open stop, then the closed one
    ref = p.reference(d).angle_deg
    a = p.simulate(d, path="plain").angle_deg
    assert np.ptp(a[100:151]) < 0.01 and np.ptp(a[250:]) < 0.01, (np.ptp(a[100:151]), np.ptp(a[250:]))
    assert np.sqrt(np.mean((a - ref) ** 2)) < 0.35


def _rms(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2)))


def test_lugre_bristle_damping_is_taken_exponentially_where_the_substep_is_too_long(monkeypatch):
    """LuGre's bristle damping after a velocity reversal, 2 sigma1 / J, is the stiffest decaying mode of the shaft.
    With sigma1 doubled (0.22 Nm s/rad) h * 2 sigma1 / J = 4.9 at 3 substeps, far past the explicit midpoint's 2:
    the exponential step for omega's damping (RHO_DAMP) follows solve_ivp through an 8 Hz oscillation across
    limp-home; the explicit midpoint alone is 6x further off."""
    over = {"friction.bristle_damping_Nm_s_per_rad": 0.22}
    p = make_plant("3B", over, substeps=3)
    d = 0.1 + 0.4 * np.sin(2 * np.pi * 8.0 * np.arange(300) * p.control_period_s)
    ref = p.reference(d).angle_deg
    exp_err = _rms(p.simulate(d, path="plain").angle_deg, ref)
    monkeypatch.setattr(integrate, "RHO_DAMP", 1e9)        # a new stepper source: never exponential
    explicit_err = _rms(make_plant("3B", over, substeps=3).simulate(d, path="plain").angle_deg, ref)
    assert np.ptp(ref) > 10.0 and exp_err < 0.05 and explicit_err > 3 * exp_err, (exp_err, explicit_err)


def test_damping_step_leaves_five_and_more_substeps_bit_for_bit(monkeypatch):
    """At n >= 5 per ms (h <= 200 us) h D / J stays below RHO_DAMP at the default parameters (D <= 2.1 sigma1 +
    sigma2: 1.55), so the stepper is the explicit midpoint to the bit there, as before the exponential step."""
    d = rich_excitation()
    a = make_plant("3B", substeps=5).simulate(d, path="plain").states
    monkeypatch.setattr(integrate, "RHO_DAMP", 1e9)
    b = make_plant("3B", substeps=5).simulate(d, path="plain").states
    assert np.array_equal(a, b)
