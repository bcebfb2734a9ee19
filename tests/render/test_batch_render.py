"""Many episodes per command: manifests, folders, the worker pool, per-episode errors, output checks,
kill-safety, start-up imports, and the small CLI fixes (joint order, quiet pipes, demo sheet)."""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from _paths import TOYARM_ASSETS

from oscar_core import get_embodiment, load_camera, load_trajectory, render_skeleton_video, save_trajectory
from oscar_core.cli import main
from oscar_core.errors import InputFileError, OutputPathError
from oscar_core.media.video import read_video
from oscar_core.render.batch import (
    EpisodeSpec,
    read_manifest,
    render_episode,
    render_many,
    specs_from_folder,
)

TRAJ, CAM = TOYARM_ASSETS / "example_trajectory.npz", TOYARM_ASSETS / "example_camera.json"


def run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def short_traj(tmp_path, name, T=6, start=0):
    path = tmp_path / name
    save_trajectory(load_trajectory(TRAJ).time_slice(start, start + T), path)
    return path


def direct(traj_path, size):
    return render_skeleton_video(get_embodiment("toyarm"), load_trajectory(traj_path), load_camera(CAM), size)


# ------------------------------------------------------------------ manifests


def write_jsonl(path, rows):
    path.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    return path


def test_jsonl_and_csv_manifests_give_the_same_specs_with_paths_relative_to_the_manifest(tmp_path):
    rows = [
        {"embodiment": "toyarm", "trajectory": "a.npz", "camera": "cam.json", "out": "out/a.mp4", "size": "64x36"},
        {"embodiment": "toyarm", "trajectory": "/abs/b.npz", "camera": "cam.json", "out": "out/b/", "fps": 5},
    ]
    j = read_manifest(write_jsonl(tmp_path / "m.jsonl", rows))
    (tmp_path / "m.csv").write_text(
        "embodiment,trajectory,camera,out,size,fps\n"
        "toyarm,a.npz,cam.json,out/a.mp4,64x36,\n"
        "toyarm,/abs/b.npz,cam.json,out/b/,,5\n"
    )
    c = read_manifest(tmp_path / "m.csv")
    assert j == c
    assert j[0] == EpisodeSpec(
        "toyarm", str(tmp_path / "a.npz"), str(tmp_path / "cam.json"), str(tmp_path / "out" / "a.mp4"), (64, 36), None
    )
    assert j[1].trajectory == "/abs/b.npz" and j[1].out == str(tmp_path / "out" / "b") + "/" and j[1].fps == 5.0


@pytest.mark.parametrize(
    "row, field",
    [
        ({"embodiment": "toyarm", "trajectory": "a.npz", "camera": "c.json"}, "line 2.out"),
        (
            {"embodiment": "toyarm", "trajectory": "a.npz", "camera": "c.json", "out": "a.mp4", "szie": "4x4"},
            "line 2.szie",
        ),
        (
            {"embodiment": "toyarm", "trajectory": "a.npz", "camera": "c.json", "out": "a.mp4", "size": "big"},
            "line 2.size",
        ),
        ({"embodiment": "toyarm", "trajectory": "a.npz", "camera": "c.json", "out": "a.mp4", "fps": -1}, "line 2.fps"),
    ],
)
def test_manifest_errors_name_the_file_line_and_field(tmp_path, row, field):
    path = tmp_path / "m.jsonl"
    path.write_text("# episodes\n" + json.dumps(row) + "\n")
    with pytest.raises(InputFileError, match=f"m.jsonl.*{field}"):
        read_manifest(path)


def test_folder_of_trajectories_takes_each_camera_beside_it_or_the_shared_one(tmp_path):
    d = tmp_path / "trajs"
    d.mkdir()
    for n in ("b", "a"):
        short_traj(d, f"{n}.npz")
    with pytest.raises(InputFileError, match="no camera for \\['a.npz', 'b.npz'\\]"):
        specs_from_folder(d, "toyarm", tmp_path / "out")
    (d / "camera.json").write_bytes(CAM.read_bytes())
    (d / "b.json").write_bytes(CAM.read_bytes())
    specs = specs_from_folder(d, "toyarm", tmp_path / "out", suffix=".mkv")
    assert [(Path(s.trajectory).name, Path(s.camera).name, Path(s.out).name) for s in specs] == [
        ("a.npz", "camera.json", "a.mkv"),
        ("b.npz", "b.json", "b.mkv"),
    ]


# ------------------------------------------------------------------ the batch engine


