"""Reference controllers for the ETB envs: the protocol, the ECU cascade (PID, sliding mode, proximate
time-optimal servo), the voltage-mode PID and sliding mode they replaced, design helpers.

    from etb_gym.controllers import make_controller
    ctrl = make_controller("pid")            # or "smc", "ptos", "pid-plain", "smc-plain", "pkg.module:Class", "rl:PATH"
    ctrl.reset(seed=0)
    duty = ctrl.act(observation)             # observation of etb_gym.envs (see envs/observation.py)

Each controller module registers its names (``register_controller``) when imported; this package imports
them all, and nothing imports back.
"""
from . import cascade, pid, ptos, smc  # noqa: F401  (register "pid", "smc", "ptos", "pid-plain", "pid-nocomp", "smc-plain")
from .base import (CONTROLLERS, BaseController, Controller, VelocityEstimator, controller_prefixes,
                   make_controller, register_controller, register_controller_prefix)

__all__ = ["CONTROLLERS", "BaseController", "Controller", "VelocityEstimator", "controller_prefixes",
           "make_controller", "register_controller", "register_controller_prefix"]
