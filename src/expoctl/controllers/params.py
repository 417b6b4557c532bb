"""Config handling shared by the baseline controllers: merge user params over defaults, reject unknown keys and
wrong types with a ConfigError naming the dotted key (controllers.<name>.<key>)."""

from __future__ import annotations

import math
from numbers import Real

from expoctl.errors import ConfigError


def check_params(prefix: str, defaults: dict, params: dict | None) -> dict:
    """Return defaults updated with `params`. Unknown keys and type mismatches (numbers vs strings vs lists) raise.
    Ints are accepted where a float default is given; non-finite numbers are rejected."""
    if params is None:
        params = {}
    if not isinstance(params, dict):
        raise ConfigError(prefix, f"must be a mapping, got {type(params).__name__}")
    unknown = sorted(set(params) - set(defaults))
    if unknown:
        raise ConfigError(f"{prefix}.{unknown[0]}", f"unknown key (known: {', '.join(sorted(defaults))})")
    out = dict(defaults)
    for k, v in params.items():
        d = defaults[k]
        key = f"{prefix}.{k}"
        if isinstance(d, bool):
            if not isinstance(v, bool):
                raise ConfigError(key, f"must be true or false, got {v!r}")
        elif isinstance(d, int):
            if isinstance(v, bool) or not isinstance(v, int):
                raise ConfigError(key, f"must be an integer, got {v!r}")
        elif isinstance(d, float):
            if isinstance(v, bool) or not isinstance(v, Real) or not math.isfinite(float(v)):
                raise ConfigError(key, f"must be a finite number, got {v!r}")
            v = float(v)
        elif isinstance(d, str):
            if not isinstance(v, str):
                raise ConfigError(key, f"must be a string, got {v!r}")
        elif isinstance(d, (list, tuple)):
            if not isinstance(v, (list, tuple)):
                raise ConfigError(key, f"must be a list, got {v!r}")
        out[k] = v
    return out


def require(condition: bool, key: str, problem: str) -> None:
    """Raise ConfigError(key, problem) unless `condition` holds."""
    if not condition:
        raise ConfigError(key, problem)
