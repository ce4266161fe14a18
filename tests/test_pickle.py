"""Plants and envs pickle (multiprocessing, Ray): the compiled engine is rebuilt on unpickling, and the
unpickled object continues bit-identically."""
import pickle

import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401  (registers the ids)
from etb_gym import make_plant
from etb_gym.components import effects as fx


@pytest.mark.parametrize("model, effects", [("1A", ()), ("2C", ()), ("3B", (fx.Backlash(),))])
def test_plant_round_trip_simulates_identically(model, effects):
    """Each drive model (A, B, C) round trips; the 3B plant carries an effect (Backlash: one more state and its
    parameters) and 1A an override. These are compositions the suite compiles anyway (1A, 2C; 3B + Backlash in
    test_effects), so with a cold kernel cache this test compiles no stepper of its own (1A and 2C with Backlash
    were two, ~1 min of CPU)."""
    p = make_plant(model, effects=list(effects),
                   overrides={"friction.viscous_Nm_s_per_rad": 2e-4} if model == "1A" else None)
    q = pickle.loads(pickle.dumps(p))
    assert q.component_names == p.component_names and np.array_equal(q.P, p.P) and q.fast == p.fast
    v = 6.0 * np.sign(np.sin(np.arange(300) / 17.0))
    a, b = p.simulate(voltage=v), q.simulate(voltage=v)
    assert np.array_equal(a.states, b.states)


@pytest.mark.parametrize("env_id", ["ETB-3B-v0", "ETB-1C-v0"])
def test_env_pickled_mid_episode_steps_bit_identically(env_id):
    e = gym.make(env_id)
    e.reset(seed=3)
    for k in range(20):
        e.step(np.array([0.4], dtype=np.float32))
    f = pickle.loads(pickle.dumps(e))
    rng = np.random.default_rng(0)
    for k in range(200):
        a = rng.uniform(-1, 1, size=(1,)).astype(np.float32)
        o1, r1, t1, u1, _ = e.step(a)
        o2, r2, t2, u2, _ = f.step(a)
        assert np.array_equal(o1, o2) and r1 == r2 and (t1, u1) == (t2, u2), k
        if t1 or u1:
            break
    o1, _ = e.reset(seed=9)
    o2, _ = f.reset(seed=9)
    assert np.array_equal(o1, o2)
    u = f.unwrapped                       # the stepper's parameter vectors read-only again: one compiled type
    assert not u._P.flags.writeable and not u._P_nominal.flags.writeable


def test_vector_env_pickled_keeps_its_read_only_view_of_the_parameters():
    """The vector env's read-only P is a view of the P a reset writes a drawn episode into: still a view after
    pickling (it came back a copy, and a randomized reset then evaluated the stepper with the old P)."""
    e = gym.make_vec("ETB-3B-v0", num_envs=2, randomize=True)
    e.reset(seed=0)
    f = pickle.loads(pickle.dumps(e))
    f.reset(seed=5)
    assert np.shares_memory(f._P, f._P_read_only) and not f._P_read_only.flags.writeable
    assert np.array_equal(f._P_read_only, f._P)
    e.close()
    f.close()


# ------------------------------------------------------------------------------ env option and action checks
@pytest.mark.parametrize("kw, words", [
    ({"control_period_s": True}, ["control_period_s = True", "got bool"]),
    ({"supply_V": True}, ["supply_V = True", "got bool"]),
    ({"episode_s": "3"}, ["episode_s = '3'", "got str"]),
    ({"episode_s": 1e7}, ["episode_s = 10000000.0 s", "at most 10,000,000"]),
    ({"supply_V": np.float64("nan")}, ["supply_V = nan"]),
])
def test_env_options_type_checked_before_allocating(kw, words):
    with pytest.raises(ValueError) as e:
        gym.make("ETB-3B-v0", **kw)
    msg = str(e.value)
    assert "np.float64" not in msg
    for w in words:
        assert w in msg, msg


def test_vector_actions_of_the_wrong_shape_are_refused():
    from envs.vector import ETBVectorEnv
    v = ETBVectorEnv(num_envs=8)
    v.reset(seed=0)
    for shape in [(4, 2), (2, 4), (8, 2), (1, 8)]:
        with pytest.raises(ValueError, match=r"expected \(8,\) or \(8, 1\)"):
            v.step(np.zeros(shape))
    v.step(np.zeros((8, 1)))
    v.step(np.zeros(8))
    v.close()
