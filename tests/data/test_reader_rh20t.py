"""RH20T reader on small cfg5 / cfg7 scenes written here in the release layout (pickled .npy dicts, MP4)."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from oscar_core.data.readers.rh20t import CONFIGS, RH20TReader, calib_tcp_quaternion
from oscar_core.media.video import write_video
from oscar_core.plugin.reader import EpisodeError

T = 8
CALIB_T = 1629432000000
STATIC, OTHER = "036422060215", "037522062165"


def rigid(rpy, xyz):
    M = np.eye(4)
    M[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
    M[:3, 3] = xyz
    return M


E_BASE = rigid((2.2, 0.1, -0.4), (0.1, 0.3, 1.2))  # base → camera, the answer
T_BASE_TCP = rigid((3.0, 0.2, 0.5), (0.45, 0.05, 0.3))  # calibration TCP pose
E_INHAND = rigid((0.3, -0.2, 0.1), (0.02, 0.01, 0.4))  # marker → in-hand camera


def save(path, obj):
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, np.array(obj, dtype=object) if isinstance(obj, dict) else obj, allow_pickle=True)


def write_scene(
    root, cfg=5, *, joints=7, wide_gripper=False, nan=False, no_gripper_file=False, video_frames=None, stamp_gap=False
):
    _, in_hand, tc, align = CONFIGS[cfg]
    tc = np.array(tc)
    # E[serial] such that rh20t's formula E[serial] @ inv(E[in_hand]) @ tc @ inv(T_base_tcp) @ align gives E_BASE
    E_static = E_BASE @ np.linalg.inv(align) @ T_BASE_TCP @ np.linalg.inv(tc) @ E_INHAND
    folder = root / f"RH20T_cfg{cfg}"
    calib = folder / "calib" / str(CALIB_T)
    K = np.array([[910.0, 0, 640.0, 0], [0, 910.0, 360.0, 0], [0, 0, 1, 0]])
    save(calib / "intrinsics.npy", {STATIC: K, OTHER: K, in_hand: K})
    save(calib / "extrinsics.npy", {STATIC: E_static[None], OTHER: E_static[None], in_hand: E_INHAND[None]})
    if cfg == 5:  # Franka: xyz + rotation vector of R @ diag(1, -1, -1)
        tcp = np.r_[T_BASE_TCP[:3, 3], Rotation.from_matrix(T_BASE_TCP[:3, :3] @ np.diag([1, -1, -1])).as_rotvec()]
    else:  # KUKA: millimetres + static-xyz Euler angles
        tcp = np.r_[T_BASE_TCP[:3, 3] * 1000, Rotation.from_matrix(T_BASE_TCP[:3, :3]).as_euler("xyz")]
    save(calib / "tcp.npy", tcp)
    scene = folder / f"task_0001_user_0016_scene_0001_cfg_000{cfg}"
    scene.mkdir(parents=True)
    (scene / "metadata.json").write_text(json.dumps({"calib": CALIB_T, "rating": 9}))
    stamps = [1629432100000 + 100 * i for i in range(T + 3)]
    first = 2  # the joint data starts at the video's third frame
    q = np.array([0.1, 0.3, -0.1, -1.5, 0.2, 1.2, 0.4]) + 0.01 * np.arange(T)[:, None]
    if nan:
        q[3, 2] = np.nan
    width = np.linspace(80.0 if cfg == 5 else 85.0, 10.0, T)
    if wide_gripper:
        width[2] = 300.0
    keys = stamps[first : first + T]
    joint = {
        s: {t: np.r_[q[i], np.zeros(7)][: 14 if cfg == 5 else joints] for i, t in enumerate(keys)}
        for s in (STATIC, OTHER)
    }
    grip = {
        s: {t: {"gripper_info": [width[i], 0.0, 0.0], "gripper_command": [0, 0, 0]} for i, t in enumerate(keys)}
        for s in (STATIC, OTHER)
    }
    save(scene / "transformed" / "joint.npy", joint)
    if not no_gripper_file:
        save(scene / "transformed" / "gripper.npy", grip)
    for s in (STATIC, OTHER, in_hand):
        cam = scene / f"cam_{s}"
        cam.mkdir()
        color = list(stamps)
        if stamp_gap:
            del color[first + 3]
        save(cam / "timestamps.npy", {"color": color, "depth": color})
        write_video(cam / "color.mp4", np.zeros((video_frames or len(stamps), 36, 64, 3), np.uint8), fps=10)
    return q, width


@pytest.mark.parametrize("cfg, embodiment", [(5, "franka"), (7, "kuka")])
def test_loads_a_scene(tmp_path, cfg, embodiment):
    q, width = write_scene(tmp_path, cfg)
    reader = RH20TReader()
    [ref] = list(reader.list_episodes(str(tmp_path)))
    assert (ref.episode_id, ref.embodiment, ref.cameras) == (
        f"rh20t_cfg{cfg}/task_0001_user_0016_scene_0001_cfg_000{cfg}",
        embodiment,
        (STATIC, OTHER),
    )
    ep = reader.load_episode(ref)
    np.testing.assert_allclose(ep.trajectory.q, q, atol=1e-12)
    np.testing.assert_allclose(ep.camera.extrinsic, E_BASE, atol=1e-9)
    assert ep.camera.direction == "world_to_camera"
    assert (ep.camera.intrinsics.width, ep.camera.intrinsics.height) == (64, 36)  # scaled from 1280x720
    assert ep.camera.intrinsics.fx == pytest.approx(910.0 * 64 / 1280)
    assert ep.trajectory.fps == pytest.approx(10.0)
    assert ep.video.n_frames == T and ep.video.start == pytest.approx(0.2)
    if cfg == 5:  # Franka Hand width in metres
        np.testing.assert_allclose(ep.trajectory.gripper[:, 0], width / 1000)
    else:  # Robotiq position 0 open .. 1 closed
        np.testing.assert_allclose(ep.trajectory.gripper[:, 0], 1 - width / 85)


def test_calib_tcp_matches_rh20t_preprocessing():
    tcp = np.r_[0.4, 0.1, 0.3, Rotation.from_euler("xyz", (3.0, 0.2, 0.5)).as_rotvec()]
    p = calib_tcp_quaternion(tcp, 5)
    R = Rotation.from_quat(p[[4, 5, 6, 3]]).as_matrix()
    np.testing.assert_allclose(R, Rotation.from_rotvec(tcp[3:]).as_matrix() @ np.diag([1, -1, -1]), atol=1e-12)
    k = calib_tcp_quaternion([400.0, 100.0, 300.0, 0.1, 0.2, 0.3], 7)
    np.testing.assert_allclose(k[:3], [0.4, 0.1, 0.3])


@pytest.mark.parametrize(
    "kind, field, words",
    [
        ("nan", "joint['036422060215'][1629432100500]", "non-finite"),
        ("wide_gripper", "gripper['036422060215'].gripper_info[0]", "300 at frame 2"),
        ("no_gripper_file", "<file>", "no such file"),
        ("short_video", "036422060215", "expected 8 frames.*found 3"),
        ("stamp_gap", "color", "consecutive video frames"),
        ("no_intrinsics_file", "<file>", "intrinsics.npy.*no such file"),
    ],
)
def test_bad_scenes(tmp_path, kind, field, words):
    kw = {
        "nan": {"nan": True},
        "wide_gripper": {"wide_gripper": True},
        "no_gripper_file": {"no_gripper_file": True},
        "short_video": {"video_frames": 5},
        "stamp_gap": {"stamp_gap": True},
        "no_intrinsics_file": {},
    }[kind]
    write_scene(tmp_path, 5, **kw)
    if kind == "no_intrinsics_file":
        next(tmp_path.rglob("intrinsics.npy")).unlink()
    [ref] = list(RH20TReader().list_episodes(str(tmp_path)))
    with pytest.raises(EpisodeError, match=words) as e:
        RH20TReader().load_episode(ref)
    assert e.value.field == field and e.value.episode_id.startswith("rh20t_cfg5/")
