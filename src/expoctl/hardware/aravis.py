"""Aravis backend: GigE Vision and USB3 Vision cameras through the open-source GenICam driver (via PyGObject).

Why Aravis: it is the maintained open-source GenICam stack on Linux, packaged by Debian/Ubuntu, drives both
transport layers (the paper's FLIR Blackfly S is USB3 Vision) and ships a GigE Vision camera emulator
(`arv-fake-gv-camera-0.8`) that the tests run against. FLIR's PySpin would tie expoctl to one vendor's closed SDK.

GenICam feature names differ between cameras; this backend looks for, in order:
- exposure: `ExposureTime` (SFNC, µs; Blackfly S) or `ExposureTimeAbs` (older GigE cameras, the emulator; µs);
- gain: `Gain` (SFNC, dB; Blackfly S) or `GainRaw` (an integer in device units; the emulator). A raw gain has no dB
  scale the camera can tell us, so the user must give `gain_db_per_raw` (dB per step, from the datasheet); the
  emulator has no physical gain, and `6` dB per step matches how its image brightens (each step adds the equivalent
  of one doubling at mid grey);
- auto exposure / auto gain (`ExposureAuto`, `GainAuto`) are switched off, so the controller is the only one acting;
- per-frame metadata: chunk data (`ChunkModeActive`, `ChunkSelector` ExposureTime and Gain → `ChunkExposureTime`,
  `ChunkGain`; the Blackfly S has them) when the camera offers both; otherwise the registers are read back right after
  each frame arrives (`expoctl.hardware.base`, "settings_source": what that means for measured delays).

Discovery note: opening a camera by id runs Aravis' device discovery, which on GigE Vision sends a discovery
broadcast on every network interface of the machine (that is how GigE Vision finds cameras).
"""

from __future__ import annotations

import time
from typing import Any

from expoctl.hardware.base import (
    SUPPORTED_PIXEL_FORMATS,
    Camera,
    CameraError,
    CameraInfo,
    Frame,
    Limits,
    Range,
    to_rgb8,
)
from expoctl.controllers.base import Settings

#: pixel formats tried when the user names none and the camera's current one is not 8-bit (colour first)
_PREFERRED_FORMATS = ("BayerRG8", "BayerGR8", "BayerGB8", "BayerBG8", "RGB8", "BGR8", "Mono8")


def load_aravis():
    """The Aravis 0.8 GObject module, or a CameraError saying what to install."""
    try:
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis
    except (ImportError, ValueError) as exc:
        raise CameraError(
            f"the Aravis camera backend is not available ({exc}). Install the system library and its GObject "
            "bindings (Debian/Ubuntu: apt-get install gir1.2-aravis-0.8 libaravis-0.8-0 aravis-tools, plus "
            "libgirepository1.0-dev libcairo2-dev pkg-config to build PyGObject) and then pip install 'expoctl[camera]'"
        ) from None
    return Aravis


def list_cameras() -> list[dict[str, str]]:
    """Every camera Aravis finds: id, address, serial, model, protocol."""
    Aravis = load_aravis()
    Aravis.update_device_list()
    out = []
    for i in range(Aravis.get_n_devices()):
        out.append({"id": Aravis.get_device_id(i) or "", "address": Aravis.get_device_address(i) or "",
                    "serial": Aravis.get_device_serial_nbr(i) or "", "model": Aravis.get_device_model(i) or "",
                    "physical_id": Aravis.get_device_physical_id(i) or "",
                    "protocol": Aravis.get_device_protocol(i) or ""})
    return out


def resolve_camera_id(camera_id: str, found: list[dict[str, str]] | None = None) -> str:
    """The Aravis device id of the camera named by `camera_id` (its device id, serial number, address or physical
    id) among `found` (default: discover now); CameraError listing the cameras found if none matches."""
    found = list_cameras() if found is None else found
    for cam in found:
        if camera_id in (cam["id"], cam["serial"], cam["address"], cam["physical_id"]):
            return cam["id"]
    if not found:
        listing = "no cameras were found at all (is it powered and connected, and on the same subnet for GigE?)"
    else:
        listing = "cameras found: " + ", ".join(f"{c['id']} ({c['protocol']} {c['address'] or c['physical_id']}, "
                                                f"serial {c['serial']})" for c in found)
    raise CameraError(f"camera '{camera_id}' not found; {listing}")


