"""The proof's truths (:mod:`.proof`): concealed effects per family, the truth plant, and where an effect
moves the reading (the truth with and without it, simulated segment-wise as the diagnosis does)."""
from __future__ import annotations

import dataclasses
import math


from ..components import effects as fx
from ..components.base import Component, Params
from ..jit import kernel
from ..plant import make_plant
from .measurement import SensorModel
from .model import prepare, simulate
from .synthetic import random_nameplate


# ---------------------------------------------------------------- a truth that is not the candidate's equation
@dataclasses.dataclass(frozen=True)
class AirflowMapParams(Params):
    peak_Nm: float = -0.05          # smooth aerodynamic map: peak closing torque near 55 deg
    peak_angle_rad: float = math.radians(55.0)
    width_rad: float = math.radians(25.0)


@kernel
def airflow_map_kernel(t, phi, omega, i, u, s, p, ds):
    x = (phi - p[1]) / p[2]
    return p[0] * math.exp(-0.5 * x * x) * (1.0 - math.exp(-8.0 * max(phi, 0.0))), 0.0, 0.0


class AirflowMap(Component):
    kind = "truth.airflow_map"
    role = "effect"
    Params = AirflowMapParams
    kernel = staticmethod(airflow_map_kernel)


def loguniform(rng, lo, hi):
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def sign(rng):
    return 1.0 if rng.random() < 0.5 else -1.0


# family -> (effects or sensor kwargs, main parameter name in the report, true value of it)
def truth_for(family: str, rng, scale: float):
    """``scale`` in [0, 1]: 1 large, 0 near the detection limit (log-uniform in between)."""
    m = lambda lo, hi: lo * (hi / lo) ** scale
    if family == "clean":
        return [], {}, None, None
    if family == "shaft_flux_loss":
        k = m(0.004, 0.04)
        return [fx.ShaftFluxLoss(loss_at_open_Nm_per_A=k, exponent=rng.uniform(2.0, 4.0))], {}, "loss_at_open_Nm_per_A", k
    if family == "coil_heating":
        c = m(60.0, 4.0)
        return [fx.CoilHeating(heat_capacity_J_per_K=c, thermal_resistance_K_per_W=8.0)], {}, "heat_capacity_J_per_K", c
    if family == "spring_asymmetry":
        d = m(0.01, 0.08) * sign(rng)
        return [fx.SpringAsymmetry(closing_preload_delta_Nm=d)], {}, "closing_preload_delta_Nm", d
    if family == "airflow_torque":
        a = -m(0.01, 0.12)
        return [AirflowMap(peak_Nm=a)], {}, None, None
    if family == "stribeck_friction":
        s = m(0.01, 0.08)
        return [fx.StribeckFriction(stiction_Nm=s, stribeck_velocity_rad_s=0.03)], {}, "stiction_Nm", s
    if family == "sensor_offset_gain":
        o = m(0.04, 1.0) * sign(rng)
        return [], {"offset_deg": o, "gain": 1.0 + m(0.001, 0.02) * sign(rng)}, "offset_deg", o
    if family == "torque_constant_error":
        d = m(0.002, 0.015) * sign(rng)
        return [fx.TorqueConstantError(delta_Nm_per_A=d)], {}, "delta_Nm_per_A", d
    if family == "supply_drop":
        v = m(0.05, 0.6)
        return [fx.SupplyDrop(forward_drop_V=v)], {}, "forward_drop_V", v
    if family == "backlash":
        b = m(0.002, 0.02)
        return [fx.Backlash(play_rad=b)], {}, "play_rad", b
    if family == "angle_dependent_friction":
        a = m(0.01, 0.08) * sign(rng)
        return [fx.AngleDependentFriction(slope_Nm=a)], {}, "slope_Nm", a
    if family == "inductance_saturation":
        dl = m(0.0008, 0.0045)
        return [fx.InductanceSaturation(inductance_drop_H=dl, saturation_current_A=rng.uniform(1.0, 3.0))], {}, \
            "inductance_drop_H", dl
    if family == "end_stop_compliance":
        o = math.radians(90.0 - m(0.3, 4.0))                   # the open stop sits earlier than drawn
        return [fx.EndStopCompliance(open_rad=o, stiffness_Nm_per_rad=rng.uniform(300.0, 3000.0))], {}, "open_rad", o
    if family == "sensor_quantization":
        bits = int(rng.integers(8, 11))                        # 8..10 bits instead of the assumed 12
        return [], {"resolution_deg": 90.0 / 2 ** bits}, "resolution_deg", 90.0 / 2 ** bits
    if family == "sensor_delay":
        k = int(round(m(1.0, 6.0)))
        return [], {"delay_steps": k}, "delay_s", k * 1e-3
    raise ValueError(family)


