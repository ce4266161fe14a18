"""The RL task on top of the ETB envs: policy features, action repeat, training reward and training references.

One implementation serves training and deployment: :class:`PolicyFeatures` turns the env's observation
stream (``etb_gym.envs.observation``: sensed angle, reference, error, last duty) into the policy input, both
inside the training wrappers (:mod:`etb_gym.rl.wrappers`, N sub-envs of ``gym.make_vec(env_id)``) and inside
the deployed controller (:class:`etb_gym.rl.controller.RLController`, N = 1), so the policy sees the same
numbers in the benchmark as in training. This module holds the pieces (no Gymnasium or SB3 imports); the
wrappers compose them around the registered env.

Features (all updated every 1 ms control period from the observation, read at decision times)::

    e      = r - y_sensed [deg]
    v      = filtered derivative of y_sensed [deg/s]   (controllers.base.VelocityEstimator, 300 rad/s)
    v_r    = filtered derivative of r [deg/s]          (same estimator, 100 rad/s: ramp / pedal rate)
    z      = leaky integral of clip(e, +-1 deg)        z_k = a z_{k-1} + T clip(e_k), a = exp(-T / 0.1 s)

    features = [ (y-45)/45, (r-45)/45, e/45, tanh(e/0.25), tanh(e/3), tanh((y-3)/1), d_prev,
                 tanh(v/50), tanh(v/1000), tanh(v_r/200), tanh(z/0.02) ]

The fine error scales (0.25 deg, limp-home distance 1 deg) let a small network resolve the sub-degree errors
that the benchmark's 0.5 deg steps need, next to the 70 deg transients.

Action repeat ``k``: the policy decides every k control periods and the duty is held in between (the env
still runs at 1 ms). Training reward per decision (true plate angle, e = r - phi, averaged over the k
periods, d the new duty, d_prev the previous decision)::

    reward = -( w_lin |e|/45 + w_log ln(1 + |e|/e0) / ln(1 + 45/e0) ) - w_rate ((d - d_prev)/2)^2

The linear term rewards a fast slew on large steps, the logarithmic one precision below a degree (its slope
is 1/(e0 + |e|)); the env's own reward is not used.

Residual mode (``task.residual = "smc"`` / ``"pid"`` / ``"pid-plain"``, residual reinforcement learning,
Silver et al. 2018, Johannink et al. 2019): a classical base controller (the built-in one of that name,
designed on the env's nominal model by ``etb_gym.benchmark.build_controller``) runs every control period on
the same observation stream, and the policy's action a in [-1, 1] is a bounded correction::

    duty = clip(d_base + residual_scale * a, -1, 1)

The base keeps its integral action and its stability margins; the policy learns to improve transients and
robustness. The policy input gets one more feature, ``base_duty`` (the base controller's duty for the coming
period), the rate penalty acts on the residual residual_scale * (a - a_prev), and ``w_residual a^2`` is
subtracted from the reward so the residual stays at zero where it does not help. With a residual the
policy's mean output starts at exactly zero (etb_gym.rl.config.zero_policy_mean zeroes its output layer), so the untrained agent
is the base controller. Training references (:func:`draw_reference`) chain
large steps, small steps anywhere (incl. 40 deg), small steps across limp-home and ramps, from a plate at
rest at a drawn angle, so every benchmark scenario type appears in training.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Mapping

import numpy as np

from etb_gym.controllers.base import VelocityEstimator
from etb_gym.envs import observation as obsmod

FEATURE_NAMES = ("angle", "reference", "error", "error_fine", "error_mid", "limp_home_side", "last_duty",
                 "velocity_slow", "velocity_fast", "reference_rate", "error_integral")
FEATURES_VERSION = 1
RESIDUAL_FEATURE = "base_duty"          # appended to FEATURE_NAMES in residual mode


def residual_bases() -> list[str]:
    """Valid ``task.residual`` base controllers: the built-in classical controllers that read the angle only
    (the policy's env observes no current or battery voltage)."""
    from etb_gym.controllers import CONTROLLERS, make_controller

    return sorted(n for n in CONTROLLERS if tuple(getattr(make_controller(n), "reads", ("angle",))) == ("angle",))


def feature_names(task: "TaskConfig | None" = None) -> tuple:
    """The policy input's names for a task (FEATURE_NAMES, plus ``base_duty`` in residual mode)."""
    return FEATURE_NAMES + ((RESIDUAL_FEATURE,) if task is not None and task.residual else ())


@dataclass(frozen=True)
class TaskConfig:
    """Everything about the MDP the policy is trained on (stored in config.json, needed to deploy it)."""

    action_repeat: int = 2              # control periods per policy decision
    episode_s: float = 1.5              # training episode length [s]
    w_lin: float = 1.0                  # reward weights (module docstring)
    w_log: float = 1.0
    e0_deg: float = 0.05
    w_rate: float = 0.05
    velocity_cutoff_rad_s: float = 300.0
    reference_rate_cutoff_rad_s: float = 100.0
    integral_tau_s: float = 0.1
    residual: str = ""                  # base controller of residual RL ("" = the policy outputs the duty)
    residual_scale: float = 0.3         # duty = clip(d_base + residual_scale * a, -1, 1)
    w_residual: float = 0.02            # reward penalty w_residual * a^2 on the residual action
    features_version: int = FEATURES_VERSION

    def __post_init__(self):
        if not (isinstance(self.action_repeat, (int, np.integer)) and 1 <= self.action_repeat <= 50):
            raise ValueError(f"task.action_repeat = {self.action_repeat!r} is invalid: expected an integer in [1, 50]")
        for f in ("episode_s", "e0_deg", "velocity_cutoff_rad_s", "reference_rate_cutoff_rad_s", "integral_tau_s"):
            v = getattr(self, f)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"task.{f} = {v!r} is invalid: expected a finite number > 0")
        if not isinstance(self.residual, str) or (self.residual and self.residual not in residual_bases()):
            raise ValueError(f"task.residual = {self.residual!r} is invalid: expected a base controller, one of "
                             f"{residual_bases()} (or '' for no residual)")
        v = self.residual_scale
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0 < v <= 2):
            raise ValueError(f"task.residual_scale = {v!r} is invalid: expected a duty range in (0, 2]")
        for f in ("w_lin", "w_log", "w_rate", "w_residual"):
            v = getattr(self, f)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"task.{f} = {v!r} is invalid: expected a finite weight >= 0")
        if self.features_version != FEATURES_VERSION:
            raise ValueError(f"task.features_version = {self.features_version!r}: this etb_gym computes policy "
                             f"features version {FEATURES_VERSION}; retrain the policy")

    @classmethod
    def from_dict(cls, d: Mapping | None) -> "TaskConfig":
        d = dict(d or {})
        valid = [f.name for f in fields(cls)]
        bad = sorted(set(d) - set(valid))
        if bad:
            raise ValueError(f"task: unknown field(s) {bad}; valid: {valid}")
        return cls(**d)

    def to_dict(self) -> dict:
        return asdict(self)


