"""The paper's CNN (Tomasi et al. 2021, authors' CNN_EG_SMALL layer sizes) with configurable input size and widths.

Layout (defaults = the authors' sizes at 224×224):
  4 conv blocks: conv k×k (valid) → [max-pool p, stride p] → BN → ReLU → dropout
      kernels 5, 3, 3, K4; widths 30, 60, 120, 240; pools 3, 3, 3, none
  3 FC blocks:   FC → BN → ReLU → dropout, widths 128, 64, 32
  output:        FC 32 → 2 (normalised gain, normalised exposure), no activation.

`output: residual` (a deviation from the paper, which found absolute regression better than regressing a change):
the two outputs are added to frame t's normalised settings, read from its constant planes. Targets and loss stay
absolute; only the parameterisation changes, so an untrained network is the hold predictor. On our CPU budget (about
1/1000 of the paper's sample-epochs) the absolute network did not get past a constant predictor (docs/network.md).

The authors flatten a 1×1 map after a fixed 7×7 fourth conv, which only works near 224×224. Here the fourth kernel
K4 is computed from the input size as the whole remaining map (7×7 at 224, 3×3 at 128, …), so the fourth conv always
sees the full field and yields 1×1 at any size: the same architecture as the authors' at 224, sound at every other
size. `min_input_size` is the smallest input that leaves a ≥ 1×1 map.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import torch
from torch import nn

from expoctl.camera.ranges import EXPOSURE_SCALES
from expoctl.config_reader import Section, is_integer, param, read_config
from expoctl.errors import ConfigError
from expoctl.net.preprocess import N_INPUT_CHANNELS, as_hw


OUTPUTS = ("absolute", "residual")
# channels of frame t's gain and exposure planes
# (expoctl.net.preprocess channel order: [R, G, B, gain, exposure] × t, …)
_T_SETTING_CHANNELS = slice(3, 5)


def _read_size(r: Section, name: str, default: tuple[int, int]) -> tuple[int, int]:
    """`input_size`: (height, width) of the network input, given as one number (square) or [height, width]."""
    v = r.value(name, default)
    ok = (is_integer(v) and v >= 1) or (isinstance(v, (list, tuple)) and len(v) == 2
                                          and all(is_integer(x) and x >= 1 for x in v))
    if not ok:
        r.problem(name, f"must be a size in pixels or [height, width], got {v!r}")
        return default
    return as_hw(v)


@dataclass(frozen=True)
class ModelConfig:
    input_size: tuple[int, int] = param((224, 224), read=_read_size)  # (height, width)
    conv_widths: tuple[int, ...] = (30, 60, 120, 240)
    conv_kernels: tuple[int, ...] = (5, 3, 3)  # the last conv's kernel is computed (covers the remaining map)
    pool: int = 3  # max-pool size = stride after each of the first len(conv_kernels) convs
    fc_widths: tuple[int, ...] = (128, 64, 32)
    dropout: float = 0.4
    # how the exposure planes and the exposure output are scaled to [0, 1] (expoctl.camera.ranges): "linear" is the
    # paper's; "log" (EV) is what the configs use — part of the network's interface, so it lives with the architecture
    exposure_scale: str = "linear"
    # "absolute": the head's two values are the normalised settings (paper). "residual": they are added to frame t's
    # own normalised settings (its gain/exposure planes), so an untrained net holds the current settings and training
    # learns the correction — the loss still compares absolute settings with absolute targets (module doc).
    output: str = "absolute"

    @classmethod
    def from_dict(cls, d: dict | None, key: str = "model", problems=None) -> "ModelConfig":
        """Every problem at once (ConfigError), each under its own key (`config_reader.read_config`)."""
        return read_config(cls, d, key, problems)

    def check(self, r: Section) -> None:
        """The architecture's rules (read_config runs it on what was read)."""
        for key, problem in self.problems():
            r.problem(key, problem)

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    def validate(self, prefix: str = "model") -> None:
        """Every problem at once (ConfigError) of a config built in code."""
        problems = self.problems()
        if problems:
            raise ConfigError.of([(f"{prefix}.{k}", p) for k, p in problems])

    def problems(self) -> list[tuple[str, str]]:
        """(key, problem) for each rule the architecture breaks."""
        problems = []
        if len(self.conv_widths) != len(self.conv_kernels) + 1:
            problems.append(("conv_widths", "needs one more entry than conv_kernels (the last conv's kernel is computed)"))
        if any(w < 1 for w in self.conv_widths + self.fc_widths):
            problems.append(("conv_widths", "widths must be ≥ 1"))
        if any(k < 1 for k in self.conv_kernels) or self.pool < 1:
            problems.append(("conv_kernels", "kernels and pool must be ≥ 1"))
        if self.exposure_scale not in EXPOSURE_SCALES:
            problems.append(("exposure_scale", f"must be one of {list(EXPOSURE_SCALES)}, got {self.exposure_scale!r}"))
        if self.output not in OUTPUTS:
            problems.append(("output", f"must be one of {list(OUTPUTS)}, got {self.output!r}"))
        if not 0.0 <= self.dropout < 1.0:
            problems.append(("dropout", f"must be in [0, 1), got {self.dropout}"))
        sane = all(k >= 1 for k in self.conv_kernels) and self.pool >= 1  # the map size needs them
        for axis, n in zip(("height", "width"), self.input_size):
            if sane and final_map_size(n, self.conv_kernels, self.pool) < 1:
                problems.append(("input_size", f"{axis} {n} too small for kernels {list(self.conv_kernels)} with "
                                 f"pool {self.pool} (minimum {min_input_size(self.conv_kernels, self.pool)})"))
        return problems


