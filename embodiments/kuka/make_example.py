"""Regenerate the KUKA plugin's bundled example trajectory and camera.

    python embodiments/kuka/make_example.py

A reach–grasp–lift–place by smooth (smoothstep) interpolation between joint
keyframes, 10 fps (RH20T's usual rate), the Robotiq gripper closing on the
object and opening to release it, and a static camera given the way RH20T
gives them (robot base → camera, OpenCV axes). The keyframes were found once
by inverse kinematics for the TCP positions in the comments (jaw pointing
down) and are written out so the script needs no solver. Output:
``assets/example_trajectory.npz`` and ``assets/example_camera.json``.
"""

from pathlib import Path

import numpy as np

from oscar_core import Camera, Intrinsics, Trajectory, interpolate_keyframes, look_at, save_camera, save_trajectory

ASSETS = Path(__file__).resolve().parent / "assets"
JOINTS = tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8))
FPS = 10.0


def _world_to_camera(eye, target) -> np.ndarray:
    """world-to-camera (4, 4), OpenCV axes: RH20T stores extrinsics in this direction."""
    R = look_at(eye, target)[:3, :3].T  # rows: the camera axes in the world
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ np.asarray(eye, float)
    return T


def main():
    # A1..A7 (rad) + Robotiq position (0 open .. 1 closed; 0.6 = holding a ~35 mm object)
    keys = np.array(
        [
            [0.0, 0.3, 0.0, -1.5, 0.0, 1.3, 0.0, 0.0],  # home, open; TCP (0.53, 0, 0.34)
            [0.245, 0.726, 0.121, -0.844, -0.080, 1.571, 0.0, 0.0],  # above the object, TCP (0.65, 0.20, 0.35)
            [0.253, 0.846, 0.084, -1.146, -0.069, 1.151, 0.0, 0.0],  # descend, TCP (0.65, 0.20, 0.15)
            [0.253, 0.846, 0.084, -1.146, -0.069, 1.151, 0.0, 0.6],  # grasp
            [-0.389, 0.461, -0.259, -1.023, 0.114, 1.667, 0.0, 0.6],  # lift and carry, TCP (0.50, -0.30, 0.45)
            [-0.453, 0.736, -0.197, -1.220, 0.141, 1.198, 0.0, 0.6],  # place, TCP (0.55, -0.35, 0.20)
            [-0.453, 0.736, -0.197, -1.220, 0.141, 1.198, 0.0, 0.0],  # release
            [0.0, 0.3, 0.0, -1.5, 0.0, 1.3, 0.0, 0.0],  # back home
        ]
    )
    q = interpolate_keyframes(keys, 12)  # 7 segments * 12 + 1 = 85 frames
    traj = Trajectory(
        JOINTS, q[:, :7], fps=FPS, gripper=q[:, 7:8], gripper_names=("gripper",), timestamps=np.arange(len(q)) / FPS
    )
    save_trajectory(traj, ASSETS / "example_trajectory.npz")
    # a RealSense-like 1280x720 camera at the side of the table, RH20T's direction (base -> camera)
    cam = Camera(
        Intrinsics(fx=1550.0, fy=1550.0, cx=639.5, cy=359.5, width=1280, height=720),
        extrinsic=_world_to_camera((1.30, -1.90, 1.05), (0.32, 0.0, 0.45)),
        convention="opencv",
        direction="world_to_camera",
        embodiment="kuka",
    )
    save_camera(cam, ASSETS / "example_camera.json")
    print(f"wrote {len(q)} frames and a camera to {ASSETS}")


if __name__ == "__main__":
    main()
