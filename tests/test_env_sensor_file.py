"""The env reads a plant file's [sensor] section (a twin's reading model): offset, gain and delay, the reading
curve and the reading filter, in the single env and the native vector env, as the twin's equation predicts."""
import math

import gymnasium as gym
import numpy as np
import pytest
from test_envs_vector import _compare

import etb_gym  # noqa: F401
from etb_gym.components.sensor import fir_push, fir_series, pack_reading_shape, shape_reading, shape_reset
from etb_gym.diagnose.measurement import SensorModel
from etb_gym.plant import make_plant
from etb_gym.plantfile import save_plant

EXACT = {"noise_std_rad": 0.0, "resolution_rad": 0.0}
CURVE = {"angle_rad": [0.1, 0.6, 1.0, 1.5], "error_rad": [0.002, -0.004, 0.001, 0.003]}
FILTER = {"weights": [0.4, 0.3, 0.2, 0.1]}


def _file(tmp_path, section, name="twin.toml"):
    return str(save_plant(make_plant("3B"), tmp_path / name, sensor=section))


def _run(plant, n=120, **kw):
    """(t_s, true angle deg, sensed deg) of an episode under a fixed duty sequence."""
    env = gym.make("ETB-3B-v0", plant=plant, episode_s=0.2, reference="pedal", **kw)
    _, info = env.reset(seed=3, options={"angle_deg": 12.0})
    rows = [(info["t_s"], info["angle_deg"], info["sensed_angle_deg"])]
    duty = np.concatenate([np.full(40, 0.9), np.full(40, -0.4), np.full(n, 0.5)])[:n]
    for d in duty:
        info = env.step(np.array([d], np.float32))[4]
        rows.append((info["t_s"], info["angle_deg"], info["sensed_angle_deg"]))
    return (np.array(c) for c in zip(*rows))


def test_offset_gain_whole_delay_follow_the_sensor_equation(tmp_path):
    section = {"offset_rad": 0.003, "gain": 1.02, "delay_s": 0.002}
    t, phi, sensed = _run(_file(tmp_path, section), sensor=EXACT)
    delayed = np.concatenate([np.full(2, phi[0]), phi[:-2]])
    np.testing.assert_allclose(sensed, 1.02 * delayed + math.degrees(0.003), rtol=0, atol=1e-9)
    env = gym.make("ETB-3B-v0", plant=_file(tmp_path, section))
    assert env.unwrapped.sensor.params.delay_steps == 2 and not env.unwrapped.kernel.has_reading_shape


def test_sensor_overrides_win_over_the_file(tmp_path):
    path = _file(tmp_path, {"offset_rad": 0.003, "gain": 1.02, "delay_s": 0.0025})
    t, phi, sensed = _run(path, sensor={**EXACT, "offset_rad": 0.0, "delay_steps": 1})
    np.testing.assert_allclose(sensed, 1.02 * np.concatenate([phi[:1], phi[:-1]]), rtol=0, atol=1e-9)


@pytest.mark.parametrize("section", [
    {"offset_rad": -0.002, "gain": 0.98, "delay_s": 0.0025},                    # a fractional delay
    {"offset_rad": 0.001, "gain": 1.0, "delay_s": 0.0014, "curve": CURVE},
    {"offset_rad": 0.0, "gain": 1.01, "delay_s": 0.0, "curve": CURVE, "filter": FILTER},
], ids=["fraction", "curve", "curve_filter"])
def test_reading_maps_give_the_twins_reading(tmp_path, section):
    """The env's readings (noise 0, no quantization) are the diagnosis twin's (SensorModel.apply) of the same
    true angle: one equation, read from the same file."""
    t, phi, sensed = _run(_file(tmp_path, section), sensor=EXACT)
    twin = SensorModel.from_section(section).apply(t, phi)
    np.testing.assert_allclose(sensed, twin, rtol=0, atol=1e-9)
    assert np.max(np.abs(sensed - phi)) > 0.05          # the maps act


def test_plant_dict_with_sensor_and_quantized_noisy_readings(tmp_path):
    d = make_plant("3B").to_dict()
    d["sensor"] = {"offset_rad": 0.01, "gain": 1.0, "delay_s": 0.0, "filter": FILTER}
    env = gym.make("ETB-3B-v0", plant=d)
    _, info = env.reset(seed=1)
    step = math.degrees(env.unwrapped.sensor.params.resolution_rad)      # quantization stays the env's
    assert abs(info["sensed_angle_deg"] / step - round(info["sensed_angle_deg"] / step)) < 1e-6
    assert abs(info["sensed_angle_deg"] - info["angle_deg"] - math.degrees(0.01)) < 0.1


@pytest.mark.parametrize("num_threads", [1, 2])
def test_vector_equals_sync_with_reading_maps(tmp_path, num_threads):
    """Bit for bit, serial and parallel (lockstep groups and an odd one); autoreset refills the maps' state."""
    path = _file(tmp_path, {"offset_rad": 0.002, "gain": 1.01, "delay_s": 0.0035, "curve": CURVE,
                            "filter": FILTER})
    kw = dict(plant=path, episode_s=0.1, observe_current=True, sensor={"noise_std_rad": 2e-4})
    assert _compare(kw, n_envs=3, n_steps=230, num_threads=num_threads)


def test_fir_push_streams_fir_series_and_shape_reset():
    rng = np.random.default_rng(0)
    x, w = rng.normal(size=30), np.array([0.5, 0.3, 0.2])
    buf, pos, out = np.full(4, x[0]), 0, []
    for v in x:
        y, pos = fir_push(buf, pos, v, w, 0, 3)
        out.append(y)
    assert np.array_equal(out, fir_series(x, w))
    shape = pack_reading_shape(0.25, None, None)
    line = np.zeros(1)
    assert shape_reset(line, shape, 2.0) == 0 and line[0] == 2.0
    assert shape_reading(4.0, line, 0, shape)[0] == 0.75 * 4.0 + 0.25 * 2.0
    assert shape_reading(1.0, np.zeros(1), 0, pack_reading_shape())[0] == 1.0


@pytest.mark.parametrize("section, words", [
    ({"gain": -1.0}, ["sensor.gain", "-1.0", "gain > 0"]),
    ({"delay_s": 0.0, "filter": {"weights": [0.5, 0.4]}}, ["sensor.filter", "weights", "sum to 1"]),
    ({"curve": {"angle_rad": [0.2, 0.1], "error_rad": [0.0, 0.0]}}, ["sensor.curve", "angle_rad", "increasing"]),
    ({"lag_s": 0.1}, ["sensor", "lag_s", "delay_s"]),
])
def test_bad_sensor_section_fails_naming_the_field(tmp_path, section, words):
    d = make_plant("3B").to_dict()
    d["sensor"] = section
    for plant in (d, ):
        with pytest.raises(ValueError) as e:
            gym.make("ETB-3B-v0", plant=plant)
        for w in words:
            assert w in str(e.value), (w, str(e.value))
    path = tmp_path / "bad.toml"
    path.write_text(etb_gym.plantfile.dumps_toml(d))
    with pytest.raises(ValueError, match="bad.toml"):
        gym.make("ETB-3B-v0", plant=str(path))
