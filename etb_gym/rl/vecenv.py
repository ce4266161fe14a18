"""Stable-Baselines3's VecEnv over a Gymnasium vector env with same-step autoreset (the task wrappers of
:mod:`etb_gym.rl.wrappers`), and the training env of a run.

SB3 conventions: float32 rewards, ``dones = terminated | truncated``, ``infos[i]["terminal_observation"]`` and
``infos[i]["TimeLimit.truncated"]`` (so off-policy algorithms bootstrap through the time limit).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from .wrappers import make_task_vec_env


class SB3VecEnv(VecEnv):
    """SB3's VecEnv API over a Gymnasium ``VectorEnv`` whose finished sub-envs restart in the same step
    (``info["final_obs"]`` / ``"_final_obs"``). ``reset()`` seeds it with SB3's ``seed()`` value or ``seed``."""

    def __init__(self, venv, seed: int = 0):
        self.venv = venv
        self._seed = int(seed)
        self.render_mode = None
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self._actions = None

    def reset(self):
        seed = self._seeds[0] if any(s is not None for s in self._seeds) else self._seed
        obs, _ = self.venv.reset(seed=int(seed))
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions):
        self._actions = actions

    def step_wait(self):
        obs, reward, term, trunc, info = self.venv.step(self._actions)
        dones = np.logical_or(term, trunc)
        infos = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(dones):
            infos[i]["terminal_observation"] = np.array(info["final_obs"][i], copy=True)
            infos[i]["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
        return obs, np.asarray(reward, np.float32), dones, infos

    def close(self):
        self.venv.close()

    def get_attr(self, attr_name, indices=None):
        return [getattr(self, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name, value, indices=None):
        setattr(self, attr_name, value)

    def env_method(self, method_name, *args, indices=None, **kwargs):
        return [getattr(self, method_name)(*args, **kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False for _ in self._get_indices(indices)]

    def get_images(self):
        raise NotImplementedError("the training vec env does not render; use gym.make(id, render_mode=...)")


def training_vec_env(env_id: str, n_envs: int, task, seed: int = 0, randomize=False, **kwargs) -> SB3VecEnv:
    """The task's wrappers around ``gym.make_vec(env_id)`` as an SB3 VecEnv."""
    return SB3VecEnv(make_task_vec_env(env_id, n_envs, task, seed=seed, randomize=randomize, **kwargs), seed=seed)


def make_training_env(cfg, seed: int | None = None, normalize_stats: Path | None = None):
    """The SB3 VecEnv of a run (:class:`~etb_gym.rl.config.RunConfig`): :func:`training_vec_env` in a VecMonitor,
    and VecNormalize when ``cfg.normalize`` (loaded from ``normalize_stats`` when resuming)."""
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    env = VecMonitor(training_vec_env(cfg.env_id, cfg.n_envs, cfg.task_config, seed=cfg.seed if seed is None else seed,
                                      randomize=cfg.env_randomization()))
    if cfg.normalize:
        if normalize_stats is not None:
            env = VecNormalize.load(str(normalize_stats), env)
            env.training = True
        else:
            env = VecNormalize(env, norm_obs=True, norm_reward=True, gamma=cfg.resolved_hyperparams()["gamma"])
    return env
