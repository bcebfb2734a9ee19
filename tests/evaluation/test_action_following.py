"""The action-following benchmark: scores against hand-made cases, stand-in models on toy sets (one copying the
simulator's frames, one always moving the ball), bad inputs refused before any model loads, resume, and the
variant transforms."""

from __future__ import annotations

import hashlib
import json
import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from oscar_core.evaluation.action_following import ActionFollowingSettings, check_sets, run_action_following
from oscar_core.evaluation.action_following_manifest import load_action_following
from oscar_core.evaluation.action_following_scores import paired_scores, score_records
from oscar_core.evaluation.variant_transforms import VariantError, apply_transforms, shift_weights
from oscar_core.media.video import read_video
from oscar_core.metrics.common import MetricInputError
from oscar_core.metrics.programmatic import ProgrammaticJudge
from oscar_core.plugin.registry import get_embodiment
from oscar_core.toyworld.judge import ball_moved

pytestmark = pytest.mark.usefixtures("one_thread")

JUDGE = "oscar_core.toyworld.judge:ball_moved"
TRUTHS = [1, 0, 0, 0, 1, 0]  # close_at_ball, stay_open, close_early, close_late, miss_1R, miss_3R


def _judge():
    return ProgrammaticJudge(ball_moved, name=JUDGE)


@pytest.fixture(scope="module")
def sets(tmp_path_factory):
    """Two toyarm sets of 33 frames (two 17-frame chunks), 64 x 64."""
    from oscar_core.toyworld.counterfactual import write_counterfactual_sets

    out = tmp_path_factory.mktemp("af_sets")
    return write_counterfactual_sets(out, ["toyarm"], 2, seed=0, frames=33)


def _key(traj) -> str:
    return hashlib.sha256(
        np.ascontiguousarray(traj.q).tobytes() + np.ascontiguousarray(traj.gripper).tobytes()
    ).hexdigest()


class StandIn:
    """A model with the public rollout path: ``rollout_inputs`` gives the condition video and one more key (the
    trajectory, as a new condition would be), ``rollout`` returns frames it looks up by that trajectory. ``mode``:
    "copy" returns the variant's own true frames; "moves" the set's close_at_ball frames (the ball always moves)."""

    def __init__(self, manifest_path, mode: str):
        m = load_action_following(manifest_path)
        self.videos = {}
        for s in m.sets:
            moving = next(v for v in s.variants if v.name == "close_at_ball").video
            for v in s.variants:
                self.videos[_key(v.trajectory)] = v.video if mode == "copy" else moving
        self.card = SimpleNamespace(name=f"stand-in-{mode}", chunk_frames=17, width=64, height=64, sampler=None)
        self.calls = 0

    def rollout_inputs(self, trajectory, camera, embodiment, size=None, **kw):
        T = len(trajectory.q)
        return {"skeleton": np.zeros((T, size[1], size[0], 3), np.uint8), "trajectory": trajectory}

    def rollout(self, first, skeleton, prompt=None, *, trajectory, sampler=None, seed=0, progress=False, **kw):
        self.calls += 1
        assert skeleton.shape[0] == len(trajectory.q)
        return SimpleNamespace(frames=read_video(self.videos[_key(trajectory)]))


def _run(manifest, out, model, **kw):
    settings = ActionFollowingSettings(sampler=None, resamples=200, **kw)
    return run_action_following(manifest, out, judge=_judge(), model=model, settings=settings)


