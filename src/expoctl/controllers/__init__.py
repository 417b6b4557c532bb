"""Causal exposure controllers behind one interface (`base`): AG+AE (`agae`), Shin et al. (`shin`), Shim et al.
(`shim`), mean intensity, fixed settings and the learned network (`learned`; the registry imports it only to build
it: it needs torch and a checkpoint). `registry` builds any of them by name from its config section. The oracle
renders the scene, so it belongs to the simulator (`expoctl.sim.oracle`).
"""

from expoctl.controllers.agae import split_exposure_first
from expoctl.controllers.base import Controller, Settings, TimedController
from expoctl.controllers.registry import make_controller, register

__all__ = ["Controller", "Settings", "TimedController", "make_controller", "register", "split_exposure_first"]
