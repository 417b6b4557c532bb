"""Real rig recordings as the pipeline's training data (`collect.source: recordings`).

Recordings live in a directory that no pipeline stage writes (data/recordings/ in the project), so nothing the
pipeline does can delete them. `copy_recordings` validates every sequence there — every problem of every sequence
in one pass — and only then copies them, with their `<split>/<sequence>/` layout, into the raw-data directory the
later stages read, swapping it in whole. The source is only read.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Callable

from expoctl.errors import InputError
from expoctl.io import atomic_dir
from expoctl.raw.format import find_sequences, read_sequence_yaml
from expoctl.raw.validate import check_sequence


def check_recordings(src: Path) -> list[Path]:
    """The dual-camera sequences under `src`, sorted; InputError naming every problem of every sequence (structure,
    sequence.yaml, frames.csv; images are decoded by ingest, which reports them all in its own single pass)."""
    if not src.is_dir():
        raise InputError(f"{src}: the recordings directory does not exist (collect.source is recordings: put each "
                         f"recorded sequence in {src}/<split>/<sequence>/, see docs/raw_format.md)")
    seqs = find_sequences(src)
    if not seqs:
        raise InputError(f"{src}: no recorded sequences (a sequence is a directory with sequence.yaml and frames.csv; "
                         f"collect.source is recordings)")
    problems: list[str] = []
    for seq in seqs:
        check = check_sequence(seq, decode_images=False)
        problems.extend(check.problems)
        if not check.problems and check.n_cameras != 2:
            problems.append(f"{seq}: a one-camera recording (cameras: {check.n_cameras} in sequence.yaml); training "
                            f"needs the dual-camera rig's sequences")
    if problems:
        raise InputError(f"{len(problems)} problem(s) in {src}:\n" + "\n".join(problems))
    return seqs


def copy_recordings(src: str | os.PathLike, out_dir: str | os.PathLike,
                    progress: Callable[[str], None] | None = None) -> list[dict]:
    """Validate the recordings under `src` and copy them into `out_dir` (replaced whole, atomically). Returns one
    summary per sequence: split directory, name, frame pairs, dynamic sections."""
    src, out_dir = Path(src), Path(out_dir)
    seqs = check_recordings(src)
    summaries = []
    with atomic_dir(out_dir) as tmp:
        for i, seq in enumerate(seqs, 1):
            rel = seq.relative_to(src)
            shutil.copytree(seq, tmp / rel, ignore=shutil.ignore_patterns(".*"))
            meta = read_sequence_yaml(seq)
            n_frames = len((tmp / rel / "frames.csv").read_text().splitlines()) - 1
            summaries.append({"sequence": rel.as_posix(), "split": rel.parts[0] if len(rel.parts) > 1 else "",
                              "n_frames": n_frames // 2,
                              "n_dynamic_sections": sum(1 for s in meta.get("sections") or []
                                                        if isinstance(s, dict) and s.get("kind") == "dynamic")})
            if progress is not None:
                progress(f"recording {i}/{len(seqs)}: {rel.as_posix()} ({n_frames // 2} frame pairs) copied")
    return summaries