def test_render_many_collects_errors_and_renders_the_rest(tmp_path):
    a, b = short_traj(tmp_path, "a.npz"), short_traj(tmp_path, "b.npz", start=30)
    specs = [
        EpisodeSpec("toyarm", str(a), str(CAM), str(tmp_path / "out" / "a.mkv"), (96, 54)),
        EpisodeSpec("toyarm", str(tmp_path / "missing.npz"), str(CAM), str(tmp_path / "out" / "m.mkv"), (96, 54)),
        EpisodeSpec("nobody", str(a), str(CAM), str(tmp_path / "out" / "n.mkv"), (96, 54)),
        EpisodeSpec("toyarm", str(b), str(CAM), str(tmp_path / "out" / "b.mkv"), (96, 54)),
    ]
    seen = []
    results = render_many(specs, on_result=seen.append)
    assert [r.ok for r in results] == [True, False, False, True] and len(seen) == 4
    assert "missing.npz" in results[1].error and "nobody" in results[2].error
    np.testing.assert_array_equal(read_video(tmp_path / "out" / "a.mkv"), direct(a, (96, 54)))
    np.testing.assert_array_equal(read_video(tmp_path / "out" / "b.mkv"), direct(b, (96, 54)))
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a.mkv", "b.mkv"]  # no debris


@pytest.mark.slow
def test_two_workers_give_the_same_videos_as_one_process(tmp_path, capsys):
    trajs = [short_traj(tmp_path, f"t{i}.npz", T=5, start=10 * i) for i in range(4)]
    rows = [{"embodiment": "toyarm", "trajectory": t.name, "camera": str(CAM), "out": f"v/{t.stem}.mkv"} for t in trajs]
    rows.append({"embodiment": "toyarm", "trajectory": "nope.npz", "camera": str(CAM), "out": "v/nope.mkv"})
    manifest = write_jsonl(tmp_path / "m.jsonl", rows)
    code, out, err = run(capsys, "render", "--manifest", manifest, "--workers", "2", "--size", "64x36", "--json")
    assert code == 1, err  # one episode failed
    data = json.loads(out)
    assert data["summary"]["episodes"] == 5 and data["summary"]["ok"] == 4 and data["summary"]["failed"] == 1
    assert data["summary"]["frames"] == 20
    bad = [e for e in data["episodes"] if not e["ok"]]
    assert len(bad) == 1 and "nope.npz" in bad[0]["error"]
    for t in trajs:
        np.testing.assert_array_equal(read_video(tmp_path / "v" / f"{t.stem}.mkv"), direct(t, (64, 36)))
    code, out, err = run(capsys, "render", "--manifest", manifest, "--size", "64x36")  # a rerun: nothing changed
    assert code == 1 and "rendered 4 of 5 episodes (1 failed, 4 unchanged and skipped), 0 frames" in out
    assert "error: episode 4" in err
    code, out, err = run(capsys, "render", "--manifest", manifest, "--size", "64x36", "--no-resume")
    assert code == 1 and "rendered 4 of 5 episodes (1 failed), 20 frames" in out and "error: episode 4" in err


def test_trajectories_folder_through_the_cli(tmp_path, capsys):
    d = tmp_path / "trajs"
    d.mkdir()
    short_traj(d, "x.npz", T=3)
    code, out, err = run(
        capsys,
        "render",
        "--embodiment",
        "toyarm",
        "--trajectories",
        d,
        "--camera",
        CAM,
        "--out",
        tmp_path / "vids",
        "--size",
        "64x36",
        "--format",
        "png",
    )
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "vids" / "x").iterdir()) == [f"frame_{i:06d}.png" for i in range(3)]


def test_batch_problems_stop_before_anything_is_rendered(tmp_path):
    a = short_traj(tmp_path, "a.npz")
    same = [
        EpisodeSpec("toyarm", str(a), str(CAM), str(tmp_path / "x.mp4")),
        EpisodeSpec("toyarm", str(a), str(CAM), str(tmp_path / "x.mp4")),
    ]
    with pytest.raises(OutputPathError, match="episode 1 writes the same output as episode 0"):
        render_many(same)
    (tmp_path / "afile").write_text("")
    under = [
        EpisodeSpec("toyarm", str(a), str(CAM), str(tmp_path / "new" / "ok.mp4")),
        EpisodeSpec("toyarm", str(a), str(CAM), str(tmp_path / "afile" / "sub" / "x.mp4")),
    ]
    with pytest.raises(OutputPathError, match="afile is a file, not a folder"):
        render_many(under)
    suffixless = [
        EpisodeSpec("toyarm", str(a), str(CAM), str(tmp_path / "new" / "ok.mp4")),
        EpisodeSpec("toyarm", str(a), str(CAM), str(tmp_path / "x")),
    ]
    with pytest.raises(OutputPathError, match="no suffix"):
        render_many(suffixless)
    assert not (tmp_path / "new").exists()  # nothing rendered, no folder made


