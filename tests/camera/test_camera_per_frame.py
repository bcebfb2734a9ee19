"""Cameras that move per frame: one extrinsic per video frame, static or link-mounted."""

from __future__ import annotations

import json
import warnings

import cv2
import numpy as np
import pytest
from _paths import REPO
from scipy.spatial.transform import Rotation

from oscar_core import JointLimitWarning, get_embodiment, load_camera, load_trajectory, look_at, render_skeleton_video
from oscar_core.camera import CONVENTIONS, DIRECTIONS, Camera, Intrinsics, convention_to_opencv, project, save_camera
from oscar_core.errors import CameraFileError

T = 6


def random_pose(rng) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    M[:3, 3] = rng.uniform(-1.5, 1.5, 3)
    return M


def intrinsics(n_dist=5) -> Intrinsics:
    dist = (0.08, -0.03, 0.002, -0.001, 0.01)[:n_dist]
    return Intrinsics(fx=610.0, fy=590.0, cx=322.0, cy=241.5, width=640, height=480, distortion=dist)


def cv2_project(points_world: np.ndarray, T_cv_world: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """The reference: cv2.projectPoints with the world → OpenCV-camera transform of one frame."""
    rvec, _ = cv2.Rodrigues(T_cv_world[:3, :3])
    dist = np.array(intr.distortion) if intr.distortion else None
    uv, _ = cv2.projectPoints(points_world.reshape(-1, 1, 3), rvec, T_cv_world[:3, 3].copy(), intr.matrix(), dist)
    return uv.reshape(-1, 2)


def points_before(T_world_cv: np.ndarray, rng, n=40) -> np.ndarray:
    z = rng.uniform(0.4, 4.0, n)
    p = np.column_stack([rng.uniform(-0.5, 0.5, (n, 2)) * z[:, None], z])
    return p @ T_world_cv[:3, :3].T + T_world_cv[:3, 3]


def user_extrinsic(T_ref_cv: np.ndarray, convention: str, direction: str) -> np.ndarray:
    T_ref_conv = T_ref_cv @ convention_to_opencv(convention)
    return T_ref_conv if direction == "camera_to_world" else np.linalg.inv(T_ref_conv)


@pytest.mark.parametrize("convention", list(CONVENTIONS))
@pytest.mark.parametrize("direction", DIRECTIONS)
def test_static_mount_per_frame_matches_cv2_frame_by_frame(convention, direction):
    rng = np.random.default_rng(7)
    intr = intrinsics()
    poses = np.stack([random_pose(rng) for _ in range(T)])  # T_world_cv per frame
    pts = np.stack([points_before(P, rng) for P in poses])  # (T, N, 3): each frame's points in its view
    cam = Camera(intr, np.stack([user_extrinsic(P, convention, direction) for P in poses]), convention, direction)
    assert cam.num_frames == T and not cam.is_static
    proj = project(pts, cam)
    assert proj.uv.shape == (T, 40, 2) and proj.in_front.all()
    for t in range(T):
        expected = cv2_project(pts[t], np.linalg.inv(poses[t]), intr)
        assert np.abs(proj.uv[t] - expected).max() < 1e-6, t


@pytest.mark.parametrize("direction", DIRECTIONS)
def test_link_mounted_per_frame_offset_matches_cv2_frame_by_frame(direction):
    rng = np.random.default_rng(8)
    intr = intrinsics(4)
    link = np.stack([random_pose(rng) for _ in range(T)])  # T_world_link per frame (from FK)
    offset = np.stack([random_pose(rng) for _ in range(T)])  # T_link_cv per frame (the camera file)
    cam = Camera(
        intr, np.stack([user_extrinsic(E, "opencv", direction) for E in offset]), "opencv", direction, mount_link="head"
    )
    pts = np.stack([points_before(link[t] @ offset[t], rng) for t in range(T)])
    proj = project(pts, cam, mount_pose=link)
    for t in range(T):
        expected = cv2_project(pts[t], np.linalg.inv(link[t] @ offset[t]), intr)
        assert np.abs(proj.uv[t] - expected).max() < 1e-6, t
    with pytest.raises(ValueError, match=f"{T} per-frame extrinsics but mount_pose has {T - 1} frames"):
        cam.world_to_cv(link[:-1])


def base(extrinsic) -> dict:
    return {
        "image_size": [640, 480],
        "intrinsics": {"fx": 600.0, "fy": 600.0, "cx": 319.5, "cy": 239.5},
        "extrinsic": extrinsic,
    }


def test_file_forms_per_frame_agree(tmp_path):
    rng = np.random.default_rng(9)
    rot = Rotation.random(T, random_state=rng)
    xyz = rng.uniform(-1, 1, (T, 3))
    mats = np.tile(np.eye(4), (T, 1, 1))
    mats[:, :3, :3], mats[:, :3, 3] = rot.as_matrix(), xyz
    forms = {
        "matrix": mats.tolist(),
        "xyz_rpy": np.column_stack([xyz, rot.as_euler("xyz")]).tolist(),
        "xyz_quat_xyzw": np.column_stack([xyz, rot.as_quat()]).tolist(),
    }
    for form, value in forms.items():
        path = tmp_path / f"{form}.json"
        path.write_text(json.dumps(base({form: value})))
        cam = load_camera(path)
        assert cam.num_frames == T and cam.extrinsic.shape == (T, 4, 4)
        np.testing.assert_allclose(cam.extrinsic, mats, atol=1e-12)
    # a round trip writes the matrix form per frame
    save_camera(cam, tmp_path / "out.json")
    again = load_camera(tmp_path / "out.json")
    assert again == cam and len(json.loads((tmp_path / "out.json").read_text())["extrinsic"]["matrix"]) == T
    # one frame given per frame is still per frame (T = 1)
    (tmp_path / "one.json").write_text(json.dumps(base({"matrix": [np.eye(4).tolist()]})))
    assert load_camera(tmp_path / "one.json").num_frames == 1
    (tmp_path / "fixed.json").write_text(json.dumps(base({"matrix": np.eye(4).tolist()})))
    assert load_camera(tmp_path / "fixed.json").num_frames is None


def test_file_errors_name_the_frame(tmp_path):
    mats = np.tile(np.eye(4), (4, 1, 1))
    mats[2, 0, 0] = 2.0  # frame 2 is not rigid
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(base({"matrix": mats.tolist()})))
    with pytest.raises(CameraFileError) as e:
        load_camera(path)
    assert e.value.field == "extrinsic.matrix[2]" and str(path) in str(e.value)
    path.write_text(json.dumps(base({"xyz_rpy": [[0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0]]})))  # ragged
    with pytest.raises(CameraFileError) as e:
        load_camera(path)
    assert e.value.field == "extrinsic.xyz_rpy[1]" and "a list of 6 numbers" in str(e.value)


