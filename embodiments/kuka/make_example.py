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

from oscar_core import Camera, Intrinsics, Trajectory, save_camera, save_trajectory

ASSETS = Path(__file__).resolve().parent / "assets"
JOINTS = tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8))
FPS = 10.0


def keyframe_trajectory(keys: np.ndarray, frames_per_segment: int) -> np.ndarray:
    """(N, D) keyframes → ((N-1)*frames_per_segment + 1, D), smoothstep between keys."""
    s = np.linspace(0, 1, frames_per_segment, endpoint=False)
    ease = s * s * (3 - 2 * s)
    parts = [a + ease[:, None] * (b - a) for a, b in zip(keys[:-1], keys[1:])]
    return np.concatenate(parts + [keys[-1:]])


def look_at_world_to_camera(eye, target, up=(0, 0, 1)) -> np.ndarray:
    """world-to-camera (4, 4) in OpenCV axes (x right, y down, z forward)."""
    eye, target, up = (np.asarray(v, float) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=0)  # rows: camera axes in the world
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ eye
    return T


def main():
    # A1..A7 (rad) + Robotiq position (0 open .. 1 closed; 0.6 = holding a ~35 mm object)
    keys = np.array([
        [0.0, 0.3, 0.0, -1.5, 0.0, 1.3, 0.0, 0.0],           # home, open; TCP (0.53, 0, 0.34)
        [0.245, 0.726, 0.121, -0.844, -0.080, 1.571, 0.0, 0.0],  # above the object, TCP (0.65, 0.20, 0.35)
        [0.253, 0.846, 0.084, -1.146, -0.069, 1.151, 0.0, 0.0],  # descend, TCP (0.65, 0.20, 0.15)
        [0.253, 0.846, 0.084, -1.146, -0.069, 1.151, 0.0, 0.6],  # grasp
        [-0.389, 0.461, -0.259, -1.023, 0.114, 1.667, 0.0, 0.6],  # lift and carry, TCP (0.50, -0.30, 0.45)
        [-0.453, 0.736, -0.197, -1.220, 0.141, 1.198, 0.0, 0.6],  # place, TCP (0.55, -0.35, 0.20)
        [-0.453, 0.736, -0.197, -1.220, 0.141, 1.198, 0.0, 0.0],  # release
        [0.0, 0.3, 0.0, -1.5, 0.0, 1.3, 0.0, 0.0],           # back home
    ])
    q = keyframe_trajectory(keys, 12)  # 7 segments * 12 + 1 = 85 frames
    traj = Trajectory(JOINTS, q[:, :7], fps=FPS, gripper=q[:, 7:8], gripper_names=("gripper",),
                      timestamps=np.arange(len(q)) / FPS)
    save_trajectory(traj, ASSETS / "example_trajectory.npz")
    # a RealSense-like 1280x720 camera at the side of the table, RH20T's direction (base -> camera)
    cam = Camera(Intrinsics(fx=1550.0, fy=1550.0, cx=639.5, cy=359.5, width=1280, height=720),
                 extrinsic=look_at_world_to_camera((1.30, -1.90, 1.05), (0.32, 0.0, 0.45)),
                 convention="opencv", direction="world_to_camera", embodiment="kuka")
    save_camera(cam, ASSETS / "example_camera.json")
    print(f"wrote {len(q)} frames and a camera to {ASSETS}")


if __name__ == "__main__":
    main()
