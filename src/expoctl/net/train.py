"""Training the controller network: Adam on the ε-weighted L1 loss, early stopping, best checkpoint, baselines.

Loss (paper): L = ε·mean|Ĝ − G*| + (1 − ε)·mean|Ê − E*| on [0, 1]-scaled targets.

Camera-consistency term (ours, `consistency_weight` λ > 0; 0 = the paper's loss): the eight camera combinations of
one time step share one label, because the best settings for frame t+1 depend on the scene, not on which camera's
frames the network looks at. Their inputs differ in the settings planes and in image brightness. The L1 loss alone
lets a network that cannot yet read the scene sit near the hold predictor and move its output with its input
settings; in closed loop, where the input is its own last output, that amplifies each step's bias
(`expoctl.net.follow`). With λ > 0 each global batch holds batch_size/2 pairs: a drawn sample and its complement,
the same time step with every frame from the other camera (c112 ↔ c221; sharing the flip), and the loss adds
λ·(ε·mean|Ĝ_a − Ĝ_b| + (1 − ε)·mean|Ê_a − Ê_b|), which is zero only for outputs that do not depend on the camera.
The complement, not a random other combination: three of a sample's seven siblings share its frame t, and the hold
predictor (where the residual network starts) already agrees on those, so random partners pull towards holding
(measured: follow 0.50 → 0.73 on seed 2's iteration 1). Partners may lie outside a `max_train_samples` subset (same
time step, same label). Same gradient steps and samples per epoch as λ = 0, so the cost per epoch is unchanged.
Synthetic over-exposure (ours, `exposure_shift_probability` p > 0; 0 = the paper's data): each epoch a share p of
the training samples is shown k ~ U[`exposure_shift_ev`] EV brighter, frames and settings planes, with its label
unchanged (`expoctl.net.exposure_shift`); consistency partners share their anchor's k. Validation is never shifted.
Clipped-frame prior (ours, `clipped_frame_weight` > 0; 0 = the paper's loss): a hinge that makes the step on an
all-white input darker and on an all-black input brighter than the real camera's AE limits, at drawn settings
(`expoctl.net.clipped_frames`); it is part of the training loss the history reports. Every run reports the steps on
such inputs over a settings grid (`white_step_max_ev`, `black_step_min_ev`).
Errors in physical units, as the deployed controller would see them (outputs clamped to [0, 1], then unscaled):
gain in dB (mean |ĝ − g*|), exposure in EV (mean |log2(ê / e*)|). The constant predictor is the per-output median
of the training targets (the L1-optimal constant); the model's errors are reported next to it. A second, stronger
reference is the hold predictor: "keep frame t's settings" (what a controller that never reacts would command). A
network that has learnt anything about exposure must beat both. The final metrics also carry the open-loop camera
follow of the best model on the whole validation split (`expoctl.net.follow`): how much its output moves with its
input settings, the quantity that amplifies a per-step bias in closed loop.

Distributed data parallel: when `torch.distributed` is initialised (torchrun), each process takes an interleaved
share of every global batch (`batch_size` stays the global batch, so hyperparameters mean the same at any
process count), gradients are averaged by DDP, validation sums are all-reduced, and every rank reaches the same
early-stopping decision. Only rank 0 calls `on_epoch`. Library code: no MLflow/Hydra here.

Device (`device`: auto | cpu | cuda; `resolve_device`): the model and every batch (inputs and targets) live on the
training device; helpers that build their own CPU inputs (`predict`, the camera follow, the clipped-frame prior and
its probe) see the model through `OnDevice`, which moves their inputs there and the outputs back. The returned model
is always on the CPU, so checkpoints and the ONNX export do not depend on where training ran. On the CPU every move is
a no-op (`Tensor.to` returns the tensor itself): results are bit-identical to a build without the option. CUDA runs
are not bit-identical to CPU runs (other kernels), nor guaranteed run to run (cuDNN).
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, fields
from typing import Callable

import numpy as np
import torch
import torch.distributed as dist
from torch import nn

from expoctl.camera.ranges import norm_to_exposure, norm_to_gain
from expoctl.net.follow import camera_follow
from expoctl.net.dataset import SampleSet, predict
from expoctl.net.exposure_shift import MAX_SHIFT_EV, ExposureShift, draw_shifts
from expoctl.net.clipped_frames import clipped_frame_loss, uniform_frame_steps
from expoctl.camera.response import Response
from expoctl.config_reader import Section, param, read_config
from expoctl.errors import ConfigError
from expoctl.net.model import ExposureNet, ModelConfig, count_macs, count_parameters


#: where training runs (train.device; resolve_device)
DEVICES = ("auto", "cpu", "cuda")


@dataclass(frozen=True)
class TrainConfig:
    lr: float = 1e-4
    batch_size: int = 64  # global batch (split across DDP processes)
    epochs: int = 200
    epsilon: float = 0.5  # loss weight of gain; 1 − ε on exposure
    weight_decay: float = 0.0
    patience: int = 20  # early stopping: epochs without a validation-loss improvement > min_delta
    min_delta: float = 0.0
    flip_prob: float = 0.5  # shared horizontal flip of the three frames
    num_threads: int = 2  # torch.set_num_threads per process
    eval_batch_size: int = 256
    max_train_samples: int | None = None  # random subset (for quick studies); None = all
    # "fixed": one random subset of max_train_samples for the whole run; "per_epoch": a fresh random subset of that
    # size every epoch (same cost per epoch, but over the run the network sees most of the data)
    train_subset: str = "fixed"
    max_validation_samples: int | None = None
    consistency_weight: float = 0.0  # λ of the camera-consistency term (module doc); 0 = the paper's loss
    # synthetic over-exposure (expoctl.net.exposure_shift): this share of training samples, each k ~ U[exposure_shift_ev]
    # EV brighter; 0 = the paper's data
    exposure_shift_probability: float = 0.0
    exposure_shift_ev: tuple[float, ...] = param((0.0, 6.0), length=2, unit="EV")
    # clipped-frame prior (expoctl.net.clipped_frames): weight of the hinge on all-white / all-black inputs; 0 = the
    # paper's loss. Per batch clipped_frame_samples white and as many black inputs; margins (white, black) in EV
    clipped_frame_weight: float = 0.0
    clipped_frame_samples: int = 4
    clipped_frame_margin_ev: tuple[float, ...] = param((0.178, 0.51), length=2, unit="EV")
    # where training runs: auto (cuda when torch.cuda.is_available(), else cpu) | cpu | cuda (resolve_device)
    device: str = param("auto", choices=DEVICES)
    onnx_exporter: str = "torchscript"  # torchscript (no extra deps) | dynamo (needs onnxscript)
    mlflow_model_format: str = "pt2"  # how the stage logs the model to MLflow: pt2 (safe, ~10 s export) | pickle

    @classmethod
    def from_dict(cls, d: dict | None, key: str = "train", problems=None) -> "TrainConfig":
        """Every problem at once (ConfigError), each under its own key (`config_reader.read_config`)."""
        return read_config(cls, d, key, problems)

    def check(self, r: Section) -> None:
        """The bounds and choices (read_config runs it once every key has the right type)."""
        for key, problem in self.problems():
            r.problem(key, problem)

    def validate(self, prefix: str = "train") -> None:
        """Every problem at once (ConfigError) of a config built in code."""
        problems = [(f"{prefix}.{key}", problem) for key, problem in self.problems()]
        if problems:
            raise ConfigError.of(problems)

    def problems(self) -> list[tuple[str, str]]:
        """(key, problem) for each value out of its bounds."""
        checks = [
            ("lr", self.lr > 0, "must be > 0"),
            ("batch_size", self.batch_size >= 2, "must be ≥ 2 (batch norm)"),
            ("epochs", self.epochs >= 1, "must be ≥ 1"),
            ("epsilon", 0.0 <= self.epsilon <= 1.0, "must be in [0, 1]"),
            ("weight_decay", self.weight_decay >= 0, "must be ≥ 0"),
            ("patience", self.patience >= 1, "must be ≥ 1"),
            ("min_delta", self.min_delta >= 0, "must be ≥ 0"),
            ("flip_prob", 0.0 <= self.flip_prob <= 1.0, "must be in [0, 1]"),
            ("consistency_weight", math.isfinite(self.consistency_weight) and self.consistency_weight >= 0,
             "must be a finite number ≥ 0"),
            ("exposure_shift_probability", 0.0 <= self.exposure_shift_probability <= 1.0, "must be in [0, 1]"),
            ("exposure_shift_ev", all(math.isfinite(v) for v in self.exposure_shift_ev)
             and 0.0 <= self.exposure_shift_ev[0] <= self.exposure_shift_ev[1] <= MAX_SHIFT_EV,
             f"must be [low, high] EV with 0 ≤ low ≤ high ≤ {MAX_SHIFT_EV:.2f} (the settings range; shifts only "
             "brighten, expoctl.net.exposure_shift)"),
            ("clipped_frame_weight", math.isfinite(self.clipped_frame_weight) and self.clipped_frame_weight >= 0,
             "must be a finite number ≥ 0"),
            ("clipped_frame_samples", self.clipped_frame_samples >= 1, "must be ≥ 1"),
            ("clipped_frame_margin_ev", all(math.isfinite(v) and 0.0 <= v <= 2.0 for v in self.clipped_frame_margin_ev),
             "must be [white, black] EV per frame, each in [0, 2]"),
            ("num_threads", self.num_threads >= 1, "must be ≥ 1"),
            ("eval_batch_size", self.eval_batch_size >= 1, "must be ≥ 1"),
            ("device", self.device in DEVICES, f"must be one of {', '.join(DEVICES)}"),  # a config built in code
            ("onnx_exporter", self.onnx_exporter in ("torchscript", "dynamo"), "must be torchscript or dynamo"),
            ("mlflow_model_format", self.mlflow_model_format in ("pt2", "pickle"), "must be pt2 or pickle"),
            ("train_subset", self.train_subset in ("fixed", "per_epoch"), "must be fixed or per_epoch"),
            ("max_train_samples", self.max_train_samples is None or self.max_train_samples >= 2, "must be ≥ 2 or null"),
            ("max_validation_samples", self.max_validation_samples is None or self.max_validation_samples >= 1,
             "must be ≥ 1 or null"),
        ]
        return [(key, f"{problem}, got {getattr(self, key)}") for key, ok, problem in checks if not ok]



def resolve_device(setting: str, local_rank: int | None = None, key: str = "train.device") -> torch.device:
    """`train.device` → the torch device: auto = cuda if torch.cuda.is_available() else cpu. CUDA picks device
    `local_rank` (one GPU per torchrun process; the stage passes LOCAL_RANK), else the current CUDA device. Asking for
    cuda where there is none is a ConfigError naming `key` (the stage checks before loading any data)."""
    if setting not in DEVICES:
        raise ConfigError(key, f"must be one of {', '.join(DEVICES)}, got {setting!r}")
    if setting == "cpu" or (setting == "auto" and not torch.cuda.is_available()):
        return torch.device("cpu")
    if not torch.cuda.is_available():
        raise ConfigError(key, "cuda, but torch.cuda.is_available() is False here (no GPU, no driver, or a CPU-only "
                               f"torch {torch.__version__}); use auto or cpu")
    index = torch.cuda.current_device() if local_rank is None else int(local_rank)
    if not 0 <= index < torch.cuda.device_count():
        raise ConfigError(key, f"cuda:{index} (local rank) but this node has {torch.cuda.device_count()} GPU(s)")
    return torch.device("cuda", index)


class OnDevice(nn.Module):
    """`model` seen from anywhere: inputs move to `device`, outputs back to the input's device (gradients flow
    through both moves). For the helpers that build CPU inputs; on the CPU both moves are no-ops."""

    def __init__(self, model: nn.Module, device: torch.device):
        super().__init__()
        self.model = model
        self.device = torch.device(device)

    # train/eval mode is the wrapped model's: helpers that save and restore `.training` see the model's own state
    @property
    def training(self) -> bool:  # type: ignore[override]
        return self.__dict__["_modules"]["model"].training if "model" in self.__dict__.get("_modules", {}) else True

    @training.setter
    def training(self, mode: bool) -> None:  # nn.Module.train sets it, then recurses into the wrapped model
        pass

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x.to(self.device)).to(x.device)


def weighted_l1(pred: torch.Tensor, target: torch.Tensor, epsilon: float) -> torch.Tensor:
    """ε·mean|Ĝ − G*| + (1 − ε)·mean|Ê − E*| (columns: gain, exposure)."""
    err = (pred - target).abs()
    return epsilon * err[:, 0].mean() + (1.0 - epsilon) * err[:, 1].mean()


def complement_partners(time_step: np.ndarray, cameras: np.ndarray) -> np.ndarray:
    """For each sample, the row of its *complement*: the same time step with every input frame from the other camera
    (c112 ↔ c221, c111 ↔ c222, …); a sample whose complement is not in the set is its own partner."""
    time_step = np.asarray(time_step, np.int64)
    cameras = np.asarray(cameras, np.int64)
    code = (cameras - 1) @ np.array([4, 2, 1])  # 0 … 7: which camera each of frames t, t−1, t−2 came from
    key = time_step * 8 + code
    lookup = np.full(int(key.max()) + 8 if len(key) else 0, -1, np.int64)
    lookup[key] = np.arange(len(key))
    partner = lookup[time_step * 8 + (7 - code)]
    return np.where(partner >= 0, partner, np.arange(len(key)))


def error_sums(pred_norm: np.ndarray, target_norm: np.ndarray, epsilon: float,
               exposure_scale: str = "linear") -> np.ndarray:
    """Sums over samples of [|Δg_norm|, |Δe_norm|, |Δg| dB, |Δ log2 e| EV] (prediction clamped, as deployed) + count;
    the normalised exposures are in `exposure_scale`."""
    pred_norm = np.asarray(pred_norm, np.float64)
    target_norm = np.asarray(target_norm, np.float64)
    d = np.abs(pred_norm - target_norm)
    gain_err_db = np.abs(norm_to_gain(pred_norm[:, 0]) - norm_to_gain(target_norm[:, 0]))
    ev_err = np.abs(np.log2(norm_to_exposure(pred_norm[:, 1], exposure_scale)
                            / norm_to_exposure(target_norm[:, 1], exposure_scale)))
    return np.array([d[:, 0].sum(), d[:, 1].sum(), gain_err_db.sum(), ev_err.sum(), len(d)], np.float64)


def metrics_from_sums(s: np.ndarray, epsilon: float) -> dict:
    n = max(s[4], 1.0)
    return {
        "loss": float((epsilon * s[0] + (1 - epsilon) * s[1]) / n),
        "gain_mae_norm": float(s[0] / n),
        "exposure_mae_norm": float(s[1] / n),
        "gain_mae_db": float(s[2] / n),
        "exposure_mae_ev": float(s[3] / n),
    }


def _dist_info() -> tuple[int, int]:
    if dist.is_available() and dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


@torch.no_grad()
def _average_bn_buffers(model: nn.Module, world: int) -> None:
    """Average batch-norm running statistics over processes, so every replica evaluates with the same model
    (DDP only broadcasts buffers at the start of each forward; the last batch leaves them rank-specific)."""
    for name, buf in model.named_buffers():
        if buf.dtype.is_floating_point and ("running_mean" in name or "running_var" in name):
            dist.all_reduce(buf)
            buf /= world


def evaluate(model: nn.Module, data: SampleSet, epsilon: float, batch_size: int = 256,
             rows: np.ndarray | None = None, device: torch.device | str = "cpu") -> dict:
    """Validation metrics; under DDP each rank evaluates an interleaved share and the sums are all-reduced (on
    `device`: nccl reduces CUDA tensors only). `model` takes CPU inputs (wrap a model on another device in
    `OnDevice`)."""
    rank, world = _dist_info()
    rows = np.arange(len(data)) if rows is None else rows
    mine = rows[rank::world]
    pred = predict(model, data, batch_size, mine)
    sums = error_sums(pred, data.targets[torch.as_tensor(mine, dtype=torch.long)].numpy(), epsilon, data.exposure_scale)
    if world > 1:
        t = torch.from_numpy(sums).to(device)
        dist.all_reduce(t)
        sums = t.cpu().numpy()
    return metrics_from_sums(sums, epsilon)


def constant_baseline(train: SampleSet) -> np.ndarray:
    """Per-output median of the training targets: the constant predictor minimising the L1 loss."""
    return np.median(train.targets.numpy(), axis=0).astype(np.float32)


def hold_prediction(data: SampleSet, rows: np.ndarray) -> np.ndarray:
    """The hold predictor: each sample's frame-t settings, normalised like the targets."""
    idx = torch.as_tensor(rows, dtype=torch.long)
    return np.stack([data.gain_norm[idx, 0].numpy(), data.exposure_norm[idx, 0].numpy()], axis=1)


