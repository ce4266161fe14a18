"""The RL task as Gymnasium vector wrappers around the registered env (``gym.make_vec("ETB-3B-v0")``).

    from etb_gym.rl.wrappers import make_task_vec_env
    venv = make_task_vec_env("ETB-3B-v0", 8, TaskConfig(residual="smc"), seed=0, randomize=True)
    feats, info = venv.reset(seed=0)
    feats, reward, terminated, truncated, info = venv.step(actions)      # one policy decision

The agent trains on the env users see: the registered vector env (its native entry point by default, or
``vectorization_mode="sync"``: N ``gym.make(env_id)`` in a ``SyncVectorEnv``, the same MDP bit for bit)
seen through these wrappers, innermost first:

=========================== ================================================================================
:class:`TrackingReward`      the env's reward replaced by -tracking_cost(reference - true angle) per period
:class:`TrainingReferences`  every episode starts with a drawn reference and plate angle
                             (:func:`~etb_gym.rl.task.draw_reference`); a finished sub-env is reset in the
                             same step (``AutoresetMode.SAME_STEP``: ``info["final_obs"]`` with ``"_final_obs"``)
:class:`BaseControllerDuty`  residual mode: one classical controller per sub-env on the observation stream;
                             its duty for the coming period is appended to the observation
:class:`ResidualAction`      residual mode: duty = clip(base duty + residual_scale * action, -1, 1)
:class:`PolicyObservation`   the policy features (:class:`~etb_gym.rl.task.PolicyFeatures`)
:class:`ActionRepeat`        one action held for ``task.action_repeat`` periods; reward = mean over them
:class:`DecisionPenalty`     actions clipped to [-1, 1]; minus the rate (and residual magnitude) penalty
=========================== ================================================================================

The pieces (features, costs, references, base controllers) are the ones the deployed controller
(:class:`etb_gym.rl.controller.RLController`) uses, so training and deployment compute the same numbers.
"""
from __future__ import annotations

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv, VectorWrapper

from .task import BaseControllers, PolicyFeatures, TaskConfig, apply_residual, draw_reference, feature_names, \
    tracking_cost


def control_period(venv: VectorEnv) -> float:
    """The control period [s] of an ETB vector env (native entry point or a SyncVectorEnv of ``gym.make``)."""
    base = venv.unwrapped
    if hasattr(base, "env") and hasattr(base.env, "dt"):        # ETBVectorEnv: its configuration env
        return float(base.env.dt)
    return float(base.get_attr("dt")[0])


def _final(obs, info):
    """The terminal observations: ``obs`` with the rows of finished sub-envs replaced by ``info["final_obs"]``."""
    mask = info.get("_final_obs")
    if mask is None or not np.any(mask):
        return obs, None
    out = np.array(obs, copy=True)
    out[mask] = info["final_obs"][mask]
    return out, np.flatnonzero(mask)


class TrackingReward(VectorWrapper):
    """reward = -tracking_cost(reference_deg - angle_deg) of the period just stepped (the true plate angle from
    ``info``; :func:`~etb_gym.rl.task.tracking_cost`). The env's own reward is not used."""

    def __init__(self, env: VectorEnv, task: TaskConfig):
        super().__init__(env)
        self.task = task

    def step(self, actions):
        obs, _, term, trunc, info = self.env.step(actions)
        return obs, -tracking_cost(info["reference_deg"] - info["angle_deg"], self.task), term, trunc, info


