"""The proof's truths (:mod:`.proof`): concealed effects per family, the truth plant, and where an effect
moves the reading (the truth with and without it, simulated segment-wise as the diagnosis does)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np


from ..components import effects as fx
from ..components.base import Component, Params
from ..jit import kernel
from ..plant import make_plant
from .measurement import SensorModel
from .model import prepare, simulate
from .synthetic import random_nameplate
from . import truth_shapes as ts


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


SHAPES = (0, 1, 2)      # 0: the candidate's formula (airflow: the Gaussian map); 1, 2: other shapes (truth_shapes)
OUTSIDE = ("detent_torque", "current_ripple")     # outside the catalogue: no candidate describes them


def family_shape(name: str) -> tuple[str, int]:
    """``"shaft_flux_loss@2"`` -> ("shaft_flux_loss", 2); a plain family name is shape 0."""
    fam, _, k = name.partition("@")
    if fam not in FAMILIES:
        raise ValueError(f"family {fam!r}: expected one of {', '.join(FAMILIES)}")
    shape = int(k) if k else 0
    if shape not in SHAPES or (shape and (fam == "clean" or fam in OUTSIDE)):
        raise ValueError(f"{name!r}: shape {shape} is not defined for {fam} (shapes {', '.join(map(str, SHAPES))}; "
                         "none but 0 for clean and the families outside the catalogue)")
    return fam, shape


# family -> (effects or sensor kwargs, main parameter name in the report, true value of it)
def truth_for(family: str, rng, scale: float, shape: int = 0):
    """``scale`` in [0, 1]: 1 large, 0 near the detection limit (log-uniform in between). ``shape`` 0: the
    candidate's own formula (airflow: a Gaussian map); 1 and 2: shapes that are not the candidate's formula
    (:func:`truth_shape`; no main parameter to compare then)."""
    m = lambda lo, hi: lo * (hi / lo) ** scale
    if shape:
        effects, sensor_kw = truth_shape(family, rng, m, shape)
        return effects, sensor_kw, None, None
    if family in OUTSIDE:
        return outside_truth(family, rng, m)
    if family == "clean":
        return [], {}, None, None
    if family == "shaft_flux_loss":
        k = m(0.003, 0.03)
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


def outside_truth(family, rng, m):
    """A torque outside the catalogue: a detent torque periodic in angle (shapes_eval.Cogging: a smoothed
    sawtooth, a rounded square or narrow pulses, period 10-30 deg), or a torque ripple proportional to the
    current and periodic in angle (CurrentRipple, period 8-25 deg). The main "parameter" is the period."""
    from .shapes_eval import Cogging
    if family == "detent_torque":
        P = math.radians(rng.uniform(10.0, 30.0))
        return [Cogging(amplitude_Nm=m(0.004, 0.03), period_rad=P, phase_rad=rng.uniform(0, P),
                        waveform=float(rng.integers(0, 3)))], {}, "period_deg", math.degrees(P)
    P = math.radians(rng.uniform(8.0, 25.0))
    return [ts.CurrentRipple(amplitude_Nm_per_A=m(0.002, 0.012), period_rad=P, phase_rad=rng.uniform(0, 2 * math.pi))], \
        {}, "period_deg", math.degrees(P)


def truth_shape(family, rng, m, shape):
    """(effects, sensor kwargs) of ``family``'s truth shape 1 or 2 (docs/diagnosis.md, "Truth shapes"), at the
    magnitude ``m(lo, hi)`` of the family's range. Sensor shapes go in the sensor kwargs as ``reading``."""
    deg = math.radians
    two = shape == 2
    if family == "shaft_flux_loss":
        k = m(0.003, 0.03)
        if two:
            return [ts.TorqueConstantProfile(loss_Nm_per_A=k, onset_rad=deg(rng.uniform(20, 60)), profile=1.0)], {}
        return [ts.TorqueConstantProfile(loss_Nm_per_A=k, onset_rad=deg(rng.uniform(35, 70)),
                                         width_rad=deg(rng.uniform(3, 10)))], {}
    if family == "coil_heating":
        c = m(30.0, 2.0)
        if two:     # one node to ambient, heat from the copper and from the PWM ripple (about u^2)
            return [ts.ThermalNetwork(winding_capacity_J_per_K=2 * c, winding_to_housing_K_per_W=8.0,
                                      housing_capacity_J_per_K=1e4, housing_to_ambient_K_per_W=1e-3,
                                      ripple_loss_W_per_V2=rng.uniform(0.03, 0.1))], {}
        return [ts.ThermalNetwork(winding_capacity_J_per_K=c, winding_to_housing_K_per_W=rng.uniform(1.0, 4.0),
                                  housing_capacity_J_per_K=rng.uniform(20.0, 80.0),
                                  housing_to_ambient_K_per_W=rng.uniform(3.0, 8.0))], {}
    if family == "spring_asymmetry":
        d = m(0.01, 0.08) * sign(rng)            # the torque it adds 2 deg below limp-home
        if two:
            return [ts.SpringShape(hardening_Nm_per_rad2=d / deg(2.0) ** 2, profile=1.0)], {}
        return [ts.SpringShape(rate_delta_Nm_per_rad=d / deg(2.0), blend_rad=deg(rng.uniform(0.2, 1.0)))], {}
    if family == "airflow_torque":
        a = -m(0.01, 0.1) * (1.0 if rng.random() < 0.8 else -1.0)
        if not two:
            a *= 0.6                             # a plateau acts over the rest of the stroke
        if two:
            return [ts.AngleTorqueProfile(level_Nm=a, centre_rad=deg(rng.uniform(50, 80)), profile=1.0)], {}
        return [ts.AngleTorqueProfile(level_Nm=a, centre_rad=deg(rng.uniform(30, 65)),
                                      width_rad=deg(rng.uniform(3, 10)))], {}
    if family == "stribeck_friction":
        s = m(0.01, 0.08)
        if two:
            return [ts.StribeckShape(stiction_Nm=s, stribeck_velocity_rad_s=rng.uniform(0.02, 0.2),
                                     closing_factor=rng.uniform(0.6, 1.4), profile=1.0)], {}
        return [ts.StribeckShape(stiction_Nm=s, stribeck_velocity_rad_s=rng.uniform(0.02, 0.2))], {}
    if family == "sensor_offset_gain":
        o = deg(m(0.04, 1.0) * sign(rng))
        if two:
            return [], {"reading": ts.SensorCurve(offset_rad=o, knee_rad=deg(rng.uniform(20, 70)),
                                                  gain_below=1.0 + m(0.001, 0.02) * sign(rng),
                                                  gain_above=1.0 + m(0.001, 0.02) * sign(rng), profile=1.0)}
        return [], {"reading": ts.SensorCurve(offset_rad=o, bow_rad=deg(m(0.05, 0.5) * sign(rng)))}
    if family == "torque_constant_error":
        d = m(0.002, 0.015) * sign(rng)
        if two:
            return [ts.CurrentTorqueConstant(delta_Nm_per_A=d, closing_delta_Nm_per_A=d * rng.uniform(0.2, 0.6),
                                             current_scale_A=0.1, profile=1.0)], {}
        return [ts.CurrentTorqueConstant(delta_Nm_per_A=-abs(d), current_scale_A=rng.uniform(1.0, 3.0))], {}
    if family == "supply_drop":
        v = m(0.05, 0.6)                         # the drop at 2 A
        if two:
            rp = v / 2.0 * rng.uniform(0.5, 0.8)
            return [ts.SupplyShape(series_resistance_ohm=v / 2.0 - rp, polarization_resistance_ohm=rp,
                                   polarization_time_s=rng.uniform(0.2, 2.0), profile=1.0)], {}
        i0 = rng.uniform(0.05, 0.3)
        rs = rng.uniform(0.0, 0.3) * v / 2.0
        return [ts.SupplyShape(series_resistance_ohm=rs, diode_drop_V=(v - 2.0 * rs) / math.asinh(2.0 / i0),
                               knee_current_A=i0)], {}
    if family == "backlash":
        b = m(0.002, 0.02)
        if two:
            return [ts.SoftBacklash(play_rad=b, closing_play_rad=b * rng.uniform(0.2, 0.6), profile=1.0)], {}
        return [ts.SoftBacklash(play_rad=1.5 * b)], {}
    if family == "angle_dependent_friction":
        a = m(0.01, 0.08) * sign(rng)
        if two:
            return [ts.AngleFrictionProfile(level_Nm=a, centre_rad=deg(rng.uniform(25, 65)),
                                            width_rad=deg(rng.uniform(2, 6)), profile=1.0)], {}
        return [ts.AngleFrictionProfile(level_Nm=a, centre_rad=deg(rng.uniform(20, 70)),
                                        width_rad=deg(rng.uniform(4, 12)))], {}
    if family == "inductance_saturation":
        dl = m(0.0008, 0.0045)
        if two:
            return [ts.InductanceShape(inductance_drop_H=dl, knee_current_A=rng.uniform(0.5, 2.0), profile=1.0)], {}
        return [ts.InductanceShape(inductance_drop_H=dl, knee_current_A=rng.uniform(0.5, 2.0),
                                   spread_A=rng.uniform(0.3, 1.0))], {}
    if family == "end_stop_compliance":
        b = deg(90.0 - m(0.3, 4.0))              # where the contact starts (re-tied to the plant's open stop)
        if two:
            return [ts.ProgressiveStop(contact_rad=b, stiffness_Nm_per_rad=rng.uniform(50.0, 300.0),
                                       reference_depth_rad=deg(rng.uniform(0.3, 1.5)), profile=1.0)], {}
        return [ts.ProgressiveStop(contact_rad=b, stiffness_Nm_per_rad=rng.uniform(300.0, 3000.0),
                                   exponent=rng.uniform(1.3, 2.0))], {}
    if family == "sensor_delay":
        if two:
            return [], {"reading": ts.SensorFilter(average_samples=int(round(m(2.0, 12.0))), profile=1.0)}
        return [], {"reading": ts.SensorFilter(time_constant_s=m(1e-3, 6e-3))}
    if family == "sensor_quantization":
        q = deg(90.0 / 2 ** int(rng.integers(8, 11)))
        if two:
            return [], {"reading": ts.SensorCodes(resolution_rad=q, hysteresis=rng.uniform(0.2, 0.8), profile=1.0),
                        "resolution_deg": 0.0}
        return [], {"reading": ts.SensorCodes(resolution_rad=q, nonlinearity=rng.uniform(0.2, 0.6)),
                    "resolution_deg": 0.0}
    raise ValueError(f"family {family!r} has no truth shape {shape}")


