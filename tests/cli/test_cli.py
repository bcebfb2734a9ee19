"""The `oscar` command: listing, rendering, overlays, the demo and bad input."""

import json

import numpy as np
import pytest
from _paths import TOYARM_ASSETS

from oscar_core import load_trajectory, save_trajectory
from oscar_core.cli import main
from oscar_core.media.video import read_video, write_video

TRAJ, CAM = TOYARM_ASSETS / "example_trajectory.npz", TOYARM_ASSETS / "example_camera.json"


def short_trajectory(folder, frames: int = 9):
    """The first ``frames`` frames of the bundled example (an overlay's cost grows with its frames; what it
    checks does not)."""
    src = np.load(TRAJ)
    path = folder / f"first{frames}.npz"
    np.savez(path, **{k: src[k][:frames] if k in ("q", "gripper") else src[k] for k in src.files})
    return path


def run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_embodiments_table_and_json(capsys):
    code, out, _ = run(capsys, "embodiments")
    assert code == 0
    header, *rows = out.splitlines()
    assert header.split()[:2] == ["name", "joints"]
    toy = [r for r in rows if r.startswith("toyarm")][0]
    assert toy.split()[1] == "4" and "Apache-2.0" in toy and "oscar-toyarm" in toy
    code, out, _ = run(capsys, "embodiments", "--json")
    data = json.loads(out)
    entry = [e for e in data["embodiments"] if e["name"] == "toyarm"][0]
    assert entry["joints"] == 4 and entry["grippers"] == ["gripper"] and entry["distribution"] == "oscar-toyarm"


def test_render_mp4_lossless_and_png(tmp_path, capsys):
    code, out, err = run(
        capsys,
        "render",
        "--embodiment",
        "toyarm",
        "--trajectory",
        TRAJ,
        "--camera",
        CAM,
        "--out",
        tmp_path / "skel.mp4",
        "--size",
        "512x288",
    )
    assert code == 0, err
    video = read_video(tmp_path / "skel.mp4")
    assert video.shape == (81, 288, 512, 3)
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
        tmp_path / "skel.mkv",
        "--size",
        "320x180",
    )
    assert code == 0, err
    lossless = read_video(tmp_path / "skel.mkv")
    from oscar_core import get_embodiment, load_camera, load_trajectory, render_skeleton_video

    direct = render_skeleton_video(get_embodiment("toyarm"), load_trajectory(TRAJ), load_camera(CAM), (320, 180))
    np.testing.assert_array_equal(lossless, direct)
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
        str(tmp_path / "frames") + "/",
        "--size",
        "320x180",
    )
    assert code == 0, err
    np.testing.assert_array_equal(read_video(tmp_path / "frames"), direct)


def test_overlay_blends_over_real_video(tmp_path, capsys):
    rng = np.random.default_rng(0)
    rgb = np.broadcast_to(rng.integers(40, 200, (1, 360, 640, 3), dtype=np.uint8), (9, 360, 640, 3))
    write_video(tmp_path / "rgb.mkv", rgb, 15)
    code, _, err = run(
        capsys,
        "render",
        "--embodiment",
        "toyarm",
        "--trajectory",
        short_trajectory(tmp_path),
        "--camera",
        CAM,
        "--out",
        tmp_path / "check.mkv",
        "--overlay",
        tmp_path / "rgb.mkv",
    )
    assert code == 0, err
    out = read_video(tmp_path / "check.mkv")
    assert out.shape == (9, 360, 640, 3)
    skeleton_px = np.any(out != rgb, axis=-1)
    assert 0.001 < skeleton_px.mean() < 0.2  # the skeleton changes a few pixels; the rest is the real frame
    # --condition-style reaches the overlay: a gripper indicator 3x larger covers more of the real frame (9 frames)
    save_trajectory(load_trajectory(TRAJ).time_slice(0, 9), tmp_path / "short.npz")
    args = ["render", "--embodiment", "toyarm", "--trajectory", tmp_path / "short.npz", "--camera", CAM]
    args += ["--overlay", tmp_path / "rgb.mkv"]
    bold = '{"gripper_radius_open": 27, "gripper_radius_closed": 12}'
    changed = []
    for name, style in (("plain", []), ("bold", ["--condition-style", bold])):
        code, _, err = run(capsys, *args, "--out", tmp_path / f"{name}.mkv", *style)
        assert code == 0, err
        changed.append(np.any(read_video(tmp_path / f"{name}.mkv") != rgb[:9], axis=-1).mean())
    assert changed[1] > 1.2 * changed[0], changed


