"""The one checker library for config groups: read a mapping's keys with their types and bounds into typed values,
collecting every problem of the whole read before stopping.

A config group's frozen dataclass owns its keys: its `from_dict` opens a `Section` on the group's mapping, reads each
key once (type, default, bounds, choices) and calls `done()`. Problems do not stop the read: a bad value is recorded
with its full key path (`world.render.hfov_deg`) and the read goes on with the key's default, so one run reports
everything that is wrong. The outermost `done()` raises them all as one `ConfigError`.

Sub-blocks (`section("vo")`) and other groups read in the same pass (`Section(d, key, problems=...)`) share one
`Problems` list, so a stage that builds several groups from the resolved config reports every group's problems
together.

Bounds are named: `min`/`max` are inclusive, `above`/`below` exclusive; the message shows which (`in [0, 0.5]`,
`in (0, 180)`).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from numbers import Real
from typing import Any

from expoctl.errors import ConfigError

#: `default` of a key that must be given
REQUIRED: Any = object()


class Problems:
    """Every (key path, problem) found so far; `raise_if_any` raises them as one ConfigError."""

    def __init__(self) -> None:
        self.items: list[tuple[str, str]] = []

    def add(self, key: str, problem: str) -> None:
        self.items.append((key, problem))

    def __len__(self) -> int:
        return len(self.items)

    def collect(self, build: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """`build(*args, **kwargs)`, with the problems of a ConfigError it raises added here instead (None then): for
        a group whose reader stops at its first problem, so it still reports alongside the others."""
        try:
            return build(*args, **kwargs)
        except ConfigError as exc:
            self.items.extend(exc.problems)
            return None

    def raise_if_any(self) -> None:
        if self.items:
            raise ConfigError.of(self.items)


def bounds_text(min: Real | None = None, max: Real | None = None, above: Real | None = None,
                below: Real | None = None) -> str:
    """'in [0, 0.5]', 'in (0, 180)', '>= 1', '> 0', … (empty without bounds)."""
    lo = f"[{min}" if min is not None else f"({above}" if above is not None else None
    hi = f"{max}]" if max is not None else f"{below})" if below is not None else None
    if lo and hi:
        return f"in {lo}, {hi}"
    if lo:
        return f">= {min}" if min is not None else f"> {above}"
    if hi:
        return f"<= {max}" if max is not None else f"< {below}"
    return ""


def within(v: Real, min: Real | None = None, max: Real | None = None, above: Real | None = None,
           below: Real | None = None) -> bool:
    return ((min is None or v >= min) and (max is None or v <= max) and (above is None or v > above)
            and (below is None or v < below))


def is_integer(v: Any) -> bool:
    """An int and not a bool (YAML true/false are bools, which Python also counts as ints)."""
    return isinstance(v, int) and not isinstance(v, bool)


def is_number(v: Any) -> bool:
    """A finite int or float, not a bool."""
    return isinstance(v, Real) and not isinstance(v, bool) and math.isfinite(float(v))


class Section:
    """The keys of one mapping at config key `key`, read one by one (see the module docstring).

    `d` None is an empty mapping unless `required`; anything else that is not a mapping is one problem and every key
    reads as its default."""

    def __init__(self, d: Any, key: str, problems: Problems | None = None, *, required: bool = False):
        self.key = key
        self.problems = problems if problems is not None else Problems()
        self._owns_problems = problems is None
        self._read: set[str] = set()
        if d is None and not required:
            d = {}
        if not isinstance(d, Mapping):
            self.problems.add(key, f"missing or not a mapping (got {d!r})")
            d = {}
        self.mapping: Mapping = d

    # ------------------------------------------------------------------------------------------------ plumbing

    def path(self, name: str) -> str:
        """The full key path of `name` ("" is the resolved config's top level: `seed`)."""
        return f"{self.key}.{name}" if self.key else name

    def has(self, name: str) -> bool:
        return name in self.mapping

    def problem(self, name: str | None, problem: str) -> None:
        """Record a problem of key `name` of this section (None: the section itself)."""
        self.problems.add(self.key if name is None else self.path(name), problem)

    def _get(self, name: str, default: Any) -> tuple[bool, Any]:
        """(given, value); a missing required key is recorded."""
        self._read.add(name)
        if name in self.mapping:
            return True, self.mapping[name]
        if default is REQUIRED:
            self.problem(name, "missing")
        return False, None

    def _bad(self, name: str, what: str, v: Any, default: Any) -> Any:
        self.problem(name, f"must be {what}, got {v!r}")
        return None if default is REQUIRED else default

    # ------------------------------------------------------------------------------------------------- readers

    def value(self, name: str, default: Any = REQUIRED) -> Any:
        """The value as given (checked by the caller), or `default`."""
        given, v = self._get(name, default)
        return v if given else (None if default is REQUIRED else default)

    def integer(self, name: str, default: Any = REQUIRED, *, min: int | None = None, max: int | None = None,
                above: int | None = None, below: int | None = None, unit: str = "", nullable: bool = False) -> Any:
        given, v = self._get(name, default)
        if not given:
            return None if default is REQUIRED else default
        if v is None and nullable:
            return None
        if not is_integer(v) or not within(v, min, max, above, below):
            return self._bad(name, _described("an integer", bounds_text(min, max, above, below), unit, nullable),
                             v, default)
        return int(v)

    def number(self, name: str, default: Any = REQUIRED, *, min: Real | None = None, max: Real | None = None,
               above: Real | None = None, below: Real | None = None, unit: str = "", nullable: bool = False) -> Any:
        """A finite number (ints accepted), returned as float."""
        given, v = self._get(name, default)
        if not given:
            return None if default is REQUIRED else default
        if v is None and nullable:
            return None
        if not is_number(v) or not within(v, min, max, above, below):
            bounds = bounds_text(min, max, above, below)
            return self._bad(name, _described("a number" if bounds else "a finite number", bounds, unit, nullable),
                             v, default)
        return float(v)

    def boolean(self, name: str, default: Any = REQUIRED) -> Any:
        given, v = self._get(name, default)
        if not given:
            return None if default is REQUIRED else default
        if not isinstance(v, bool):
            return self._bad(name, "true or false", v, default)
        return v

    def text(self, name: str, default: Any = REQUIRED, *, nullable: bool = False) -> Any:
        """A non-empty string."""
        given, v = self._get(name, default)
        if not given:
            return None if default is REQUIRED else default
        if v is None and nullable:
            return None
        if not isinstance(v, str) or not v:
            return self._bad(name, "a non-empty string" + (" or null" if nullable else ""), v, default)
        return v

    def choice(self, name: str, choices: Sequence, default: Any = REQUIRED) -> Any:
        given, v = self._get(name, default)
        if not given:
            return None if default is REQUIRED else default
        if isinstance(v, (list, dict)) or v not in choices:
            names = ", ".join("null" if c is None else str(c) for c in choices)
            return self._bad(name, f"one of {names}", v, default)
        return v

    def pair(self, name: str, default: Any = REQUIRED, *, min: Real | None = None, max: Real | None = None,
             above: Real | None = None, below: Real | None = None, unit: str = "") -> Any:
        """[low, high]: two numbers with low <= high, each within the bounds; returned as a tuple of floats."""
        given, v = self._get(name, default)
        if not given:
            return None if default is REQUIRED else default
        if not (isinstance(v, (list, tuple)) and len(v) == 2 and all(is_number(x) and within(x, min, max, above, below)
                                                                    for x in v) and v[0] <= v[1]):
            bounds = bounds_text(min, max, above, below)
            each = f", each a number {bounds}" + (f" {unit}" if unit else "") if bounds else ""
            return self._bad(name, f"[low, high] with low <= high{each}", v, default)
        return float(v[0]), float(v[1])

    def names(self, name: str, known: Sequence[str], default: Any = REQUIRED, *, what: str = "name") -> Any:
        """A non-empty list of distinct names from `known`, returned as a tuple."""
        given, v = self._get(name, default)
        if not given:
            return None if default is REQUIRED else default
        if isinstance(v, str) or not isinstance(v, (list, tuple)) or not v:
            return self._bad(name, f"a non-empty list of {what}s ({', '.join(known)})", v, default)
        bad = False
        if len(set(v)) != len(v):
            self.problem(name, f"lists a {what} twice: {v!r}")
            bad = True
        for n in v:
            if n not in known:
                self.problem(name, f"unknown {what} {n!r} (known: {', '.join(known)})")
                bad = True
        return (None if default is REQUIRED else default) if bad else tuple(v)

    def numbers(self, name: str, default: Any = REQUIRED, *, min: Real | None = None, max: Real | None = None,
                above: Real | None = None, below: Real | None = None, unit: str = "", empty: bool = False) -> Any:
        """A list of finite numbers within the bounds (non-empty unless `empty`), returned as a tuple of floats."""
        given, v = self._get(name, default)
        if not given:
            return None if default is REQUIRED else default
        if (isinstance(v, str) or not isinstance(v, (list, tuple)) or (not v and not empty)
                or not all(is_number(x) and within(x, min, max, above, below) for x in v)):
            bounds = bounds_text(min, max, above, below)
            kind = ("a list" if empty else "a non-empty list") + (" of numbers " + bounds if bounds else
                                                                  " of finite numbers")
            return self._bad(name, kind + (f" {unit}" if unit and bounds else ""), v, default)
        return tuple(float(x) for x in v)

    def section(self, name: str, *, required: bool = False) -> "Section":
        """The sub-block `name` (a mapping), sharing this section's problems; absent reads as empty unless
        `required`."""
        given, v = self._get(name, REQUIRED if required else None)
        return Section(v if given else ({} if not required else None), self.path(name), self.problems,
                       required=False)

    def read(self, cls: type) -> Any:
        """This section's keys as an instance of the typed config dataclass `cls` (`read_config`)."""
        return _read_dataclass(self, cls)

    def moved(self, name: str, new_key: str, note: str = "") -> None:
        """A key that no longer belongs here: given, it is one problem naming where it went."""
        self._read.add(name)
        if name in self.mapping:
            self.problem(name, f"moved to {new_key}" + (f" ({note})" if note else ""))

    # ---------------------------------------------------------------------------------------------------- end

    def done(self, known: Sequence[str] | None = None) -> None:
        """Record every key of the mapping that was not read (or is not in `known`) as unknown; the outermost
        section then raises every problem found (ConfigError)."""
        allowed = set(known) if known is not None else self._read
        expected = sorted(allowed)
        for k in self.mapping:
            if k not in allowed:
                self.problem(str(k), f"unknown key (expected one of {expected})")
        if self._owns_problems:
            self.problems.raise_if_any()


def _described(kind: str, bounds: str, unit: str, nullable: bool) -> str:
    text = kind + (f" {bounds}" if bounds else "") + (f" {unit}" if unit and bounds else "")
    return text + (" or null" if nullable else "")


def read_seed(top: Section) -> int:
    """The run's base seed: key `seed` at the resolved config's top level (`Section(cfg, "")`), default 0. Every
    stage that seeds anything (collect, train, evaluate, select_model) reads it here."""
    return top.integer("seed", 0, min=0)


# --------------------------------------------------------------------------------------- typed config dataclasses


def param(default: Any = REQUIRED, *, min: Real | None = None, max: Real | None = None, above: Real | None = None,
          below: Real | None = None, unit: str = "", choices: Sequence | None = None, length: int | None = None,
          empty: bool = False, read: Callable[["Section", str, Any], Any] | None = None) -> Any:
    """A field of a typed config dataclass with the bounds its reader checks (`read_config`): `min`/`max` inclusive,
    `above`/`below` exclusive, `choices` for a string, `length` (and `empty`) for a tuple of numbers. `read(section,
    name, default)` reads a key whose form a type cannot say (a size given as one number or [height, width])."""
    meta = {"min": min, "max": max, "above": above, "below": below, "unit": unit, "choices": choices,
            "length": length, "empty": empty, "read": read}
    if default is REQUIRED:
        return dataclasses.field(metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def read_config(cls: type, d: Any, key: str, problems: Problems | None = None) -> Any:
    """The one reader of a config section into its frozen dataclass `cls`: every field read with the type its
    annotation gives and the bounds of its `param(...)`, unknown keys refused, then the dataclass's own cross-key
    `check(section)`. Every problem carries its full key path (`controllers.agae.damping`); without `problems`, they
    are raised together as one ConfigError, else added there for the caller to raise."""
    r = Section(d, key, problems)
    value = r.read(cls)
    r.done()
    return value


def _read_field(r: Section, name: str, hint: Any, default: Any, meta: Mapping) -> Any:
    """One dataclass field from section `r`, dispatched on its type annotation (or read by its own `read`)."""
    if meta.get("read") is not None:
        return meta["read"](r, name, default)
    nullable = False
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType) and type(None) in args:
        nullable = True
        rest = [a for a in args if a is not type(None)]
        hint = rest[0] if len(rest) == 1 else Any
        origin, args = typing.get_origin(hint), typing.get_args(hint)
    bounds = {k: meta.get(k) for k in ("min", "max", "above", "below")}
    unit = meta.get("unit") or ""
    if nullable and r.has(name) and r.mapping[name] is None:
        r._read.add(name)
        return None
    if hint is bool:
        return r.boolean(name, default)
    if hint is int:
        return r.integer(name, default, unit=unit, nullable=nullable, **bounds)
    if hint is float:
        return r.number(name, default, unit=unit, nullable=nullable, **bounds)
    if hint is str:
        if meta.get("choices"):
            return r.choice(name, tuple(meta["choices"]), default)
        return r.text(name, default, nullable=nullable)
    if origin is tuple and args and args[0] in (float, int):
        value = r.numbers(name, default, unit=unit, empty=bool(meta.get("empty")), **bounds)
        length = meta.get("length")
        if value is not None and value is not default and length is not None and len(value) != length:
            return r._bad(name, f"a list of {length} numbers", r.mapping[name], default)
        if value is not None and value is not default and args[0] is int:
            if not all(float(v).is_integer() for v in value):
                return r._bad(name, "a list of integers", r.mapping[name], default)
            value = tuple(int(v) for v in value)
        return value
    if dataclasses.is_dataclass(hint):
        sub = r.section(name)
        value = sub.read(hint)
        sub.done()
        return value
    return r.value(name, default)  # Any / Mapping: checked by the dataclass's own `check`


def _read_dataclass(self: Section, cls: type) -> Any:
    """This section's keys as an instance of the frozen dataclass `cls` (see `read_config`); the caller calls
    `done()`. A dataclass may define `check(self, section)` for its bounds and the rules between keys; it runs on
    what was read (a bad key reads as its default), and a key already named is not named twice. One whose keys
    need more than types and bounds reads them itself in a classmethod `from_section(section)` (same contract)."""
    custom = getattr(cls, "from_section", None)
    if callable(custom):  # a config whose keys need more than a type and bounds (e.g. libviso2's 0/1 switches)
        return custom(self)
    hints = typing.get_type_hints(cls)
    before = len(self.problems)
    values = {}
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = REQUIRED
        values[f.name] = _read_field(self, f.name, hints[f.name], default, f.metadata)
    if len(self.problems) > before:
        # a required key that is missing or bad has no value to build with: the defaults stand in
        values = {k: v for k, v in values.items() if v is not None or _nullable(hints[k])}
        try:
            value = cls(**values)
        except TypeError:
            return None
    else:
        value = cls(**values)
    check = getattr(value, "check", None)
    if callable(check):
        # the rules run on what was read (a bad key reads as its default); a key already named is not named again
        named = {k for k, _ in self.problems.items[before:]}
        mark = len(self.problems)
        check(self)
        self.problems.items[mark:] = [(k, p) for k, p in self.problems.items[mark:] if k not in named]
    return value


def _nullable(hint: Any) -> bool:
    return typing.get_origin(hint) in (typing.Union, types.UnionType) and type(None) in typing.get_args(hint)

