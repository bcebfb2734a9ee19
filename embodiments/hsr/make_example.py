"""Regenerate the HSR bundled example trajectory and head camera.

    python embodiments/hsr/make_example.py

The robot drives 15 cm forward while turning slightly left, raises and
stretches its arm over a table, grasps, lifts and releases, by smooth
interpolation between joint keyframes. The head tilts down to watch the hand,
as a teleoperator would. Writes ``assets/example_trajectory.npz`` (with
``base_pose``) and ``assets/example_camera.json`` (the head RGB-D camera).
"""

from pathlib import Path

import numpy as np

from oscar_core import Camera, Trajectory, interpolate_keyframes, save_camera, save_trajectory
from oscar_embodiments.hsr import JOINTS, base_pose_from_xy_yaw
from oscar_embodiments.hsr.adapters import head_camera

HERE = Path(__file__).resolve().parent
ASSETS = HERE / "assets"


def make_trajectory() -> Trajectory:
    # columns: the 7 joints, hand_motor_joint (rad, larger = more open), base x, y (m), yaw (rad)
    keys = np.array(
        [
            # lift  flex   roll  wflex  wroll  pan   tilt   hand   x     y     yaw
            [0.05, -0.40, 0.00, -1.20, 0.00, 0.00, -0.50, 0.00, 0.00, 0.00, 0.00],  # carrying pose, hand closed
            [0.15, -1.20, 0.00, -0.35, 0.00, 0.05, -0.65, 1.10, 0.15, 0.02, 0.08],  # drive up, raise the arm, open
            [0.12, -1.50, 0.00, -0.05, 0.00, 0.05, -0.70, 1.10, 0.15, 0.02, 0.08],  # reach over the table
            [0.12, -1.50, 0.00, -0.05, 0.00, 0.05, -0.70, -0.30, 0.15, 0.02, 0.08],  # grasp (squeezes past contact)
            [0.30, -1.35, 0.00, -0.20, 0.00, 0.05, -0.55, -0.30, 0.15, 0.02, 0.08],  # lift
            [0.30, -1.35, 0.00, -0.20, 0.00, 0.05, -0.55, 1.00, 0.15, 0.02, 0.08],  # release
            [0.20, -1.00, 0.00, -0.60, 0.00, 0.00, -0.55, 1.00, 0.12, 0.02, 0.08],  # withdraw
        ]
    )
    q = interpolate_keyframes(keys, 16)  # 6 segments * 16 + 1 = 97 frames
    return Trajectory(
        joint_names=JOINTS,
        q=q[:, :7],
        fps=10.0,
        gripper=q[:, 7:8],
        gripper_names=("hand",),
        base_pose=base_pose_from_xy_yaw(q[:, 8], q[:, 9], q[:, 10]),
    )


def make_camera() -> Camera:
    """The head RGB-D camera: the nominal 640x480 sensor of the HSR description (1.047 rad horizontal
    field of view), identity pose in head_rgbd_sensor_link (an optical frame)."""
    return head_camera()


def main():
    traj = make_trajectory()
    save_trajectory(traj, ASSETS / "example_trajectory.npz")
    save_camera(make_camera(), ASSETS / "example_camera.json")
    print(f"wrote {len(traj)} frames and the head camera to {ASSETS}")


if __name__ == "__main__":
    main()
