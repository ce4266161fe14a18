"""The ETB env's options checked at the boundary: constructor arguments, reward weights, randomization ranges
and reset options. Every error names the option, the value and what was expected, as a sentence."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping

import numpy as np

from etb_gym.components.base import show
from etb_gym.components.sensor import PositionSensorParams, pack_reading_shape
from etb_gym.components.supply import SUPPLY_RANGE_V
from etb_gym.plant import MODELS, Plant, make_plant
from etb_gym.variants import MIN_COIL_TEMPERATURE_C

DEFAULT_REWARD_WEIGHTS = {"tracking": 1.0, "effort": 0.02, "chattering": 0.05}
# per-episode randomization: quantity -> (low, high), drawn uniformly in this order
DEFAULT_RANDOMIZATION = {
    "supply_V": (9.0, 16.0),                # battery voltage seen by the bridge [V]
    "coil_temperature_C": (-40.0, 125.0),   # R(T) = R_20 * (1 + 0.00393 * (T - 20 C))
    "friction_scale": (0.5, 1.5),           # multiplies all friction torques (T_c, T_s, sigma2)
    "spring_scale": (0.8, 1.2),             # multiplies spring preload and rate
    "inertia_scale": (0.9, 1.1),            # multiplies J
    "sensor_noise_std_deg": (0.0, 0.05),    # white noise of the angle sensor [deg]
}
RESET_OPTIONS = ("angle_deg", "reference", "params", "supply_V")
ENV_KWARGS = ("model", "reference", "episode_s", "control_period_s", "observe_current", "observe_supply",
              "full_state", "sensor",
              "plant", "params", "supply_V", "pwm_mode", "randomize", "reward_weights", "render_mode")
MAX_EPISODE_STEPS = 10_000_000      # the reference is tabulated per episode: bound the memory before allocating


def finite_number(where, v, lo=-math.inf, hi=math.inf, expected="a finite number"):
    """``float(v)`` when it is a finite number in [lo, hi]; otherwise a ValueError naming ``where``."""
    if isinstance(v, (bool, np.bool_, str, bytes)):         # True is not 1 s, "3" is not 3 V
        raise ValueError(f"{where} = {show(v)} is invalid: expected {expected}, got {type(v).__name__}")
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{where} = {show(v)} is invalid: expected {expected}") from None
    if not (math.isfinite(f) and lo <= f <= hi):
        raise ValueError(f"{where} = {show(v)} is invalid: expected {expected}")
    return f


def voltage(where, v) -> float:
    """A battery voltage inside the supply's range."""
    return finite_number(where, v, *SUPPLY_RANGE_V, "a voltage in [%g, %g] V" % SUPPLY_RANGE_V)


def flag(name, v) -> bool:
    """An on/off option: True/False (or 1/0); anything else raises naming the option."""
    if isinstance(v, (bool, np.bool_)) or (isinstance(v, (int, np.integer)) and v in (0, 1)):
        return bool(v)
    raise ValueError(f"{name} = {v!r} is invalid: expected True or False")


def load_plant_spec(plant) -> Plant:
    """A Plant from a path (.toml/.json plant file), a plant description dict, or a Plant."""
    return load_plant_and_sensor(plant)[0]


def load_plant_and_sensor(plant) -> tuple[Plant, dict | None]:
    """:func:`load_plant_spec` and the plant file's (or dict's) ``[sensor]`` section, checked
    (components.sensor.sensor_section), or None (a Plant object, or no section)."""
    if isinstance(plant, Plant):
        return plant, None
    if isinstance(plant, (str, Path)):
        from etb_gym.plantfile import load_plant_and_sensor as load

        return load(plant)
    if isinstance(plant, Mapping):
        section = plant.get("sensor")
        if section is not None:
            from etb_gym.components.sensor import sensor_section

            section = sensor_section(section)
        return Plant.from_dict({k: v for k, v in plant.items() if k != "sensor"}), section
    raise ValueError(f"plant = {plant!r}: expected a plant file path (.toml or .json), a plant description "
                     "dict (Plant.to_dict()) or a Plant")


