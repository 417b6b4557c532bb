"""The fixture DAG's outputs, hashed: what every host must reproduce in the pinned numeric mode (issue 46).

tests/pipeline/fixture_manifest.json holds one digest per file under data/, models/ and reports/ after the end-to-end
test's first `dvc repro` (tests/pipeline/test_dvc_pipeline.py, overrides `OVERRIDES`, `numerics.mode: pinned`, the
default). That test compares its own run against it, so each CI host, whatever its CPU, must give the same bytes.

Most files are hashed as bytes. The exceptions record what differs between any two runs on one host, and say why:
- `VALUES`: files that hold wall-clock times (training epochs, samples/s, per-frame controller milliseconds,
  per-run seconds, the report's timing section) or this checkout's absolute path. They are hashed by value with those
  fields left out, by the rules of benchmarks/same_outputs.py (`strip_volatile`, `TIMING_SECTION`): JSON and YAML
  without time/host/path keys, Markdown without its timing section, checkpoints by their weights and their other
  fields without times, Parquet tables without their clock columns.
- `EXCLUDED`: reports/numerics.json names the host's CPU and library versions by design; the test checks instead
  that it says `pinned`, applied before any numeric library was imported.
MLflow run ids and timestamps live in the MLflow store (outside these directories), never in an output.

Regenerate after a change that is meant to change the fixture's bytes (one line; the end-to-end test, which then
writes the manifest from its own run instead of comparing, ~5–10 min):

    EXPOCTL_WRITE_FIXTURE_MANIFEST=1 .venv/bin/python -m pytest tests/pipeline/test_dvc_pipeline.py -k per_key_rerun

or from a fixture project that ran `dvc repro` with params.yaml `overrides` = OVERRIDES:

    .venv/bin/python tests/pipeline/fixture_manifest.py write PROJECT_DIR     # check PROJECT_DIR: compare (exit 1)
"""

from __future__ import annotations

import argparse
import fnmatch
import hashlib
import importlib.util
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

PROJECT_ROOT = Path(__file__).resolve().parents[2]
MANIFEST = Path(__file__).with_name("fixture_manifest.json")
OUTPUT_DIRS = ("data", "models", "reports")
#: the end-to-end test's first run: the whole DAG, iteration 3 and the closed-loop selection on
OVERRIDES = ["scale=fixture", "iteration3.enabled=true", "select_model.enabled=true"]
WRITE_ENV = "EXPOCTL_WRITE_FIXTURE_MANIFEST"
REGENERATE = f"{WRITE_ENV}=1 .venv/bin/python -m pytest tests/pipeline/test_dvc_pipeline.py -k per_key_rerun"

#: glob -> why the file is compared by value, not by bytes
VALUES: dict[str, str] = {
    "models/*.pt": "the checkpoint records training times (epoch seconds, samples/s) beside its weights",
    "reports/train.json": "epoch seconds and samples/s",
    "reports/iter*/train.json": "epoch seconds and samples/s",
    "reports/select_model.json": "closed-loop run seconds",
    "reports/results.md": "its timing section",
    "reports/eval/frames.parquet": "controller_ms per frame",
    "reports/eval/runs.parquet": "seconds per run",
    "reports/eval/windows.json": "seconds per window",
}
#: glob -> why the file is not compared at all
EXCLUDED: dict[str, str] = {
    "reports/numerics.json": "names this host's CPU and library versions (the run's record of where it ran)",
}


