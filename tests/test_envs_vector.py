"""The native vector env equals N single envs (SyncVectorEnv) step for step, including autoreset."""
import gymnasium as gym
import numpy as np
import pytest

import etb_gym  # noqa: F401
from etb_gym.envs.vector import ETBVectorEnv
from etb_gym.jit import HAVE_NUMBA


def _compare(kw, n_envs=3, n_steps=None, seed=11, options=None, env_id="ETB-3B-v0", num_threads=None):
    nat = gym.make_vec(env_id, num_envs=n_envs, num_threads=num_threads, **kw)
    syn = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="sync", **kw)
    assert isinstance(nat.unwrapped, ETBVectorEnv)
    assert nat.single_observation_space == syn.single_observation_space
    assert nat.action_space == syn.action_space
    o1, i1 = nat.reset(seed=seed, options=options)
    o2, i2 = syn.reset(seed=seed, options=options)
    _same(o1, o2, i1, i2)
    n_steps = n_steps or nat.unwrapped.env.max_steps + 3
    rng = np.random.default_rng(5)
    saw_reset = False
    for t in range(n_steps):
        a = rng.uniform(-1.3, 1.3, (n_envs, 1)).astype(np.float32)
        r1 = nat.step(a)
        r2 = syn.step(a)
        for x, y in zip(r1[:4], r2[:4]):
            assert np.array_equal(x, y), f"step {t}"
            assert x.dtype == y.dtype
        _same(r1[0], r2[0], r1[4], r2[4])
        saw_reset |= bool(np.any(r1[4]["t_s"] == 0.0)) and t > 0
    return saw_reset


def _same(o1, o2, i1, i2):
    assert np.array_equal(o1, o2)
    assert set(i1) == set(i2)
    for k in i1:
        assert np.array_equal(i1[k], i2[k]), k
        assert i1[k].dtype == i2[k].dtype, k


def test_vector_equals_sync_with_autoreset():
    # short episodes so that next-step autoreset (and its reward 0 / reset obs) is exercised twice
    saw = _compare(dict(episode_s=0.15, randomize=True, observe_current=True), n_envs=3, n_steps=320)
    assert saw


def test_vector_equals_sync_delay_quantized_current_full_state():
    kw = dict(episode_s=0.3, reference="pedal", full_state=True, observe_current=True,
              sensor={"delay_steps": 2, "current_resolution_A": 0.01, "noise_std_rad": 1e-3})
    _compare(kw, n_envs=2, n_steps=310, options={"angle_deg": 20.0, "params": {"friction.coulomb_Nm": 0.15}})


def test_vector_seed_list_reset_mask_and_errors():
    env = gym.make_vec("ETB-1A-v0", num_envs=4, episode_s=0.05)
    obs, info = env.reset(seed=[3, 4, 5, 6])
    single = gym.make("ETB-1A-v0", episode_s=0.05)
    o, _ = single.reset(seed=5)
    assert np.array_equal(obs[2], o)
    obs2, info2 = env.reset(options={"reset_mask": np.array([False, True, False, False])})
    assert info2["_angle_deg"].tolist() == [False, True, False, False]
    assert np.array_equal(obs2[0], obs[0])
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([[0.0], [np.nan], [0.0], [0.0]], np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((3, 1), np.float32))
    with pytest.raises(ValueError, match="unknown argument"):
        gym.make_vec("ETB-1A-v0", num_envs=2, speed=3)


def private_reads(source: str) -> list[str]:
    """``obj._name`` reads in ``source`` where ``obj`` is not ``self`` (dunders aside): reach-through into
    another object's internals."""
    import ast

    out = []
    for node in ast.walk(ast.parse(source)):
        if (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")
                and not (isinstance(node.value, ast.Name) and node.value.id == "self")):
            out.append(f"line {node.lineno}: {ast.unparse(node)}")
    return out


def test_vector_env_reads_no_private_attribute_of_the_single_env():
    """The vector env takes the single env's public EnvKernel (env.kernel) and episode draws, nothing private:
    a rename inside ETBEnv cannot break the compiled loops."""
    import inspect

    import etb_gym.envs.vector as vector

    found = private_reads(inspect.getsource(vector))
    assert not found, "envs/vector.py reads private attributes of other objects: " + "; ".join(found)
    # the check itself sees such a read
    assert private_reads("def f(self):\n    return self.env._P_nominal + self._ok\n") == \
        ["line 2: self.env._P_nominal"]


@pytest.mark.skipif(not HAVE_NUMBA, reason="the compiled noise stream (without numba fill_normals is numpy itself)")
def test_compiled_noise_is_numpys_standard_normal():
    """envs/noise.py: numpy's PCG64 and ziggurat standard_normal ported to compiled code give numpy's numbers bit for
    bit (10^5 per seed, the ziggurat's rejection and tail branches included) and leave numpy's generator state."""
    from numba import njit

    from etb_gym.envs.noise import fill_normals, pcg_words, set_pcg_words

    fill = njit(lambda out, words: fill_normals(out, words))
    for seed in (0, 1, 2):
        rng = np.random.default_rng(seed)
        words = pcg_words(rng, np.zeros(4, np.uint64))
        out = np.empty((400, 250))
        fill(out, words)
        assert np.array_equal(out, rng.standard_normal((400, 250)))
        assert np.array_equal(words, pcg_words(rng, np.zeros(4, np.uint64)))
        assert np.abs(out).max() > 3.6541528853610088      # the tail branch (x beyond the ziggurat's r) ran
        plain = np.empty((128, 3))
        fill_normals(plain, words)          # from Python: numpy itself
        assert np.array_equal(plain, rng.standard_normal((128, 3)))
        other = np.random.default_rng(99)
        set_pcg_words(other, words)
        assert np.array_equal(other.standard_normal(5), rng.standard_normal(5))


def test_parallel_vector_step_equals_sync():
    """The parallel vector step (num_threads=2, lockstep groups of two plants and an odd one) equals N single envs,
    noise refills (every 128 steps) and autoresets included. On 3B, whose parallel vector step
    tests/test_speed.py's thread-pool check compiles too (on 1A it was ~10 s of compile CPU for this test alone)."""
    assert _compare(dict(episode_s=0.15, observe_current=True), n_envs=5, n_steps=300, seed=21, env_id="ETB-3B-v0",
                    num_threads=2)