FAMILIES = ["clean", "shaft_flux_loss", "coil_heating", "spring_asymmetry", "airflow_torque", "stribeck_friction",
            "sensor_offset_gain", "torque_constant_error", "supply_drop", "backlash", "angle_dependent_friction",
            "sensor_delay", "inductance_saturation", "end_stop_compliance", "sensor_quantization",
            "detent_torque", "current_ripple"]
QUICK = ["clean", "shaft_flux_loss", "sensor_offset_gain", "spring_asymmetry"]


def truth_plant(rng, effects, substeps=40, nameplate="3B"):
    """The truth: 3B with friction and spring perturbed, or (``nameplate="random"``) a random nameplate."""
    if nameplate == "random":
        p = random_nameplate(rng, substeps=substeps)
        return p.replace(effects=tie(effects, p)) if effects else p
    over = {"friction.coulomb_Nm": 0.2 * rng.uniform(0.85, 1.15), "spring.preload_Nm": 0.15 * rng.uniform(0.9, 1.1),
            "spring.rate_Nm_per_rad": 0.36 * rng.uniform(0.9, 1.1)}
    over["friction.static_Nm"] = over["friction.coulomb_Nm"] * 1.1
    p = make_plant("3B", over, substeps=substeps)
    if effects:
        p = p.replace(effects=tie(effects, p))
    return p


