"""The proof's open-loop excitation is drawn in angle terms of the recorded plant (synthetic.TravelDuty): a
strong motor is not driven into its open stop, a weak one still travels, and the levels hold the plate where
they say."""
import math

import numpy as np
import pytest

from etb_gym.diagnose.synthetic import TravelDuty, make_recording, open_loop_duty, random_nameplate
from etb_gym.plant import make_plant


def _at_open_stop(plant, seed):
    rec = make_recording(plant, np.random.default_rng(seed), duration_s=3.0, noise_deg=0.01)
    hi = math.degrees(plant.angle_max_rad)
    lh = math.degrees(plant.limp_home_rad)
    p5, p95 = np.percentile(rec.angle_deg, [5, 95])
    return float(np.mean(rec.angle_deg > hi - 1.0)), (p95 - p5) / (hi - lh)


def test_strong_and_weak_nameplates_travel_without_living_at_the_open_stop():
    """Nameplate 1001 (stall torque 2.9x what the spring and friction need at the open stop) sat at its open
    stop 74 % of the time under the earlier raw duties (docs/diagnosis.md, round 11); 3B (1.4x) 9 %."""
    for plant in (random_nameplate(np.random.default_rng(1001)), make_plant("3B")):
        share, travel = _at_open_stop(plant, 0)
        assert share < 0.25, share
        assert travel > 0.6, travel


def test_levels_hold_the_plate_at_their_target_angle():
    """A level held from below lands near its target: the spring's torque plus the friction, u = R T / c_M."""
    plant = random_nameplate(np.random.default_rng(1003))
    tv = TravelDuty(plant)
    for f in (0.3, 0.7):
        d = np.concatenate([np.zeros(200), np.full(800, tv.level(f, 1.0))])
        tr = plant.simulate(duty=d, angle_deg=math.degrees(plant.limp_home_rad))
        assert math.degrees(tr.angle_rad[-1]) == pytest.approx(math.degrees(tv.angle_rad(f)), abs=8.0)
    assert tv.level(0.7) > tv.level(0.3) > 0.0 > tv.closed_push(1.0)
    assert 0.0 < tv.open_push() <= 1.0


def test_excitation_defaults_to_3B_and_stays_in_duty_range():
    rng = np.random.default_rng(3)
    d = open_loop_duty(2.0, rng)
    assert d.shape == (2000,) and np.all(np.abs(d) <= 1.0) and np.isfinite(d).all()
