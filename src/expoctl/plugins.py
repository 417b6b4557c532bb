"""Plugin registries: one per kind of thing a user plugs in (gain/exposure controllers, feature front ends).

An entry is a name, a frozen typed config dataclass (read by `expoctl.config_reader.read_config`, so its keys are
checked with their full path `controllers.<name>.<key>`), a factory, and what reports need to know about it (a label,
a colour, its place in tables). Entries register where they are defined, with the registry's decorator:

    @CONTROLLERS.register("hold", config=HoldConfig, label="Hold")
    class HoldController(Controller): ...

Where entries come from, in this order:
1. Built-ins: every module of the registry's own packages (`expoctl.controllers`, `expoctl.features`) is imported on
   first use, so a new built-in is one new file and nothing else.
2. Installed packages: Python entry points in the registry's group (`expoctl.controllers`, `expoctl.frontends`),
   the convention pytest plugins and gymnasium environments use. An entry point names a module (importing it
   registers) or a decorated object; its name must be the name it registers.

A plugin that fails to load (import error, no such name registered, a class without the kind's methods, a config
that is not a dataclass) does not stop the others: the problem is kept with the plugin's package and reported when
the name is asked for (`get`) or by `problems()`, which the compose stage adds to its one-pass config check.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
import traceback
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

from expoctl.config_reader import Problems, read_config
from expoctl.errors import ConfigError

#: the package name of entries that ship with expoctl
BUILTIN = "expoctl"


@dataclass(frozen=True)
class Plugin:
    """One registered entry."""

    kind: str                      # "controller" | "front end"
    name: str
    config: type                   # frozen dataclass of its config section
    factory: Callable[..., Any]    # factory(config, context) -> the object
    package: str                   # the distribution that registered it ("expoctl" for built-ins)
    module: str                    # the module it was registered from
    label: str                     # as tables and figures print it
    rank: int = 1000               # place in tables and figures (built-ins 10 … 90; then by name)
    colour: str | None = None      # matplotlib colour; None: one from the default cycle by position
    info: Mapping[str, Any] = field(default_factory=dict)  # kind-specific facts (controllers: `needs`)
    target: Any = None             # the decorated object (a class, or what `factory=` was registered on)

    def read_config(self, section: Any, key: str, problems: Problems | None = None) -> Any:
        """The typed config of this entry from its section (`controllers.<name>`), every problem with its path."""
        return read_config(self.config, section, key, problems)

    @property
    def origin(self) -> str:
        """'<name> (package <package>, module <module>)': how messages name a plugin."""
        return f"{self.name!r} (package {self.package}, module {self.module})"


class Registry:
    """The entries of one plugin kind; see the module docstring."""

    def __init__(self, kind: str, group: str, config_key: str, builtin_packages: tuple[str, ...],
                 required_methods: tuple[str, ...]):
        self.kind = kind
        self.group = group                    # entry point group
        self.config_key = config_key          # where their config sections live: controllers, features
        self.builtin_packages = builtin_packages
        self.required_methods = required_methods
        self._entries: dict[str, Plugin] = {}
        self._broken: dict[str, tuple[str, str]] = {}   # name -> (package, what is wrong)
        self._loaded = False
        self._loading_package: str | None = None        # the distribution whose entry point is being loaded
        self._before_reload: dict[str, Plugin] = {}     # plugins known before `reload` (their modules stay imported)

    # ------------------------------------------------------------------------------------------------ register

    def register(self, name: str, *, config: type, factory: Callable[..., Any] | None = None,
                 label: str | None = None, rank: int = 1000, colour: str | None = None,
                 **info: Any) -> Callable[[Any], Any]:
        """Decorator for a class (built with `cls(config)`, or `cls(config, context=...)` if its constructor has a
        `context` parameter) or, with `factory=` given, for anything. Returns the decorated object unchanged."""

        def decorate(obj: Any) -> Any:
            build = factory if factory is not None else _class_factory(obj)
            module = getattr(obj, "__module__", None) or "?"
            package = self._loading_package or _distribution_of(module)
            problem = self.problem_of(name, obj if inspect.isclass(obj) else None, config)
            taken = self._entries.get(name)
            if problem is None and package != BUILTIN and taken is not None and taken.package == BUILTIN:
                problem = f"its name is taken by the built-in {self.kind}"
            if problem:
                if package == BUILTIN:
                    raise TypeError(f"{self.kind} {name!r} ({module}): {problem}")
                self._broken[name] = (package, problem)
                return obj
            self._entries[name] = Plugin(self.kind, name, config, build, package, module, label or name, rank,
                                         colour, dict(info), obj)
            self._broken.pop(name, None)
            return obj

        return decorate

    def unregister(self, name: str) -> None:
        """Forget `name` (tests that register a throwaway entry)."""
        self._entries.pop(name, None)
        self._broken.pop(name, None)

    def problem_of(self, name: str, cls: type | None, config: type) -> str | None:
        """Why `cls` with `config` cannot register as `name` (None: it can)."""
        if not name or not name.isidentifier():
            return f"the name must be an identifier (it is a config key and a column), got {name!r}"
        if not (inspect.isclass(config) and dataclasses.is_dataclass(config)):
            return f"config= must be a dataclass (its typed config section), got {config!r}"
        if not config.__dataclass_params__.frozen:
            return f"config {config.__name__} must be a frozen dataclass (@dataclass(frozen=True))"
        if cls is not None:
            missing = [m for m in self.required_methods if not callable(getattr(cls, m, None))
                       or getattr(getattr(cls, m), "__isabstractmethod__", False)]
            if missing:
                return f"class {cls.__name__} lacks the method(s) {', '.join(missing)} every {self.kind} has"
        return None

    # -------------------------------------------------------------------------------------------------- lookup

    def names(self) -> tuple[str, ...]:
        """Every loadable entry's name, in table order (rank, then name)."""
        self._load()
        return tuple(sorted(self._entries, key=lambda n: (self._entries[n].rank, n)))

    def entries(self) -> tuple[Plugin, ...]:
        return tuple(self._entries[n] for n in self.names())

    def __iter__(self):
        return iter(self.names())

    def __contains__(self, name: object) -> bool:
        self._load()
        return name in self._entries

    def get(self, name: str, key: str | None = None) -> Plugin:
        """The entry `name`; a ConfigError at `key` (default `<config_key>.<name>`) naming why it is not there."""
        self._load()
        if name in self._entries:
            return self._entries[name]
        key = key or f"{self.config_key}.{name}"
        if name in self._broken:
            package, problem = self._broken[name]
            raise ConfigError(key, f"{self.kind} plugin {name!r} (package {package}) is broken: {problem}")
        raise ConfigError(key, f"unknown {self.kind} {name!r} (known: {', '.join(self.names())}); a plugin "
                          f"registers through the entry point group '{self.group}' of an installed package")

    def name_of(self, obj: Any) -> str | None:
        """The name `obj` (a decorated class or object) is registered under, if any."""
        self._load()
        return next((p.name for p in self._entries.values() if p.target is obj), None)

    def broken(self) -> dict[str, tuple[str, str]]:
        """{name: (package, problem)} of every plugin that failed to load."""
        self._load()
        return dict(self._broken)

    def problems(self, names: Iterable[str], key: str) -> list[tuple[str, str]]:
        """(key, problem) for each of `names` that is not a loadable entry."""
        out = []
        for name in names:
            try:
                self.get(name, key)
            except ConfigError as exc:
                out.extend(exc.problems)
        return out

    def read_names(self, r: Any, name: str) -> tuple[str, ...]:
        """A list of this registry's names at key `name` of config section `r` (null or absent: every registered
        one, in table order); an unknown or broken plugin is a problem naming it (and its package)."""
        known = self.names()
        given = r.value(name, None)
        if given is None:
            return known
        if isinstance(given, str) or not isinstance(given, (list, tuple)) or not given:
            r.problem(name, f"must be null (every one) or a non-empty list of {self.kind}s ({', '.join(known)}), "
                            f"got {given!r}")
            return known
        if len(set(map(str, given))) != len(given):
            r.problem(name, f"lists a {self.kind} twice: {list(given)!r}")
        for key, problem in self.problems([str(n) for n in given], r.path(name)):
            r.problems.add(key, problem)
        return tuple(n for n in given if n in known) or known

    def build(self, name: str, config: Any, context: Any = None) -> Any:
        """A fresh object of entry `name` from its typed config (and the runtime `context` some entries need)."""
        return self.get(name).factory(config, context)

    def labels(self) -> dict[str, str]:
        return {p.name: p.label for p in self.entries()}

    # --------------------------------------------------------------------------------------------------- load

    def reload(self) -> None:
        """Look at the installed entry points again (a test that installs or removes a plugin package)."""
        self._before_reload = {n: p for n, p in self._entries.items() if p.package != BUILTIN}
        for name in self._before_reload:
            del self._entries[name]
        self._broken.clear()
        self._loaded = False
        self._load()

    def _load(self) -> None:
        if self._loaded:
            return
        self._loaded = True
        for package in self.builtin_packages:
            for module in _modules_of(package):
                importlib.import_module(module)  # a broken built-in is a bug of ours: let it raise
        for ep in _entry_points(self.group):
            dist = ep.dist.name if ep.dist is not None else "?"
            if ep.name in self._entries and self._entries[ep.name].package == BUILTIN:
                self._broken.setdefault(ep.name, (dist, f"its name is taken by the built-in {self.kind}"))
                continue
            self._loading_package = dist
            try:
                obj = ep.load()
            except Exception as exc:  # anything a third-party import raises
                where = traceback.extract_tb(exc.__traceback__)[-1]
                self._broken[ep.name] = (dist, f"importing {ep.value} failed: {type(exc).__name__}: {exc} "
                                               f"({where.filename}:{where.lineno})")
                continue
            finally:
                self._loading_package = None
            earlier = self._before_reload.get(ep.name)
            if ep.name not in self._entries and earlier is not None and earlier.package == dist:
                self._entries[ep.name] = earlier  # its module was imported before: its decorator does not run again
            if ep.name not in self._entries and ep.name not in self._broken:
                self._broken[ep.name] = (dist, f"the entry point loads {ep.value} ({type(obj).__name__}), which "
                                               f"registers no {self.kind} named {ep.name!r} (decorate it with "
                                               f"expoctl's {self.kind} registry `register({ep.name!r}, ...)`)")


