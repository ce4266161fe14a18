"""Algorithms and the run configuration: the SB3 algorithm registry with its default hyperparameters, the
:class:`RunConfig` of a training run (validated before anything is written), the model factory.

    from etb_gym.rl import RunConfig
    cfg = RunConfig(env_id="ETB-3B-v0", algo="sac", hyperparams={"gamma": 0.99}).validate()

Every hyperparameter override is checked here, with a sentence naming the option, the value and what is
expected (``--hp gamma=1.5``: a discount factor in (0, 1]), so a bad value never reaches SB3 or a run folder.
"""
from __future__ import annotations

import inspect
import json
import math
from pathlib import Path
from dataclasses import asdict, dataclass, field, fields
from typing import Mapping

import numpy as np

from .task import TaskConfig

RUN_FORMAT = "etb_gym.rl.run/1"


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
        validate_hyperparams(self.algo, self.hyperparams, self.n_envs)
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
    return [p for p in inspect.signature(algorithm_class(algo).__init__).parameters if p not in _NOT_HP]


# constructor arguments that the run sets itself (not hyperparameters)
_NOT_HP = ("self", "policy", "env", "_init_setup_model", "policy_kwargs", "device", "seed", "tensorboard_log",
           "verbose", "action_noise")


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _is_num(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and math.isfinite(v)


def _ent_coef(v) -> bool:
    if isinstance(v, str):
        if v == "auto":
            return True
        if v.startswith("auto_"):
            try:
                return float(v[5:]) > 0
            except ValueError:
                return False
        return False
    return _is_num(v) and v >= 0


# hyperparameter -> (check, what is expected); other constructor arguments are checked against the type of
# their default value in the algorithm's signature
HP_RULES = {
    "learning_rate": (lambda v: _is_num(v) and v > 0, "a learning rate > 0"),
    "buffer_size": (lambda v: _is_int(v) and v >= 1, "an integer >= 1 (transitions)"),
    "batch_size": (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
    "gamma": (lambda v: _is_num(v) and 0 < v <= 1, "a discount factor in (0, 1]"),
    "tau": (lambda v: _is_num(v) and 0 < v <= 1, "a soft-update coefficient in (0, 1]"),
    "learning_starts": (lambda v: _is_int(v) and v >= 0, "an integer >= 0 (transitions)"),
    "train_freq": (lambda v: _is_int(v) and v >= 1, "an integer >= 1 (steps)"),
    "gradient_steps": (lambda v: _is_int(v) and (v >= 1 or v == -1),
                       "an integer >= 1 (or -1: one per collected transition)"),
    "net_arch": (lambda v: isinstance(v, (list, tuple)) and len(v) > 0 and all(_is_int(u) and u >= 1 for u in v),
                 "a list of layer widths, e.g. [64, 64]"),
    "action_noise_std": (lambda v: _is_num(v) and v >= 0, "a noise standard deviation >= 0 (duty)"),
    "utd": (lambda v: _is_num(v) and v > 0, "an update-to-data ratio > 0"),
    "n_steps": (lambda v: _is_int(v) and v >= 1, "an integer >= 1 (steps per sub-env and rollout)"),
    "n_epochs": (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
    "gae_lambda": (lambda v: _is_num(v) and 0 <= v <= 1, "a number in [0, 1]"),
    "clip_range": (lambda v: _is_num(v) and v > 0, "a number > 0"),
    "ent_coef": (_ent_coef, "a number >= 0 (SAC / TQC also 'auto' or 'auto_<initial value>')"),
    "vf_coef": (lambda v: _is_num(v) and v >= 0, "a number >= 0"),
    "max_grad_norm": (lambda v: _is_num(v) and v > 0, "a number > 0"),
    "top_quantiles_to_drop_per_net": (lambda v: _is_int(v) and v >= 0, "an integer >= 0"),
    "policy_delay": (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
    "target_policy_noise": (lambda v: _is_num(v) and v >= 0, "a number >= 0"),
    "target_noise_clip": (lambda v: _is_num(v) and v >= 0, "a number >= 0"),
    "target_update_interval": (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
}


def _show(v) -> str:
    """A value as the user would type it after ``--hp KEY=`` (no Python or numpy reprs)."""
    if isinstance(v, str):
        return v
    try:
        return json.dumps(v.tolist() if hasattr(v, "tolist") else v)
    except (TypeError, ValueError):
        return str(v)


def _by_default_type(cls, key):
    """(check, expectation) from the type of the constructor's default value, or None."""
    p = inspect.signature(cls.__init__).parameters.get(key)
    if p is None or p.default is inspect.Parameter.empty:
        return None
    d = p.default
    if isinstance(d, bool):
        return (lambda v: isinstance(v, bool)), "true or false"
    if isinstance(d, int):
        return _is_int, "an integer"
    if isinstance(d, float):
        return _is_num, "a finite number"
    return None


def validate_hyperparams(algo: str, hyperparams: Mapping, n_envs: int = 1) -> None:
    """Raise ValueError (a sentence naming the option, the value and the expectation) for the first invalid
    hyperparameter override of ``algo``; unknown keys list the valid ones."""
    cls = algorithm_class(algo)
    defaults = ALGORITHMS[algo]["defaults"]
    if not isinstance(hyperparams, Mapping):
        raise ValueError(f"hyperparams = {hyperparams!r} is invalid: expected a mapping of names to values")
    for k, v in hyperparams.items():
        if k not in defaults and k not in _SPECIAL_HP and not _accepts(cls, k):
            raise ValueError(f"--hp {k}={_show(v)}: {k!r} is not a hyperparameter of {algo}; valid are "
                             f"{', '.join(sorted(set(defaults) | set(_hp_names(algo))))}")
        rule = HP_RULES.get(k) or _by_default_type(cls, k)
        if rule is not None and not rule[0](v):
            raise ValueError(f"--hp {k}={_show(v)} is invalid for {algo}: expected {rule[1]}")
    hp = {**defaults, **hyperparams}
    if ALGORITHMS[algo]["off_policy"] and hp["batch_size"] > hp["buffer_size"]:
        raise ValueError(f"--hp batch_size={_show(hp['batch_size'])} is invalid for {algo}: expected at most "
                         f"buffer_size ({_show(hp['buffer_size'])})")
    if algo == "ppo" and hp["n_steps"] * n_envs < 2:
        raise ValueError(f"--hp n_steps={_show(hp['n_steps'])} is invalid for ppo with {n_envs} sub-env(s): expected "
                         "n_steps * n_envs >= 2 (PPO normalizes advantages over a rollout)")


def _accepts(cls, key):
    return key in inspect.signature(cls.__init__).parameters and key not in _NOT_HP


def env_dt(env_id: str) -> float:
    """The control period [s] of a registered ETB env id (its model's default)."""
    from etb_gym.benchmark import model_of
    from etb_gym.plant import make_plant

    return make_plant(model_of(env_id)).control_period_s


def versions() -> dict:
    import gymnasium
    import stable_baselines3
    import torch

    import etb_gym

    return {"etb_gym": getattr(etb_gym, "__version__", "dev"), "stable_baselines3": stable_baselines3.__version__,
            "gymnasium": gymnasium.__version__, "torch": torch.__version__}


def read_config(run_dir: Path) -> RunConfig:
    p = Path(run_dir) / "config.json"
    if not p.exists():
        raise FileNotFoundError(f"{run_dir}: no config.json (not an etb_gym RL run folder or policy folder)")
    try:
        d = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{p}: not valid JSON ({exc})") from None
    return RunConfig.from_dict(d)



# ------------------------------------------------------------------------------------------------ model
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