@dataclass
class TrainResult:
    model: ExposureNet  # best-validation weights, eval mode, unwrapped, on the CPU (whatever the training device)
    best_epoch: int
    epochs_run: int
    history: list[dict]
    metrics: dict  # final: validation (model + baseline), improvement, sizes, speed


def _subset(n: int, limit: int | None, rng: np.random.Generator) -> np.ndarray:
    if limit is None or limit >= n:
        return np.arange(n)
    return np.sort(rng.choice(n, size=limit, replace=False))


def fit(model_cfg: ModelConfig, cfg: TrainConfig, train: SampleSet, validation: SampleSet, seed: int,
        on_epoch: Callable[[int, dict], None] | None = None, log: Callable[[str], None] | None = None,
        response: Response | None = None, device: torch.device | str | None = None) -> TrainResult:
    """Train on `train`, early-stop on `validation` loss, return the best model and metrics (see module doc).
    `response`: the camera response the images were encoded with, needed for `exposure_shift_probability` > 0.
    `device`: where to train; None resolves `cfg.device` (`resolve_device`, the current CUDA device)."""
    device = resolve_device(cfg.device) if device is None else torch.device(device)
    shifter = None
    if cfg.exposure_shift_probability > 0:
        if response is None:
            raise ConfigError("train.exposure_shift_probability",
                              "synthetic over-exposure needs the camera response (the sensor block)")
        shifter = ExposureShift(response, train.exposure_scale)
    if tuple(train.input_hw) != tuple(model_cfg.input_size):
        raise ConfigError("model.input_size", f"{model_cfg.input_size} but the data were prepared at {train.input_hw}")
    for data in (train, validation):
        if data.exposure_scale != model_cfg.exposure_scale:
            raise ConfigError("model.exposure_scale",
                              f"{model_cfg.exposure_scale!r} but the data were scaled {data.exposure_scale!r}")
    rank, world = _dist_info()
    torch.set_num_threads(cfg.num_threads)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    train_rows = _subset(len(train), cfg.max_train_samples, rng)
    val_rows = _subset(len(validation), cfg.max_validation_samples, rng)
    if len(train_rows) < 2 * world:
        raise ConfigError("train", f"only {len(train_rows)} training samples for {world} process(es)")
    if cfg.batch_size < 2 * world:
        raise ConfigError("train.batch_size", f"{cfg.batch_size} is too small for {world} processes (≥ 2 each)")

    model = ExposureNet(model_cfg).to(device)  # initialised on the CPU (same weights on any device), then moved
    on_device = OnDevice(model, device)  # for the helpers that build CPU inputs
    net: nn.Module = model
    if world > 1:
        net = nn.parallel.DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None)
    torch.manual_seed(seed * 1000 + rank)  # dropout masks differ per process, reproducibly
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)

    # the clipped-frame prior's own random stream: the paper's configuration keeps its batches
    prior_gen = torch.Generator().manual_seed(seed * 7919 + 104729 + rank) if cfg.clipped_frame_weight > 0 else None
    best = (math.inf, -1, None)
    seen = np.zeros(len(train), bool)  # which training samples any epoch drew
    partners = complement_partners(train.time_step, train.cameras) if cfg.consistency_weight > 0 else None
    history: list[dict] = []
    n_bad = 0
    total_train_time = 0.0
    samples_seen = 0
    for epoch in range(cfg.epochs):
        if cfg.train_subset == "per_epoch" and epoch > 0:  # identical on every rank: seeded by (seed, epoch) only
            train_rows = _subset(len(train), cfg.max_train_samples, np.random.default_rng([seed, epoch]))
        gen = torch.Generator().manual_seed(seed * 7919 + epoch)  # identical on every rank
        perm = train_rows[torch.randperm(len(train_rows), generator=gen).numpy()]
        if partners is None:  # (with consistency pairs, the batches mark what they draw)
            seen[train_rows] = True
        flips = torch.rand(len(perm), generator=gen) < cfg.flip_prob
        # drawn only when on, so the paper's configuration keeps its random stream
        shifts = (draw_shifts(len(perm), cfg.exposure_shift_probability, cfg.exposure_shift_ev, gen)
                  if shifter is not None else torch.zeros(len(perm)))
        net.train()
        t0 = time.perf_counter()
        loss_sum, n_sum = 0.0, 0
        for start in range(0, len(perm), cfg.batch_size):
            glob = slice(start, start + cfg.batch_size)
            if len(perm[glob]) < 2 * world:
                break  # batch norm needs ≥ 2 samples per process; drop a tiny remainder
            rows, flip, shift = perm[glob][rank::world], flips[glob][rank::world], shifts[glob][rank::world]
            if partners is None:
                x, y = train.batch(rows, flip, shift, shifter)
                x, y = x.to(device), y.to(device)
                loss = weighted_l1(net(x), y, cfg.epsilon)
            else:  # first half: drawn samples; second half: their partners, same flips (module doc)
                half = len(rows) // 2
                anchors, flip, shift = rows[:half], flip[:half], shift[:half]
                rows = np.concatenate([anchors, partners[anchors]])
                seen[rows] = True
                x, y = train.batch(rows, torch.cat([flip, flip]), torch.cat([shift, shift]), shifter)
                x, y = x.to(device), y.to(device)
                pred = net(x)
                loss = (weighted_l1(pred, y, cfg.epsilon)
                        + cfg.consistency_weight * weighted_l1(pred[:half], pred[half:], cfg.epsilon))
            if prior_gen is not None:
                loss = loss + cfg.clipped_frame_weight * clipped_frame_loss(
                    on_device, cfg.clipped_frame_samples, cfg.clipped_frame_margin_ev, tuple(train.input_hw),
                    train.exposure_scale, prior_gen).to(device)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            loss_sum += loss.item() * len(rows)
            n_sum += len(rows)
        if world > 1:
            _average_bn_buffers(model, world)
        dt = time.perf_counter() - t0
        total_train_time += dt
        samples_seen += n_sum
        train_loss = loss_sum / max(n_sum, 1)
        if world > 1:
            t = torch.tensor([loss_sum, float(n_sum)], dtype=torch.float64, device=device)
            dist.all_reduce(t)
            train_loss = float(t[0] / max(t[1], 1))
        val = evaluate(on_device, validation, cfg.epsilon, cfg.eval_batch_size, val_rows, device)
        rec = {"train_loss": train_loss, **{f"val_{k}": v for k, v in val.items()},
               "epoch_seconds": dt, "train_samples_per_s": n_sum * world / dt if dt > 0 else float("nan")}
        history.append(rec)
        improved = val["loss"] < best[0] - cfg.min_delta
        if improved:
            best = (val["loss"], epoch, copy.deepcopy(model.state_dict()))
            n_bad = 0
        else:
            n_bad += 1
        if rank == 0:
            if on_epoch is not None:
                on_epoch(epoch, rec)
            if log is not None:
                log(f"epoch {epoch:3d}  train {train_loss:.4f}  val {val['loss']:.4f}  "
                    f"gain {val['gain_mae_db']:.2f} dB  exposure {val['exposure_mae_ev']:.3f} EV"
                    f"{'  *' if improved else ''}")
        if n_bad >= cfg.patience:
            break

    model.load_state_dict(best[2])
    model.eval()
    val = evaluate(on_device, validation, cfg.epsilon, cfg.eval_batch_size, val_rows, device)
    const = constant_baseline(train)
    base_pred = np.broadcast_to(const, (len(val_rows), 2))
    val_targets = validation.targets.numpy()[val_rows]
    base = metrics_from_sums(error_sums(base_pred, val_targets, cfg.epsilon, validation.exposure_scale), cfg.epsilon)
    hold = metrics_from_sums(error_sums(hold_prediction(validation, val_rows), val_targets, cfg.epsilon,
                                        validation.exposure_scale), cfg.epsilon)
    follow = camera_follow(on_device, validation, cfg.eval_batch_size)  # the whole split: every c111/c222 pair
    white = uniform_frame_steps(on_device, 255, tuple(validation.input_hw), validation.exposure_scale)
    black = uniform_frame_steps(on_device, 0, tuple(validation.input_hw), validation.exposure_scale)
    model.to("cpu")  # checkpoints and ONNX exports from CPU tensors, whatever the training device
    metrics = {
        **{f"val_{k}": v for k, v in val.items()},
        "val_follow": follow["follow"], "val_follow_bias_ev": follow["bias_ev"],
        "val_implied_offset_ev": follow["implied_offset_ev"],
        # the step on an all-white (all-black) input over a settings grid: ≥ 0 (≤ 0) somewhere = an absorbing state
        "white_step_max_ev": float(white.max()), "black_step_min_ev": float(black.min()),
        **{f"baseline_val_{k}": v for k, v in base.items()},
        **{f"hold_val_{k}": v for k, v in hold.items()},
        "baseline_gain_norm": float(const[0]), "baseline_exposure_norm": float(const[1]),
        "improvement_gain_db": base["gain_mae_db"] - val["gain_mae_db"],
        "improvement_exposure_ev": base["exposure_mae_ev"] - val["exposure_mae_ev"],
        "val_loss_ratio_to_baseline": val["loss"] / base["loss"] if base["loss"] > 0 else float("nan"),
        "beats_baseline": bool(val["loss"] < base["loss"]),
        "best_epoch": best[1], "epochs_run": len(history),
        "n_train_samples": int(len(train_rows)), "n_distinct_train_samples": int(seen.sum()),
        "n_validation_samples": int(len(val_rows)),
        "n_processes": world, "n_parameters": count_parameters(model), "macs_per_sample": count_macs(model_cfg),
        "train_samples_per_s": samples_seen * world / total_train_time if total_train_time > 0 else float("nan"),
    }
    return TrainResult(model=model, best_epoch=best[1], epochs_run=len(history), history=history, metrics=metrics)