def build_plant(model, plant, pwm_mode, control_period_s, params) -> Plant:
    """The env's plant: the model's (or ``plant``), with the PWM mode, control period and overrides applied."""
    return build_plant_and_sensor(model, plant, pwm_mode, control_period_s, params)[0]


def build_plant_and_sensor(model, plant, pwm_mode, control_period_s, params) -> tuple[Plant, dict | None]:
    """:func:`build_plant` and the ``[sensor]`` section of ``plant`` (:func:`load_plant_and_sensor`), or None."""
    section = None
    if plant is not None:
        p, section = load_plant_and_sensor(plant)
    else:
        if str(model).strip().upper() not in MODELS:
            raise ValueError(f"model = {model!r}: expected one of {list(MODELS)}")
        p = make_plant(model)
    if pwm_mode is not None and pwm_mode != p.supply.pwm_mode:
        p = p.replace(supply=p.supply.replace(pwm_mode=pwm_mode))
    if control_period_s is not None:
        cp = finite_number("control_period_s", control_period_s, 1e-6, 1.0, "a period in [1e-6, 1] s")
        if cp != p.control_period_s:
            p = p.replace(control_period_s=cp)
    if params:
        if not isinstance(params, Mapping):
            raise ValueError(f"params = {params!r}: expected a dict of 'component.field' overrides")
        p = p.with_params(dict(params))
    return p, section


def episode_steps(episode_s, dt) -> tuple[float, int]:
    """``(episode_s, max_steps)``: the episode length checked against the control period ``dt``."""
    f = finite_number("episode_s", episode_s, 0.0, math.inf, "a duration > 0 s")
    if f / dt > MAX_EPISODE_STEPS:
        raise ValueError(f"episode_s = {show(episode_s)} s is {f / dt:.3g} control periods of "
                         f"{dt:g} s: expected at most {MAX_EPISODE_STEPS:,} per episode "
                         f"({MAX_EPISODE_STEPS * dt:g} s); use shorter episodes")
    max_steps = int(round(f / dt))
    if max_steps < 1:
        raise ValueError(f"episode_s = {episode_s!r} is shorter than one control period ({dt} s)")
    return f, max_steps


def sensor_overrides(sensor) -> dict:
    if sensor is not None and not isinstance(sensor, Mapping):
        raise ValueError(f"sensor = {sensor!r}: expected a dict of PositionSensorParams overrides")
    return dict(sensor or {})


def sensor_setup(section: dict | None, sensor, dt: float) -> tuple[PositionSensorParams, np.ndarray]:
    """The env's angle sensor: ``(PositionSensorParams, the packed reading shape)`` (components.sensor
    pack_reading_shape). In order, later wins: PositionSensorParams' defaults; the plant file's ``[sensor]``
    ``offset_rad``, ``gain`` and ``delay_s`` (whole control periods to ``delay_steps``, the rest of a period a
    fractional delay, interpolated); the ``sensor=`` overrides (a ``delay_steps`` there replaces the file's
    whole delay, fraction included). The file's ``curve`` and ``filter`` always apply; noise and quantization
    are the env's (PositionSensorParams, ``sensor=``)."""
    overrides = sensor_overrides(sensor)
    fraction = 0.0
    base = {}
    if section is not None:
        periods = section["delay_s"] / dt
        whole = round(periods)
        if abs(periods - whole) > 1e-9 * max(1.0, periods):
            whole = math.floor(periods)
            fraction = periods - whole
        base = {"offset_rad": section["offset_rad"], "gain": section["gain"], "delay_steps": int(whole)}
        if "delay_steps" in overrides:
            fraction = 0.0
    merged = {**base, **overrides}
    params = PositionSensorParams().replace(**merged) if merged else PositionSensorParams()
    curve, filt = (None, None) if section is None else (section["curve"], section["filter"])
    return params, pack_reading_shape(fraction, curve, filt)


