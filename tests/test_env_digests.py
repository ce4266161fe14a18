"""Behaviour lock: env trajectories (single and native vector env, every observation, sensing and randomization
option) hash to the digests recorded in tests/data/env_digests.json (written by ``tests/env_digests.py``).
A refactor must leave them bit-identical; a change of behaviour on purpose rewrites the file (see that module)."""
import json

import pytest

from env_digests import DATA, digests
from etb_gym.jit import HAVE_NUMBA


def test_quick_digests_unchanged():
    ref = json.loads(DATA.read_text())["quick"]
    now = digests(quick=True)
    differ = sorted(k for k in ref if now.get(k) != ref[k])
    assert set(now) == set(ref), "the case list changed: rewrite with python tests/env_digests.py --write"
    assert not differ, (f"{len(differ)} of {len(ref)} env trajectories changed: {differ}. If intended, rewrite "
                        "tests/data/env_digests.json with python tests/env_digests.py --write and say why")


@pytest.mark.skipif(not HAVE_NUMBA, reason="the full record includes the multi-threaded vector env")
def test_digest_record_covers_all_models_and_fast_equals_plain():
    full = json.loads(DATA.read_text())["full"]
    assert sum(k.startswith("vector ") for k in full) >= 30 and sum(k.startswith("single ") for k in full) >= 20
    assert all(v is True for k, v in full.items() if k.endswith("fast == plain") or k.endswith("round trip"))


@pytest.mark.parametrize("d", [0, 1, 3])
def test_env_delay_is_d_periods_like_the_sensor_component(d):
    """sensor={"delay_steps": d}: the reading after step k is the true angle after step k - d (docs/envs.md),
    in the single and the vector env, as PositionSensor (the diagnosis's sensor) has it."""
    import gymnasium as gym
    import numpy as np

    import etb_gym
    sensor = {"delay_steps": d, "noise_std_rad": 0.0, "resolution_rad": 0.0}
    env = gym.make("ETB-3B-v0", sensor=sensor)
    env.reset(seed=0)
    rng = np.random.default_rng(1)
    true, seen = [], []
    for _ in range(40):
        info = env.step(np.array([rng.uniform(-1, 1)], dtype=np.float32))[4]
        true.append(info["angle_deg"])
        seen.append(info["sensed_angle_deg"])
    true, seen = np.array(true), np.array(seen)
    assert np.max(np.abs(seen[d:] - true[:len(true) - d])) < 1e-4
    venv = etb_gym.make_vec("ETB-3B-v0", num_envs=2, sensor=sensor) if hasattr(etb_gym, "make_vec") else \
        gym.make_vec("ETB-3B-v0", num_envs=2, vectorization_mode="vector_entry_point", sensor=sensor)
    venv.reset(seed=0)
    vt, vs = [], []
    for _ in range(20):
        info = venv.step(np.full((2, 1), 0.5, dtype=np.float32))[4]
        vt.append(info["angle_deg"][0])
        vs.append(info["sensed_angle_deg"][0])
    vt, vs = np.array(vt), np.array(vs)
    assert np.max(np.abs(vs[d:] - vt[:len(vt) - d])) < 1e-4