def tie(effects, plant):
    """The truth shapes' copies of the plant's spring and open stop set to ``plant``'s (the candidates' own
    truths, shape 0, are left as they were), and the inductance drops (written for 3B: 0.8-4.5 mH of 20 mH,
    knees at 0.5-3 A of 9.6 A) scaled to ``plant``'s inductance and current (on a 2 mH nameplate a 3B-sized
    drop would make the inductance negative); for 3B nothing changes."""
    out = []
    for e in effects:
        if isinstance(e, (ts.InductanceShape, fx.InductanceSaturation)):
            e = _scale_inductance(e, plant)
        if isinstance(e, (ts.SpringShape, ts.SoftBacklash)):
            e = ts.tie_to_spring(e, plant)
        elif isinstance(e, ts.ProgressiveStop):
            e = e.with_params(contact_rad=e.params.contact_rad + plant.angle_max_rad - math.radians(90.0))
        out.append(e)
    return out


def _scale_inductance(e, plant):
    ref = make_plant("3B").drive.params
    q = plant.drive.params
    fl = q.inductance_H / ref.inductance_H
    fi = (plant.supply.voltage_V / q.resistance_ohm) / (12.0 / ref.resistance_ohm)
    if abs(fl - 1.0) < 1e-12 and abs(fi - 1.0) < 1e-12:
        return e
    over = {"inductance_drop_H": e.params.inductance_drop_H * fl}
    for k in ("knee_current_A", "spread_A", "saturation_current_A"):
        if hasattr(e.params, k):
            over[k] = getattr(e.params, k) * fi
    return e.with_params(**over)


