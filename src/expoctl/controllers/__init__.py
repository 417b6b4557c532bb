"""Causal exposure controllers behind one interface (`base`): AG+AE (`agae`), Shin et al. (`shin`), Shim et al.
(`shim`), mean intensity, fixed settings and the learned network (`learned`: it needs torch and a checkpoint).
`registry` holds every controller by name with its typed config; each module registers its own controller, and
installed packages add theirs through the `expoctl.controllers` entry point group (docs/add_controller.md). The
oracle renders the scene, so it lives in the simulator (`expoctl.sim.oracle`, which registers it).
"""

from expoctl.controllers.agae import split_exposure_first
from expoctl.controllers.base import Controller, Settings, TimedController
from expoctl.controllers.registry import (CONTROLLERS, ControllerContext, controller_names, make_controller,
                                          register_controller)

__all__ = ["CONTROLLERS", "Controller", "ControllerContext", "Settings", "TimedController", "controller_names",
           "make_controller", "register_controller", "split_exposure_first"]
