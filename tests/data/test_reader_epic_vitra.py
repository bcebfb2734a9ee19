"""EPIC-Kitchens via VITRA: per-episode pickled .npy dicts written here in VITRA's layout + a raw MP4."""

import os

import numpy as np
import pytest

from oscar_core.data.readers.epic_vitra import EpicVitraReader, parse_episode_name
from oscar_core.media.video import write_video
from oscar_core.plugin.reader import EpisodeError
from oscar_embodiments.mano.synthetic import hand_keypoints

T, FIRST, FPS = 8, 10, 25
K = np.array([[300.0, 0.0, 48.0], [0.0, 300.0, 27.0], [0.0, 0.0, 1.0]])


def write_episode(root, *, kept_left=None, nan=False, drop=None, frames=None, video=True, video_frames=30, evil=False):
    ann = root / "episodic_annotations"
    ann.mkdir(parents=True, exist_ok=True)
    hands = {}
    for side, dx in (("left", -0.1), ("right", 0.1)):
        j = np.stack([hand_keypoints(curl=t / T, side=side) + [dx, 0.05, 0.45] for t in range(T)])
        if nan and side == "right":
            j[2, 5, 1] = np.nan
        hands[side] = {
            "joints_camspace": j,
            "kept_frames": np.ones(T, int).tolist() if side == "right" or kept_left is None else kept_left,
            "beta": np.zeros(10),
            "hand_pose": np.tile(np.eye(3), (T, 15, 1, 1)),
        }
    d = {
        "extrinsics": np.tile(np.eye(4), (T, 1, 1)),
        "intrinsics": K,
        "video_name": "P01_01",
        "video_decode_frame": list(range(FIRST, FIRST + T)) if frames is None else frames,
        "anno_type": "right",
        "text": {"right": [("Open the fridge.", (0, T - 1))], "left": []},
        "avg_speed": 0.01,
        "total_rotvec_degree": 3.0,
        "total_transl_dist": 0.02,
        **hands,
    }
    if drop:
        del d[drop]
    if evil:

        class Evil:
            def __reduce__(self):
                return (os.system, ("echo pwned",))

        d["extra"] = Evil()
    np.save(ann / "EPIC_P01_01_ep_000003.npy", np.array(d, dtype=object), allow_pickle=True)
    if video:
        v = np.zeros((video_frames, 54, 96, 3), np.uint8)
        for i in range(video_frames):
            v[i] = i * 8
        (root / "videos" / "P01" / "videos").mkdir(parents=True, exist_ok=True)
        write_video(root / "videos" / "P01" / "videos" / "P01_01.MP4", v, fps=FPS, codec="h264")
    return hands


def test_parse_names_as_vitra_splits_them():
    assert parse_episode_name("EPIC_P01_01_ep_000003") == ("EPIC", "P01_01", "000003")
    assert parse_episode_name("notanepisode") is None


def test_lists_by_name_and_loads(tmp_path):
    hands = write_episode(tmp_path, kept_left=[1, 1, 0, 0, 1, 1, 1, 1])
    reader = EpicVitraReader()
    [ref] = list(reader.list_episodes(str(tmp_path)))
    assert (ref.episode_id, ref.embodiment, ref.n_frames) == ("epic_kitchens/P01_01/000003", "mano", None)
    ep = reader.load_episode(ref)
    kp = ep.trajectory.keypoints.reshape(T, 2, 21, 3)
    np.testing.assert_allclose(kp[:, 1], hands["right"]["joints_camspace"])
    assert np.isnan(kp[2:4, 0]).all() and np.allclose(kp[4, 0], hands["left"]["joints_camspace"][4])
    assert ep.task == "Open the fridge." and ep.trajectory.fps == FPS
    assert (ep.camera.intrinsics.fx, ep.camera.intrinsics.width) == (300.0, 96)
    got = ep.video.read([0, T - 1])[:, 0, 0, 0].astype(int)
    np.testing.assert_allclose(got, [FIRST * 8, (FIRST + T - 1) * 8], atol=4)  # frames 10 and 17 of the raw video


@pytest.mark.parametrize(
    "kind, field, words",
    [
        ("nan", "right.joints_camspace", "non-finite values in 1 kept frames"),
        ("missing_field", "intrinsics", "missing"),
        ("gap", "video_decode_frame", "consecutive"),
        ("no_video", "egocentric", "no such file"),
        ("short_video", "egocentric", "expected 8 frames.*found 5"),
        ("evil", "pickle global", "posix.system|nt.system"),
    ],
)
def test_bad_episodes(tmp_path, kind, field, words):
    kw = {
        "nan": {"nan": True},
        "missing_field": {"drop": "intrinsics"},
        "gap": {"frames": [10, 11, 13, 14, 15, 16, 17, 18]},
        "no_video": {"video": False},
        "short_video": {"video_frames": 15},
        "evil": {"evil": True},
    }[kind]
    write_episode(tmp_path, **kw)
    [ref] = list(EpicVitraReader().list_episodes(str(tmp_path)))
    with pytest.raises(EpisodeError, match=words) as e:
        EpicVitraReader().load_episode(ref)
    assert e.value.field == field and e.value.episode_id == "epic_kitchens/P01_01/000003"
