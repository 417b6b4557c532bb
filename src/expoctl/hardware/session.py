"""Recording sessions on real cameras: `drive` (one camera under a controller) and `record` (the paper's dual-camera
data collection). Both run the library's loop (`expoctl.sim.closed_loop.drive_rig`) over a `LiveRig` and write a raw
sequence with `expoctl.raw.format.SequenceWriter`.

Stopping, and what is left on disk:
- after `frames` frames, or on Ctrl-C / SIGTERM (the first one: finish the current frame, then stop; a second one
  aborts and writes nothing): the frames so far are written as a complete sequence (frames.csv, sequence.yaml);
- a camera that fails (stops sending, stops answering): the frames before the failure are written the same way and
  the error is raised afterwards, naming the camera and where the frames are;
- the output directory appears only when complete (SequenceWriter writes to a hidden sibling and renames), and an
  existing directory is never replaced: the session refuses to start.
"""

from __future__ import annotations

import queue
import signal
import threading
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from expoctl.hardware.base import Camera, CameraError, Limits
from expoctl.hardware.live import LiveRig
from expoctl.controllers.base import Controller, Settings, TimedController
from expoctl.errors import ConfigError, InputError
from expoctl.sim.closed_loop import RigFrame, drive_rig
from expoctl.sim.protocol import PerturbationConfig
from expoctl.raw.format import SequenceWriter

UNTIL_STOPPED = 10**12  # "no frame limit": the loop runs until Ctrl-C or a camera fails


def check_out_dir(out: str | Path) -> Path:
    """The output sequence directory: refuse an existing one (nothing of the user's is ever replaced)."""
    out = Path(out)
    if out.exists():
        raise InputError(f"{out}: already exists; expoctl never overwrites a recording — choose a new --out directory")
    if out.parent.exists() and not out.parent.is_dir():
        raise InputError(f"{out.parent}: is not a directory")
    return out


def camera_controller_names() -> tuple[str, ...]:
    """The registered controllers that can drive a real camera: all but those that need the simulator's scene."""
    from expoctl.controllers.registry import controller_names

    return controller_names(runs_without=("scene",))


def controller_config(name: str, limits: Limits, model: str | None = None, backend: str = "auto") -> Any:
    """The typed config of controller `name` for a camera with these usable limits: its defaults, with every gain
    and exposure bound it has (its own, or a nested AG+AE's) set to the camera's range, as the camera's own AE has
    it; a controller that needs a network gets `--model` as its checkpoint. Checked as the config would be."""
    from expoctl.config_reader import read_config
    from expoctl.controllers.registry import CONTROLLERS, with_limits

    names = camera_controller_names()
    if name not in names:
        raise InputError(f"--controller {name!r}: unknown or not for a real camera (use one of {', '.join(names)})")
    entry = CONTROLLERS.get(name)
    wants_model = "checkpoint" in entry.info.get("needs", ())
    if (model is not None) != wants_model:
        raise InputError(f"--model PATH is needed with --controller {name}, and only then"
                         if model is None else f"--model is only for --controller learned, not {name}")
    config = with_limits(entry.config(), {"exposure_lower_us": limits.exposure_us.low,
                                          "exposure_upper_us": limits.exposure_us.high,
                                          "gain_lower_db": limits.gain_db.low, "gain_upper_db": limits.gain_db.high})
    if wants_model:
        path = Path(model)
        if not path.is_file():
            raise InputError(f"--model {model}: model checkpoint not found")
        if backend == "auto":
            backend = "onnx" if path.with_suffix(".onnx").is_file() else "torch"
        config = replace(config, checkpoint=str(path), backend=backend, num_threads=1)
    try:  # the camera's range may break the controller's own rules (Shim's 75 µs floor): say so by key
        return read_config(entry.config, asdict(config), f"controllers.{name}")
    except ConfigError as exc:
        raise InputError(f"--controller {name} cannot use this camera's range: {exc}") from None


def make_camera_controller(name: str, config: Any) -> Controller:
    from expoctl.controllers.registry import make_controller

    threads = getattr(config, "num_threads", None)
    if "checkpoint" in _needs(name) and threads:
        # The network's input is assembled with torch ops even when ONNX Runtime runs the network; with torch's
        # default pool of one thread per core, a (1, 15, 64, 64) division took 19 ms on a loaded 2-core machine
        # instead of 0.1 ms. The loop runs on the threads it was given, so torch gets the same number.
        import torch

        torch.set_num_threads(int(threads))
    return make_controller(name, config)


def _needs(name: str) -> tuple[str, ...]:
    from expoctl.controllers.registry import needs

    return needs(name)


