"""The nominal plant model the controllers are built on (what a control engineer would have on paper).

Everything is read from a core :class:`etb_gym.Plant` (default ``make_plant("3B")``); the spring torque is
evaluated with the spring component's own kernel, so there is one implementation of eq. 19.

Quasi-static coil (L di/dt neglected) used by the feed-forward terms:

    u = R * T / k + k * omega          voltage that produces shaft torque T at speed omega

Load torques the feed-forward cancels (positive = opposing opening):

    T_spring(phi) = R_F (phi - phi_LH) + T_SP0 sat((phi - phi_LH)/eps)         (limp-home spring, eq. 19)
    T_fric(omega) ~ T_c sgn(omega) + sigma2 omega                               (sliding-regime friction)
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from etb_gym import Plant, make_plant


@dataclass(frozen=True)
class NominalModel:
    """Nominal parameters (SI) of an ETB plant, as seen by the controller designer."""

    inertia_kg_m2: float
    resistance_ohm: float
    inductance_H: float                   # small-signal inductance at zero current, limp-home
    torque_constant_Nm_per_A: float       # at limp-home (drive C: k_C cos(phi_LH))
    limp_home_rad: float
    preload_Nm: float
    spring_rate_Nm_per_rad: float
    limp_home_compliance_rad: float
    coulomb_Nm: float
    static_Nm: float
    viscous_Nm_s_per_rad: float
    bristle_stiffness_Nm_per_rad: float   # presliding stiffness (0 for viscous friction)
    supply_V: float
    control_period_s: float
    closed_rad: float
    open_rad: float
    plant: Plant = field(repr=False, compare=False, default=None)

    @classmethod
    def from_plant(cls, plant: Plant) -> "NominalModel":
        sp = plant.spring.params if plant.spring is not None else None
        lh = sp.limp_home_rad if sp is not None else 0.0
        drv = plant.drive
        k = float(np.asarray(drv.torque_constant(lh)))
        L = float(np.asarray(drv.inductance(0.0, lh)))
        fp = plant.friction.params if plant.friction is not None else None
        coul = float(getattr(fp, "coulomb_Nm", 0.0)) if fp is not None else 0.0
        stat = float(getattr(fp, "static_Nm", coul)) if fp is not None else 0.0
        visc = float(getattr(fp, "viscous_Nm_s_per_rad", 0.0)) if fp is not None else 0.0
        sig0 = float(getattr(fp, "bristle_stiffness_Nm_per_rad", 0.0)) if fp is not None else 0.0
        return cls(
            inertia_kg_m2=plant.rotor.inertia_kg_m2, resistance_ohm=drv.params.resistance_ohm,
            inductance_H=L, torque_constant_Nm_per_A=k, limp_home_rad=lh,
            preload_Nm=sp.preload_Nm if sp else 0.0, spring_rate_Nm_per_rad=sp.rate_Nm_per_rad if sp else 0.0,
            limp_home_compliance_rad=sp.limp_home_compliance_rad if sp else 1e-3,
            coulomb_Nm=coul, static_Nm=stat, viscous_Nm_s_per_rad=visc, bristle_stiffness_Nm_per_rad=sig0,
            supply_V=plant.supply.voltage_V, control_period_s=plant.control_period_s,
            closed_rad=plant.angle_min_rad, open_rad=plant.angle_max_rad, plant=plant)

    @classmethod
    def for_model(cls, model: str = "3B", params: dict | None = None, supply_V: float | None = None) -> "NominalModel":
        return cls.from_plant(make_plant(model, params, supply_V=supply_V))

    # ---------------------------------------------------------------------------------- load torques
    def spring_torque_Nm(self, phi_rad: float) -> float:
        """Torque the limp-home springs exert against opening at rest (eq. 19 via the core kernel)."""
        if self.plant is None or self.plant.spring is None:
            return 0.0
        spring = self.plant.spring
        p = np.asarray(spring.param_vector(), float)
        tq, _, _ = _spring_py(spring)(0.0, float(phi_rad), 0.0, 0.0, 0.0, _EMPTY, p, _EMPTY)
        return -float(tq)

    @property
    def volts_per_Nm(self) -> float:
        return self.resistance_ohm / self.torque_constant_Nm_per_A

    def describe(self) -> str:
        return (f"J={self.inertia_kg_m2:.3g} kg m^2, R={self.resistance_ohm:.3g} ohm, L={self.inductance_H:.3g} H, "
                f"k={self.torque_constant_Nm_per_A:.3g} Nm/A, R_F={self.spring_rate_Nm_per_rad:.3g} Nm/rad, "
                f"T_SP0={self.preload_Nm:.3g} Nm, T_c={self.coulomb_Nm:.3g} Nm, T_s={self.static_Nm:.3g} Nm, "
                f"sigma2={self.viscous_Nm_s_per_rad:.3g} Nm s/rad, V={self.supply_V:.3g} V")


_EMPTY = np.zeros(0)


def _spring_py(spring):
    k = spring.kernel
    return getattr(k, "py_func", k)


def resolve_model(model=None, params: dict | None = None) -> NominalModel:
    """Accept a NominalModel, a Plant, or a model name ("1A".."3C", default "3B") + overrides."""
    if isinstance(model, NominalModel):
        return model
    if isinstance(model, Plant):
        return NominalModel.from_plant(model.with_params(params) if params else model)
    return NominalModel.for_model("3B" if model is None else str(model), params)


_MODELS_BY_KEY: dict = {}


def model_key(nom: NominalModel) -> str:
    """A hashable key of a nominal model (its plant's parameters and drive), for caching designs per model.
    :func:`model_for_key` returns the model again."""
    p = nom.plant
    key = repr(sorted(p.params_dict().items())) + str(p.model) + type(p.drive).__name__ + repr(nom.supply_V)
    _MODELS_BY_KEY.setdefault(key, nom)
    return key


def model_for_key(key: str) -> NominalModel:
    return _MODELS_BY_KEY[key]
