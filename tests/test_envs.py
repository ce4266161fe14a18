"""The ETB Gymnasium envs: registration, conformance, determinism, options, errors, plant files."""
import math
import warnings

import gymnasium as gym
import numpy as np
import pytest

import etb_gym
from etb_gym.envs import ENV_IDS, observation
from etb_gym.envs.env import DEFAULT_RANDOMIZATION, ETBEnv
from etb_gym.envs.references import Step

IDS = [f"ETB-{m}-v0" for m in etb_gym.MODELS]


def test_nine_ids_registered():
    assert ENV_IDS == tuple(IDS)
    for i in IDS:
        assert i in gym.registry
        assert gym.registry[i].vector_entry_point is not None


@pytest.mark.parametrize("env_id", IDS)
def test_checkers_pass_without_warnings(env_id):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(gym.make(env_id).unwrapped)
        sb3_check_env(gym.make(env_id))


def test_make_with_module_prefix_in_fresh_interpreter():
    import subprocess
    import sys

    code = ("import gymnasium as gym; e = gym.make('etb_gym:ETB-3B-v0'); o, i = e.reset(seed=0); "
            "print(type(e.unwrapped).__name__, o.shape)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["ETBEnv", "(4,)"]


def _rollout(env, seed, n=400, options=None):
    obs, info = env.reset(seed=seed, options=options)
    rng = np.random.default_rng(123)
    O, R, I = [obs], [], [info]
    for _ in range(n):
        obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, 1).astype(np.float32))
        O.append(obs)
        R.append(r)
        I.append(info)
    return np.array(O), np.array(R), I


def test_same_seed_bit_identical():
    kw = dict(randomize=True, observe_current=True, full_state=True)
    a = _rollout(gym.make("ETB-3B-v0", **kw), seed=7)
    b = _rollout(gym.make("ETB-3B-v0", **kw), seed=7)
    c = _rollout(gym.make("ETB-3B-v0", **kw), seed=8)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert [sorted(i.items()) for i in a[2]] == [sorted(i.items()) for i in b[2]]
    assert not np.array_equal(a[0], c[0])


def test_observation_matches_contract_and_info():
    env = gym.make("ETB-3B-v0", observe_current=True, sensor={"noise_std_rad": 0.0})
    obs, info = env.reset(seed=0, options={"angle_deg": 10.0, "reference": Step(10, 80, 0.05)})
    assert env.observation_space.contains(obs) and obs.dtype == np.float32
    for _ in range(60):
        obs, r, term, trunc, info = env.step(np.array([0.7], np.float32))
    m = observation.decode(obs)
    assert m.reference_deg == pytest.approx(80.0, abs=1e-4)
    assert m.angle_deg == pytest.approx(info["sensed_angle_deg"], abs=1e-3)
    assert abs(info["sensed_angle_deg"] - info["angle_deg"]) <= 0.5 * math.degrees(
        env.unwrapped.sensor.params.resolution_rad) + 1e-9
    assert m.last_duty == pytest.approx(0.7, abs=1e-6) and info["duty"] == pytest.approx(0.7, abs=1e-6)
    assert m.current_A == pytest.approx(info["current_A"], abs=0.1)
    expected = observation.encode(info["sensed_angle_deg"], info["reference_deg"], info["duty"])
    assert np.array_equal(obs[:4], expected)
    assert info["voltage_V"] == pytest.approx(info["duty"] * 12.0)
    assert info["t_s"] == pytest.approx(0.06)
    keys = {"angle_deg", "sensed_angle_deg", "velocity_deg_s", "current_A", "voltage_V", "duty", "reference_deg",
            "supply_V", "torque_electric_Nm", "torque_spring_Nm", "torque_friction_Nm", "torque_stops_Nm", "t_s"}
    assert set(info) == keys
    # the plate opened towards the reference with a positive duty
    assert info["angle_deg"] > 12.0


