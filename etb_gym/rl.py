"""Stable-Baselines3 agents on the ETB envs: algorithms, resumable training, evaluation with the benchmark's
metrics, and the policy-as-controller adapter (``make_controller("rl:PATH")``).

    from etb_gym.rl import RunConfig, train, RLController
    train(RunConfig(env_id="ETB-3B-v0", algo="sac", timesteps=200_000, n_envs=4, randomize=True), "runs/sac")
    ctrl = RLController("runs/sac")              # or make_controller("rl:runs/sac")
    duty = ctrl.act(observation)                 # the controller protocol of etb_gym.controllers.base

The MDP the agents learn (features, action repeat, reward, training references) is in
:mod:`etb_gym.rl_task`. A run folder holds::

    config.json           everything needed to rebuild the env, the features and the policy (RunConfig)
    model.zip             final policy (SB3 zip);  best_model.zip: best evaluation score so far
    vecnormalize.pkl      observation/reward statistics (only with normalize=True)
    checkpoints/          periodic and on-interrupt checkpoints (model, replay buffer, statistics) + latest.json
    eval.csv              evaluation history;  eval_reference.json: PID / sliding-mode figures it is scored against
    learning_curve.png    evaluation score and training return over timesteps;  tb/: TensorBoard logs
    status.json           state (running / interrupted / finished), timesteps, accumulated wall time

Evaluation: every ``eval_freq`` transitions the current policy runs as a controller through
``etb_gym.benchmark.simulate`` on the benchmark's scenarios (default its quick set, nominal plant) and is
scored with ``etb_gym.benchmark.metrics``: score = geometric mean over runs of
rms_error_deg(agent) / min(rms_error_deg(PID), rms_error_deg(SMC)) (< 1: better than both classical
controllers, the issue's target is <= 1.2 on every run).
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import shutil
import signal
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .io import write_atomic
from .rl_task import (FEATURE_NAMES, BaseControllers, PolicyFeatures, TaskConfig, TrainingVecEnv,  # noqa: F401
                      apply_residual,
                      feature_names)

RUN_FORMAT = "etb_gym.rl.run/1"
CHECKPOINT_DIR = "checkpoints"
LATEST = "latest.json"
KEEP_CHECKPOINTS = 2

# ------------------------------------------------------------------------------------------------ algorithms
_NET = [64, 64]
_OFF_POLICY = {"learning_rate": 3e-4, "buffer_size": 300_000, "batch_size": 256, "gamma": 0.98, "tau": 0.005,
               "learning_starts": 5_000, "train_freq": 1, "net_arch": _NET}
ALGORITHMS: dict[str, dict] = {
    "sac": {"module": "stable_baselines3", "cls": "SAC", "off_policy": True, "defaults": dict(_OFF_POLICY)},
    "td3": {"module": "stable_baselines3", "cls": "TD3", "off_policy": True,
            "defaults": {**_OFF_POLICY, "action_noise_std": 0.1}},
    "ppo": {"module": "stable_baselines3", "cls": "PPO", "off_policy": False,
            "defaults": {"learning_rate": 3e-4, "n_steps": 1024, "batch_size": 256, "n_epochs": 10, "gamma": 0.98,
                         "gae_lambda": 0.95, "clip_range": 0.2, "ent_coef": 0.0, "net_arch": _NET}},
    "tqc": {"module": "sb3_contrib", "cls": "TQC", "off_policy": True,
            "defaults": {**_OFF_POLICY, "top_quantiles_to_drop_per_net": 2}},
}
# keys of "hyperparams" that are not constructor arguments of the algorithm
_SPECIAL_HP = ("net_arch", "action_noise_std", "utd")


def available_algorithms() -> list[str]:
    out = []
    for name, spec in ALGORITHMS.items():
        try:
            __import__(spec["module"])
        except ImportError:
            continue
        out.append(name)
    return out


def algorithm_class(name: str):
    """The SB3 class of an algorithm name (ValueError listing the valid names)."""
    key = str(name).lower()
    if key not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {name!r}: valid are {available_algorithms()}")
    spec = ALGORITHMS[key]
    try:
        mod = __import__(spec["module"], fromlist=[spec["cls"]])
    except ImportError:
        raise ValueError(f"algorithm {name!r} needs {spec['module']} (pip install {spec['module'].replace('_', '-')}); "
                         f"available: {available_algorithms()}") from None
    return getattr(mod, spec["cls"])


# ------------------------------------------------------------------------------------------------ run config
@dataclass
class RunConfig:
    """A training run: the env, the algorithm and its hyperparameters, the task, evaluation and checkpoints."""

    env_id: str = "ETB-3B-v0"
    algo: str = "sac"
    timesteps: int = 100_000           # policy decisions (transitions) summed over sub-envs
    n_envs: int = 8
    seed: int = 0
    randomize: bool | dict = False     # the env's per-episode randomization: True (its defaults) or
                                       # {quantity: [low, high]} overriding some of its default ranges
    normalize: bool = False            # VecNormalize observations and rewards (see docs/rl.md: off by default)
    task: dict = field(default_factory=dict)
    hyperparams: dict = field(default_factory=dict)   # overrides of ALGORITHMS[algo]["defaults"]
    checkpoint_freq: int = 50_000      # transitions between checkpoints
    eval_freq: int = 10_000            # transitions between evaluations (0: none)
    eval_scenarios: list = field(default_factory=lambda: ["step_10_80", "step_80_10", "small_step_limp_home",
                                                          "small_step_limp_home_neg", "small_step_40",
                                                          "small_step_40_neg", "ramp_10_80", "pedal"])
    eval_variants: list = field(default_factory=lambda: ["nominal"])
    torch_threads: int = 1
    time_limit_s: float = 0.0          # stop (as finished) once the run's accumulated wall time exceeds this (0: none)
    format: str = RUN_FORMAT

    def validate(self) -> "RunConfig":
        from etb_gym.envs import ENV_IDS

        if self.format != RUN_FORMAT:
            raise ValueError(f"config format {self.format!r}: expected {RUN_FORMAT!r}")
        if self.env_id not in ENV_IDS:
            raise ValueError(f"unknown env {self.env_id!r}: valid are {list(ENV_IDS)}")
        self.algo = str(self.algo).lower()
        algorithm_class(self.algo)
        for f in ("timesteps", "n_envs", "checkpoint_freq", "torch_threads"):
            v = getattr(self, f)
            if not (isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1):
                raise ValueError(f"{f} = {v!r} is invalid: expected an integer >= 1")
        if not (isinstance(self.eval_freq, (int, np.integer)) and self.eval_freq >= 0):
            raise ValueError(f"eval_freq = {self.eval_freq!r} is invalid: expected an integer >= 0 (0: no evaluation)")
        if not (isinstance(self.time_limit_s, (int, float)) and math.isfinite(self.time_limit_s)
                and self.time_limit_s >= 0):
            raise ValueError(f"time_limit_s = {self.time_limit_s!r} is invalid: expected seconds >= 0 (0: no limit)")
        if not isinstance(self.randomize, (bool, dict)):
            raise ValueError(f"randomize = {self.randomize!r} is invalid: expected true/false or a dict "
                             "{quantity: [low, high]}")
        if isinstance(self.randomize, dict):
            from etb_gym.envs.env import ETBEnv

            ETBEnv(randomize=self.env_randomization())        # validates names and ranges with the env's messages
        if not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"seed = {self.seed!r} is invalid: expected an integer >= 0")
        TaskConfig.from_dict(self.task)
        from etb_gym.benchmark import SCENARIOS, VARIANTS, check_names

        check_names("scenario", self.eval_scenarios, SCENARIOS)
        check_names("variant", self.eval_variants, VARIANTS)
        defaults = ALGORITHMS[self.algo]["defaults"]
        for k in self.hyperparams:
            if k not in defaults and k not in _SPECIAL_HP and not _accepts(algorithm_class(self.algo), k):
                raise ValueError(f"hyperparameter {k!r} is not understood by {self.algo}: valid are "
                                 f"{sorted(set(defaults) | set(_hp_names(self.algo)))}")
        return self

    def env_randomization(self):
        """The env's ``randomize`` argument: False, True, or its default ranges updated with this dict."""
        if isinstance(self.randomize, dict):
            from etb_gym.envs.env import DEFAULT_RANDOMIZATION

            return {**DEFAULT_RANDOMIZATION, **{k: tuple(v) for k, v in self.randomize.items()}}
        return bool(self.randomize)

    @property
    def task_config(self) -> TaskConfig:
        return TaskConfig.from_dict(self.task)

    def resolved_hyperparams(self) -> dict:
        hp = dict(ALGORITHMS[self.algo]["defaults"])
        hp.update(self.hyperparams)
        if ALGORITHMS[self.algo]["off_policy"]:
            # gradient steps per vector step: update-to-data ratio 0.25 by default (a gradient step costs
            # ~50x a plant step here, so more sub-envs mean more data per gradient step, not more compute)
            hp.setdefault("gradient_steps", max(1, int(round(hp.pop("utd", 0.25) * self.n_envs))))
        return hp

    def to_dict(self) -> dict:
        d = asdict(self)
        d["task"] = self.task_config.to_dict()
        d["hyperparams_resolved"] = self.resolved_hyperparams()
        return d

    @classmethod
    def from_dict(cls, d: Mapping) -> "RunConfig":
        d = dict(d)
        resolved = d.pop("hyperparams_resolved", None)
        if resolved is not None:          # pin the values the run used (defaults may change between versions)
            d["hyperparams"] = {**resolved, **d.get("hyperparams", {})}
        for k in ("versions", "env_dt_s", "features"):
            d.pop(k, None)
        valid = [f.name for f in fields(cls)]
        bad = sorted(set(d) - set(valid))
        if bad:
            raise ValueError(f"run config: unknown field(s) {bad}; valid: {valid}")
        return cls(**d).validate()


