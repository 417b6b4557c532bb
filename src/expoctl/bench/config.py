"""Which resolved config a benchmark runs on: a given file, the project's, or the one packaged with expoctl.

The packaged configs (`expoctl/bench/configs/<scale>.yaml`, package data) are conf/ composed at that scale, so the
benchmark runs from an installed wheel with no checkout beside it; a drift test keeps them equal to conf/.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

from expoctl.errors import InputError

#: the packaged benchmark configs, by scale
SCALES = ("default", "fixture")


def packaged_config_text(scale: str) -> str:
    """The YAML text of the packaged benchmark config at `scale`."""
    if scale not in SCALES:
        raise InputError(f"unknown benchmark scale {scale!r} (known: {', '.join(SCALES)})")
    path = resources.files("expoctl.bench").joinpath("configs", f"{scale}.yaml")
    if not path.is_file():
        raise InputError(f"the packaged benchmark config {scale}.yaml is missing from this install of expoctl "
                         f"({path}); reinstall expoctl")
    return path.read_text(encoding="utf-8")


def read_config_file(path: Path) -> dict[str, Any]:
    """A resolved config file as a dict; an InputError naming the file if it is missing or not a YAML mapping."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: no such config file") from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InputError(f"{path}: not a readable YAML config ({exc})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: a resolved config is a YAML mapping, got {type(data).__name__}")
    return data


def load_benchmark_config(config: Path | None, project: Path, scale: str = "default") -> tuple[dict[str, Any], str]:
    """(config dict, where it came from): `config` if given; else the project's configs/resolved.yaml if it
    exists (the numbers are then the evaluate stage's); else the packaged config at `scale`."""
    import yaml

    if config is not None:
        return read_config_file(config), str(config)
    project_config = Path(project) / "configs" / "resolved.yaml"
    if project_config.is_file():
        return read_config_file(project_config), str(project_config)
    data = yaml.safe_load(packaged_config_text(scale))
    return data, f"packaged benchmark config ({scale})"
