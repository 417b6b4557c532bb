"""The feature front-end registry: every front end by name (`orb`, `viso`, and installed plugins), with its typed
config (`features.<name>`) and label. A front end registers where it is defined:

    @register_frontend("harris", config=HarrisConfig, label="Harris")
    class HarrisFrontEnd:               # the FrontEnd protocol (expoctl.features.frontend)
        def __init__(self, config: HarrisConfig): ...
        def extract(self, grey): ...
        def n_features(self, extracted): ...
        def match(self, prev, cur, seed): ...   # -> (n_matches, n_inliers)

Installed packages register through the `expoctl.frontends` entry point group (`expoctl.plugins`). Which front ends
run is `features.frontends` (features, labels) and `evaluate.frontends` (evaluate, select_model).
"""

from __future__ import annotations

from typing import Any

from expoctl.plugins import Plugin, Registry

FRONTENDS = Registry("front end", "expoctl.frontends", "features", ("expoctl.features",),
                     ("extract", "n_features", "match"))

#: the name of the labels' combined objective over every front end (labels.frontend), never a front end's name
COMBINED = "combined"


def register_frontend(name: str, *, config: type, **kw: Any):
    """Decorator: register a front-end class under `name`; `label` and `rank` set how reports show it."""
    if name == COMBINED or name.endswith("_sumlog"):
        raise ValueError(f"front end name {name!r} is reserved (labels' {COMBINED!r}, evaluate's '<name>_sumlog')")
    return FRONTENDS.register(name, config=config, **kw)


def frontend(name: str, key: str | None = None) -> Plugin:
    return FRONTENDS.get(name, key)


def frontend_names() -> tuple[str, ...]:
    """Every registered front end, in table order."""
    return FRONTENDS.names()


def frontend_label(name: str) -> str:
    """How tables print a front end (`orb_sumlog`: its base front end's label with ' (SumLog)')."""
    base, sumlog = (name[: -len("_sumlog")], True) if name.endswith("_sumlog") else (name, False)
    label = FRONTENDS.get(base).label if base in FRONTENDS else base
    return label + (" (SumLog)" if sumlog else "")


def read_frontend_config(name: str, section: Any, problems=None, key: str | None = None) -> Any:
    """`features.<name>` as its typed config (every problem with its key path)."""
    key = key or f"features.{name}"
    return frontend(name, key).read_config(section, key, problems)


def make_frontend(name: str, config: Any = None):
    """A fresh front end `name` from its typed config (or its section as a mapping; None: defaults). Each run or
    worker makes its own: matchers may keep state between frames."""
    entry = frontend(name)
    if not isinstance(config, entry.config):
        config = entry.read_config(config, f"features.{name}")
    return entry.factory(config, None)
