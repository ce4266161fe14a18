"""Physical components of an ETB plant, one file per effect (see base.py for the kernel contract)."""
from .base import REGISTRY, Component, Params
from .drive import (DRIVES, FluxDrive, FluxDriveParams, InductanceTable, LinearDrive, LinearDriveParams,
                    NonlinearInductanceDrive, NonlinearInductanceDriveParams)
from .friction import (FRICTIONS, DahlFriction, DahlFrictionParams, LuGreFriction, LuGreFrictionParams,
                       ViscousFriction, ViscousFrictionParams)
from .rotor import RotorParams
from .sensor import PositionSensor, PositionSensorParams
from .spring import LimpHomeSpring, LimpHomeSpringParams
from .stops import EndStops, EndStopsParams
from .supply import PWM_MODES, SupplyParams
from . import effects  # noqa: E402,F401  registers the diagnosis effects (kinds effect.*) for plant files

__all__ = [n for n in dir() if not n.startswith("_")]
