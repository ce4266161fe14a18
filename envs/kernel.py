"""The env kernel: the compiled core that the single env (:class:`~etb_gym.envs.env.ETBEnv`) and the native
vector env (:class:`~etb_gym.envs.vector.ETBVectorEnv`) share, and the only thing the vector env takes from a
single env besides its episode draws.

An :class:`EnvKernel` holds, for one env configuration: the plant's generated stepper (``control_step``,
``rhs``) with its constants (control period, substeps, PWM), the nominal parameter vector, the pre-scaled
reward weights, the sensor's constants and delay-line length, the observation layout (which optional entries,
full-state scales, the box and whether to clip to it) and the info's torque columns. It is immutable; each env
keeps its own episode state (plant state, delay line, noise block) and passes it to these functions.

The kernels written here are the step reward (:func:`step_reward`); the sensor reading, delay line and a
plant file's reading maps are ``etb_gym.components.sensor``'s (:func:`sense`, :func:`delay_push`,
:func:`shape_reading`), the observation scaling
``etb_gym.envs.observation``'s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np

from etb_gym.components.sensor import PositionSensorParams, pack_reading_shape, shape_line_length
from etb_gym.jit import kernel
from etb_gym.plant import Plant

from . import observation as obsmod

RAD2DEG = 180.0 / math.pi
TRACKING_SCALE_DEG = 90.0
OBS_BOUND = 10.0           # observation box: [-10, 10] except last_duty in [-1, 1]
NOISE_BLOCK = 128          # sensor noise is drawn from np_random in blocks of this many control periods
INFO_KEYS = ("angle_deg", "sensed_angle_deg", "velocity_deg_s", "current_A", "voltage_V", "duty", "reference_deg",
             "supply_V")   # then the torques (EnvKernel.info_torques), then "t_s"
_ROLE_TORQUE_KEYS = {"drive": "torque_electric_Nm", "friction": "torque_friction_Nm",
                     "spring": "torque_spring_Nm", "stops": "torque_stops_Nm"}


@kernel
def step_reward(error_deg, duty, last_duty, w_tracking, w_effort, w_chattering):
    """The reward of one step (see ETBEnv's docstring); the weights come pre-scaled:
    ``w_tracking / TRACKING_SCALE_DEG`` and ``w_chattering / 4`` (:attr:`EnvKernel.reward_weights`)."""
    dd = duty - last_duty
    return -(w_tracking * abs(error_deg) + w_effort * (duty * duty) + w_chattering * (dd * dd))


def state_scales(p: Plant) -> np.ndarray:
    """Scale of each state for the full-state observation: angle pi/2 rad, velocity 50 rad/s, current 10 A,
    friction bristle deflection T_s/sigma0 (the presliding range), any other state 1."""
    scales = np.ones(p.n_states)
    scales[0], scales[1], scales[2] = math.pi / 2, 50.0, obsmod.CURRENT_SCALE_A
    for (s0, s1), c in zip(p.state_slices, p.components):
        q = c.params
        if s1 > s0 and hasattr(q, "bristle_stiffness_Nm_per_rad"):
            top = getattr(q, "static_Nm", getattr(q, "coulomb_Nm", 0.0))
            if top > 0:
                scales[s0:s1] = top / q.bristle_stiffness_Nm_per_rad
    return scales


def info_torques(p: Plant) -> tuple:
    """``((info key, aux column), ...)``: the four role torques (column -1: the plant has no such component,
    reported as 0), then ``torque_<name>_Nm`` of every other component."""
    roles = {r: (p.component_names.index(r) if r in p.component_names else -1) for r in _ROLE_TORQUE_KEYS}
    return tuple((_ROLE_TORQUE_KEYS[r], k) for r, k in roles.items()) + tuple(
        (f"torque_{n}_Nm", k) for k, n in enumerate(p.component_names) if n not in _ROLE_TORQUE_KEYS)


@dataclass(frozen=True, eq=False)
class EnvKernel:
    """The compiled core of one env configuration (see the module docstring). Build it with :meth:`build`."""

    plant: Plant
    control_step: Callable     # control_step(x, d, V, P, t0, dt, substeps, switching, f_pwm, aux) -> ok
    rhs: Callable              # rhs(t, x, u, P, dx, aux): derivatives and each component's torque
    dt: float                  # control period [s]
    substeps: int
    switching: bool            # switched PWM (else averaged)
    pwm_frequency_hz: float
    P_nominal: np.ndarray      # the plant's parameter vector (read-only)
    max_steps: int             # control periods per episode
    reward_weights: np.ndarray  # (w_tracking / 90, w_effort, w_chattering / 4), step_reward's arguments
    sensor: np.ndarray         # (gain, offset, resolution, current noise std, current resolution,
    #                            supply noise std, supply resolution), sense()'s constants
    delay_length: int          # the angle's delay line: ring-buffer length (0: no delay)
    reading_shape: np.ndarray  # a twin's reading maps after the delay line (components.sensor.shape_reading's
    #                            constants, pack_reading_shape: fractional delay, curve, filter; [0, 0, 0]: none)
    shape_length: int          # the length of shape_reading's state (1 + the filter's taps)
    noise_cols: int            # noise columns per control period: angle, current (, supply)
    observe_current: bool
    observe_supply: bool
    full_state: bool
    n_obs: int
    supply_index: int          # observation index of the supply reading (4, or 5 after the current)
    state_scales: np.ndarray   # full-state observation: each state divided by its scale
    obs_low: np.ndarray        # the observation box (float32)
    obs_high: np.ndarray
    clip_obs: bool             # clip observations to the box (only a plant without end stops or the full state
    #                            can leave it)
    info_torques: tuple        # ((info key, aux column or -1), ...)

    @classmethod
    def build(cls, plant: Plant, sensor: PositionSensorParams, reward_weights: Mapping, *, max_steps: int,
              observe_current: bool, observe_supply: bool, full_state: bool,
              reading_shape: np.ndarray | None = None) -> "EnvKernel":
        """The kernel of an env on ``plant`` (options already checked, see etb_gym.envs.options);
        ``reading_shape``: a plant file's reading maps (options.sensor_setup), None for none."""
        sp, w = sensor, reward_weights
        shape = pack_reading_shape() if reading_shape is None else np.array(reading_shape, float)
        n_obs = 4 + observe_current + observe_supply + (plant.n_states if full_state else 0)
        low = np.full(n_obs, -OBS_BOUND, np.float32)
        low[3] = -1.0
        P = plant.P.copy()
        P.setflags(write=False)
        fns = plant.stepper()
        return cls(
            plant=plant, control_step=fns.control_step, rhs=fns.rhs, dt=plant.control_period_s,
            substeps=plant.substeps, switching=plant.supply.switching,
            pwm_frequency_hz=plant.supply.pwm_frequency_hz, P_nominal=P, max_steps=max_steps,
            reward_weights=np.array([w["tracking"] / TRACKING_SCALE_DEG, w["effort"], w["chattering"] * 0.25]),
            sensor=np.array([sp.gain, sp.offset_rad, sp.resolution_rad, sp.current_noise_std_A,
                             sp.current_resolution_A, sp.supply_noise_std_V, sp.supply_resolution_V]),
            delay_length=sp.delay_steps,                 # readings d periods old (as PositionSensor)
            reading_shape=shape, shape_length=shape_line_length(shape),
            noise_cols=2 + observe_supply, observe_current=observe_current, observe_supply=observe_supply,
            full_state=full_state, n_obs=n_obs, supply_index=4 + observe_current,
            state_scales=state_scales(plant), obs_low=low, obs_high=-low,
            clip_obs=plant.stops is None or full_state, info_torques=info_torques(plant))

    @property
    def observed_state_scale(self) -> np.ndarray:
        """1 / state_scales when the full state is observed, else an empty array (the vector env's loop)."""
        return 1.0 / self.state_scales if self.full_state else np.zeros(0)

    def delay_line(self, angle_rad: float) -> np.ndarray:
        """A fresh delay line (delay_push's ring buffer) filled with ``angle_rad``."""
        return np.full(self.delay_length, angle_rad)

    @property
    def has_reading_shape(self) -> bool:
        """The reading has a twin's maps (a fractional delay, a curve or a filter) after the delay line."""
        return bool(np.any(self.reading_shape != 0.0))