class BackgroundWriter:
    """A `SequenceWriter` fed from the loop through a bounded queue, writing on one worker thread.

    PNG encoding is the loop's largest cost after the network (13 ms for 640×480 on a loaded 2-core machine) and
    OpenCV releases the GIL while encoding, so the loop grabs and runs the controller on the next frame meanwhile.
    One worker keeps the writer's calls in order; the bounded queue makes a loop faster than the disk wait instead of
    filling memory. A write error surfaces at the next `add_frame` or at `close`."""

    def __init__(self, writer: SequenceWriter, max_queued: int = 16):
        self.writer = writer
        self.meta = writer.meta
        self._queue: queue.Queue = queue.Queue(maxsize=max_queued)
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._work, name="expoctl-writer", daemon=True)
        self._thread.start()

    def _work(self) -> None:
        while (item := self._queue.get()) is not None:
            try:
                if self._error is None:
                    self.writer.add_frame(*item)
            except BaseException as exc:  # reported to the loop's thread, never lost
                self._error = exc
            finally:
                self._queue.task_done()
        self._queue.task_done()

    def add_frame(self, *args) -> None:
        if self._error is not None:
            raise self._error
        self._queue.put(args)

    def _drain(self) -> None:
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()

    def close(self) -> Path:
        self._drain()
        if self._error is not None:
            self.writer.abort()
            raise self._error
        return self.writer.close()

    def abort(self) -> None:
        self._error = self._error or RuntimeError("aborted")
        self._drain()
        self.writer.abort()


@dataclass
class SessionResult:
    out_dir: Path | None
    n_frames: int
    stopped: str  # "completed" | "interrupted" | "camera failed"
    summary: dict[str, Any] = field(default_factory=dict)


@contextmanager
def _graceful_stop() -> Iterator[dict]:
    """SIGINT/SIGTERM set a flag the loop checks after each frame; a second signal raises KeyboardInterrupt."""
    state = {"stop": False}

    def handler(signum, _frame):
        if state["stop"]:
            raise KeyboardInterrupt
        state["stop"] = True

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield state
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _run(rig: LiveRig, loop: Iterator[RigFrame], writer: BackgroundWriter, n_frames: int, first_index: int,
         on_frame: Callable[[int, RigFrame, float], None]) -> tuple[int, str, CameraError | None, list[float]]:
    """Write frames from `loop` until done, stopped or a camera fails; returns (frames, how it stopped, error,
    wall-clock time of each frame's arrival)."""
    written, stopped, error, arrivals = 0, "completed", None, []
    with _graceful_stop() as state:
        try:
            for frame in loop:
                arrivals.append(time.perf_counter())
                fid = frame.frame_index - first_index
                for cam in frame.cameras:
                    writer.add_frame(fid, cam.camera, cam.timestamp_ns, cam.settings.gain_db,
                                     cam.settings.exposure_us, cam.image)
                written += 1
                on_frame(fid, frame, arrivals[-1])
                if written >= n_frames:
                    break
                if state["stop"]:
                    stopped = "interrupted"
                    break
        except CameraError as exc:
            stopped, error = "camera failed", exc
        except ValueError as exc:  # the loop's own check: a controller returned non-finite settings
            stopped, error = "controller failed", CameraError(f"{exc}.")
        except OSError as exc:  # the recording itself cannot be written (disk full, permissions)
            writer.abort()
            raise InputError(f"{writer.writer.seq_dir}: writing the recording failed ({exc}); nothing was written") from None
        except BaseException:  # KeyboardInterrupt (a second Ctrl-C) or a bug: leave nothing half-written
            writer.abort()
            raise
        finally:
            try:
                rig.stop()
            except CameraError:
                pass
    return written, stopped, error, arrivals


def _finish(writer: BackgroundWriter, out: Path, written: int, stopped: str, error: CameraError | None) -> Path | None:
    """Close (frames written) or abort (none) the sequence; re-raise a camera failure saying what was kept."""
    if written == 0:
        writer.abort()
        if error is not None:
            raise CameraError(f"{error} Nothing was recorded, so nothing was written.")
        return None
    writer.meta["stopped"] = stopped if error is None else f"{stopped}: {error}"
    try:
        path = writer.close()
    except OSError as exc:
        raise InputError(f"{out}: writing the recording failed ({exc}); nothing was written") from None
    if writer.meta.get("cameras") == 1 and (path / "cam2").is_dir() and not any((path / "cam2").iterdir()):
        (path / "cam2").rmdir()  # the writer prepares both camera folders; a one-camera recording has one
    if error is not None:
        raise CameraError(f"{error} The {written} frame(s) recorded before it are saved in {path} "
                          "(a complete sequence: expoctl validate accepts it).")
    return path


