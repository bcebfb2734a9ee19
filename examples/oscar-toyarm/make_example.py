"""Regenerate the toy arm's bundled example trajectory and camera.

    python examples/oscar-toyarm/make_example.py

A reach–grasp–lift made by smooth interpolation between joint keyframes, and
a static camera looking at the arm from the front-right. Output goes to
``oscar_toyarm/assets/``.
"""

from pathlib import Path

import numpy as np

from oscar_core import Camera, Intrinsics, Trajectory, interpolate_keyframes, look_at, save_camera, save_trajectory

ASSETS = Path(__file__).parent / "oscar_toyarm" / "assets"
JOINTS = ("base_yaw", "shoulder", "elbow", "wrist_pitch", "finger_left")


def main():
    # joints: yaw, shoulder, elbow, wrist, finger opening (m per finger); gripper width = 2 * finger
    keys = np.array(
        [
            [0.0, 0.0, 0.0, 0.0, 0.035],  # home, open
            [0.6, 0.7, 1.2, 0.9, 0.035],  # reach over the object
            [0.6, 0.9, 1.35, 0.8, 0.035],  # descend
            [0.6, 0.9, 1.35, 0.8, 0.010],  # grasp
            [0.2, 0.4, 1.0, 0.9, 0.010],  # lift and carry
            [0.2, 0.5, 1.1, 0.8, 0.035],  # release
        ]
    )
    q = interpolate_keyframes(keys, 16)  # 5 segments * 16 + 1 = 81 frames
    traj = Trajectory(joint_names=JOINTS[:4], q=q[:, :4], fps=15.0, gripper=2 * q[:, 4:5], gripper_names=("gripper",))
    save_trajectory(traj, ASSETS / "example_trajectory.npz")
    cam = Camera(
        Intrinsics(fx=430.0, fy=430.0, cx=319.5, cy=179.5, width=640, height=360),
        extrinsic=look_at((1.05, -0.85, 0.7), (0.15, 0.0, 0.4)),
        embodiment="toyarm",
    )
    save_camera(cam, ASSETS / "example_camera.json")
    print(f"wrote {len(q)} frames and a camera to {ASSETS}")


if __name__ == "__main__":
    main()
