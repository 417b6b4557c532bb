"""Raw dual-camera sequences: the on-disk format a real rig or the simulator's `collect` writes (docs/raw_format.md).

```
<sequence>/sequence.yaml   source (sim|rig), rig{baseline_m, fps, resolution [w, h], intrinsics{fx, fy, cx, cy}},
                           world, route, reference_controller, seed, sections [{start_frame, end_frame, kind}]
<sequence>/frames.csv      frame_id, camera (1|2), timestamp_ns, gain_db, exposure_us, image (relative path)
<sequence>/cam1/000000.png, cam2/000000.png   8-bit RGB PNG
```

`SequenceWriter` writes one sequence into a hidden temporary directory and renames it into place on `close()`, so a
crash never leaves a half-written sequence. The reader functions raise `InputError`; the validator in
`expoctl.raw.validate` collects every problem instead of stopping at the first.
"""

from __future__ import annotations

import csv
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd
import yaml

from expoctl.errors import InputError

FRAMES_CSV = "frames.csv"
SEQUENCE_YAML = "sequence.yaml"
FRAMES_COLUMNS = ["frame_id", "camera", "timestamp_ns", "gain_db", "exposure_us", "image"]
SECTION_KINDS = ("static", "dynamic", "interior")  # interior: inside a tunnel, away from its portals
SOURCES = ("sim", "rig")


def is_sequence_dir(path: Path) -> bool:
    """A directory is a sequence if it holds a frames.csv or a sequence.yaml."""
    return path.is_dir() and ((path / FRAMES_CSV).exists() or (path / SEQUENCE_YAML).exists())


def find_sequences(raw_dir: str | os.PathLike) -> list[Path]:
    """All sequence directories under `raw_dir` (any depth; hidden temp dirs skipped), sorted by path."""
    raw_dir = Path(raw_dir)
    if not raw_dir.is_dir():
        raise InputError(f"{raw_dir}: raw data directory does not exist")
    if is_sequence_dir(raw_dir):
        return [raw_dir]
    found = []
    for root, dirs, _files in os.walk(raw_dir):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for d in list(dirs):
            p = Path(root) / d
            if is_sequence_dir(p):
                found.append(p)
                dirs.remove(d)  # a sequence's cam1/ cam2/ are not sequences
    return sorted(found)


def read_sequence_yaml(seq_dir: str | os.PathLike) -> dict[str, Any]:
    """Parse sequence.yaml into a dict; InputError if missing or not a YAML mapping."""
    path = Path(seq_dir) / SEQUENCE_YAML
    if not path.exists():
        raise InputError(f"{path}: missing sequence.yaml")
    try:
        meta = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: malformed YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(meta, dict):
        raise InputError(f"{path}: expected a mapping at the top level, got {type(meta).__name__}")
    return meta


def read_frames_csv(seq_dir: str | os.PathLike) -> pd.DataFrame:
    """frames.csv as a DataFrame of strings (the validator converts and checks types row by row)."""
    path = Path(seq_dir) / FRAMES_CSV
    if not path.exists():
        raise InputError(f"{path}: missing frames.csv")
    try:
        return pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot parse CSV ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None


def read_png_size(path: str | os.PathLike) -> tuple[int, int] | None:
    """(width, height) from a PNG header without decoding; None if the file is not a PNG."""
    with open(path, "rb") as f:
        head = f.read(24)
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


#: the last 12 bytes of every complete PNG: the IEND chunk (length 0, type, CRC)
PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def png_has_end(path: str | os.PathLike) -> bool:
    """Whether the file ends with the PNG end chunk (IEND), without decoding: a truncated PNG does not."""
    with open(path, "rb") as f:
        f.seek(0, os.SEEK_END)
        if f.tell() < len(PNG_END):
            return False
        f.seek(-len(PNG_END), os.SEEK_END)
        return f.read() == PNG_END


