"""Camera and RGB-D sensor configuration of the hand camera, and the sensor model applied to renders.

The camera is mounted on ``panda_hand`` and looks along the gripper. Inside the core every camera
is in the OpenCV convention (x right, y down, z forward); the conversion from SAPIEN's camera axes
(x forward, y left, z up) happens once, here (:data:`CV_FROM_SAPIEN`).

Two sensor models (:attr:`CameraConfig.model`):

- ``"d435"`` (the ``realistic`` preset): an active-stereo RGB-D camera of the Intel RealSense D435
  class, the core's ``objslam_core::sensor`` module (its docs cite the datasheet and papers behind
  every number). It is a *sensor model*: it needs the renderer's geometry (each pixel's surface
  point and normal) and never sees labels or object ids. Depth gets correlated disparity noise, a
  per-episode scale error, mixed depths at silhouettes, the second imager's shadow, grazing
  dropouts and minimum / maximum range, and is registered to the colour image through the
  calibration the estimator assumes (the unit's true colour intrinsics, depth intrinsics and colour
  ← depth extrinsic differ from it by a per-episode draw). Colour gets motion blur from the arm's
  motion over the exposure and shot + read noise. The colour image is rendered with the unit's
  *true* intrinsics; frames carry the nominal ones, which the estimator assumes.
- ``"ideal"`` (the ``ideal`` preset): exact rendered depth with :class:`DepthNoiseConfig`, perfect
  registration, noise-free colour, nominal intrinsics.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

#: Rotation taking OpenCV camera coordinates to SAPIEN camera coordinates (columns: cv x, y, z
#: expressed in SAPIEN axes): cv x = −sapien y, cv y = −sapien z, cv z = sapien x.
SAPIEN_FROM_CV = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class DepthNoiseConfig:
    """Depth noise model: ``d' = round(d · (1 + ε) / q) · q`` with ``ε ~ N(0, sigma_rel)``, seeded by the
    run seed. Set both to 0 for perfect depth."""

    sigma_rel: float = 0.001
    """Multiplicative Gaussian noise, standard deviation relative to depth (0.1 % ≈ 0.5 mm at 0.5 m)."""
    quantisation_m: float = 0.001
    """Depth quantisation step, metres (1 mm, a typical 16-bit depth unit)."""

    def apply(self, depth_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy copy of ``depth_m`` (0 = no return stays 0)."""
        d = depth_m.astype(np.float32, copy=True)
        valid = d > 0
        if self.sigma_rel > 0:
            d[valid] *= (1.0 + rng.normal(0.0, self.sigma_rel, size=int(valid.sum()))).astype(np.float32)
        if self.quantisation_m > 0:
            d[valid] = np.round(d[valid] / self.quantisation_m) * self.quantisation_m
        return d


@dataclass(frozen=True)
class StereoDepthConfig:
    """Depth of the ``d435`` model (mirrors ``objslam_core::sensor::StereoDepthConfig``, whose docs
    give the sources)."""

    focal_px: float = 383.0
    """Depth imager focal length, pixels (D435 at 640x480: librealsense reports fx ≈ 381-386)."""
    baseline_m: float = 0.050
    """Stereo baseline, metres (D435 datasheet: 50 mm)."""
    subpixel_rms_px: float = 0.08
    """Disparity error RMS, pixels (Intel's tuning white paper: about 0.08 on a textured flat
    target). Depth RMS = z² · subpixel / (focal · baseline): 1.04 mm at 0.5 m."""
    correlation_px: float = 4.0
    """Correlation length of the disparity error, depth pixels (grid spacing of the noise field)."""
    scale_sigma: float = 0.005
    """Per-episode depth-scale error, standard deviation (0.5 %, clipped to 3 σ; the datasheet
    bounds absolute error by 2 %)."""
    min_range_m: float = 0.152
    """Minimum range, metres (Min-Z = focal × baseline / 126 = 0.152 m at 640x480)."""
    max_range_m: float = 3.0
    """Maximum range, metres (datasheet: up to ~10 m; 3 m is beyond every surface of the scenes)."""
    unit_m: float = 0.001
    """Depth unit, metres (the D400 default 1 mm)."""
    edge_jump_m: float = 0.01
    """A silhouette is a depth jump above ``edge_jump_m + edge_jump_rel · z``, metres."""
    edge_jump_rel: float = 0.02
    """Relative part of the silhouette jump threshold."""
    mixed_band_px: int = 1
    """Half-width of the band of mixed (flying) depths at silhouettes, pixels (0 = none)."""
    mixed_fraction: float = 0.5
    """Share of the band's pixels given a depth mixed between the near and far surface."""
    grazing_start_deg: float = 70.0
    """Incidence angle where grazing dropouts start, degrees."""
    grazing_end_deg: float = 85.0
    """Incidence angle where every return drops out, degrees."""
    shadow: bool = True
    """Invalidate pixels hidden from the second imager (50 mm to the right) by nearer surfaces."""


