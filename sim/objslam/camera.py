"""Camera and depth-sensor configuration for the hand camera.

The camera is mounted on ``panda_hand`` and looks along the gripper. Inside the core every camera
is in the OpenCV convention (x right, y down, z forward); the conversion from SAPIEN's camera axes
(x forward, y left, z up) happens once, here (:data:`CV_FROM_SAPIEN`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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
    depth_noise: DepthNoiseConfig = DepthNoiseConfig()
    """Depth noise model."""
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

    def intrinsics(self) -> np.ndarray:
        """The 3x3 intrinsic matrix (principal point at the image centre)."""
        f = self.height / 2 / math.tan(math.radians(self.fovy_deg) / 2)
        return np.array([[f, 0, self.width / 2], [0, f, self.height / 2], [0, 0, 1]], dtype=np.float64)
