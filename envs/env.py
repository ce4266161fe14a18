"""The ETB Gymnasium environment: track a throttle-angle reference with the H-bridge duty cycle.

Its options are checked in :mod:`.options`; its compiled core (stepper, reward, sensing and observation
constants) is an :class:`~etb_gym.envs.kernel.EnvKernel`, which the native vector env shares.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from etb_gym.components.sensor import PositionSensor, delay_push, sense, shape_reading, shape_reset
from etb_gym.jit import py_func
from etb_gym.plant import read_only
from etb_gym.variants import PlantVariant

from . import observation as obsmod
from . import options as opt
from .kernel import NOISE_BLOCK, OBS_BOUND, RAD2DEG, TRACKING_SCALE_DEG, EnvKernel, step_reward
from .options import (DEFAULT_RANDOMIZATION, DEFAULT_REWARD_WEIGHTS, ENV_KWARGS, MAX_EPISODE_STEPS, RESET_OPTIONS,
                      load_plant_spec)
from .references import (RANDOM_REFERENCES, PiecewiseLinear, Reference, Steps, as_reference, make_random_task,
                         make_reference)

# names kept importable from here (this module's public surface before the options and the kernel moved out)
__all__ = ["ETBEnv", "Episode", "EnvKernel", "DEFAULT_RANDOMIZATION", "DEFAULT_REWARD_WEIGHTS", "ENV_KWARGS",
           "MAX_EPISODE_STEPS", "NOISE_BLOCK", "OBS_BOUND", "RAD2DEG", "RESET_OPTIONS", "REFERENCE_MARGIN_DEG",
           "TRACKING_SCALE_DEG", "load_plant_spec", "sense", "step_reward"]

REFERENCE_MARGIN_DEG = 90.0  # references must stay within the end stops +- this margin

# the single env runs the kernels' plain-Python functions: on scalars they beat a compiled call's dispatch
_sense, _step_reward, _delay_push = py_func(sense), py_func(step_reward), py_func(delay_push)
_encode_into, _encode_current_into = py_func(obsmod.encode_into), py_func(obsmod.encode_current_into)
_encode_supply_into = py_func(obsmod.encode_supply_into)


class Episode:
    """What is drawn at a reset: parameter vector, supply, initial state, reference and its table."""

    __slots__ = ("P", "supply_V", "x0", "reference", "ref_table", "noise_std_rad", "draws")

    def __init__(self, P, supply_V, x0, reference, ref_table, noise_std_rad, draws):
        self.P, self.supply_V, self.x0 = P, supply_V, x0
        self.reference, self.ref_table = reference, ref_table
        self.noise_std_rad, self.draws = noise_std_rad, draws


class ETBEnv(gym.Env):
    """
    ## Description

    An electronic throttle body (paper models 1A..3C): a permanent-magnet actuator turns the throttle plate directly
    against two preloaded return springs that meet at the limp-home angle (3 deg), heavy friction and two
    end stops (0 deg closed, 90 deg open). The agent sets the H-bridge duty cycle once per control period
    (1 ms) so that the plate angle follows a reference. The plant is integrated with the package's fixed
    20-substep stepper (``etb_gym.plant``), so ETB-3B-v0 has LuGre friction and a nonlinear-inductance
    drive, and a plant file can add any extra physics (``plant=``).

    ## Action Space

    ``Box(-1, 1, (1,), float32)``: the H-bridge duty cycle d. The coil sees u = d * V_supply (averaged PWM,
    or switched at 5 kHz with ``pwm_mode="switching"``). Finite actions outside [-1, 1] are clipped to it
    (the applied value is ``info["duty"]``); NaN or infinite actions raise ValueError.

    ## Observation Space

    ``Box(-10, 10, (n,), float32)`` (``last_duty`` in [-1, 1]) in the layout of ``etb_gym.envs.observation`` (decode it with
    ``observation.decode``), every entry of order one:

    | index | entry | unit / scaling |
    |-------|-------|----------------|
    | 0 | sensed throttle angle (sensor model: noise, 12-bit quantization, offset/gain, delay) | (deg - 45) / 45 |
    | 1 | reference angle | (deg - 45) / 45 |
    | 2 | reference - sensed angle | deg / 45 |
    | 3 | duty applied in the previous period | [-1, 1] |
    | 4 | sensed coil current (only with ``observe_current=True``) | A / 10 |
    | 4 or 5 | sensed battery voltage (only with ``observe_supply=True``; after the current if both) | V / 10 |
    | ... | full plant state (only with ``full_state=True``): ``plant.state_names`` each divided by ``env.state_scales`` | ~1 |

    Typical ranges: angle entries in [-1.02, 1.02], current in [-1.3, 1.3]. References must stay within the
    end stops +- 90 deg, so the box is never left with end stops; for a plant without end stops or with
    ``full_state`` the entries are clipped to the box.

    ## Rewards

    With e = reference - true angle [deg] at the end of the period, d the applied duty and d_prev the one
    before::

        reward = -( w_tracking * |e| / 90  +  w_effort * d^2  +  w_chattering * ((d - d_prev) / 2)^2 )

    Default weights ``{"tracking": 1.0, "effort": 0.02, "chattering": 0.05}`` (``reward_weights`` replaces
    any of them); every term is at most its weight, so the worst step reward is about -1.07 and a good
    controller earns about -0.01 per step (~1 deg error).

    ## Starting State

    The plate rests at ``angle_deg`` (default: limp-home, 3 deg) with zero velocity and current; the
    friction states hold whatever torque the springs exert there, as far as static friction can (a plate
    further than ~11 deg from limp-home is released from a state it cannot hold and starts moving).

    ## Episode End

    No termination (the plate cannot leave its stops). Truncation after ``episode_s`` of plant time
    (default 3 s = 3000 steps). A non-finite plant state raises FloatingPointError.

    ## Arguments

    ``gym.make("ETB-3B-v0", **kwargs)``:

    * ``model``: "1A".."3C" (set by the id); ignored when ``plant`` is given.
    * ``reference``: the reference task: a name (``constant, step, steps, ramp, piecewise_linear, sine, chirp,
      random_steps, pedal``), a dict ``{"name": ..., **params}`` or a ``references.Reference`` object.
      Random ones are drawn anew from ``np_random`` at every reset (default ``"random_steps"``).
    * ``episode_s`` (3.0), ``control_period_s`` (None = the plant's, 1 ms).
    * ``observe_current`` (False), ``observe_supply`` (False), ``full_state`` (False): extra observation
      entries. The current reading has 0.01 A noise; the battery reading 0.05 V noise and a 10-bit ADC over
      20 V (0.0195 V steps), set with ``sensor={"supply_noise_std_V": ..., "supply_resolution_V": ...}``.
    * ``sensor``: dict of ``PositionSensorParams`` overrides, e.g. ``{"noise_std_rad": 0.0}``; they win over
      a plant file's ``[sensor]``.
    * ``plant``: a plant file (.toml/.json, see docs/plant-file.md), a plant dict or a ``Plant``. A
      ``[sensor]`` section (a twin's reading model) sets the angle sensor's offset, gain and delay and adds
      its reading curve and filter (options.sensor_setup, docs/envs.md); noise and quantization stay the env's.
    * ``params``: dict of ``"component.field"`` overrides applied to the plant (e.g.
      ``{"friction.coulomb_Nm": 0.25}``).
    * ``supply_V``: battery voltage (None = the plant's, 12 V); ``pwm_mode``: "averaged" or "switching".
    * ``randomize``: False, True (all of ``DEFAULT_RANDOMIZATION``) or a dict ``{quantity: (low, high)}``
      randomizing exactly the listed quantities: supply_V, coil_temperature_C, friction_scale, spring_scale,
      inertia_scale, sensor_noise_std_deg. Draws are uniform, per episode, from ``np_random``.
    * ``reward_weights``: dict with keys tracking, effort, chattering.
    * ``render_mode``: None, "rgb_array" (HxWx3 uint8) or "human" (matplotlib window).

    ## Reset options

    ``env.reset(seed=..., options={...})``: ``angle_deg`` (initial plate angle at rest), ``reference`` (as the
    argument), ``params`` (``"component.field"`` overrides for this episode only, applied before the
    randomization), ``supply_V`` (this episode's battery voltage, overrides its randomization).

    ## Info

    Every ``reset`` and ``step`` returns floats: ``angle_deg``, ``sensed_angle_deg``, ``velocity_deg_s``,
    ``current_A``, ``voltage_V`` (mean bridge voltage of the period), ``duty``, ``reference_deg``,
    ``supply_V``, ``torque_electric_Nm``, ``torque_spring_Nm``, ``torque_friction_Nm``, ``torque_stops_Nm``,
    ``torque_<effect>_Nm`` for each extra component of the plant, and ``t_s``.

    ## Version History

    * v0: initial version.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 30}

    def __init__(self, model: str = "3B", reference: Any = "random_steps", episode_s: float = 3.0,
                 control_period_s: float | None = None, observe_current: bool = False,
                 observe_supply: bool = False, full_state: bool = False,
                 sensor: Mapping | None = None, plant: Any = None, params: Mapping | None = None,
                 supply_V: float | None = None, pwm_mode: str | None = None, randomize: bool | Mapping = False,
                 reward_weights: Mapping | None = None, render_mode: str | None = None, **kwargs):
        if kwargs:
            raise ValueError(f"ETBEnv: unknown argument(s) {sorted(kwargs)}; valid: {list(ENV_KWARGS)}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode = {render_mode!r}: expected None or one of {self.metadata['render_modes']}")
        self.render_mode = render_mode
        p, section = opt.build_plant_and_sensor(model, plant, pwm_mode, control_period_s, params)
        self.plant = p
        self.dt = p.control_period_s
        self.episode_s, self.max_steps = opt.episode_steps(episode_s, self.dt)
        self.supply_V = p.supply.voltage_V if supply_V is None else opt.voltage("supply_V", supply_V)
        # the sensor is set at construction only (a plant file's [sensor], then sensor=); its noise level may be
        # randomized per episode
        sensor_params, reading_shape = opt.sensor_setup(section, sensor, self.dt)
        self.sensor = PositionSensor(sensor_params)
        self.reward_weights = opt.reward_weights(reward_weights)
        self.randomization = opt.randomization(randomize)
        self._init_reference(reference)
        self.observe_current, self.full_state = opt.flag("observe_current", observe_current), bool(full_state)
        self.observe_supply = opt.flag("observe_supply", observe_supply)
        k = self.kernel = EnvKernel.build(p, self.sensor.params, self.reward_weights, max_steps=self.max_steps,
                                          observe_current=self.observe_current,
                                          observe_supply=self.observe_supply, full_state=self.full_state,
                                          reading_shape=reading_shape)
        self.n_obs = k.n_obs
        self.state_scales = k.state_scales
        self.action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.observation_space = spaces.Box(k.obs_low.copy(), k.obs_high.copy(), (k.n_obs,), np.float32)
        self._init_constants(k)
        # ---- episode state (set by reset)
        self._x = p.initial_state()
        self._aux = np.zeros(len(p.components))
        self._k = 0
        self._episode = None
        self._renderer = None
        self._hist = None

    def _init_reference(self, reference):
        self._reference_spec = reference
        self._table_cache: dict = {}
        self._fixed_reference = self._random_task = None           # one of them, validated now
        if self._is_random_spec(reference):
            self._random_task = self._make_random_task(reference)
        else:
            self._fixed_reference = self._build_reference(reference, None)

    def _init_constants(self, k: EnvKernel):
        """Local copies of the kernel's constants for the per-step code (attribute reads on self are cheaper)."""
        p = k.plant
        self._control_step, self._rhs = k.control_step, k.rhs
        self._nsub, self._sw, self._fpwm = k.substeps, k.switching, k.pwm_frequency_hz
        self._wt, self._we, self._wc = (float(w) for w in k.reward_weights)
        self._gain, self._offset, self._q, self._cur_std, self._cur_q, self._sup_std, self._sup_q = \
            (float(v) for v in k.sensor)
        self._supply_index = k.supply_index
        self._shaped, self._shape = k.has_reading_shape, k.reading_shape      # a plant file's reading maps
        self._sline, self._spos = np.zeros(k.shape_length), 0
        self._inv_scales = 1.0 / k.state_scales
        self._obs_low, self._obs_high = k.obs_low, k.obs_high
        self._clip_obs = k.clip_obs
        self._P_nominal = k.P_nominal
        self._nominal = p.params_dict()
        self._t_grid = np.arange(self.max_steps + 1) * self.dt
        self._x0_cache: dict = {}
        self._dx = np.empty(p.n_states)
        self._lo_deg, self._hi_deg = p.angle_min_rad * RAD2DEG, p.angle_max_rad * RAD2DEG
        self._default_angle_deg = p.limp_home_rad * RAD2DEG

    # ------------------------------------------------------------------------------ references
    @staticmethod
    def _is_random_spec(spec) -> bool:
        if isinstance(spec, str):
            return spec in RANDOM_REFERENCES
        if isinstance(spec, Mapping):
            return spec.get("name") in RANDOM_REFERENCES
        return False

    def _spec_dict(self, spec: str | Mapping) -> dict:
        d = {"name": spec} if isinstance(spec, str) else dict(spec)
        if d.get("name") in RANDOM_REFERENCES + ("chirp",):
            d.setdefault("duration_s", self.episode_s)
        if "name" not in d:
            as_reference(d)   # raises the helpful error
        return d

    def _make_random_task(self, spec):
        d = self._spec_dict(spec)
        return make_random_task(d.pop("name"), **d)

    def _build_reference(self, spec, rng) -> Reference:
        if isinstance(spec, (str, Mapping)):
            d = self._spec_dict(spec)
            return make_reference(d.pop("name"), rng=rng, **d)
        return as_reference(spec, rng)

    def _check_range(self, ref, vmin, vmax):
        lo, hi = self._lo_deg - REFERENCE_MARGIN_DEG, self._hi_deg + REFERENCE_MARGIN_DEG
        if vmin < lo or vmax > hi:
            raise ValueError(f"reference {ref!r} leaves [{lo:g}, {hi:g}] deg (range {vmin:g}..{vmax:g} "
                             f"deg): expected set points within the end stops +- {REFERENCE_MARGIN_DEG:g} deg")

    def _ref_table(self, ref: Reference) -> np.ndarray:
        """The reference over the episode's time grid, range-checked; cached per reference object."""
        hit = self._table_cache.get(id(ref))
        if hit is not None and hit[0] is ref:
            return hit[1]
        tab = np.asarray(ref.table(self._t_grid), dtype=float)
        if isinstance(ref, (Steps, PiecewiseLinear)):
            vals = ref.values_deg          # validated finite; the table only holds (interpolated) knot values
            if tab.shape != self._t_grid.shape:
                raise ValueError(f"reference {ref!r} gave a table of shape {tab.shape}")
        else:
            vals = tab
            if tab.shape != self._t_grid.shape or not np.all(np.isfinite(tab)):
                raise ValueError(f"reference {ref!r} gave non-finite or misshaped values over the episode")
        self._check_range(ref, vals.min(), vals.max())
        if len(self._table_cache) > 16:
            self._table_cache.clear()
        self._table_cache[id(ref)] = (ref, tab)
        return tab

    def _draw_reference(self, rng):
        """This episode's reference from the env's random task and its table (no cache: drawn once)."""
        task = self._random_task
        ref = task.draw(rng)
        self._check_range(ref, *task.bounds_deg)
        return ref, ref.table(self._t_grid)

    def _initial_state(self, angle_deg: float) -> np.ndarray:
        x0 = self._x0_cache.get(angle_deg)
        if x0 is None:
            x0 = self.plant.initial_state(angle_deg / RAD2DEG)
            if len(self._x0_cache) > 64:
                self._x0_cache.clear()
            self._x0_cache[angle_deg] = x0
        return x0

    def draw_episode(self, rng: np.random.Generator, options: Mapping | None = None) -> Episode:
        """Everything a reset decides, drawn from ``rng`` in a fixed order (randomization, then reference).
        Shared by the single env and the vector env so that both draw identically."""
        opts = opt.reset_options(options)
        angle = opts.get("angle_deg")
        if angle is None:
            angle = self._default_angle_deg
        else:
            angle = opt.finite_number("options['angle_deg']", angle, self._lo_deg, self._hi_deg,
                                      f"an angle within the end stops [{self._lo_deg:g}, {self._hi_deg:g}] deg")
        overrides = opt.episode_params(opts.get("params"))
        V = self.supply_V
        noise = self.sensor.params.noise_std_rad
        draws = {}
        if self.randomization:
            for k, (lo, hi) in self.randomization.items():
                draws[k] = float(rng.uniform(lo, hi))
            self._apply_draws(draws, overrides)
            if "supply_V" in draws:
                V = draws["supply_V"]
            if "sensor_noise_std_deg" in draws:
                noise = draws["sensor_noise_std_deg"] / RAD2DEG
        if opts.get("supply_V") is not None:
            V = opt.voltage("options['supply_V']", opts["supply_V"])
        P = read_only(self.plant.param_vector(overrides)) if overrides else self._P_nominal   # one compiled type
        spec = opts.get("reference")
        if spec is not None:
            ref = self._build_reference(spec, rng)
            tab = self._ref_table(ref)
        elif self._random_task is not None:
            ref, tab = self._draw_reference(rng)
        else:
            ref = self._fixed_reference
            tab = self._ref_table(ref)
        return Episode(P, V, self._initial_state(angle), ref, tab, noise, draws)

    def _apply_draws(self, draws, overrides):
        """This episode's plant variant (etb_gym.variants) applied on top of ``overrides`` (in place)."""
        plant_part = {k: v for k, v in draws.items() if k not in ("supply_V", "sensor_noise_std_deg")}
        overrides.update(PlantVariant.from_draws(plant_part).overrides(self._nominal, overrides))

    # ------------------------------------------------------------------------------ sensing
    def _read_angle(self, phi):
        """Sensed angle [rad] of true angle ``phi`` (delayed, noisy, quantized) and the noise row used."""
        if self._dbuf:
            phi, self._dpos = _delay_push(self._dbuf, self._dpos, phi)
        if self._shaped:
            phi, self._spos = shape_reading(phi, self._sline, self._spos, self._shape)
        pos = self._npos
        if pos == NOISE_BLOCK:
            self._noise = self.np_random.standard_normal((NOISE_BLOCK, self.kernel.noise_cols))
            pos = 0
        self._npos = pos + 1
        return _sense(phi, self._gain, self._offset, self._noise_std * self._noise.item(pos, 0), self._q), pos

    def _read_current(self, i, pos):
        return _sense(i, 1.0, 0.0, self._cur_std * self._noise.item(pos, 1), self._cur_q)

    def _read_supply(self, pos):
        return _sense(self._V, 1.0, 0.0, self._sup_std * self._noise.item(pos, 2), self._sup_q)

    # ------------------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        ep = self.draw_episode(self.np_random, options)
        self._episode = ep
        self._P, self._V, self._ref, self._tab = ep.P, ep.supply_V, ep.reference, ep.ref_table
        self._noise_std = ep.noise_std_rad
        x = self._x = ep.x0.copy()
        self._k = 0
        self._duty = 0.0
        self._rhs(0.0, x, 0.0, ep.P, self._dx, self._aux)
        self._dbuf = [x.item(0)] * self.kernel.delay_length      # the delay line (delay_push), a list here
        self._dpos = 0
        if self._shaped:
            self._spos = shape_reset(self._sline, self._shape, x.item(0))
        self._noise = self.np_random.standard_normal((NOISE_BLOCK, self.kernel.noise_cols))
        self._npos = 0
        r = self._tab.item(0)
        obs, info = self._observe(x, r, 0.0, 0.0)
        if self.render_mode is not None:
            self._start_history()
            if self.render_mode == "human":
                self.render()
        return obs, info

    def _observe(self, x, r, d, t):
        phi, omega, i = x.item(0), x.item(1), x.item(2)
        sensed, pos = self._read_angle(phi)
        s_deg = sensed * RAD2DEG
        obs = np.empty(self.n_obs, np.float32)
        _encode_into(obs, s_deg, r, d)
        if self.observe_current:
            _encode_current_into(obs, self._read_current(i, pos))
        if self.observe_supply:
            _encode_supply_into(obs, self._supply_index, self._read_supply(pos))
        if self.full_state:
            obs[self.n_obs - x.size:] = x * self._inv_scales
        if self._clip_obs:
            np.minimum(obs, self._obs_high, out=obs)
            np.maximum(obs, self._obs_low, out=obs)
        aux = self._aux
        info = {"angle_deg": phi * RAD2DEG, "sensed_angle_deg": s_deg, "velocity_deg_s": omega * RAD2DEG,
                "current_A": i, "voltage_V": d * self._V, "duty": d, "reference_deg": r, "supply_V": self._V}
        for key, k in self.kernel.info_torques:
            info[key] = aux.item(k) if k >= 0 else 0.0
        info["t_s"] = t
        return obs, info

    def _coerce_action(self, action) -> float:
        a = np.asarray(action, dtype=float)
        if a.size != 1:
            raise ValueError(f"action {action!r} has {a.size} entries: expected one duty cycle (shape (1,))")
        return float(a.reshape(-1)[0])

    def step(self, action):
        if self._episode is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        if type(action) is np.ndarray and action.shape == (1,):
            d = float(action[0])
        else:
            d = self._coerce_action(action)
        if not -1.0 <= d <= 1.0:
            if not math.isfinite(d):
                raise ValueError(f"action = {d!r}: expected a finite duty cycle in [-1, 1]")
            d = 1.0 if d > 1.0 else -1.0
        k, dt, x = self._k, self.dt, self._x
        if not self._control_step(x, d, self._V, self._P, k * dt, dt, self._nsub, self._sw, self._fpwm, self._aux):
            raise FloatingPointError(self.plant.divergence_message(x, (k + 1) * dt))
        k += 1
        self._k = k
        r = self._tab.item(k) if k <= self.max_steps else self._ref((k) * dt)
        reward = _step_reward(r - x.item(0) * RAD2DEG, d, self._duty, self._wt, self._we, self._wc)
        self._duty = d
        obs, info = self._observe(x, r, d, k * dt)
        if self._hist is not None:
            self._record(k, info)
            if self.render_mode == "human":
                self.render()
        return obs, reward, False, k >= self.max_steps, info

    # ------------------------------------------------------------------------------ rendering
    def _start_history(self):
        n = self.max_steps + 1
        self._hist = np.full((3, n), np.nan)
        self._hist_k = 0
        self._record(0, None)

    def _record(self, k, info):
        if k < self._hist.shape[1]:
            self._hist[0, k] = self._x.item(0) * RAD2DEG
            self._hist[1, k] = self._tab.item(k)
            self._hist[2, k] = self._duty
            self._hist_k = k

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human' to "
                            "gym.make")
            return None
        if self._hist is None:
            raise gym.error.ResetNeeded("call reset() before render()")
        if self._renderer is None:
            from .rendering import ETBRenderer

            self._renderer = ETBRenderer(self.episode_s, self._lo_deg, self._hi_deg,
                                         self.plant.limp_home_rad * RAD2DEG, human=self.render_mode == "human",
                                         fps=self.metadata["render_fps"])
        k = self._hist_k
        frame = self._renderer.draw(self._t_grid[: k + 1], self._hist[0, : k + 1], self._hist[1, : k + 1],
                                    self._hist[2, : k + 1], self.model_name)
        return None if self.render_mode == "human" else frame

    @property
    def episode(self) -> Episode | None:
        """What the last reset drew: ``P``, ``supply_V``, ``x0``, ``reference``, ``ref_table``,
        ``noise_std_rad`` and the randomization ``draws`` ({quantity: value})."""
        return self._episode

    @property
    def model_name(self) -> str:
        return f"ETB-{self.plant.model}" if self.plant.model else "custom plant"

    def __setstate__(self, state):
        """Unpickled arrays come back writable: the parameter vectors are handed to the compiled stepper read-only
        again, the one argument type it is compiled for (plant.read_only; a writable P compiled the whole
        right-hand side a second time in every process that unpickled an env)."""
        self.__dict__.update(state)
        for name in ("_P", "_P_nominal"):
            a = state.get(name)
            if isinstance(a, np.ndarray):
                a.setflags(write=False)

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