class TrainingReferences(VectorWrapper):
    """Episodes of the RL task. ``reset(seed)`` seeds the sub-envs (``seed + k``) and the reference draws
    (``np.random.default_rng(seed)``), then starts every sub-env, one by one, with its own drawn reference and
    initial plate angle (``reset(options={"reset_mask", "reference", "angle_deg"})``). A sub-env that finishes
    in ``step`` is started again the same way within that step; its last observation is in
    ``info["final_obs"]`` (rows where ``info["_final_obs"]``), its last info in ``info["final_info"]``."""

    def __init__(self, env: VectorEnv, task: TaskConfig, seed: int = 0):
        super().__init__(env)
        self.task, self._seed = task, int(seed)
        self.dt = control_period(env)
        steps = round(task.episode_s / self.dt)
        if steps % task.action_repeat:
            raise ValueError(f"task.episode_s = {task.episode_s} s is {steps} control periods: expected a multiple "
                             f"of task.action_repeat = {task.action_repeat}")
        self.rng = np.random.default_rng(self._seed)
        self.metadata = {**env.metadata, "autoreset_mode": AutoresetMode.SAME_STEP}

    def _start(self, rows):
        obs = None
        for i in rows:
            ref, a0 = draw_reference(self.rng, self.task.episode_s, self.dt)
            mask = np.zeros(self.num_envs, bool)
            mask[i] = True
            obs, _ = self.env.reset(options={"reset_mask": mask, "reference": ref, "angle_deg": a0})
        return obs

    def reset(self, *, seed=None, options=None):
        if options:
            raise ValueError(f"reset(options={options!r}): the training wrappers draw their own references; "
                             "expected no options")
        seed = self._seed if seed is None else int(seed)
        self.rng = np.random.default_rng(seed)
        _, info = self.env.reset(seed=seed)
        return self._start(range(self.num_envs)), info

    def step(self, actions):
        obs, reward, term, trunc, info = self.env.step(actions)
        done = np.logical_or(term, trunc)
        if done.any():
            info = dict(info, final_obs=obs, _final_obs=done.copy(), final_info=info, _final_info=done.copy())
            obs = self._start(np.flatnonzero(done))
        return obs, reward, term, trunc, info


class _FollowsObservations(VectorWrapper):
    """A wrapper with per-sub-env state (``self.tracker``: ``reset_rows(rows, obs_rows)``, ``update(obs)``) that
    follows the observation stream, and that shows ``self._shown(obs)`` instead of the observation. At an
    episode end the tracker sees the final observation, which is shown the same way (``info["final_obs"]``),
    then restarts the finished rows from the reset observation."""

    tracker = None

    def _shown(self, obs):
        raise NotImplementedError

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.tracker.reset_rows(np.arange(self.num_envs), obs)
        return self._shown(obs), info

    def step(self, actions):
        obs, reward, term, trunc, info = self.env.step(actions)
        last, rows = _final(obs, info)
        self.tracker.update(last)
        if rows is not None:
            info = dict(info, final_obs=self._shown(last))
            self.tracker.reset_rows(rows, np.asarray(obs)[rows])
        return self._shown(obs), reward, term, trunc, info


class BaseControllerDuty(_FollowsObservations):
    """Residual mode: the base controllers (:class:`~etb_gym.rl.task.BaseControllers`, one per sub-env, built
    like the benchmark builds ``spec`` for ``env_id``) follow the observation stream; each observation gets one
    more column, the base duty for the coming period (float64, exact)."""

    def __init__(self, env: VectorEnv, spec: str, env_id: str):
        super().__init__(env)
        self.base = self.tracker = BaseControllers(spec, env_id, self.num_envs)
        box = env.single_observation_space
        self.single_observation_space = spaces.Box(np.append(box.low, -1.0), np.append(box.high, 1.0),
                                                   (box.shape[0] + 1,), np.float64)
        self.observation_space = spaces.Box(np.tile(self.single_observation_space.low, (self.num_envs, 1)),
                                            np.tile(self.single_observation_space.high, (self.num_envs, 1)),
                                            (self.num_envs, box.shape[0] + 1), np.float64)

    def _shown(self, obs):
        return np.column_stack([np.asarray(obs, np.float64), self.base.duty])


class ResidualAction(VectorWrapper):
    """Residual mode: the action a in [-1, 1] is a correction of the base duty (the observation's last column,
    :class:`BaseControllerDuty`): duty = clip(d_base + residual_scale * a, -1, 1)."""

    def __init__(self, env: VectorEnv, task: TaskConfig):
        super().__init__(env)
        self.task = task
        self._base = np.zeros(self.num_envs)

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._base = obs[:, -1].copy()
        return obs, info

    def step(self, actions):
        duty = apply_residual(self._base, np.asarray(actions, np.float64).reshape(self.num_envs), self.task)
        obs, reward, term, trunc, info = self.env.step(duty.reshape(-1, 1))
        self._base = obs[:, -1].copy()
        return obs, reward, term, trunc, info


