"""Figures of the evaluation report, drawn from reports/eval/ (matplotlib, Agg; every writer is atomic).

- `tunnel_timeline`: the paper's Fig. 7 — ORB and libviso2-style NFM and the per-frame gain and exposure through a
  tunnel entry and exit, every controller on the same window; one column per route split.
- `image_strips`: the paper's Fig. 6 — frames around a tunnel exit, one row per controller, NFM under each.
- `controller_timeline`: one controller over all windows of a split (MLflow child-run figure).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from expoctl.io import atomic_path

def controller_style(controller: str) -> tuple[str | None, str]:
    """(colour, label) of a controller as its registration gives them (`expoctl.controllers.registry`); a name no
    longer registered (an old metrics file): no colour (matplotlib's cycle picks one) and its name."""
    from expoctl.controllers.registry import CONTROLLERS

    if controller in CONTROLLERS:
        entry = CONTROLLERS.get(controller)
        return entry.colour, entry.label
    return None, controller


def ordered(names) -> list[str]:
    """Controller names in table order (the registry's ranks: agae, shin, shim, mean_intensity, fixed, learned,
    oracle, then plugins), names no longer registered last."""
    from expoctl.evaluation.aggregate import controller_order

    return sorted(names, key=controller_order)


def label(controller: str) -> str:
    return controller_style(controller)[1]


def frontends_of(frames: pd.DataFrame) -> list[str]:
    """The raw front ends a per-frame table holds (its nfm_<front end> columns), in registry order."""
    from expoctl.evaluation.run import frame_variants

    return [v for v in frame_variants(frames) if not v.endswith("_sumlog")]


def frontend_label(name: str, long: bool = False) -> str:
    """A front end's label (`orb` → ORB, `viso` → libviso2; long: libviso2-style), SumLog variants with ' (SL)'."""
    from expoctl.features.registry import FRONTENDS

    base = name[: -len("_sumlog")] if name.endswith("_sumlog") else name
    text = base
    if base in FRONTENDS:
        entry = FRONTENDS.get(base)
        text = entry.info.get("long_label", entry.label) if long else entry.label
    return text + (" (SL)" if name.endswith("_sumlog") else "")


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | os.PathLike) -> None:
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")


def _shade_dynamic(ax, w: pd.DataFrame, x: str) -> None:
    dyn = w["section"].to_numpy() == "dynamic"
    xs = w[x].to_numpy(dtype=float)
    start = None
    for i, d in enumerate(list(dyn) + [False]):
        if d and start is None:
            start = i
        elif not d and start is not None:
            ax.axvspan(xs[start], xs[i - 1], color="0.92", zorder=0)
            start = None


def pick_window(frames: pd.DataFrame, split: str, prefer: str = "passage") -> str | None:
    """The sequence (window) of `split` shown in the timeline: the first whose label contains `prefer`, else the
    first; None when the split has no frames."""
    f = frames[frames["route_split"] == split]
    if f.empty:
        return None
    seqs = f.drop_duplicates("sequence")[["sequence", "window_label"]].sort_values("sequence")
    hit = seqs[seqs["window_label"].str.contains(prefer)]
    return str((hit if len(hit) else seqs)["sequence"].iloc[0])


def tunnel_timeline(frames: pd.DataFrame, path: str | os.PathLike, splits=("validation", "test")) -> bool:
    """Fig. 7: rows ORB NFM, libviso2 NFM, gain, exposure over time (s from the window's first portal crossing);
    one column per split; all controllers. Returns False (nothing written) if no split has frames."""
    plt = _plt()
    chosen = [(s, pick_window(frames, s)) for s in splits]
    chosen = [(s, q) for s, q in chosen if q is not None]
    if not chosen:
        return False
    fes = frontends_of(frames)
    n = len(fes)  # one row per front end's NFM, then gain and exposure
    fig, axes = plt.subplots(n + 2, len(chosen), figsize=(6.2 * len(chosen), 9.5 * (n + 2) / 4), sharex="col",
                             squeeze=False)
    for col, (split, seq) in enumerate(chosen):
        w_all = frames[frames["sequence"] == seq]
        for ctrl in ordered(set(w_all["controller"])):
            w = w_all[w_all["controller"] == ctrl].sort_values("frame")
            colour, name = controller_style(ctrl)
            x = w["frame"].to_numpy()
            kw = dict(color=colour, label=name, lw=1.3 if ctrl in ("learned", "agae", "oracle") else 0.9)
            for row, fe in enumerate(fes):
                axes[row, col].plot(x, w[f"nfm_{fe}"], **kw)
            axes[n, col].plot(x, w["gain_db"], **kw)
            axes[n + 1, col].plot(x, w["exposure_us"] / 1000.0, **kw)
        ref = w_all[w_all["controller"] == w_all["controller"].iloc[0]].sort_values("frame")
        for ax in axes[:, col]:
            _shade_dynamic(ax, ref, "frame")
            ax.grid(alpha=0.3)
        label_ = str(w_all["window_label"].iloc[0])
        axes[0, col].set_title(f"{split}: {w_all['city'].iloc[0]} city, {label_}\n({seq}; grey = dynamic section)",
                               fontsize=9)
        for row, fe in enumerate(fes):
            axes[row, col].set_ylabel(f"{frontend_label(fe, long=True)} inlier matches")
        axes[n, col].set_ylabel("gain (dB)")
        axes[n + 1, col].set_ylabel("exposure (ms)")
        axes[n + 1, col].set_yscale("log")
        axes[n + 1, col].set_xlabel("frame")
    axes[0, 0].legend(fontsize=7, ncol=2, loc="lower left")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