class PolicyFeatures:
    """The policy input for N parallel observation streams (module docstring). ``reset_rows(rows, obs)`` starts
    streams from their first observation, ``update(obs)`` feeds the next control period of all streams,
    ``value()`` returns the (N, len(FEATURE_NAMES)) float32 features."""

    def __init__(self, n: int, dt: float, task: TaskConfig):
        self.n, self.dt, self.task = int(n), float(dt), task
        self.vel = VelocityEstimator(dt, task.velocity_cutoff_rad_s)
        self.ref_vel = VelocityEstimator(dt, task.reference_rate_cutoff_rad_s)
        self.a_int = math.exp(-dt / task.integral_tau_s)
        self.vel.y_prev, self.vel.v = np.zeros(n), np.zeros(n)
        self.ref_vel.y_prev, self.ref_vel.v = np.zeros(n), np.zeros(n)
        self.z = np.zeros(n)
        self.obs = np.zeros((n, 4))

    @staticmethod
    def _split(obs):
        o = np.asarray(obs, dtype=np.float64)
        y = o[:, 0] * obsmod.ANGLE_SCALE_DEG + obsmod.ANGLE_CENTER_DEG
        r = o[:, 1] * obsmod.ANGLE_SCALE_DEG + obsmod.ANGLE_CENTER_DEG
        return o, y, r

    def reset_rows(self, rows, obs_rows) -> None:
        o, y, r = self._split(obs_rows)
        self.vel.y_prev[rows], self.vel.v[rows] = y, 0.0
        self.ref_vel.y_prev[rows], self.ref_vel.v[rows] = r, 0.0
        self.z[rows] = 0.0
        self.obs[rows] = o[:, :4]

    def update(self, obs) -> None:
        o, y, r = self._split(obs)
        self.vel.update(y)
        self.ref_vel.update(r)
        e = o[:, 2] * obsmod.ANGLE_SCALE_DEG
        self.z = self.a_int * self.z + self.dt * np.clip(e, -1.0, 1.0)
        self.obs[:] = o[:, :4]

    def value(self, base_duty=None) -> np.ndarray:
        """The features; in residual mode ``base_duty`` (N,) is the base controller's duty, the last column."""
        o = self.obs
        y = o[:, 0] * obsmod.ANGLE_SCALE_DEG + obsmod.ANGLE_CENTER_DEG
        e = o[:, 2] * obsmod.ANGLE_SCALE_DEG
        v, vr = self.vel.v, self.ref_vel.v
        nf = len(FEATURE_NAMES)
        out = np.empty((self.n, nf + (1 if self.task.residual else 0)), np.float32)
        if self.task.residual:
            if base_duty is None:
                raise ValueError("residual task: PolicyFeatures.value() needs the base controller's duty")
            out[:, nf] = base_duty
        out[:, 0:3] = o[:, 0:3]
        out[:, 3] = np.tanh(e / 0.25)
        out[:, 4] = np.tanh(e / 3.0)
        out[:, 5] = np.tanh((y - 3.0) / 1.0)
        out[:, 6] = o[:, 3]
        out[:, 7] = np.tanh(v / 50.0)
        out[:, 8] = np.tanh(v / 1000.0)
        out[:, 9] = np.tanh(vr / 200.0)
        out[:, 10] = np.tanh(self.z / 0.02)
        return out


