"""DROID raw reader on small episode folders written here in the real layout (h5py, JSON, PyAV)."""

import json

import numpy as np
import pytest

h5py = pytest.importorskip("h5py")

from scipy.spatial.transform import Rotation

from oscar_core.data.readers.droid import DroidRawReader
from oscar_core.media.video import write_video
from oscar_core.plugin.reader import EpisodeError

T = 9
EXT1, EXT2, WRIST = "24259877", "26405488", "13062452"
POSE = (0.2, -0.6, 0.5, -2.1, 0.05, 0.4)


def write_episode(
    root,
    rel="IRIS/success/2023-03-01/Wed_Mar__1_12:00:00_2023",
    *,
    intrinsics=True,
    nan=False,
    drop=None,
    video=True,
    video_frames=T,
    metadata=True,
    gripper_rows=T,
):
    folder = root / rel
    (folder / "recordings" / "MP4").mkdir(parents=True)
    q = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.7]) + 0.05 * np.sin(np.arange(T)[:, None] + np.arange(7))
    with h5py.File(folder / "trajectory.h5", "w") as f:
        qq = q.copy()
        if nan:
            qq[3, 1] = np.nan
        f["observation/robot_state/joint_positions"] = qq
        f["observation/robot_state/gripper_position"] = np.linspace(0, 1, gripper_rows)
        f["observation/robot_state/cartesian_position"] = np.zeros((T, 6))
        for s in (EXT1, EXT2, WRIST):
            f[f"observation/camera_extrinsics/{s}_left"] = np.tile(POSE, (T, 1))
            if intrinsics:
                f[f"observation/camera_intrinsics/{s}_left"] = np.tile(
                    [[520.0, 0, 640], [0, 520.0, 360], [0, 0, 1]], (T, 1, 1)
                )
        if drop:
            del f[drop]
    if metadata:
        (folder / "metadata_IRIS+abc+2023.json").write_text(
            json.dumps(
                {
                    "ext1_cam_serial": EXT1,
                    "ext2_cam_serial": EXT2,
                    "wrist_cam_serial": WRIST,
                    "current_task": "put the pen in the cup",
                    "trajectory_length": T,
                    "success": True,
                }
            )
        )
    if video:
        for s in (EXT1, EXT2, WRIST):
            write_video(
                folder / "recordings" / "MP4" / f"{s}.mp4", np.zeros((video_frames, 36, 64, 3), np.uint8), fps=15
            )
    return q


def test_lists_from_metadata_and_loads(tmp_path):
    q = write_episode(tmp_path)
    reader = DroidRawReader()
    [ref] = list(reader.list_episodes(str(tmp_path)))
    assert ref.episode_id == "droid/IRIS/success/2023-03-01/Wed_Mar__1_12:00:00_2023"
    assert (ref.n_frames, ref.fps, ref.task, ref.cameras) == (
        T,
        15.0,
        "put the pen in the cup",
        (f"{EXT1}_left", f"{EXT2}_left"),
    )
    ep = reader.load_episode(ref)
    np.testing.assert_allclose(ep.trajectory.q, q)
    want = np.eye(4)
    want[:3, :3] = Rotation.from_euler("xyz", POSE[3:]).as_matrix()
    want[:3, 3] = POSE[:3]
    np.testing.assert_allclose(ep.camera.extrinsic, want, atol=1e-12)
    assert ep.camera.intrinsics.fx == 520.0 and ep.camera_name == f"{EXT1}_left"
    assert ep.video.path.endswith(f"{EXT1}.mp4") and ep.video.n_frames == T


def test_second_camera_and_supplied_intrinsics(tmp_path):
    write_episode(tmp_path, intrinsics=False)
    [ref] = list(DroidRawReader().list_episodes(str(tmp_path)))
    with pytest.raises(EpisodeError, match=f"observation/camera_intrinsics/{EXT1}_left.*missing"):
        DroidRawReader().load_episode(ref)
    from dataclasses import replace

    ref2 = replace(ref, meta={**ref.meta, "camera": f"{EXT2}_left"})
    ep = DroidRawReader(intrinsics={EXT2: (300.0, 300.0, 32.0, 18.0)}).load_episode(ref2)
    assert ep.camera.intrinsics.fx == 300.0 and ep.video.path.endswith(f"{EXT2}.mp4")


@pytest.mark.parametrize(
    "kind, field, words",
    [
        ("nan", "observation/robot_state/joint_positions", "non-finite"),
        ("missing_field", "observation/robot_state/gripper_position", "missing"),
        ("no_video", f"{EXT1}_left", "no such file"),
        ("truncated_video", f"{EXT1}_left", "truncated|readable video"),
        ("no_metadata", "<file>", "metadata JSON"),
        ("gripper_rows", "observation/robot_state/gripper_position", "9 rows.*found 12 rows"),
    ],
)
def test_bad_episodes(tmp_path, kind, field, words):
    kw = {
        "nan": {"nan": True},
        "missing_field": {"drop": "observation/robot_state/gripper_position"},
        "no_video": {"video": False},
        "no_metadata": {"metadata": False},
        "gripper_rows": {"gripper_rows": 12},
    }.get(kind, {})
    write_episode(tmp_path, **kw)
    [ref] = list(DroidRawReader().list_episodes(str(tmp_path)))
    if kind == "truncated_video":
        mp4 = next((tmp_path).rglob(f"{EXT1}.mp4"))
        mp4.write_bytes(mp4.read_bytes()[:-400])
    if kind == "no_metadata":  # listing still finds the episode, with no cameras known
        assert ref.cameras == ()
    with pytest.raises(EpisodeError, match=words) as e:
        DroidRawReader().load_episode(ref)
    assert e.value.field == field and e.value.episode_id.startswith("droid/IRIS")
