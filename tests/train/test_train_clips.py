"""The training-clip format: write a shard, read it back, and reject every kind of bad clip by name."""

import json
import sys

import numpy as np
import pytest
import torch
from _paths import REPO, TOYARM_ASSETS

from oscar_core import load_camera, load_trajectory
from oscar_core.train.clips import (
    CLIPSET_FILE,
    SHARD_INDEX,
    Clip,
    ClipFormatError,
    ClipRecord,
    ClipSet,
    ClipSetWriter,
    clip_openness,
)

sys.path.insert(0, str(REPO / "examples" / "oscar-toyarm"))
from oscar_toyarm import ToyArm

W, H = 32, 24


@pytest.fixture(scope="module")
def parts():
    traj = load_trajectory(TOYARM_ASSETS / "example_trajectory.npz").time_slice(0, 12)
    cam = load_camera(TOYARM_ASSETS / "example_camera.json")
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (len(traj), H, W, 3), dtype=np.uint8)
    return traj, cam, rgb


def record(traj, clip_id="ep0", **kw):
    op = clip_openness(ToyArm(), traj)
    d = dict(
        id=clip_id,
        source="toyworld",
        embodiment="toyarm",
        n_frames=len(traj),
        fps=float(traj.fps),
        width=W,
        height=H,
        openness=tuple(map(tuple, op)),
        files={},
        caption="pick up the cube",
    )
    d.update(kw)
    return ClipRecord(**d)


def write_set(root, parts, n=2, **clip_kw):
    traj, cam, rgb = parts
    w = ClipSetWriter(root)
    with w.shard("shard-000000") as s:
        for i in range(n):
            s.add(Clip(record(traj, f"ep{i}"), rgb=rgb, trajectory=traj, camera=cam, **clip_kw))
    return w


def test_round_trip_is_lossless(tmp_path, parts):
    traj, cam, rgb = parts
    pe = torch.randn(7, 16)
    lat = {
        "video": torch.randn(2, 4, 2, 3, 4),
        "skeleton": torch.randn(2, 4, 2, 3, 4),
        "starts": [0, 3],
        "window": 5,
        "vae": "tiny",
    }
    write_set(tmp_path, parts, skeleton=rgb[::-1].copy(), prompt_embeds=pe, latents=lat)
    cs = ClipSet(tmp_path)
    assert [r.id for r in cs] == ["ep0", "ep1"]
    clip = cs.load("ep1")
    np.testing.assert_array_equal(clip.rgb, rgb)  # FFV1 is lossless
    np.testing.assert_array_equal(clip.skeleton, rgb[::-1])
    np.testing.assert_array_equal(clip.trajectory.q, traj.q)
    assert torch.equal(clip.prompt_embeds, pe)
    assert torch.equal(clip.latents["video"], lat["video"]) and clip.latents["starts"].tolist() == [0, 3]
    assert clip.latents["window"] == "5" and clip.latents["vae"] == "tiny"
    np.testing.assert_allclose(cs.record("ep0").openness_array, clip_openness(ToyArm(), traj))


def test_window_reads_only_its_frames(tmp_path, parts):
    traj, _, rgb = parts
    write_set(tmp_path, parts, n=1)
    clip = ClipSet(tmp_path).load("ep0", start=3, frames=5)
    np.testing.assert_array_equal(clip.rgb, rgb[3:8])
    np.testing.assert_array_equal(clip.trajectory.q, traj.q[3:8])
    with pytest.raises(ClipFormatError, match=r"clip 'ep0'.*n_frames.*at least 13 frames"):
        ClipSet(tmp_path).load("ep0", start=8, frames=5)


def test_openness_tracks_the_gripper(parts):
    traj = parts[0]
    op = clip_openness(ToyArm(), traj)
    assert op.shape == (len(traj), 1)
    np.testing.assert_allclose(op[:, 0], np.clip(traj.gripper[:, 0] / 0.08, 0, 1))