# ------------------------------------------------------------------ output checks


@pytest.mark.parametrize(
    "out, message",
    [
        ("skel", "no suffix.*trailing /, --format png"),
        ("skel.avi", "unsupported suffix '.avi'"),
        ("afile/skel.mp4", "afile is a file, not a folder"),
        ("afile/deeper/skel.mp4", "afile is a file, not a folder"),
        ("missing/skel.mp4", "folder .*missing does not exist"),
    ],
)
def test_bad_outputs_are_refused_before_any_rendering(tmp_path, capsys, monkeypatch, out, message):
    import oscar_core.render.skeleton_stream as rs

    def boom(*a, **k):
        raise AssertionError("rendering started")

    monkeypatch.setattr(rs.SKELETON, "iter_chunks", boom)
    (tmp_path / "afile").write_text("")
    code, _, err = run(
        capsys, "render", "--embodiment", "toyarm", "--trajectory", TRAJ, "--camera", CAM, "--out", tmp_path / out
    )
    assert code == 2 and "rendering started" not in err
    assert __import__("re").search(message, err), err


def test_odd_h264_size_is_refused_before_rendering_and_png_is_an_explicit_choice(tmp_path, capsys, monkeypatch):
    import oscar_core.render.skeleton_stream as rs

    real = rs.SKELETON.iter_chunks
    calls = []
    monkeypatch.setattr(rs.SKELETON, "iter_chunks", lambda *a, **k: calls.append(1) or real(*a, **k))
    code, _, err = run(
        capsys,
        "render",
        "--embodiment",
        "toyarm",
        "--trajectory",
        TRAJ,
        "--camera",
        CAM,
        "--out",
        tmp_path / "odd.mp4",
        "--size",
        "65x37",
    )
    assert code == 2 and "even width and height, found 65x37" in err and calls == []
    code, out, err = run(
        capsys,
        "render",
        "--embodiment",
        "toyarm",
        "--trajectory",
        short_traj(tmp_path, "s.npz", T=2),
        "--camera",
        CAM,
        "--out",
        tmp_path / "frames",
        "--format",
        "png",
        "--size",
        "65x37",
    )
    assert code == 0, err
    assert len(list((tmp_path / "frames").glob("*.png"))) == 2 and calls == [1]


