"""The controller registry: every gain/exposure controller by name, with its typed config and report style.

A controller registers where it is defined (`expoctl.plugins` has the rules, entry points included):

    @dataclass(frozen=True)
    class HoldConfig:
        gain_db: float = 0.0

    @register_controller("hold", config=HoldConfig, label="Hold")
    class HoldController(Controller):
        def __init__(self, config: HoldConfig): ...

Its config section is `controllers.<name>` (absent: every default). What a controller may need besides its config
is known only where it runs, and comes as a `ControllerContext`: `needs` names it at registration ("checkpoint":
the learned network's file; "scene": the simulator's scene and sensor, so it cannot drive a real camera or collect).
"""

from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass, fields, is_dataclass, replace
from typing import Any

from expoctl.controllers.base import Controller
from expoctl.errors import ConfigError
from expoctl.plugins import Plugin, Registry

#: what a controller can need at run time besides its config (`needs=` at registration)
NEEDS = ("checkpoint", "scene")

#: built-ins: every module of expoctl.controllers, the oracle (it renders the scene, so it lives with the simulator) and
#: the reinforcement-learning baseline (it sees what the benchmark environment delivers, so it lives with the benchmark)
CONTROLLERS = Registry("controller", "expoctl.controllers", "controllers",
                       ("expoctl.controllers", "expoctl.sim.oracle", "expoctl.bench.rl.controller"), ("reset", "update"))


@dataclass(frozen=True)
class ControllerContext:
    """The run-time inputs of a controller (those its registration `needs`)."""

    seed: int = 0
    checkpoint: str | None = None    # needs "checkpoint": the trained network (.pt; its .onnx beside it)
    scene: Any = None                # needs "scene": the simulator's scene (RouteScene / CachedScene) ...
    sensor: Any = None               # ... its sensor,
    n_frames: int | None = None      # ... the traversal's length in frames
    first_frame: int = 0             # ... and the first frame the loop runs (warm-up included)


def register_controller(name: str, *, config: type, needs: tuple[str, ...] = (), **kw: Any):
    """Decorator: register a controller class (or, with `factory=`, anything) under `name`; see the module doc.
    `label`, `colour` and `rank` set how reports show it."""
    bad = [n for n in needs if n not in NEEDS]
    if bad:
        raise ValueError(f"controller {name!r}: needs= names {bad}, known: {list(NEEDS)}")
    return CONTROLLERS.register(name, config=config, needs=tuple(needs), **kw)


def controller(name: str, key: str | None = None) -> Plugin:
    """The registry entry `name` (ConfigError at `key`, default `controllers.<name>`, if unknown or broken)."""
    return CONTROLLERS.get(name, key)


def needs(name: str) -> tuple[str, ...]:
    return tuple(controller(name).info.get("needs", ()))


def controller_names(*, runs_without: tuple[str, ...] = (), opt_in: bool = False) -> tuple[str, ...]:
    """Every registered controller in table order (what `evaluate.controllers: null` drives); with `runs_without`,
    those that need none of those inputs (e.g. `runs_without=("scene",)`: the ones that can drive a real camera or
    collect). Controllers registered with `opt_in=True` (`rl`: its agent comes from an optional stage, off by
    default) only with `opt_in=True`: a default run must not need a model no default stage makes."""
    return tuple(p.name for p in CONTROLLERS.entries() if not set(p.info.get("needs", ())) & set(runs_without)
                 and (opt_in or not p.info.get("opt_in", False)))


def is_opt_in(name: str) -> bool:
    return bool(controller(name).info.get("opt_in", False))


def read_controller_config(name: str, section: Any, problems=None, key: str | None = None) -> Any:
    """`controllers.<name>` as its typed config (every problem with its key path)."""
    key = key or f"controllers.{name}"
    return controller(name, key).read_config(section, key, problems)