class PolicyObservation(_FollowsObservations):
    """The policy features of the observation stream (:class:`~etb_gym.rl.task.PolicyFeatures`), updated every
    control period; in residual mode the last input column is the base duty (:class:`BaseControllerDuty`)."""

    def __init__(self, env: VectorEnv, task: TaskConfig):
        super().__init__(env)
        self.task = task
        self.features = self.tracker = PolicyFeatures(self.num_envs, control_period(env), task)
        n = len(feature_names(task))
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (n,), np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, (self.num_envs, n), np.float32)

    def _shown(self, obs):
        return self.features.value(np.asarray(obs)[:, -1] if self.task.residual else None)


class ActionRepeat(VectorWrapper):
    """One action held for ``repeat`` control periods; the reward is the mean of theirs. Episodes must end on a
    decision boundary (:class:`TrainingReferences` checks that the episode length allows it)."""

    def __init__(self, env: VectorEnv, repeat: int):
        super().__init__(env)
        self.repeat = int(repeat)

    def step(self, actions):
        total = np.zeros(self.num_envs)
        for j in range(self.repeat):
            obs, reward, term, trunc, info = self.env.step(actions)
            total += reward
            if j < self.repeat - 1 and np.any(np.logical_or(term, trunc)):
                raise RuntimeError("sub-env episodes fell out of step with the decision period")
        return obs, total / self.repeat, term, trunc, info


class DecisionPenalty(VectorWrapper):
    """Per decision: actions must be finite and are clipped to [-1, 1]; the reward loses the rate penalty
    w_rate ((a - a_prev)/2)^2 (residual mode: on the residual duty, and w_residual a^2)."""

    def __init__(self, env: VectorEnv, task: TaskConfig):
        super().__init__(env)
        self.task = task
        self._prev = np.zeros(self.num_envs)

    def reset(self, *, seed=None, options=None):
        out = self.env.reset(seed=seed, options=options)
        self._prev = np.zeros(self.num_envs)
        return out

    def step(self, actions):
        a = np.asarray(actions, dtype=np.float64).reshape(self.num_envs)
        if not np.all(np.isfinite(a)):
            raise ValueError(f"actions {a.tolist()}: expected finite duty cycles")
        a = np.clip(a, -1.0, 1.0)
        obs, reward, term, trunc, info = self.env.step(a)
        task, dd = self.task, a - self._prev
        if task.residual:
            reward = reward - task.w_rate * (0.5 * task.residual_scale * dd) ** 2 - task.w_residual * a ** 2
        else:
            reward = reward - task.w_rate * (0.5 * dd) ** 2
        self._prev = a.copy()
        self._prev[np.logical_or(term, trunc)] = 0.0
        return obs, reward, term, trunc, info


def wrap_task(venv: VectorEnv, env_id: str, task: TaskConfig, seed: int = 0) -> VectorEnv:
    """The RL task around an ETB vector env of ``env_id`` (module docstring)."""
    venv = TrainingReferences(TrackingReward(venv, task), task, seed=seed)
    if task.residual:
        venv = ResidualAction(BaseControllerDuty(venv, task.residual, env_id), task)
    return DecisionPenalty(ActionRepeat(PolicyObservation(venv, task), task.action_repeat), task)


def make_task_vec_env(env_id: str, n_envs: int, task: TaskConfig, seed: int = 0, randomize=False,
                      vectorization_mode: str = "vector_entry_point", **env_kwargs) -> VectorEnv:
    """``gym.make_vec(env_id, n_envs, episode_s=task.episode_s, randomize=...)`` seen through the task."""
    import gymnasium as gym

    import etb_gym.envs  # noqa: F401  (registers the ids)

    venv = gym.make_vec(env_id, num_envs=int(n_envs), vectorization_mode=vectorization_mode,
                        episode_s=task.episode_s, randomize=randomize, **env_kwargs)
    return wrap_task(venv, env_id, task, seed)