def sensor_model(sensor_kw, dt_s) -> SensorModel:
    # a reading shape (truth_shapes.SensorShape, key "reading") has no SensorModel form: it is left out here
    """The truth's sensor effects (``truth_for``'s sensor kwargs) as the diagnosis's SensorModel."""
    return SensorModel(offset_deg=sensor_kw.get("offset_deg", 0.0), gain=sensor_kw.get("gain", 1.0),
                       delay_s=sensor_kw.get("delay_steps", 0) * dt_s,
                       resolution_deg=sensor_kw.get("resolution_deg", 0.0))


def effect_footprint(truth, rec, effects, sensor_kw, residual="replay"):
    """(reading with the concealed effect, reading without it) along ``rec`` [deg]. Plate effects: the
    segment-wise simulation of the truth with and without the effect (re-initialized where the tool
    re-initializes, so a stick-slip event placed differently does not count for the rest of the recording).
    Sensor effects: the true angle (the truth replayed on the recorded voltage) read with and without them.
    ``residual="observer"`` (plate effects only): the one-step predictions of the closed-loop residual
    (observer.py) instead of the replay, i.e. what the diagnosis can see of the effect on a closed loop."""
    if effects:
        data = prepare([rec], 12.0, residual=residual)
        sm = SensorModel()
        return simulate(truth, sm, data)[0][0], simulate(truth.replace(effects=()), sm, data)[0][0]
    if residual != "replay":
        return None
    duty = rec.voltage_V / truth.supply.voltage_V
    phi = truth.simulate(duty=duty[:-1], angle_deg=math.degrees(truth.limp_home_rad)).angle_deg
    shape = sensor_kw.get("reading")
    if shape is not None:                      # a truth shape of the reading: the angle read through it
        read = np.degrees(shape.apply(np.radians(phi)))
        q = sensor_kw.get("resolution_deg", 90.0 / 4096)       # the recording's own grid after the shape
        return (q_round(read, q) if q else read), q_round(phi, 90.0 / 4096)
    return sensor_model(sensor_kw, rec.dt_s).apply(rec.t_s, phi, quantize=True), phi


def q_round(x, q):
    return q * np.round(np.asarray(x) / q)


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
