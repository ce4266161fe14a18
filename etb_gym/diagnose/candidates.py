"""The candidate library: each effect id with its component (or sensor transform), fitted parameters and ties.

A candidate's fitted parameters start at ``init`` and are searched inside [lower, upper] in normalized
coordinates x = (p - init) / scale (so finite-difference steps and trust regions are comparable across
parameters). ``ties`` copy a plant parameter into the effect (the spring/stop corrections repeat the
plant's own spring/stop) so they follow the calibrated nominal values.
"""
from __future__ import annotations

import dataclasses
import math

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


@dataclasses.dataclass(frozen=True)
class Candidate:
    id: str
    family: str
    description: str
    fit: tuple
    component: type | None = None          # an Effect class (ODE) or None (sensor side)
    ties: tuple = ()                       # ((effect field, plant key), ...)
    fixed: tuple = ()                      # ((effect field, value), ...)

    @property
    def sensor(self) -> bool:
        return self.component is None


P = FitParam
R = math.radians
CANDIDATES: dict[str, Candidate] = {c.id: c for c in (
    Candidate("coil_heating", "electrical", fx.CoilHeating.description,
              (P("heat_capacity_J_per_K", 20.0, 0.5, 2000.0, 10.0, "J/K"),
               P("thermal_resistance_K_per_W", 5.0, 0.2, 200.0, 5.0, "K/W")),
              fx.CoilHeating, ties=(("cold_resistance_ohm", "drive.resistance_ohm"),)),
    Candidate("supply_drop", "electrical", fx.SupplyDrop.description,
              (P("series_resistance_ohm", 0.02, -0.5, 3.0, 0.1, "ohm"),
               P("forward_drop_V", 0.05, -1.0, 3.0, 0.2, "V")), fx.SupplyDrop),
    Candidate("torque_constant_error", "electrical", fx.TorqueConstantError.description,
              (P("delta_Nm_per_A", 0.0, -0.08, 0.08, 0.01, "N m/A"),), fx.TorqueConstantError),
    Candidate("inductance_saturation", "electrical", fx.InductanceSaturation.description,
              (P("inductance_drop_H", 0.001, -0.02, 0.0045, 0.002, "H"),
               P("saturation_current_A", 1.5, 0.2, 10.0, 1.0, "A")), fx.InductanceSaturation),
    Candidate("shaft_flux_loss", "magnetic", fx.ShaftFluxLoss.description,
              (P("loss_at_open_Nm_per_A", 0.01, -0.05, 0.12, 0.01, "N m/A"),
               P("exponent", 2.0, 0.5, 8.0, 1.0, "1")), fx.ShaftFluxLoss),
    Candidate("spring_asymmetry", "mechanical", fx.SpringAsymmetry.description,
              (P("closing_preload_delta_Nm", 0.0, -0.14, 0.3, 0.02, "N m"),
               P("closing_rate_delta_Nm_per_rad", 0.0, -0.3, 1.5, 0.2, "N m/rad")), fx.SpringAsymmetry,
              ties=(("limp_home_rad", "spring.limp_home_rad"),
                    ("limp_home_compliance_rad", "spring.limp_home_compliance_rad"))),
    Candidate("backlash", "mechanical", fx.Backlash.description,
              (P("play_rad", 0.004, 0.0, 0.06, 0.003, "rad"),), fx.Backlash,
              ties=(("limp_home_rad", "spring.limp_home_rad"), ("preload_Nm", "spring.preload_Nm"),
                    ("rate_Nm_per_rad", "spring.rate_Nm_per_rad"),
                    ("limp_home_compliance_rad", "spring.limp_home_compliance_rad"),
                    ("limp_home_damping_Nm_s_per_rad", "spring.limp_home_damping_Nm_s_per_rad"))),
    Candidate("end_stop_compliance", "mechanical", fx.EndStopCompliance.description,
              (P("open_rad", R(90.0), R(84.0), R(96.0), R(0.5), "rad"),
               P("closed_rad", 0.0, R(-3.0), R(3.0), R(0.2), "rad"),
               P("stiffness_Nm_per_rad", 1000.0, 20.0, 1e5, 300.0, "N m/rad")), fx.EndStopCompliance,
              ties=(("nominal_closed_rad", "stops.closed_rad"), ("nominal_open_rad", "stops.open_rad"),
                    ("nominal_stiffness_Nm_per_rad", "stops.stiffness_Nm_per_rad"),
                    ("nominal_damping_Nm_s_per_rad", "stops.damping_Nm_s_per_rad"),
                    ("damping_Nm_s_per_rad", "stops.damping_Nm_s_per_rad"))),
    Candidate("airflow_torque", "mechanical", fx.AirflowTorque.description,
              (P("quadratic_Nm", 0.0, -0.6, 0.6, 0.02, "N m"),
               P("cubic_Nm", 0.0, -0.6, 0.6, 0.02, "N m")), fx.AirflowTorque),
    Candidate("stribeck_friction", "friction", fx.StribeckFriction.description,
              (P("stiction_Nm", 0.01, 0.0, 0.4, 0.02, "N m"),
               P("stribeck_velocity_rad_s", 0.05, 0.002, 3.0, 0.05, "rad/s")), fx.StribeckFriction),
    Candidate("angle_dependent_friction", "friction", fx.AngleDependentFriction.description,
              (P("slope_Nm", 0.0, -0.3, 0.3, 0.02, "N m"),
               P("curvature_Nm", 0.0, -0.8, 0.8, 0.05, "N m")), fx.AngleDependentFriction),
    Candidate("sensor_offset_gain", "sensing", "position sensor offset or gain error",
              (P("offset_deg", 0.0, -10.0, 10.0, 0.1, "deg"), P("gain", 1.0, 0.7, 1.3, 0.01, "1"))),
    Candidate("sensor_delay", "sensing", "transport delay in the position measurement",
              (P("delay_s", 0.001, 0.0, 0.05, 0.002, "s"),)),
    Candidate("sensor_quantization", "sensing", "position sensor resolution coarser than assumed", ()),
)}

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