FAMILIES = ["clean", "shaft_flux_loss", "coil_heating", "spring_asymmetry", "airflow_torque", "stribeck_friction",
            "sensor_offset_gain", "torque_constant_error", "supply_drop", "backlash", "angle_dependent_friction",
            "sensor_delay", "inductance_saturation", "end_stop_compliance", "sensor_quantization"]
QUICK = ["clean", "shaft_flux_loss", "sensor_offset_gain", "spring_asymmetry"]


def truth_plant(rng, effects, substeps=40, nameplate="3B"):
    """The truth: 3B with friction and spring perturbed, or (``nameplate="random"``) a random nameplate."""
    if nameplate == "random":
        p = random_nameplate(rng, substeps=substeps)
        return p.replace(effects=effects) if effects else p
    over = {"friction.coulomb_Nm": 0.2 * rng.uniform(0.85, 1.15), "spring.preload_Nm": 0.15 * rng.uniform(0.9, 1.1),
            "spring.rate_Nm_per_rad": 0.36 * rng.uniform(0.9, 1.1)}
    over["friction.static_Nm"] = over["friction.coulomb_Nm"] * 1.1
    p = make_plant("3B", over, substeps=substeps)
    if effects:
        p = p.replace(effects=effects)
    return p


def sensor_model(sensor_kw, dt_s) -> SensorModel:
    """The truth's sensor effects (``truth_for``'s sensor kwargs) as the diagnosis's SensorModel."""
    return SensorModel(offset_deg=sensor_kw.get("offset_deg", 0.0), gain=sensor_kw.get("gain", 1.0),
                       delay_s=sensor_kw.get("delay_steps", 0) * dt_s,
                       resolution_deg=sensor_kw.get("resolution_deg", 0.0))


def effect_footprint(truth, rec, effects, sensor_kw):
    """(reading with the concealed effect, reading without it) along ``rec`` [deg]. Plate effects: the
    segment-wise simulation of the truth with and without the effect (re-initialized where the tool
    re-initializes, so a stick-slip event placed differently does not count for the rest of the recording).
    Sensor effects: the true angle (the truth replayed on the recorded voltage) read with and without them."""
    if effects:
        data = prepare([rec], 12.0)
        sm = SensorModel()
        return simulate(truth, sm, data)[0][0], simulate(truth.replace(effects=()), sm, data)[0][0]
    duty = rec.voltage_V / truth.supply.voltage_V
    phi = truth.simulate(duty=duty[:-1], angle_deg=math.degrees(truth.limp_home_rad)).angle_deg
    return sensor_model(sensor_kw, rec.dt_s).apply(rec.t_s, phi, quantize=True), phi


PAIRS = ["shaft_flux_loss+coil_heating", "angle_dependent_friction+supply_drop", "sensor_delay+torque_constant_error"]


def pair_footprints(truth, rec, parts, sensor_kw):
    """Reading with both effects, reading with neither, and per effect (reading with both - reading without
    that one), all by the segment-wise simulation of the truth (deg)."""
    data = prepare([rec], 12.0)
    sim = lambda effects, kw: simulate(truth.replace(effects=tuple(effects)), sensor_model(kw, rec.dt_s), data)[0][0]
    both = sim(truth.effects, sensor_kw)
    each = []
    for _, _, fx_k, kw_k, _, _ in parts:
        rest = [e for e in truth.effects if all(e is not f for f in fx_k)]
        each.append(both - sim(rest, {k: v for k, v in sensor_kw.items() if k not in kw_k}))
    return both, sim((), {}), each