def test_sensor_scalar_equation_equals_component():
    env = ETBEnv(sensor={"noise_std_rad": 0.0, "offset_rad": 0.001, "gain": 1.01})
    env.reset(seed=0)
    u = env.unwrapped
    for phi in np.linspace(-0.01, 1.6, 37):
        v, _ = u._read_angle(float(phi))
        assert v == float(u.sensor.transform(phi, 0.0))


def test_sensing_and_reward_kernels_compiled_equal_plain():
    """The vector env runs the compiled kernels, the single env their py_func: the same bits."""
    from etb_gym.envs.env import sense, step_reward
    from etb_gym.jit import HAVE_NUMBA, py_func

    if not HAVE_NUMBA:
        pytest.skip("needs numba")
    rng = np.random.default_rng(0)
    for v, n, q in zip(rng.uniform(-0.1, 1.7, 200), rng.normal(0, 1e-3, 200), [0.0, 3.8e-4] * 100):
        assert sense(v, 1.01, 1e-3, n, q) == py_func(sense)(v, 1.01, 1e-3, n, q)
    q = 90.0 / 4096 / 57.29577951308232
    halfway = q * (np.arange(-5, 50) + 0.5)                 # exact ties round to even in both
    assert [sense(v, 1.0, 0.0, 0.0, q) for v in halfway] == [py_func(sense)(v, 1.0, 0.0, 0.0, q) for v in halfway]
    for e, d, dp in rng.uniform(-90, 90, (50, 3)) / [1, 90, 90]:
        assert step_reward(e, d, dp, 1 / 90, 0.02, 0.0125) == py_func(step_reward)(e, d, dp, 1 / 90, 0.02, 0.0125)
    out_c, out_p = np.zeros(5, np.float32), np.zeros(5, np.float32)
    for a, r, d, i in rng.uniform(-10, 95, (50, 4)):
        observation.encode_into(out_c, a, r, d / 100)
        observation.encode_current_into(out_c, i / 5)
        py_func(observation.encode_into)(out_p, a, r, d / 100)
        py_func(observation.encode_current_into)(out_p, i / 5)
        assert np.array_equal(out_c, out_p)


def test_reward_terms_and_weights():
    env = ETBEnv(reference={"name": "constant", "value_deg": 30.0}, sensor={"noise_std_rad": 0.0},
                 reward_weights={"effort": 0.0, "chattering": 0.0})
    _, info = env.reset(seed=0)
    _, r, *_ , info = env.step(np.array([1.0], np.float32))
    assert r == pytest.approx(-abs(30.0 - info["angle_deg"]) / 90.0)
    env2 = ETBEnv(reference={"name": "constant", "value_deg": 30.0})
    env2.reset(seed=0)
    _, r2, *_ , info2 = env2.step(np.array([1.0], np.float32))
    assert r2 == pytest.approx(-(abs(30 - info2["angle_deg"]) / 90 + 0.02 * 1.0 + 0.05 * 0.25))
    assert -1.1 < r2 < 0


