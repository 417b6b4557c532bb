"""Feature matching vs camera settings at a fixed pose: the simulator's behaviour checks (simulator spec, Validation).

Two checks the spec asks of the closed-loop simulator:

1. *Inliers vs exposure form an inverted U that shifts with scene luminance.* At one pose the consecutive pair
   (t, t+1) is rendered and captured once per setting. Too short an exposure leaves few electrons per pixel, so
   texture drowns in shot and read noise and in 8-bit quantisation of the dark end; too long an exposure clips
   highlights (no gradients left) and smears texture along the ego-motion (motion blur grows linearly with the
   exposure time). Between the two ends the inlier count peaks. The peak sits at a fixed image brightness, so it
   moves by the scene's luminance ratio: a 2^k times darker scene needs k EV more exposure.
2. *High gain raises false detections.* At a fixed product exposure × linear gain the mean image is the same, but
   the collected charge falls as 1/gain: shot noise relative to the signal grows as √gain, and the read noise
   (fixed in electrons) is amplified with the signal. On a textureless patch that noise alone crosses FAST's
   threshold, so detections appear that no scene point explains and that do not survive matching / RANSAC.

Settings axis: the *effective exposure* t·10^(g/20) (µs at 0 dB). A sweep runs the exposure over the camera range
at 0 dB, and where the longest exposure is still too dark (the tunnel) continues with gain at the longest exposure
— what an auto-exposure would do. Every capture of frame k uses the sensor generator `sensor_rng(seed, 1, k)`, as
the closed loop does, so settings change the noise only through the physics, not through the draws.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from expoctl.camera.ranges import EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX
from expoctl.features.pipeline import rgb_to_grey
from expoctl.sim.closed_loop import sensor_rng

Y_RGB = np.array([0.2126, 0.7152, 0.0722], np.float32)  # Rec.709 luminance weights of the linear RGB channels
DB_PER_EV = 20.0 * math.log10(2.0)  # 6.02 dB of gain = one stop


@dataclass(frozen=True)
class SweepPoint:
    """One setting at one pose: image statistics of frame t and per-front-end counts of the pair (t, t+1)."""

    exposure_us: float
    gain_db: float
    mean_grey: float  # frame t, 0–255
    saturated_fraction: float  # frame t, share of grey pixels at 255
    n_features: dict = field(default_factory=dict)  # front end -> features in frame t
    n_inliers: dict = field(default_factory=dict)  # front end -> inlier matches t -> t+1

    @property
    def effective_exposure_us(self) -> float:
        return self.exposure_us * 10.0 ** (self.gain_db / 20.0)

    @property
    def ev(self) -> float:
        """Stops above the shortest exposure at 0 dB."""
        return math.log2(self.effective_exposure_us / EXPOSURE_US_MIN)

    def as_dict(self) -> dict:
        return {"exposure_us": self.exposure_us, "gain_db": self.gain_db, "ev": self.ev,
                "mean_grey": self.mean_grey, "saturated_fraction": self.saturated_fraction,
                "n_features": dict(self.n_features), "n_inliers": dict(self.n_inliers)}


def exposure_grid_us(step_ev: float = 0.5) -> np.ndarray:
    """Exposures from 75 µs up in `step_ev` stops, ending exactly at 30 ms (the last step may be shorter)."""
    n = int(math.floor(math.log2(EXPOSURE_US_MAX / EXPOSURE_US_MIN) / step_ev + 1e-9))
    grid = EXPOSURE_US_MIN * 2.0 ** (step_ev * np.arange(n + 1))
    return grid if math.isclose(grid[-1], EXPOSURE_US_MAX) else np.append(grid, EXPOSURE_US_MAX)


def gain_grid_db(step_ev: float = 0.5) -> np.ndarray:
    """Gains above 0 dB in `step_ev` stops up to 30 dB (the continuation of a sweep at the longest exposure)."""
    step = step_ev * DB_PER_EV
    grid = step * np.arange(1, int(math.floor(GAIN_DB_MAX / step + 1e-9)) + 1)
    return grid if math.isclose(grid[-1], GAIN_DB_MAX) else np.append(grid, GAIN_DB_MAX)


def median_luminance_cd_m2(luminance: np.ndarray) -> float:
    """Median Rec.709 luminance Y (cd/m²) of an H×W×3 linear luminance image."""
    return float(np.median(luminance @ Y_RGB))


def capture_pair(scene, sensor, frame: int, exposure_us: float, gain_db: float, seed: int):
    """Grey frames t and t+1 at one setting, motion blur over this exposure included (scene.luminance)."""
    out = []
    for t in (frame, frame + 1):
        lum = scene.luminance(t, float(exposure_us), 1)
        out.append(rgb_to_grey(sensor.capture(lum, float(exposure_us), float(gain_db), sensor_rng(seed, 1, t))))
    return out[0], out[1]


def measure_pair(grey_a: np.ndarray, grey_b: np.ndarray, frontends: dict, exposure_us: float, gain_db: float,
                 match_seed: int) -> SweepPoint:
    """Counts for one pair; `frontends` maps names to front ends (make_frontend)."""
    n_feat, n_inl = {}, {}
    for name, fe in frontends.items():
        a, b = fe.extract(grey_a), fe.extract(grey_b)
        n_feat[name] = int(fe.n_features(a))
        n_inl[name] = int(fe.match(a, b, match_seed)[1])
    return SweepPoint(float(exposure_us), float(gain_db), float(grey_a.mean()), float(np.mean(grey_a == 255)),
                      n_feat, n_inl)


def sweep_settings(scene, sensor, frame: int, settings: list[tuple[float, float]], frontends: dict,
                   seed: int = 0) -> list[SweepPoint]:
    """One SweepPoint per (exposure_us, gain_db) at the pose of `frame` (pair frame, frame + 1)."""
    points = []
    for exposure_us, gain_db in settings:
        a, b = capture_pair(scene, sensor, frame, exposure_us, gain_db, seed)
        points.append(measure_pair(a, b, frontends, exposure_us, gain_db, match_seed=seed + frame))
    return points


def sweep_exposure(scene, sensor, frame: int, frontends: dict, seed: int = 0, step_ev: float = 0.5,
                   extend_below_saturated: float | None = 0.25) -> list[SweepPoint]:
    """Exposure sweep at 0 dB over 75 µs–30 ms; continued with gain at 30 ms when less than `extend_below_saturated`
    of the 30 ms frame is clipped (most of the image could still get brighter, so the U's falling side lies beyond
    the exposure range; None: never). Returns points in increasing effective exposure."""
    points = sweep_settings(scene, sensor, frame, [(e, 0.0) for e in exposure_grid_us(step_ev)], frontends, seed)
    if extend_below_saturated is not None and points[-1].saturated_fraction < extend_below_saturated:
        points += sweep_settings(scene, sensor, frame, [(EXPOSURE_US_MAX, g) for g in gain_grid_db(step_ev)],
                                 frontends, seed)
    return points


def peak(points: list[SweepPoint], frontend: str) -> SweepPoint:
    """The point of most inliers (the first of ties, i.e. the shortest effective exposure)."""
    return max(points, key=lambda p: (p.n_inliers[frontend], -p.ev))


def equal_brightness_settings(effective_exposure_us: float, gains_db) -> list[tuple[float, float]]:
    """(exposure_us, gain_db) pairs with the same product t·10^(g/20), i.e. the same mean image below clipping."""
    out = []
    for g in gains_db:
        t = effective_exposure_us / 10.0 ** (g / 20.0)
        if not EXPOSURE_US_MIN <= t <= EXPOSURE_US_MAX:
            raise ValueError(f"{effective_exposure_us:g} µs effective at {g:g} dB needs {t:g} µs, outside the range")
        out.append((float(t), float(g)))
    return out


def flat_field_luminance_cd_m2(sensor, effective_exposure_us: float, signal_fraction: float) -> float:
    """Uniform luminance whose mean signal is `signal_fraction` of the saturation signal (full well or ADC full scale)
    at this effective exposure and 0 dB; equal products t·gain then give the same mean DN at every gain."""
    return signal_fraction * sensor.saturation_luminance_cd_m2(effective_exposure_us, 0.0)


def flat_field_detections(sensor, luminance_cd_m2: float, exposure_us: float, gain_db: float, frontends: dict,
                          seed: int = 0, frame: int = 0) -> tuple[dict, float]:
    """({front end: features detected}, mean grey) on a capture of a uniform (textureless) scene: every detection is
    noise, none is a scene point."""
    lum = np.full((sensor.height, sensor.width, 3), float(luminance_cd_m2), np.float32)
    grey = rgb_to_grey(sensor.capture(lum, exposure_us, gain_db, sensor_rng(seed, 1, frame)))
    return {n: int(fe.n_features(fe.extract(grey))) for n, fe in frontends.items()}, float(grey.mean())


def pose_frames(city, trajectory, exit_lead_s: float = 1.5) -> dict:
    """Frame indices of three fixed poses on a whole-lap `trajectory`: `open_road` (farthest along the route from any
    tunnel), `tunnel` (middle of the first tunnel), `exit` (`exit_lead_s` before leaving the first tunnel, looking
    at the bright portal)."""
    n = len(trajectory.timestamps_ns)
    times = trajectory.timestamps_ns[: n - 1] * 1e-9  # frame n-1 has no successor
    s = trajectory.s_at(times)
    length = city.length_m
    spans = city.tunnel_spans()

    def dist_to_tunnels(x):
        d = np.full(x.shape, np.inf)
        for a, b in spans:
            inside = ((x - a) % length) <= (b - a)
            gap = np.minimum((a - x) % length, (x - b) % length)
            d = np.minimum(d, np.where(inside, 0.0, gap))
        return d

    a, b = spans[0]
    mid = (a + 0.5 * (b - a)) % length
    exit_s = (b - exit_lead_s * trajectory.speed_mps) % length

    def nearest(target):
        return int(np.argmin(np.abs((s - target + 0.5 * length) % length - 0.5 * length)))

    return {"open_road": int(np.argmax(dist_to_tunnels(s))), "tunnel": nearest(mid), "exit": nearest(exit_s)}
