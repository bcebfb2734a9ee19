"""The calibration score: 1 for a video that is the rendered body itself, 0 for a camera that sees no robot,
and on the toy world the true camera above cameras moved by centimetres or turned by degrees.

The toy world draws its robots with the capsule body the score renders, so its episodes with their true
cameras are the known answer. ``python benchmarks/calibration.py score`` measures the separation on 18
episodes (docs/calibration.md); these tests take the first episode of each robot. Moves along the viewing
direction of 2 and 5 cm are left out here: the benchmark shows the score does not always see them at 160 px.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from oscar_core import get_embodiment, save_camera, save_trajectory
from oscar_core.calibration.score import ScoreConfig, calibration_score, motion_iou, perturb_camera
from oscar_core.cli import main
from oscar_core.media.video import write_video
from oscar_core.render.capsules import render_capsule_video
from oscar_core.toyworld.episode import episode_rng, make_episode

SIZE, FRAMES = (160, 120), 24

WRONG = (
    [(f"{d} cm along {a}", np.eye(3)[k] * d / 100, np.zeros(3)) for d in (2, 5, 10) for k, a in enumerate("xy")]
    + [("10 cm along z", np.array([0, 0, 0.1]), np.zeros(3))]
    + [(f"{d} deg about {a}", np.zeros(3), np.eye(3)[k] * d) for d in (2, 5) for k, a in enumerate("xyz")]
)


@pytest.fixture(scope="module", params=["toyarm", "franka", "kuka"])
def episode(request):
    emb = get_embodiment(request.param)
    return emb, make_episode(emb, episode_rng(0, request.param, 0), *SIZE, FRAMES, 10.0)


def test_the_true_camera_scores_above_every_wrong_one(episode):
    emb, ep = episode
    true = calibration_score(ep.rgb, emb, ep.trajectory, ep.camera)
    assert 0.6 < true.score <= 1.0 and true.pairs >= 15
    for label, shift, turn in WRONG:
        wrong = calibration_score(ep.rgb, emb, ep.trajectory, perturb_camera(ep.camera, shift, turn)).score
        assert true.score > wrong, label


def test_a_video_of_the_body_itself_scores_one_and_a_still_video_zero():
    emb = get_embodiment("franka")
    ep = make_episode(emb, episode_rng(0, "franka", 1), *SIZE, 12, 10.0)
    body = render_capsule_video(emb, ep.trajectory, ep.camera)
    res = calibration_score(body, emb, ep.trajectory, ep.camera)
    assert res.score == 1.0 and all(r["iou"] == 1.0 for r in res.per_pair if r["counted"])
    still = np.repeat(ep.rgb[:1], len(ep.rgb), axis=0)
    assert calibration_score(still, emb, ep.trajectory, ep.camera).score == 0.0
    # a camera turned away sees no robot: its pairs still count (the robot moves) and score 0
    away = perturb_camera(ep.camera, rotate_deg=(0, 180, 0))
    res = calibration_score(ep.rgb, emb, ep.trajectory, away)
    assert res.pairs > 0 and res.score == 0.0 and all(r["render_px"] == 0 for r in res.per_pair)


def test_a_robot_that_never_moves_has_no_score():
    emb = get_embodiment("toyarm")
    ep = make_episode(emb, episode_rng(0, "toyarm", 2), *SIZE, 8, 10.0)
    traj = ep.trajectory
    still = traj.replace(q=np.repeat(traj.q[:1], len(traj), 0), gripper=np.repeat(traj.gripper[:1], len(traj), 0))
    res = calibration_score(ep.rgb, emb, still, ep.camera)
    assert np.isnan(res.score) and res.pairs == 0 and len(res.per_pair) == len(traj) - 1
    assert res.to_dict()["score"] is None


def test_iou_and_pairs_on_closed_forms():
    a = np.zeros((4, 4), bool)
    b = np.zeros((4, 4), bool)
    assert motion_iou(a, b) == 0.0
    a[0, :2] = True
    b[0, 1:3] = True
    assert motion_iou(a, b) == pytest.approx(1 / 3)
    emb = get_embodiment("toyarm")
    ep = make_episode(emb, episode_rng(0, "toyarm", 3), *SIZE, 20, 10.0)
    res = calibration_score(ep.rgb, emb, ep.trajectory, ep.camera, ScoreConfig(gap=3, max_pairs=5))
    assert [(r["t0"], r["t1"]) for r in res.per_pair] == [(0, 3), (4, 7), (8, 11), (12, 15), (16, 19)]
    counted = [r["iou"] for r in res.per_pair if r["counted"]]
    assert res.score == pytest.approx(float(np.median(counted)))
    with pytest.raises(ValueError, match="ScoreConfig.gap"):
        ScoreConfig(gap=0)


def test_the_camera_is_fitted_to_the_video_size():
    # the same episode at twice the size (frames scaled up): the score resizes both to 160 px and agrees
    import cv2

    emb = get_embodiment("kuka")
    ep = make_episode(emb, episode_rng(0, "kuka", 1), *SIZE, 12, 10.0)
    big = np.stack([cv2.resize(f, (320, 240), interpolation=cv2.INTER_NEAREST) for f in ep.rgb])
    a = calibration_score(ep.rgb, emb, ep.trajectory, ep.camera).score
    b = calibration_score(big, emb, ep.trajectory, ep.camera).score
    assert abs(a - b) < 0.05


def test_cli_score(tmp_path, capsys):
    emb = get_embodiment("toyarm")
    ep = make_episode(emb, episode_rng(0, "toyarm", 4), *SIZE, 16, 10.0)
    write_video(tmp_path / "rgb.mkv", ep.rgb, 10.0)
    save_trajectory(ep.trajectory, tmp_path / "traj.npz")
    save_camera(ep.camera, tmp_path / "cam.json")
    args = [
        "calibrate",
        "score",
        "--video",
        str(tmp_path / "rgb.mkv"),
        "--trajectory",
        str(tmp_path / "traj.npz"),
        "--camera",
        str(tmp_path / "cam.json"),
        "--embodiment",
        "toyarm",
    ]
    assert main(args + ["--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    direct = calibration_score(ep.rgb, emb, ep.trajectory, ep.camera)
    assert doc["score"] == direct.score and doc["pairs"] == direct.pairs > 10  # FFV1 is lossless
    assert main(args) == 0
    assert capsys.readouterr().out.startswith(f"score {direct.score:.3f} (median over {direct.pairs} frame pairs")
    write_video(tmp_path / "short.mkv", ep.rgb[:5], 10.0)
    args[3] = str(tmp_path / "short.mkv")
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "short.mkv: expected at least 16 frames (the trajectory's length), found 5" in err


def test_data_filter_rejects_a_wrong_calibration(tmp_path):
    from _datasets import write_episode

    from oscar_core.data.engine import read_stage
    from oscar_core.data.filters import FilterConfig
    from oscar_core.data.run import run_filter, run_ingest

    emb = get_embodiment("toyarm")
    ep = make_episode(emb, episode_rng(0, "toyarm", 0), *SIZE, FRAMES, 10.0)
    src = tmp_path / "src"
    write_episode(src, "right", ep.trajectory, ep.camera, rgb=ep.rgb, size=SIZE)
    write_episode(src, "wrong", ep.trajectory, perturb_camera(ep.camera, (0.1, 0, 0)), rgb=ep.rgb, size=SIZE)
    out = str(tmp_path / "run")
    run_ingest(str(src), "npz", out, workers=1, progress=False)
    run_filter(
        out, FilterConfig(min_length=10, max_point_speed=100, min_calibration_score=0.5), workers=1, progress=False
    )
    rows = {r["id"].split("/")[1]: r for r in read_stage(str(Path(out) / "filter"))}
    right, wrong = rows["right"], rows["wrong"]
    assert right["filter_status"] == "ok", right["filter_reason"]
    assert right["filter_calibration_score"] == pytest.approx(
        calibration_score(ep.rgb, emb, ep.trajectory, ep.camera).score, abs=0.05
    )  # after the video's compression
    assert wrong["filter_status"] == "rejected" and wrong["filter_reason"].startswith("calibration_score: ")
    assert wrong["filter_value"] < 0.5
    # off by default: not measured
    from oscar_core.data.engine import StageRecomputed

    with pytest.warns(StageRecomputed, match="min_calibration_score: 0.5 -> 0.0"):  # another config: computed again
        run_filter(out, FilterConfig(min_length=10, max_point_speed=100), workers=1, progress=False)
    rows = {r["id"].split("/")[1]: r for r in read_stage(str(Path(out) / "filter"))}
    assert np.isnan(rows["wrong"]["filter_calibration_score"]) and rows["wrong"]["filter_status"] == "ok"


def test_perturb_camera_moves_and_turns_in_the_cameras_own_axes():
    from oscar_core.calibration.pnp import position_error_mm, rotation_error_deg
    from oscar_core.calibration.synthetic import problem

    _, cam, _ = problem(get_embodiment("kuka"), 0)
    pose = np.linalg.inv(cam.world_to_cv())
    moved = perturb_camera(cam, shift_m=(0.0, 0.05, 0.0))
    np.testing.assert_allclose(np.linalg.inv(moved.world_to_cv())[:3, 3] - pose[:3, 3], 0.05 * pose[:3, 1], atol=1e-12)
    assert rotation_error_deg(moved, cam) < 1e-6
    rolled = perturb_camera(cam, rotate_deg=(0.0, 0.0, 5.0))
    new = np.linalg.inv(rolled.world_to_cv())
    np.testing.assert_allclose(new[:3, 2], pose[:3, 2], atol=1e-12)  # a roll keeps the viewing direction
    assert rotation_error_deg(rolled, cam) == pytest.approx(5.0) and position_error_mm(rolled, cam) < 1e-9
    tilted = np.linalg.inv(perturb_camera(cam, rotate_deg=(3.0, 0.0, 0.0)).world_to_cv())
    np.testing.assert_allclose(tilted[:3, 0], pose[:3, 0], atol=1e-12)  # a tilt about x keeps the x axis
    assert np.degrees(np.arccos(tilted[:3, 2] @ pose[:3, 2])) == pytest.approx(3.0)