def test_actions_clipped_and_nonfinite_rejected():
    env = gym.make("ETB-1A-v0")
    env.reset(seed=0)
    *_, info = env.step(np.array([3.0], np.float32))
    assert info["duty"] == 1.0
    *_, info = env.step(np.array([-2.0], np.float32))
    assert info["duty"] == -1.0
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(ValueError, match="finite"):
            env.step(np.array([bad], np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.array([0.1, 0.2]))


def test_truncation_after_episode_s():
    env = gym.make("ETB-2A-v0", episode_s=0.02)
    env.reset(seed=0)
    truncs = [env.step(np.zeros(1, np.float32))[3] for _ in range(20)]
    assert truncs == [False] * 19 + [True]


def test_reset_options_and_step_scenario():
    env = ETBEnv(sensor={"noise_std_rad": 0.0})
    obs, info = env.reset(seed=0, options={"angle_deg": 10, "reference": Step(10, 80, 0.05), "supply_V": 14.0,
                                           "params": {"friction.coulomb_Nm": 0.1, "friction.static_Nm": 0.12}})
    assert info["angle_deg"] == pytest.approx(10.0) and info["reference_deg"] == 10.0 and info["supply_V"] == 14.0
    refs = [env.step(np.zeros(1, np.float32))[-1]["reference_deg"] for _ in range(60)]
    assert refs[48] == 10.0 and refs[49] == 80.0     # step at t = 0.05 s = after 50 periods
    # the episode's params are not sticky
    _, info = env.reset(seed=0)
    assert info["supply_V"] == 12.0 and info["angle_deg"] == pytest.approx(3.0)


def test_params_overrides_change_physics():
    def final_angle(**opt):
        env = ETBEnv(reference="steps", sensor={"noise_std_rad": 0.0})
        env.reset(seed=0, options=opt or None)
        for _ in range(100):
            *_, info = env.step(np.array([0.4], np.float32))
        return info["angle_deg"]

    base = final_angle()
    weak = final_angle(params={"spring.preload_Nm": 0.05})
    assert weak > base + 1.0


@pytest.mark.parametrize("call, match", [
    (lambda: gym.make("ETB-3B-v0", refrence="steps"), r"unknown argument.*refrence.*valid"),
    (lambda: gym.make("ETB-3B-v0", reference="stepz"), r"unknown reference 'stepz'.*'steps'"),
    (lambda: gym.make("ETB-3B-v0", reference={"name": "step", "height": 3}), r"unknown parameter.*height.*valid"),
    (lambda: gym.make("ETB-3B-v0", randomize={"friction": (0.5, 1.5)}), r"unknown quantity.*friction_scale"),
    (lambda: gym.make("ETB-3B-v0", reward_weights={"speed": 1}), r"unknown key.*chattering"),
    (lambda: gym.make("ETB-3B-v0", sensor={"noise": 1}), r"unknown parameter.*noise_std_rad"),
    (lambda: gym.make("ETB-3B-v0", params={"friction.mu": 1}), r"mu"),
    (lambda: gym.make("ETB-3B-v0", model="4D"), r"4D"),
    (lambda: ETBEnv(render_mode="ascii"), r"render_mode.*rgb_array"),
    (lambda: gym.make("ETB-3B-v0").reset(options={"angle": 3}), r"unknown option.*angle_deg"),
    (lambda: gym.make("ETB-3B-v0").reset(options={"angle_deg": 120}), r"angle_deg.*end stops"),
    (lambda: gym.make("ETB-3B-v0").reset(options={"reference": "ramp2"}), r"unknown reference.*ramp"),
    (lambda: gym.make("ETB-3B-v0").reset(options={"params": {"supply.voltage_V": 9}}), r"supply_V"),
    (lambda: gym.make("ETB-3B-v0").reset(options={"params": {"gearbox.ratio": 9}}), r"unknown component.*valid"),
    (lambda: gym.make("ETB-3B-v0").reset(options={"reference": {"name": "constant", "value_deg": 400}}),
     r"leaves"),
    (lambda: gym.make("ETB-3B-v0", reference={"name": "random_steps", "high_deg": 300}).reset(), r"leaves"),
    (lambda: gym.make("ETB-3B-v0", reference={"name": "random_steps", "min_dwell_s": -1}), r"min_dwell_s"),
])
def test_bad_input_names_the_choices(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_unknown_id_lists_ids():
    with pytest.raises(gym.error.Error, match="ETB-3D.*Did you mean"):
        gym.make("ETB-3D-v0")


def test_randomization_draws_in_documented_ranges():
    env = ETBEnv(randomize=True)
    nominal = env.plant.params_dict()
    for seed in range(5):
        env.reset(seed=seed)
        d = env.episode.draws
        assert set(d) == set(DEFAULT_RANDOMIZATION)
        for k, (lo, hi) in DEFAULT_RANDOMIZATION.items():
            assert lo <= d[k] <= hi
        P = env.episode.P
        expect = env.plant.param_vector({
            "drive.resistance_ohm": nominal["drive.resistance_ohm"] * (1 + 0.00393 * (d["coil_temperature_C"] - 20)),
            "friction.coulomb_Nm": nominal["friction.coulomb_Nm"] * d["friction_scale"],
            "friction.static_Nm": nominal["friction.static_Nm"] * d["friction_scale"],
            "friction.viscous_Nm_s_per_rad": nominal["friction.viscous_Nm_s_per_rad"] * d["friction_scale"],
            "spring.preload_Nm": nominal["spring.preload_Nm"] * d["spring_scale"],
            "spring.rate_Nm_per_rad": nominal["spring.rate_Nm_per_rad"] * d["spring_scale"],
            "rotor.inertia_kg_m2": nominal["rotor.inertia_kg_m2"] * d["inertia_scale"]})
        assert np.array_equal(P, expect)
        assert env.episode.supply_V == d["supply_V"]
    only = ETBEnv(randomize={"supply_V": (10.0, 11.0)})
    _, info = only.reset(seed=0)
    assert 10 <= info["supply_V"] <= 11 and only.episode.P is only._P_nominal


def test_plant_from_file(tmp_path):
    from etb_gym.plantfile import save_plant

    plant = etb_gym.make_plant("2C", {"friction.coulomb_Nm": 0.3})
    path = save_plant(plant, tmp_path / "calibrated_plant.toml")
    env = gym.make("ETB-3B-v0", plant=str(path))
    assert env.unwrapped.plant.model == "2C"
    assert env.unwrapped.plant.friction.params.coulomb_Nm == 0.3
    env.reset(seed=0)
    env.step(np.zeros(1, np.float32))
    env_dict = gym.make("ETB-3B-v0", plant=plant.to_dict())
    assert np.array_equal(env_dict.unwrapped.plant.P, plant.P)
    with pytest.raises(FileNotFoundError):
        gym.make("ETB-3B-v0", plant=str(tmp_path / "missing.toml"))


def test_switching_pwm_and_extra_observations():
    env = gym.make("ETB-3A-v0", pwm_mode="switching", full_state=True, observe_current=True)
    obs, info = env.reset(seed=0)
    n = env.unwrapped.plant.n_states
    assert obs.shape == (5 + n,)
    obs, *_ = env.step(np.array([0.5], np.float32))
    assert env.observation_space.contains(obs)
    x = env.unwrapped._x
    assert np.allclose(obs[5:], (x / env.unwrapped.state_scales).astype(np.float32))


def test_render_rgb_array_and_headless_human():
    env = gym.make("ETB-2B-v0", render_mode="rgb_array", reference="steps", episode_s=0.5)
    env.reset(seed=0)
    for _ in range(300):
        env.step(np.array([0.6], np.float32))
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert frame.shape[0] >= 200 and frame.shape[1] >= 400
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 50          # a drawing, not a blank canvas
    env.step(np.array([-0.6], np.float32))
    assert not np.array_equal(env.render(), frame)                     # the picture follows the state
    env.close()
    human = gym.make("ETB-2B-v0", render_mode="human", episode_s=0.01)  # Agg backend in tests: no window
    human.reset(seed=0)
    for _ in range(3):
        human.step(np.zeros(1, np.float32))
    assert human.render() is None
    human.close()


def test_plant_file_docs_examples_and_effect_torque_in_info(tmp_path):
    import re
    import tomllib
    from pathlib import Path

    text = (Path(__file__).parents[1] / "docs" / "plant-file.md").read_text()
    blocks = re.findall(r"```toml\n(.*?)```", text, re.S)
    assert len(blocks) == 2
    full = tmp_path / "doc_example.toml"
    full.write_text(blocks[0])
    env = gym.make("ETB-1A-v0", plant=str(full))
    assert env.unwrapped.plant.model == "3B"
    _, info = env.reset(seed=0, options={"angle_deg": 60.0})
    assert info["torque_airflow_torque_Nm"] > 0.0          # quadratic_Nm = 0.02 at 60 deg
    *_, info = env.step(np.zeros(1, np.float32))
    assert "torque_airflow_torque_Nm" in info
    assert etb_gym.Plant.from_dict(tomllib.loads(blocks[1])).friction.params.static_Nm == 0.3
