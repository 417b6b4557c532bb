"""Are two pipeline checkouts' outputs the same? Proof that a refactor changed no result (not a test).

Compares every file under the output directories (data/, models/, reports/ by default) of two checkouts that ran
the same `dvc repro` (e.g. the fixture scale before and after a change). A file counts as the same when its bytes
are equal; otherwise, with each checkout's own path replaced by a placeholder: JSON and YAML files are compared with
the fields that name times, durations, hosts or paths left out (and file hashes, which follow from checkpoints that
record training times); Markdown reports without their timing section; Parquet tables by value without those
columns; checkpoints (.pt) by weights, then their other fields as JSON. Prints the files that differ and a count per kind; exits 1
when anything differs or exists on one side only.

    git clone -q . /tmp/before && git -C /tmp/before checkout -q OLD
    git clone -q . /tmp/after  && git -C /tmp/after  checkout -q NEW
    (in each: set params.yaml overrides to ["scale=fixture"], ln -s your ../shared beside it, then dvc repro)
    .venv/bin/python benchmarks/same_outputs.py /tmp/before /tmp/after
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import pandas as pd
import yaml

OUTPUT_DIRS = ("data", "models", "reports")
# keys whose values are times, durations, hosts or paths: they differ between two runs of the same code
VOLATILE_KEY = re.compile(r"(^|_)(seconds|second|time|times|duration|elapsed|timestamp|host|hostname|cpu|path|paths|"
                          r"dir|started|finished|date|per_s|samples_per_s|ms|ms_median|pid|sha256)$|_per_s$|_per_frame$|_path$|_dir$",
                          re.IGNORECASE)


def strip_volatile(x):
    if isinstance(x, dict):
        return {k: strip_volatile(v) for k, v in x.items() if not VOLATILE_KEY.search(str(k))}
    if isinstance(x, list):
        return [strip_volatile(v) for v in x]
    return x


TIMING_SECTION = re.compile(r"^## [^\n]*timing[^\n]*\n.*?(?=^## |\Z)", re.IGNORECASE | re.MULTILINE | re.DOTALL)


def text(path: Path, root: Path) -> str:
    return path.read_text().replace(str(root.resolve()), "<root>").replace(str(root), "<root>")


def same_structured(a: Path, b: Path, ra: Path, rb: Path) -> bool:
    """JSON or YAML, volatile fields left out."""
    load = json.loads if a.suffix == ".json" else yaml.safe_load
    try:
        return strip_volatile(load(text(a, ra))) == strip_volatile(load(text(b, rb)))
    except (ValueError, UnicodeDecodeError, yaml.YAMLError):
        return False


def same_markdown(a: Path, b: Path, ra: Path, rb: Path) -> bool:
    return TIMING_SECTION.sub("", text(a, ra)) == TIMING_SECTION.sub("", text(b, rb))


def same_checkpoint(a: Path, b: Path) -> bool:
    import torch  # only when a checkpoint differs in bytes

    ca, cb = torch.load(a, map_location="cpu", weights_only=True), torch.load(b, map_location="cpu", weights_only=True)
    if not (isinstance(ca, dict) and isinstance(cb, dict)) or ca.keys() != cb.keys():
        return False
    sa, sb = ca.pop("state_dict", {}), cb.pop("state_dict", {})
    if sa.keys() != sb.keys() or not all(torch.equal(sa[k], sb[k]) for k in sa):
        return False
    return strip_volatile(json.loads(json.dumps(ca, default=str))) == strip_volatile(json.loads(json.dumps(cb, default=str)))


def same_parquet(a: Path, b: Path) -> bool:
    ta, tb = pd.read_parquet(a), pd.read_parquet(b)
    drop = [c for c in ta.columns if VOLATILE_KEY.search(c)]
    ta, tb = ta.drop(columns=drop, errors="ignore"), tb.drop(columns=drop, errors="ignore")
    return list(ta.columns) == list(tb.columns) and ta.equals(tb)


def files_under(root: Path, dirs) -> set[str]:
    out = set()
    for d in dirs:
        base = root / d
        if base.is_dir():
            out |= {str(p.relative_to(root)) for p in base.rglob("*") if p.is_file() and ".dvc" not in p.parts}
    return out


def compare(a_root: Path, b_root: Path, dirs=OUTPUT_DIRS) -> dict:
    fa, fb = files_under(a_root, dirs), files_under(b_root, dirs)
    result = {"only_a": sorted(fa - fb), "only_b": sorted(fb - fa), "bytes": 0, "values": [], "differ": []}
    for rel in sorted(fa & fb):
        a, b = a_root / rel, b_root / rel
        if a.read_bytes() == b.read_bytes():
            result["bytes"] += 1
        elif a.suffix in (".json", ".yaml", ".yml") and same_structured(a, b, a_root, b_root):
            result["values"].append(rel)
        elif a.suffix == ".md" and same_markdown(a, b, a_root, b_root):
            result["values"].append(rel)
        elif a.suffix == ".pt" and same_checkpoint(a, b):
            result["values"].append(rel)
        elif a.suffix == ".parquet" and same_parquet(a, b):
            result["values"].append(rel)
        else:
            result["differ"].append(rel)
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--dirs", nargs="+", default=list(OUTPUT_DIRS))
    args = ap.parse_args(argv)
    missing = [str(p) for p in (args.before, args.after) if not p.is_dir()]
    if missing:
        print(f"same_outputs: not a directory: {', '.join(missing)}", file=sys.stderr)
        return 2
    r = compare(args.before, args.after, args.dirs)
    print(f"byte-identical: {r['bytes']} files; equal apart from times/paths: {len(r['values'])}; "
          f"differ: {len(r['differ'])}; only before: {len(r['only_a'])}; only after: {len(r['only_b'])}")
    for kind in ("values", "differ", "only_a", "only_b"):
        for rel in r[kind]:
            print(f"  {kind}: {rel}")
    return 1 if (r["differ"] or r["only_a"] or r["only_b"]) else 0


if __name__ == "__main__":
    sys.exit(main())
