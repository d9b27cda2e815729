"""The SAPIEN tabletop: table, textured objects, the Franka Panda with a hand camera, lights.

Entry point: :class:`SimWorld` (build from a :class:`~objslam.scene.SceneSpec`), then
:meth:`SimWorld.render` → :class:`SensorFrame` (what the robot senses) and
:meth:`SimWorld.ground_truth` (what only evaluation sees), and :meth:`SimWorld.move_camera_to`,
which solves IK for a camera pose and executes a smooth trajectory along a Cartesian camera path
(the camera keeps looking at the scene) with the PD drives while emitting frames at a fixed rate
(a video stream, as SLAM needs). Forward kinematics, IK and the collision checks of every camera
move are the core planner's (``objslam_core::plan``: table, self-collision and the obstacles of
:meth:`SimWorld.set_obstacles`); a camera path that is not free falls back to the planner's joint
path (RRT-Connect when the straight line collides). Every move is timed by the planner's Ruckig
trajectories (jerk- and acceleration-limited, joint speed capped by the run's ``max_joint_speed``)
and tracked by the PD drives with velocity feed-forward: a dense Cartesian camera path as one
Ruckig move of its path parameter, so the camera does not stop at its waypoints
(``Planner.time_parameterize_path``; the Ruckig crate's own intermediate waypoints need its web
service), a joint-path fallback rest-to-rest between its corners.

Rendering is CPU-only (Mesa lavapipe ≥ 24.3; see ECOSYSTEM.md). Physics runs at 240 Hz with the
solver settings ManiSkill uses for reliable grasps.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import sapien

from . import _native
from .calibration import ArmErrors, ContactConfig
from .camera import SAPIEN_FROM_CV, CameraConfig, RgbdSensor
from .camera_path import CameraPaths, quat_from_matrix
from .detector import DetectorView
from .meshes import get_asset
from .scene import ObjectSpec, SceneSpec
from .textures import TextureConfig, object_texture, table_texture

#: Physics rate, Hz.
PHYSICS_HZ = 240
#: Panda arm joint stiffness / damping / force limit of the PD drives (ECOSYSTEM.md).
ARM_STIFFNESS, ARM_DAMPING, ARM_FORCE_LIMIT = 1000.0, 100.0, 100.0
#: Gripper finger drive.
GRIPPER_STIFFNESS, GRIPPER_DAMPING, GRIPPER_FORCE_LIMIT = 1000.0, 100.0, 100.0
GRIPPER_OPEN_M = 0.04
#: Physics settings for grasping (ManiSkill's; ECOSYSTEM.md), used with ``SimWorld(grasp_physics=True)``.
GRASP_PHYSICS = {"contact_offset_m": 0.02, "solver_position_iterations": 25, "patch_radius_m": 0.1}
#: The camera path length is sampled every this many physics steps (30 Hz).
PATH_SAMPLE_STEPS = PHYSICS_HZ // 30
#: A comfortable start configuration (camera looking down over the table).
READY_QPOS = np.array([0.0, -0.6, 0.0, -2.4, 0.0, 1.8, math.pi / 4, GRIPPER_OPEN_M, GRIPPER_OPEN_M])


class UnreachablePoseError(RuntimeError):
    """IK found no collision-free joint configuration for a requested camera pose."""

    def __init__(self, what: str, position: np.ndarray) -> None:
        super().__init__(
            f"{what}: camera pose at {np.round(position, 3).tolist()} is unreachable "
            "(no collision-free IK solution)"
        )
        self.position = position


class MotionError(RuntimeError):
    """The arm did not reach its joint target (blocked or diverged)."""


def panda_urdf_path() -> Path:
    """The Panda URDF shipped in the mani-skill wheel (installed with ``--no-deps``; never imported)."""
    env = os.environ.get("OBJSLAM_PANDA_URDF")
    if env:
        return Path(env)
    spec = importlib.util.find_spec("mani_skill")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError(
            "mani_skill is not installed: run `make setup` (it installs mani-skill --no-deps)"
        )
    path = Path(spec.submodule_search_locations[0]) / "assets/robots/panda/panda_v2.urdf"
    if not path.exists():
        raise FileNotFoundError(f"Panda URDF not found at {path}")
    return path


@dataclass
class SensorFrame:
    """What the robot senses in one frame (plus segmentation, used only by the simulated detector)."""

    index: int
    """Frame index in the run."""
    sim_time_s: float
    """Simulated time, seconds."""
    rgb: np.ndarray
    """(H, W, 3) uint8."""
    depth_m: np.ndarray
    """(H, W) float32 metres, 0 = no return (noise applied)."""
    segmentation: np.ndarray
    """(H, W) uint32 actor ids (detector input only)."""
    intrinsics: np.ndarray
    """(3, 3) float64."""
    world_from_camera_fk: np.ndarray
    """(4, 4) camera pose from forward kinematics of the robot's nominal model (URDF, nominal hand-eye)
    on the joint readings paired with the image (offset by the encoder errors, sampled the time offset
    before it: :mod:`objslam.calibration`), OpenCV axes. What a real robot knows; not the true pose."""
    world_from_camera_gt: np.ndarray
    """(4, 4) true camera pose from the renderer (evaluation only)."""
    qpos: np.ndarray
    """Joint readings paired with the image (9,)."""
    detector_view: DetectorView | None = None
    """What the simulated detector may know of the frame's true geometry (simulator side only)."""