def test_a_model_copying_the_simulator_scores_100_and_one_always_moving_the_fraction_by_hand(sets, tmp_path):
    copy = _run(sets, tmp_path / "copy", StandIn(sets, "copy")).report["scores"]
    assert copy["decision_accuracy"]["value"] == 1.0 and copy["pairwise"]["value"] == 1.0
    assert copy["pairwise"]["pairs"] == 2 * 8  # 2 successes x 4 failures per set
    for c in copy["chunks"]:
        assert c["psnr_db"]["value"] == 100.0 and c["object_error"]["value"] == 0.0
    assert all(v["end_error"]["value"] == 0.0 for v in copy["variants"].values())
    # a hand-made case: the second set keeps only close_at_ball and miss_1R (both true successes); a model that
    # always moves the ball gets that set right and not the first: 1 of 2; pairwise: 0 of 8 told apart
    m = json.loads(sets.read_text())
    m["sets"][1]["variants"] = [v for v in m["sets"][1]["variants"] if v["name"] in ("close_at_ball", "miss_1R")]
    edited = sets.parent / "edited.json"
    edited.write_text(json.dumps(m))
    moves = _run(edited, tmp_path / "moves", StandIn(edited, "moves")).report
    s = moves["scores"]
    assert s["decision_accuracy"]["value"] == 0.5
    assert s["pairwise"]["value"] == 0.0 and s["pairwise"]["pairs"] == 8
    assert s["variants"]["close_at_ball"]["agreement"]["value"] == 1.0
    assert s["variants"]["stay_open"]["agreement"]["value"] == 0.0
    assert s["variants"]["stay_open"]["agreement"]["ci_undefined"].startswith("an interval needs at least 2 sets")
    assert "nan" not in (tmp_path / "moves" / "summary.md").read_text().lower()
    # paired on the same sets: always moving minus copying, per set: decision accuracy -100 pp, pairwise -100 pp
    settings = ActionFollowingSettings(resamples=200)
    paired = run_action_following(
        sets,
        tmp_path / "moves_all",
        judge=_judge(),
        model=StandIn(sets, "moves"),
        settings=settings,
        paired=tmp_path / "copy",
    ).report["paired"]
    assert paired["decision_accuracy"]["value"] == -1.0 and paired["pairwise"]["value"] == -1.0
    assert "-100.0 pp" in (tmp_path / "moves_all" / "summary.md").read_text()
    with pytest.raises(MetricInputError, match="manifest_sha256.*a run on the same sets"):
        run_action_following(
            sets,
            tmp_path / "refused",
            judge=_judge(),
            model=StandIn(sets, "moves"),
            settings=settings,
            paired=tmp_path / "moves",
        )


def test_scores_by_hand_and_paired_differences():
    def rec(name, truth, verdicts):
        return {
            "set": name,
            "variants": [
                {"name": f"v{i}", "outcome": t, "verdict": v, "truth_verdict": None, "end_error": None, "chunks": []}
                for i, (t, v) in enumerate(zip(truth, verdicts))
            ],
        }

    a = [rec("s1", [1, 0, 0], [1, 0, 0]), rec("s2", [1, 0, 0], [1, 1, 0]), rec("s3", [1, 0, 1], [0, 0, 0])]
    s = score_records(a, resamples=500)
    assert s["decision_accuracy"]["value"] == pytest.approx(1 / 3)
    # pairs with different truths: s1 2, s2 2, s3 2; told apart: s1 2, s2 1 (v0-v2), s3 0
    assert s["pairwise"]["value"] == pytest.approx(3 / 6) and s["pairwise"]["pairs"] == 6
    lo, hi = s["decision_accuracy"]["ci"]
    assert 0.0 <= lo <= 1 / 3 <= hi <= 1.0
    assert s["chunks"] == {"undefined": "no true frames: per-chunk drift needs them"}
    b = [rec("s1", [1, 0, 0], [1, 1, 1]), rec("s2", [1, 0, 0], [1, 1, 1]), rec("s3", [1, 0, 1], [1, 1, 1])]
    p = paired_scores(a, b, resamples=500)
    assert p["decision_accuracy"]["value"] == pytest.approx(1 / 3)
    assert p["pairwise"]["value"] == pytest.approx(0.5)
    # undefined statistics are sentences
    same = [rec("s1", [1, 1], [1, 0])]
    u = score_records(same)
    assert u["pairwise"]["undefined"].startswith("pairwise rate: no set has two variants")


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda m: m["sets"][0].pop("info"), "sets[0].info"),  # the judge reads info.px_to_floor_radii
        (lambda m: [v.update(transforms=[]) for v in m["sets"][0]["variants"]], "sets[0].variants"),
        (lambda m: m["sets"][1]["variants"][2].update(outcome=2), "sets[1].variants[2].outcome"),
        (
            lambda m: m["sets"][0]["variants"][4]["transforms"][0].update(shift_m=40.0),
            "sets[0].variants[4].transforms[0]",
        ),
        (lambda m: m.update(chunk=True), "sets[0].trajectory"),  # with --chunk-frames 13: 33 frames do not fit
    ],
)
def test_bad_input_exits_2_naming_the_file_and_field_before_any_model_loads(
    sets, tmp_path, monkeypatch, capsys, edit, field
):
    import oscar_zoo
    from oscar_core.cli import main

    m = json.loads(sets.read_text())
    edit(m)
    chunk = m.pop("chunk", False)
    bad = sets.parent / "bad.json"
    bad.write_text(json.dumps(m))
    monkeypatch.setattr(oscar_zoo, "load", lambda *a, **k: pytest.fail("the model was loaded"))
    args = [
        "eval",
        "action-following",
        str(bad),
        "--model",
        "oscar-toy",
        "--judge",
        JUDGE,
        "--out",
        str(tmp_path / "o"),
    ]
    assert main(args + (["--chunk-frames", "13"] if chunk else [])) == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines() if line.startswith("error:")]
    assert len(err) == 1 and str(bad) in err[0] and f"'{field}" in err[0], err


