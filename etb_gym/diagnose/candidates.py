"""The candidate library: each effect id with its component (or sensor transform), fitted parameters and ties.

A candidate's fitted parameters start at ``init`` and are searched inside [lower, upper] in normalized
coordinates x = (p - init) / scale (so finite-difference steps and trust regions are comparable across
parameters). ``ties`` copy a plant parameter into the effect (the spring/stop corrections repeat the
plant's own spring/stop) so they follow the calibrated nominal values.

Any nameplate: the numbers in the table below are written for the default 3B plant; each parameter names
the nameplate quantity ``ref`` they are proportional to (stall torque, torque constant, friction level,
resistance, inductance, current, heating power, spring preload and rate, stop stiffness) or, for the stop
angles, the stop they are measured from. :meth:`Candidate.params_for` rescales them to the plant being
diagnosed (:func:`nameplate`), so starting values, steps and bounds follow the user's plant file.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..components import effects as fx


@dataclasses.dataclass(frozen=True)
class FitParam:
    name: str            # effect field (or "component.field" for nominal parameters)
    init: float
    lower: float
    upper: float
    scale: float
    unit: str
    follows: tuple = ()  # nominal only: other "component.field" keys scaled by the same ratio
    ref: str = ""        # nameplate quantity the numbers are written for (see NAMEPLATE_3B); "" absolute
    cap: str = ""        # nameplate quantity (times CAP_FRACTION) the upper bound may not exceed

    def for_nameplate(self, plate: dict) -> "FitParam":
        """This parameter with init, bounds and scale moved to the nameplate ``plate`` (see :func:`nameplate`)."""
        p = self
        if p.ref in SHIFT_REFS:
            d = plate[p.ref] - NAMEPLATE_3B[p.ref]
            p = dataclasses.replace(p, init=p.init + d, lower=p.lower + d, upper=p.upper + d)
        elif p.ref:
            f = max(plate[p.ref] / NAMEPLATE_3B[p.ref], MIN_RATIO)
            p = dataclasses.replace(p, init=p.init * f, lower=p.lower * f, upper=p.upper * f, scale=p.scale * f)
        if p.cap:
            hi = min(p.upper, CAP_FRACTION * plate[p.cap])
            init = p.init if p.init < hi else (0.5 * hi if hi > 0 else 0.5 * (p.lower + hi))
            p = dataclasses.replace(p, upper=hi, init=init)
        return p


@dataclasses.dataclass(frozen=True)
class Candidate:
    id: str
    family: str
    description: str
    fit: tuple
    component: type | None = None          # an Effect class (ODE) or None (sensor side)
    ties: tuple = ()                       # ((effect field, plant key), ...)
    fixed: tuple = ()                      # ((effect field, value), ...)
    # its small-parameter effect is, to first order, a change of a nominal parameter the calibration has already
    # fitted: its scan re-solves the nominal parameters at each point in open loop too (fit.fit, profile_scan)
    profiled: bool = False
    # its main (first) parameter adds to the nameplate quantity ``ref`` that every calibrated torque is balanced
    # against (a torque-constant error: the drive torque (c_M + delta) i): its scan also walks the calibration's
    # trade, the nominal torques co-scaled by (c_M + delta) / c_M at each point (fit.coscale_start)
    coscaled: bool = False
    # the effect switched off with its composition kept (states, segment restarts, the observer's structure):
    # ((effect field, value or plant key), ...); a plant key (a str, as in ``ties``) takes the plant's own value.
    # explain.switched_off uses it for the footprint guard (every fitted family has one)
    off: tuple = ()
    # starting values (physical, written for 3B as FitParam's numbers) of the *second* fitted parameter: where the
    # first's value alone does not place the fit's basin (a Stribeck velocity that spans decades over rigs), the
    # fit starts from the grid (scan values of the first) x (these), short fits from each and full fits from the
    # best few (fit.multi_start)
    starts: tuple = ()

    @property
    def sensor(self) -> bool:
        return self.component is None

    def params_for(self, plant) -> tuple:
        """The fitted parameters with starting values, bounds and scales for ``plant``'s nameplate."""
        plate = nameplate(plant)
        return tuple(p.for_nameplate(plate) for p in self.fit)