def _hp_names(algo):
    import inspect

    return [p for p in inspect.signature(algorithm_class(algo).__init__).parameters if p not in _NOT_HP]


# constructor arguments that the run sets itself (not hyperparameters)
_NOT_HP = ("self", "policy", "env", "_init_setup_model", "policy_kwargs", "device", "seed", "tensorboard_log",
           "verbose", "action_noise")


def _accepts(cls, key):
    import inspect

    return key in inspect.signature(cls.__init__).parameters and key not in _NOT_HP


def _atomic_bytes(path: Path, data: bytes) -> None:
    write_atomic(path, data)


def _atomic_json(path: Path, obj) -> None:
    _atomic_bytes(path, (json.dumps(obj, indent=2, sort_keys=False) + "\n").encode())


def _save_model(model, path: Path) -> None:
    buf = io.BytesIO()
    model.save(buf)
    _atomic_bytes(path, buf.getvalue())


def _save_pickle_of(save_fn, path: Path) -> None:
    """Run an SB3 ``save_*(file)`` into a temporary file, then move it into place."""
    write_atomic(path, save_fn)


def versions() -> dict:
    import gymnasium
    import stable_baselines3
    import torch

    import etb_gym

    return {"etb_gym": getattr(etb_gym, "__version__", "dev"), "stable_baselines3": stable_baselines3.__version__,
            "gymnasium": gymnasium.__version__, "torch": torch.__version__}