def _open_writer(out: Path, meta: dict) -> BackgroundWriter:
    try:
        return BackgroundWriter(SequenceWriter(out, meta))
    except OSError as exc:
        raise InputError(f"{out}: cannot create the recording there ({exc})") from None


def _open_writer_and_start(out: Path, meta: dict, rig) -> BackgroundWriter:
    """The recording's writer, then the cameras started; a camera that cannot start leaves nothing behind."""
    writer = _open_writer(out, meta)
    try:
        rig.start()
    except BaseException:
        writer.abort()
        raise
    return writer


def _rate_hz(arrivals: list[float]) -> float | None:
    return (len(arrivals) - 1) / (arrivals[-1] - arrivals[0]) if len(arrivals) > 1 and arrivals[-1] > arrivals[0] else None


def _stats(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"median": None, "p95": None, "max": None}
    a = np.asarray(values, dtype=np.float64)
    return {"median": round(float(np.median(a)), 3), "p95": round(float(np.percentile(a, 95)), 3),
            "max": round(float(a.max()), 3)}


def _limits_dict(limits: Limits) -> dict:
    return {"gain_db": [limits.gain_db.low, limits.gain_db.high],
            "exposure_us": [limits.exposure_us.low, limits.exposure_us.high]}


def _camera_frame_stats(rig: LiveRig, c: int) -> dict:
    missed, stale = rig.stats.camera_frames_missed[c], rig.stats.discarded_stale[c]
    return {"skipped_stale": stale, "dropped": max(0, missed - stale)}


# --- drive ----------------------------------------------------------------------------------------------------------


def drive(camera: Camera, limits: Limits, controller_name: str, params: Any, out: Path, n_frames: int, *,
          initial: Settings | None = None, timeout_s: float = 2.0,
          report: Callable[[str], None] = print) -> SessionResult:
    """One camera in closed loop under a controller, free-running at the camera's frame rate (module doc)."""
    controller = TimedController(make_camera_controller(controller_name, params))
    rig = LiveRig([camera], [limits], triggered=False, timeout_s=timeout_s)
    start = limits.clamp(initial if initial is not None else camera.read_settings())
    w, h = camera.info.resolution
    meta = {"source": "rig", "cameras": 1,
            "rig": {"fps": camera.info.frame_rate_hz or 1.0, "resolution": [int(w), int(h)]},
            "controller": {"name": controller_name, "params": asdict(params)},
            "initial_settings": {"gain_db": start.gain_db, "exposure_us": start.exposure_us},
            "camera1": camera.info.to_dict(), "limits": {"camera1": _limits_dict(limits)}}
    writer = _open_writer_and_start(out, meta, rig)
    loop = drive_rig(rig, 1, controller, start, range(0, n_frames), seed=0, limit=rig.limit)
    report(f"{'frame':>6} {'gain_dB':>8} {'exposure_us':>11} {'mean':>6} {'controller_ms':>13} {'delay_frames':>12}")

    def on_frame(fid: int, frame: RigFrame, _t: float) -> None:
        cam = frame.camera(1)
        ms = controller.update_ms[-1] if controller.update_ms else None  # the update on the previous frame
        delay = rig.last_delay[0]
        report(f"{fid:6d} {cam.settings.gain_db:8.2f} {cam.settings.exposure_us:11.1f} {float(cam.image.mean()):6.1f} "
               f"{'-' if ms is None else f'{ms:.2f}':>13} {'-' if delay is None else delay:>12}")

    written, stopped, error, arrivals = _run(rig, loop, writer, n_frames, 0, on_frame)
    rate = _rate_hz(arrivals)
    summary = {"frames": written, "loop_hz": None if rate is None else round(rate, 3),
               "controller_ms": _stats(controller.update_ms),
               "actuation_delay_frames": _stats([float(d) for d in rig.delay[0].delays]),
               "actuation_delays_measured": len(rig.delay[0].delays),
               "settings_source": camera.info.settings_source, **_camera_frame_stats(rig, 0)}
    if rate is not None:
        writer.meta["rig"]["fps"] = round(rate, 3)  # what the sequence really has, not the camera's nominal rate
    writer.meta["drive"] = summary
    writer.meta["camera1"] = camera.info.to_dict()  # the settings source may have changed during the run
    path = _finish(writer, out, written, stopped, error)
    return SessionResult(path, written, stopped, summary)


