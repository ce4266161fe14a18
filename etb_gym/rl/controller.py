"""A trained policy as a controller: :class:`RLController` (the controller protocol of
``etb_gym.controllers.base``) and the ``rl:PATH`` prefix of ``make_controller``, registered on import.

    ctrl = RLController("baselines/residual_sac_3b")     # == make_controller("rl:baselines/residual_sac_3b")
    ctrl.reset(seed=0)
    duty = ctrl.act(observation)                         # observation of gym.make("ETB-3B-v0")
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from .config import RunConfig, algorithm_class, env_dt, read_config
from .task import BaseControllers, PolicyFeatures, apply_residual, feature_names


class RLController:
    """A trained policy under the controller protocol (``name``, ``dt``, ``reset(seed)``, ``act(obs) -> duty``).

    ``RLController(path)``: a run folder (``model.zip`` + ``config.json``) or a policy zip with ``config.json``
    beside it. The controller rebuilds the training features (:class:`~etb_gym.rl.task.PolicyFeatures`) from
    the observation stream, applies the saved VecNormalize statistics if the run used them, asks the policy
    for a deterministic duty every ``action_repeat`` periods and holds it in between."""

    def __init__(self, path: str | os.PathLike | None = None, *, model=None, config: RunConfig | None = None,
                 obs_rms=None, name: str | None = None):
        if model is None:
            model, config, obs_rms, label = _load_policy_cached(path)
        elif config is None:
            raise ValueError("RLController(model=...): pass the run's config= as well")
        else:
            label = "rl"
        self.model, self.config = model, config
        self.task = config.task_config
        self.obs_rms = obs_rms
        self.name = name or label
        self.dt = env_dt(config.env_id)
        self.features = PolicyFeatures(1, self.dt, self.task)
        # residual mode: the same base controller as in training (built-in, designed on the nominal model)
        self.base = BaseControllers(self.task.residual, config.env_id, 1) if self.task.residual else None
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        self._k = 0
        self._duty = 0.0
        self._seed = seed
        self._residual = 0.0

    def _normalize(self, f):
        if self.obs_rms is None:
            return f
        rms, clip, eps = self.obs_rms
        return np.clip((f - rms.mean) / np.sqrt(rms.var + eps), -clip, clip).astype(np.float32)

    def act(self, observation) -> float:
        o = np.asarray(observation, dtype=np.float64).reshape(1, -1)
        if o.shape[1] < 4:
            raise ValueError(f"observation has {o.shape[1]} entries: expected the env's layout "
                             "(angle, reference, error, last_duty, ...)")
        if self._k == 0:
            self.features.reset_rows(np.array([0]), o[:, :4])
            if self.base is not None:
                self.base.reset_rows([0], o, seed=self._seed)
        else:
            self.features.update(o[:, :4])
            if self.base is not None:
                self.base.update(o)
        if self._k % self.task.action_repeat == 0:
            f = self.features.value(None if self.base is None else self.base.duty)
            a, _ = self.model.predict(self._normalize(f), deterministic=True)
            d = float(np.asarray(a).reshape(-1)[0])
            if not math.isfinite(d):
                raise FloatingPointError(f"{self.name}: the policy returned a non-finite duty ({d!r})")
            self._residual = min(1.0, max(-1.0, d))
        self._k += 1
        if self.base is None:
            self._duty = self._residual
        else:
            self._duty = float(apply_residual(self.base.duty[0], self._residual, self.task))
        return self._duty

    def __repr__(self):
        return f"RLController(name={self.name!r}, algo={self.config.algo!r}, env={self.config.env_id!r})"





_POLICY_CACHE: dict = {}


def _load_policy_cached(path):
    """:func:`_load_policy`, memoized on the resolved path and the files' modification times (the benchmark
    builds a controller per run; the policy itself is stateless, the controller's features are per instance)."""
    p = Path(str(path)).expanduser() if path is not None else None
    key = None
    if p is not None and p.exists():
        files = [p / "model.zip", p / "config.json"] if p.is_dir() else [p, p.parent / "config.json"]
        key = (str(p.resolve()), tuple(f.stat().st_mtime_ns if f.exists() else 0 for f in files))
        hit = _POLICY_CACHE.get(key)
        if hit is not None:
            return hit
    out = _load_policy(path)
    if key is not None:
        _POLICY_CACHE.clear()
        _POLICY_CACHE[key] = out
    return out


def _load_policy(path):
    """(model, config, obs_rms or None, label) from a run folder or a policy zip (config.json beside it)."""
    if path is None or str(path).strip() == "":
        raise ValueError("rl controller: expected a path, e.g. rl:baselines/sac_3b (a run folder or policy .zip)")
    p = Path(str(path)).expanduser()
    if p.is_dir():
        run_dir, zip_path = p, p / "model.zip"
    elif p.suffix == ".zip" or p.with_suffix(".zip").exists():
        zip_path = p if p.suffix == ".zip" else p.with_suffix(".zip")
        run_dir = zip_path.parent
    else:
        raise FileNotFoundError(f"rl controller: {p} does not exist (expected a run folder with model.zip and "
                                "config.json, or a policy .zip with config.json beside it)")
    if not zip_path.exists():
        raise FileNotFoundError(f"rl controller: {zip_path} does not exist")
    cfg = read_config(run_dir)
    cls = algorithm_class(cfg.algo)
    try:
        model = cls.load(str(zip_path), device="cpu")
    except Exception as exc:  # SB3 raises assorted errors for a zip of another algorithm / corrupt file
        raise ValueError(f"rl controller: cannot load {zip_path} as a {cfg.algo.upper()} policy "
                         f"(config.json says algo={cfg.algo!r}): {exc}") from None
    names = feature_names(cfg.task_config)
    n = len(names)
    if tuple(model.observation_space.shape) != (n,):
        raise ValueError(f"rl controller: {zip_path} expects observations of shape {model.observation_space.shape}, "
                         f"this etb_gym builds {n} policy features {names} for its config.json")
    obs_rms = None
    if cfg.normalize:
        stats = run_dir / "vecnormalize.pkl"
        if not stats.exists():
            raise FileNotFoundError(f"rl controller: the run normalized observations but {stats} is missing")
        import pickle

        with open(stats, "rb") as fh:
            vn = pickle.load(fh)
        obs_rms = (vn.obs_rms, vn.clip_obs, vn.epsilon)
    label = f"rl:{run_dir.name}" if zip_path.name == "model.zip" else f"rl:{run_dir.name}/{zip_path.stem}"
    return model, cfg, obs_rms, label


def load_controller(path: str, **kwargs) -> RLController:
    """The ``rl`` prefix loader of :func:`etb_gym.controllers.make_controller`: ``rl:PATH``."""
    unknown = sorted(set(kwargs) - {"name"})
    if unknown:
        raise TypeError(f"rl:{path}: unknown argument(s) {unknown}; valid: ['name']")
    return RLController(path, **kwargs)


def _register() -> None:
    from etb_gym.controllers.base import register_controller_prefix

    register_controller_prefix("rl", load_controller)


_register()

