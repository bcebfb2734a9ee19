"""`oscar toyworld example`: the documented two-command rollout of oscar-toy runs exactly as printed, its files are
the toy world's own episode; `--first-frame` takes a video; `toyworld policy-eval` runs on every body the toy world
accepts or refuses it before writing anything."""

import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _paths import REPO

from oscar_core.camera import load_camera
from oscar_core.cli import main
from oscar_core.errors import InputFileError
from oscar_core.kinematics.trajectory import load_trajectory
from oscar_core.media.video import read_video, write_video
from oscar_core.model.image import read_first_frame, read_image
from oscar_core.plugin.registry import Registry
from oscar_core.toyworld.motion import ToyWorldError
from oscar_core.toyworld.policy_eval import plan_session, policy_eval_refusal, session_rng
from oscar_core.toyworld.policy_eval_write import write_policy_eval
from oscar_core.train.clips import ClipSet

#: The two commands of the example, as docs/toyworld.md (and the README) print them.
EXAMPLE = "oscar toyworld example --out toy_example"
ROLLOUT = (
    "oscar rollout --model oscar-toy --embodiment toyarm --first-frame toy_example/first_frame.png "
    "--trajectory toy_example/trajectory.npz --camera toy_example/camera.json --out toy_rollout.mp4"
)


def _docs_commands() -> list[str]:
    """Every `oscar ...` command of docs/toyworld.md's bash blocks, continuation lines joined."""
    text = (REPO / "docs" / "toyworld.md").read_text()
    out = []
    for block in text.split("```bash")[1:]:
        body = block.split("```")[0].replace("\\\n", " ")
        out += [" ".join(line.split("#")[0].split()) for line in body.splitlines() if line.strip().startswith("oscar ")]
    return out


def test_the_docs_print_the_example_commands_verbatim():
    cmds = _docs_commands()
    assert EXAMPLE in cmds and ROLLOUT in cmds
    assert cmds.index(EXAMPLE) + 1 == cmds.index(ROLLOUT)