def test_time_slice_and_frame_check():
    rng = np.random.default_rng(3)
    cam = Camera(intrinsics(0), np.stack([random_pose(rng) for _ in range(T)]))
    part = cam.time_slice(2, 5)
    assert part.num_frames == 3 and np.array_equal(part.extrinsic, cam.extrinsic[2:5])
    fixed = Camera(intrinsics(0), random_pose(rng))
    assert fixed.time_slice(2, 5) is fixed and fixed.num_frames is None and fixed.is_static
    fixed.check_frames(99)  # one extrinsic fits any length
    cam.check_frames(T)
    with pytest.raises(ValueError, match=f"with {T} per-frame extrinsics, points must have shape \\({T}, ..., 3\\)"):
        project(np.zeros((T - 1, 3)), cam)
    with pytest.raises(CameraFileError) as e:
        cam.check_frames(T + 1, "cam.json")
    assert (e.value.field, e.value.expected, e.value.found) == (
        "extrinsic",
        f"{T + 1} per-frame extrinsics, one per trajectory frame",
        f"{T} extrinsics",
    )


@pytest.fixture(scope="module")
def franka_example():
    emb = get_embodiment("franka")
    traj = emb.check_trajectory(load_trajectory(emb.example_trajectory)).time_slice(0, 24)
    return emb, traj, load_camera(emb.example_camera).resized(256, 144)