def _same_outputs():
    """benchmarks/same_outputs.py, whose rules for what is a time, a host or a path this manifest shares."""
    spec = importlib.util.spec_from_file_location("same_outputs", PROJECT_ROOT / "benchmarks" / "same_outputs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _match(rel: str, patterns: dict[str, str]) -> str | None:
    return next((p for p in patterns if fnmatch.fnmatchcase(rel, p)), None)


def value_digest(path: Path, root: Path, so=None) -> str:
    """The digest of a `VALUES` file: its content with times, hosts and this checkout's path left out."""
    so = so or _same_outputs()
    if path.suffix in (".json", ".yaml", ".yml"):
        import yaml

        text = so.text(path, root)
        data = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
        return _sha(json.dumps(so.strip_volatile(data), sort_keys=True, default=str).encode())
    if path.suffix == ".md":
        return _sha(so.TIMING_SECTION.sub("", so.text(path, root)).encode())
    if path.suffix == ".pt":
        import torch

        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        state = ckpt.pop("state_dict", {}) if isinstance(ckpt, dict) else {}
        h = hashlib.sha256()
        for name in sorted(state):
            t = state[name].contiguous()
            h.update(f"{name}:{t.dtype}:{tuple(t.shape)}".encode())
            h.update(t.numpy().tobytes() if t.dtype != torch.bfloat16 else t.view(torch.int16).numpy().tobytes())
        rest = so.strip_volatile(json.loads(json.dumps(ckpt, default=str)))
        h.update(json.dumps(rest, sort_keys=True).encode())
        return h.hexdigest()
    if path.suffix == ".parquet":
        import pandas as pd

        table = pd.read_parquet(path)
        table = table.drop(columns=[c for c in table.columns if so.VOLATILE_KEY.search(c)]).reset_index(drop=True)
        h = hashlib.sha256()
        for c in table.columns:
            h.update(f"{c}:{table[c].dtype}".encode())
            h.update(pd.util.hash_pandas_object(table[c], index=False).to_numpy().tobytes())
        return h.hexdigest()
    raise ValueError(f"{path}: no rule to compare a {path.suffix} file by value")


def digests(root: Path) -> dict[str, str]:
    """{relative path: 'bytes:<sha256>' or 'values:<sha256>'} for every output file of the project at `root`."""
    so = _same_outputs()
    out = {}
    for rel in sorted(so.files_under(root, OUTPUT_DIRS)):
        rel = Path(rel).as_posix()
        if _match(rel, EXCLUDED):
            continue
        path = root / rel
        out[rel] = f"values:{value_digest(path, root, so)}" if _match(rel, VALUES) else f"bytes:{_sha(path.read_bytes())}"
    return out


def _overrides(root: Path) -> list[str]:
    import yaml

    return list((yaml.safe_load((root / "params.yaml").read_text()) or {}).get("overrides") or [])


def build(root: Path) -> dict[str, Any]:
    """The manifest of the fixture project at `root` (refused unless it ran with OVERRIDES, pinned)."""
    from expoctl.host import host_cpu

    if _overrides(root) != OVERRIDES:
        raise SystemExit(f"{root}/params.yaml overrides are {_overrides(root)}, not the end-to-end test's {OVERRIDES}")
    numerics = json.loads((root / "reports" / "numerics.json").read_text())
    if numerics.get("mode") != "pinned" or not numerics.get("applied_before_import"):
        raise SystemExit(f"{root}: reports/numerics.json says mode {numerics.get('mode')!r}, applied before import "
                         f"{numerics.get('applied_before_import')}: a manifest is made in the pinned mode only")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True).stdout
    return {"about": "tests/pipeline/fixture_manifest.py: the fixture DAG's outputs, every host the same (issue 46)",
            "regenerate": REGENERATE, "overrides": OVERRIDES, "numerics_mode": "pinned",
            "made_on": {"host_cpu": host_cpu(), "commit": commit.strip() or "unknown",
                        "versions": numerics.get("versions", {})},
            "compared_by_value": VALUES, "excluded": EXCLUDED, "files": digests(root)}


def differences(root: Path, manifest: dict[str, Any] | None = None) -> list[str]:
    """One line per file that is missing, extra or different at `root` against the manifest; [] if all equal."""
    manifest = manifest if manifest is not None else json.loads(MANIFEST.read_text())
    want, got = manifest["files"], digests(root)
    lines = [f"missing: {rel}" for rel in sorted(want.keys() - got.keys())]
    lines += [f"not in the manifest: {rel}" for rel in sorted(got.keys() - want.keys())]
    lines += [f"differs ({want[rel].split(':')[0]}): {rel}" for rel in sorted(want.keys() & got.keys())
              if want[rel] != got[rel]]
    return lines


def write(root: Path, path: Path = MANIFEST) -> Path:
    path.write_text(json.dumps(build(root), indent=1, sort_keys=False) + "\n")
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("action", choices=("write", "check"))
    ap.add_argument("project", type=Path, help="a fixture project after `dvc repro` with overrides = OVERRIDES")
    args = ap.parse_args(argv)
    sys.path[:0] = [str(PROJECT_ROOT / "src")]
    if args.action == "write":
        print(f"wrote {write(args.project)} ({len(json.loads(MANIFEST.read_text())['files'])} files)")
        return 0
    diff = differences(args.project)
    print("\n".join(diff) if diff else f"{args.project}: every output as in {MANIFEST.name}")
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main())
