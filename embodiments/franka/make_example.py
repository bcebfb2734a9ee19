"""Regenerate the Franka plugin's bundled example trajectory and camera.

    python embodiments/franka/make_example.py

A reach–grasp–lift–place by smooth (smoothstep) interpolation between joint
keyframes, 15 fps, gripper closing on the object and opening to release it,
and a static camera in front-right of the robot that sees the whole arm.
The keyframes were found once by inverse kinematics for the TCP positions in
the comments (hand pointing down) and are written out here so the script has
no solver dependency. Output: ``assets/example_trajectory.npz`` and
``assets/example_camera.json``, and the same for ``franka_robotiq``
(``assets/example_trajectory_robotiq.npz``, gripper as DROID's 0 open .. 1
closed, and ``assets/example_camera_robotiq.json``).
"""

from pathlib import Path

import numpy as np

from oscar_core import Camera, Intrinsics, Trajectory, interpolate_keyframes, look_at, save_camera, save_trajectory

ASSETS = Path(__file__).resolve().parent / "assets"
JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))
FPS = 15.0


def main():
    # 7 joints (rad) + finger width (m): 0.08 open .. 0.025 holding a 2.5 cm object
    keys = np.array(
        [
            [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785, 0.080],  # ready pose, open
            [0.022, 0.123, -0.206, -2.127, 0.032, 2.246, 0.785, 0.080],  # above the object, TCP (0.55, -0.10, 0.25)
            [-0.019, 0.401, -0.155, -2.187, 0.113, 2.580, 0.785, 0.080],  # descend, TCP (0.55, -0.10, 0.10)
            [-0.019, 0.401, -0.155, -2.187, 0.113, 2.580, 0.785, 0.025],  # grasp
            [0.319, -0.145, 0.177, -2.046, 0.027, 1.905, 0.785, 0.025],  # lift and carry, TCP (0.45, 0.25, 0.40)
            [0.510, 0.309, 0.330, -2.286, -0.182, 2.569, 0.785, 0.025],  # place, TCP (0.35, 0.40, 0.12)
            [0.510, 0.309, 0.330, -2.286, -0.182, 2.569, 0.785, 0.080],  # release
            [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785, 0.080],  # back to ready
        ]
    )
    q = interpolate_keyframes(keys, 16)  # 7 segments * 16 + 1 = 113 frames
    traj = Trajectory(
        JOINTS, q[:, :7], fps=FPS, gripper=q[:, 7:8], gripper_names=("gripper",), timestamps=np.arange(len(q)) / FPS
    )
    save_trajectory(traj, ASSETS / "example_trajectory.npz")
    # a ZED-2-like 1280x720 camera, right of the robot, looking across the workspace
    cam = Camera(
        Intrinsics(fx=1400.0, fy=1400.0, cx=639.5, cy=359.5, width=1280, height=720),
        extrinsic=look_at((1.05, -1.50, 0.85), (0.28, 0.05, 0.33)),
        embodiment="franka",
    )
    save_camera(cam, ASSETS / "example_camera.json")
    # the same motion for franka_robotiq (a Robotiq 2F-85, DROID's signal: 0 open .. 1 closed)
    # the Robotiq's 85 mm stroke holds the 2.5 cm object at 1 - 25/85
    position = np.clip(1.0 - q[:, 7:8] * 1000.0 / 85.0, 0.0, 1.0)
    save_trajectory(traj.replace(gripper=position), ASSETS / "example_trajectory_robotiq.npz")
    save_camera(
        Camera(cam.intrinsics, cam.extrinsic, embodiment="franka_robotiq"), ASSETS / "example_camera_robotiq.json"
    )
    print(f"wrote {len(q)} frames and a camera to {ASSETS} (franka and franka_robotiq)")


if __name__ == "__main__":
    main()
