"""`oscar rollout` and `oscar zoo list|pull` with the toy-arm plugin and a tiny exported model."""

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from _models import tiny_world_model
from _paths import TOYARM_ASSETS

import oscar_zoo
from oscar_core.errors import OscarError
from oscar_core.media.video import read_video
from oscar_core.model import ModelCard, OscarWorldModel
from oscar_core.model.cli import add_model_parsers, side_by_side_path
from oscar_core.model.tiny import build_tiny_transformer, build_tiny_vae
from oscar_zoo.cli import add_zoo_parsers
from oscar_zoo.testing import MockHub

TRAJ, CAM = (
    TOYARM_ASSETS / "example_trajectory.npz",
    TOYARM_ASSETS / "example_camera.json",
)  # 81 frames at 15 fps, 640x360


def run(capsys, *argv):
    """What `oscar` does with the commands of add_model_parsers (rollout) and add_zoo_parsers (zoo, encode-prompt)."""
    parser = argparse.ArgumentParser(prog="oscar")
    sub = parser.add_subparsers(dest="command", required=True)
    add_model_parsers(sub)
    add_zoo_parsers(sub)
    args = parser.parse_args([str(a) for a in argv])
    try:
        code = args.func(args)
    except (OscarError, ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=__import__("sys").stderr)
        code = 2
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(autouse=True)
def isolated(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hf-cache"))
    monkeypatch.setenv("OSCAR_ZOO_REGISTRY", str(tmp_path / "zoo.json"))
    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    model = tiny_world_model(skeleton_scale=0.05, name="tiny", chunk_frames=41, fps=15.0)
    return oscar_zoo.export(model, tmp_path_factory.mktemp("m") / "tiny")


@pytest.fixture(scope="module")
def first_frame(tmp_path_factory):
    path = tmp_path_factory.mktemp("img") / "first.png"
    img = np.random.default_rng(0).integers(0, 256, (360, 640, 3), dtype=np.uint8)
    cv2.imwrite(str(path), img)
    return path


def _args(model_dir, first_frame, out, *extra):
    return (
        "rollout",
        "--model",
        model_dir,
        "--embodiment",
        "toyarm",
        "--first-frame",
        first_frame,
        "--trajectory",
        TRAJ,
        "--camera",
        CAM,
        "--out",
        out,
        "--size",
        "64x32",
        "--steps",
        "1",
        "--no-progress",
        *extra,
    )


def test_rollout_writes_video_and_side_by_side(capsys, tmp_path, model_dir, first_frame):
    out = tmp_path / "video.mkv"
    code, stdout, err = run(capsys, *_args(model_dir, first_frame, out, "--json"))
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["frames"] == 81 and summary["chunks"] == 2 and summary["size"] == [64, 32]
    video = read_video(out)
    side = read_video(side_by_side_path(out))
    assert video.shape == (81, 32, 64, 3) and side.shape == (81, 32, 128, 3)
    np.testing.assert_array_equal(side[:, :, :64], video)  # left half: the rollout itself (lossless .mkv)


def test_the_python_function_writes_what_the_command_writes(capsys, tmp_path, model_dir, first_frame):
    """oscar rollout is RolloutRequest -> run_rollout -> print: the same frames and the same summary."""
    from oscar_core.model import RolloutRequest, run_rollout

    code, stdout, err = run(capsys, *_args(model_dir, first_frame, tmp_path / "cli.mkv", "--json", "--seed", "2"))
    assert code == 0, err
    seen = []
    result = run_rollout(
        RolloutRequest(
            model=str(model_dir),
            embodiment="toyarm",
            first_frame=str(first_frame),
            trajectory=str(TRAJ),
            camera=str(CAM),
            out=str(tmp_path / "api.mkv"),
            size="64x32",
            steps=1,
            seed=2,
            progress=False,
        ),
        notify=seen.append,
    )
    np.testing.assert_array_equal(read_video(result.out), read_video(tmp_path / "cli.mkv"))
    assert result.side_by_side == side_by_side_path(tmp_path / "api.mkv") and result.side_by_side.is_file()
    cli = json.loads(stdout)
    for key in ("rollout", "side_by_side", "timings"):
        cli.pop(key), result.summary.pop(key)
    assert result.summary == cli
    assert any(m.startswith("text: ") for m in seen) and set(result.timings) >= {"load", "sample", "wall"}


def test_first_frame_size_must_match_the_camera(capsys, tmp_path, model_dir):
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((100, 200, 3), np.uint8))
    code, _, err = run(capsys, *_args(model_dir, small, tmp_path / "v.mp4"))
    assert (
        code == 2 and "field 'image size': expected 640x360 (the image size of camera" in err and "found 200x100" in err
    )


def test_trajectory_shorter_than_one_chunk(capsys, tmp_path, model_dir, first_frame):
    code, _, err = run(capsys, *_args(model_dir, first_frame, tmp_path / "v.mp4", "--chunk-frames", "85"))
    assert code == 2 and "expected at least one chunk of 85 frames, found 81 frames; use chunk_frames=81" in err


def test_unknown_model_and_missing_prompt_embedding(capsys, tmp_path, model_dir, first_frame):
    code, _, err = run(capsys, *_args("nope", first_frame, tmp_path / "v.mp4"))
    assert code == 2 and "cosmos-predict2.5-2b, oscar-2b" in err
    code, _, err = run(
        capsys,
        *_args(model_dir, first_frame, tmp_path / "v.mp4", "--prompt", "wave", "--prompt-cache", tmp_path / "cache"),
    )
    assert code == 2 and "expected a cached embedding" in err and "--prompt-embeds" in err