def pose_to_matrix(p: sapien.Pose) -> np.ndarray:
    """4x4 homogeneous matrix of a SAPIEN pose."""
    return np.asarray(p.to_transformation_matrix(), dtype=np.float64)


class SimWorld:
    """A built scene with the robot and its hand camera."""

    def __init__(
        self,
        spec: SceneSpec,
        camera: CameraConfig,
        rng: np.random.Generator,
        *,
        grasp_physics: bool = False,
        textures: TextureConfig | None = None,
        arm_errors: ArmErrors | None = None,
        contact: ContactConfig | None = None,
    ) -> None:
        """``grasp_physics``: ManiSkill's settings for reliable grasps (contact offset 0.02 m, 25 solver
        position iterations, finger patch radius 0.1 m; see :data:`GRASP_PHYSICS`). Off for the
        mapping episodes, whose physics only settles objects. ``textures``: how surfaces are
        textured (default :class:`~objslam.textures.TextureConfig`). With the ``d435`` camera model
        the sensor unit's seed is drawn from ``rng``. ``arm_errors``: how this robot differs
        from its nominal model (:mod:`objslam.calibration`; ``None`` = not at all): the camera is mounted at
        the true hand-eye pose, the encoders read the true angles plus their offsets, and each frame's
        joint reading is the one sampled the time offset before the image. ``contact``: the objects'
        masses and friction and the fingertips' friction (default: :class:`ContactConfig`'s)."""
        camera.validate()
        self.contact = contact if contact is not None else ContactConfig()
        self.contact.validate()
        self.arm_errors = arm_errors if arm_errors is not None else ArmErrors.none()
        self._offsets = np.concatenate([self.arm_errors.joint_offsets_rad, np.zeros(2)])
        # (sim time, joint readings) of the last physics steps, for the time offset.
        self._reading_history: list[tuple[float, np.ndarray]] = []
        self.spec = spec
        self.camera_config = camera
        self.textures = textures if textures is not None else TextureConfig()
        self.rng = rng
        self.sensor = RgbdSensor(camera, int(rng.integers(1 << 62))) if camera.model == "d435" else None
        self.frame_index = 0
        self.last_timings_ms: dict[str, float] = {"render": 0.0, "sensor": 0.0}
        """Wall time of the last :meth:`render`, ms: ``render`` (scene update, picture, buffer
        read-back) and ``sensor`` (buffer conversion and the sensor model)."""
        self.sim_time_s = 0.0
        self.camera_path_length_m = 0.0
        """Length of the camera's path so far, metres (forward kinematics sampled at 30 Hz)."""
        self.last_move_path = "joint"
        """How the last :meth:`move_camera_to` moved: ``cartesian`` or ``joint`` (fallback)."""
        self._steps = 0
        self._arm_velocity = np.zeros(7)
        self._ik_cache: dict[bytes, np.ndarray] = {}
        self._last_camera_xyz: np.ndarray | None = None

        self.grasp_physics = grasp_physics
        shape_default, body_default = sapien.physx.get_shape_config(), sapien.physx.get_body_config()
        if grasp_physics:
            sapien.physx.set_shape_config(contact_offset=GRASP_PHYSICS["contact_offset_m"], rest_offset=0.0)
            sapien.physx.set_body_config(
                solver_position_iterations=GRASP_PHYSICS["solver_position_iterations"],
                solver_velocity_iterations=1,
            )
        try:
            scene = sapien.Scene()
            self._build(scene, spec, camera)
        finally:  # the configs are process-wide defaults: restore them for later worlds
            sapien.physx.set_shape_config(shape_default)
            sapien.physx.set_body_config(body_default)

    def _build(self, scene: sapien.Scene, spec: SceneSpec, camera: CameraConfig) -> None:
        scene.set_timestep(1.0 / PHYSICS_HZ)
        self.scene = scene
        scene.set_ambient_light([0.45, 0.45, 0.45])
        scene.add_directional_light([0.3, 0.2, -1.0], [0.75, 0.75, 0.75], shadow=False)
        scene.add_point_light([0.5, -0.6, 1.2], [0.6, 0.6, 0.6], shadow=False)
        scene.add_point_light([0.5, 0.6, 1.2], [0.6, 0.6, 0.6], shadow=False)
        self._build_table()
        self.object_actors: dict[int, sapien.Entity] = {}
        self._build_objects()
        self._build_robot()
        mount = sapien.Pose(list(camera.mount_xyz), list(camera.mount_wxyz))
        self.hand_from_sapien_camera = pose_to_matrix(mount)
        """The nominal camera mount (the model the estimator and the planner use)."""
        self._tcp_from_camera = np.linalg.inv(self._hand_from_tcp) @ self.hand_from_camera_cv()
        self._camera_from_tcp = np.linalg.inv(self._tcp_from_camera)
        # The renderer's camera sits at the true mount: nominal · hand-eye error (in OpenCV axes).
        cv = np.eye(4)
        cv[:3, :3] = SAPIEN_FROM_CV
        true_mount = self.hand_from_sapien_camera @ cv @ self.arm_errors.camera_from_true_camera @ np.linalg.inv(cv)
        self.camera = scene.add_mounted_camera(
            "hand_camera",
            self.hand.entity,
            sapien.Pose(true_mount[:3, 3].tolist(), quat_from_matrix(true_mount[:3, :3]).tolist()),
            camera.width,
            camera.height,
            math.radians(camera.fovy_deg),
            camera.near_m,
            camera.far_m,
        )
        self.intrinsics = camera.intrinsics()
        """The colour intrinsics the estimator assumes (frames carry these)."""
        k_render = self.intrinsics
        if self.sensor is not None:
            # The unit's true intrinsics differ from the assumed ones by its calibration error.
            k_render = self.sensor.true_intrinsics()
            self.camera.set_perspective_parameters(
                camera.near_m, camera.far_m, k_render[0, 0], k_render[1, 1], k_render[0, 2], k_render[1, 2], 0.0
            )
        k = np.asarray(self.camera.get_intrinsic_matrix(), dtype=np.float64)
        if not np.allclose(k, k_render, atol=1e-2):
            raise RuntimeError(f"camera intrinsics disagree with the config: {k} vs {k_render}")
        self.actor_to_object = {
            a.per_scene_id: (oid, spec.objects[oid].cls) for oid, a in self.object_actors.items()
        }
        self.robot_actor_ids = {link.entity.per_scene_id for link in self.robot.get_links()}
        # Segmentation id → whether the robot's: a table lookup per pixel (ids past the table's
        # last entry, which is False, read it).
        self._robot_id_table = np.zeros(max(self.robot_actor_ids, default=0) + 2, dtype=bool)
        self._robot_id_table[list(self.robot_actor_ids)] = True
        self._robot_ids = sorted(self.robot_actor_ids)
        self.finger_actor_ids = {link.entity.per_scene_id for link in self.fingers}
        # Let objects settle on the table.
        for _ in range(PHYSICS_HZ // 4):
            self._step()

    # ----- building -------------------------------------------------------------------------------
    def _build_table(self) -> None:
        t = self.spec.table
        mat = sapien.render.RenderMaterial()
        mat.base_color_texture = sapien.render.RenderTexture2D(
            table_texture(self.spec.seed, style=self.textures.style), "R8G8B8A8Unorm"
        )
        b = self.scene.create_actor_builder()
        half = [t.size[0] / 2, t.size[1] / 2, 0.025]
        b.add_box_collision(half_size=half)
        b.add_box_visual(half_size=half, material=mat)
        table = b.build_static(name="table")
        table.set_pose(sapien.Pose([t.center[0], t.center[1], -0.025]))
        self.table = table
        # A floor far below, so depth beyond the table edge has a return like a real room.
        fb = self.scene.create_actor_builder()
        fb.add_box_visual(
            half_size=[3, 3, 0.01], material=sapien.render.RenderMaterial(base_color=[0.35, 0.35, 0.38, 1])
        )
        floor = fb.build_static(name="floor")
        floor.set_pose(sapien.Pose([0, 0, -0.75]))

    def _build_objects(self) -> None:
        for o in self.spec.objects:
            if o.mesh is not None:
                self.object_actors[o.id] = self._build_mesh_object(o)
                continue
            mat = sapien.render.RenderMaterial()
            mat.base_color_texture = sapien.render.RenderTexture2D(
                object_texture(
                    self.spec.seed, o.id, style=self.textures.style, poor_fraction=self.textures.poor_fraction
                ), "R8G8B8A8Unorm"
            )
            mat.roughness = 0.8
            b = self.scene.create_actor_builder()
            density, mu = self.contact.object_physics(o.cls)
            phys = self.scene.create_physical_material(mu, mu, 0.0)
            if o.shape == "cuboid":
                b.add_box_collision(half_size=list(o.half_extents), material=phys, density=density)
                b.add_box_visual(half_size=list(o.half_extents), material=mat)
            else:
                # SAPIEN cylinders lie along x: rotate them upright.
                upright = sapien.Pose(q=[math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0])
                r, hz = o.half_extents[0], o.half_extents[2]
                b.add_cylinder_collision(pose=upright, radius=r, half_length=hz, material=phys, density=density)
                b.add_cylinder_visual(pose=upright, radius=r, half_length=hz, material=mat)
            actor = b.build(name=f"obj{o.id}_{o.cls}")
            cz = o.half_extents[2] + 1e-4
            q = [math.cos(o.yaw_rad / 2), 0.0, 0.0, math.sin(o.yaw_rad / 2)]
            actor.set_pose(sapien.Pose([o.position[0], o.position[1], cz], q))
            self.object_actors[o.id] = actor

    def _build_mesh_object(self, o: ObjectSpec) -> sapien.Entity:
        """A scanned mesh: its textured visual OBJs and its wheel collision OBJ (one convex shape
        per group), placed in the object's ground-truth frame (:mod:`objslam.meshes`), with the
        asset's mass (inertia of a solid box of the ground-truth size) and friction."""
        assert o.mesh is not None
        asset = get_asset(o.mesh.asset)
        t = o.mesh.object_from_mesh
        local = sapien.Pose(t[:3, 3].tolist(), quat_from_matrix(t[:3, :3]).tolist())
        k = [asset.unit_m * o.mesh.scale] * 3
        b = self.scene.create_actor_builder()
        phys = self.scene.create_physical_material(asset.friction, asset.friction, 0.0)
        b.add_multiple_convex_collisions_from_file(str(asset.path(asset.collision)), pose=local, scale=k, material=phys)
        for f in asset.visual:
            b.add_visual_from_file(str(asset.path(f)), pose=local, scale=k)
        ext = 2 * np.asarray(o.half_extents)
        inertia = asset.mass_kg / 12 * np.array(
            [ext[1] ** 2 + ext[2] ** 2, ext[0] ** 2 + ext[2] ** 2, ext[0] ** 2 + ext[1] ** 2]
        )
        b.set_mass_and_inertia(asset.mass_kg, sapien.Pose(), inertia.tolist())
        actor = b.build(name=f"obj{o.id}_{o.cls}_{asset.name}")
        q = [math.cos(o.yaw_rad / 2), 0.0, 0.0, math.sin(o.yaw_rad / 2)]
        actor.set_pose(sapien.Pose([o.position[0], o.position[1], o.half_extents[2] + 1e-4], q))
        return actor

    def _build_robot(self) -> None:
        loader = self.scene.create_urdf_loader()
        loader.fix_root_link = True
        for finger in ("panda_leftfinger", "panda_rightfinger"):
            loader.set_link_material(finger, self.contact.finger_friction, self.contact.finger_friction, 0.0)
        robot = loader.load(str(panda_urdf_path()))
        if self.grasp_physics:
            for link in robot.get_links():
                if link.name in ("panda_leftfinger", "panda_rightfinger"):
                    for shape in link.get_collision_shapes():
                        shape.set_patch_radius(GRASP_PHYSICS["patch_radius_m"])
                        shape.set_min_patch_radius(GRASP_PHYSICS["patch_radius_m"])
        robot.set_root_pose(sapien.Pose([0, 0, 0]))
        self.robot = robot
        self.joints = robot.get_active_joints()
        for j in self.joints[:7]:
            j.set_drive_properties(stiffness=ARM_STIFFNESS, damping=ARM_DAMPING, force_limit=ARM_FORCE_LIMIT)
        for j in self.joints[7:]:
            j.set_drive_properties(
                stiffness=GRIPPER_STIFFNESS, damping=GRIPPER_DAMPING, force_limit=GRIPPER_FORCE_LIMIT
            )
        links = robot.get_links()
        self.hand = next(link for link in links if link.name == "panda_hand")
        self.fingers = [link for link in links if link.name in ("panda_leftfinger", "panda_rightfinger")]
        self.qlimits = np.asarray(robot.get_qlimits(), dtype=np.float64)
        # Kinematics, IK and collision checks of every camera move go through the core's planner
        # (the same one that plans the grasps), against the table, the arm itself and the obstacles
        # of :meth:`set_obstacles` (the current map's objects during an episode).
        self.planner = _native.Planner(str(panda_urdf_path()))
        q0 = np.zeros(7)
        self._hand_from_tcp = np.linalg.inv(self.planner.link_poses(q0)["panda_hand"]) @ self.planner.forward_tcp(q0)
        self.obstacles_json = "[]"
        self.set_qpos(READY_QPOS)

    # ----- state ----------------------------------------------------------------------------------
    def set_qpos(self, q: np.ndarray) -> None:
        """Teleport the arm to joint readings ``q`` (used once at start) and hold it there."""
        q_true = np.asarray(q, dtype=np.float64) - self._offsets[: len(q)]
        self.robot.set_qpos(q_true)
        self.robot.set_qvel(np.zeros_like(q_true))
        self._set_targets(q)
        self._reading_history = [(self.sim_time_s, self.qpos())]

    def _set_targets(self, q: np.ndarray) -> None:
        for j, t, off in zip(self.joints, q, self._offsets):
            j.set_drive_target(float(t - off))
            j.set_drive_velocity_target(0.0)

    def _true_qpos(self) -> np.ndarray:
        """The simulated joints' true positions (physics only; the robot senses :meth:`qpos`)."""
        return np.asarray(self.robot.get_qpos(), dtype=np.float64)

    def qpos(self) -> np.ndarray:
        """Joint readings now: the true positions plus the encoder offsets (``arm_errors``). Every
        command is in readings: the joint controller servos them (:meth:`set_arm_targets`)."""
        return self._true_qpos() + self._offsets

    def qpos_delayed(self) -> np.ndarray:
        """The joint readings sampled ``arm_errors.time_offset_s`` ago (linear between physics steps;
        the oldest kept when the history is shorter): what a frame rendered now is paired with."""
        dt = self.arm_errors.time_offset_s
        if dt <= 0.0 or not self._reading_history:
            return self.qpos()
        t = self.sim_time_s - dt
        hist = self._reading_history
        if t <= hist[0][0]:
            return hist[0][1].copy()
        for (t0, q0), (t1, q1) in zip(reversed(hist[:-1]), reversed(hist[1:])):
            if t0 <= t <= t1:
                s = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
                return (1.0 - s) * q0 + s * q1
        return hist[-1][1].copy()

    def _step(self) -> None:
        self.robot.set_qf(self.robot.compute_passive_force(gravity=True, coriolis_and_centrifugal=True))
        before = self.robot.get_qpos()
        self.scene.step()
        self._arm_velocity = (np.asarray(self.robot.get_qpos(), dtype=np.float64)[:7] - before[:7]) * PHYSICS_HZ
        self.sim_time_s += 1.0 / PHYSICS_HZ
        self._steps += 1
        if self.arm_errors.time_offset_s > 0.0:
            self._reading_history.append((self.sim_time_s, self.qpos()))
            keep = int(self.arm_errors.time_offset_s * PHYSICS_HZ) + 3
            if len(self._reading_history) > keep:
                del self._reading_history[: len(self._reading_history) - keep]
        if self._steps % PATH_SAMPLE_STEPS == 0:
            xyz = self.world_from_camera_fk(self.qpos())[:3, 3]
            if self._last_camera_xyz is not None:
                self.camera_path_length_m += float(np.linalg.norm(xyz - self._last_camera_xyz))
            self._last_camera_xyz = xyz

    def arm_targets(self) -> np.ndarray:
        """The arm's seven commanded joint positions, in readings (what the controller was told)."""
        return np.array([float(np.ravel(j.get_drive_target())[0]) for j in self.joints[:7]]) + self._offsets[:7]

    def arm_drive_torques(self) -> np.ndarray:
        """The arm's seven joint torques from its PD drives now, N·m: stiffness × position error +
        damping × velocity error, within the force limit (what the joint controller commands; gravity
        is compensated separately, :meth:`_step`). The velocity is the joints' motion over the last
        physics step: PhysX's reported joint velocity stays at up to 0.03 rad/s with the arm at rest
        under a steady load (its solver's correction, not motion), and with it a 20 N force at the
        TCP came out as 13 N (at rest, position errors alone give it back)."""
        arm = self.joints[:7]
        target = np.array([float(np.ravel(j.get_drive_target())[0]) for j in arm])
        velocity_target = np.array([float(np.ravel(j.get_drive_velocity_target())[0]) for j in arm])
        tau = ARM_STIFFNESS * (target - self._true_qpos()[:7]) + ARM_DAMPING * (velocity_target - self._arm_velocity)
        return np.clip(tau, -ARM_FORCE_LIMIT, ARM_FORCE_LIMIT)

    def external_wrench(self) -> np.ndarray:
        """Estimated wrench on the hand from outside the robot, expressed at the TCP in world axes:
        ``[fx, fy, fz, mx, my, mz]`` (N, N·m), as a Panda's ``O_F_ext_hat_K`` gives it: the drive
        torques balance gravity-compensated statics, ``Jᵀ w = −τ``, solved by least squares with the
        TCP's geometric Jacobian (the core planner's kinematics, ``Planner.tcp_jacobian``). At rest with joint
        friction off it gives back a force applied at the TCP within 1.5 N (``tests/test_place_feel.py``).
        Not modelled: the arm's inertia (accelerations show as wrench) and the joints' friction
        (PhysX's, proportional to the joint loads: 17-66 N of apparent upward force during a
        put-down descent, up to 139 N held by static friction after it; ``PlaceConfig.feel_support``),
        so it is read as a change over a short window, not as a level
        (:meth:`~objslam.place.Placer.feel_down`)."""
        jac = self.planner.tcp_jacobian(self.qpos()[:7])
        w, *_ = np.linalg.lstsq(jac.T, -self.arm_drive_torques(), rcond=None)
        return w

    # ----- kinematics -----------------------------------------------------------------------------
    def hand_from_camera_cv(self) -> np.ndarray:
        """``panda_hand_from_camera`` of the nominal model (hand-eye calibration), OpenCV camera axes."""
        m = self.hand_from_sapien_camera.copy()
        m[:3, :3] = m[:3, :3] @ SAPIEN_FROM_CV
        return m

    def world_from_camera_fk(self, q: np.ndarray) -> np.ndarray:
        """Camera pose (OpenCV axes) from forward kinematics of joint readings ``q`` on the nominal
        model (the core's chain from the URDF and the nominal hand-eye transform)."""
        q7 = np.clip(np.asarray(q, dtype=np.float64)[:7], self.qlimits[:7, 0], self.qlimits[:7, 1])
        return self.planner.forward_tcp(q7) @ self._tcp_from_camera

    def set_obstacles(self, objects_json: str) -> None:
        """The objects the arm must keep clear of when moving the camera: a JSON list of map
        object records (with ``"geometry"``) or of ObjectGeometry dicts. Forgets cached IK."""
        objs = json.loads(objects_json)
        self.obstacles_json = json.dumps([o.get("geometry", o) for o in objs])
        self._ik_cache.clear()

    def world_from_camera_gt(self) -> np.ndarray:
        """True camera pose from the renderer (OpenCV axes)."""
        world_from_gl = np.asarray(self.camera.get_model_matrix(), dtype=np.float64)
        return world_from_gl @ np.diag([1.0, -1.0, -1.0, 1.0])

    def _ik_from(self, world_from_camera: np.ndarray, seed: np.ndarray, restarts: bool = False) -> np.ndarray | None:
        """Collision-free IK (core planner) for a camera pose from ``seed`` (``restarts``: also from
        the planner's random restarts); the full joint vector with the gripper open, or ``None``."""
        lo, hi = self.qlimits[:7, 0], self.qlimits[:7, 1]
        q7 = self.planner.inverse_tcp(
            world_from_camera @ self._camera_from_tcp, np.clip(np.asarray(seed, dtype=np.float64)[:7], lo, hi),
            self.obstacles_json, restarts,
        )
        if q7 is None:
            return None
        return np.concatenate([np.asarray(q7, dtype=np.float64), [GRIPPER_OPEN_M, GRIPPER_OPEN_M]])

    def camera_path(
        self, q0: np.ndarray, world_from_camera: np.ndarray, q_goal: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Joint waypoints (k, 9) from ``q0`` that keep the camera on the scene on its way to
        ``world_from_camera`` (:class:`~objslam.camera_path.CameraPaths`, with this world's IK,
        forward kinematics, obstacles and table); ``None`` when no such path is found."""
        return CameraPaths(
            ik=self._ik_from,
            fk=self.world_from_camera_fk,
            path_is_free=lambda w: bool(self.planner.path_is_free(w, self.obstacles_json)),
            table_center_xy=(float(self.spec.table.center[0]), float(self.spec.table.center[1])),
        ).path(q0, world_from_camera, q_goal)

    def solve_ik(self, world_from_camera: np.ndarray, what: str = "view") -> np.ndarray:
        """Joint positions placing the camera at ``world_from_camera`` (OpenCV axes); tries the current
        configuration then a few deterministic seeds. Raises :class:`UnreachablePoseError`."""
        seeds = [self.qpos(), READY_QPOS.copy()]
        for k in range(4):
            s = READY_QPOS.copy()
            s[0] = [-0.8, 0.8, -0.4, 0.4][k]
            seeds.append(s)
        for seed in seeds:
            q = self._ik_from(world_from_camera, seed)
            if q is not None:
                return q
        q = self._ik_from(world_from_camera, self.qpos(), restarts=True)
        if q is not None:
            return q
        raise UnreachablePoseError(what, world_from_camera[:3, 3])

    def is_reachable(self, world_from_camera: np.ndarray) -> bool:
        """Whether IK reaches a camera pose (the solution is kept for the move that follows)."""
        key = np.round(np.asarray(world_from_camera, dtype=np.float64), 9).tobytes()
        if key in self._ik_cache:
            return True
        try:
            q = self.solve_ik(world_from_camera, "candidate")
        except UnreachablePoseError:
            return False
        if len(self._ik_cache) > 256:
            self._ik_cache.clear()
        self._ik_cache[key] = q
        return True

    # ----- sensing --------------------------------------------------------------------------------
    def render(self) -> SensorFrame:
        """Render the hand camera now and apply the sensor model (:attr:`CameraConfig.model`).
        :attr:`last_timings_ms` says how long each part took."""
        t0 = time.perf_counter()
        self.scene.update_render()
        self.camera.take_picture()
        rgba = self.camera.get_picture("Color")
        pos = self.camera.get_picture("Position")
        seg = self.camera.get_picture("Segmentation")[..., 1].astype(np.uint32)
        normals_gl = self.camera.get_picture("Normal") if self.sensor is not None else None
        t1 = time.perf_counter()
        q = self.qpos_delayed()
        if self.sensor is None or normals_gl is None:
            robot = self._robot_id_table.take(seg, mode="clip") if self.camera_config.mask_robot_depth else None
            # [0, 1] to 8 bits, rounded: one float copy, scaled, clipped and offset in place.
            scaled = rgba[..., :3] * np.float32(255.0)
            np.clip(scaled, 0.0, 255.0, out=scaled)
            scaled += np.float32(0.5)
            rgb = scaled.astype(np.uint8)
            depth = np.where(pos[..., 3] < 1, -pos[..., 2], 0.0).astype(np.float32)
            depth[depth > self.camera_config.far_m] = 0.0
            if robot is not None:
                depth[robot] = 0.0
            depth = self.camera_config.depth_noise.apply(depth, self.rng)
        else:
            # The renderer's own buffers go to the sensor model, which reads them in OpenGL axes;
            # the robot's own pixels (the finger tips), by their segmentation ids, have no surface.
            dropped = self._robot_ids if self.camera_config.mask_robot_depth else ()
            rgb, depth = self.sensor.apply(
                pos,
                normals_gl,
                rgba,
                frame_index=self.frame_index,
                camera_end_from_start=self._exposure_motion(self.qpos()),
                segmentation=seg,
                dropped_ids=dropped,
            )
        self.last_timings_ms = {"render": (t1 - t0) * 1e3, "sensor": (time.perf_counter() - t1) * 1e3}
        world_from_camera_gt = self.world_from_camera_gt()
        frame = SensorFrame(
            index=self.frame_index,
            sim_time_s=self.sim_time_s,
            rgb=rgb,
            depth_m=depth,
            segmentation=seg,
            intrinsics=self.intrinsics,
            world_from_camera_fk=self.world_from_camera_fk(q),
            world_from_camera_gt=world_from_camera_gt,
            qpos=q,
            detector_view=self._detector_view(world_from_camera_gt),
        )
        self.frame_index += 1
        return frame

    def _exposure_motion(self, q: np.ndarray) -> np.ndarray | None:
        """``camera_end_from_start`` over the colour exposure centred on now, from the arm's joint
        velocities over the last physics step (None at rest or without exposure)."""
        t = self.camera_config.colour.exposure_s
        v = self._arm_velocity
        if t <= 0 or float(np.max(np.abs(v))) < 1e-4:
            return None
        q0, q1 = q.copy(), q.copy()
        q0[:7] -= v * t / 2
        q1[:7] += v * t / 2
        return np.linalg.inv(self.world_from_camera_fk(q1)) @ self.world_from_camera_fk(q0)

    def _detector_view(self, world_from_camera_gt: np.ndarray) -> DetectorView:
        """The frame's true geometry as the simulated detector may use it (never the estimator)."""
        gt = self.ground_truth()
        return DetectorView(
            world_from_camera=world_from_camera_gt,
            intrinsics=self.sensor.true_intrinsics() if self.sensor is not None else self.intrinsics,
            object_centres={a: gt[oid][0] for a, (oid, _) in self.actor_to_object.items()},
            table_actor_id=self.table.per_scene_id,
            table_center=tuple(self.spec.table.center),
            table_size=tuple(self.spec.table.size),
        )

    def ground_truth(self) -> dict[int, tuple[np.ndarray, float]]:
        """Current object poses: id → (centre (3,), yaw rad). Evaluation only."""
        out = {}
        for oid, actor in self.object_actors.items():
            p = actor.entity_pose if hasattr(actor, "entity_pose") else actor.get_pose()
            w, x, y, z = p.q
            yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
            out[oid] = (np.asarray(p.p, dtype=np.float64), yaw)
        return out

    # ----- acting ---------------------------------------------------------------------------------
    def move_camera_to(
        self,
        world_from_camera: np.ndarray,
        *,
        frame_rate_hz: float,
        max_joint_speed: float = 1.0,
        settle_s: float = 0.3,
        what: str = "view",
        path: str = "cartesian",
    ) -> Iterator[SensorFrame]:
        """Move the camera to a pose: collision-free IK, then (``path="cartesian"``) the joint
        waypoints of :meth:`camera_path` or (``"joint"``, or when no free Cartesian path is found)
        the core planner's collision-free joint path, executed by :meth:`move_along`
        (:attr:`last_move_path` says which); yields a rendered frame every ``1 / frame_rate_hz``
        simulated seconds and one after settling. Raises :class:`UnreachablePoseError` before
        moving if IK fails."""
        if frame_rate_hz <= 0:
            raise ValueError("frame_rate_hz: must be > 0")
        key = np.round(np.asarray(world_from_camera, dtype=np.float64), 9).tobytes()
        q_goal = self._ik_cache.pop(key, None)
        if q_goal is None:
            q_goal = self.solve_ik(world_from_camera, what)
        waypoints = self.camera_path(self.qpos(), world_from_camera, q_goal) if path == "cartesian" else None
        self.last_move_path = "joint" if waypoints is None else "cartesian"
        if waypoints is None:
            # The core planner's collision-free joint path (a straight line when free, else RRT-Connect).
            lo, hi = self.qlimits[:7, 0], self.qlimits[:7, 1]
            r = self.planner.plan_to_joints(np.clip(self.qpos()[:7], lo, hi), q_goal[:7], self.obstacles_json)
            if not r["ok"]:
                raise UnreachablePoseError(what, world_from_camera[:3, 3])
            w = np.asarray(r["waypoints"], dtype=np.float64)
            waypoints = np.concatenate([w, np.full((len(w), 2), GRIPPER_OPEN_M)], axis=1)
            waypoints[0] = self.qpos()
        yield from self.move_along(
            waypoints,
            frame_rate_hz=frame_rate_hz,
            max_joint_speed=max_joint_speed,
            settle_s=settle_s,
            stop_at_waypoints=self.last_move_path == "joint",
        )

    def set_arm_targets(self, q_arm: np.ndarray, finger_m: float, dq_arm: np.ndarray | None = None) -> None:
        """PD drive targets: arm joint readings ``q_arm`` (7) with velocity feed-forward ``dq_arm`` (zero
        when ``None``), both fingers at ``finger_m``."""
        for i, j in enumerate(self.joints):
            if i < 7:
                j.set_drive_target(float(q_arm[i] - self._offsets[i]))
                j.set_drive_velocity_target(float(dq_arm[i]) if dq_arm is not None else 0.0)
            else:
                j.set_drive_target(float(finger_m))

    def track(self, traj: dict[str, Any], finger_m: float) -> Iterator[int]:
        """Track a sampled joint trajectory of the core planner (``times_s``, ``positions``,
        ``velocities``, ``duration_s``) with the PD drives: the samples interpolated linearly at the
        physics rate, velocity feed-forward, fingers at ``finger_m``. Yields the number of physics
        steps taken after each step; leaves the last sample as the target (the caller settles)."""
        t = np.asarray(traj["times_s"], dtype=np.float64)
        pos = np.asarray(traj["positions"], dtype=np.float64)
        vel = np.asarray(traj["velocities"], dtype=np.float64)
        n = math.ceil(float(traj["duration_s"]) * PHYSICS_HZ)
        tk = np.arange(1, n + 1) / PHYSICS_HZ
        q = np.stack([np.interp(tk, t, pos[:, i]) for i in range(7)], axis=1)
        dq = np.stack([np.interp(tk, t, vel[:, i]) for i in range(7)], axis=1)
        for k in range(n):
            self.set_arm_targets(q[k], finger_m, dq[k])
            self._step()
            yield k + 1
        self.set_arm_targets(pos[-1], finger_m)

    def move_along(
        self,
        waypoints: np.ndarray,
        *,
        frame_rate_hz: float,
        max_joint_speed: float = 1.0,
        settle_s: float = 0.3,
        stop_at_waypoints: bool = False,
    ) -> Iterator[SensorFrame]:
        """Execute a joint path (k ≥ 2 waypoints of 9 joints, the first the current configuration,
        the fingers held at the last waypoint's) timed by the core planner's Ruckig trajectories
        under its jerk and acceleration limits, every joint's speed capped at ``max_joint_speed``:
        through the waypoints without stopping (``Planner.time_parameterize_path``, for dense
        paths such as a Cartesian camera path) or, with ``stop_at_waypoints``, rest-to-rest from
        waypoint to waypoint (a sparse path whose corners matter: RRT-Connect's). Yields a frame
        every ``1 / frame_rate_hz`` simulated seconds and one after settling at the last waypoint."""
        w = np.asarray(waypoints, dtype=np.float64)
        q7 = np.clip(w[:, :7], self.qlimits[:7, 0], self.qlimits[:7, 1])
        pieces = [q7[i : i + 2] for i in range(len(q7) - 1)] if stop_at_waypoints else [q7]
        finger_m = float(w[-1, 7])
        steps_per_frame = max(1, round(PHYSICS_HZ / frame_rate_hz))
        steps = 0
        for piece in pieces:
            traj = self.planner.time_parameterize_path(piece, max_joint_speed)
            for _ in self.track(traj, finger_m):
                steps += 1
                if steps % steps_per_frame == 0:
                    yield self.render()
        q_goal = q7[-1]
        self.set_arm_targets(q_goal, finger_m)
        for _ in range(int(settle_s * PHYSICS_HZ)):
            self._step()
        err = float(np.max(np.abs(self.qpos()[:7] - q_goal)))
        if err > 0.02:
            raise MotionError(f"arm stopped {err:.3f} rad from its joint target")
        yield self.render()


FrameCallback = Callable[[SensorFrame], None]
