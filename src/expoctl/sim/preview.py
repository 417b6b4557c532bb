"""`expoctl preview`: drive one simulated camera over a route with a controller and save a contact sheet for a look.

The sheet has one row per tunnel transition (frames spread over the `dynamic` section around a portal crossing, so
an entry and an exit each read left to right) — or evenly spaced frames with `--select uniform` — each thumbnail stamped with frame,
gain, exposure and section; below it a timeline of the whole run: exposure value (EV of t·gain) commanded by the
controller, mean image level, and the dynamic sections shaded. A lagging AE shows as mean level pinned at 255 (or
near 0) for several frames after a portal while EV catches up. `--video` also writes every frame as an MP4.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from expoctl.camera.ranges import exposure_value_ev
from expoctl.controllers.base import Settings
from expoctl.errors import InputError


@dataclass
class PreviewFrame:
    frame_index: int
    settings: Settings
    image: np.ndarray
    section: str


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--city", required=True,
                        help="city name (train, validation, test) or a YAML city config file (may say `base: <name>`)")
    parser.add_argument("--traversal", type=int, default=0, help="traversal index of the city's route (default 0)")
    parser.add_argument("--frames", type=int, default=None, help="number of frames (default: the whole route)")
    parser.add_argument("--start", type=int, default=0, help="first frame shown; earlier frames warm the controller up")
    parser.add_argument("--controller", default="agae", help="controller name (expoctl.controllers.registry)")
    parser.add_argument("--config", type=Path, default=None,
                        help="resolved config (configs/resolved.yaml): sensor, rig, world (render, city_dir) and "
                             "controllers.<name> come from it")
    parser.add_argument("--width", type=int, default=None, help="render width in pixels (default: world.render, else 320)")
    parser.add_argument("--height", type=int, default=None, help="render height in pixels (default: world.render, else 240)")
    parser.add_argument("--seed", type=int, default=0, help="seed for trajectory and sensor noise")
    parser.add_argument("--initial-gain-db", type=float, default=0.0)
    parser.add_argument("--initial-exposure-us", type=float, default=5000.0)
    parser.add_argument("--select", choices=("transitions", "uniform"), default="transitions",
                        help="thumbnails: one row per tunnel transition (default) or evenly spaced")
    parser.add_argument("--columns", type=int, default=8, help="thumbnails per row (default 8)")
    parser.add_argument("--rows", type=int, default=4, help="at most this many rows (default 4)")
    parser.add_argument("--thumb-width", type=int, default=200, help="thumbnail width in pixels (default 200)")
    parser.add_argument("--out", type=Path, default=Path("preview.png"), help="contact-sheet PNG (default preview.png)")
    parser.add_argument("--video", type=Path, default=None, help="also write every frame to this MP4")


def run(args: argparse.Namespace) -> int:
    import yaml

    from expoctl.camera.sensor import SensorConfig
    from expoctl.controllers.registry import make_controller
    from expoctl.config_reader import Problems
    from expoctl.sim.closed_loop import RigConfig, RouteScene, make_sensors, run_closed_loop
    from expoctl.world import WorldConfig, load_city

    cfg: dict[str, Any] = {}
    if args.config is not None:
        if not args.config.is_file():
            raise InputError(f"{args.config}: config file not found")
        cfg = yaml.safe_load(args.config.read_text()) or {}
        if not isinstance(cfg, dict):
            raise InputError(f"{args.config}: not a YAML mapping")
    problems = Problems()  # every config problem at once
    rig = RigConfig.from_dict(cfg.get("rig"), "rig", problems)
    world = WorldConfig.from_dict(cfg.get("world"), "world", problems)
    sensor = SensorConfig.from_dict(cfg.get("sensor"), "sensor", problems)
    problems.raise_if_any()
    render = world.render
    if "render" not in (cfg.get("world") or {}):  # no config: a quick look at 320×240
        render = render.with_size(320, 240)
    render = render.with_size(args.width, args.height)
    if render.width < 16 or render.height < 16:
        raise InputError(f"--width/--height must be at least 16 pixels, got {render.width}x{render.height}")
    for name in ("columns", "rows", "thumb_width"):
        if getattr(args, name) < 1:
            raise InputError(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    if args.start < 0:
        raise InputError(f"--start must be >= 0, got {args.start}")

    city = load_city(_city_spec(args.city), world.city_dir)
    n_total = None if args.frames is None else args.start + args.frames
    traj = city.traversal(args.traversal, n_total, rig.fps, args.seed)
    n_total = len(traj.timestamps_ns)
    if args.start >= n_total:
        raise InputError(f"--start {args.start} is past the route's last frame ({n_total - 1})")
    controller = make_controller(args.controller, (cfg.get("controllers") or {}).get(args.controller))
    sensors, _ = make_sensors(sensor, render, 1, 0.0, args.seed)
    kinds = _frame_kinds(traj.sections, n_total)
    loop = run_closed_loop(RouteScene(city, traj, rig, render), sensors, controller,
                           Settings(args.initial_gain_db, args.initial_exposure_us), range(0, n_total), args.seed)
    frames = [PreviewFrame(f.frame_index, f.camera(1).settings, f.camera(1).image, kinds[f.frame_index])
              for f in loop if f.frame_index >= args.start]

    title = (f"{city.name} traversal {args.traversal}, controller {controller.name}, {render.width}x{render.height} "
             f"@ {rig.fps:g} Hz")
    rows = _select(frames, traj.sections, args.select, args.columns, args.rows)
    sheet = contact_sheet(frames, rows,
                          args.columns, args.thumb_width, title)
    _write_png_small(sheet, args.out)
    print(f"wrote {args.out} ({sheet.shape[1]}x{sheet.shape[0]}, {len(frames)} frames rendered)")
    if args.video is not None:
        write_video(frames, args.video, rig.fps)
        print(f"wrote {args.video}")
    return 0


def _city_spec(city: str) -> str | dict:
    """A city name as is; a path to a YAML file → its mapping."""
    import yaml

    if city.endswith((".yaml", ".yml")) or Path(city).is_file():
        path = Path(city)
        if not path.is_file():
            raise InputError(f"{path}: city config file not found")
        spec = yaml.safe_load(path.read_text())
        if not isinstance(spec, dict):
            raise InputError(f"{path}: a city config must be a YAML mapping")
        return spec
    return city


# --- pictures -------------------------------------------------------------------------------------------------------


def annotate(image: np.ndarray, frame: PreviewFrame, scale: float = 1.0) -> np.ndarray:
    """Stamp frame, section, gain and exposure into the top-left corner, on a dark box so it reads on white."""
    import cv2

    out = np.ascontiguousarray(image.copy())
    lines = [f"#{frame.frame_index} {frame.section}",
             f"{frame.settings.gain_db:.1f} dB {frame.settings.exposure_us / 1000.0:.2f} ms"]
    fs = 0.4 * scale
    step = int(round(14 * scale))
    sizes = [cv2.getTextSize(t, cv2.FONT_HERSHEY_SIMPLEX, fs, 1)[0] for t in lines]
    box_w = min(out.shape[1], max(w for w, _ in sizes) + 6)
    box_h = min(out.shape[0], step * len(lines) + int(round(5 * scale)))
    out[:box_h, :box_w] = (out[:box_h, :box_w].astype(np.uint16) * 2 // 5).astype(np.uint8)  # darken to 40 %
    colour = (255, 210, 60) if frame.section == "dynamic" else (255, 255, 255)
    for i, text in enumerate(lines):
        cv2.putText(out, text, (3, step * (i + 1)), cv2.FONT_HERSHEY_SIMPLEX, fs, colour, 1, cv2.LINE_AA)
    return out


def contact_sheet(frames: list[PreviewFrame], rows: list[list[int]], columns: int, thumb_width: int, title: str) -> np.ndarray:
    """Grid of annotated thumbnails (`rows` hold positions in `frames`) above a timeline of the whole run."""
    import cv2

    h0, w0 = frames[0].image.shape[:2]
    th = int(round(h0 * thumb_width / w0))
    grid = np.full((max(1, len(rows)) * (th + 4) + 4, columns * (thumb_width + 4) + 4, 3), 40, np.uint8)
    for r, row in enumerate(rows):
        for c, pos in enumerate(row[:columns]):
            f = frames[pos]
            thumb = cv2.resize(f.image, (thumb_width, th), interpolation=cv2.INTER_AREA)
            y, x = 4 + r * (th + 4), 4 + c * (thumb_width + 4)
            grid[y:y + th, x:x + thumb_width] = annotate(thumb, f, scale=thumb_width / 200.0)
    header = np.full((26, grid.shape[1], 3), 255, np.uint8)
    cv2.putText(header, title, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    marks = sorted({frames[p].frame_index for row in rows for p in row})
    return np.vstack([header, grid, timeline(frames, grid.shape[1], marks)])


def timeline(frames: list[PreviewFrame], width_px: int, marks: list[int] = (), height_px: int = 220) -> np.ndarray:
    """EV commanded, mean image level and saturated share per frame; dynamic sections shaded, thumbnails ticked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    idx = np.array([f.frame_index for f in frames])
    ev = exposure_value_ev([f.settings.gain_db for f in frames], [f.settings.exposure_us for f in frames])
    level = np.array([float(f.image.mean()) for f in frames])
    # share of pixels clipped white in any channel: overexposure after a tunnel exit shows here, not in the mean
    saturated_pct = np.array([100.0 * float(np.mean(f.image.max(axis=2) >= 250)) for f in frames])
    dpi = 100
    fig, ax = plt.subplots(figsize=(width_px / dpi, height_px / dpi), dpi=dpi)
    dyn = np.array([f.section == "dynamic" for f in frames])
    for a, b in _runs(dyn):
        ax.axvspan(idx[a] - 0.5, idx[b] + 0.5, color="0.85", lw=0)
    ax.plot(idx, level, color="tab:orange", lw=1.2, label="mean image level (0–255)")
    ax.plot(idx, saturated_pct, color="tab:red", lw=1.0, label="saturated pixels (%)")
    ax.set_ylim(0, 260)
    ax.set_ylabel("level / %")
    ax.set_xlabel("frame (grey: dynamic sections; ticks: thumbnails)")
    for m in marks:
        ax.axvline(m, ymin=0, ymax=0.04, color="k", lw=0.8)
    ax2 = ax.twinx()
    ax2.plot(idx, ev, color="tab:blue", lw=1.2, label="EV = log2(t·gain) commanded")
    ax2.set_ylabel("EV", color="tab:blue")
    lines = ax.get_lines()[:2] + ax2.get_lines()
    ax.legend(lines, [ln.get_label() for ln in lines], loc="upper right", fontsize=7, framealpha=0.8)
    ax.set_xlim(idx[0] - 0.5, idx[-1] + 0.5)
    fig.tight_layout(pad=0.3)
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    if img.shape[1] != width_px:
        import cv2

        img = cv2.resize(img, (width_px, img.shape[0]), interpolation=cv2.INTER_AREA)
    return img


