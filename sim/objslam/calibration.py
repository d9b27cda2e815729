"""The simulated robot cell as it differs from what the estimator is told: the arm's calibration errors
(:class:`RobotConfig`), the table pose's (:class:`TableConfig`), and the contact physics of grasping
(:class:`ContactConfig`: real objects' masses and friction against the fingertips).

The estimator knows the robot through its *nominal* model: the Panda URDF and the nominal hand-eye
(camera mount) transform. The camera pose prior it receives is forward kinematics of that model on
the joint readings paired with each image. The simulated robot differs from that model, as a real one
does, by the errors of :class:`RobotConfig`, drawn once per episode from the run seed
(:func:`draw_arm_errors`):

- **Hand-eye error**: the camera sits at ``nominal mount · E`` on the hand, ``E`` a rigid transform of
  fixed size (``hand_eye_trans_m``, ``hand_eye_rot_deg``) in a direction drawn uniformly, constant over
  the episode. The renderer's camera is mounted at the true pose; the prior uses the nominal one.
- **Joint offsets**: each arm joint's encoder reads ``true angle + offset``, offsets Gaussian with
  standard deviation ``joint_offset_deg``, constant over the episode. The joint controller servos the
  readings, so the arm stands where the nominal model is off by the offsets: the kinematic error
  changes smoothly with the configuration instead of being one rigid shift.
- **Time offset**: the joint state paired with an image was sampled ``time_offset_s`` before the
  image's exposure (drawn uniformly in ``[0, time_offset_max_s]``): frames taken while the arm moves
  carry the motion over that interval as pose error.
- **Per-view bias and per-frame jitter** (``view_bias_*``, ``frame_jitter_*``; 0 under ``realistic``):
  an error redrawn for every view (arm move) and every frame, independent of everything else. This is
  the ``ideal`` preset's model (1 cm / 1° per view, 0.5 mm / 0.05° per frame): independent, zero-mean
  errors that the SLAM gauge averages out over views.

Cited hardware figures (docs of each field give the numbers used):

- Franka Emika Panda datasheet: pose repeatability ±0.1 mm (ISO 9283) — repeatability, not accuracy.
- Franzese, Spahn, Kober, Della Santina, "MUKCa: Accurate and Affordable Cobot Calibration Without
  External Measurement Devices", arXiv:2503.12584 (2025): the nominal kinematic models of a Franka
  and a KUKA cobot have a mean absolute position error of the order of 10 mm, 0.2 mm after their
  calibration.
- Zivid hand-eye calibration guide ("Unsatisfactory hand-eye calibration results"): residuals are
  expected sub-millimetre for small robots and in the millimetre range for larger ones, rotation
  sub-degree; Enebuse et al., "Accuracy evaluation of hand-eye calibration techniques for vision-guided
  robots", PLOS ONE 17(10) e0273261 (2022): millimetre-level translation and tenths-of-a-degree
  rotation errors of the common methods on a UR5e.
- Olson, "A Passive Solution to the Sensor Synchronization Problem", IROS 2010: sensors without clock
  synchronisation stamped on arrival at the host carry latencies of milliseconds to tens of
  milliseconds; 10 ms at 90°/s is 16 cm at 10 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RobotConfig:
    """How the simulated arm differs from the nominal model the estimator is given (``[robot]``).
    Each draw is seeded by the run seed mixed with the scene's (:func:`arm_error_seed`)."""

    hand_eye_trans_m: float = 0.003
    """Hand-eye (camera mount) translation error, metres: its length, direction uniform, constant over
    the episode. Default 3 mm (hand-eye calibration residuals are millimetres: Zivid guide, Enebuse et
    al. 2022). ``ideal``: 0."""
    hand_eye_rot_deg: float = 0.3
    """Hand-eye rotation error, degrees: its angle, axis uniform. Default 0.3° (residuals of tenths of a
    degree, same sources). ``ideal``: 0."""
    joint_offset_deg: float = 0.1
    """Standard deviation of each arm joint's encoder offset, degrees (reading = true + offset). Default
    0.1°: at the Panda's 0.6-0.8 m lever arms about 1-1.5 mm per joint, a few millimetres and a few
    tenths of a degree at the camera over seven joints, below the ~10 mm mean error of an uncalibrated
    Franka model (MUKCa, arXiv:2503.12584), which also holds link-length errors. ``ideal``: 0."""
    time_offset_max_s: float = 0.02
    """The joint state paired with an image was sampled this long before the exposure at most, seconds
    (the offset is drawn uniformly in ``[0, time_offset_max_s]`` per episode). Default 20 ms: host
    timestamping latencies of unsynchronised sensors (Olson, IROS 2010). ``ideal``: 0."""
    view_bias_trans_m: float = 0.0
    """Per-view translation error redrawn every view, metres (its length, direction uniform). The
    ``ideal`` preset's model: 0.01. Default 0."""
    view_bias_rot_deg: float = 0.0
    """Per-view rotation error redrawn every view, degrees. ``ideal``: 1.0. Default 0."""
    frame_jitter_trans_m: float = 0.0
    """Per-frame translation jitter, standard deviation per axis, metres. ``ideal``: 0.0005. Default 0."""
    frame_jitter_rot_deg: float = 0.0
    """Per-frame rotation jitter, standard deviation per axis of the rotation vector, degrees.
    ``ideal``: 0.05. Default 0."""

    def validate(self) -> None:
        """Raise ``ValueError`` naming the key if a value is out of range."""
        limits = {
            "hand_eye_trans_m": 0.05,
            "hand_eye_rot_deg": 5.0,
            "joint_offset_deg": 2.0,
            "time_offset_max_s": 0.2,
            "view_bias_trans_m": 0.05,
            "view_bias_rot_deg": 5.0,
            "frame_jitter_trans_m": 0.01,
            "frame_jitter_rot_deg": 1.0,
        }
        for key, hi in limits.items():
            v = getattr(self, key)
            if not (math.isfinite(v) and 0.0 <= v <= hi):
                raise ValueError(f"robot.{key}: {v} must be in [0, {hi}]")