def test_strict_turns_an_empty_view_into_an_error_and_leaves_nothing(tmp_path, capsys):
    cam = json.loads(CAM.read_text())
    m = np.array(cam["extrinsic"]["matrix"])
    m[:3, :3] = m[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # turn round: looks away from the robot
    cam["extrinsic"]["matrix"] = m.tolist()
    away = tmp_path / "away.json"
    away.write_text(json.dumps(cam))
    traj = short_traj(tmp_path, "s.npz", T=4)
    args = ["render", "--embodiment", "toyarm", "--trajectory", traj, "--camera", away, "--size", "64x36"]
    code, out, err = run(capsys, *args, "--out", tmp_path / "warn.mp4")
    assert code == 0 and "warning: EmptyViewWarning" in err and "in 4 of 4 frames: 0-3" in err
    code, out, err = run(capsys, *args, "--out", tmp_path / "strict.mp4", "--strict")
    assert code == 2 and "sees nothing" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["away.json", "s.npz", "warn.mp4"]


# ------------------------------------------------------------------ killed renders


@pytest.mark.slow
@pytest.mark.parametrize("out", ["long.mp4", "long/"])
def test_a_killed_render_leaves_no_output_and_the_next_run_clears_its_temporaries(tmp_path, out):
    traj = load_trajectory(TRAJ)
    long = traj.replace(q=np.tile(traj.q, (60, 1)), gripper=np.tile(traj.gripper, (60, 1)), timestamps=None)
    save_trajectory(long, tmp_path / "long.npz")
    target = tmp_path / out.rstrip("/")
    cmd = [
        sys.executable,
        "-m",
        "oscar_core.cli",
        "render",
        "--embodiment",
        "toyarm",
        "--camera",
        str(CAM),
        "--size",
        "320x180",
        "--out",
        f"{tmp_path}/{out}",
    ]
    proc = subprocess.Popen(cmd + ["--trajectory", str(tmp_path / "long.npz")], stderr=subprocess.PIPE)
    deadline = time.time() + 60
    while time.time() < deadline and proc.poll() is None and not [p for p in tmp_path.iterdir() if ".tmp" in p.name]:
        time.sleep(0.05)
    time.sleep(0.3)  # mid-encode
    assert proc.poll() is None, f"the render ended before it could be killed: {proc.stderr.read().decode()}"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    left = [p.name for p in tmp_path.iterdir() if ".tmp" in p.name]
    assert len(left) == 1 and left[0].startswith(f".{target.name}.{proc.pid}.")
    assert not target.exists()
    short = short_traj(tmp_path, "short.npz", T=3)
    subprocess.run(cmd + ["--trajectory", str(short)], check=True, capture_output=True)
    assert target.exists()
    assert [p.name for p in tmp_path.iterdir() if ".tmp" in p.name] == []


def test_a_live_writers_temporary_is_never_removed(tmp_path):
    from oscar_core.media.video import VideoWriter, remove_stale_temporaries

    target = tmp_path / "x.mkv"
    w = VideoWriter(target, 10)
    dead = tmp_path / f".x.mkv.{2**22 + 12345}.abc.tmp.mkv"  # a pid that is not running
    dead.write_bytes(b"")
    assert remove_stale_temporaries(target) == [dead]
    assert w.tmp.exists()  # ours (same pid) stays
    w.write(np.zeros((2, 4, 4, 3), np.uint8))
    w.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.mkv"]


# ------------------------------------------------------------------ start-up


def imported_by(code: str) -> set[str]:
    probe = (
        "import sys, io, contextlib\n"
        + code
        + "\nprint(' '.join(m for m in ('torch', 'matplotlib', 'pytorch_kinematics', 'scipy', 'av', 'cv2') "
        "if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    return set(out.split())


@pytest.mark.slow
def test_help_and_listing_import_no_heavy_libraries_and_a_render_no_torch(tmp_path):
    quiet = "with contextlib.redirect_stdout(io.StringIO()):\n    try: main({})\n    except SystemExit: pass"
    head = "from oscar_core.cli import main\n"
    assert imported_by(head + quiet.format("['--help']")) == set()
    assert imported_by(head + quiet.format("['embodiments', '--json']")) == set()
    render = quiet.format(
        repr(
            [
                "render",
                "--embodiment",
                "toyarm",
                "--trajectory",
                str(short_traj(tmp_path, "one.npz", T=1)),
                "--camera",
                str(CAM),
                "--out",
                str(tmp_path / "one.mp4"),
            ]
        )
    )
    assert imported_by(head + render) == {"av", "cv2"}
    assert (tmp_path / "one.mp4").exists()


# ------------------------------------------------------------------ small CLI fixes


def test_embodiments_json_gives_each_joint_order(capsys):
    code, out, _ = run(capsys, "embodiments", "--json")
    assert code == 0
    for e in json.loads(out)["embodiments"]:
        assert e["joint_names"] == list(get_embodiment(e["name"]).joint_names)
        assert len(e["joint_names"]) == e["joints"]


def test_piping_into_a_closed_reader_exits_quietly():
    proc = subprocess.Popen(
        [sys.executable, "-m", "oscar_core.cli", "embodiments", "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.close()  # like `| head` that has already gone
    err = proc.stderr.read().decode()
    proc.wait()
    assert "Traceback" not in err and "BrokenPipe" not in err and proc.returncode == 1


def test_contact_sheet_names_rows_outside_the_frames():
    from oscar_core.demo import contact_sheet

    video = np.zeros((3, 20, 30, 3), np.uint8)
    video[:, 5:15, 5:25] = 200
    plain = contact_sheet([video, video], columns=2)
    named = contact_sheet([video, video], columns=2, labels=["franka", "kuka"])
    band = named.shape[1] - plain.shape[1]
    assert band > 20
    np.testing.assert_array_equal(named[:, band:], plain)  # frames untouched
    assert (named[:, :band] > 100).sum() > 20  # text in the band
    assert not np.array_equal(named[4:24, :band], named[28:48, :band])  # two different names


def test_demo_lists_plugins_it_skipped_and_why(tmp_path):
    from oscar_core.demo import run_demo
    from oscar_core.plugin.registry import Registry

    bad = tmp_path / "broken_plugin.py"
    bad.write_text("raise ImportError('needs a library that is not installed')\n")
    lines = []
    summary = run_demo(
        tmp_path / "demo",
        size=(64, 36),
        registry=Registry(plugin_paths=[bad], warn=False),
        names=["toyarm"],
        log=lines.append,
    )
    assert any("skipped plugin" in line and "not installed" in line for line in lines), lines
    assert any("not installed" in s["reason"] for s in summary["skipped"])


def test_an_existing_frame_folder_fails_its_episode_only(tmp_path):
    a = short_traj(tmp_path, "a.npz", T=2)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("mine")
    specs = [
        EpisodeSpec("toyarm", str(a), str(CAM), f"{tmp_path}/full/", (64, 36)),
        EpisodeSpec("toyarm", str(a), str(CAM), f"{tmp_path}/fresh/", (64, 36)),
    ]
    r = render_many(specs)
    assert [x.ok for x in r] == [False, True] and "not an empty folder" in r[0].error
    assert [p.name for p in (tmp_path / "full").iterdir()] == ["keep.txt"]
    assert len(list((tmp_path / "fresh").glob("*.png"))) == 2


def test_render_episode_reports_warnings_instead_of_printing_them(tmp_path, recwarn):
    traj = load_trajectory(TRAJ).time_slice(0, 3)
    q = traj.q.copy()
    q[1, 0] = 50.0  # far beyond the first joint's limit
    save_trajectory(traj.replace(q=q), tmp_path / "over.npz")
    r = render_episode(EpisodeSpec("toyarm", str(tmp_path / "over.npz"), str(CAM), str(tmp_path / "o.mkv"), (64, 36)))
    assert r.ok and r.frames == 3 and any("JointLimitWarning" in w and "beyond its limits" in w for w in r.warnings)
    assert len(recwarn) == 0


def test_render_draws_the_condition_style_and_refuses_a_bad_one_before_writing(tmp_path, capsys):
    from oscar_core.render.raster import SkeletonStyle

    traj = short_traj(tmp_path, "t.npz")
    bold = {"gripper_radius_open": 27, "gripper_radius_closed": 14}
    base = ["render", "--embodiment", "toyarm", "--trajectory", traj, "--camera", CAM, "--size", "64x36"]
    code, out, err = run(capsys, *base, "--out", tmp_path / "bold.mkv", "--condition-style", json.dumps(bold))
    assert code == 0, err
    want = render_skeleton_video(
        get_embodiment("toyarm"), load_trajectory(traj), load_camera(CAM), (64, 36), style=SkeletonStyle(**bold)
    )
    got = read_video(tmp_path / "bold.mkv")
    np.testing.assert_array_equal(got, want)  # FFV1 is lossless
    assert (got != direct(traj, (64, 36))).any()  # the style changed the picture
    # the same style through a batch (the fingerprint holds it: a batch in another style renders again)
    folder = tmp_path / "trajs"
    folder.mkdir()
    save_trajectory(load_trajectory(traj), folder / "a.npz")
    (folder / "camera.json").write_text(Path(CAM).read_text())
    batch = ["render", "--embodiment", "toyarm", "--trajectories", folder, "--size", "64x36", "--format", "mkv"]
    assert run(capsys, *batch, "--out", tmp_path / "videos")[0] == 0
    assert run(capsys, *batch, "--out", tmp_path / "videos", "--condition-style", json.dumps(bold))[0] == 0
    np.testing.assert_array_equal(read_video(tmp_path / "videos" / "a.mkv"), want)
    for bad, message in [
        ("{not json", "--condition-style: expected a JSON mapping of style fields"),
        ('{"gripper_radius_open": -2}', "condition_style.gripper_radius_open: expected a finite number > 0"),
        ('{"size": 1}', "found unknown keys ['size']"),
    ]:
        for args in (base + ["--out", tmp_path / "bad.mkv"], batch + ["--out", tmp_path / "bad"]):
            code, out, err = run(capsys, *args, "--condition-style", bad)
            assert code == 2 and message in err and err.count("\n") == 1, err
        assert not (tmp_path / "bad.mkv").exists() and not (tmp_path / "bad").exists()
    # a style draws the skeleton: another condition with a style is refused, nothing written
    code, out, err = run(
        capsys, *base, "--out", tmp_path / "m.mkv", "--condition", "capsules", "--condition-style", "{}"
    )
    assert code == 2 and "expected the skeleton condition" in err and not (tmp_path / "m.mkv").exists()