@dataclass(frozen=True)
class ColourConfig:
    """Colour of the ``d435`` model (``objslam_core::sensor::ColourConfig``)."""

    exposure_s: float = 0.015
    """Exposure time, seconds (indoor auto-exposure at 30 fps is 10-33 ms); the camera's motion over
    it, from the joint velocities, blurs the image. 0 = no blur."""
    shot_gain: float = 0.03
    """Signal-dependent noise variance per 8-bit level (σ ≈ 2 levels at mid grey)."""
    read_noise: float = 1.0
    """Signal-independent noise, standard deviation in 8-bit levels."""


@dataclass(frozen=True)
class CalibrationConfig:
    """Per-episode calibration errors of the ``d435`` model: the truth the simulator renders with
    differs from the nominal calibration the estimator assumes."""

    extrinsic_trans_sigma_m: float = 0.002
    """Colour ← depth extrinsic translation error, σ per axis, metres (≈ 3.5 mm in norm)."""
    extrinsic_rot_sigma_deg: float = 0.2
    """Colour ← depth extrinsic rotation error, σ per axis, degrees (≈ 0.35° in angle)."""
    colour_focal_sigma_rel: float = 0.003
    """Colour focal length error, relative σ."""
    colour_pp_sigma_px: float = 1.5
    """Colour principal point error, σ per axis, pixels."""
    depth_focal_sigma_rel: float = 0.003
    """Depth focal length error, relative σ."""
    depth_pp_sigma_px: float = 1.5
    """Depth principal point error, σ per axis, depth pixels."""


#: Sensor models of :attr:`CameraConfig.model`.
CAMERA_MODELS = ("d435", "ideal")


@dataclass(frozen=True)
class CameraConfig:
    """The hand camera."""

    width: int = 640
    """Image width, pixels."""
    height: int = 480
    """Image height, pixels."""
    fovy_deg: float = 58.0
    """Vertical field of view, degrees (a RealSense D435 colour camera has about 42°; 58° sees more
    of the table from 0.45 m)."""
    near_m: float = 0.02
    """Near clipping plane, metres."""
    far_m: float = 3.0
    """Far clipping plane, metres; beyond it depth is 0 (no return)."""
    mount_xyz: tuple[float, float, float] = (0.0, 0.0, 0.05)
    """Camera position in the ``panda_hand`` frame, metres."""
    mount_wxyz: tuple[float, float, float, float] = (0.7071068, 0.0, -0.7071068, 0.0)
    """Camera orientation in the ``panda_hand`` frame (SAPIEN camera axes), quaternion w, x, y, z."""
    model: str = "d435"
    """Sensor model: ``"d435"`` (active-stereo RGB-D, the realistic preset) or ``"ideal"``
    (exact depth with :attr:`depth_noise`, perfect colour and registration; the ideal preset)."""
    depth_noise: DepthNoiseConfig = DepthNoiseConfig()
    """Depth noise of the ``ideal`` model."""
    stereo: StereoDepthConfig = field(default_factory=StereoDepthConfig)
    """Depth of the ``d435`` model."""
    colour: ColourConfig = field(default_factory=ColourConfig)
    """Colour of the ``d435`` model."""
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    """Calibration errors of the ``d435`` model."""
    mask_robot_depth: bool = True
    """Set depth to 0 on pixels of the robot itself (the finger tips at the image edges)."""

    def validate(self) -> None:
        """Raise ``ValueError`` naming the field if a value is out of range."""
        if not (16 <= self.width <= 4096 and 16 <= self.height <= 4096):
            raise ValueError(f"camera.width/height: {self.width}x{self.height} outside 16..4096")
        if not (5.0 <= self.fovy_deg <= 150.0):
            raise ValueError(f"camera.fovy_deg: {self.fovy_deg} outside [5, 150]")
        if not (0 < self.near_m < self.far_m):
            raise ValueError("camera.near_m/far_m: need 0 < near < far")
        for key, v in (
            ("camera.depth_noise.sigma_rel", self.depth_noise.sigma_rel),
            ("camera.depth_noise.quantisation_m", self.depth_noise.quantisation_m),
        ):
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{key}: {v} must be a finite number ≥ 0 (0 turns it off)")
        if self.model not in CAMERA_MODELS:
            raise ValueError(f"camera.model: unknown {self.model!r}; known: {', '.join(CAMERA_MODELS)}")
        if self.stereo.mixed_band_px < 0:
            raise ValueError(f"camera.stereo.mixed_band_px: {self.stereo.mixed_band_px} must be ≥ 0")
        # The core checks every sensor-model range and names the key (``camera.stereo.baseline_m``).
        from . import _native

        try:
            _native.sensor_model(json.dumps(self.sensor_request(seed=0)))
        except _native.InputError as e:
            raise ValueError(str(e)) from e

    def intrinsics(self) -> np.ndarray:
        """The 3x3 intrinsic matrix (principal point at the image centre)."""
        f = self.height / 2 / math.tan(math.radians(self.fovy_deg) / 2)
        return np.array([[f, 0, self.width / 2], [0, f, self.height / 2], [0, 0, 1]], dtype=np.float64)

    def sensor_request(self, *, seed: int, frame_index: int = 0, camera_end_from_start: Any = None) -> dict:
        """The request of ``_native.sensor_model`` for this camera."""
        return {
            "config": {"stereo": asdict(self.stereo), "colour": asdict(self.colour), "calibration": asdict(self.calibration)},
            "seed": int(seed),
            "frame_index": int(frame_index),
            "intrinsics": self.intrinsics().tolist(),
            "camera_end_from_start": None if camera_end_from_start is None else np.asarray(camera_end_from_start).tolist(),
        }