def arm_error_seed(run_seed: int, scene_seed: int) -> int:
    """Seed of an episode's arm errors: the run seed mixed with the scene file's seed, so every
    episode of a benchmark draws its own calibration (as ``episode.kinematic_noise_seed`` did)."""
    return (run_seed * 1_000_003 + scene_seed) % (1 << 63)


#: Random streams of an episode (:func:`episode_rng`).
STREAM_SENSOR, STREAM_DETECTOR, STREAM_STRATEGY = 1, 2, 3
#: The grasp world's own sensor and detector streams.
STREAM_GRASP_SENSOR, STREAM_GRASP_DETECTOR = 7, 8
#: The AR experiment's camera unit and live depth noise.
STREAM_AR_UNIT, STREAM_AR_LIVE = 9, 10


def episode_rng(run_seed: int, scene_seed: int, stream: int) -> np.random.Generator:
    """Random stream ``stream`` (``STREAM_*``) of one episode, from the run seed mixed with the scene
    file's seed (:func:`arm_error_seed`): the scenes of one run draw independent sensor noise,
    detector noise (each object's persistent miss and confusion fields are keyed by its index in
    the scene, so with the run seed alone object k of every scene would be missed or mislabelled
    from the same directions) and random-strategy choices."""
    return np.random.default_rng([arm_error_seed(run_seed, scene_seed), stream])


def _unit(rng: np.random.Generator) -> np.ndarray:
    while True:
        v = rng.standard_normal(3)
        n = float(np.linalg.norm(v))
        if n > 1e-9:
            return v / n


def rotation_from_vector(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis × angle, radians), Rodrigues' formula."""
    w = np.asarray(w, dtype=np.float64)
    th = float(np.linalg.norm(w))
    if th < 1e-12:
        return np.eye(3)
    k = w / th
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(th) * kx + (1.0 - math.cos(th)) * kx @ kx


