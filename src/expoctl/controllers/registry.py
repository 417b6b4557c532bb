"""Name → controller factory. `make_controller("agae", cfg["controllers"]["agae"])`.

`CONTROLLERS` is a plain dict so other modules (the simulator's oracle) can add themselves with `register(...)`
without editing this file. A factory takes the controller's own config section (a dict, possibly empty) and returns a
fresh Controller; unknown keys and bad values raise ConfigError("controllers.<name>.<key>", ...).
"""

from __future__ import annotations

from collections.abc import Callable

from expoctl.controllers.base import Controller
from expoctl.errors import ConfigError

ControllerFactory = Callable[[dict], Controller]


def _agae(params: dict) -> Controller:
    from expoctl.controllers.agae import AgAeController

    return AgAeController(params)


def _shin(params: dict) -> Controller:
    from expoctl.controllers.shin import ShinController

    return ShinController(params)


def _shim(params: dict) -> Controller:
    from expoctl.controllers.shim import ShimController

    return ShimController(params)


def _mean_intensity(params: dict) -> Controller:
    from expoctl.controllers.mean_intensity import MeanIntensityController

    return MeanIntensityController(params)


def _fixed(params: dict) -> Controller:
    from expoctl.controllers.fixed import FixedController

    return FixedController(params)


def _learned(params: dict) -> Controller:
    # imported lazily: it needs torch and a trained checkpoint (params["checkpoint"])
    from expoctl.controllers.learned import make_learned

    return make_learned(params)


CONTROLLERS: dict[str, ControllerFactory] = {
    "agae": _agae,
    "shin": _shin,
    "shim": _shim,
    "mean_intensity": _mean_intensity,
    "fixed": _fixed,
    "learned": _learned,
}


def register(name: str, factory: ControllerFactory) -> None:
    """Add (or replace) a controller factory under `name`."""
    CONTROLLERS[name] = factory


def make_controller(name: str, params: dict | None = None) -> Controller:
    """Build the controller called `name` from its config section `params` (None = all defaults)."""
    if name not in CONTROLLERS:
        raise ConfigError("controllers", f"unknown controller {name!r} (known: {', '.join(sorted(CONTROLLERS))})")
    return CONTROLLERS[name]({} if params is None else params)