def test_zoo_list_and_pull(capsys, tmp_path, model_dir, monkeypatch):
    code, out, _ = run(capsys, "zoo", "list")
    assert code == 0 and out.splitlines()[0].split()[:2] == ["name", "repo@revision"]
    assert "zywu2115/OSCAR-2B@main (unpinned)" in out
    code, out, _ = run(capsys, "zoo", "list", "--json")
    names = [m["name"] for m in json.loads(out)["models"]]
    assert names == ["cosmos-predict2.5-2b", "oscar-2b", "oscar-toy", "oscar-toy-fast"]
    with MockHub() as hub:
        hub.add_folder("me/tiny", model_dir)
        monkeypatch.setenv("HF_ENDPOINT", hub.url)  # read when the command runs, not at import
        code, out, err = run(capsys, "zoo", "pull", "me/tiny", "--json")
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")
    assert code == 0, err
    folder = Path(json.loads(out)["folder"])
    assert (folder / "oscar_model.json").is_file() and "models--me--tiny" in str(folder)
    assert json.loads(out)["lock"].endswith("oscar-locks/models--me--tiny/main.json")
    code, out, _ = run(capsys, "zoo", "pull", "me/tiny", "--offline")
    assert code == 0 and "verified" in out


def test_rollout_of_a_mesh_model_is_conditioned_on_the_mesh_video(capsys, tmp_path, first_frame):
    from oscar_core import get_embodiment, load_camera, load_trajectory
    from oscar_core.render.mesh import render_mesh_video

    model = tiny_world_model(skeleton_scale=0.05, name="tiny-mesh", chunk_frames=41, fps=15.0, condition="mesh")
    folder = oscar_zoo.export(model, tmp_path / "tiny-mesh")
    out = tmp_path / "video.mkv"
    code, _, err = run(capsys, *_args(folder, first_frame, out))
    assert code == 0, err
    from oscar_core.render.skeleton_video import overlay_skeleton

    side = read_video(side_by_side_path(out))  # right half: the condition video it was given, over the rollout
    mesh = render_mesh_video(get_embodiment("toyarm"), load_trajectory(TRAJ), load_camera(CAM), (64, 32))
    assert mesh.any()
    np.testing.assert_array_equal(side[:, :, 64:], overlay_skeleton(mesh, side[:, :, :64]))


def test_rollout_reports_its_fixed_costs_and_compile_decision(capsys, tmp_path, model_dir, first_frame):
    import time

    t0 = time.perf_counter()
    code, stdout, err = run(capsys, *_args(model_dir, first_frame, tmp_path / "v.mkv", "--json", "--no-side-by-side"))
    outer = time.perf_counter() - t0
    assert code == 0, err
    summary = json.loads(stdout)
    timings = summary["timings"]
    parts = ("startup", "import", "load", "render", "text", "compile", "encode", "sample", "decode", "write")
    assert set(timings) == {*parts, "wall"}
    assert all(timings[k] >= 0 for k in parts) and timings["sample"] > 0 and timings["decode"] > 0
    assert sum(timings[k] for k in parts) <= timings["wall"] + 0.01  # each rounded to ms
    # in this test process "startup" is the whole pytest session so far: the command itself took < outer
    assert timings["wall"] - timings["startup"] <= outer + 0.01
    assert summary["compile"].startswith("compile=auto: eager on cpu") and summary["dtype"] == "torch.float32"
    code, stdout, _ = run(
        capsys, *_args(model_dir, first_frame, tmp_path / "w.mkv", "--json", "--no-side-by-side", "--no-compile")
    )
    assert code == 0 and json.loads(stdout)["compile"] == "compile=never"


def test_a_video_first_frame_rolls_out_as_its_frame_0(capsys, tmp_path, model_dir, first_frame):
    """--first-frame takes a video: the rollout from a lossless video whose frame 0 is the image equals the rollout
    from the image itself (same seed); the later frames of the video play no part."""
    img = cv2.imread(str(first_frame))[..., ::-1]
    frames = np.stack([img, 255 - img, img // 2])
    from oscar_core.media.video import write_video

    write_video(tmp_path / "episode.mkv", frames, 15.0)
    outs = []
    for name, src in (("from_image", first_frame), ("from_video", tmp_path / "episode.mkv")):
        out = tmp_path / f"{name}.mkv"
        code, _, err = run(capsys, *_args(model_dir, src, out, "--no-side-by-side"))
        assert code == 0, err
        outs.append(read_video(out))
    np.testing.assert_array_equal(outs[0], outs[1])


def test_rollout_uses_the_card_sampler_unless_a_flag_says_otherwise(capsys, tmp_path, first_frame):
    card = ModelCard(name="tiny-card", chunk_frames=41, fps=15.0, sampler={"steps": 1, "guidance": 2.0})
    folder = oscar_zoo.export(
        OscarWorldModel.from_modules(build_tiny_transformer(seed=0), build_tiny_vae(seed=0), card), tmp_path / "m"
    )
    args = [a for a in _args(folder, first_frame, tmp_path / "v.mkv", "--json") if a not in ("--steps", "1")]
    code, stdout, err = run(capsys, *args)
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["steps"] == 1 and summary["guidance"] == {"w": 2.0, "form": "diffusers"}
    assert (
        "sampler: steps 1 (model card), guidance 2 (model card), guidance form diffusers (library default), "
        "preset none (library default)"
    ) in err
    code, stdout, err = run(capsys, *args, "--guidance", "0.5", "--guidance-form", "standard")
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["guidance"] == {"w": 0.5, "form": "standard"} and summary["sampler_sources"]["guidance"] == "given"
    assert "guidance 0.5 (flag), guidance form standard (flag)" in err
