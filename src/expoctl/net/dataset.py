"""Training data: samples.parquet + frames.parquet + image store → batches of network inputs.

Speed: every frame any sample needs is read once from the memory-mapped store (`data/images/<sequence>.npy`,
uint8 (n_frames, 2, H, W, 3), axis 1 = camera − 1), passed through `expoctl.net.preprocess.prepare_frame` (the same
code the deployed controller runs) and kept in one uint8 array (N, 3, h, w). The 8 camera combinations of a time
step share their frames, so the cache holds each frame once. A batch is then an index gather plus
`assemble_input` — no decoding or resizing per sample per epoch.

Augmentation (optional): a horizontal flip shared by the three frames of a sample (flipping them independently
would invent motion that never happened); gain/exposure planes are constant and unaffected. And synthetic
over-exposure (`expoctl.net.exposure_shift`): the three frames and their settings as the camera would have delivered
them k EV brighter, the label unchanged.

Exposure scaling: samples.parquet stores targets in the paper's linear scaling (the data contract); the planes and
targets handed to the network use `exposure_scale` (the model's, `expoctl.camera.ranges`), converted here once.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import torch

from expoctl.camera.ranges import rescale_exposure_norm
from expoctl.errors import InputError
from expoctl.net.preprocess import N_FRAMES, as_hw, assemble_input, prepare_frame, settings_to_norm

if TYPE_CHECKING:
    from expoctl.net.exposure_shift import ExposureShift

SAMPLE_COLUMNS = ("sample_id", "sequence", "frame_id", "cam_t", "cam_t1", "cam_t2",
                  "target_gain_norm", "target_exposure_norm", "split")
FRAME_COLUMNS = ("sequence", "frame_id", "camera", "gain_db", "exposure_us", "image_index")


@dataclass
class SampleSet:
    """Everything needed to make batches for one split; tensors are CPU and contiguous."""

    frames: torch.Tensor  # (N_frames, 3, h, w) uint8, shared by all splits built together
    frame_idx: torch.Tensor  # (S, 3) int64 rows of `frames` for t, t−1, t−2
    gain_norm: torch.Tensor  # (S, 3) float32
    exposure_norm: torch.Tensor  # (S, 3) float32
    targets: torch.Tensor  # (S, 2) float32 [gain_norm, exposure_norm], exposure in `exposure_scale`
    sample_id: np.ndarray  # (S,)
    time_step: np.ndarray  # (S,) int64 in 0 … T−1: equal values share (sequence, frame_id), hence one label
    cameras: np.ndarray  # (S, 3) int64: camera (1 | 2) of the frames t, t−1, t−2
    store_hw: tuple[int, int]
    input_hw: tuple[int, int]
    exposure_scale: str = "linear"  # scaling of exposure_norm and targets[:, 1] (expoctl.camera.ranges)

    def __len__(self) -> int:
        return int(self.frame_idx.shape[0])

    def batch(self, idx, flip: torch.Tensor | None = None, shift_ev: torch.Tensor | None = None,
              shifter: "ExposureShift | None" = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Samples `idx` → (inputs (B, 15, h, w) float32, targets (B, 2)). `flip`: (B,) bool, mirror those samples.
        `shift_ev`: (B,) EV ≥ 0, show those samples brighter by `shifter` (`expoctl.net.exposure_shift`)."""
        idx = torch.as_tensor(idx, dtype=torch.long)
        imgs = self.frames[self.frame_idx[idx]]  # (B, 3, 3, h, w)
        if flip is not None and bool(flip.any()):
            imgs = imgs.clone()
            imgs[flip] = torch.flip(imgs[flip], dims=[-1])
        gain, exposure = self.gain_norm[idx], self.exposure_norm[idx]
        if shift_ev is not None and bool((shift_ev > 0).any()):
            if shifter is None or shifter.exposure_scale != self.exposure_scale:
                raise ValueError("a shifted batch needs an ExposureShift with the samples' exposure scale")
            imgs, gain, exposure = shifter.apply(imgs, gain, exposure, shift_ev)
        return assemble_input(imgs, gain, exposure), self.targets[idx]


