"""LeRobot v3.0 reader on small datasets written here in the real layout (pyarrow + PyAV): DROID and AIROA-MoMa."""

import json

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

from scipy.spatial.transform import Rotation

from oscar_core.data.readers.lerobot import LeRobotReader
from oscar_core.media.video import write_video
from oscar_core.plugin.reader import EpisodeError

FPS = 15.0
LENGTHS = (8, 10)  # two episodes sharing one data file and one MP4 per camera
RPY = (0.1, -0.4, 2.0)
XYZ = (0.3, -0.5, 0.6)
K = (200.0, 200.0, 24.0, 16.0)


def _frames(n, offset):
    """(n, 32, 48, 3) frames whose value encodes their global index."""
    f = np.zeros((n, 32, 48, 3), np.uint8)
    for i in range(n):
        f[i] = (offset + i) * 10
    return f


def _q(T, seed):
    rng = np.random.default_rng(seed)
    base = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.7])
    return base + 0.1 * np.sin(np.arange(T)[:, None] / 3.0 + rng.uniform(0, 6, 7))


def write_droid_v3(root, *, cameras=("exterior_1_left", "wrist_left"), lengths=LENGTHS, nan_at=None, video_frames=None):
    """A DROID LeRobot v3.0 dataset (column names from lerobot's port_droid.py)."""
    root.mkdir(parents=True, exist_ok=True)
    features = {
        "observation.state.joint_position": {"dtype": "float32", "shape": [7], "names": None},
        "observation.state.gripper_position": {"dtype": "float32", "shape": [1], "names": None},
        "timestamp": {"dtype": "float32", "shape": [1], "names": None},
        "frame_index": {"dtype": "int64", "shape": [1], "names": None},
        "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    }
    for c in cameras:
        features[f"observation.images.{c}"] = {
            "dtype": "video",
            "shape": [32, 48, 3],
            "names": ["height", "width", "channels"],
        }
        features[f"camera_extrinsics.{c}"] = {"dtype": "float64", "shape": [6], "names": None}
    (root / "meta").mkdir()
    (root / "meta" / "info.json").write_text(
        json.dumps(
            {
                "codebase_version": "v3.0",
                "robot_type": "franka",
                "fps": FPS,
                "chunks_size": 1000,
                "features": features,
                "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
                "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
            }
        )
    )
    cols = {
        k: []
        for k in (
            "observation.state.joint_position",
            "observation.state.gripper_position",
            "timestamp",
            "frame_index",
            "episode_index",
            "index",
        )
    }
    for c in cameras:
        cols[f"camera_extrinsics.{c}"] = []
    ep_rows, start, t0 = [], 0, 0.0
    for e, T in enumerate(lengths):
        q = _q(T, e)
        if nan_at is not None and nan_at[0] == e:
            q[nan_at[1], 2] = np.nan
        g = np.linspace(0, 1, T)[:, None]
        cols["observation.state.joint_position"] += q.tolist()
        cols["observation.state.gripper_position"] += g.tolist()
        cols["timestamp"] += (np.arange(T) / FPS).tolist()
        cols["frame_index"] += list(range(T))
        cols["episode_index"] += [e] * T
        cols["index"] += list(range(start, start + T))
        for c in cameras:
            cols[f"camera_extrinsics.{c}"] += [list(XYZ) + list(RPY)] * T
        row = {
            "episode_index": e,
            "tasks": [f"task {e}"],
            "length": T,
            "data/chunk_index": 0,
            "data/file_index": 0,
            "dataset_from_index": start,
            "dataset_to_index": start + T,
        }
        for c in cameras:
            k = f"observation.images.{c}"
            row.update(
                {
                    f"videos/{k}/chunk_index": 0,
                    f"videos/{k}/file_index": 0,
                    f"videos/{k}/from_timestamp": t0,
                    f"videos/{k}/to_timestamp": t0 + T / FPS,
                }
            )
        ep_rows.append(row)
        start, t0 = start + T, t0 + T / FPS
    (root / "data" / "chunk-000").mkdir(parents=True)
    pq.write_table(pa.table(cols), root / "data" / "chunk-000" / "file-000.parquet")
    (root / "meta" / "episodes" / "chunk-000").mkdir(parents=True)
    pq.write_table(pa.Table.from_pylist(ep_rows), root / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
    total = sum(lengths) if video_frames is None else video_frames
    for c in cameras:
        d = root / "videos" / f"observation.images.{c}" / "chunk-000"
        d.mkdir(parents=True)
        write_video(d / "file-000.mp4", _frames(total, 0), fps=FPS)
    return root


def test_lists_droid_episodes_from_metadata(tmp_path):
    root = write_droid_v3(tmp_path / "droid")
    refs = list(LeRobotReader().list_episodes(str(root)))
    assert [r.episode_id for r in refs] == ["droid/0", "droid/1"]
    r = refs[1]
    assert (r.source, r.reader, r.embodiment, r.n_frames, r.fps, r.task) == (
        "droid",
        "lerobot",
        "franka_robotiq",
        10,
        FPS,
        "task 1",
    )
    assert r.cameras == ("observation.images.exterior_1_left", "observation.images.wrist_left")
    assert r.meta["camera"] == "observation.images.exterior_1_left"
    json.dumps(r.meta)  # manifest rows must serialise


def test_loads_droid_episode_slice_of_shared_files(tmp_path):
    root = write_droid_v3(tmp_path / "droid")
    reader = LeRobotReader(intrinsics={"exterior_1_left": K})
    ref = list(reader.list_episodes(str(root)))[1]
    ep = reader.load_episode(ref)
    np.testing.assert_allclose(ep.trajectory.q, _q(10, 1), atol=1e-6)  # float32 storage
    # the gripper signal is whatever the franka DROID adapter makes of the episode's own rows (its unit may change)
    from oscar_embodiments.franka.adapters import from_droid

    want_traj, _ = from_droid(
        {"observation/joint_position": _q(10, 1), "observation/gripper_position": np.linspace(0, 1, 10)},
        "exterior_1_left",
        extrinsic=list(XYZ) + list(RPY),
        intrinsics=K,
        image_size=(48, 32),
        fps=FPS,
    )
    np.testing.assert_allclose(ep.trajectory.gripper, want_traj.gripper, atol=1e-6)
    want = np.eye(4)
    want[:3, :3] = Rotation.from_euler("xyz", RPY).as_matrix()  # second implementation of the Euler convention
    want[:3, 3] = XYZ
    np.testing.assert_allclose(ep.camera.extrinsic, want, atol=1e-9)
    assert (ep.camera.intrinsics.width, ep.camera.intrinsics.height) == (48, 32)
    assert ep.camera.direction == "camera_to_world" and ep.camera_name == "observation.images.exterior_1_left"
    frames = ep.video.read([0, 9])
    np.testing.assert_allclose(frames[:, 0, 0, 0], [80, 170], atol=3)  # episode 1 starts at global frame 8
    assert ep.task == "task 1"


def test_droid_without_intrinsics_names_the_field(tmp_path):
    root = write_droid_v3(tmp_path / "droid")
    ref = next(iter(LeRobotReader().list_episodes(str(root))))
    with pytest.raises(EpisodeError, match=r"droid/0.*intrinsics of observation.images.exterior_1_left.*found none"):
        LeRobotReader().load_episode(ref)


def test_droid_bad_inputs(tmp_path):
    reader = LeRobotReader(intrinsics={"exterior_1_left": K})
    root = write_droid_v3(tmp_path / "nan", nan_at=(1, 4))
    ref = list(reader.list_episodes(str(root)))[1]
    with pytest.raises(EpisodeError) as e:
        reader.load_episode(ref)
    assert e.value.episode_id == "droid/1" and e.value.field == "observation.state.joint_position"
    assert "non-finite" in e.value.found and e.value.path.endswith("file-000.parquet")

    root = write_droid_v3(tmp_path / "short", video_frames=12)  # the shared MP4 ends inside episode 1
    ref = list(reader.list_episodes(str(root)))[1]
    with pytest.raises(EpisodeError, match=r"expected 10 frames at 15 fps from 0.533333 s.*found 4 frames"):
        reader.load_episode(ref)

    root = write_droid_v3(tmp_path / "trunc")
    mp4 = root / "videos" / "observation.images.exterior_1_left" / "chunk-000" / "file-000.mp4"
    mp4.write_bytes(mp4.read_bytes()[: mp4.stat().st_size // 2])
    ref = list(reader.list_episodes(str(root)))[0]
    with pytest.raises(EpisodeError) as e:
        reader.load_episode(ref)
    assert e.value.path == str(mp4) and e.value.field == "observation.images.exterior_1_left"
    assert "truncated" in e.value.found or e.value.expected == "a readable video"

    mp4.unlink()
    with pytest.raises(EpisodeError, match="no such file"):
        reader.load_episode(ref)

    root = write_droid_v3(tmp_path / "rows")  # the episode table says 10 frames, the data file holds 8 of them
    ref = list(reader.list_episodes(str(root)))[1]
    p = root / "data" / "chunk-000" / "file-000.parquet"
    pq.write_table(pq.read_table(p).slice(0, 16), p)
    with pytest.raises(EpisodeError, match=r"field 'episode_index': expected 10 rows of episode 1.*found 8 rows"):
        reader.load_episode(ref)

    root = write_droid_v3(tmp_path / "nodata")
    ref = list(reader.list_episodes(str(root)))[0]
    tab = pq.read_table(root / "data" / "chunk-000" / "file-000.parquet").drop_columns(
        ["observation.state.gripper_position"]
    )
    pq.write_table(tab, root / "data" / "chunk-000" / "file-000.parquet")
    with pytest.raises(EpisodeError) as e:
        reader.load_episode(ref)
    assert e.value.field == "observation.state.gripper_position" and e.value.found.startswith("missing")


def write_moma_v3(root, T=12):
    """An AIROA-MoMa LeRobot v3.0 dataset: observation.state named by info.json, a head camera."""
    root.mkdir(parents=True)
    names = [
        "arm_lift_joint",
        "arm_flex_joint",
        "arm_roll_joint",
        "wrist_flex_joint",
        "wrist_roll_joint",
        "hand_motor_joint",
        "head_pan_joint",
        "head_tilt_joint",
    ]
    key = "observation.images.head_camera_rgb"
    (root / "meta" / "episodes" / "chunk-000").mkdir(parents=True)
    (root / "meta" / "info.json").write_text(
        json.dumps(
            {
                "codebase_version": "v3.0",
                "robot_type": "hsr",
                "fps": 10,
                "features": {
                    "observation.state": {"dtype": "float32", "shape": [8], "names": names},
                    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
                    key: {"dtype": "video", "shape": [32, 48, 3], "names": ["height", "width", "channels"]},
                },
            }
        )
    )
    state = np.zeros((T, 8))
    state[:, 0] = np.linspace(0.0, 0.3, T)
    state[:, 1] = -0.5
    (root / "data" / "chunk-000").mkdir(parents=True)
    pq.write_table(
        pa.table(
            {
                "observation.state": state.tolist(),
                "timestamp": (np.arange(T) / 10).tolist(),
                "frame_index": list(range(T)),
                "episode_index": [0] * T,
            }
        ),
        root / "data" / "chunk-000" / "file-000.parquet",
    )
    pq.write_table(
        pa.Table.from_pylist(
            [
                {
                    "episode_index": 0,
                    "tasks": ["tidy"],
                    "length": T,
                    "data/chunk_index": 0,
                    "data/file_index": 0,
                    f"videos/{key}/chunk_index": 0,
                    f"videos/{key}/file_index": 0,
                    f"videos/{key}/from_timestamp": 0.0,
                    f"videos/{key}/to_timestamp": T / 10,
                }
            ]
        ),
        root / "meta" / "episodes" / "chunk-000" / "file-000.parquet",
    )
    d = root / "videos" / key / "chunk-000"
    d.mkdir(parents=True)
    write_video(d / "file-000.mp4", _frames(T, 0), fps=10)
    return state


def test_loads_airoa_moma_episode(tmp_path):
    state = write_moma_v3(tmp_path / "moma")
    reader = LeRobotReader()
    ref = next(iter(reader.list_episodes(str(tmp_path / "moma"))))
    assert (ref.episode_id, ref.embodiment, ref.cameras) == (
        "airoa_moma/0",
        "hsr",
        ("observation.images.head_camera_rgb",),
    )
    ep = reader.load_episode(ref)
    from oscar_embodiments.hsr import JOINTS

    np.testing.assert_allclose(ep.trajectory.q[:, list(JOINTS).index("arm_lift_joint")], state[:, 0], atol=1e-6)
    assert ep.camera.mount_link == "head_rgbd_sensor_link" and ep.trajectory.fps == 10
    assert ep.video.n_frames == 12


def test_unknown_lerobot_dataset_is_refused(tmp_path):
    (tmp_path / "meta").mkdir()
    (tmp_path / "meta" / "info.json").write_text(
        json.dumps({"codebase_version": "v3.0", "fps": 30, "features": {"action": {"dtype": "float32"}}})
    )
    with pytest.raises(ValueError, match="expected a DROID .* or AIROA-MoMa"):
        list(LeRobotReader().list_episodes(str(tmp_path)))