# ------------------------------------------------------------------------------------------ nameplate
MIN_RATIO = 0.05          # a nameplate quantity of 0 (no spring, say) still leaves the parameter a scale
CAP_FRACTION = 0.94
SHIFT_REFS = ("open_stop_rad", "closed_stop_rad")
_OPTIONAL = ("friction_Nm", "preload_Nm", "rate_Nm_per_rad", "stop_stiffness_Nm_per_rad")


def nameplate(plant, _base=None) -> dict:
    """The plant quantities the candidates' numbers scale with (SI units). For the default 3B plant this is
    NAMEPLATE_3B. Electrical quantities come from the drive, mechanical ones from the spring, friction
    and stops (missing components: the 3B value)."""
    d = plant.drive
    q = d.params
    R = float(q.resistance_ohm)
    V = float(plant.supply.voltage_V)
    lo = plant.angle_min_rad if math.isfinite(plant.angle_min_rad) else 0.0
    hi = plant.angle_max_rad if math.isfinite(plant.angle_max_rad) else math.pi / 2
    phis = np.linspace(lo, hi, 7)
    k = float(np.mean(np.abs(d.torque_constant(phis))))
    i_max = V / R
    L = np.asarray(d.inductance(np.linspace(0.0, 1.5 * i_max, 9)[:, None], phis[None, :]), float)
    out = {k: NAMEPLATE_3B[k] for k in _OPTIONAL} if _base is None else {}
    out.update(resistance_ohm=R, supply_V=V, current_A=i_max, power_W=V * i_max, inv_power_W=1.0 / (V * i_max),
               torque_constant_Nm_per_A=k, stall_torque_Nm=k * i_max,
               inductance_H=float(np.asarray(d.inductance(0.0, lo))),
               min_inductance_H=float(np.min(L)), open_stop_rad=hi, closed_stop_rad=lo)
    if plant.friction is not None:
        f = plant.friction.params.to_dict()
        if "coulomb_Nm" in f:
            out["friction_Nm"] = float(f["coulomb_Nm"])
        elif "viscous_Nm_s_per_rad" in f:                  # viscous only: the torque at 1 rad/s
            out["friction_Nm"] = float(f["viscous_Nm_s_per_rad"]) * 1.0
    if plant.spring is not None:
        sp = plant.spring.params
        out.update(preload_Nm=float(sp.preload_Nm), rate_Nm_per_rad=float(sp.rate_Nm_per_rad))
    if plant.stops is not None:
        out["stop_stiffness_Nm_per_rad"] = float(plant.stops.params.stiffness_Nm_per_rad)
    return out


class _Nameplate3B(dict):
    """:func:`nameplate` of the default 3B plant, computed on first use (the candidates' numbers are written
    for it, so for 3B every parameter keeps exactly the numbers of the table)."""

    def __missing__(self, key):
        if not dict.__len__(self):
            from ..plant import make_plant
            self.update(nameplate(make_plant("3B"), _base={}))
            return self[key]
        raise KeyError(key)


NAMEPLATE_3B = _Nameplate3B()