def decode_8bit_image(path: str | os.PathLike) -> np.ndarray:
    """Decode an image file as stored (grey H×W, or BGR/BGRA H×W×C, uint8); InputError naming the file if it is
    missing, unreadable or not 8-bit."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: image file missing")
    data = np.fromfile(path, dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        if data[:8].tobytes() == b"\x89PNG\r\n\x1a\n" and not png_has_end(path):
            raise InputError(f"{path}: truncated or corrupt PNG ({data.size} bytes, no end chunk): unreadable")
        raise InputError(f"{path}: unreadable or corrupt image")
    if img.dtype != np.uint8:
        raise InputError(f"{path}: expected an 8-bit image, got {img.dtype}")
    return img


def read_image_rgb(path: str | os.PathLike) -> np.ndarray:
    """Decode an 8-bit RGB image (H×W×3 uint8); InputError naming the file if unreadable or not 8-bit colour."""
    img = decode_8bit_image(path)
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise InputError(f"{path}: expected an RGB image, got shape {img.shape}")
    return np.ascontiguousarray(img[..., 2::-1])  # BGR(A) → RGB


class SequenceWriter:
    """Write one raw sequence atomically.

    >>> with SequenceWriter(out / "train" / "seq_000", meta) as w:
    ...     w.add_frame(frame_id=0, camera=1, timestamp_ns=0, gain_db=0.0, exposure_us=5000.0, image=rgb)
    The directory appears only when the `with` block exits without an exception.
    """

    def __init__(self, seq_dir: str | os.PathLike, meta: dict[str, Any]):
        self.seq_dir = Path(seq_dir)
        self.meta = dict(meta)
        self.seq_dir.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = Path(tempfile.mkdtemp(prefix=f".{self.seq_dir.name}.", dir=self.seq_dir.parent))
        (self._tmp / "cam1").mkdir()
        (self._tmp / "cam2").mkdir()
        self._rows: list[list[Any]] = []
        self._closed = False

    def add_frame(self, frame_id: int, camera: int, timestamp_ns: int, gain_db: float, exposure_us: float,
                  image: np.ndarray) -> None:
        if camera not in (1, 2):
            raise ValueError(f"camera must be 1 or 2, got {camera}")
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"image must be H×W×3 uint8 RGB, got {image.dtype} {image.shape}")
        rel = f"cam{camera}/{int(frame_id):06d}.png"
        # PNG level 1: a few times faster to write than the default and only ~10 % larger.
        ok, buf = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 1])
        if not ok:
            raise OSError(f"could not encode {rel}")
        (self._tmp / rel).write_bytes(buf.tobytes())
        self._rows.append([int(frame_id), int(camera), int(timestamp_ns), float(gain_db), float(exposure_us), rel])

    def close(self) -> Path:
        """Write frames.csv and sequence.yaml, then move the sequence into place (replacing an older one)."""
        if self._closed:
            return self.seq_dir
        rows = sorted(self._rows, key=lambda r: (r[0], r[1]))
        with open(self._tmp / FRAMES_CSV, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(FRAMES_COLUMNS)
            for r in rows:
                w.writerow([r[0], r[1], r[2], repr(r[3]), repr(r[4]), r[5]])
        (self._tmp / SEQUENCE_YAML).write_text(yaml.safe_dump(_plain(self.meta), sort_keys=False))
        if self.seq_dir.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{self.seq_dir.name}.old.", dir=self.seq_dir.parent))
            os.replace(self.seq_dir, old / "x")
            os.replace(self._tmp, self.seq_dir)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(self._tmp, self.seq_dir)
        self._closed = True
        return self.seq_dir

    def abort(self) -> None:
        shutil.rmtree(self._tmp, ignore_errors=True)
        self._closed = True

    def __enter__(self) -> "SequenceWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _plain(obj: Any) -> Any:
    """numpy scalars/arrays and tuples → plain YAML-safe Python values."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj
