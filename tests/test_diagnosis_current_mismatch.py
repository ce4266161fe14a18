"""result.current_mismatch: on an open-loop (replayed) recording the recorded current is a test of its own, so an
effect the calibrated friction and spring carry in the angle but not in the current is not a `match`."""
import numpy as np

from etb_gym.diagnose.measurement import SensorModel
from etb_gym.diagnose.model import angle_residuals_deg, prepare, simulate
from etb_gym.diagnose.result import RMS_K, current_mismatch, significant_mismatch
from etb_gym.diagnose.synthetic import make_recording
from etb_gym.plant import make_plant


def test_replayed_current_off_the_model_is_a_mismatch_the_angle_does_not_see():
    truth = make_plant("3B", substeps=20)
    rec = make_recording(truth, np.random.default_rng(7), duration_s=2.0, closed=False, noise_deg=0.03,
                         name="o.csv")
    data = prepare([rec], 12.0, residual="replay")
    own = current_mismatch(data, truth, SensorModel())[0]
    assert 0.8 < own < 1.3, own                                   # the truth's own model: the current's noise
    # a resistance 10 % off: the current 10 % off, far beyond its noise
    R = truth.params_dict()["drive.resistance_ohm"]
    lossy = truth.with_params({"drive.resistance_ohm": 1.1 * R})
    off = current_mismatch(data, lossy, SensorModel())[0]
    assert off > RMS_K, off
    assert significant_mismatch(data, angle_residuals_deg(simulate(lossy, SensorModel(), data), data), lossy,
                                SensorModel())
    # a closed loop is left to its current residual's structure (disturbance.py); no current: nothing to test
    obs = prepare([rec], 12.0, residual="observer")
    assert current_mismatch(obs, lossy, SensorModel()) == [None]
    bare = make_recording(truth, np.random.default_rng(7), duration_s=2.0, closed=False, noise_deg=0.03,
                          name="b.csv", with_current=False)
    assert current_mismatch(prepare([bare], 12.0, residual="replay"), lossy, SensorModel()) == [None]