def test_overlay_too_short(tmp_path, capsys):
    write_video(tmp_path / "short.mkv", np.zeros((8, 360, 640, 3), np.uint8), 15)
    code, _, err = run(
        capsys,
        "render",
        "--embodiment",
        "toyarm",
        "--trajectory",
        short_trajectory(tmp_path),
        "--camera",
        CAM,
        "--out",
        tmp_path / "x.mp4",
        "--overlay",
        tmp_path / "short.mkv",
    )
    assert code == 2 and "short.mkv" in err and "at least 9 frames" in err


@pytest.mark.parametrize(
    "case", ["no_intrinsics", "unwritable", "unknown_embodiment", "bad_size", "wrong_embodiment_camera"]
)
def test_bad_input_is_a_clear_error(tmp_path, capsys, case):
    cam = json.loads(CAM.read_text())
    out = tmp_path / "out.mp4"
    args = ["render", "--embodiment", "toyarm", "--trajectory", TRAJ, "--camera", CAM, "--out", out]
    if case == "no_intrinsics":
        del cam["intrinsics"]
        (tmp_path / "cam.json").write_text(json.dumps(cam))
        args[6] = tmp_path / "cam.json"
        expect = ["cam.json", "intrinsics"]
    elif case == "unwritable":
        args[8] = tmp_path / "missing_dir" / "out.mp4"
        expect = ["missing_dir", "cannot write"]
    elif case == "unknown_embodiment":
        args[2] = "robbie"
        expect = ["unknown embodiment 'robbie'", "toyarm"]
    elif case == "bad_size":
        args += ["--size", "512by288"]
        expect = ["--size", "WIDTHxHEIGHT"]
    else:
        cam["embodiment"] = "franka"
        (tmp_path / "cam.json").write_text(json.dumps(cam))
        args[6] = tmp_path / "cam.json"
        expect = ["cam.json", "embodiment", "'toyarm'", "'franka'"]
    code, _, err = run(capsys, *args)
    assert code == 2
    for fragment in expect:
        assert fragment in err, err
    assert list(tmp_path.glob("**/*.mp4")) == []  # nothing half-written


def test_demo_writes_videos_and_contact_sheet(tmp_path, capsys):
    # the toy world's row is run_demo's (tests/toyworld/test_toyworld_rollouts.py, with a tiny model; CI's make demo
    # with oscar-toy): here the command's own part, every embodiment's video and the sheet
    code, out, err = run(capsys, "demo", "--out", tmp_path / "demo", "--no-toy-world")
    assert code == 0, err
    summary = json.loads((tmp_path / "demo" / "summary.json").read_text())
    assert "toy_world" not in summary and not (tmp_path / "demo" / "toyworld_rollout.mp4").exists()
    names = {v["embodiment"] for v in summary["videos"]}
    assert "toyarm" in names
    assert read_video(tmp_path / "demo" / "toyarm.mp4").shape == (81, 288, 512, 3)
    import cv2

    sheet = cv2.imread(str(tmp_path / "demo" / "contact_sheet.png"))
    assert sheet is not None and sheet.shape[0] >= 288 * len(names)


def test_overlay_frames_are_fitted_like_the_calibration(tmp_path, capsys):
    """--size of another aspect ratio: the real frames are centre-cropped as the intrinsics are, not stretched."""
    from oscar_core import get_embodiment, load_camera, load_trajectory, overlay_skeleton, render_skeleton_video
    from oscar_core.render.skeleton_video import fit_image

    # a frame whose left and right thirds differ, so a stretch and a crop give different pixels
    rgb = np.zeros((9, 360, 640, 3), np.uint8)
    rgb[:, :, :213] = (200, 40, 40)
    rgb[:, :, 427:] = (40, 40, 200)
    write_video(tmp_path / "rgb.mkv", rgb, 15)
    traj = short_trajectory(tmp_path)
    code, _, err = run(
        capsys,
        "render",
        "--embodiment",
        "toyarm",
        "--trajectory",
        traj,
        "--camera",
        CAM,
        "--out",
        tmp_path / "check.mkv",
        "--overlay",
        tmp_path / "rgb.mkv",
        "--size",
        "320x240",
    )
    assert code == 0, err
    skeleton = render_skeleton_video(get_embodiment("toyarm"), load_trajectory(traj), load_camera(CAM), (320, 240))
    fitted = np.stack([fit_image(f, 320, 240, "crop") for f in rgb])
    np.testing.assert_array_equal(read_video(tmp_path / "check.mkv"), overlay_skeleton(skeleton, fitted))
    assert not np.array_equal(fitted[0], fit_image(rgb[0], 320, 240, "stretch"))
