"""EgoDex reader on small episodes written here in the real layout (h5py ARKit transforms + MP4)."""

import numpy as np
import pytest

h5py = pytest.importorskip("h5py")

from scipy.spatial.transform import Rotation

from oscar_core.data.readers.egodex import EGODEX_JOINTS, EgoDexReader
from oscar_core.media.video import write_video
from oscar_core.plugin.reader import EpisodeError
from oscar_embodiments.mano.synthetic import hand_keypoints

T = 10
K = np.array([[736.6, 0.0, 960.0], [0.0, 736.6, 540.0], [0.0, 0.0, 1.0]])
GL_FROM_CV = np.diag([1.0, -1.0, -1.0])  # ARKit / OpenGL camera axes from OpenCV axes


def camera_frame_points():
    """(T, 2, 21, 3) hands in the OpenCV camera frame, 0.4–0.5 m in front of it."""
    pts = np.empty((T, 2, 21, 3))
    for t in range(T):
        for h, side in enumerate(("left", "right")):
            kp = hand_keypoints(curl=t / (T - 1), side=side)
            pts[t, h] = kp + np.array([-0.1 if side == "left" else 0.1, 0.05, 0.4 + 0.01 * t])
    return pts


def camera_poses():
    """(T, 4, 4) camera → world, ARKit axes, moving and turning."""
    P = np.tile(np.eye(4), (T, 1, 1))
    P[:, :3, :3] = Rotation.from_euler(
        "xyz", np.stack([0.1 * np.arange(T), np.full(T, 0.3), np.zeros(T)], 1)
    ).as_matrix()
    P[:, :3, 3] = np.stack([0.02 * np.arange(T), np.full(T, 1.5), np.zeros(T)], 1)
    return P


def write_episode(root, name="part1/basic_pick_place/0", *, nan=False, drop=None, video=True, video_frames=T):
    h5 = root / f"{name}.hdf5"
    h5.parent.mkdir(parents=True, exist_ok=True)
    cv = camera_frame_points()
    P = camera_poses()
    world = (
        np.einsum("tij,thkj->thki", P[:, :3, :3], np.einsum("ij,thkj->thki", GL_FROM_CV, cv)) + P[:, None, None, :3, 3]
    )
    with h5py.File(h5, "w") as f:
        f.attrs["llm_description"] = "Pick up the cup and place it on the plate."
        f["camera/intrinsic"] = K
        f["transforms/camera"] = P
        for h, side in enumerate(("left", "right")):
            for k, joint in enumerate(EGODEX_JOINTS[side]):
                M = np.tile(np.eye(4), (T, 1, 1))
                M[:, :3, 3] = world[:, h, k]
                if nan and (h, k) == (1, 8):
                    M[4, 0, 3] = np.nan
                f[f"transforms/{joint}"] = M
                f[f"confidences/{joint}"] = np.ones(T)
            f[f"transforms/{side}IndexFingerMetacarpal"] = np.tile(np.eye(4), (T, 1, 1))  # stored, not used
        if drop:
            del f[drop]
    if video:
        write_video(h5.with_suffix(".mp4"), np.zeros((video_frames, 54, 96, 3), np.uint8), fps=30)
    return cv


def test_loads_an_episode_into_the_camera_frame(tmp_path):
    cv = write_episode(tmp_path)
    reader = EgoDexReader()
    [ref] = list(reader.list_episodes(str(tmp_path)))
    assert (ref.episode_id, ref.embodiment, ref.n_frames, ref.fps) == (
        "egodex/part1/basic_pick_place/0",
        "mano",
        T,
        30.0,
    )
    assert ref.task == "Pick up the cup and place it on the plate."
    ep = reader.load_episode(ref)
    np.testing.assert_allclose(ep.trajectory.keypoints.reshape(T, 2, 21, 3), cv, atol=1e-9)
    cam = ep.camera
    assert (cam.intrinsics.fx, cam.intrinsics.cx, cam.intrinsics.width, cam.intrinsics.height) == (736.6, 960.0, 96, 54)
    np.testing.assert_array_equal(cam.extrinsic, np.eye(4))
    g = ep.trajectory.gripper  # open hand at t=0 → fist at the end: openness falls
    assert g[0, 0] > g[-1, 0] and g[0, 1] > g[-1, 1]


def test_low_confidence_points_become_missing(tmp_path):
    write_episode(tmp_path)
    with h5py.File(next(tmp_path.rglob("*.hdf5")), "a") as f:
        c = np.ones(T)
        c[3] = 0.1
        f["confidences/rightIndexFingerTip"][...] = c
    [ref] = list(EgoDexReader().list_episodes(str(tmp_path)))
    kp = EgoDexReader(min_confidence=0.5).load_episode(ref).trajectory.keypoints.reshape(T, 2, 21, 3)
    assert np.isnan(kp[3, 1, 8]).all() and np.isfinite(kp[2, 1, 8]).all() and np.isfinite(kp[3, 1, 7]).all()


@pytest.mark.parametrize(
    "kind, field, words",
    [
        ("nan", "transforms/rightIndexFingerTip", "non-finite"),
        ("missing_field", "transforms/leftThumbTip", "missing"),
        ("no_video", "egocentric", "no such file"),
        ("short_video", "egocentric", "expected 10 frames.*found 6"),
        ("truncated_video", "egocentric", "truncated|readable video"),
        ("no_intrinsic", "camera/intrinsic", "missing"),
    ],
)
def test_bad_episodes(tmp_path, kind, field, words):
    kw = {
        "nan": {"nan": True},
        "missing_field": {"drop": "transforms/leftThumbTip"},
        "no_video": {"video": False},
        "short_video": {"video_frames": 6},
        "truncated_video": {},
        "no_intrinsic": {"drop": "camera/intrinsic"},
    }[kind]
    write_episode(tmp_path, **kw)
    if kind == "truncated_video":
        mp4 = next(tmp_path.rglob("*.mp4"))
        mp4.write_bytes(mp4.read_bytes()[: mp4.stat().st_size // 2])
    [ref] = list(EgoDexReader().list_episodes(str(tmp_path)))
    with pytest.raises(EpisodeError, match=words) as e:
        EgoDexReader().load_episode(ref)
    assert e.value.field == field and e.value.episode_id == "egodex/part1/basic_pick_place/0"