def reward_weights(weights) -> dict:
    """DEFAULT_REWARD_WEIGHTS with ``weights`` (a dict of some of its keys) replacing their values."""
    w = dict(DEFAULT_REWARD_WEIGHTS)
    if weights is not None:
        if not isinstance(weights, Mapping):
            raise ValueError(f"reward_weights = {weights!r}: expected a dict with keys "
                             f"{sorted(DEFAULT_REWARD_WEIGHTS)}")
        bad = sorted(set(weights) - set(w))
        if bad:
            raise ValueError(f"reward_weights: unknown key(s) {bad}; valid: {sorted(w)}")
        for k, v in weights.items():
            w[k] = finite_number(f"reward_weights[{k!r}]", v, 0.0, math.inf, "a finite weight >= 0")
    return w


def _range(k, v) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in v)
    except (TypeError, ValueError):
        raise ValueError(f"randomize[{k!r}] = {v!r}: expected a (low, high) pair of numbers") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise ValueError(f"randomize[{k!r}] = {v!r}: expected finite low <= high")
    if k != "coil_temperature_C" and lo < 0:
        raise ValueError(f"randomize[{k!r}] = {v!r}: expected non-negative bounds")
    if k in ("supply_V", "inertia_scale") and lo <= 0:
        raise ValueError(f"randomize[{k!r}] = {v!r}: expected bounds > 0")
    if k == "supply_V" and not (SUPPLY_RANGE_V[0] <= lo and hi <= SUPPLY_RANGE_V[1]):
        raise ValueError(f"randomize[{k!r}] = {v!r}: expected voltages in [%g, %g] V" % SUPPLY_RANGE_V)
    if k == "coil_temperature_C" and lo <= MIN_COIL_TEMPERATURE_C:
        raise ValueError(f"randomize[{k!r}] = {v!r}: expected temperatures above "
                         f"{MIN_COIL_TEMPERATURE_C:.0f} C (R > 0)")
    return lo, hi


def randomization(randomize) -> dict:
    """``{quantity: (low, high)}`` in the canonical draw order, from False / True / a dict of ranges."""
    if randomize is False or randomize is None:
        return {}
    if randomize is True:
        return dict(DEFAULT_RANDOMIZATION)
    if not isinstance(randomize, Mapping):
        raise ValueError(f"randomize = {randomize!r}: expected False, True or a dict {{quantity: (low, high)}} "
                         f"with quantities from {list(DEFAULT_RANDOMIZATION)}")
    out = {}
    for k, v in randomize.items():
        if k not in DEFAULT_RANDOMIZATION:
            raise ValueError(f"randomize: unknown quantity {k!r}; valid: {list(DEFAULT_RANDOMIZATION)}")
        out[k] = _range(k, v)
    return {k: out[k] for k in DEFAULT_RANDOMIZATION if k in out}   # canonical draw order


def reset_options(opts) -> Mapping:
    """The reset options checked for their keys (``{}`` for None)."""
    opts = {} if opts is None else opts
    if opts.__class__ is not dict and not isinstance(opts, Mapping):     # (typing's isinstance is slow)
        raise ValueError(f"reset options = {opts!r}: expected a dict with keys from {list(RESET_OPTIONS)}")
    if opts:
        bad = sorted(set(opts) - set(RESET_OPTIONS))
        if bad:
            raise ValueError(f"reset: unknown option(s) {bad}; valid: {list(RESET_OPTIONS)}")
    return opts


def episode_params(params) -> dict:
    """``options['params']``: this episode's "component.field" overrides (the supply is set otherwise)."""
    if not params:
        return {}
    if not isinstance(params, Mapping):
        raise ValueError(f"options['params'] = {params!r}: expected a dict of 'component.field' overrides")
    for key in params:
        if isinstance(key, str) and key.startswith("supply."):
            raise ValueError(f"options['params'][{key!r}]: the supply is set per episode with "
                             "options['supply_V'] (and at construction with supply_V= / pwm_mode=)")
    return dict(params)
