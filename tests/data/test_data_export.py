"""Export to the training-clip format and the ``oscar data`` command line, end to end on a small run."""

import json

import numpy as np
import pytest
from _datasets import SIZE, base_parts, write_episode

from oscar_core.cli import main
from oscar_core.data.engine import read_stage
from oscar_core.data.export import clip_id
from oscar_core.train.clips import ClipSet


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("export")
    traj, _ = base_parts()
    write_episode(root / "src", "ep0", seed=0, task="wave")
    write_episode(root / "src", "ep1", seed=1)
    write_episode(root / "src", "short", traj.time_slice(0, 40), seed=2)
    run = root / "run"
    common = ["--workers", "1", "--no-progress"]
    assert main(["data", "ingest", str(root / "src"), "--reader", "npz", "--out", str(run), *common]) == 0
    assert main(["data", "filter", str(run), *common]) == 0
    return root, run


def test_export_writes_a_clip_set_the_trainer_reads(run):
    from oscar_core.render.skeleton_video import render_skeleton_video
    from oscar_toyarm import ToyArm

    root, r = run
    assert (
        main(
            [
                "data",
                "export",
                str(r),
                "--out",
                str(root / "clips"),
                "--render-skeleton",
                "--workers",
                "1",
                "--no-progress",
            ]
        )
        == 0
    )
    cs = ClipSet(root / "clips")
    recs = sorted(cs, key=lambda c: c.id)
    assert [c.meta["episode"] for c in recs] == ["src/ep0", "src/ep1"]  # the short one was filtered out
    rec = recs[0]
    assert rec.id == clip_id("src/ep0") and rec.task == "wave" and rec.caption is None
    assert (rec.n_frames, rec.fps, rec.width, rec.height) == (81, 15.0, *SIZE)
    clip = cs.load(rec)
    src = root / "src" / "ep0"
    from oscar_core import load_camera, load_trajectory
    from oscar_core.media.video import read_video

    np.testing.assert_array_equal(clip.rgb, read_video(src / "rgb.mkv"))  # lossless both ways
    np.testing.assert_array_equal(clip.trajectory.q, load_trajectory(src / "trajectory.npz").q)
    assert clip.camera == load_camera(src / "camera.json")
    np.testing.assert_array_equal(clip.skeleton, render_skeleton_video(ToyArm(), clip.trajectory, clip.camera, SIZE))
    rows = {x["id"]: x for x in read_stage(str(r / "export"))}
    assert rows["src/ep0"]["export_clip"] == rec.id and rows["src/short"].get("export_status") is None


def test_export_resized_skeleton_on_the_fly(run, tmp_path):
    _, r = run
    import shutil

    r2 = tmp_path / "run"
    shutil.copytree(r, r2, ignore=shutil.ignore_patterns("export"))
    assert (
        main(
            [
                "data",
                "export",
                str(r2),
                "--out",
                str(tmp_path / "clips"),
                "--size",
                "64x36",
                "--workers",
                "1",
                "--no-progress",
            ]
        )
        == 0
    )
    rec = next(iter(ClipSet(tmp_path / "clips")))
    assert (rec.width, rec.height) == (64, 36) and "skeleton" not in rec.files
    clip = ClipSet(tmp_path / "clips").load(rec)
    assert (clip.camera.intrinsics.width, clip.camera.intrinsics.height) == (64, 36)


def test_clip_ids_are_valid_and_unique():
    a, b = clip_id("droid/ep 1"), clip_id("droid-ep-1")
    assert a != b and a.startswith("droid-ep-1-") and len(a) == len("droid-ep-1-") + 8


def test_stats_command_table_json_and_plot(run, capsys):
    pytest.importorskip("matplotlib")
    root, r = run
    capsys.readouterr()
    assert main(["data", "stats", str(r), "--json", "--plot", str(root / "stats.png")]) == 0
    st = json.loads(capsys.readouterr().out)
    assert st["total"]["public"] == 3 and st["total"]["kept"] == 2 and st["total"]["rejected"] == {"filter:length": 1}
    assert (root / "stats.png").read_bytes()[:4] == b"\x89PNG"
    assert json.loads((r / "stats.json").read_text()) == st
    assert main(["data", "stats", str(r)]) == 0
    assert "filter:length" in capsys.readouterr().out


def test_cli_errors_name_what_is_missing(tmp_path, capsys):
    assert main(["data", "filter", str(tmp_path / "nothing"), "--workers", "1"]) == 2
    assert "expected a finished stage before 'filter'" in capsys.readouterr().err
    assert main(["data", "filter", str(tmp_path), "--set", "min_lenght=3"]) == 2
    assert "min_lenght" in capsys.readouterr().err