def rigid(translation: np.ndarray, rotation_vector: np.ndarray) -> np.ndarray:
    """4x4 rigid transform from a translation and a rotation vector."""
    m = np.eye(4)
    m[:3, :3] = rotation_from_vector(rotation_vector)
    m[:3, 3] = translation
    return m


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation (deg) difference of two 4x4 poses."""
    dt = float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))
    r = estimate[:3, :3].T @ truth[:3, :3]
    c = min(1.0, max(-1.0, (float(np.trace(r)) - 1.0) / 2.0))
    return dt, math.degrees(math.acos(c))


@dataclass(frozen=True)
class ArmErrors:
    """One episode's draw of :class:`RobotConfig`."""

    camera_from_true_camera: np.ndarray
    """(4, 4) hand-eye error ``E``, OpenCV camera axes: ``hand_from_camera_true = hand_from_camera_nominal · E``."""
    joint_offsets_rad: np.ndarray
    """(7,) encoder offsets of the arm joints, radians (reading = true + offset)."""
    time_offset_s: float
    """The joint state of a frame was sampled this long before its image, seconds."""
    config: RobotConfig
    seed: int

    @staticmethod
    def none() -> ArmErrors:
        """A robot exactly like its model."""
        return ArmErrors(np.eye(4), np.zeros(7), 0.0, RobotConfig(0.0, 0.0, 0.0, 0.0), 0)

    @property
    def is_exact(self) -> bool:
        """Whether the simulated robot equals its model (no error of any kind)."""
        c = self.config
        return (
            self.time_offset_s == 0.0
            and not np.any(self.joint_offsets_rad)
            and np.array_equal(self.camera_from_true_camera, np.eye(4))
            and c.view_bias_trans_m == c.view_bias_rot_deg == c.frame_jitter_trans_m == c.frame_jitter_rot_deg == 0.0
        )

    def view_bias(self, view_index: int) -> np.ndarray:
        """(4, 4) camera-frame error of view ``view_index`` (identity when ``view_bias_*`` are 0); depends
        only on (seed, view)."""
        c = self.config
        if c.view_bias_trans_m == 0.0 and c.view_bias_rot_deg == 0.0:
            return np.eye(4)
        rng = np.random.default_rng([self.seed, 0xB1A5, view_index])
        t = _unit(rng) * c.view_bias_trans_m
        return rigid(t, _unit(rng) * math.radians(c.view_bias_rot_deg))

    def frame_jitter(self, frame_index: int) -> np.ndarray:
        """(4, 4) camera-frame jitter of frame ``frame_index``; depends only on (seed, frame)."""
        c = self.config
        if c.frame_jitter_trans_m == 0.0 and c.frame_jitter_rot_deg == 0.0:
            return np.eye(4)
        rng = np.random.default_rng([self.seed, 0x7177, frame_index])
        t = rng.standard_normal(3) * c.frame_jitter_trans_m
        return rigid(t, rng.standard_normal(3) * math.radians(c.frame_jitter_rot_deg))

    def prior(self, world_from_camera_nominal: np.ndarray, view_index: int, frame_index: int) -> np.ndarray:
        """The prior the estimator receives for a frame: nominal forward kinematics of the (offset,
        delayed) joint readings, times the view's bias and the frame's jitter (both identity under
        ``realistic``)."""
        return world_from_camera_nominal @ self.view_bias(view_index) @ self.frame_jitter(frame_index)


def draw_arm_errors(config: RobotConfig, seed: int) -> ArmErrors:
    """Draw one episode's arm errors (deterministic in ``seed``)."""
    config.validate()
    rng = np.random.default_rng([seed, 0xA4])
    t = _unit(rng) * config.hand_eye_trans_m
    e = rigid(t, _unit(rng) * math.radians(config.hand_eye_rot_deg))
    offsets = rng.standard_normal(7) * math.radians(config.joint_offset_deg)
    dt = float(rng.uniform(0.0, config.time_offset_max_s)) if config.time_offset_max_s > 0 else 0.0
    return ArmErrors(e, offsets, dt, config, seed)


@dataclass(frozen=True)
class TableConfig:
    """Calibration error of the table pose the mapper is given (``[table]``). The simulated table top
    is the plane z = 0 of the robot's base frame; the mapper receives the plane measured by the cell's
    calibration instead, off by a height error and a tilt drawn once per episode
    (:func:`draw_table_plane`). Its support snap (objects extended down to the table) uses that plane,
    and its local point clouds cut the table around it (each frame also re-fits the plane to the
    depth returns within 3 cm of it: ``LocalCloudConfig::table_fit_band_m``).

    Size of the error: a table located by touching it with the arm (or by the hand camera) inherits the
    arm's absolute accuracy, millimetres (MUKCa, arXiv:2503.12584: ~10 mm mean for an uncalibrated
    Franka, 0.2 mm calibrated); a 2 mm height difference across a 0.6 m probing baseline is a 0.2° tilt."""

    height_error_m: float = 0.002
    """Standard deviation of the height error at the table centre, metres. Default 2 mm. ``ideal``: 0."""
    tilt_error_deg: float = 0.2
    """Tilt of the given plane against the true one, degrees: its angle, about a horizontal axis of
    uniform direction. Default 0.2°. ``ideal``: 0."""

    def validate(self) -> None:
        """Raise ``ValueError`` naming the key if a value is out of range."""
        for key, hi in (("height_error_m", 0.05), ("tilt_error_deg", 5.0)):
            v = getattr(self, key)
            if not (math.isfinite(v) and 0.0 <= v <= hi):
                raise ValueError(f"table.{key}: {v} must be in [0, {hi}]")