def make_controller(name: str, config: Any = None, context: ControllerContext | None = None) -> Controller:
    """A fresh controller `name` from its typed config (or its section as a mapping, read here; None: defaults)
    and the run-time `context` its registration needs."""
    entry = controller(name)
    if not isinstance(config, entry.config):
        config = entry.read_config(config, f"controllers.{name}")
    context = context or ControllerContext()
    for need in entry.info.get("needs", ()):
        missing = [f for f in (("scene", "sensor", "n_frames") if need == "scene" else (need,))
                   if getattr(context, f) is None and getattr(config, f, None) is None]
        if missing:
            raise ConfigError(f"controllers.{name}", f"needs {', '.join(missing)} at run time ({entry.origin}): "
                              + ("it renders candidate frames, so it runs only inside the simulator (evaluate)"
                                 if need == "scene" else "a trained network"))
    return entry.factory(config, context)


@dataclass(frozen=True)
class NoConfig:
    """The config of a controller given by import path without a `Config` of its own: no keys."""


def resolve_controller(ref: str, key: str = "controller") -> str:
    """The registry name of `ref`: a registered name as is, or an import path "module:attr" (e.g.
    "my_pkg.ctl:HoldController"). An import path to a registered object gives its name; to a plain Controller
    class, registers it here under its `name` attribute (else the attribute name), with its `Config` class
    attribute as config when that is a frozen dataclass (else no keys). Any process that resolves the same path
    gets the same name (evaluate's workers do, before they build it). ConfigError at `key` naming what is wrong."""
    if ":" not in ref:
        controller(ref, key)
        return ref
    module_name, _, attr = ref.partition(":")
    if not module_name or not attr:
        raise ConfigError(key, f"{ref!r} is neither a registered controller nor an import path 'module:Class'")
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:  # whatever the user's module raises on import
        raise ConfigError(key, f"{ref!r}: importing {module_name!r} failed: {type(exc).__name__}: {exc}") from None
    obj = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise ConfigError(key, f"{ref!r}: module {module_name!r} has no attribute {attr!r}")
        obj = getattr(obj, part)
    known = CONTROLLERS.name_of(obj)
    if known is not None:
        return known
    if not inspect.isclass(obj):
        raise ConfigError(key, f"{ref!r} is a {type(obj).__name__}, not a controller class (register a factory "
                          "with @register_controller(..., factory=...) instead)")
    name = getattr(obj, "name", None)
    name = name if isinstance(name, str) and name.isidentifier() and name != Controller.name else attr.split(".")[-1]
    config = getattr(obj, "Config", None)
    config = config if inspect.isclass(config) and is_dataclass(config) else NoConfig
    taken = CONTROLLERS.get(name) if name in CONTROLLERS else None
    if taken is not None:
        raise ConfigError(key, f"{ref!r} would register as {name!r}, a name taken by {taken.origin}; give the class "
                          "another `name`")
    problem = CONTROLLERS.problem_of(name, obj, config)
    if problem:
        raise ConfigError(key, f"{ref!r}: {problem}")
    factory = None
    try:
        params = inspect.signature(obj).parameters
    except (TypeError, ValueError):
        params = {"config": None}
    if not params:  # a class built with no arguments (no config of its own)
        factory = lambda _config, _context: obj()  # noqa: E731
    elif set(params) == {"context"}:
        factory = lambda _config, context: obj(context=context)  # noqa: E731
    CONTROLLERS.register(name, config=config, factory=factory, label=getattr(obj, "label", None) or name)(obj)
    return name


def with_limits(config: Any, limits: dict[str, float]) -> Any:
    """`config` with each of the keys `limits` names (exposure_lower_us, gain_upper_db, …) that it or a nested
    config has set to the given value: a real camera's usable range, as its own AE has it."""
    if not is_dataclass(config):
        return config
    changes = {}
    for f in fields(config):
        value = getattr(config, f.name)
        if f.name in limits:
            changes[f.name] = float(limits[f.name])
        elif is_dataclass(value):
            changes[f.name] = with_limits(value, limits)
    return replace(config, **changes)
