"""The numeric mode (config group `numerics`, expoctl.numerics) applied to a stage process before anything else.

Its switches are read when torch, numpy, OpenCV and numba are imported, and the stage modules import them at their
top (stages/train.py imports torch), so `stage_main` would be too late. `python -m stages.<name>` imports the package
`stages` first, and stages/__init__.py calls `boot()`: for a DVC stage's entry point it reads `numerics` from
configs/resolved.yaml (PyYAML only) and sets the environment, which the stage's worker processes inherit and its Ray
tasks are sent (expoctl.parallel.runtime_env). Every other import of the package (the tests, the dvc.yaml generator,
the sweep) changes nothing. A bad `numerics` value is raised by `stage_main` (`numerics_for`), as a one-line error.

guard and compose compute nothing numeric and run before configs/resolved.yaml exists, so they are not booted.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from expoctl.numerics import NumericsConfig, apply_environment, apply_in_process, baseline_warning, record

#: stages that run before the resolved config exists and compute nothing numeric
NOT_BOOTED = frozenset({"guard", "compose"})
_RESOLVED = Path(__file__).resolve().parents[1] / "configs" / "resolved.yaml"

_booted: dict[str, Any] = {}  # "config": NumericsConfig, "late": [...], "error": Exception; empty: not booted


def stage_module(argv: list[str] | None = None) -> str | None:
    """'train' when this interpreter was started as `python [options] -m stages.train ...` (also under torchrun,
    which starts its workers that way), else None."""
    argv = list(sys.orig_argv if argv is None else argv)
    for i, arg in enumerate(argv[1:-1], start=1):
        if arg == "-m":
            name = argv[i + 1]
            return name.split(".", 1)[1] if name.startswith("stages.") and name.count(".") == 1 else None
        if not arg.startswith("-"):  # a script or -c: not a module run
            return None
    return None


def boot(argv: list[str] | None = None, resolved: Path = _RESOLVED) -> bool:
    """Apply the resolved config's numeric mode to this process if it is a DVC stage's entry point; True if it did.
    Errors are kept for `numerics_for` (stage_main turns them into one line)."""
    from stages.table import STAGE_BY_NAME

    stage = stage_module(argv)
    if stage is None or stage not in STAGE_BY_NAME or stage in NOT_BOOTED or not resolved.is_file():
        return False
    try:
        import yaml

        loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
        cfg = yaml.load(resolved.read_text(), Loader=loader)
        config = NumericsConfig.from_resolved(cfg)
    except Exception as exc:  # noqa: BLE001 — reported by stage_main, with the stage's own error handling
        _booted.clear()
        _booted["error"] = exc
        return False
    _booted.clear()
    _booted.update(config=config, late=apply_environment(config))
    return True


def numerics_for(cfg: dict[str, Any]) -> dict[str, Any]:
    """In stage_main, once the stage's config is loaded: the mode's in-process settings (torch's deterministic
    algorithms), a warning on a host below the baseline, and the record the stage's MLflow run gets. Raises the boot's
    error (a ConfigError naming `numerics.mode`), and refuses a process that was not booted with the config it runs
    (configs/resolved.yaml rewritten between the two reads: the environment would not match the record)."""
    import logging

    if "error" in _booted:
        raise _booted["error"]
    config = NumericsConfig.from_resolved(cfg)
    late = _booted.get("late", [])
    if _booted and _booted["config"] != config:
        from expoctl.errors import InputError

        raise InputError(f"configs/resolved.yaml changed while the stage started (numerics.mode "
                         f"{_booted['config'].mode} -> {config.mode}); run it again")
    if not _booted and config.pinned:
        # not started as `python -m stages.<name>` (a test calling the stage in process): this process's environment
        # is left alone, and the record says that whatever it imported was imported unpinned
        from expoctl.numerics import READ_AT_IMPORT

        late = [m for m in READ_AT_IMPORT if m in sys.modules] or ["(not started as python -m stages.<name>)"]
    apply_in_process(config)
    warning = baseline_warning(config)
    if warning:
        logging.getLogger(__name__).warning(warning)
    _booted["record"] = record(config, late)
    return _booted["record"]


def stage_record(cfg: dict[str, Any]) -> dict[str, Any]:
    """This stage's numeric record (what `numerics_for` returned to stage_main; computed now for a stage called in
    process, without stage_main)."""
    return _booted["record"] if "record" in _booted else numerics_for(cfg)
