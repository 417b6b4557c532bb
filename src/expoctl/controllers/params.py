"""Config handling shared by the baseline controllers: merge user params over defaults, reject unknown keys and
wrong types with a ConfigError naming the dotted key (controllers.<name>.<key>), on the checker library's
`expoctl.config_reader` type tests."""

from __future__ import annotations

from expoctl.config_reader import Problems, is_integer, is_number
from expoctl.errors import ConfigError


def check_params(prefix: str, defaults: dict, params: dict | None) -> dict:
    """Return defaults updated with `params`. Unknown keys and type mismatches (numbers vs strings vs lists) raise,
    every one at once. Ints are accepted where a float default is given; non-finite numbers are rejected."""
    if params is None:
        params = {}
    if not isinstance(params, dict):
        raise ConfigError(prefix, f"must be a mapping, got {type(params).__name__}")
    problems = Problems()
    out = dict(defaults)
    for k, v in params.items():
        key = f"{prefix}.{k}"
        if k not in defaults:
            problems.add(key, f"unknown key (known: {', '.join(sorted(defaults))})")
            continue
        d = defaults[k]
        if isinstance(d, bool):
            if not isinstance(v, bool):
                problems.add(key, f"must be true or false, got {v!r}")
        elif isinstance(d, int):
            if not is_integer(v):
                problems.add(key, f"must be an integer, got {v!r}")
        elif isinstance(d, float):
            if not is_number(v):
                problems.add(key, f"must be a finite number, got {v!r}")
            else:
                v = float(v)
        elif isinstance(d, str):
            if not isinstance(v, str):
                problems.add(key, f"must be a string, got {v!r}")
        elif isinstance(d, (list, tuple)):
            if not isinstance(v, (list, tuple)):
                problems.add(key, f"must be a list, got {v!r}")
        out[k] = v
    problems.raise_if_any()
    return out


def require(condition: bool, key: str, problem: str) -> None:
    """Raise ConfigError(key, problem) unless `condition` holds."""
    if not condition:
        raise ConfigError(key, problem)