def image_strips(frames: pd.DataFrame, thumbs_dir: str | os.PathLike, path: str | os.PathLike, split: str = "test",
                 portal: str = "exit", n_columns: int = 6, controllers=None) -> bool:
    """Fig. 6: thumbnails around a tunnel `portal` of one window of `split`, one row per controller, each captioned
    with its ORB NFM. Returns False when no thumbnails exist for that split."""
    plt = _plt()
    thumbs_dir = Path(thumbs_dir)
    seq = pick_window(frames, split, "exit" if portal == "exit" else "entry") or pick_window(frames, split)
    if seq is None:
        return False
    w_all = frames[frames["sequence"] == seq]
    ctrls = [c for c in (controllers or ordered(set(w_all["controller"]))) if c in set(w_all["controller"])]
    loaded = {}
    for c in ctrls:
        run_id = str(w_all[w_all["controller"] == c]["run_id"].iloc[0])
        p = thumbs_dir / f"{run_id}.npz"
        if p.is_file():
            with np.load(p) as z:
                if len(z["frame"]):
                    loaded[c] = (z["frame"].copy(), z["image"].copy())
    if not loaded:
        return False
    common = sorted(set.intersection(*(set(f.tolist()) for f, _ in loaded.values())))
    ref = w_all[w_all["controller"] == ctrls[0]].set_index("frame")
    near = [k for k in common if ref.loc[k, "portal_kind"] == portal] or common
    cols = [near[i] for i in np.unique(np.linspace(0, len(near) - 1, min(n_columns, len(near))).round().astype(int))]
    rows = [c for c in ctrls if c in loaded]
    caption_fe = frontends_of(frames)[0]  # each thumbnail's caption: the first front end's NFM
    fig, axes = plt.subplots(len(rows), len(cols), figsize=(1.9 * len(cols), 1.75 * len(rows)), squeeze=False)
    for i, c in enumerate(rows):
        fr, imgs = loaded[c]
        per = w_all[w_all["controller"] == c].set_index("frame")
        for j, k in enumerate(cols):
            ax = axes[i, j]
            ax.imshow(imgs[int(np.where(fr == k)[0][0])])
            ax.set_xticks([])
            ax.set_yticks([])
            nfm = per.loc[k, f"nfm_{caption_fe}"]
            ax.set_xlabel(f"{frontend_label(caption_fe)} NFM {'—' if not np.isfinite(nfm) else int(nfm)}", fontsize=7,
                          labelpad=1)
            if i == 0:
                ax.set_title(f"t {per.loc[k, 'portal_dt_s']:+.1f} s", fontsize=8)
            if j == 0:
                ax.set_ylabel(label(c), fontsize=8)
    fig.suptitle(f"{split}: {w_all['city'].iloc[0]} city, around the tunnel {portal} ({seq}); "
                 f"t = time from the portal crossing", fontsize=9)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


def controller_timeline(frames: pd.DataFrame, split: str, controller: str, path: str | os.PathLike) -> bool:
    """One controller over every window of `split`: ORB/libviso2 NFM, gain, exposure vs frame, one line per window."""
    plt = _plt()
    f = frames[(frames["route_split"] == split) & (frames["controller"] == controller)]
    if f.empty:
        return False
    fes = frontends_of(frames)
    n = len(fes)
    fig, axes = plt.subplots(n + 2, 1, figsize=(7.5, 8 * (n + 2) / 4), sharex=True)
    for seq, w in f.groupby("sequence"):
        w = w.sort_values("frame")
        x = w["frame"].to_numpy()
        for row, fe in enumerate(fes):
            kw = {"label": str(w["window_label"].iloc[0]) + f" ({seq})"} if row == 0 else {}
            axes[row].plot(x, w[f"nfm_{fe}"], lw=1, **kw)
        axes[n].plot(x, w["gain_db"], lw=1)
        axes[n + 1].plot(x, w["exposure_us"] / 1000.0, lw=1)
    labels = [f"{frontend_label(fe, long=True)} NFM" for fe in fes] + ["gain (dB)", "exposure (ms)"]
    for ax, lab in zip(axes, labels):
        ax.set_ylabel(lab)
        ax.grid(alpha=0.3)
    axes[n + 1].set_yscale("log")
    axes[n + 1].set_xlabel("frame")
    axes[0].legend(fontsize=6)
    axes[0].set_title(f"{label(controller)} — {split} ({f['city'].iloc[0]} city)", fontsize=10)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


def nfm_bars(metrics: dict, path: str | os.PathLike, split: str, kind: str = "dynamic") -> bool:
    """Bar chart: mean median/minimum NFM per controller and front end (one split, one section kind)."""
    plt = _plt()
    ctrls = ordered((metrics.get(split) or {}).keys())
    if not ctrls:
        return False
    first = metrics[split][ctrls[0]][kind]
    fes = [fe for fe in first if not fe.endswith("_sumlog")] + [fe for fe in first if fe.endswith("_sumlog")]
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    width = 0.8 / len(ctrls)
    for a, stat in enumerate(("median_nfm", "min_nfm")):
        for i, c in enumerate(ctrls):
            vals = [metrics[split][c][kind][fe][stat] for fe in fes]
            vals = [np.nan if v is None else v for v in vals]
            axes[a].bar(np.arange(len(fes)) + (i - len(ctrls) / 2 + 0.5) * width, vals, width,
                        color=controller_style(c)[0], label=label(c))
        axes[a].set_xticks(np.arange(len(fes)), [frontend_label(fe) for fe in fes])
        axes[a].set_yscale("symlog", linthresh=10)
        axes[a].set_title(f"{split}, {kind} sections: {'median' if stat == 'median_nfm' else 'minimum'} NFM "
                          "(mean over sections)", fontsize=9)
        axes[a].grid(alpha=0.3, axis="y")
    axes[0].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True