P = FitParam
R = math.radians
CANDIDATES: dict[str, Candidate] = {c.id: c for c in (
    Candidate("coil_heating", "electrical", fx.CoilHeating.description,
              (P("heat_capacity_J_per_K", 20.0, 0.5, 2000.0, 10.0, "J/K", ref="power_W"),
               P("thermal_resistance_K_per_W", 5.0, 0.2, 200.0, 5.0, "K/W", ref="inv_power_W")),
              fx.CoilHeating, ties=(("cold_resistance_ohm", "drive.resistance_ohm"),),
              off=(("temperature_coefficient_per_K", 0.0),)),
    Candidate("supply_drop", "electrical", fx.SupplyDrop.description,
              (P("series_resistance_ohm", 0.02, -0.5, 3.0, 0.1, "ohm", ref="resistance_ohm"),
               P("forward_drop_V", 0.05, -1.0, 3.0, 0.2, "V"),
               # the current over which the forward drop builds up is the rig's switch or diode, not a constant
               # (docs/diagnosis-history.md, open loop round 13: a diode-like drop with a 0.05-0.3 A knee)
               P("forward_current_A", 0.05, 0.005, 1.0, 0.05, "A", ref="current_A")), fx.SupplyDrop,
              off=(("series_resistance_ohm", 0.0), ("forward_drop_V", 0.0))),
    Candidate("torque_constant_error", "electrical", fx.TorqueConstantError.description,
              (P("delta_Nm_per_A", 0.0, -0.08, 0.08, 0.01, "N m/A", ref="torque_constant_Nm_per_A"),), fx.TorqueConstantError,
              # the calibration balances the drive torque with preload, rate and friction: it absorbs the error's
              # static part (docs/diagnosis-history.md round 16), so the fit starts along that trade
              coscaled=True, off=(("delta_Nm_per_A", 0.0),)),
    Candidate("inductance_saturation", "electrical", fx.InductanceSaturation.description,
              (P("inductance_drop_H", 0.001, -0.02, 0.0045, 0.002, "H", ref="inductance_H",
                 cap="min_inductance_H"),
               P("saturation_current_A", 1.5, 0.2, 10.0, 1.0, "A", ref="current_A")), fx.InductanceSaturation,
              off=(("inductance_drop_H", 0.0),)),
    Candidate("shaft_flux_loss", "magnetic", fx.ShaftFluxLoss.description,
              (P("loss_at_open_Nm_per_A", 0.01, -0.05, 0.12, 0.01, "N m/A", ref="torque_constant_Nm_per_A"),
               P("exponent", 2.0, 0.5, 8.0, 1.0, "1")), fx.ShaftFluxLoss, off=(("loss_at_open_Nm_per_A", 0.0),)),
    Candidate("spring_asymmetry", "mechanical", fx.SpringAsymmetry.description,
              (P("closing_preload_delta_Nm", 0.0, -0.14, 0.3, 0.02, "N m", ref="preload_Nm"),
               P("closing_rate_delta_Nm_per_rad", 0.0, -0.3, 1.5, 0.2, "N m/rad", ref="rate_Nm_per_rad")), fx.SpringAsymmetry,
              ties=(("limp_home_rad", "spring.limp_home_rad"),
                    ("limp_home_compliance_rad", "spring.limp_home_compliance_rad")),
              off=(("closing_preload_delta_Nm", 0.0), ("closing_rate_delta_Nm_per_rad", 0.0))),
    Candidate("backlash", "mechanical", fx.Backlash.description,
              (P("play_rad", 0.004, 0.0, 0.06, 0.003, "rad"), P("closing_ratio", 1.0, 0.0, 4.0, 0.25, "1")),
              fx.Backlash,
              ties=(("limp_home_rad", "spring.limp_home_rad"), ("preload_Nm", "spring.preload_Nm"),
                    ("rate_Nm_per_rad", "spring.rate_Nm_per_rad"),
                    ("limp_home_compliance_rad", "spring.limp_home_compliance_rad"),
                    ("limp_home_damping_Nm_s_per_rad", "spring.limp_home_damping_Nm_s_per_rad")),
              # outside the play the springs act at d - b sign d: exactly a preload lowered by R_F b
              # the closing side's play as a share r of the opening side's (a lever resting off the play's middle):
              # it starts at 1 (symmetric), so the screening and the scan see the symmetric play, and a recording
              # that never passes below limp-home leaves it there (no gradient): the unseen side mirrors the seen one
              profiled=True, off=(("play_rad", 0.0), ("closing_ratio", 1.0))),
    Candidate("end_stop_compliance", "mechanical", fx.EndStopCompliance.description,
              (P("open_rad", R(90.0), R(84.0), R(96.0), R(0.5), "rad", ref="open_stop_rad"),
               P("closed_rad", 0.0, R(-3.0), R(3.0), R(0.2), "rad", ref="closed_stop_rad"),
               P("stiffness_Nm_per_rad", 1000.0, 20.0, 1e5, 300.0, "N m/rad", ref="stop_stiffness_Nm_per_rad")), fx.EndStopCompliance,
              ties=(("nominal_closed_rad", "stops.closed_rad"), ("nominal_open_rad", "stops.open_rad"),
                    ("nominal_stiffness_Nm_per_rad", "stops.stiffness_Nm_per_rad"),
                    ("nominal_damping_Nm_s_per_rad", "stops.damping_Nm_s_per_rad"),
                    ("damping_Nm_s_per_rad", "stops.damping_Nm_s_per_rad")),
              off=(("open_rad", "stops.open_rad"), ("closed_rad", "stops.closed_rad"),
                   ("stiffness_Nm_per_rad", "stops.stiffness_Nm_per_rad"))),
    Candidate("airflow_torque", "mechanical", fx.AirflowTorque.description,
              (P("quadratic_Nm", 0.0, -0.6, 0.6, 0.02, "N m", ref="stall_torque_Nm"),
               P("cubic_Nm", 0.0, -0.6, 0.6, 0.02, "N m", ref="stall_torque_Nm")), fx.AirflowTorque,
              off=(("quadratic_Nm", 0.0), ("cubic_Nm", 0.0))),
    Candidate("stribeck_friction", "friction", fx.StribeckFriction.description,
              (P("stiction_Nm", 0.01, 0.0, 0.4, 0.02, "N m", ref="friction_Nm"),
               P("stribeck_velocity_rad_s", 0.05, 0.002, 3.0, 0.05, "rad/s")), fx.StribeckFriction,
              # the drop's exponent (StribeckFrictionParams.exponent) stays at the paper's 0.5: fitted in [0.5, 2]
              # (round 29) it fitted training recordings better, but the twins moved both ways (held-out 6.5x ->
              # 32.6x on the blind 3B s38, 11.6x -> 4.7x on s37, 10.7x -> 22.0x on s21) at up to 7x the CPU
              # (docs/diagnosis-history.md, round 29 a29stribeck and the seed-19 survey)
              # a rig's Stribeck velocity spans decades (0.02-1 rad/s); from 0.05 alone the fit of a rational drop
              # stayed at stiction 0.144 N m (truth 0.080), RSS 2x the best start's (docs/diagnosis-history.md round 21)
              off=(("stiction_Nm", 0.0),), starts=(0.2, 1.0)),
    Candidate("angle_dependent_friction", "friction", fx.AngleDependentFriction.description,
              (P("slope_Nm", 0.0, -0.3, 0.3, 0.02, "N m", ref="friction_Nm"),
               P("curvature_Nm", 0.0, -0.8, 0.8, 0.05, "N m", ref="friction_Nm")), fx.AngleDependentFriction,
              off=(("slope_Nm", 0.0), ("curvature_Nm", 0.0))),
    Candidate("sensor_offset_gain", "sensing", "position sensor offset, gain or curvature error",
              (P("offset_deg", 0.0, -10.0, 10.0, 0.1, "deg"), P("gain", 1.0, 0.7, 1.3, 0.01, "1"),
               P("bow_deg", 0.0, -3.0, 3.0, 0.05, "deg")),           # the bow: BOW_PARAM, below
              off=(("offset_deg", 0.0), ("gain", 1.0), ("bow_deg", 0.0))),
    Candidate("sensor_delay", "sensing", "transport delay in the position measurement",
              (P("delay_s", 0.001, 0.0, 0.05, 0.002, "s"),), off=(("delay_s", 0.0),)),
    Candidate("sensor_quantization", "sensing", "position sensor resolution coarser than assumed", ()),
)}