@torch.no_grad()
def predict(model: torch.nn.Module, data: SampleSet, batch_size: int = 256, rows: np.ndarray | None = None) -> np.ndarray:
    """Raw (unclamped) normalised network outputs for `rows` of `data` (default all), in eval mode."""
    was_training = model.training
    model.eval()
    rows = np.arange(len(data)) if rows is None else rows
    out = [model(data.batch(rows[i:i + batch_size])[0]).numpy() for i in range(0, len(rows), batch_size)]
    model.train(was_training)
    return np.concatenate(out) if out else np.zeros((0, 2), np.float32)


def _require(df: pd.DataFrame, cols, what: str) -> None:
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise InputError(f"{what}: missing column(s) {missing}")


def load_sample_sets(samples: pd.DataFrame, frames: pd.DataFrame, images_dir: str | Path, input_size,
                     splits=("train", "validation"), samples_name: str = "samples",
                     frames_name: str = "frames", exposure_scale: str = "linear") -> dict[str, SampleSet]:
    """Build one SampleSet per requested split (splits absent from `samples` get no entry); planes and targets in
    `exposure_scale` (the model's)."""
    _require(samples, SAMPLE_COLUMNS, samples_name)
    _require(frames, FRAME_COLUMNS, frames_name)
    images_dir = Path(images_dir)
    input_hw = as_hw(input_size)
    samples = samples[samples["split"].isin(splits)].reset_index(drop=True)
    if samples.empty:
        raise InputError(f"{samples_name}: no samples in split(s) {list(splits)}")
    for col in ("target_gain_norm", "target_exposure_norm"):
        v = samples[col].to_numpy(dtype=np.float64)
        if not np.all(np.isfinite(v)):
            bad = samples.loc[~np.isfinite(v), "sample_id"].iloc[0]
            raise InputError(f"{samples_name}: {col} is not finite for sample_id {bad}")

    # The three frame keys of every sample: (sequence, frame_id − k, camera of that frame).
    keys = pd.concat(
        [pd.DataFrame({"sequence": samples["sequence"], "frame_id": samples["frame_id"].astype(np.int64) - k,
                       "camera": samples[cam].astype(np.int64), "slot": k, "row": np.arange(len(samples))})
         for k, cam in enumerate(("cam_t", "cam_t1", "cam_t2"))], ignore_index=True)
    fr = frames[list(FRAME_COLUMNS)].copy()
    fr["frame_id"] = fr["frame_id"].astype(np.int64)
    fr["camera"] = fr["camera"].astype(np.int64)
    if fr.duplicated(["sequence", "frame_id", "camera"]).any():
        d = fr[fr.duplicated(["sequence", "frame_id", "camera"])].iloc[0]
        raise InputError(f"{frames_name}: duplicate row for sequence {d.sequence} frame {d.frame_id} camera {d.camera}")
    merged = keys.merge(fr, on=["sequence", "frame_id", "camera"], how="left")
    if merged["image_index"].isna().any():
        m = merged[merged["image_index"].isna()].iloc[0]
        sid = samples["sample_id"].iloc[int(m.row)]
        raise InputError(f"{samples_name}: sample_id {sid} needs sequence {m.sequence} frame {m.frame_id} "
                         f"camera {m.camera}, which is not in {frames_name}")

    # Unique frames → cache rows.
    uniq = merged[["sequence", "frame_id", "camera", "image_index"]].drop_duplicates(["sequence", "frame_id", "camera"])
    uniq = uniq.sort_values(["sequence", "image_index", "camera"]).reset_index(drop=True)
    uniq["cache_row"] = np.arange(len(uniq))
    cache = np.empty((len(uniq), 3, *input_hw), dtype=np.uint8)
    store_hw = None
    for seq, grp in uniq.groupby("sequence", sort=True):
        path = images_dir / f"{seq}.npy"
        if not path.exists():
            raise InputError(f"{path}: image store for sequence {seq} not found")
        try:
            store = np.load(path, mmap_mode="r")
        except (ValueError, OSError) as exc:
            raise InputError(f"{path}: cannot read image store ({exc})") from None
        if store.dtype != np.uint8 or store.ndim != 5 or store.shape[1] != 2 or store.shape[4] != 3:
            raise InputError(f"{path}: expected uint8 (n_frames, 2, H, W, 3), got {store.dtype} {store.shape}")
        hw = (int(store.shape[2]), int(store.shape[3]))
        if store_hw is not None and hw != store_hw:
            raise InputError(f"{path}: image size {hw} differs from other sequences' {store_hw}")
        store_hw = hw
        img_idx = grp["image_index"].to_numpy(dtype=np.int64)
        if img_idx.min() < 0 or img_idx.max() >= store.shape[0]:
            raise InputError(f"{path}: image_index {int(img_idx.max())} out of range (store has {store.shape[0]} frames)")
        for row, i, cam in zip(grp["cache_row"].to_numpy(), img_idx, grp["camera"].to_numpy()):
            cache[row] = prepare_frame(store[i, cam - 1], hw, input_hw).transpose(2, 0, 1)

    merged = merged.merge(uniq[["sequence", "frame_id", "camera", "cache_row"]], on=["sequence", "frame_id", "camera"])
    merged = merged.sort_values(["row", "slot"])
    n = len(samples)
    frame_idx = merged["cache_row"].to_numpy(np.int64).reshape(n, N_FRAMES)
    g, e = settings_to_norm(merged["gain_db"].to_numpy(np.float64), merged["exposure_us"].to_numpy(np.float64),
                            exposure_scale)
    g, e = g.reshape(n, N_FRAMES), e.reshape(n, N_FRAMES)
    targets = np.stack([samples["target_gain_norm"].to_numpy(np.float64),
                        rescale_exposure_norm(samples["target_exposure_norm"].to_numpy(np.float64), "linear",
                                              exposure_scale)], axis=1).astype(np.float32)

    frames_t = torch.from_numpy(cache)
    out = {}
    for split in splits:
        sel = np.flatnonzero(samples["split"].to_numpy() == split)
        if len(sel) == 0:
            continue
        out[split] = SampleSet(
            frames=frames_t,
            frame_idx=torch.from_numpy(np.ascontiguousarray(frame_idx[sel])),
            gain_norm=torch.from_numpy(np.ascontiguousarray(g[sel])),
            exposure_norm=torch.from_numpy(np.ascontiguousarray(e[sel])),
            targets=torch.from_numpy(np.ascontiguousarray(targets[sel])),
            sample_id=samples["sample_id"].to_numpy()[sel],
            time_step=pd.MultiIndex.from_arrays([samples["sequence"].astype(str).to_numpy()[sel],
                                                 samples["frame_id"].to_numpy(np.int64)[sel]]).factorize()[0]
                                                 .astype(np.int64),
            cameras=samples[["cam_t", "cam_t1", "cam_t2"]].to_numpy(np.int64)[sel],
            store_hw=store_hw,
            input_hw=input_hw,
            exposure_scale=exposure_scale,
        )
    return out


def load_sample_sets_from_files(samples_path, frames_path, images_dir, input_size, splits=("train", "validation"),
                                exposure_scale: str = "linear"):
    """As `load_sample_sets`, reading the two Parquet tables (errors name the files)."""
    tables = []
    for p in (samples_path, frames_path):
        p = Path(p)
        if not p.exists():
            raise InputError(f"{p}: not found")
        try:
            tables.append(pd.read_parquet(p))
        except Exception as exc:  # pyarrow raises several types for corrupt files
            raise InputError(f"{p}: cannot read Parquet ({exc})") from None
    return load_sample_sets(tables[0], tables[1], images_dir, input_size, splits,
                            samples_name=str(samples_path), frames_name=str(frames_path),
                            exposure_scale=exposure_scale)