# ------------------------------------------------------------------------------------------------ env + model
def make_training_env(cfg: RunConfig, seed: int | None = None, normalize_stats: Path | None = None):
    """The SB3 VecEnv of a run: :class:`TrainingVecEnv` (native vector env) in a VecMonitor, and VecNormalize
    when ``cfg.normalize`` (loaded from ``normalize_stats`` when resuming)."""
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    env = VecMonitor(TrainingVecEnv(cfg.env_id, cfg.n_envs, cfg.task_config, seed=cfg.seed if seed is None else seed,
                                    randomize=cfg.env_randomization()))
    if cfg.normalize:
        if normalize_stats is not None:
            env = VecNormalize.load(str(normalize_stats), env)
            env.training = True
        else:
            env = VecNormalize(env, norm_obs=True, norm_reward=True, gamma=cfg.resolved_hyperparams()["gamma"])
    return env


def make_model(cfg: RunConfig, env, tensorboard_log: str | None):
    cls = algorithm_class(cfg.algo)
    hp = cfg.resolved_hyperparams()
    net = hp.pop("net_arch", _NET)
    noise_std = hp.pop("action_noise_std", None)
    hp.pop("utd", None)
    kw = dict(hp)
    if cfg.algo == "ppo":
        kw["policy_kwargs"] = {"net_arch": {"pi": list(net), "vf": list(net)}}
    else:
        kw["policy_kwargs"] = {"net_arch": list(net)}
    if noise_std:
        from stable_baselines3.common.noise import NormalActionNoise

        kw["action_noise"] = NormalActionNoise(np.zeros(1), np.full(1, float(noise_std)))
    model = cls("MlpPolicy", env, seed=cfg.seed, device="cpu", tensorboard_log=tensorboard_log, verbose=0, **kw)
    if cfg.task_config.residual:
        zero_policy_mean(model)
    return model


def zero_policy_mean(model) -> None:
    """Residual mode: zero the policy's output layer (the mean action of SAC / TQC / PPO, the deterministic
    action of TD3), so the untrained agent's deterministic residual is exactly 0: it starts as the base
    controller. The hidden layers keep their random initialization, so gradients still flow."""
    import torch

    pol = model.policy
    layers = []
    if hasattr(pol, "actor") and hasattr(pol.actor, "mu"):                  # SAC, TQC, TD3
        mu = pol.actor.mu
        layers.append(mu if isinstance(mu, torch.nn.Linear) else [m for m in mu if isinstance(m, torch.nn.Linear)][-1])
        if hasattr(pol, "actor_target"):                                   # TD3 keeps a target copy
            tm = pol.actor_target.mu
            layers.append(tm if isinstance(tm, torch.nn.Linear) else [m for m in tm if isinstance(m, torch.nn.Linear)][-1])
    elif hasattr(pol, "action_net"):                                        # PPO
        layers.append(pol.action_net)
    with torch.no_grad():
        for layer in layers:
            layer.weight.zero_()
            layer.bias.zero_()


# ------------------------------------------------------------------------------------------------ controller
class RLController:
    """A trained policy under the controller protocol (``name``, ``dt``, ``reset(seed)``, ``act(obs) -> duty``).

    ``RLController(path)``: a run folder (``model.zip`` + ``config.json``) or a policy zip with ``config.json``
    beside it. The controller rebuilds the training features (:class:`~etb_gym.rl_task.PolicyFeatures`) from
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
        self.dt = _env_dt(config.env_id)
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


def _env_dt(env_id: str) -> float:
    from etb_gym.benchmark import model_of
    from etb_gym.plant import make_plant

    return make_plant(model_of(env_id)).control_period_s


def read_config(run_dir: Path) -> RunConfig:
    p = Path(run_dir) / "config.json"
    if not p.exists():
        raise FileNotFoundError(f"{run_dir}: no config.json (not an etb_gym RL run folder or policy folder)")
    try:
        d = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{p}: not valid JSON ({exc})") from None
    return RunConfig.from_dict(d)


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


# ------------------------------------------------------------------------------------------------ evaluation
def _eval_jobs(cfg: RunConfig, controller: str):
    from etb_gym.benchmark import make_jobs

    return make_jobs([controller], cfg.eval_scenarios, cfg.eval_variants, [0], env_id=cfg.env_id)


def evaluate_controller(ctrl, cfg: RunConfig, label: str) -> dict:
    """{(scenario, variant): benchmark metrics} of one controller on the run's evaluation jobs (seed 0)."""
    from etb_gym.benchmark import SCENARIOS, metrics, simulate

    out = {}
    for job in _eval_jobs(cfg, label):
        trace, _ = simulate(job, controller=ctrl)
        out[(job.scenario, job.variant)] = metrics(trace, SCENARIOS[job.scenario])
    return out


def classical_reference(cfg: RunConfig, cache: Path | None = None) -> dict:
    """{"scenario/variant": {"pid": rms, "smc": rms, "best": min}} on the evaluation jobs (cached in ``cache``)."""
    if cache is not None and cache.exists():
        ref = json.loads(cache.read_text())
        want = {f"{s}/{v}" for s in cfg.eval_scenarios for v in cfg.eval_variants}
        if want <= set(ref):
            return ref
    from etb_gym.benchmark import build_controller

    ref: dict = {}
    for name in ("pid", "smc"):
        ctrl = build_controller(name, cfg.env_id)
        for (s, v), m in evaluate_controller(ctrl, cfg, name).items():
            ref.setdefault(f"{s}/{v}", {})[name] = m["rms_error_deg"]
    for r in ref.values():
        r["best"] = min(r["pid"], r["smc"])
    if cache is not None:
        _atomic_json(cache, ref)
    return ref


def score_of(rms: Mapping[str, float], ref: Mapping[str, Mapping]) -> float:
    """Geometric mean of rms / best-classical rms over the evaluation runs (inf if any run is non-finite)."""
    logs = []
    for k, v in rms.items():
        if not math.isfinite(v):
            return math.inf
        logs.append(math.log(max(v, 1e-9) / max(ref[k]["best"], 1e-9)))
    return float(math.exp(np.mean(logs))) if logs else math.nan


EVAL_COLUMNS = ("timesteps", "wall_time_s", "score", "worst_ratio", "train_return")


def read_eval_csv(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with open(path, newline="") as fh:
        return [{k: float(v) for k, v in r.items()} for r in csv.DictReader(fh)]


def write_eval_csv(path: Path, rows: list[dict]) -> None:
    cols = list(EVAL_COLUMNS) + sorted({k for r in rows for k in r} - set(EVAL_COLUMNS))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols)
    w.writeheader()
    for r in rows:
        w.writerow({c: (f"{r[c]:.6g}" if isinstance(r.get(c), float) else r.get(c, "")) for c in cols})
    _atomic_bytes(path, buf.getvalue().encode())


# ------------------------------------------------------------------------------------------------ callbacks
class TrainingInterrupted(KeyboardInterrupt):
    """Raised out of ``learn`` after the on-interrupt checkpoint has been written."""


class _TimeLimit(Exception):
    """Ends ``learn`` at a rollout boundary once the run's wall-time budget is spent (then finished normally)."""