def test_unfinished_shard_is_ignored_and_stale_temp_removed(tmp_path, parts):
    traj, cam, rgb = parts
    w = write_set(tmp_path, parts, n=1)
    s = w.shard("shard-000001")
    s.add(Clip(record(traj, "late"), rgb=rgb, trajectory=traj, camera=cam))  # never closed: a killed writer
    assert [r.id for r in ClipSet(tmp_path)] == ["ep0"]
    assert not w.shard_done("shard-000001") and w.shard_done("shard-000000")
    assert w.remove_stale() == [] and s.tmp.exists()  # its writer (this process) is alive: kept
    import os
    import subprocess
    import sys

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    gone = s.tmp.with_name(s.tmp.name.replace(f".{os.getpid()}.", f".{dead.pid}."))
    s.tmp.rename(gone)  # as if the writer had been that process, killed
    assert [p.name for p in w.remove_stale()] == [gone.name] and not gone.exists()


def test_exception_leaves_nothing(tmp_path, parts):
    traj, cam, rgb = parts
    w = ClipSetWriter(tmp_path)
    with pytest.raises(ClipFormatError, match="rgb"):
        with w.shard("shard-000000") as s:
            s.add(Clip(record(traj), rgb=rgb[:5], trajectory=traj, camera=cam))
    assert sorted(p.name for p in tmp_path.iterdir()) == [CLIPSET_FILE]


def test_duplicate_ids_across_shards_name_both(tmp_path, parts):
    traj, cam, rgb = parts
    w = write_set(tmp_path, parts, n=1)
    with w.shard("shard-000001") as s:
        s.add(Clip(record(traj, "ep0"), rgb=rgb, trajectory=traj, camera=cam))
    with pytest.raises(ClipFormatError, match=r"shard-000001.*'ep0'.*also in shard-000000"):
        ClipSet(tmp_path)


def _edit_index(root, fn):
    index = root / "shard-000000" / SHARD_INDEX
    rows = [json.loads(l) for l in index.read_text().splitlines()]
    fn(rows[0])
    index.write_text("".join(json.dumps(r) + "\n" for r in rows))


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda r: r.pop("fps"), "fps"),
        (lambda r: r["files"].pop("camera"), "files.camera"),
        (lambda r: r.update(openness=[[0.5]] * 3), "openness"),
        (lambda r: r.update(openness=[[1.5]] * r["n_frames"]), "openness"),
        (lambda r: r.update(n_frames=0), "n_frames"),
        (lambda r: r["files"].update(rgb="../../etc/passwd.mkv"), "files.rgb"),
        (lambda r: r.update(colour="red"), "colour"),
    ],
)
def test_bad_records_name_shard_clip_and_field(tmp_path, parts, edit, field):
    write_set(tmp_path, parts, n=1)
    _edit_index(tmp_path, edit)
    with pytest.raises(ClipFormatError) as err:
        ClipSet(tmp_path)
    msg = str(err.value)
    assert f"field '{field}'" in msg and "shard-000000" in msg


def test_mismatched_lengths_and_missing_files(tmp_path, parts):
    traj, cam, rgb = parts
    write_set(tmp_path, parts, n=2)
    _edit_index(tmp_path, lambda r: r.update(n_frames=r["n_frames"] + 1, openness=r["openness"] + [r["openness"][-1]]))
    cs = ClipSet(tmp_path)
    with pytest.raises(ClipFormatError, match=r"clip 'ep0'.*'trajectory'.*13 frames"):
        cs.load("ep0")
    (tmp_path / "shard-000000" / "ep1" / "camera.json").unlink()
    with pytest.raises(ClipFormatError, match=r"clip 'ep1'.*files.camera.*no such file"):
        cs.load("ep1")


def test_truncated_video_is_reported(tmp_path, parts):
    write_set(tmp_path, parts, n=1)
    path = tmp_path / "shard-000000" / "ep0" / "rgb.mkv"
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(ClipFormatError, match=r"clip 'ep0'.*files.rgb|clip 'ep0'.*'rgb'"):
        ClipSet(tmp_path).load("ep0")


def test_not_a_clip_set(tmp_path):
    with pytest.raises(ClipFormatError, match="not a clip set"):
        ClipSet(tmp_path)
    (tmp_path / CLIPSET_FILE).write_text('{"format": "other"}')
    with pytest.raises(ClipFormatError, match="'format'"):
        ClipSet(tmp_path)