@pytest.mark.slow
def test_the_documented_example_runs_verbatim_in_a_fresh_folder(tmp_path):
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    for cmd in (EXAMPLE, ROLLOUT):
        done = subprocess.run(shlex.split(cmd), cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, f"{cmd}\n{done.stderr[-3000:]}"
        assert "Traceback" not in done.stderr
    video = read_video(tmp_path / "toy_rollout.mp4")
    assert video.shape == (17, 64, 64, 3)
    first = read_image(tmp_path / "toy_example" / "first_frame.png")
    # frame 0 of the rollout is the given first frame through the VAE and H.264: close, not equal
    mse = np.mean((video[0].astype(float) - first.astype(float)) ** 2)
    assert 10 * np.log10(255**2 / mse) > 18, "the rollout does not start from the example's first frame"


def test_the_example_is_the_toy_worlds_own_episode(tmp_path):
    """first_frame.png, trajectory.npz and camera.json equal frame 0, trajectory and camera of held-out episode 9 of
    `toyworld generate` with the same seed (a second path through the generator, the clip-set writer and reader)."""
    assert main(["toyworld", "example", "--out", str(tmp_path / "ex"), "--seed", "3", "--json"]) == 0
    assert (
        main(
            [
                "toyworld",
                "generate",
                "--embodiments",
                "toyarm",
                "--episodes",
                "10",
                "--seed",
                "3",
                "--out",
                str(tmp_path / "clips"),
                "--no-skeleton",
                "--json",
            ]
        )
        == 0
    )
    cs = ClipSet(tmp_path / "clips")
    rec = next(r for r in cs if r.meta["episode"] == 9)
    assert rec.meta["split"] == "heldout"
    clip = cs.load(rec, skeleton=False)
    np.testing.assert_array_equal(read_image(tmp_path / "ex" / "first_frame.png"), clip.rgb[0])
    traj = load_trajectory(tmp_path / "ex" / "trajectory.npz")
    np.testing.assert_allclose(traj.q, clip.trajectory.q, atol=1e-12)
    assert traj.joint_names == clip.trajectory.joint_names and traj.fps == clip.trajectory.fps == 10.0
    cam = load_camera(tmp_path / "ex" / "camera.json")
    np.testing.assert_allclose(cam.world_to_cv(), clip.camera.world_to_cv(), atol=1e-9)
    assert (cam.intrinsics.width, cam.intrinsics.height) == (64, 64)


def test_example_refuses_bad_input_before_writing(tmp_path, capsys):
    assert main(["toyworld", "example", "--out", str(tmp_path / "m"), "--embodiment", "mano"]) == 2
    assert "reads its skeleton from keypoints" in capsys.readouterr().err and not (tmp_path / "m").exists()
    (tmp_path / "f").write_text("x")
    assert main(["toyworld", "example", "--out", str(tmp_path / "f")]) == 2
    assert f"{tmp_path / 'f'}: cannot write output: it is a file, expected a folder" in capsys.readouterr().err


# ------------------------------------------------------------------ --first-frame: an image or a video's frame 0


def _frames(n=5, h=48, w=64):
    rng = np.random.default_rng(1)
    return rng.integers(0, 256, (n, h, w, 3), dtype=np.uint8)


def test_a_video_first_frame_is_its_frame_0(tmp_path):
    frames = _frames()
    write_video(tmp_path / "clip.mkv", frames, 10.0)  # lossless: frame 0 exactly
    np.testing.assert_array_equal(read_image(tmp_path / "clip.mkv"), frames[0])
    write_video(tmp_path / "clip.mp4", frames, 10.0)
    got = read_image(tmp_path / "clip.mp4")
    assert got.shape == (48, 64, 3)
    err = [np.abs(got.astype(int) - f.astype(int)).mean() for f in frames]
    assert int(np.argmin(err)) == 0  # nearest to frame 0 of all frames (H.264 is lossy)


def test_bad_first_frames_name_the_file_and_what_was_expected(tmp_path):
    (tmp_path / "junk.mp4").write_bytes(b"not a video at all")
    with pytest.raises(
        InputFileError,
        match=r"junk.mp4: field 'video frame 0': expected a readable image \(PNG, "
        r"JPEG\) or video .* found a file that does not decode as a video",
    ):
        read_image(tmp_path / "junk.mp4")
    (tmp_path / "junk.png").write_bytes(b"not an image")
    with pytest.raises(InputFileError, match="junk.png: field 'image': .* found text"):
        read_image(tmp_path / "junk.png")
    with pytest.raises(InputFileError, match="field 'image': expected a file: .* found a folder"):
        read_image(tmp_path)
    with pytest.raises(InputFileError, match="no such file"):
        read_image(tmp_path / "missing.mkv")


def test_a_video_first_frame_is_checked_against_the_camera(tmp_path):
    from oscar_core.camera import Camera, Intrinsics

    write_video(tmp_path / "clip.mkv", _frames(), 10.0)
    cam = Camera(Intrinsics(50.0, 50.0, 32.0, 24.0, 64, 48), np.eye(4))
    np.testing.assert_array_equal(read_first_frame(tmp_path / "clip.mkv", cam, "cam.json"), _frames()[0])
    small = Camera(Intrinsics(50.0, 50.0, 16.0, 12.0, 32, 24), np.eye(4))
    with pytest.raises(InputFileError, match=r"clip.mkv: field 'image size': expected 32x24 .* found 64x48"):
        read_first_frame(tmp_path / "clip.mkv", small, "cam.json")


# ------------------------------------------------------------------ policy-eval: every body the toy world accepts


def _toy_world_bodies():
    reg = Registry()
    return [n for n in reg.names()]


@pytest.mark.parametrize("name", _toy_world_bodies())
def test_policy_eval_plans_every_body_it_does_not_refuse(name):
    """A body the up-front check accepts plans its sessions (the first ones of seed 0 and 1); one it refuses gets
    one reason naming it."""
    emb = Registry().get(name)
    why = policy_eval_refusal(emb)
    if why is not None:
        assert f"embodiment {name!r}" in why
        return
    for seed in (0, 1):
        for i in range(3):
            for attempt in range(20):  # as write_policy_eval: a session no camera sees whole is drawn again
                try:
                    s = plan_session(emb, session_rng(seed, name, i, attempt), 64, 64, 17)
                    break
                except ToyWorldError:
                    raise
                except ValueError:
                    continue
            assert len(s.episodes) == 4


def test_agibot_g1_session_that_needed_more_candidates_now_plans():
    """Session 1 of agibot_g1 under seed 0, attempt 1 (its attempt 0 has no camera that sees the ball at both ends),
    has no place far enough among its first 768 configurations; more are drawn instead of failing the run."""
    emb = Registry().get("agibot_g1")
    s = plan_session(emb, session_rng(0, "agibot_g1", 1, 1), 64, 64, 17)
    assert np.linalg.norm(s.episodes[0].motion.object[0, :2] - s.ball[:2]) == 0.0  # the ball starts where planned
    with pytest.raises(ToyWorldError, match="found none in 768 sampled configurations"):
        plan_session(emb, session_rng(0, "agibot_g1", 1, 1), 64, 64, 17, n_candidates=768, rounds=1)


def test_policy_eval_refuses_hsr_up_front_naming_the_reason(tmp_path, capsys):
    out = tmp_path / "pe"
    code = main(["toyworld", "policy-eval", "--embodiments", "toyarm,hsr", "--sessions", "1", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert "embodiment 'hsr': its end-effector reaches the floor over a patch" in err
    assert "its base stays still in the toy world" in err and "6 ball radii" in err
    assert not out.exists() or not any(out.iterdir())  # toyarm's session was not written first
    with pytest.raises(ToyWorldError, match="no gripper|reads its skeleton"):
        write_policy_eval(tmp_path / "m", ["mano"], 1)