# ------------------------------------------------------------------------------------------ sensor side
# The bow: a reading curve's curvature, the third parameter of sensor_offset_gain (sensor_fields builds it). In a closed
# loop the loop holds the reading, so offset and gain trade exactly against the calibrated spring's preload and rate;
# only a curvature is left to see (docs/diagnosis-history.md, round 26 n26sensor). In open loops too since round 27
# (t27bow): there a static torque over angle moves the plate's rest angle, which a bowed reading curve mimics, so a
# reading map that leads is asked whether the current (its back-EMF follows the true motion, not the reading) sides
# with a torque (discriminate.reading_or_motion).
BOW_PARAM = CANDIDATES["sensor_offset_gain"].fit[2]
BOW_KNOTS = 17            # knots of the bow's curve over the travel (a parabola's interpolation error: bow / 256)


def bow_curve(bow_deg: float, lo_rad: float, hi_rad: float, held=None):
    """The reading error of a bow: a parabola over the travel [lo, hi] (the stops), ``bow_deg`` at mid-travel and
    zero at the stops, d(phi) = 4 b u (1 - u), u = (phi - lo) / (hi - lo): with the offset and gain free, any
    quadratic reading error over angle. ``held`` (a learned SensorMapParams, sensor_map.py) is added to it on the
    union of both grids (the learned curve is learned on top of the bow). SensorMapParams, or ``held`` if b = 0."""
    from ..components.effects_maps import SensorMapParams
    if bow_deg == 0.0:
        return held
    if not hi_rad > lo_rad:
        raise ValueError(f"a reading bow needs the plant's travel; its stops are {lo_rad} and {hi_rad} rad")
    grid = np.linspace(lo_rad, hi_rad, BOW_KNOTS)
    if held is not None:
        grid = np.union1d(grid, np.asarray(held.angle_rad, float))
    u = np.clip((grid - lo_rad) / (hi_rad - lo_rad), 0.0, 1.0)
    err = 4.0 * math.radians(bow_deg) * u * (1.0 - u)
    if held is not None:
        err = err + np.interp(grid, np.asarray(held.angle_rad, float), np.asarray(held.error_rad, float))
    return SensorMapParams(angle_rad=tuple(float(a) for a in grid), error_rad=tuple(float(e) for e in err))


