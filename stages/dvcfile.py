"""What dvc.yaml and dvc.lock say about each stage's outputs, read without DVC itself.

The guard stage and a failing stage's message run inside `dvc repro`, which holds the repository lock, so they read
the two YAML files directly: dvc.yaml for the declared outputs (its `foreach` stages expanded the way DVC does for
our one pattern, `${item.<key>}` and `${key}` over a `vars` mapping), dvc.lock for what the last successful run of
each stage wrote (path, md5, and for a directory the md5 of its `.dir` manifest in the DVC cache).
tests/stages/test_dvcfile.py checks the expansion against DVC's own.
"""

from __future__ import annotations

import configparser
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

_VAR = re.compile(r"\$\{(item\.(\w+)|key)\}")


@dataclass(frozen=True)
class Output:
    stage: str
    path: str          # relative to the project root, as declared
    cache: bool
    persist: bool


@dataclass(frozen=True)
class Locked:
    """An output as the stage's last successful run recorded it in dvc.lock."""
    stage: str
    path: str
    md5: str | None
    size: int | None
    nfiles: int | None

    @property
    def is_dir(self) -> bool:
        return bool(self.md5 and self.md5.endswith(".dir"))


def _substitute(value: Any, key: str, item: dict) -> Any:
    if isinstance(value, str):
        return _VAR.sub(lambda m: str(key if m.group(1) == "key" else item[m.group(2)]), value)
    if isinstance(value, list):
        return [_substitute(v, key, item) for v in value]
    if isinstance(value, dict):
        return {_substitute(k, key, item): _substitute(v, key, item) for k, v in value.items()}
    return value


def _vars(doc: dict) -> dict:
    out: dict = {}
    for entry in doc.get("vars") or []:
        if isinstance(entry, dict):
            out.update(entry)
    return out


def resolved_stages(root: Path) -> dict[str, dict]:
    """{stage name: its dvc.yaml definition}, `foreach` stages expanded to `<name>@<key>`."""
    return resolve_document(yaml.safe_load((root / "dvc.yaml").read_text()) or {})


def resolve_document(doc: dict) -> dict[str, dict]:
    """`resolved_stages` of a dvc.yaml document already read (stages/dvc_yaml.py compares a generated one)."""
    variables = _vars(doc)
    out: dict[str, dict] = {}
    for name, stage in (doc.get("stages") or {}).items():
        if "foreach" in stage:
            ref = re.fullmatch(r"\$\{(\w+)\}", str(stage["foreach"]))
            items = variables[ref.group(1)] if ref else stage["foreach"]
            for key, item in items.items():
                out[f"{name}@{key}"] = _substitute(stage["do"], str(key), item)
        else:
            out[name] = stage
    return out


def _entries(stage: dict, field: str) -> list[tuple[str, dict]]:
    out = []
    for entry in stage.get(field) or []:
        if isinstance(entry, dict):
            (path, opts), = entry.items()
            out.append((str(path), opts or {}))
        else:
            out.append((str(entry), {}))
    return out


def declared_outputs(root: Path) -> list[Output]:
    """Every output (outs and metrics) of every stage of dvc.yaml."""
    out = []
    for name, stage in resolved_stages(root).items():
        for field in ("outs", "metrics", "plots"):
            for path, opts in _entries(stage, field):
                out.append(Output(name, path, bool(opts.get("cache", field == "outs")), bool(opts.get("persist"))))
    return out


def locked_outputs(root: Path) -> dict[str, Locked]:
    """{output path: as dvc.lock records it}; empty before the first `dvc repro`."""
    lock = root / "dvc.lock"
    if not lock.is_file():
        return {}
    doc = yaml.safe_load(lock.read_text()) or {}
    out = {}
    for name, stage in (doc.get("stages") or {}).items():
        for o in stage.get("outs") or []:
            out[str(o["path"])] = Locked(name, str(o["path"]), o.get("md5"), o.get("size"), o.get("nfiles"))
    return out


def cache_dir(root: Path) -> Path:
    """The DVC cache directory (`cache.dir` of .dvc/config.local or .dvc/config, else .dvc/cache)."""
    for name in ("config.local", "config"):
        path = root / ".dvc" / name
        if path.is_file():
            parser = configparser.ConfigParser()
            try:
                parser.read_string(path.read_text())
            except configparser.Error:
                continue
            if parser.has_option("cache", "dir"):
                d = Path(parser.get("cache", "dir"))
                return d if d.is_absolute() else (path.parent / d).resolve()
    return root / ".dvc" / "cache"


def dir_manifest(root: Path, md5: str) -> set[str] | None:
    """The relative file paths of a cached directory output (its `.dir` manifest), None if not in the cache."""
    path = cache_dir(root) / "files" / "md5" / md5[:2] / md5[2:]
    try:
        entries = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return {str(e["relpath"]) for e in entries if isinstance(e, dict) and "relpath" in e}