def test_a_model_of_another_size_is_refused_naming_the_first_frame(sets):
    m = load_action_following(sets)
    with pytest.raises(MetricInputError, match=r"sets\[0\].first_frame.*32x32 \(the model's size\).*64x64"):
        check_sets(m, _judge(), SimpleNamespace(chunk_frames=17, width=32, height=32), None)


def test_resume_keeps_finished_sets_and_other_settings_are_refused(sets, tmp_path):
    from oscar_core._util.stage import StageChanged

    model = StandIn(sets, "copy")
    out = tmp_path / "run"
    first = _run(sets, out, model)
    assert model.calls == 12 and first.report["timing"]["sets_run"] == 2
    (out / "records" / "toyarm-0001.json").unlink()  # as if killed after the first set
    again = _run(sets, out, model)
    assert model.calls == 18 and again.report["timing"] == {**again.report["timing"], "sets_run": 1, "sets_reused": 1}
    assert again.report["scores"] == first.report["scores"]
    with pytest.raises(StageChanged, match="seed: 0 -> 1"):
        _run(sets, out, model, seed=1)


def test_rollout_batch_is_used_when_the_inputs_are_the_condition_video_alone(sets, tmp_path):
    class Batched(StandIn):
        def rollout_inputs(self, trajectory, camera, embodiment, size=None, **kw):
            T = len(trajectory.q)
            video = np.zeros((T, size[1], size[0], 3), np.uint8)
            video[0, 0, 0, 0] = int(_key(trajectory)[:2], 16)  # which variant, for the stand-in to find it
            self.by_mark = getattr(self, "by_mark", {})
            self.by_mark[int(video[0, 0, 0, 0])] = self.videos[_key(trajectory)]
            return {"skeleton": video, "actions": None}

        def rollout(self, *a, **k):
            raise AssertionError("one rollout per variant where a batch was possible")

        def rollout_batch(self, firsts, skeletons, prompt, *, sampler=None, seeds=None, **k):
            assert len(set(seeds)) == 1 and len(firsts) == 6
            return [read_video(self.by_mark[int(s[0, 0, 0, 0])]) for s in skeletons]

    res = _run(sets, tmp_path / "b", Batched(sets, "copy"))
    assert res.report["scores"]["decision_accuracy"]["value"] == 1.0


