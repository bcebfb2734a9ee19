"""The toy-world policy-evaluation demonstration: scripted policies, the manifest writer, the ball judge, and the
whole `oscar eval run` loop on its manifest with a tiny random model."""

import json
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

import oscar_zoo
from oscar_core.camera import project
from oscar_core.cli import main as oscar_main
from oscar_core.evaluation import load_manifest
from oscar_core.registry import Registry
from oscar_core.toyworld.judge import agreement_with_real, ball_moved
from oscar_core.toyworld.policy_eval import (SUCCESS_RADII, Policy, floor_homography, plan_session, session_rng,
                                             write_policy_eval)
from oscar_core.video import read_video

# an expert aims within 0.3 ball radii (the grab distance is 2.2); "never" aims 50 radii away
SURE = (Policy("expert", 0.3), Policy("never", 50.0))


@pytest.fixture(autouse=True)
def isolated(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hf-cache"))
    monkeypatch.setenv("OSCAR_ZOO_REGISTRY", str(tmp_path / "zoo.json"))


@pytest.fixture(scope="module")
def toyarm():
    return Registry().get("toyarm")


def _session(emb, i, policies=SURE, frames=9):
    names = [p.name for p in policies]
    return plan_session(emb, session_rng(0, emb.name, i), 32, 32, frames, policies=policies,
                        policy_rngs={n: session_rng(0, emb.name, i, 0, n) for n in names})


def test_expert_always_succeeds_and_far_aim_never(toyarm):
    for i in range(4):
        s = _session(toyarm, i)
        expert, never = s.episodes
        assert expert.success == 1 and expert.grabbed and expert.displacement >= SUCCESS_RADII, i
        assert never.success == 0 and not never.grabbed and never.displacement == 0.0, i
        # the grasp went where it was aimed (sampling + FK refinement), within a fraction of a ball radius
        assert np.linalg.norm(expert.grasp_error - expert.aim_error) < 0.5, (i, expert.grasp_error, expert.aim_error)
        # every policy starts from the same pose and the same ball
        assert np.array_equal(expert.motion.trajectory.q[0], never.motion.trajectory.q[0])
        assert np.array_equal(expert.motion.object[0], never.motion.object[0])


def test_floor_homography_maps_projected_plane_points_back(toyarm):
    s = _session(toyarm, 0)
    R = s.radius
    H = floor_homography(s.camera, R, R)
    pts = s.ball + np.array([[0, 0, 0], [2 * R, 0, 0], [0, -3 * R, 0], [1.5 * R, 2.5 * R, 0]])
    uv = project(pts, s.camera).uv
    back = (H @ np.c_[uv, np.ones(4)].T).T
    back = back[:, :2] / back[:, 2:]
    np.testing.assert_allclose(back, pts[:, :2] / R, atol=1e-6)


def _disc_video(centres, size=32, r=2.5):
    """Grey frames with a yellow disc at each (x, y) pixel centre."""
    yy, xx = np.mgrid[0:size, 0:size]
    v = np.full((len(centres), size, size, 3), 90, np.uint8)
    for t, (x, y) in enumerate(centres):
        v[t][(xx - x) ** 2 + (yy - y) ** 2 <= r * r] = (255, 209, 0)
    return v


def test_ball_moved_known_answers():
    # identity homography / 2: one ball radius = 2 pixels, so 3 radii = 6 pixels
    info = {"px_to_floor_radii": np.diag([0.5, 0.5, 1.0]).tolist(), "success_radii": 3.0, "ball_start_px": [10, 10]}
    clip = SimpleNamespace(info=info)
    moved = ball_moved(_disc_video([(10, 10)] * 5 + [(18, 10)] * 4), clip)  # 8 px = 4 radii
    assert moved["binary"] == 1 and moved["partial"] == 100
    short = ball_moved(_disc_video([(10, 10)] * 5 + [(13, 10)] * 4), clip)  # 3 px = 1.5 radii = 50 %
    assert short["binary"] == 0 and short["partial"] == 50, short
    still = ball_moved(_disc_video([(10, 10)] * 9), clip)
    assert still["binary"] == 0 and still["partial"] == 0
    gone = _disc_video([(10, 10)] * 9)
    gone[-3:] = 90  # the ball vanished from the last quarter
    lost = ball_moved(gone, clip)
    assert lost["binary"] == 0 and "not visible" in lost["reason"]
    with pytest.raises(ValueError, match="px_to_floor_radii"):
        ball_moved(gone, SimpleNamespace(info={}))


def test_manifest_real_outcomes_and_judge_agreement(tmp_path):
    summary = write_policy_eval(tmp_path / "pe", ["toyarm"], 2, seed=0, width=32, height=32, frames=9,
                                policies=SURE)
    m = load_manifest(tmp_path / "pe" / "manifest.json")
    assert m.policies == ("expert", "never") and len(m.cells) == 4 and m.size == (32, 32)
    assert m.real_success_rates() == {"expert": 1.0, "never": 0.0}
    assert summary["policies"]["expert"]["success_rate"] == 1.0
    for c in m.cells:
        video = read_video(c.real_video)
        assert video.shape == (9, 32, 32, 3)
        first = cv2.imread(str(c.first_frame))[..., ::-1]
        assert np.array_equal(first, video[0]), c.id  # every policy of the session starts from this frame
        assert set(c.info) == {"ball_start_px", "ball_radius_px", "px_to_floor_radii", "success_radii"}
    # the judge's correctness check: on the simulator's renders it agrees with the simulator's outcome
    agree = agreement_with_real(tmp_path / "pe" / "manifest.json")
    assert agree["cells"] == 4 and agree["agreement"] == 1.0, agree
    assert agree["tp"] == 2 and agree["tn"] == 2


def test_same_seed_same_files(tmp_path):
    for d in ("a", "b"):
        write_policy_eval(tmp_path / d, ["toyarm"], 1, seed=3, width=32, height=32, frames=9, policies=SURE)
    for name in ("toyarm-0000/expert.npz", "toyarm-0000/first.png", "toyarm-0000/camera.json"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


@pytest.mark.slow
def test_eval_run_end_to_end_on_the_toy_manifest(tmp_path, capsys):
    from oscar_core.model import ModelCard, OscarWorldModel
    from oscar_core.model.tiny import build_tiny_transformer, build_tiny_vae

    code = oscar_main(["toyworld", "policy-eval", "--embodiments", "toyarm", "--sessions", "2", "--seed", "0",
                       "--size", "32x32", "--frames", "9", "--out", str(tmp_path / "pe"), "--json"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert list(summary["policies"]) == ["expert", "good", "sloppy", "random"]
    model = OscarWorldModel.from_modules(build_tiny_transformer(seed=0, skeleton_scale=0.05), build_tiny_vae(seed=0),
                                         ModelCard(name="tiny", chunk_frames=5, fps=10.0))
    model_dir = oscar_zoo.export(model, tmp_path / "tiny")
    out = tmp_path / "report"
    code = oscar_main(["eval", "run", str(tmp_path / "pe" / "manifest.json"), "--model", str(model_dir),
                       "--judge", "oscar_core.toyworld.judge:ball_moved", "--pairwise", "--steps", "1",
                       "--out", str(out), "--no-progress"])
    assert code == 0  # every cell got a valid verdict
    report = json.loads((out / "report.json").read_text())
    m = load_manifest(tmp_path / "pe" / "manifest.json")
    real = m.real_success_rates()
    rows = {p["policy"]: p for p in report["policies"]}
    for p, rate in real.items():
        assert rows[p]["real_success_rate"] == pytest.approx(rate)
        assert rows[p]["judged"] == 2 and rows[p]["wm_success_rate"] is not None
    assert all(c["status"] == "ok" for c in report["cells"]), report["cells"]
    assert (out / "summary.md").is_file() and len(list((out / "rollouts").rglob("*.mkv"))) == 8
    assert len(report["pairs"]) == 2 * 6  # 6 pairs of 4 policies per session
