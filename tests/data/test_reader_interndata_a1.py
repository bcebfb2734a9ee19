"""InternData-A1 reader on a small LeRobot v2.1 release written here (pyarrow + PyAV): Franka tasks only."""

import json

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

from scipy.spatial.transform import Rotation

from oscar_core.data.readers.interndata_a1 import InternDataA1Reader
from oscar_core.media.video import write_video
from oscar_core.plugin.reader import EpisodeError

FPS = 30
POSE = [0.9, 0.1, 0.7, 0.3, -0.6, 0.65, -0.3]  # x, y, z, qw, qx, qy, qz (normalised below)
INTR = [600.0, 600.0, 320.0, 240.0]


def _features(arms=1):
    f = {
        "images.rgb.head": {"dtype": "video", "shape": [48, 64, 3], "names": ["height", "width", "channel"]},
        "images.rgb.hand": {"dtype": "video", "shape": [48, 64, 3], "names": ["height", "width", "channel"]},
        "head_camera_intrinsics": {"dtype": "float32", "shape": [4]},
        "head_camera_to_robot_extrinsics": {"dtype": "float32", "shape": [7]},
        "states.gripper.position": {"dtype": "float32", "shape": [1]},
        "timestamp": {"dtype": "float32", "shape": [1]},
    }
    f["states.joint.position"] = {"dtype": "float32", "shape": [7 * arms]}
    return f


def write_task(
    root,
    rel="articulation_tasks/franka/close_the_electriccooker",
    lengths=(9, 11),
    *,
    arms=1,
    bad_gripper=False,
    video_frames=None,
    nan=False,
):
    ds = root / rel
    (ds / "meta").mkdir(parents=True)
    (ds / "meta" / "info.json").write_text(
        json.dumps(
            {
                "codebase_version": "v2.1",
                "robot_type": "franka",
                "fps": FPS,
                "chunks_size": 1000,
                "features": _features(arms),
                "data_path": "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet",
                "video_path": "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4",
            }
        )
    )
    pose = np.array(POSE)
    pose[3:] /= np.linalg.norm(pose[3:])
    with open(ds / "meta" / "episodes.jsonl", "w") as f:
        for e, T in enumerate(lengths):
            f.write(json.dumps({"episode_index": e, "tasks": ["close the electric cooker"], "length": T}) + "\n")
            q = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.7]) + 0.02 * e + 0.01 * np.arange(T)[:, None]
            if nan:
                q[2, 4] = np.nan
            g = np.full((T, 1), 0.04)
            if bad_gripper:
                g[3] = 0.5  # 50 cm: not a Panda finger width
            (ds / "data" / "chunk-000").mkdir(parents=True, exist_ok=True)
            pq.write_table(
                pa.table(
                    {
                        "states.joint.position": q.tolist(),
                        "states.gripper.position": g.tolist(),
                        "head_camera_intrinsics": [INTR] * T,
                        "head_camera_to_robot_extrinsics": [pose.tolist()] * T,
                        "timestamp": (np.arange(T) / FPS).tolist(),
                        "frame_index": list(range(T)),
                        "episode_index": [e] * T,
                    }
                ),
                ds / "data" / "chunk-000" / f"episode_{e:06d}.parquet",
            )
            for key in ("images.rgb.head", "images.rgb.hand"):
                d = ds / "videos" / "chunk-000" / key
                d.mkdir(parents=True, exist_ok=True)
                write_video(d / f"episode_{e:06d}.mp4", np.zeros((video_frames or T, 48, 64, 3), np.uint8), fps=FPS)
    return pose


def test_lists_franka_tasks_only_and_loads(tmp_path):
    pose = write_task(tmp_path)
    write_task(tmp_path, rel="basic_tasks/genie1/pick_cup", arms=2)  # dual arm: skipped
    reader = InternDataA1Reader()
    refs = list(reader.list_episodes(str(tmp_path)))
    assert [r.episode_id for r in refs] == [
        "interndata_a1/articulation_tasks/franka/close_the_electriccooker/0",
        "interndata_a1/articulation_tasks/franka/close_the_electriccooker/1",
    ]
    assert (
        refs[1].n_frames == 11 and refs[1].task == "close the electric cooker" and refs[1].cameras == ("head", "hand")
    )
    ep = reader.load_episode(refs[1])
    assert ep.trajectory.q.shape == (11, 7) and ep.trajectory.fps == FPS
    np.testing.assert_allclose(ep.trajectory.q[:, 0], 0.02 + 0.01 * np.arange(11), atol=1e-6)
    want = np.eye(4)
    want[:3, :3] = Rotation.from_quat(pose[[4, 5, 6, 3]]).as_matrix()  # scipy wants x, y, z, w
    want[:3, 3] = pose[:3]
    np.testing.assert_allclose(ep.camera.extrinsic, want, atol=1e-6)
    assert ep.camera.intrinsics.fx == 600.0 and ep.video.path.endswith("images.rgb.head/episode_000001.mp4")


@pytest.mark.parametrize(
    "kind, field, words",
    [
        ("bad_gripper", "states.gripper.position", "0.5 at frame 3"),
        ("short_video", "images.rgb.head", "found 5 frames"),
        ("missing_column", "head_camera_intrinsics", "missing"),
        ("nan", "states.joint.position", "non-finite"),
    ],
)
def test_bad_episodes(tmp_path, kind, field, words):
    write_task(
        tmp_path,
        bad_gripper=kind == "bad_gripper",
        video_frames=5 if kind == "short_video" else None,
        nan=kind == "nan",
    )
    refs = list(InternDataA1Reader().list_episodes(str(tmp_path)))
    if kind == "missing_column":
        p = next(tmp_path.rglob("episode_000000.parquet"))
        pq.write_table(pq.read_table(p).drop_columns(["head_camera_intrinsics"]), p)
    with pytest.raises(EpisodeError, match=words) as e:
        InternDataA1Reader().load_episode(refs[0])
    assert e.value.field == field and e.value.episode_id.endswith("close_the_electriccooker/0")
