"""AgiBot World reader on a small dataset written here in the real layout (h5py, JSON, PyAV)."""

import json

import numpy as np
import pytest

h5py = pytest.importorskip("h5py")

from oscar_core.data.readers.agibot_world import AgiBotWorldReader
from oscar_core.kinematics.trajectory import Trajectory
from oscar_core.media.video import write_video
from oscar_core.plugin.reader import EpisodeError
from oscar_embodiments.agibot_g1 import HEAD_CAMERA_LINK, JOINTS, AgiBotG1

T = 12
HEAD_IN_LINK = np.array([[0.0, 0.0, 1.0, 0.11], [0.0, 1.0, 0.0, -0.03], [-1.0, 0.0, 0.0, 0.0], [0, 0, 0, 1.0]])


@pytest.fixture(scope="module")
def g1():
    return AgiBotG1()


def write_episode(
    root, g1, task="327", episode="648642", *, action_rows=T, nan=False, drop=None, no_camera_file=None, video_frames=T
):
    """One episode in AgiBot World's folders, from known joint values and a known head-camera mount."""
    lo, hi = g1.tree.limits()
    body = [g1.tree.joint_names.index(n) for n in JOINTS]
    mid = (lo[body] + hi[body]) / 2
    q = mid + 0.05 * np.sin(np.arange(T)[:, None] / 4.0 + np.arange(len(JOINTS)))
    grip = np.stack([np.linspace(0, 1, action_rows), np.zeros(action_rows)], axis=1)
    traj = Trajectory(JOINTS, q, 30, gripper=np.stack([np.linspace(0, 1, T), np.zeros(T)], axis=1))
    link = g1.fk(g1.full_configuration(g1.check_trajectory(traj)), links=[HEAD_CAMERA_LINK]).numpy()[:, 0]
    cam_to_base = link @ HEAD_IN_LINK
    h5 = root / "proprio_stats" / task / episode / "proprio_stats.h5"
    h5.parent.mkdir(parents=True)
    arms = q[:, 4:].copy()
    if nan:
        arms[5, 3] = np.nan
    with h5py.File(h5, "w") as f:
        f["timestamp"] = 1_734_000_000_000_000_000 + np.arange(T, dtype=np.int64) * 33_333_333
        f["state/joint/position"] = arms
        f["state/waist/position"] = q[:, [1, 0]]
        f["state/head/position"] = q[:, [2, 3]]
        f["action/effector/position"] = grip
        if drop:
            del f[drop]
    cam = root / "parameters" / task / episode / "parameters" / "camera"
    cam.mkdir(parents=True)
    files = {
        "head_intrinsic_params": {"intrinsic": {"fx": 390.1, "fy": 389.7, "ppx": 321.2, "ppy": 243.8}},
        "head_extrinsic_params_aligned": [
            {"extrinsic": {"rotation_matrix": C[:3, :3].tolist(), "translation_vector": C[:3, 3].tolist()}}
            for C in cam_to_base
        ],
    }
    for name, doc in files.items():
        if name != no_camera_file:
            (cam / f"{name}.json").write_text(json.dumps(doc))
    videos = root / "observations" / task / episode / "videos"
    videos.mkdir(parents=True)
    write_video(videos / "head_color.mp4", np.zeros((video_frames, 48, 64, 3), np.uint8), fps=30)
    write_video(videos / "hand_left_color.mp4", np.zeros((2, 48, 64, 3), np.uint8), fps=30)
    (root / "task_info").mkdir(exist_ok=True)
    (root / "task_info" / f"task_{task}.json").write_text(
        json.dumps([{"episode_id": int(episode), "task_name": "Pick up the cup"}])
    )
    return q, cam_to_base, h5


def _load(root):
    reader = AgiBotWorldReader()
    refs = list(reader.list_episodes(str(root)))
    return reader, refs


def test_lists_and_loads_an_episode(tmp_path, g1):
    q, cam_to_base, h5 = write_episode(tmp_path, g1)
    reader, refs = _load(tmp_path)
    assert len(refs) == 1
    ref = refs[0]
    assert (ref.episode_id, ref.embodiment, ref.n_frames, ref.task) == (
        "agibot_world/327/648642",
        "agibot_g1",
        T,
        "Pick up the cup",
    )
    assert ref.cameras == ("head_color", "hand_left_color")
    ep = reader.load_episode(ref)
    np.testing.assert_allclose(ep.trajectory.q, q, atol=1e-12)
    # the adapter's default keeps the stored per-frame head-camera poses (the head moves)
    assert ep.camera.mount_link is None and ep.camera.num_frames == T
    np.testing.assert_allclose(ep.camera.extrinsic, np.broadcast_to(cam_to_base, (T, 4, 4)), atol=1e-9)
    assert ep.video.n_frames == T and ep.video.fps == pytest.approx(30.0)
    assert ep.camera_name == "head_color"


@pytest.mark.parametrize(
    "kind, field, words",
    [
        ("action_longer", "action/effector/position", "12 rows.*found 15 rows"),
        ("nan", "state/joint/position", "non-finite"),
        ("missing_field", "state/head/position", "missing"),
        ("camera_file", "<file>", "head_extrinsic_params_aligned.json.*no such file"),
        ("short_video", "head_color", "expected 12 frames.*found 7 frames"),
        ("truncated_h5", "<file>", "a readable file"),
        ("truncated_mp4", "head_color", "truncated|readable video"),
    ],
)
def test_bad_episodes_are_rejected_with_their_reason(tmp_path, g1, kind, field, words):
    kw = {
        "action_longer": {"action_rows": 15},
        "nan": {"nan": True},
        "missing_field": {"drop": "state/head/position"},
        "camera_file": {"no_camera_file": "head_extrinsic_params_aligned"},
        "short_video": {"video_frames": 7},
    }.get(kind, {})
    _, _, h5 = write_episode(tmp_path, g1, **kw)
    if kind == "truncated_h5":
        h5.write_bytes(h5.read_bytes()[:1000])
    if kind == "truncated_mp4":
        mp4 = tmp_path / "observations" / "327" / "648642" / "videos" / "head_color.mp4"
        mp4.write_bytes(mp4.read_bytes()[: mp4.stat().st_size // 2])
    reader, refs = _load(tmp_path)
    with pytest.raises(EpisodeError, match=words) as e:
        reader.load_episode(refs[0])
    assert e.value.episode_id == "agibot_world/327/648642" and e.value.field == field


def test_listing_reads_no_arrays(tmp_path, g1, monkeypatch):
    write_episode(tmp_path, g1)
    import h5py as _h5

    def boom(*a, **k):
        raise AssertionError("list_episodes read array data")

    monkeypatch.setattr(_h5.Dataset, "__getitem__", boom)
    monkeypatch.setattr(_h5.Dataset, "__array__", boom)
    assert [r.n_frames for r in AgiBotWorldReader().list_episodes(str(tmp_path))] == [T]