def draw_table_plane(config: TableConfig, seed: int, center_xy: tuple[float, float]) -> tuple[float, float, float]:
    """The table plane the mapper is given, ``z = a·x + b·y + c``, as ``(a, b, c)``: the true top z = 0
    tilted by ``tilt_error_deg`` about a random horizontal axis through the table centre and raised by
    a Gaussian height error there (deterministic in ``seed``)."""
    config.validate()
    rng = np.random.default_rng([seed, 0x7AB1E])
    dh = float(rng.standard_normal()) * config.height_error_m
    azimuth = float(rng.uniform(0.0, 2.0 * math.pi))
    slope = math.tan(math.radians(config.tilt_error_deg))
    a, b = slope * math.cos(azimuth), slope * math.sin(azimuth)
    c = dh - a * center_xy[0] - b * center_xy[1]
    return a, b, c


#: Physical properties of each object class (the simulated objects are solid primitives): density
#: giving a real item's mass in the primitive's volume, kg/m³, and the static = dynamic friction
#: coefficient of its surface. Masses: a packaged box of 0.15-0.4 kg in 0.5-1.5 l (block 300), a
#: 0.3 kg paperback of 0.5 l (book 600), a 0.6-0.9 kg keyboard of 1.7 l (keyboard 400), a 0.3 kg
#: ceramic mug filling a 0.5 l cylinder (cup 600), a full 330 ml can, 0.35 kg in 0.4 l (can 900), a
#: full 0.5 l bottle, 0.52 kg in 0.7 l (bottle 750), a 0.35 kg bowl in 1 l (bowl 350), a light ball
#: (ball 200). Friction: cardboard and paper 0.5, hard plastic 0.35, glazed ceramic 0.4, aluminium
#: 0.4, PET 0.35, felt 0.6 (mid-range of handbook values for these surfaces against rubber-like and
#: plastic pads; tabulated coefficients vary by ±50 % with surface and load: Blau, "The
#: significance and use of the friction coefficient", Tribology International 34 (2001) 585-591).
HOUSEHOLD_OBJECTS: dict[str, tuple[float, float]] = {
    "block": (300.0, 0.5),
    "book": (600.0, 0.5),
    "keyboard": (400.0, 0.35),
    "cup": (600.0, 0.4),
    "can": (900.0, 0.4),
    "bottle": (750.0, 0.35),
    "bowl": (350.0, 0.4),
    "ball": (200.0, 0.6),
}


@dataclass(frozen=True)
class ContactConfig:
    """Contact physics of grasping (``[contact]``): the objects' masses and friction and the Panda's
    fingertips. PhysX combines two surfaces' coefficients by their average, so a finger of
    ``finger_friction`` μ_f on an object of μ_o grips with (μ_f + μ_o) / 2."""

    objects: str = "household"
    """``"household"``: each class's density and friction from :data:`HOUSEHOLD_OBJECTS`;
    ``"uniform"``: every object 300 kg/m³ and friction 1.0 (the ``ideal`` preset)."""
    finger_friction: float = 0.6
    """Friction coefficient of the fingertip pads (static = dynamic). Default 0.6: rubber-like pads,
    giving 0.45-0.6 against the household surfaces (the stock Franka fingers are hard plastic, lower
    still). ``ideal``: 2.0."""

    def validate(self) -> None:
        """Raise ``ValueError`` naming the key if a value is out of range."""
        if self.objects not in ("household", "uniform"):
            raise ValueError(f"contact.objects: unknown {self.objects!r}; known: household, uniform")
        if not (math.isfinite(self.finger_friction) and 0.0 < self.finger_friction <= 3.0):
            raise ValueError(f"contact.finger_friction: {self.finger_friction} must be in (0, 3]")

    def object_physics(self, cls: str) -> tuple[float, float]:
        """(density kg/m³, friction) of an object of class ``cls``."""
        if self.objects == "uniform":
            return 300.0, 1.0
        return HOUSEHOLD_OBJECTS.get(cls, (300.0, 0.5))