def final_map_size(n: int, kernels, pool: int) -> int:
    """Spatial size after the valid convs + pools (= the computed last kernel)."""
    for k in kernels:
        n = (n - k + 1) // pool
        if n < 1:
            return 0
    return n


def min_input_size(kernels, pool: int) -> int:
    n = 1
    while final_map_size(n, kernels, pool) < 1:
        n += 1
    return n


class ExposureNet(nn.Module):
    """15×H×W → 2 (normalised gain, normalised exposure); see module doc."""

    def __init__(self, cfg: ModelConfig = ModelConfig()):
        super().__init__()
        cfg.validate()
        self.cfg = cfg
        last_k = tuple(final_map_size(n, cfg.conv_kernels, cfg.pool) for n in cfg.input_size)
        layers: list[nn.Module] = []
        c_in = N_INPUT_CHANNELS
        kernels = [(k, k) for k in cfg.conv_kernels] + [last_k]
        for i, (c_out, k) in enumerate(zip(cfg.conv_widths, kernels)):
            layers.append(nn.Conv2d(c_in, c_out, kernel_size=k))
            if i < len(cfg.conv_kernels):
                layers.append(nn.MaxPool2d(cfg.pool, stride=cfg.pool))
            layers += [nn.BatchNorm2d(c_out), nn.ReLU(inplace=True), nn.Dropout(cfg.dropout)]
            c_in = c_out
        self.features = nn.Sequential(*layers)
        head: list[nn.Module] = [nn.Flatten()]
        for c_out in cfg.fc_widths:
            head += [nn.Linear(c_in, c_out), nn.BatchNorm1d(c_out), nn.ReLU(inplace=True), nn.Dropout(cfg.dropout)]
            c_in = c_out
        out = nn.Linear(c_in, 2)
        if cfg.output == "residual":
            # zero-initialised so the untrained network is exactly the hold predictor; gradients still reach it
            nn.init.zeros_(out.weight)
            nn.init.zeros_(out.bias)
        head.append(out)
        self.head = nn.Sequential(*head)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.head(self.features(x))
        if self.cfg.output == "residual":
            y = y + x[:, _T_SETTING_CHANNELS, 0, 0]  # planes are constant: any pixel is the frame-t setting
        return y


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def count_macs(cfg: ModelConfig) -> int:
    """Multiply-adds per sample of the convs and FC layers (BN/ReLU/pool excluded, as in the paper's 0.66 G)."""
    h, w = cfg.input_size
    c_in = N_INPUT_CHANNELS
    macs = 0
    kernels = [(k, k) for k in cfg.conv_kernels]
    kernels.append((final_map_size(h, cfg.conv_kernels, cfg.pool), final_map_size(w, cfg.conv_kernels, cfg.pool)))
    for i, (c_out, (kh, kw)) in enumerate(zip(cfg.conv_widths, kernels)):
        h, w = h - kh + 1, w - kw + 1
        macs += h * w * c_out * c_in * kh * kw
        if i < len(cfg.conv_kernels):
            h, w = h // cfg.pool, w // cfg.pool
        c_in = c_out
    for c_out in list(cfg.fc_widths) + [2]:
        macs += c_in * c_out
        c_in = c_out
    return macs


def scale_widths(cfg: ModelConfig, multiplier: float) -> ModelConfig:
    """All conv and FC widths × multiplier (rounded, ≥ 1): the sweep's single 'width' knob."""
    conv = tuple(max(1, round(c * multiplier)) for c in cfg.conv_widths)
    fc = tuple(max(1, round(c * multiplier)) for c in cfg.fc_widths)
    d = asdict(cfg)
    d.update(conv_widths=conv, fc_widths=fc)
    return ModelConfig(**d)