class AravisCamera(Camera):
    """One camera opened through Aravis (see the module doc for the features used)."""

    def __init__(self, camera_id: str, *, width: int | None = None, height: int | None = None,
                 pixel_format: str | None = None, frame_rate_hz: float | None = None,
                 gain_db_per_raw: float | None = None, n_buffers: int = 8):
        self._Aravis = Aravis = load_aravis()
        from gi.repository import GLib

        self._GLib = GLib
        self._stream = None
        self._cam = None
        self._lost = False  # set once the device stopped answering: no more round trips to it (each would time out)
        device_id = resolve_camera_id(camera_id)
        self._name = camera_id
        self._n_buffers = int(n_buffers)
        try:
            self._cam = Aravis.Camera.new(device_id)
            self._dev = self._cam.get_device()
            self._features = self._pick_features(gain_db_per_raw)
            self._switch_off_auto()
            self._set_region(width, height)
            fmt = self._set_pixel_format(pixel_format)
            if frame_rate_hz is not None:
                self._set_frame_rate(frame_rate_hz)
            self.limits = self._read_limits()
            self._chunk_parser = self._enable_chunks()
            x, y, w, h = self._cam.get_region()
            rate = self._cam.get_frame_rate() if self._cam.is_frame_rate_available() else None
            self.info = CameraInfo(camera_id=camera_id, backend="aravis", model=self._cam.get_model_name() or "",
                                   serial=self._cam.get_device_serial_number() or "", pixel_format=fmt,
                                   resolution=(int(w), int(h)), frame_rate_hz=None if rate is None else float(rate),
                                   features=dict(self._features, device_id=device_id),
                                   settings_source="chunk" if self._chunk_parser is not None else "readback")
        except GLib.Error as exc:
            self.close()
            raise CameraError(f"camera {camera_id}: {exc.message}") from None
        except CameraError:
            self.close()
            raise

    # --- setup -------------------------------------------------------------------------------------------------------

    def _has(self, feature: str) -> bool:
        return bool(self._dev.is_feature_available(feature)) if self._dev.get_feature(feature) is not None else False

    def _pick_features(self, gain_db_per_raw: float | None) -> dict[str, Any]:
        f: dict[str, Any] = {}
        if self._has("ExposureTime"):
            f["exposure"] = "ExposureTime"
        elif self._has("ExposureTimeAbs"):
            f["exposure"] = "ExposureTimeAbs"
        else:
            raise CameraError(f"camera {self._name}: has neither ExposureTime nor ExposureTimeAbs (µs); "
                              "expoctl cannot set its exposure")
        f["exposure_unit"] = self._dev.get_feature(f["exposure"]).get_unit() or "us (SFNC default)"
        if self._has("GainSelector"):
            sel = self._dev.dup_available_enumeration_feature_values_as_strings("GainSelector") or []
            if "All" in sel:  # the Blackfly S has one analogue gain for all channels
                self._dev.set_string_feature_value("GainSelector", "All")
        if self._has("Gain"):
            f["gain"] = "Gain"
            f["gain_unit"] = self._dev.get_feature("Gain").get_unit() or "dB (SFNC default)"
        elif self._has("GainRaw"):
            if gain_db_per_raw is None or not gain_db_per_raw > 0:
                raise CameraError(
                    f"camera {self._name}: exposes its gain only as the integer GainRaw (device units, no dB scale); "
                    f"give --gain-db-per-raw (dB per raw step, from the camera's datasheet), got {gain_db_per_raw}")
            f["gain"] = "GainRaw"
            f["gain_db_per_raw"] = float(gain_db_per_raw)
        else:
            raise CameraError(f"camera {self._name}: has neither Gain (dB) nor GainRaw; expoctl cannot set its gain")
        return f

    def _switch_off_auto(self) -> None:
        for feature in ("ExposureAuto", "GainAuto"):
            if self._has(feature):
                self._dev.set_string_feature_value(feature, "Off")

    def _set_region(self, width: int | None, height: int | None) -> None:
        if width is None and height is None:
            return
        _, _, w0, h0 = self._cam.get_region()
        wb, hb = self._cam.get_width_bounds(), self._cam.get_height_bounds()
        w, h = width or w0, height or h0
        problems = []
        if not wb[0] <= w <= wb[1]:
            problems.append(f"--width {w} is outside its range {wb[0]}–{wb[1]}")
        if not hb[0] <= h <= hb[1]:
            problems.append(f"--height {h} is outside its range {hb[0]}–{hb[1]}")
        if problems:
            raise CameraError(f"camera {self._name}: " + "; ".join(problems))
        self._cam.set_region(0, 0, int(w), int(h))
        _, _, w1, h1 = self._cam.get_region()
        if (w1, h1) != (w, h):
            raise CameraError(f"camera {self._name}: asked for {w}x{h} pixels, the camera set {w1}x{h1} "
                              "(width/height must be a multiple of its increment)")

    def _set_pixel_format(self, pixel_format: str | None) -> str:
        available = self._dev.dup_available_enumeration_feature_values_as_strings("PixelFormat") or []
        usable = [p for p in available if p in SUPPORTED_PIXEL_FORMATS]
        if pixel_format is not None:
            if pixel_format not in available or pixel_format not in SUPPORTED_PIXEL_FORMATS:
                raise CameraError(f"camera {self._name}: pixel format {pixel_format} is not usable; the camera offers "
                                  f"{', '.join(available) or 'none'} and expoctl converts "
                                  f"{', '.join(usable) or 'none of them'}")
            self._cam.set_pixel_format_from_string(pixel_format)
            return pixel_format
        current = self._cam.get_pixel_format_as_string()
        if current in SUPPORTED_PIXEL_FORMATS:
            return current
        for p in _PREFERRED_FORMATS:
            if p in available:
                self._cam.set_pixel_format_from_string(p)
                return p
        raise CameraError(f"camera {self._name}: none of its pixel formats ({', '.join(available)}) is an 8-bit format "
                          f"expoctl converts ({', '.join(SUPPORTED_PIXEL_FORMATS)})")

    def _set_frame_rate(self, fps: float) -> None:
        if not self._cam.is_frame_rate_available():
            raise CameraError(f"camera {self._name}: its frame rate cannot be set (no AcquisitionFrameRate)")
        lo, hi = self._cam.get_frame_rate_bounds()
        if not lo <= fps <= hi:
            raise CameraError(f"camera {self._name}: --fps {fps:g} is outside its frame-rate range {lo:g}–{hi:g} Hz")
        self._cam.set_frame_rate(float(fps))

    def _read_limits(self) -> Limits:
        f = self._features
        e_lo, e_hi = self._dev.get_float_feature_bounds(f["exposure"])
        if f["gain"] == "Gain":
            g_lo, g_hi = self._dev.get_float_feature_bounds("Gain")
        else:
            r_lo, r_hi = self._dev.get_integer_feature_bounds("GainRaw")
            g_lo, g_hi = r_lo * f["gain_db_per_raw"], r_hi * f["gain_db_per_raw"]
        return Limits(Range(float(g_lo), float(g_hi)), Range(float(e_lo), float(e_hi)))

    def _enable_chunks(self):
        """Chunk data with the exposure time and gain of each frame, if the camera has both (else None)."""
        if not (self._has("ChunkModeActive") and self._has("ChunkSelector")):
            return None
        selectors = self._dev.dup_available_enumeration_feature_values_as_strings("ChunkSelector") or []
        if not ("ExposureTime" in selectors and "Gain" in selectors):
            return None
        try:
            self._cam.set_chunks("ExposureTime,Gain")
            return self._cam.create_chunk_parser()
        except self._GLib.Error:
            return None  # read-back still works; settings_source says which one was used

    # --- acquisition -------------------------------------------------------------------------------------------------

    def apply(self, settings: Settings) -> Settings:
        f = self._features
        try:
            self._dev.set_float_feature_value(f["exposure"], float(settings.exposure_us))
            if f["gain"] == "Gain":
                self._dev.set_float_feature_value("Gain", float(settings.gain_db))
            else:
                self._dev.set_integer_feature_value("GainRaw", int(round(settings.gain_db / f["gain_db_per_raw"])))
            return self._read_settings()
        except self._GLib.Error as exc:
            self._lost = True
            raise CameraError(f"camera {self._name}: setting gain/exposure failed ({exc.message}); "
                              "the camera stopped answering (disconnected or powered off?)") from None

    def read_settings(self) -> Settings:
        try:
            return self._read_settings()
        except self._GLib.Error as exc:
            self._lost = True
            raise CameraError(f"camera {self._name}: reading gain/exposure failed ({exc.message}); "
                              "the camera stopped answering (disconnected or powered off?)") from None

    def _read_settings(self) -> Settings:
        f = self._features
        exposure = self._dev.get_float_feature_value(f["exposure"])
        if f["gain"] == "Gain":
            gain = self._dev.get_float_feature_value("Gain")
        else:
            gain = self._dev.get_integer_feature_value("GainRaw") * f["gain_db_per_raw"]
        return Settings(float(gain), float(exposure))

    def start(self, triggered: bool) -> None:
        Aravis = self._Aravis
        try:
            self._cam.set_acquisition_mode(Aravis.AcquisitionMode.CONTINUOUS)
            if triggered:
                if not self._cam.is_software_trigger_supported():
                    raise CameraError(f"camera {self._name}: has no software trigger (TriggerSoftware); "
                                      "expoctl record pairs the two cameras by triggering them together")
                self._cam.set_trigger("Software")
            elif self._has("TriggerMode"):
                self._cam.clear_triggers()
            self._stream = self._cam.create_stream(None, None)
            payload = self._cam.get_payload()
            for _ in range(self._n_buffers):
                self._stream.push_buffer(Aravis.Buffer.new_allocate(payload))
            self._cam.start_acquisition()
        except self._GLib.Error as exc:
            raise CameraError(f"camera {self._name}: cannot start streaming ({exc.message})") from None
        self._triggered = triggered

    def trigger(self) -> None:
        try:
            self._cam.software_trigger()
        except self._GLib.Error as exc:
            self._lost = True
            raise CameraError(f"camera {self._name}: software trigger failed ({exc.message}); "
                              "the camera stopped answering (disconnected or powered off?)") from None

    def grab(self, timeout_s: float, newest: bool = False) -> tuple[Frame, int]:
        if self._stream is None:
            raise RuntimeError("grab() before start()")
        Aravis = self._Aravis
        deadline = time.monotonic() + timeout_s
        discarded = 0
        while True:
            left_us = int(max(0.0, deadline - time.monotonic()) * 1e6)
            buf = self._stream.timeout_pop_buffer(max(left_us, 1))
            if buf is None:
                self._lost = True
                raise CameraError(f"camera {self._name}: no frame arrived within {timeout_s:g} s; the camera stopped "
                                  "sending (disconnected, powered off, or its emulator was stopped?)")
            if newest:  # drop what queued up while we were busy: the controller acts on the latest image
                while (nxt := self._stream.try_pop_buffer()) is not None:
                    self._stream.push_buffer(buf)
                    buf, discarded = nxt, discarded + 1
            if buf.get_status() == Aravis.BufferStatus.SUCCESS:
                break
            self._stream.push_buffer(buf)  # incomplete (lost packets): the caller sees it as a device frame-id gap
        try:
            frame = self._frame_from(buf)
        finally:
            self._stream.push_buffer(buf)
        return frame, discarded

    def discard_queued(self) -> int:
        n = 0
        while self._stream is not None and (buf := self._stream.try_pop_buffer()) is not None:
            self._stream.push_buffer(buf)
            n += 1
        return n

    def _frame_from(self, buf) -> Frame:
        try:
            # the image part only: with chunk data the payload also carries the chunks after it
            image = to_rgb8(buf.get_image_data(), buf.get_image_width(), buf.get_image_height(), self.info.pixel_format)
        except ValueError as exc:
            raise CameraError(f"camera {self._name}: {exc}") from None
        settings = None
        if self._chunk_parser is not None:
            try:
                settings, source = self._chunk_settings(buf), "chunk"
            except self._GLib.Error:
                # chunks enabled but not in the frames (some firmware needs a restart of the stream): read back from
                # now on, and say so in what the recording records about this camera
                self._chunk_parser = None
                self.info.settings_source = "readback"
                self.info.features["chunk_data"] = "enabled, but frames carried none: read back instead"
        try:
            if settings is None:
                settings, source = self._read_settings(), "readback"
        except self._GLib.Error as exc:
            self._lost = True
            raise CameraError(f"camera {self._name}: reading the frame's gain/exposure failed ({exc.message}); "
                              "the camera stopped answering (disconnected or powered off?)") from None
        return Frame(image=image, settings=settings, settings_source=source,
                     timestamp_ns=int(buf.get_system_timestamp()), device_timestamp_ns=int(buf.get_timestamp()),
                     device_frame_id=int(buf.get_frame_id()))

    def _chunk_settings(self, buf) -> Settings:
        exposure = self._chunk_parser.get_float_value(buf, "ChunkExposureTime")
        gain = self._chunk_parser.get_float_value(buf, "ChunkGain")
        return Settings(float(gain), float(exposure))

    def stop(self) -> None:
        if self._cam is None or self._stream is None:
            return
        if self._lost:
            return  # nothing to tell a device that is gone; close() keeps the stream alive (its finalizer writes too)
        try:
            self._cam.stop_acquisition()
            if getattr(self, "_triggered", False):
                self._cam.clear_triggers()  # leave the camera free-running, as most users expect to find it
        except self._GLib.Error:
            pass  # a camera that is gone cannot be stopped; close() still releases our side
        self._stream = None

    def close(self) -> None:
        try:
            self.stop()
        finally:
            if self._lost and self._cam is not None:
                # Releasing a GigE device writes to it (give up control, stop the stream); to a device that is gone
                # each write times out after 2.5 s, and Python would release it at exit. Never release it instead:
                # one extra GObject reference each (the process is about to report the failure and end).
                for obj in (self._stream, self._cam, self._dev):
                    _leak(obj)
            self._stream = None
            self._cam = None
            self._dev = None


def _leak(obj) -> None:
    """Add a GObject reference that is never dropped (PyGObject does not expose g_object_ref)."""
    if obj is None:
        return
    import ctypes

    get = ctypes.pythonapi.PyCapsule_GetPointer
    get.restype, get.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]
    gobject = ctypes.CDLL("libgobject-2.0.so.0")
    gobject.g_object_ref.restype, gobject.g_object_ref.argtypes = ctypes.c_void_p, [ctypes.c_void_p]
    gobject.g_object_ref(get(obj.__gpointer__, None))

