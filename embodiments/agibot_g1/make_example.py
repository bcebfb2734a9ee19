"""Regenerate the AgiBot G1 bundled example trajectory and head camera.

    python embodiments/agibot_g1/make_example.py

A left-arm reach–grasp–lift–place made by smooth interpolation between joint
keyframes; the right arm holds a ready pose, the waist leans forward and the
head tilts down to watch the hands, as an operator would. The keyframes were
found once by numerical inverse kinematics on ``assets/g1.urdf`` for tool
centre targets above a table (metres, robot base frame)::

    ready (0.68, 0.16, 0.80)   above the object (0.72, 0.08, 0.88)
    grasp (0.72, 0.08, 0.78)   lifted (0.68, 0.06, 0.95)   placed (0.66, -0.08, 0.82)

(waist lift 0.15 m, pitch 0.2 rad) with the fingers pointing down and
inwards and the elbow below the shoulder; they are stored below as plain
numbers (reached within 1 cm; the last joint, a roll about the tool axis,
was then smoothed by hand, which does not move the tool centre).
Writes ``assets/example_trajectory.npz`` and ``assets/example_camera.json``.
"""

from pathlib import Path

import numpy as np

from oscar_core import Camera, Intrinsics, Trajectory, interpolate_keyframes, save_camera, save_trajectory
from oscar_embodiments.agibot_g1 import HEAD_CAMERA_LINK, JOINTS

HERE = Path(__file__).resolve().parent
ASSETS = HERE / "assets"

# Head camera pose in head_link2 (OpenCV axes, camera-to-link). head_link2 has
# x forward, y down, z to the robot's left when the head is level, so the
# optical axis (camera z) is link x and image right (camera x) is link -z.
# Translation: on the front of the head, estimated from the head's collision
# sphere in the reference URDF (centre (0.0115, -0.0253, 0.0009) m, radius
# 0.113 m in head_link2); not a calibration.
HEAD_CAMERA_IN_HEAD_LINK2 = np.array(
    [
        [0.0, 0.0, 1.0, 0.11],
        [0.0, 1.0, 0.0, -0.03],
        [-1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
# An illustrative 640x480 pinhole (about 80 degrees horizontal field of view);
# real episodes use their own head_intrinsic_params.json (see adapters.py).
HEAD_INTRINSICS = Intrinsics(fx=380.0, fy=380.0, cx=319.5, cy=239.5, width=640, height=480)

READY_L = [1.872, -0.959, -2.46, -1.45, 1.913, 1.476, 0.028]
ABOVE_L = [1.764, -1.28, -2.682, -1.446, 2.197, 1.71, 0.427]
GRASP_L = [1.813, -1.166, -2.255, -1.337, 2.057, 1.303, 0.807]
LIFT_L = [1.671, -1.184, -2.708, -1.45, 1.888, 1.71, 0.5]
PLACE_L = [1.776, -1.617, -2.294, -1.45, 2.356, 1.618, 0.6]
# the right arm mirrors the left arm's ready pose (every joint's sign flips)
READY_R = [-v for v in READY_L]


def keyframe(lift, pitch, head_yaw, head_pitch, left, right, grip_left, grip_right):
    return [lift, pitch, head_yaw, head_pitch, *left, *right, grip_left, grip_right]


def make_trajectory() -> Trajectory:
    # gripper signals: AgiBot World action/effector/position, 0 = open, 1 = closed
    keys = np.array(
        [
            keyframe(0.15, 0.20, 0.00, 0.35, READY_L, READY_R, 0.0, 0.0),  # ready, looking at the table
            keyframe(0.15, 0.20, 0.10, 0.45, ABOVE_L, READY_R, 0.0, 0.0),  # above the object
            keyframe(0.15, 0.22, 0.12, 0.50, GRASP_L, READY_R, 0.0, 0.0),  # descend
            keyframe(0.15, 0.22, 0.12, 0.50, GRASP_L, READY_R, 1.0, 0.0),  # close
            keyframe(0.17, 0.20, 0.08, 0.40, LIFT_L, READY_R, 1.0, 0.0),  # lift
            keyframe(0.17, 0.20, 0.00, 0.45, PLACE_L, READY_R, 1.0, 0.0),  # carry over the target
            keyframe(0.17, 0.20, 0.00, 0.45, PLACE_L, READY_R, 0.0, 0.0),  # release
        ]
    )
    q = interpolate_keyframes(keys, 16)  # 6 segments * 16 + 1 = 97 frames
    return Trajectory(
        joint_names=JOINTS,
        q=q[:, : len(JOINTS)],
        fps=30.0,
        gripper=q[:, len(JOINTS) :],
        gripper_names=("left_gripper", "right_gripper"),
    )


def make_camera() -> Camera:
    return Camera(
        HEAD_INTRINSICS,
        HEAD_CAMERA_IN_HEAD_LINK2,
        convention="opencv",
        direction="camera_to_world",
        mount_link=HEAD_CAMERA_LINK,
        embodiment="agibot_g1",
    )


def main():
    traj = make_trajectory()
    save_trajectory(traj, ASSETS / "example_trajectory.npz")
    save_camera(make_camera(), ASSETS / "example_camera.json")
    print(f"wrote {len(traj)} frames and the head camera to {ASSETS}")


if __name__ == "__main__":
    main()