def test_render_per_frame_equals_one_static_render_per_frame(franka_example):
    emb, traj, cam = franka_example
    orbit = np.stack(
        [look_at([1.6 * np.cos(a), 1.6 * np.sin(a), 0.9], [0.3, 0.0, 0.35]) for a in np.linspace(-0.9, 0.9, len(traj))]
    )
    moving = Camera(cam.intrinsics, orbit)
    video = render_skeleton_video(emb, traj, moving)
    assert video.shape[0] == len(traj)
    for t in (0, 11, len(traj) - 1):  # frame t through the moving camera = frame t through a static one at pose t
        still = render_skeleton_video(emb, traj.time_slice(t, t + 1), Camera(cam.intrinsics, orbit[t]))
        assert np.array_equal(video[t], still[0]), t
    assert not np.array_equal(video[0], video[-1])
    # every frame the same pose: identical to the static camera
    same = Camera(cam.intrinsics, np.repeat(cam.extrinsic[None], len(traj), axis=0))
    assert np.array_equal(render_skeleton_video(emb, traj, same), render_skeleton_video(emb, traj, cam))


def test_render_refuses_a_frame_count_mismatch(franka_example):
    emb, traj, cam = franka_example
    moving = Camera(cam.intrinsics, np.repeat(cam.extrinsic[None], len(traj) + 3, axis=0))
    with pytest.raises(CameraFileError) as e:
        render_skeleton_video(emb, traj, moving, camera_source="head_cam.json")
    msg = str(e.value)
    assert (
        "head_cam.json" in msg and f"{len(traj)} per-frame extrinsics" in msg and f"{len(traj) + 3} extrinsics" in msg
    )


def test_link_mounted_per_frame_render_agibot():
    """A head camera with a per-frame offset from its link: frame t renders as a fixed offset would at t."""
    emb = get_embodiment("agibot_g1")
    traj = load_trajectory(emb.example_trajectory).time_slice(0, 8)
    cam = load_camera(emb.example_camera).resized(160, 120)
    rng = np.random.default_rng(4)
    offsets = np.repeat(cam.extrinsic[None], len(traj), axis=0)
    offsets[:, :3, 3] += rng.normal(0, 0.02, (len(traj), 3))  # the camera shakes in the head
    moving = Camera(cam.intrinsics, offsets, mount_link=cam.mount_link)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", JointLimitWarning)
        video = render_skeleton_video(emb, traj, moving)
        for t in (0, 5):
            fixed = Camera(cam.intrinsics, offsets[t], mount_link=cam.mount_link)
            assert np.array_equal(video[t], render_skeleton_video(emb, traj.time_slice(t, t + 1), fixed)[0])


def test_batch_paths_equal_the_frame_by_frame_ones():
    """The one-pass parser and checker of long per-frame lists give what the per-frame code gives."""
    from oscar_core.camera import as_rigid_transform, as_rigid_transforms
    from oscar_core.camera.extrinsics import _parse_one_extrinsic, _per_frame_fast

    rng = np.random.default_rng(11)
    rot = Rotation.random(50, random_state=rng)
    xyz = rng.uniform(-1, 1, (50, 3))
    mats = np.tile(np.eye(4), (50, 1, 1))
    mats[:, :3, :3], mats[:, :3, 3] = rot.as_matrix(), xyz
    for form, value in {
        "matrix": mats.tolist(),
        "xyz_rpy": np.column_stack([xyz, rot.as_euler("xyz")]).tolist(),
        "xyz_quat_xyzw": np.column_stack([xyz, rot.as_quat() * 1.0005]).tolist(),
    }.items():
        fast = _per_frame_fast(form, value)
        slow = np.stack([_parse_one_extrinsic(form, v, form, "<t>") for v in value])
        assert fast is not None and np.abs(fast - slow).max() < 1e-14, form
    noisy = mats.astype(np.float32).astype(np.float64)  # float32-stored calibrations: re-orthonormalised
    batch = as_rigid_transforms(noisy)
    single = np.stack([as_rigid_transform(m) for m in noisy])
    assert np.abs(batch - single).max() < 1e-14 and not np.array_equal(batch, noisy)
    noisy[3, :3, 0] *= -1  # a reflection at frame 3
    with pytest.raises(CameraFileError) as e:
        as_rigid_transforms(noisy, "cam.json")
    assert e.value.field == "extrinsic[3]" and "reflection" in str(e.value)


