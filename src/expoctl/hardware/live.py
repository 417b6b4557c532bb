"""Real cameras as a `expoctl.sim.closed_loop.Rig`, so `drive_rig` — the simulator's loop — drives them too.

Per call `capture(t, settings)`:
1. each camera gets its command for frame t (written only when it changed: a write is a round trip to the device);
2. free-running (one camera, `drive`): take the newest frame the camera has sent, discarding older queued ones so the
   controller always acts on the latest image (and, with register read-back, every frame queued before a new
   command was written: read back after the write, it would be labelled with settings it was not exposed with);
   triggered (`record`): drop anything still queued (a late frame of an earlier trigger), software-trigger every
   camera, then take one frame from each — both frames of a pair come from the same trigger;
3. pairing check (two cameras): the two frames' host receive times must lie within `pair_tolerance_ms`. Frames of
   consecutive triggers are at least one loop period apart (≥ 20 ms up to 50 Hz, 40 ms at 25 Hz), so the default
   tolerance of 10 ms cannot pair frames of different triggers; it catches a camera that missed a trigger or
   delivered a stale frame.
   A pair outside it is discarded and the trigger repeated (counted in `stats.mispaired`); three in a row stop
   the run with an error naming both cameras;
4. bookkeeping: frames the camera numbered but we never received (gaps in its frame counter: dropped in transport or
   discarded as stale) and the actuation delay (`ActuationDelay`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

from expoctl.hardware.base import Camera, CameraError, Frame, Limits
from expoctl.controllers.base import Settings
from expoctl.sim.closed_loop import CameraFrame, RigFrame

#: a reported setting equals a command when within these (GenICam devices round to their own increments, and
#: the command we compare with is what the device itself read back after the write)
GAIN_TOLERANCE_DB = 0.02
EXPOSURE_TOLERANCE_REL = 2e-3
EXPOSURE_TOLERANCE_US = 1.0


def same_settings(a: Settings, b: Settings) -> bool:
    return (abs(a.gain_db - b.gain_db) <= GAIN_TOLERANCE_DB
            and abs(a.exposure_us - b.exposure_us) <= max(EXPOSURE_TOLERANCE_US, EXPOSURE_TOLERANCE_REL * b.exposure_us))


class ActuationDelay:
    """How many camera frames pass until a command shows in a frame's metadata.

    A command computed from the frame with device frame number k and first seen in the metadata of frame j has a
    delay of j − k frames; 1 is the loop's design (settings from frame t act at t+1). Commands that do not change the
    settings cannot be seen and are not counted; a command overtaken by a newer one before it showed is dropped."""

    def __init__(self) -> None:
        self._pending: list[tuple[int, Settings]] = []  # (frame number the command was computed from, settings)
        self.delays: list[int] = []

    def commanded(self, from_frame: int, accepted: Settings, previous: Settings | None) -> None:
        if previous is not None and same_settings(accepted, previous):
            return
        self._pending.append((from_frame, accepted))
        del self._pending[:-8]  # a camera that never shows a command must not grow this without bound

    def observed(self, frame: int, reported: Settings) -> int | None:
        """The delay of the command this frame first shows, if any."""
        for i in range(len(self._pending) - 1, -1, -1):  # newest first: an older equal command is superseded
            k, s = self._pending[i]
            if frame > k and same_settings(reported, s):
                del self._pending[: i + 1]
                self.delays.append(frame - k)
                return frame - k
        return None


@dataclass
class RigStats:
    frames: int = 0
    camera_frames_missed: list[int] = field(default_factory=list)  # per camera: gaps in the device frame counter
    discarded_stale: list[int] = field(default_factory=list)  # per camera: queued frames skipped for a newer one
    mispaired: int = 0  # pairs discarded for exceeding the pairing tolerance (triggered rigs)
    pair_offsets_ms: list[float] = field(default_factory=list)  # |Δt| of every accepted pair


class LiveRig:
    """One or two real cameras behind the `Rig` protocol (module doc). Call `start()` first."""

    def __init__(self, cameras: Sequence[Camera], limits: Sequence[Limits], *, triggered: bool,
                 timeout_s: float = 2.0, pair_tolerance_ms: float = 10.0, max_mispaired_in_row: int = 3):
        if len(cameras) not in (1, 2) or len(limits) != len(cameras):
            raise ValueError("a live rig has one or two cameras, with one Limits each")
        self.cameras = list(cameras)
        self.limits = list(limits)
        self.triggered = triggered
        self.timeout_s = float(timeout_s)
        self.pair_tolerance_ns = int(pair_tolerance_ms * 1e6)
        self.max_mispaired_in_row = int(max_mispaired_in_row)
        n = len(cameras)
        self.stats = RigStats(camera_frames_missed=[0] * n, discarded_stale=[0] * n)
        self.delay = [ActuationDelay() for _ in cameras]
        self.last_delay: list[int | None] = [None] * n  # delay resolved by the latest frame, per camera
        self._accepted: list[Settings | None] = [None] * n  # what each device holds (last write, read back)
        self._wanted: list[Settings | None] = [None] * n  # what each device was last asked for
        self._last_frame_no: list[int | None] = [None] * n

    def start(self) -> None:
        for cam in self.cameras:
            cam.start(self.triggered)

    def stop(self) -> None:
        for cam in self.cameras:
            cam.stop()

    def limit(self, camera: int, settings: Settings) -> Settings:
        """`drive_rig`'s limit: a command restricted to camera `camera`'s usable range."""
        return self.limits[camera - 1].clamp(settings)

    def capture(self, frame_index: int, settings: Sequence[Settings]) -> RigFrame:
        n = len(settings)
        for c in range(n):
            if self._command(c, settings[c]) and not self.triggered and self.cameras[c].info.settings_source == "readback":
                # frames already received were exposed before this write, yet reading the registers after them
                # would report the new settings: drop them (with chunk data every frame says what it had)
                self.stats.discarded_stale[c] += self.cameras[c].discard_queued()
        for _attempt in range(self.max_mispaired_in_row):
            frames = self._grab(n)
            if n == 1 or abs(frames[0].timestamp_ns - frames[1].timestamp_ns) <= self.pair_tolerance_ns:
                break
            self.stats.mispaired += 1
            offset_ms = (frames[0].timestamp_ns - frames[1].timestamp_ns) / 1e6
            for c, f in enumerate(frames):  # discarded, but received: not a transport loss
                self._account(c, f)
        else:
            raise CameraError(
                f"cameras {self.cameras[0].camera_id} and {self.cameras[1].camera_id}: the two frames of one trigger "
                f"arrived {offset_ms:+.1f} ms apart, outside the pairing tolerance of {self.pair_tolerance_ns / 1e6:g} ms, "
                f"{self.max_mispaired_in_row} times in a row (a camera misses triggers, or the link is overloaded; "
                "raise --pair-tolerance-ms only if the frames really belong together)")
        if n == 2:
            self.stats.pair_offsets_ms.append(abs(frames[0].timestamp_ns - frames[1].timestamp_ns) / 1e6)
        self.stats.frames += 1
        for c, f in enumerate(frames):
            self._account(c, f)
        cams = tuple(CameraFrame(c + 1, f.settings, f.image, f.timestamp_ns) for c, f in enumerate(frames))
        return RigFrame(frame_index, frames[0].timestamp_ns, cams)

    # --- internals ---------------------------------------------------------------------------------------------------

    def _command(self, c: int, wanted: Settings) -> bool:
        """Write `wanted` to camera c unless it is what the device was last asked for; True if written."""
        if wanted == self._wanted[c]:  # skip the round trip
            return False
        previous = self._accepted[c]
        accepted = self.cameras[c].apply(wanted)
        self._wanted[c] = wanted
        # the command was computed from the camera's latest frame (before the first frame: from "frame −1")
        from_frame = self._last_frame_no[c] if self._last_frame_no[c] is not None else -1
        if self._last_frame_no[c] is not None:
            self.delay[c].commanded(from_frame, accepted, previous)
        self._accepted[c] = accepted
        return True

    def _grab(self, n: int) -> list[Frame]:
        if self.triggered:
            for c, cam in enumerate(self.cameras[:n]):
                self.stats.discarded_stale[c] += cam.discard_queued()  # a late frame of an earlier trigger
            for cam in self.cameras[:n]:
                cam.trigger()
        frames = []
        for c in range(n):
            frame, discarded = self.cameras[c].grab(self.timeout_s, newest=not self.triggered)
            self.stats.discarded_stale[c] += discarded
            frames.append(frame)
        return frames

    def _account(self, c: int, f: Frame) -> None:
        last = self._last_frame_no[c]
        if last is not None and f.device_frame_id > last + 1:
            self.stats.camera_frames_missed[c] += f.device_frame_id - last - 1
        self._last_frame_no[c] = f.device_frame_id
        self.last_delay[c] = self.delay[c].observed(f.device_frame_id, f.settings)