def test_gripper_and_shift_transforms():
    from oscar_core.kinematics.trajectory import load_trajectory
    from oscar_core.policy.ik import EndEffectorIK
    from oscar_core.toyworld.counterfactual import _Redraw, plan_counterfactual_set, set_rng

    emb = get_embodiment("toyarm")
    for attempt in range(30):
        try:
            cs = plan_counterfactual_set(emb, set_rng(3, "toyarm", 0, attempt), 64, 64, 33)
            break
        except _Redraw:
            continue
    base = cs.base
    o = emb.gripper_openness(base.gripper)
    flipped = apply_transforms(base, emb, [{"gripper": "flip", "from": 5, "to": 9}])
    fo = emb.gripper_openness(flipped.gripper)
    assert np.allclose(fo[5:9], 1 - o[5:9]) and np.array_equal(fo[:5], o[:5]) and np.array_equal(fo[9:], o[9:])
    w = shift_weights(33, 10, 14, 6)
    assert w[0] == 0 and w[4] == 0 and (w[10:14] == 1).all() and 0 < w[7] < 1 and w[19] == 0 and 0 < w[16] < 1
    t = {"shift_m": 0.01, "axis": "y", "from": 10, "to": 14, "ramp": 6}
    moved = apply_transforms(base, emb, [t])
    ik = EndEffectorIK(emb)
    d = ik.pose(moved.q)[:, :3, 3] - ik.pose(base.q)[:, :3, 3]
    assert np.allclose(d[10:14], [0, 0.01, 0], atol=2e-4)
    assert np.array_equal(moved.q[:4], base.q[:4]) and np.array_equal(moved.q[20:], base.q[20:])
    with pytest.raises(VariantError, match="transforms\\[0\\]: field 'shift_m': expected an arm that can follow"):
        apply_transforms(base, emb, [{**t, "shift_m": 50.0}])
    with pytest.raises(VariantError, match="field 'from': expected a frame >= 1"):
        apply_transforms(base, emb, [{**t, "from": 0}])
    assert load_trajectory  # the base is a plain trajectory, saved and loaded as any other


def test_the_manifest_is_copied_with_its_sets_and_still_loads(sets, tmp_path):
    shutil.copytree(sets.parent, tmp_path / "copy")
    m = load_action_following(tmp_path / "copy" / "manifest.json")
    assert [v.name for v in m.sets[0].variants][:2] == ["close_at_ball", "stay_open"]
    assert [v.outcome for v in m.sets[0].variants] == TRUTHS


def test_tiny_encoder_reaches_the_loader_and_the_fingerprint_and_is_refused_with_the_ceiling(
    sets, tmp_path, monkeypatch, capsys
):
    import oscar_zoo
    from oscar_core.cli import main
    from oscar_core.evaluation import action_following as af
    from oscar_core.model.errors import ModelInputError

    weights = tmp_path / "enc.safetensors"
    weights.write_bytes(b"not read here")
    seen = {}

    def fake_load(spec, revision=None, **kw):
        seen.update(kw)
        return StandIn(sets, "copy")

    monkeypatch.setattr(oscar_zoo, "load", fake_load)
    settings = ActionFollowingSettings(model_spec="oscar-toy", sampler=None, resamples=200, tiny_encoder=str(weights))
    run = run_action_following(sets, tmp_path / "run", judge=_judge(), settings=settings)
    assert seen["tiny_encoder"] == str(weights)
    digest = hashlib.sha256(b"not read here").hexdigest()
    parts = json.loads((tmp_path / "run" / "fingerprint.json").read_text())["parts"]
    assert parts["encoder"] == f"tiny-sha256:{digest}" and run.report["scores"]
    plain = af._fingerprint_parts(load_action_following(sets), ActionFollowingSettings(), "m", None, 17, _judge(), "l")
    assert "encoder" not in plain  # runs without the option keep their fingerprints
    with pytest.raises(ModelInputError, match="tiny_encoder: expected none with the ceiling"):
        ActionFollowingSettings(ceiling=True, tiny_encoder=str(weights))
    monkeypatch.setattr(oscar_zoo, "load", lambda *a, **k: pytest.fail("the model was loaded"))
    base = ["--model", "oscar-toy", "--ceiling", "--tiny-encoder", str(weights), "--out", str(tmp_path / "c")]
    assert main(["eval", "action-following", str(sets), "--judge", JUDGE, *base]) == 2
    assert "--tiny-encoder: expected none with the ceiling" in capsys.readouterr().err
    assert main(["toyworld", "action-following", "--quick", *base]) == 2
    assert "--tiny-encoder: expected none with the ceiling" in capsys.readouterr().err
    assert not (tmp_path / "c" / "sets").exists()  # refused before any set was made
    missing = ["--model", "oscar-toy", "--tiny-encoder", str(tmp_path / "no.safetensors"), "--out", str(tmp_path / "d")]
    assert main(["eval", "action-following", str(sets), "--judge", JUDGE, *missing]) == 2
    assert "--tiny-encoder" in capsys.readouterr().err