class RgbdSensor:
    """The ``d435`` sensor model of one episode: the unit's calibration state drawn from ``seed``,
    applied frame by frame to the renderer's buffers (``_native.sensor_model``)."""

    def __init__(self, config: CameraConfig, seed: int) -> None:
        from . import _native

        self._native = _native
        self.config = config
        self.seed = int(seed)
        self._request = config.sensor_request(seed=self.seed)
        _, _, info = _native.sensor_model(json.dumps(self._request))
        self.unit = json.loads(info)["unit"]
        """The unit's calibration state (true vs assumed intrinsics, scale and registration error)."""
        self.last_stats: dict[str, int] = {}
        """The depth model's pixel counts on the last frame (shadow, grazing, mixed, ...)."""

    def true_intrinsics(self) -> np.ndarray:
        """The colour camera's true intrinsics (the renderer's); the estimator assumes
        :meth:`CameraConfig.intrinsics`."""
        k = self.unit["colour_true"]
        return np.array([[k["fx"], 0, k["cx"]], [0, k["fy"], k["cy"]], [0, 0, 1]], dtype=np.float64)

    def apply(
        self,
        points_in_camera: np.ndarray,
        normals_in_camera: np.ndarray,
        rgb: np.ndarray,
        *,
        frame_index: int,
        camera_end_from_start: np.ndarray | None = None,
        segmentation: np.ndarray | None = None,
        dropped_ids: Sequence[int] = (),
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(rgb, depth_m)`` the sensor delivers from a rendered frame: (H, W, 3) camera-frame
        points (OpenCV axes, z ≤ 0 = no surface), normals and 8-bit colour, or the renderer's own
        (H, W, 4) position (OpenGL axes, w ≥ 1 = no surface), normal and RGBA in [0, 1] buffers;
        ``camera_end_from_start`` is the camera's motion over the exposure (4x4, None = at rest).
        With the renderer's buffers, pixels whose ``segmentation`` id (H, W) is in ``dropped_ids``
        (the robot's own) count as no surface."""
        motion = None if camera_end_from_start is None else np.asarray(camera_end_from_start).tolist()
        req = dict(self._request, frame_index=int(frame_index), camera_end_from_start=motion)
        renderer = np.shape(points_in_camera)[-1] == 4
        depth, colour, info = self._native.sensor_model(
            json.dumps(req),
            np.ascontiguousarray(points_in_camera, dtype=np.float32),
            np.ascontiguousarray(normals_in_camera, dtype=np.float32),
            np.ascontiguousarray(rgb, dtype=np.float32 if renderer else np.uint8),
            None if segmentation is None else np.ascontiguousarray(segmentation, dtype=np.uint32),
            list(dropped_ids),
        )
        self.last_stats = json.loads(info)["stats"]
        return colour, depth


#: OpenGL camera axes (SAPIEN's position / normal buffers: x right, y up, z back) → OpenCV.
CV_FROM_GL = np.array([1.0, -1.0, -1.0], dtype=np.float32)