def test_keypoint_embodiment_world_points_with_a_per_frame_camera():
    """Any embodiment: world-frame hand keypoints through a per-frame egocentric camera render
    exactly as the same keypoints moved into each frame's camera frame (mano's converter)
    through the identity camera."""
    from oscar_embodiments.mano import Mano, trajectory_from_keypoints
    from oscar_embodiments.mano.synthetic import hand_keypoints

    T_, rng = 5, np.random.default_rng(5)
    poses = np.stack([look_at(rng.uniform(-0.1, 0.1, 3) + [0.0, -0.1, 0.0], [0.0, 0.0, 0.45]) for _ in range(T_)])
    kp = np.stack(
        [
            np.stack(
                [hand_keypoints(0.2 * t, side="left") + [-0.08, 0, 0.45], hand_keypoints(0.2 * t) + [0.08, 0, 0.45]]
            )
            for t in range(T_)
        ]
    )  # world frame
    grip = np.full((T_, 2), 0.5)
    intr = Intrinsics(200.0, 200.0, 95.5, 71.5, 192, 144)
    world = trajectory_from_keypoints(kp, 30.0, gripper=grip)
    moved = trajectory_from_keypoints(kp, 30.0, camera_poses=poses, gripper=grip)
    a = render_skeleton_video(Mano(), world, Camera(intr, poses, embodiment="mano"))
    b = render_skeleton_video(Mano(), moved, Camera(intr, np.eye(4), embodiment="mano"))
    drawn = (a.any(axis=-1) | b.any(axis=-1)).sum()
    assert drawn > 500 and (a != b).any(axis=-1).sum() <= 0.01 * drawn  # the same up to float rounding (two routes)


def test_training_clip_window_slices_a_per_frame_camera(tmp_path):
    """A clip whose camera moves: a window of the clip gets the extrinsics of its frames."""
    import sys

    from oscar_core.train.clips import Clip, ClipFormatError, ClipRecord, ClipSet, ClipSetWriter

    repo = REPO
    sys.path.insert(0, str(repo / "examples" / "oscar-toyarm"))
    from oscar_toyarm import ASSETS

    traj = load_trajectory(ASSETS / "example_trajectory.npz").time_slice(0, 10)
    cam = load_camera(ASSETS / "example_camera.json")
    rng = np.random.default_rng(2)
    moving = Camera(cam.intrinsics, np.stack([cam.extrinsic @ _shift(rng) for _ in range(10)]))
    rgb = rng.integers(0, 255, (10, 24, 32, 3), dtype=np.uint8)

    def rec(clip_id):
        return ClipRecord(
            id=clip_id,
            source="test",
            embodiment="toyarm",
            n_frames=10,
            fps=float(traj.fps),
            width=32,
            height=24,
            openness=tuple((1.0,) for _ in range(10)),
            files={},
        )

    w = ClipSetWriter(tmp_path)
    with w.shard("shard-000000") as s:
        s.add(Clip(rec("moving"), rgb=rgb, trajectory=traj, camera=moving))
        s.add(Clip(rec("short"), rgb=rgb, trajectory=traj, camera=moving.time_slice(0, 7)))
    clip = ClipSet(tmp_path).load("moving", start=3, frames=4, video=False)
    assert clip.camera.num_frames == 4 and np.allclose(clip.camera.extrinsic, moving.extrinsic[3:7], atol=1e-12)
    assert len(clip.trajectory) == 4
    with pytest.raises(ClipFormatError, match="10 per-frame extrinsics"):
        ClipSet(tmp_path).load("short", video=False)


def _shift(rng) -> np.ndarray:
    M = np.eye(4)
    M[:3, 3] = rng.normal(0, 0.01, 3)
    return M