def _callbacks():
    from stable_baselines3.common.callbacks import BaseCallback

    class RunCallback(BaseCallback):
        """Periodic checkpoints (model, replay buffer, VecNormalize statistics, eval state; atomic, with a
        ``latest.json`` pointer written last), evaluations with the benchmark's metrics (TensorBoard
        ``eval/*``, ``eval.csv``, ``best_model.zip``) and the on-interrupt checkpoint.

        All three happen at the start of a rollout: there the replay buffer holds exactly ``num_timesteps``
        transitions and the gradient steps of the previous rollout are done, so a checkpoint loses nothing
        (SB3 calls ``on_step`` before it stores the step's transition)."""

        def __init__(self, run: "Run"):
            super().__init__(verbose=0)
            self.run = run
            self.next_ckpt = None
            self.next_eval = None

        def _on_training_start(self):
            r, n = self.run, self.model.num_timesteps
            self.next_ckpt = (n // r.cfg.checkpoint_freq + 1) * r.cfg.checkpoint_freq
            self.next_eval = (n // r.cfg.eval_freq + 1) * r.cfg.eval_freq if r.cfg.eval_freq else None

        def _on_rollout_start(self) -> None:
            run, n = self.run, self.model.num_timesteps
            if run.stop_requested:
                path = run.checkpoint(self.model, tag="_interrupted")
                run.write_status("interrupted", n)
                raise TrainingInterrupted(f"interrupted at {n} timesteps: checkpoint {path}")
            if self.next_eval is not None and n >= self.next_eval:
                run.evaluate(self.model, self.logger)
                self.next_eval = (n // run.cfg.eval_freq + 1) * run.cfg.eval_freq
            if n >= self.next_ckpt:
                run.checkpoint(self.model)
                self.next_ckpt = (n // run.cfg.checkpoint_freq + 1) * run.cfg.checkpoint_freq
            if run.cfg.time_limit_s and run.wall_time_s >= run.cfg.time_limit_s:
                run.time_limited = True
                raise _TimeLimit()

        def _on_step(self) -> bool:
            for info in self.locals.get("infos", ()):
                ep = info.get("episode")
                if ep is not None:
                    self.run.returns.append(float(ep["r"]))
            return True

    return RunCallback


# ------------------------------------------------------------------------------------------------ training
class Run:
    """State of one training run folder (see the module docstring for its files)."""

    def __init__(self, cfg: RunConfig, out: Path):
        self.cfg, self.out = cfg, Path(out)
        self.ckpt_dir = self.out / CHECKPOINT_DIR
        self.returns: list[float] = []
        self.eval_rows = read_eval_csv(self.out / "eval.csv")
        self.best = min([r["score"] for r in self.eval_rows if math.isfinite(r["score"])], default=math.inf)
        self.wall0 = time.perf_counter()
        self.wall_before = 0.0
        self._ref = None
        self.env = None
        self.stop_requested = False
        self.time_limited = False

    @property
    def wall_time_s(self) -> float:
        return self.wall_before + time.perf_counter() - self.wall0

    # -- status
    def write_status(self, state: str, timesteps: int) -> None:
        _atomic_json(self.out / "status.json", {"state": state, "timesteps": int(timesteps),
                                                 "target_timesteps": self.cfg.timesteps,
                                                 "wall_time_s": round(self.wall_time_s, 1),
                                                 "best_score": self.best if math.isfinite(self.best) else None})

    # -- evaluation
    def reference(self):
        if self._ref is None:
            self._ref = classical_reference(self.cfg, self.out / "eval_reference.json")
        return self._ref

    def _obs_rms(self):
        from stable_baselines3.common.vec_env import VecNormalize

        if isinstance(self.env, VecNormalize):
            return (self.env.obs_rms, self.env.clip_obs, self.env.epsilon)
        return None

    def evaluate(self, model, logger=None) -> dict:
        ref = self.reference()
        ctrl = RLController(model=model, config=self.cfg, obs_rms=self._obs_rms(), name="rl")
        res = evaluate_controller(ctrl, self.cfg, "rl")
        rms = {f"{s}/{v}": m["rms_error_deg"] for (s, v), m in res.items()}
        score = score_of(rms, ref)
        ratios = {k: v / max(ref[k]["best"], 1e-9) for k, v in rms.items()}
        row = {"timesteps": float(model.num_timesteps), "wall_time_s": self.wall_time_s, "score": score,
               "worst_ratio": max(ratios.values()),
               "train_return": float(np.mean(self.returns[-20:])) if self.returns else math.nan}
        row.update({f"rms/{k}": v for k, v in rms.items()})
        self.eval_rows.append(row)
        write_eval_csv(self.out / "eval.csv", self.eval_rows)
        if logger is not None:
            logger.record("eval/score", score)
            logger.record("eval/worst_ratio", row["worst_ratio"])
            for k, v in rms.items():
                logger.record(f"eval/rms_{k.replace('/', '_')}", v)
        if score < self.best:
            self.best = score
            _save_model(model, self.out / "best_model.zip")
            if self.cfg.normalize:
                _save_pickle_of(lambda fh: _dump(self.env, fh), self.out / "best_vecnormalize.pkl")
        return row

    # -- checkpoints
    def checkpoint(self, model, tag: str = "") -> Path:
        n = int(model.num_timesteps)
        base = f"ckpt_{n}{tag}"
        self.ckpt_dir.mkdir(parents=True, exist_ok=True)
        _save_model(model, self.ckpt_dir / f"{base}.zip")
        entry = {"timesteps": n, "model": f"{base}.zip", "replay_buffer": None, "vecnormalize": None,
                 "env_id": self.cfg.env_id, "algo": self.cfg.algo, "wall_time_s": round(self.wall_time_s, 1),
                 "best_score": self.best if math.isfinite(self.best) else None, "time": time.time()}
        if ALGORITHMS[self.cfg.algo]["off_policy"]:
            _save_pickle_of(model.save_replay_buffer, self.ckpt_dir / f"{base}_replay_buffer.pkl")
            entry["replay_buffer"] = f"{base}_replay_buffer.pkl"
        if self.cfg.normalize:
            _save_pickle_of(lambda fh: _dump(self.env, fh), self.ckpt_dir / f"{base}_vecnormalize.pkl")
            entry["vecnormalize"] = f"{base}_vecnormalize.pkl"
        _atomic_json(self.ckpt_dir / LATEST, entry)
        self._prune(entry)
        self.write_status("running", n)
        return self.ckpt_dir / entry["model"]

    def _prune(self, latest):
        """Keep the newest KEEP_CHECKPOINTS checkpoints (the one latest.json names always survives)."""
        zips = sorted(self.ckpt_dir.glob("ckpt_*.zip"), key=lambda p: p.stat().st_mtime)
        for old in zips[:-KEEP_CHECKPOINTS]:
            stem = old.stem
            if old.name == latest["model"]:
                continue
            for f in self.ckpt_dir.glob(stem + "*"):
                if f.name.startswith(stem + "_") or f.name == old.name:
                    f.unlink(missing_ok=True)

    def latest(self) -> dict:
        p = self.ckpt_dir / LATEST
        if not p.exists():
            raise FileNotFoundError(f"{self.out}: no checkpoint to resume from ({p} is missing; the run was "
                                    "interrupted before its first checkpoint, start it again with --force)")
        entry = json.loads(p.read_text())
        for key in ("model", "replay_buffer", "vecnormalize"):
            if entry.get(key) and not (self.ckpt_dir / entry[key]).exists():
                raise FileNotFoundError(f"{self.out}: checkpoint file {self.ckpt_dir / entry[key]} named by "
                                        f"{p} is missing")
        if entry.get("env_id") != self.cfg.env_id or entry.get("algo") != self.cfg.algo:
            raise ValueError(f"{p}: checkpoint of env {entry.get('env_id')!r} / algo {entry.get('algo')!r} does not "
                             f"match the run's config.json ({self.cfg.env_id!r} / {self.cfg.algo!r})")
        return entry

    # -- final outputs
    def finish(self, model) -> None:
        _save_model(model, self.out / "model.zip")
        if self.cfg.normalize:
            _save_pickle_of(lambda fh: _dump(self.env, fh), self.out / "vecnormalize.pkl")
        if self.eval_rows:
            plot_learning_curve(self.eval_rows, self.out / "learning_curve.png", title=_curve_title(self.cfg))


def _dump(obj, fh):
    import pickle

    pickle.dump(obj, fh)


def prepare_output(out: Path, force: bool) -> None:
    """A fresh run folder: refuse to touch an existing non-empty folder unless ``force`` (and then only if it is
    an RL run folder: it holds config.json)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"--out {out}: exists and is not a folder")
    if out.exists() and any(out.iterdir()):
        if not force:
            raise FileExistsError(f"--out {out}: the folder exists and is not empty; pass --force to replace it, "
                                  f"or --resume {out} to continue its run")
        if not (out / "config.json").exists():
            raise FileExistsError(f"--out {out}: not an RL run folder (no config.json); refusing to delete it even "
                                  "with --force")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)


def check_resume(saved: RunConfig, requested: Mapping[str, Any]) -> None:
    """Raise if an explicitly requested setting contradicts the run being resumed."""
    for key in ("env_id", "algo", "n_envs", "randomize", "normalize"):
        v = requested.get(key)
        if key == "randomize" and v is True and saved.randomize:
            continue                      # --randomize on resume of a run with (custom) randomization
        if v is not None and (str(v).lower() if key == "algo" else v) != getattr(saved, key):
            raise ValueError(f"--resume: the checkpoint was trained with {key}={getattr(saved, key)!r}, not {v!r} "
                             "(incompatible checkpoint; start a new run with --out instead)")


def train(cfg: RunConfig | None, out, *, resume: bool = False, force: bool = False, requested: Mapping | None = None,
          timesteps: int | None = None, time_limit_s: float | None = None, callbacks: Sequence = (),
          progress: bool = True, log=print):
    """Train (or, with ``resume``, continue) the run in folder ``out``; returns the model.

    New run: ``cfg`` is validated, ``out`` prepared (see :func:`prepare_output`), ``config.json`` written.
    Resume: the config comes from ``out/config.json`` (``requested`` settings must agree with it), the latest
    checkpoint's model, replay buffer and normalization statistics are loaded and training continues to
    ``timesteps`` (default: the config's; ``time_limit_s`` replaces the wall-time budget, which counts the
    whole run) without resetting the step counter. Ctrl-C / SIGTERM save a
    checkpoint first, then re-raise KeyboardInterrupt."""
    import torch

    out = Path(out)
    if resume:
        if not out.is_dir():
            raise FileNotFoundError(f"--resume {out}: no such run folder")
        cfg = read_config(out)
        check_resume(cfg, requested or {})
        if timesteps is not None:
            cfg.timesteps = int(timesteps)
        if time_limit_s is not None:      # a new budget for the accumulated wall time (0: none)
            cfg.time_limit_s = float(time_limit_s)
        cfg.validate()
    else:
        cfg = cfg.validate()
        prepare_output(out, force)
    torch.set_num_threads(cfg.torch_threads)
    run = Run(cfg, out)
    cls = algorithm_class(cfg.algo)
    if resume:
        entry = run.latest()
        run.wall_before = float(entry.get("wall_time_s") or 0.0)
        n0 = int(entry["timesteps"])
        run.eval_rows = [r for r in run.eval_rows if r["timesteps"] <= n0]
        run.best = entry["best_score"] if entry.get("best_score") is not None else math.inf
        stats = run.ckpt_dir / entry["vecnormalize"] if entry.get("vecnormalize") else None
        run.env = make_training_env(cfg, seed=cfg.seed + n0, normalize_stats=stats)
        model = cls.load(str(run.ckpt_dir / entry["model"]), env=run.env, device="cpu",
                         tensorboard_log=str(out / "tb"))
        if entry.get("replay_buffer"):
            model.load_replay_buffer(str(run.ckpt_dir / entry["replay_buffer"]))
        log(f"resuming {cfg.algo.upper()} on {cfg.env_id} from {entry['model']} at {model.num_timesteps} timesteps"
            f" -> {cfg.timesteps}")
    else:
        d = cfg.to_dict()
        d["env_dt_s"] = _env_dt(cfg.env_id)
        d["features"] = list(feature_names(cfg.task_config))
        d["versions"] = versions()
        _atomic_json(out / "config.json", d)
        run.env = make_training_env(cfg)
        model = make_model(cfg, run.env, str(out / "tb"))
        if cfg.eval_freq:
            run.reference()
    remaining = cfg.timesteps - model.num_timesteps
    cb = [_callbacks()(run), *callbacks]
    handlers = {}

    def request_stop(signum, frame):
        if run.stop_requested:            # a second Ctrl-C: stop at once (no checkpoint)
            raise KeyboardInterrupt
        run.stop_requested = True
        log(f"signal {signum}: stopping at the next rollout boundary after a checkpoint (again to abort)")

    if _in_main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            handlers[sig] = signal.signal(sig, request_stop)
    run.write_status("running", model.num_timesteps)
    try:
        if remaining > 0:
            model.learn(total_timesteps=remaining, callback=cb, reset_num_timesteps=not resume, tb_log_name="run",
                        progress_bar=progress)
    except _TimeLimit:
        log(f"time limit {cfg.time_limit_s:g} s reached at {model.num_timesteps} timesteps")
    except TrainingInterrupted as exc:
        if run.eval_rows:
            plot_learning_curve(run.eval_rows, out / "learning_curve.png", title=_curve_title(cfg))
        log(f"{exc}; continue with --resume {out}")
        run.env.close()
        raise
    finally:
        for sig, h in handlers.items():
            signal.signal(sig, h)
    if cfg.eval_freq and (not run.eval_rows or run.eval_rows[-1]["timesteps"] < model.num_timesteps):
        run.evaluate(model)
    run.checkpoint(model)
    run.finish(model)
    run.write_status("finished (time limit)" if run.time_limited else "finished", model.num_timesteps)
    run.env.close()
    return model


def _in_main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


# ------------------------------------------------------------------------------------------------ plots
def _curve_title(cfg: RunConfig) -> str:
    task = cfg.task_config
    res = f" (residual on {task.residual}, scale {task.residual_scale:g})" if task.residual else ""
    return f"{cfg.algo.upper()}{res} on {cfg.env_id}"


def plot_learning_curve(rows: list[dict], path: Path, title: str = "") -> None:
    """Evaluation score (geometric-mean RMS ratio to the better classical controller) and training return."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.array([r["timesteps"] for r in rows])
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True, constrained_layout=True)
    keys = sorted({k for r in rows for k in r if k.startswith("rms/")})
    a1.plot(x, [r["score"] for r in rows], "k-o", ms=3, lw=2, label="score (geometric mean)")
    a1.plot(x, [r["worst_ratio"] for r in rows], "-", color="tab:red", lw=1, label="worst scenario")
    a1.axhline(1.0, color="tab:green", ls="--", lw=1, label="better of PID / SMC")
    a1.axhline(1.2, color="tab:orange", ls=":", lw=1, label="target 1.2x")
    a1.set_yscale("log")
    a1.set_ylabel("RMS error / best classical")
    a1.legend(fontsize=7, loc="upper right")
    a1.set_title((title + "\n" if title else "") + f"{len(keys)} benchmark runs per evaluation", fontsize=10)
    a1.grid(alpha=0.3, which="both")
    a2.plot(x, [r["train_return"] for r in rows], "-", color="tab:blue")
    a2.set_ylabel("training episode return\n(mean of last 20)")
    a2.set_xlabel("timesteps (policy decisions)")
    a2.grid(alpha=0.3)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    _atomic_bytes(Path(path), buf.getvalue())


# ------------------------------------------------------------------------------------------------ comparison
def rms_comparison(rows: Sequence[Mapping], agent: str, others: Sequence[str] = ("pid", "smc")) -> tuple[str, list]:
    """The issue's target table from benchmark rows (``etb_gym.benchmark.read_results``): per scenario and
    variant the RMS tracking error of ``agent`` and of the classical controllers (means over seeds), and
    ratio = agent / min(others). Returns (Markdown, list of dict rows)."""
    from collections import defaultdict

    others = [c for c in others if c != agent]
    acc = defaultdict(list)
    for r in rows:
        acc[(r["env"], r["scenario"], r["variant"], r["controller"])].append(float(r["rms_error_deg"]))
    keys = sorted({(e, s, v) for e, s, v, c in acc if c == agent},
                  key=lambda k: (k[0], k[2] != "nominal", k[2], k[1]))
    if not keys:
        raise ValueError(f"no benchmark rows for controller {agent!r}: controllers present are "
                         f"{sorted({c for *_, c in acc})}")
    table = []
    for e, s, v in keys:
        row = {"env": e, "scenario": s, "variant": v, agent: float(np.mean(acc[(e, s, v, agent)]))}
        for c in others:
            row[c] = float(np.mean(acc[(e, s, v, c)])) if (e, s, v, c) in acc else math.nan
        best = min((row[c] for c in others if math.isfinite(row[c])), default=math.nan)
        row["ratio"] = row[agent] / best if math.isfinite(best) and best > 0 else math.nan
        table.append(row)
    ratios = np.array([r["ratio"] for r in table])
    ok = ratios <= 1.2
    better = ratios < 1.0
    lines = [f"# RMS tracking error: {agent} vs {' / '.join(others)}", "",
             f"ratio = RMS({agent}) / min(RMS of {', '.join(others)}); target <= 1.2 everywhere, < 1 somewhere.",
             "", f"**{int(ok.sum())}/{len(table)}** runs within 1.2x, **{int(better.sum())}/{len(table)}** better than "
             f"both (nominal: {int(sum(o for o, r in zip(ok, table) if r['variant'] == 'nominal'))}/"
             f"{sum(r['variant'] == 'nominal' for r in table)} within 1.2x; geometric-mean ratio "
             f"{float(np.exp(np.mean(np.log(np.clip(ratios, 1e-9, None))))):.3g}).", "",
             f"| scenario | variant | {agent} [deg] | " + " | ".join(f"{c} [deg]" for c in others) + " | ratio | |",
             "|---|---|---|" + "---|" * len(others) + "---|---|"]
    for r in table:
        mark = "better than both" if r["ratio"] < 1.0 else ("within 1.2x" if r["ratio"] <= 1.2 else "**miss**")
        lines.append(f"| {r['scenario']} | {r['variant']} | {r[agent]:.4g} | "
                     + " | ".join(f"{r[c]:.4g}" for c in others) + f" | {r['ratio']:.3g} | {mark} |")
    return "\n".join(lines) + "\n", table


def main(argv=None) -> int:
    """``python -m etb_gym.rl compare OUT/results.csv --agent rl:DIR [--md FILE] [--csv FILE]``."""
    import argparse

    p = argparse.ArgumentParser(prog="python -m etb_gym.rl", description="RL helpers: the RMS comparison table")
    sub = p.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("compare", help="RMS tracking error of an agent vs PID and SMC from benchmark results.csv")
    c.add_argument("results", help="results.csv of scripts/benchmark.py")
    c.add_argument("--agent", required=True, help="the agent's controller spec as in results.csv, e.g. rl:DIR")
    c.add_argument("--md", default=None, help="write the Markdown table here")
    c.add_argument("--csv", default=None, help="write the table rows here")
    a = p.parse_args(argv)
    from etb_gym.benchmark import read_results

    md, table = rms_comparison(read_results(a.results), a.agent)
    print(md)
    if a.md:
        _atomic_bytes(Path(a.md), md.encode())
    if a.csv:
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=list(table[0]))
        w.writeheader()
        w.writerows(table)
        _atomic_bytes(Path(a.csv), buf.getvalue().encode())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