# --- record ---------------------------------------------------------------------------------------------------------


def record(cameras: tuple[Camera, Camera], limits: tuple[Limits, Limits], reference: str, params: Any, out: Path, *,
           n_frames: int | None, baseline_m: float, seed: int = 0, warmup_frames: int = 30,
           perturbation: PerturbationConfig = PerturbationConfig(), pair_tolerance_ms: float = 10.0,
           timeout_s: float = 2.0, intrinsics: dict | None = None,
           report: Callable[[str], None] = print) -> SessionResult:
    """The paper's dual-camera data collection (module doc): camera 1 under `reference`, camera 2 perturbed from
    camera 1's settings frame by frame (`expoctl.sim.protocol`), both software-triggered together."""
    if reference not in camera_controller_names():
        raise InputError(f"--reference {reference!r}: unknown (use one of {', '.join(camera_controller_names())})")
    (w1, h1), (w2, h2) = cameras[0].info.resolution, cameras[1].info.resolution
    if (w1, h1) != (w2, h2):
        raise CameraError(f"cameras {cameras[0].camera_id} ({w1}x{h1}) and {cameras[1].camera_id} ({w2}x{h2}) deliver "
                          "different image sizes; set both to the same --width/--height")
    controller = TimedController(make_camera_controller(reference, params))
    rig = LiveRig(list(cameras), list(limits), triggered=True, timeout_s=timeout_s,
                  pair_tolerance_ms=pair_tolerance_ms)
    start = limits[0].clamp(cameras[0].read_settings())
    meta = {"source": "rig",
            "rig": {"baseline_m": float(baseline_m), "fps": 1.0, "resolution": [int(w1), int(h1)],
                    **({"intrinsics": dict(intrinsics)} if intrinsics else {})},
            "reference_controller": {"name": reference, "params": asdict(params)},
            "seed": int(seed), "perturbation": perturbation.to_dict(), "warmup_frames": int(warmup_frames),
            "initial_settings": {"gain_db": start.gain_db, "exposure_us": start.exposure_us},
            "camera1": cameras[0].info.to_dict(), "camera2": cameras[1].info.to_dict(),
            "limits": {"camera1": _limits_dict(limits[0]), "camera2": _limits_dict(limits[1])},
            "pairing": {"method": "software trigger, both cameras per frame",
                        "timestamp": "host receive time (Aravis system timestamp), one clock for both cameras",
                        "tolerance_ms": float(pair_tolerance_ms)}}
    writer = _open_writer_and_start(out, meta, rig)
    n = UNTIL_STOPPED if n_frames is None else int(n_frames)
    loop = drive_rig(rig, 2, controller, start, range(warmup_frames, warmup_frames + n), seed,
                     perturbation=perturbation, warmup_frames=warmup_frames, limit=rig.limit)
    report(f"recording {cameras[0].camera_id} (camera 1, {reference}) + {cameras[1].camera_id} (camera 2, perturbed) "
           f"into {out}; Ctrl-C stops and keeps the frames")

    def on_frame(fid: int, frame: RigFrame, _t: float) -> None:
        if fid % 25 == 0:
            c1, c2 = frame.camera(1).settings, frame.camera(2).settings
            report(f"frame {fid}: camera 1 {c1.gain_db:.2f} dB {c1.exposure_us:.0f} µs, "
                   f"camera 2 {c2.gain_db:.2f} dB {c2.exposure_us:.0f} µs, pair offset "
                   f"{rig.stats.pair_offsets_ms[-1]:.2f} ms")

    written, stopped, error, arrivals = _run(rig, loop, writer, n, warmup_frames, on_frame)
    rate = _rate_hz(arrivals)
    offsets = rig.stats.pair_offsets_ms
    summary = {"frames": written, "loop_hz": None if rate is None else round(rate, 3),
               "controller_ms": _stats(controller.update_ms),
               "pair_offset_ms": _stats(offsets), "mispaired": rig.stats.mispaired,
               "camera1": _camera_frame_stats(rig, 0), "camera2": _camera_frame_stats(rig, 1),
               "settings_source": [c.info.settings_source for c in cameras]}
    if rate is not None:
        writer.meta["rig"]["fps"] = round(rate, 3)
    writer.meta["pairing"]["max_offset_ms"] = summary["pair_offset_ms"]["max"]
    writer.meta["record"] = summary
    writer.meta["camera1"], writer.meta["camera2"] = (c.info.to_dict() for c in cameras)
    path = _finish(writer, out, written, stopped, error)
    return SessionResult(path, written, stopped, summary)
