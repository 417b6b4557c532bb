"""guard stage: refuse to run the pipeline while a DVC output directory holds files no stage wrote.

`dvc repro` replaces a stage's output directory whenever the stage re-runs (and checks one out again from the cache
when it restores it), so anything a user put inside one — typically a real rig recording copied under `data/raw/`,
which is the `collect` stage's output — would be deleted without a word. DVC has no hook before it touches outputs,
so this stage runs first on every `dvc repro` (`always_changed`, and `compose`, the root of every other stage,
depends on its stamp file), looks at every directory output, and stops the run with exit code 2 naming each foreign
path before any stage has run. It writes its stamp, whose content never changes, and the list of installed plugins
(`configs/plugins.yaml`), which changes only when a plugin package is installed, removed or upgraded: only then does
another stage re-run because of it.

What counts as foreign in a directory output:
- the stage ran before (dvc.lock has its `.dir` hash): every file not in that directory's manifest in the DVC cache;
- it never ran: for the raw-data outputs, every sequence whose sequence.yaml does not say `source: sim` (the
  simulator's) — real recordings say `source: rig`.
Real recordings live in `data/recordings/`, which is no stage's output (`collect.source: recordings`).
"""

from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path

import yaml

from stages.dvcfile import declared_outputs, dir_manifest, locked_outputs
from stages.project import PROJECT_ROOT, RECORDINGS_DIR

GUARD_STAMP = Path("configs") / "guard.ok"
#: the installed plugins (stages/table.py recorded_plugins): compose depends on it, so a plugin installed, removed
#: or upgraded re-runs compose, whose resolved config records them for the stages that build plugins
PLUGINS_FILE = Path("configs") / "plugins.yaml"
STAMP_TEXT = "# written by stages/guard.py when no DVC output held foreign files; its content never changes\n"
_RAW_OUTPUTS = ("data/raw",)  # prefixes: data/raw, data/raw_iter2, …
_SHOWN = 8


def _files(d: Path) -> list[str]:
    """Files under `d`, relative, skipping dot-names (our atomic writers' temporaries)."""
    out = []
    for p in d.rglob("*"):
        rel = p.relative_to(d)
        if p.is_file() and not any(part.startswith(".") for part in rel.parts):
            out.append(rel.as_posix())
    return out


def _group(rels: list[str]) -> dict[str, int]:
    """Files grouped by their sequence-level directory (two levels: <split>/<sequence>) or themselves."""
    groups: dict[str, int] = defaultdict(int)
    for rel in rels:
        parts = rel.split("/")
        groups["/".join(parts[:2]) + "/" if len(parts) > 2 else rel] += 1
    return dict(groups)


def _describe(out_dir: Path, group: str, n: int) -> str:
    what = f"{n} file{'s' * (n != 1)}"
    seq_yaml = out_dir / group / "sequence.yaml"
    if group.endswith("/") and seq_yaml.is_file():
        try:
            source = (yaml.safe_load(seq_yaml.read_text()) or {}).get("source")
        except yaml.YAMLError:
            source = None
        what += f", a recorded sequence (source: {source})" if source else ", a sequence"
    return what


def _unlocked_raw_foreign(out_dir: Path) -> list[str]:
    """Files of sequences in a never-run raw output that the simulator did not write."""
    from expoctl.raw.format import SEQUENCE_YAML, find_sequences

    foreign = []
    for seq in find_sequences(out_dir):
        try:
            source = (yaml.safe_load((seq / SEQUENCE_YAML).read_text()) or {}).get("source")
        except (OSError, yaml.YAMLError, AttributeError):
            source = None
        if source != "sim":
            foreign += [(seq.relative_to(out_dir) / f).as_posix() for f in _files(seq)]
    return foreign


def foreign_files(root: Path) -> dict[str, tuple[str, dict[str, int]]]:
    """{output directory: (its stage, {foreign path group: number of files})} for every directory output of dvc.yaml
    that holds files its stage did not write."""
    locked = locked_outputs(root)
    found: dict[str, tuple[str, dict[str, int]]] = {}
    for out in declared_outputs(root):
        d = root / out.path
        if not d.is_dir():
            continue
        entry = locked.get(out.path)
        if entry is not None and entry.is_dir:
            manifest = dir_manifest(root, entry.md5)
            if manifest is None:  # not in the cache (cache: false, or the cache was cleared): nothing to compare
                continue
            foreign = [f for f in _files(d) if f not in manifest]
        elif entry is None and out.path.startswith(_RAW_OUTPUTS):
            foreign = _unlocked_raw_foreign(d)
        else:
            continue
        if foreign:
            found[out.path] = (out.stage, _group(sorted(foreign)))
    return found


def message(found: dict[str, tuple[str, dict[str, int]]], root: Path) -> str:
    lines = ["these files are inside a DVC stage's output directory but were not written by that stage; "
             "`dvc repro` would delete them when the stage re-runs or is restored, so nothing was run:"]
    for path, (stage, groups) in found.items():
        shown = list(groups.items())
        for group, n in shown[:_SHOWN]:
            lines.append(f"  {path}/{group} ({_describe(root / path, group, n)}): inside the output of stage '{stage}'")
        if len(shown) > _SHOWN:
            lines.append(f"  … and {len(shown) - _SHOWN} more under {path}/")
    lines.append(f"Move real recordings to {RECORDINGS_DIR}/<split>/<sequence>/ and set "
                 "collect.source=recordings (docs/raw_format.md); move anything else out of the output directory.")
    return "\n".join(lines)


def main(root: Path = PROJECT_ROOT) -> int:
    from expoctl.io import write_text

    found = foreign_files(root)
    if found:
        print(f"expoctl guard: error: {message(found, root)}", file=sys.stderr)
        return 2
    stamp = root / GUARD_STAMP
    if not stamp.is_file() or stamp.read_text() != STAMP_TEXT:
        write_text(STAMP_TEXT, stamp)
    write_plugins(root / PLUGINS_FILE)
    return 0


def plugins_text() -> str:
    from stages.table import recorded_plugins

    return ("# written by stages/guard.py: the installed expoctl plugins (entry points), read without importing them\n"
            + yaml.safe_dump(recorded_plugins(), sort_keys=True))


def write_plugins(path: Path) -> None:
    """The installed plugins' list, rewritten only when it changed (DVC hashes content; nothing else re-runs)."""
    from expoctl.io import write_text

    text = plugins_text()
    if not path.is_file() or path.read_text() != text:
        write_text(text, path)


if __name__ == "__main__":
    sys.exit(main())