def _class_factory(cls: Any) -> Callable[[Any, Any], Any]:
    """factory(config, context) for a class built as `cls(config)`, or `cls(config, context=...)` when its
    constructor has a parameter named `context`."""
    try:
        takes_context = "context" in inspect.signature(cls).parameters
    except (TypeError, ValueError):
        takes_context = False
    if takes_context:
        return lambda config, context: cls(config, context=context)
    return lambda config, context: cls(config)


def _modules_of(package: str) -> list[str]:
    """`package` and every module and subpackage under it, by name (imported in sorted order: deterministic)."""
    pkg = importlib.import_module(package)
    names = [package]
    if not hasattr(pkg, "__path__"):  # a single module
        return names
    for info in pkgutil.walk_packages(pkg.__path__, package + "."):
        if info.name.rsplit(".", 1)[-1].startswith("_"):
            continue
        names.append(info.name)
    return sorted(names)


def _entry_points(group: str) -> list[metadata.EntryPoint]:
    return sorted(metadata.entry_points(group=group), key=lambda ep: ep.name)


def _distribution_of(module: str) -> str:
    """The installed distribution a module belongs to ("expoctl" for our own, the module's top package otherwise)."""
    top = module.split(".", 1)[0]
    if top == "expoctl":
        return BUILTIN
    dists = metadata.packages_distributions().get(top)
    return dists[0] if dists else top
