"""Reference controllers for the ETB envs: the protocol, designed PID, sliding mode, design helpers.

    from etb_gym.controllers import make_controller
    ctrl = make_controller("pid")            # or "smc", "pid-plain", "pkg.module:Class", "rl:PATH"
    ctrl.reset(seed=0)
    duty = ctrl.act(observation)             # observation of etb_gym.envs (see envs/observation.py)
"""
from .base import (CONTROLLERS, BaseController, Controller, VelocityEstimator, controller_prefixes,
                   make_controller, register_controller_prefix)

__all__ = ["CONTROLLERS", "BaseController", "Controller", "VelocityEstimator", "controller_prefixes",
           "make_controller", "register_controller_prefix"]
