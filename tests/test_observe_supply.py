"""ECU sensing as observation options: battery voltage (observe_supply) beside the coil current."""
import gymnasium as gym
import numpy as np
import pytest

import etb_gym  # noqa: F401
from etb_gym.envs.observation import SUPPLY_SCALE_V, decode, encode


@pytest.mark.parametrize("current", [False, True])
def test_supply_reading_layout_noise_and_resolution(current):
    env = gym.make("ETB-3B-v0", observe_current=current, observe_supply=True, supply_V=13.0)
    obs, _ = env.reset(seed=3)
    assert obs.shape == (4 + current + 1,)
    readings = []
    for _ in range(400):
        obs, *_ = env.step(np.zeros(1, np.float32))
        m = decode(obs, observe_current=current, observe_supply=True)
        assert (m.current_A is not None) == current
        readings.append(m.supply_V)
    v = np.array(readings)
    q = 20.0 / 1024
    assert np.allclose(v / q, np.round(v / q), atol=1e-3)          # 10-bit ADC over 20 V
    assert abs(v.mean() - 13.0) < 0.01 and 0.03 < v.std() < 0.07   # 0.05 V noise


def test_supply_reading_follows_the_episode_battery():
    env = gym.make("ETB-3B-v0", observe_supply=True, randomize={"supply_V": (9.0, 16.0)},
                   sensor={"supply_noise_std_V": 0.0, "supply_resolution_V": 0.0})
    for seed in range(3):
        obs, info = env.reset(seed=seed)
        assert decode(obs, observe_supply=True).supply_V == pytest.approx(info["supply_V"], rel=1e-6)


def test_vector_env_reads_the_same_supply_bit_for_bit():
    kw = dict(observe_current=True, observe_supply=True, randomize=True)
    vec = gym.make_vec("ETB-3B-v0", num_envs=3, **kw)
    sync = gym.vector.SyncVectorEnv([lambda: gym.make("ETB-3B-v0", **kw) for _ in range(3)])
    a, _ = vec.reset(seed=5)
    b, _ = sync.reset(seed=5)
    assert np.array_equal(a, b)
    rng = np.random.default_rng(0)
    for _ in range(300):
        act = rng.uniform(-1, 1, (3, 1)).astype(np.float32)
        a, *_ = vec.step(act)
        b, *_ = sync.step(act)
        assert np.array_equal(a, b)


def test_encode_decode_round_trip_with_supply():
    o = encode(12.0, 15.0, 0.25, current_A=2.0, supply_V=11.5)
    m = decode(o, observe_current=True, observe_supply=True)
    assert m.supply_V == pytest.approx(11.5, rel=1e-6) and m.current_A == pytest.approx(2.0, rel=1e-6)
    assert o[5] == pytest.approx(11.5 / SUPPLY_SCALE_V)
    with pytest.raises(ValueError, match="supply"):
        decode(o[:4], observe_supply=True)


@pytest.mark.parametrize("option, value", [("observe_supply", "yes"), ("observe_supply", 2),
                                           ("observe_current", "no"), ("observe_supply", None)])
def test_bad_option_values_name_the_option(option, value):
    with pytest.raises(ValueError, match=f"{option} = .* is invalid: expected True or False"):
        gym.make("ETB-3B-v0", **{option: value})


def test_bad_supply_sensor_parameters_name_the_field():
    with pytest.raises(ValueError, match="supply_noise_std_V"):
        gym.make("ETB-3B-v0", observe_supply=True, sensor={"supply_noise_std_V": -0.1})
