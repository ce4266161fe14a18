"""The diagnosis tool's candidate effects that act inside the ODE, as plant components (by effect id).

    from etb_gym.components.effects import ShaftFluxLoss
    plant = make_plant("3B", effects=[ShaftFluxLoss(loss_at_open_Nm_per_A=0.03)])

Equations: effects_electrical.py, effects_mechanical.py, effects_friction.py. Sensor-side effects
(offset/gain, delay, quantization) act on the measurement, not on the plate: see
``etb_gym.diagnose.measurement``. Importing this module registers the kinds ``effect.<id>`` so plant
files holding them load (``etb_gym.plantfile.load_plant``).
"""
from __future__ import annotations

from .effects_electrical import (CoilHeating, CoilHeatingParams, Effect, InductanceSaturation,
                                 InductanceSaturationParams, ShaftFluxLoss, ShaftFluxLossParams, SupplyDrop,
                                 SupplyDropParams, TorqueConstantError, TorqueConstantErrorParams)
from .effects_friction import (AngleDependentFriction, AngleDependentFrictionParams, StribeckFriction,
                               StribeckFrictionParams)
from .effects_mechanical import (AirflowTorque, AirflowTorqueParams, Backlash, BacklashParams, EndStopCompliance,
                                 EndStopComplianceParams, SpringAsymmetry, SpringAsymmetryParams)
from .effects_maps import (MAP_EFFECTS, AngleFrictionMap, AngleTorqueMap, CurrentVoltageMap, SensorMap,  # noqa: F401
                           SpeedFrictionMap, TorqueConstantMap,  # tables learned from data (diagnosis-shapes.md)
                           CurrentInductanceMap, CurrentTorqueConstantMap, CurrentTorqueMap)
from .effects_thermal import ThermalNetwork, ThermalNetworkParams  # noqa: F401  (a Foster network, learned)
from .effects_periodic import PeriodicAngleTorque, PeriodicAngleTorqueParams  # noqa: F401  (a Fourier series in angle)

ODE_EFFECTS: dict[str, type[Effect]] = {c.effect_id: c for c in (
    CoilHeating, SupplyDrop, TorqueConstantError, InductanceSaturation, ShaftFluxLoss,
    SpringAsymmetry, Backlash, EndStopCompliance, AirflowTorque,
    StribeckFriction, AngleDependentFriction)}

__all__ = [n for n in dir() if not n.startswith("_")]