def sensor_fields(fields: dict, plant, held: dict | None) -> dict:
    """SensorModel's fields from the sensing candidates' fitted ``fields`` and the held maps ``held``
    (Spec.sensor_map): a bow becomes a reading curve over the plant's travel, added to a held curve."""
    out = {**fields, **(held or {})}
    bow = out.pop("bow_deg", 0.0)
    if bow != 0.0:
        lo = plant.angle_min_rad if math.isfinite(plant.angle_min_rad) else 0.0
        hi = plant.angle_max_rad if math.isfinite(plant.angle_max_rad) else math.pi / 2
        out["curve"] = bow_curve(bow, lo, hi, (held or {}).get("curve"))
    return out


FITTED_CANDIDATES = tuple(k for k, c in CANDIDATES.items() if c.fit)

def candidate(cid: str) -> Candidate:
    if cid not in CANDIDATES:
        raise ValueError(f"unknown effect id {cid!r}; valid: {', '.join(CANDIDATES)}")
    return CANDIDATES[cid]


# nominal parameters that are uncertain on every rig, by friction model digit
def nominal_params(plant) -> tuple:
    """The calibration's parameters for ``plant`` (friction level, spring preload and rate)."""
    f = plant.friction
    out = []
    if f is not None:
        q = f.params.to_dict()
        if "coulomb_Nm" in q:
            follows = ("friction.static_Nm",) if "static_Nm" in q else ()
            out.append(P("friction.coulomb_Nm", q["coulomb_Nm"], 0.2 * q["coulomb_Nm"], 4 * q["coulomb_Nm"],
                         0.1 * q["coulomb_Nm"], "N m", follows))
        elif "viscous_Nm_s_per_rad" in q:
            v = q["viscous_Nm_s_per_rad"]
            out.append(P("friction.viscous_Nm_s_per_rad", v, 0.05 * v, 20 * v, 0.2 * v, "N m s/rad"))
    if plant.spring is not None:
        s = plant.spring.params
        out.append(P("spring.preload_Nm", s.preload_Nm, 0.0, 4 * s.preload_Nm + 0.1, 0.1 * s.preload_Nm + 1e-3, "N m"))
        out.append(P("spring.rate_Nm_per_rad", s.rate_Nm_per_rad, 0.0, 4 * s.rate_Nm_per_rad + 0.1,
                     0.1 * s.rate_Nm_per_rad + 1e-3, "N m/rad"))
    return tuple(out)
