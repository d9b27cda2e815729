"""Camera paths between views that keep the scene in view: the straight line between two camera
poses with the orientation slerped (then lifted, then through a hub view), every waypoint a
collision-free IK solution and every leg checked. Used by :meth:`objslam.world.SimWorld.camera_path`;
the world supplies the IK, forward kinematics, collision check and table."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


def look_at(eye: np.ndarray, target: np.ndarray, up_hint: np.ndarray | None = None) -> np.ndarray:
    """``world_from_camera`` (OpenCV axes) at ``eye`` looking at ``target``. The image's "up"
    (−y) is aligned with ``up_hint`` projected onto the image plane (default: world +z, or world +x
    when looking straight down — the image top then points away from the robot)."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    n = np.linalg.norm(z)
    if not np.isfinite(n) or n < 1e-9:
        raise ValueError("look_at: eye and target coincide")
    z /= n
    up = np.array([0.0, 0.0, 1.0]) if up_hint is None else np.asarray(up_hint, float)
    if abs(float(np.dot(up, z))) > 0.95:
        up = np.array([1.0, 0.0, 0.0])
    y = -(up - np.dot(up, z) * z)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, eye
    return m


@dataclass
class CameraPaths:
    """Camera-path planning for one arm state (its obstacles as they are now)."""

    ik: Callable[[np.ndarray, np.ndarray], np.ndarray | None]
    """Collision-free IK of a camera pose from a seed joint vector: the full joint vector, or None."""
    fk: Callable[[np.ndarray], np.ndarray]
    """Camera pose (4x4, OpenCV axes) of a joint vector."""
    path_is_free: Callable[[np.ndarray], bool]
    """Whether a (k, 7) arm joint path is collision-free, segment by segment."""
    table_center_xy: tuple[float, float]
    """Table-top centre (the hub views look at it), metres."""

    def path(
        self, q0: np.ndarray, world_from_camera: np.ndarray, q_goal: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Joint waypoints (k, 9) from ``q0`` that keep the camera looking at the scene on its way
        to ``world_from_camera`` (a joint-space move can swing it off the table, and the tracker
        needs the scene in view while the arm moves). Tried in order: the straight line between the
        two camera positions with the orientation slerped, then the same line lifted by 10 and
        20 cm at its middle, then two such legs through a hub view (above the midpoint of the two
        views, then above the table centre, 0.5 m over the table, looking at its centre).
        With ``q_goal`` (an IK solution of the goal), the camera's roll about its optical axis is
        not slerped but follows the wrist joint from its start to its goal value (the optical axis
        is the last joint's axis): the slerp's shortest roll can need the wrist beyond its limits,
        and roll does not change what the camera sees. Every waypoint is collision-free IK and every
        leg is checked segment by segment (core planner). ``None`` when none works."""
        q7_end = None if q_goal is None else float(q_goal[6])
        direct = self._line(q0, world_from_camera, q7_end)
        if direct is not None:
            return direct
        t0 = self.fk(q0)
        t1 = np.asarray(world_from_camera, dtype=np.float64)
        table = np.array([*self.table_center_xy, 0.0])
        mid = (t0[:3, 3] + t1[:3, 3]) / 2.0
        hubs = [
            np.array([mid[0], mid[1], max(t0[2, 3], t1[2, 3], 0.35) + 0.1]),
            table + np.array([0.0, 0.0, 0.5]),
        ]
        for eye in hubs:
            hub = look_at(eye, table)
            first = self._line(q0, hub)
            if first is None:
                continue
            second = self._line(first[-1], world_from_camera, q7_end)
            if second is not None:
                return np.concatenate([first, second[1:]])
        return None

    def _line(
        self, q0: np.ndarray, world_from_camera: np.ndarray, q7_end: float | None = None
    ) -> np.ndarray | None:
        """One leg of :meth:`path`: the straight (then lifted) line with the orientation
        slerped, waypoints every 2 cm / 5° at most, each solved by IK seeded with the previous one
        (with ``q7_end``: then turned about the optical axis so the wrist joint moves linearly from
        its start value to ``q7_end``); ``None`` when a waypoint is unreachable, the arm would jump
        (> 0.35 rad on a joint) or the last waypoint's roll misses the goal by > 3°."""
        t0 = self.fk(q0)
        t1 = np.asarray(world_from_camera, dtype=np.float64)
        a, b = quat_from_matrix(t0[:3, :3]), quat_from_matrix(t1[:3, :3])
        if float(np.dot(a, b)) < 0:
            b = -b
        angle = 2.0 * math.acos(min(1.0, abs(float(np.dot(a, b)))))
        dist = float(np.linalg.norm(t1[:3, 3] - t0[:3, 3]))
        n = max(4, math.ceil(dist / 0.02), math.ceil(math.degrees(angle) / 5.0))
        f0, f1 = _fixation_point(t0), _fixation_point(t1)
        for lift in (0.0, 0.1, 0.2):
            path = [np.asarray(q0, dtype=np.float64).copy()]
            for k in range(1, n + 1):
                s = k / n
                t = np.eye(4)
                t[:3, 3] = (1 - s) * t0[:3, 3] + s * t1[:3, 3]
                t[2, 3] += lift * math.sin(math.pi * s)
                # Slerped orientation, turned (minimally) to aim at the interpolated fixation
                # point: the camera keeps looking where the two views look.
                t[:3, :3] = _aim(_matrix_from_quat(_slerp(a, b, s)), (1 - s) * f0 + s * f1 - t[:3, 3])
                q = (
                    self.ik(t, path[-1])
                    if q7_end is None
                    else self._ik_roll(t, path[-1], (1 - s) * q0[6] + s * q7_end)
                )
                if q is None or float(np.max(np.abs(q[:7] - path[-1][:7]))) > 0.35:
                    break
                path.append(q)
            else:
                if q7_end is not None and abs(path[-1][6] - q7_end) > math.radians(3.0):
                    return None
                if not self.path_is_free(np.array(path)[:, :7]):
                    continue
                return np.array(path)
        return None

    def _ik_roll(self, world_from_camera: np.ndarray, seed: np.ndarray, q7: float) -> np.ndarray | None:
        """IK for a camera pose up to its roll about the optical axis, chosen so the wrist joint
        ends near ``q7`` (two corrections: the optical axis is the wrist's axis up to the camera's
        mounting offset). The first solve asks for the roll the seed's camera has plus the wanted
        wrist change, so it starts next to the seed whatever roll the target was given."""

        def turned(t: np.ndarray, phi: float) -> np.ndarray:
            c, s = math.cos(phi), math.sin(phi)
            rz = np.eye(4)
            rz[:2, :2] = [[c, -s], [s, c]]
            return t @ rz

        t = np.asarray(world_from_camera, dtype=np.float64)
        z = t[:3, 2]
        x_seed = self.fk(seed)[:3, 0]
        x_seed = x_seed - float(np.dot(x_seed, z)) * z
        if float(np.linalg.norm(x_seed)) > 1e-6:
            x_seed /= np.linalg.norm(x_seed)
            t = turned(t, math.atan2(float(np.dot(np.cross(t[:3, 0], x_seed), z)), float(np.dot(t[:3, 0], x_seed))))
        t = turned(t, q7 - float(seed[6]))
        q = self.ik(t, seed)
        for _ in range(2):
            if q is None:
                return None
            phi = q7 - float(q[6])
            if abs(phi) < 1e-3:
                break
            t = turned(t, phi)
            q = self.ik(t, q)
        return q


def _fixation_point(world_from_camera: np.ndarray) -> np.ndarray:
    """Where a view looks: its optical axis meets the table plane (z = 0) when it points down
    by more than ~10°, else the point 0.4 m along the axis."""
    eye, axis = world_from_camera[:3, 3], world_from_camera[:3, 2]
    if axis[2] < -0.17 and eye[2] > 0:
        return eye + axis * (eye[2] / -axis[2])
    return eye + 0.4 * axis


def _aim(r: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """``r`` rotated by the smallest rotation taking its z axis (the optical axis) to ``direction``."""
    n = float(np.linalg.norm(direction))
    if n < 1e-9:
        return r
    z, d = r[:, 2], direction / n
    v, c = np.cross(z, d), float(np.dot(z, d))
    if c < -0.999:
        return r
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return (np.eye(3) + k + k @ k / (1.0 + c)) @ r


def quat_from_matrix(r: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix (Shepperd's method, float64: SAPIEN's
    ``Pose`` conversion is float32 and would move every waypoint, and so the recorded runs, by ~1e-7)."""
    tr = float(np.trace(r))
    if tr > 0:
        k = math.sqrt(tr + 1.0) * 2
        q = np.array([0.25 * k, (r[2, 1] - r[1, 2]) / k, (r[0, 2] - r[2, 0]) / k, (r[1, 0] - r[0, 1]) / k])
    else:
        i = int(np.argmax(np.diag(r)))
        j, m = (i + 1) % 3, (i + 2) % 3
        k = math.sqrt(1.0 + r[i, i] - r[j, j] - r[m, m]) * 2
        q = np.zeros(4)
        q[0] = (r[m, j] - r[j, m]) / k
        q[1 + i] = 0.25 * k
        q[1 + j] = (r[j, i] + r[i, j]) / k
        q[1 + m] = (r[m, i] + r[i, m]) / k
    return q / np.linalg.norm(q)


def _matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _slerp(a: np.ndarray, b: np.ndarray, s: float) -> np.ndarray:
    """Spherical linear interpolation between unit quaternions on the same hemisphere."""
    dot = min(1.0, float(np.dot(a, b)))
    if dot > 0.9995:
        q = a + s * (b - a)
        return q / np.linalg.norm(q)
    th = math.acos(dot)
    return (math.sin((1 - s) * th) * a + math.sin(s * th) * b) / math.sin(th)
