"""Scenarios and plant variants of the controller benchmark (etb_gym.benchmark runs them).

A scenario is a reference for the env (times include the 0.3 s hold at the initial angle before the step or
profile); a variant is a named cell of the robustness grid, a :class:`~etb_gym.variants.PlantVariant` of the
env's plant (see docs/controllers.md for the list).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping

from etb_gym.variants import PlantVariant

HOLD_S = 0.3
TAIL_S = 0.1


# ------------------------------------------------------------------------------------------------ scenarios
@dataclass(frozen=True)
class Scenario:
    name: str
    kind: str                      # "step" or "tracking"
    reference: Mapping             # env reference spec (dict), times include the hold
    initial_deg: float
    duration_s: float
    step_at_s: float = HOLD_S
    step_from_deg: float = float("nan")
    step_to_deg: float = float("nan")
    description: str = ""


def _step(name, a, b, after_s=0.5, desc=""):
    return Scenario(name, "step", {"name": "step", "initial_deg": a, "final_deg": b, "at_s": HOLD_S}, a,
                    HOLD_S + after_s, HOLD_S, a, b, desc or f"step {a:g} -> {b:g} deg")


SCENARIOS: dict[str, Scenario] = {s.name: s for s in [
    _step("step_10_80", 10.0, 80.0, desc="large opening step 10 -> 80 deg"),
    _step("step_80_10", 80.0, 10.0, desc="large closing step 80 -> 10 deg"),
    _step("small_step_limp_home", 3.0, 3.5, desc="+0.5 deg out of limp-home (3 deg)"),
    _step("small_step_limp_home_neg", 3.0, 2.5, desc="-0.5 deg below limp-home"),
    _step("step2_limp_home", 3.0, 5.0, desc="+2 deg out of limp-home"),
    _step("step2_limp_home_neg", 3.0, 1.0, desc="-2 deg below limp-home"),
    _step("small_step_40", 40.0, 40.5, desc="+0.5 deg at part load"),
    _step("small_step_40_neg", 40.0, 39.5, desc="-0.5 deg at part load"),
    _step("step2_40", 40.0, 42.0, desc="+2 deg at part load"),
    _step("step2_40_neg", 40.0, 38.0, desc="-2 deg at part load"),
    Scenario("ramp_10_80", "tracking", {"name": "ramp", "start_deg": 10.0, "end_deg": 80.0, "at_s": HOLD_S,
                                        "duration_s": 0.5}, 10.0, HOLD_S + 0.7,
             description="ramp 10 -> 80 deg in 0.5 s (140 deg/s), then hold"),
    Scenario("ramp_80_10", "tracking", {"name": "ramp", "start_deg": 80.0, "end_deg": 10.0, "at_s": HOLD_S,
                                        "duration_s": 0.5}, 80.0, HOLD_S + 0.7,
             description="ramp 80 -> 10 deg in 0.5 s, then hold"),
    Scenario("pedal", "tracking", {"name": "pedal", "duration_s": 2.0}, 4.0, 2.0,
             description="pedal-like driving profile drawn from the seed (idle, part load, WOT tip-in/out)"),
]}

QUICK_SCENARIOS = ("step_10_80", "step_80_10", "small_step_limp_home", "small_step_limp_home_neg",
                   "small_step_40", "small_step_40_neg", "ramp_10_80", "pedal")
SMALL_STEP_SCENARIOS = ("small_step_limp_home", "small_step_limp_home_neg", "small_step_40", "small_step_40_neg")


# ------------------------------------------------------------------------------------------------ variants
@dataclass(frozen=True)
class Variant:
    """A named cell of the robustness grid: a :class:`~etb_gym.variants.PlantVariant` of the env's plant."""

    name: str
    description: str
    plant: PlantVariant = field(default_factory=PlantVariant)

    def env_kwargs(self, env_id: str) -> dict:
        """params / supply_V / sensor arguments of gym.make for this variant (relative to the env's plant)."""
        from etb_gym.plant import make_plant

        kw = {"params": self.plant.overrides(make_plant(model_of(env_id)).params_dict())}
        if self.plant.supply_V is not None:
            kw["supply_V"] = self.plant.supply_V
        if self.plant.sensor_noise_std_deg is not None:
            kw["sensor"] = {"noise_std_rad": math.radians(self.plant.sensor_noise_std_deg)}
        return kw


VARIANTS: dict[str, Variant] = {v.name: v for v in [
    Variant("nominal", "the env's default plant (12 V, 20 C, nominal friction/springs/sensor)"),
    Variant("supply_9V", "battery at 9 V", PlantVariant(supply_V=9.0)),
    Variant("supply_16V", "battery at 16 V", PlantVariant(supply_V=16.0)),
    Variant("coil_-40C", "coil at -40 C: R x (1 + 0.00393 (T - 20))", PlantVariant(coil_temperature_C=-40.0)),
    Variant("coil_125C", "coil at 125 C", PlantVariant(coil_temperature_C=125.0)),
    Variant("friction_-50", "friction (T_c, T_s, sigma2) -50 %", PlantVariant(friction_scale=0.5)),
    Variant("friction_+50", "friction +50 %", PlantVariant(friction_scale=1.5)),
    Variant("springs_-20", "spring preload and rate -20 %", PlantVariant(spring_scale=0.8)),
    Variant("springs_+20", "spring preload and rate +20 %", PlantVariant(spring_scale=1.2)),
    Variant("sensor_noise_high", "angle sensor noise 0.05 deg (5x)", PlantVariant(sensor_noise_std_deg=0.05)),
]}

DEFAULT_CONTROLLERS = ("ptos", "pid", "smc", "pid-plain", "smc-plain")
DEFAULT_ENV = "ETB-3B-v0"


def model_of(env_id: str) -> str:
    from etb_gym.envs import ENV_IDS

    if env_id not in ENV_IDS:
        raise ValueError(f"unknown env {env_id!r}: valid are {list(ENV_IDS)}")
    return env_id.split("-")[1]


def check_names(kind: str, names: Iterable[str], valid: Mapping) -> list[str]:
    out = list(names)
    bad = [n for n in out if n not in valid]
    if bad:
        raise ValueError(f"unknown {kind}(s) {bad}: valid are {list(valid)}")
    return out


def step_band_deg(sc: Scenario) -> float:
    """The settling band of a step scenario: max(2 % of the step, 0.1 deg)."""
    return max(0.02 * abs(sc.step_to_deg - sc.step_from_deg), 0.1)