def tracking_cost(e_deg: np.ndarray, task: TaskConfig) -> np.ndarray:
    """Per-period tracking cost w_lin |e|/45 + w_log ln(1 + |e|/e0) / ln(1 + 45/e0) (module docstring)."""
    a = np.abs(e_deg)
    return task.w_lin * a / 45.0 + task.w_log * np.log1p(a / task.e0_deg) / math.log1p(45.0 / task.e0_deg)


# ------------------------------------------------------------------------------------------------ references
LIMP_HOME_DEG = 3.0
LOW_DEG, HIGH_DEG = 0.5, 85.0


def draw_reference(rng: np.random.Generator, duration_s: float, dt: float) -> tuple[dict, float]:
    """A training reference and the initial plate angle (at rest): (``piecewise_linear`` spec, angle_deg).

    The plate starts at rest at a0 (30 %: near limp-home 3 +- 3 deg, else uniform 0.5..85 deg); the reference
    holds a0 for 0.05..0.3 s, then chains segments with dwell 0.1..0.35 s, each one of: a large step (30 %,
    new level uniform 0.5..85 deg), a small step anywhere (30 %, +-0.1..2.5 deg), a step near / across
    limp-home (20 %, level 3 +- 3 deg) or a ramp (20 %, to a uniform level at 50..400 deg/s). Knots lie on
    the control grid, so a step is a one-period linear segment (the env samples the reference on the grid)."""
    def grid(t):
        return round(t / dt) * dt

    def clip(x):
        return float(min(HIGH_DEG, max(LOW_DEG, x)))

    a0 = clip(LIMP_HOME_DEG + rng.uniform(-3.0, 3.0)) if rng.random() < 0.3 else float(rng.uniform(LOW_DEG, HIGH_DEG))
    times, values = [0.0], [a0]
    t, level = grid(rng.uniform(0.05, 0.3)), a0
    while t < duration_s:
        u = rng.random()
        if u < 0.8:
            if u < 0.3:
                new = float(rng.uniform(LOW_DEG, HIGH_DEG))
            elif u < 0.6:
                new = clip(level + rng.choice((-1.0, 1.0)) * rng.uniform(0.1, 2.5))
            else:
                new = clip(LIMP_HOME_DEG + rng.uniform(-3.0, 3.0))
            times += [t, t + dt]
            values += [level, new]
            t = t + dt
        else:
            new = float(rng.uniform(LOW_DEG, HIGH_DEG))
            dur = max(grid(abs(new - level) / rng.uniform(50.0, 400.0)), dt)
            times += [t, t + dur]
            values += [level, new]
            t = t + dur
        level = new
        t = grid(t + rng.uniform(0.1, 0.35))
    times, values = np.array(times), np.array(values)
    keep = np.concatenate([[True], np.diff(times) > 1e-12])
    return {"name": "piecewise_linear", "times_s": times[keep].tolist(), "values_deg": values[keep].tolist()}, a0


# ------------------------------------------------------------------------------------------------ residual
class BaseControllers:
    """The residual mode's base controllers of N observation streams (one classical controller instance per
    stream, built like the benchmark builds them: designed on the env's nominal model). ``duty`` holds each
    stream's base duty for the coming control period, computed from the stream's latest observation."""

    def __init__(self, spec: str, env_id: str, n: int):
        from etb_gym.benchmark import build_controller

        if spec not in residual_bases():
            raise ValueError(f"task.residual = {spec!r} is invalid: expected a base controller, one of "
                             f"{residual_bases()}")
        self.spec = spec
        self.ctrls = [build_controller(spec, env_id) for _ in range(int(n))]
        self.duty = np.zeros(int(n))

    def reset_rows(self, rows, obs_rows, seed: int | None = None) -> None:
        for i, o in zip(rows, np.asarray(obs_rows, dtype=np.float64)):
            self.ctrls[i].reset(seed=seed)
            self.duty[i] = self.ctrls[i].act(o)

    def update(self, obs) -> np.ndarray:
        o = np.asarray(obs, dtype=np.float64)
        for i, c in enumerate(self.ctrls):
            self.duty[i] = c.act(o[i])
        return self.duty


def apply_residual(base_duty, action, task: TaskConfig):
    """duty = clip(d_base + residual_scale * a, -1, 1) (module docstring)."""
    return np.clip(np.asarray(base_duty) + task.residual_scale * np.asarray(action), -1.0, 1.0)
