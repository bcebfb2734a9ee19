"""oscar embodiment plugin: two human hands, 21 keypoints each.

Datasets: EgoDex, EPIC-Kitchens (egocentric). A trajectory carries the
hands' 3D keypoints in its ``keypoints`` field, (T, 42, 3): the 21 points of
the left hand, then of the right (:mod:`.topology`); NaN marks a missing
point or hand, which is then not drawn. Two ways to make one:

* :func:`trajectory_from_keypoints` — straight from (T, 2, 21, 3) keypoints
  (tracker output); needs nothing beyond oscar;
* :func:`trajectory_from_mano` — from MANO parameters through ``smplx.MANO``;
  needs ``pip install "oscar-wm[mano]"`` and the licensed MANO model files.

The ``gripper`` columns ("left", "right") hold each hand's openness, the
normalised fingertip flexion of :mod:`.flexion` (1 = open flat hand,
0 = fist); it draws the open/close indicator at the palm centre and is the
signal of the training-window prior (:func:`hand_openness`). Cameras:
egocentric keypoints live in the camera frame, rendered with an identity
extrinsic (:func:`egocentric_camera`); see :mod:`.convert` for world-frame
keypoints seen by a moving camera. Provenance and licences: ``README.md``.
"""

from __future__ import annotations

from pathlib import Path

from oscar_core import CameraSpec, Embodiment, Gripper, Skeleton, SkeletonFrames, TrajectoryError, hookimpl

from .convert import egocentric_camera, gripper_signal, to_camera_frame, trajectory_from_keypoints
from .flexion import hand_openness
from .mano_model import ENV_MANO_DIR, SMPLX_MISSING, mano_keypoints, require_smplx, smplx_problem, trajectory_from_mano
from .mano_pickle import MANOModelError, load_mano_pickle
from .topology import COLORS, EDGES, GROUPS, HANDS, NUM_KEYPOINTS, PALM, POINT_NAMES

__all__ = [
    "Mano",
    "ASSETS",
    "trajectory_from_keypoints",
    "trajectory_from_mano",
    "mano_keypoints",
    "hand_openness",
    "gripper_signal",
    "to_camera_frame",
    "egocentric_camera",
    "load_mano_pickle",
    "MANOModelError",
    "smplx_problem",
    "require_smplx",
    "SMPLX_MISSING",
    "ENV_MANO_DIR",
    "oscar_register_embodiments",
]

ASSETS = Path(__file__).resolve().parent / "assets"


class Mano(Embodiment):
    """Left and right human hands as 21-keypoint skeletons (MANO joints + fingertips)."""

    name = "mano"
    description = (
        "two human hands, 21 keypoints each, from (T, 2, 21, 3) keypoints or MANO parameters "
        '(the MANO-parameter input needs smplx: pip install "oscar-wm[mano]", and the licensed MANO files)'
    )
    license = "Apache-2.0"  # the topology and colours are ours; MANO model files are licensed separately
    datasets = ("egodex", "epic_kitchens")
    skeleton = Skeleton(links=POINT_NAMES, edges=EDGES, groups=GROUPS, colors=COLORS)
    # signal: openness from fingertip flexion, 0 (fist) .. 1 (flat open hand); drawn at the palm centre
    grippers = (
        Gripper("left", link="left_wrist", signal_range=(0.0, 1.0), closed_at="low"),
        Gripper("right", link="right_wrist", signal_range=(0.0, 1.0), closed_at="low"),
    )
    camera = CameraSpec(convention="opencv", direction="camera_to_world", mount_link=None)
    example_trajectory = ASSETS / "example_trajectory.npz"
    example_camera = ASSETS / "example_camera.json"

    def check_trajectory(self, traj):
        """Requires ``keypoints`` (T, 42, 3); fills the gripper columns from them when absent."""
        if traj.keypoints is None:
            raise TrajectoryError(
                traj.source,
                "keypoints",
                f"shape (T, {len(POINT_NAMES)}, 3): the 21 keypoints of the left hand, then the right "
                "(make one with oscar_embodiments.mano.trajectory_from_keypoints)",
                "missing",
            )
        if traj.gripper.shape[1] == 0 and traj.keypoints.shape[1] == len(POINT_NAMES):
            kp = traj.keypoints.reshape(len(traj), 2, NUM_KEYPOINTS, 3)
            traj = traj.replace(gripper=gripper_signal(kp), gripper_names=HANDS)
        return super().check_trajectory(traj)

    def frames(self, traj, device="cpu", mount_link=None) -> SkeletonFrames:
        """The keypoints themselves; the indicators at each palm centre (mean of the wrist and four MCPs).

        Hands have no links to mount a camera on: a moving camera is folded into
        the keypoints by the converters (:mod:`.convert`), so ``mount_link`` is
        always None here (``check_camera`` refuses a mounted camera).
        """
        if mount_link is not None:
            raise ValueError(
                f"mano: a camera cannot ride on link {mount_link!r}; give keypoints in the camera frame "
                "(trajectory_from_keypoints(..., camera_poses=...))"
            )
        pts = traj.keypoints
        hands = pts.reshape(len(traj), 2, NUM_KEYPOINTS, 3)
        palm = hands[:, :, list(PALM)].mean(axis=2)  # NaN if any palm point is missing
        return SkeletonFrames(pts, palm, self.gripper_openness(traj.gripper, traj.source), None)

    def info(self) -> dict:
        out = super().info()
        out["keypoints"] = len(POINT_NAMES)
        problem = smplx_problem()
        out["mano_parameters"] = "available (smplx installed)" if problem is None else problem
        return out


@hookimpl
def oscar_register_embodiments():
    return [Mano]