def _write_png_small(image: np.ndarray, path: Path) -> None:
    """RGB PNG at the strongest zlib level (sensor noise makes sheets compress poorly; they go into docs)."""
    import cv2

    from expoctl.io import atomic_path

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:
        raise OSError(f"could not encode PNG for {path}")
    with atomic_path(path, suffix=".png") as tmp:
        tmp.write_bytes(buf.tobytes())


def write_video(frames: list[PreviewFrame], path: Path, fps: float) -> None:
    import cv2

    from expoctl.io import atomic_path

    h, w = frames[0].image.shape[:2]
    with atomic_path(path, suffix=".mp4") as tmp:
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
        if not writer.isOpened():
            raise InputError(f"{path}: OpenCV cannot write MP4 video here (no mp4v encoder)")
        try:
            for f in frames:
                writer.write(np.ascontiguousarray(annotate(f.image, f, scale=w / 320.0)[..., ::-1]))
        finally:
            writer.release()


# --- selection ------------------------------------------------------------------------------------------------------


def _select(frames: list[PreviewFrame], sections: list[dict], how: str, columns: int, max_rows: int) -> list[list[int]]:
    """Rows of positions in `frames` to show: one row spread over each dynamic section (a portal crossing ±2 s: the
    approach, the crossing and the adaptation after it), or evenly spaced frames."""
    pos_of = {f.frame_index: i for i, f in enumerate(frames)}
    rows: list[list[int]] = []
    if how == "transitions":
        for s in sorted((s for s in sections if s["kind"] == "dynamic"), key=lambda s: s["start_frame"]):
            inside = [pos_of[i] for i in range(int(s["start_frame"]), int(s["end_frame"]) + 1) if i in pos_of]
            if len(inside) >= 2:
                rows.append(_spread(inside, columns))
            if len(rows) == max_rows:
                break
    if not rows:  # uniform, or no transition in the rendered frames
        n = min(len(frames), columns * max_rows)
        picks = _spread(list(range(len(frames))), n)
        rows = [picks[i:i + columns] for i in range(0, len(picks), columns)]
    return rows


def _spread(items: list[int], n: int) -> list[int]:
    if len(items) <= n:
        return list(items)
    return [items[int(round(k * (len(items) - 1) / (n - 1)))] for k in range(n)] if n > 1 else [items[0]]


def _frame_kinds(sections: list[dict], n_frames: int) -> list[str]:
    kinds = ["unlabelled"] * n_frames
    for s in sections:
        for i in range(max(0, int(s["start_frame"])), min(n_frames - 1, int(s["end_frame"])) + 1):
            kinds[i] = str(s["kind"])
    return kinds


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) positions of each run of True."""
    out, start = [], None
    for i, m in enumerate(mask):
        if m and start is None:
            start = i
        elif not m and start is not None:
            out.append((start, i - 1))
            start = None
    if start is not None:
        out.append((start, len(mask) - 1))
    return out
