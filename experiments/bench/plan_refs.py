"""Reference timing for the `plan` benches: SAPIEN's pinocchio IK on the same 16 top-down TCP
targets as `core/benches/plan.rs` (`ik_targets`), from the same initial configuration.

Prints {"entries": {"ik_pinocchio": {"median_ms": ...}}} (median over all solves).
Run: /work/main/.venv/bin/python experiments/bench/plan_refs.py
"""

import importlib.util
import json
import os
import time

import numpy as np
import sapien

Q_READY = [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, np.pi / 4]
REPEATS = 20


def targets():
    out = []
    for k in range(16):
        x, y, z = 0.35 + 0.1 * (k % 4), -0.3 + 0.2 * (k // 4), 0.15
        yaw = -0.6 + 0.08 * k
        # top_down_pose: Rz(yaw) * Rx(pi), quaternion wxyz.
        out.append(sapien.Pose([x, y, z], [0.0, np.cos(yaw / 2), np.sin(yaw / 2), 0.0]))
    return out


def main():
    base = importlib.util.find_spec("mani_skill").submodule_search_locations[0]
    urdf = os.path.join(base, "assets/robots/panda/panda_v2.urdf")
    scene = sapien.Scene()
    loader = scene.create_urdf_loader()
    loader.fix_root_link = True
    robot = loader.load(urdf)
    pm = robot.create_pinocchio_model()
    tcp = [link.name for link in robot.get_links()].index("panda_hand_tcp")
    q0 = np.array(Q_READY + [0.04, 0.04])
    times = []
    for _ in range(REPEATS):
        for t in targets():
            start = time.perf_counter()
            pm.compute_inverse_kinematics(tcp, t, initial_qpos=q0, active_qmask=[1] * 7 + [0, 0], max_iterations=200)
            times.append((time.perf_counter() - start) * 1e3)
    print(json.dumps({"entries": {"ik_pinocchio": {"median_ms": float(np.median(times))}}}))


if __name__ == "__main__":
    main()
