"""The toy simulator's push rule (``carry_object(..., push_contact=...)``) against analytic cases, and the
counterfactual sets' ``open_push`` variant: its simulator truth beside ``stay_open``'s and ``close_at_ball``'s, the
judge and the ball locator on its true frames, and sets made without pushing unchanged bit for bit."""

from __future__ import annotations

import hashlib
import json
from types import SimpleNamespace

import numpy as np
import pytest

from oscar_core.plugin.registry import get_embodiment
from oscar_core.toyworld.counterfactual import (
    PUSH_MIN_RADII,
    PUSH_VARIANT,
    VARIANTS,
    _Redraw,
    plan_counterfactual_set,
    set_rng,
    simulate_variant,
    variants_of,
    write_counterfactual_sets,
)
from oscar_core.toyworld.motion import GRAB_RADII, PUSH_CONTACT_RADII, ToyWorldError, carry_object

R = 0.05
C = PUSH_CONTACT_RADII * R  # the contact distance, metres
BALL = np.array([0.0, 0.0, R])


def _line(x0: float, x1: float, y: float, z: float, T: int = 15) -> np.ndarray:
    """(T, 3) end-effector positions, metres: a straight line along x at (y, z)."""
    return np.stack([np.linspace(x0, x1, T), np.full(T, y), np.full(T, z)], 1)


def _push(ee, openness=None, start=BALL):
    o = np.ones(len(ee)) if openness is None else openness
    return carry_object(ee, o, start, R, GRAB_RADII * R, push_contact=C)


@pytest.mark.parametrize("dz_radii", [0.0, 0.8, 1.0])
def test_a_hand_moving_along_x_into_the_ball_pushes_it_along_x_to_the_contact_distance(dz_radii):
    # the end-effector slides along x at dz above the ball's centre, from 5 R behind it to 2 R past its start: the
    # ball ends touching it, sqrt(c^2 - dz^2) ahead of where it stopped, on the floor, on the x axis
    dz = dz_radii * R
    ee = _line(-5 * R, 2 * R, 0.0, R + dz)
    pos, att = _push(ee)
    ahead = np.sqrt(C * C - dz * dz)
    np.testing.assert_allclose(pos[-1], [2 * R + ahead, 0.0, R], atol=1e-12)
    np.testing.assert_allclose(pos[:, 1:], np.repeat(BALL[None, 1:], len(ee), 0), atol=1e-12)  # along x only
    assert not att.any()
    # it moves only once the end-effector is within the contact distance, and then stays touching it
    touching = ee[:, 0] + ahead > 0
    np.testing.assert_allclose(pos[~touching], np.repeat(BALL[None], (~touching).sum(), 0))
    np.testing.assert_allclose(pos[touching, 0], ee[touching, 0] + ahead, atol=1e-12)


def test_one_fast_step_through_the_ball_still_pushes_it():
    # two frames, 10 radii apart: the sub-steps (at most c / 4) catch the ball on the way
    ee = np.array([[-5 * R, 0.0, R], [5 * R, 0.0, R]])
    pos, _ = _push(ee)
    np.testing.assert_allclose(pos[-1], [5 * R + C, 0.0, R], atol=1e-12)


def test_a_hand_passing_beside_or_above_beyond_the_contact_distance_does_not_move_it():
    for ee in (
        _line(-5 * R, 5 * R, 1.05 * C, R),  # beside, at the ball's height
        _line(-5 * R, 5 * R, 0.0, R + 1.05 * C),  # straight over it
        _line(-5 * R, 5 * R, 0.8 * C, R + 0.8 * C),  # diagonally: 1.13 c away
    ):
        pos, att = _push(ee)
        np.testing.assert_array_equal(pos, np.repeat(BALL[None], len(ee), 0))
        assert not att.any()
        # and exactly what the rule without pushing gives
        off = carry_object(ee, np.ones(len(ee)), BALL, R, GRAB_RADII * R)
        np.testing.assert_array_equal(pos, off[0])


def test_a_gripper_closing_at_the_ball_carries_it_as_without_pushing():
    # comes down from above (never within c while open), closes 1 R above the centre, carries, opens and rises
    ee = np.array(
        [
            [0, 0, 6 * R],
            [0, 0, 4 * R],
            [0, 0, 2.7 * R],
            [0, 0, 2 * R],
            [0, 0, 2 * R],
            [4 * R, 0, 3 * R],
            [8 * R, 0, 2 * R],
        ]
        + [[8 * R, 0, 2 * R], [8 * R, 0, 5 * R]]
    )
    o = np.array([1, 1, 1, 0, 0, 0, 0, 1, 1], dtype=float)
    pos, att = _push(ee, o)
    off_pos, off_att = carry_object(ee, o, BALL, R, GRAB_RADII * R)
    np.testing.assert_array_equal(att, off_att)
    np.testing.assert_array_equal(pos, off_pos)
    assert att.tolist() == [False, False, False, True, True, True, True, False, False]
    np.testing.assert_allclose(pos[-1], [8 * R, 0, R])  # dropped below where it was carried


def test_closed_fingers_that_hold_nothing_do_not_push():
    # closes far from the ball (no grab), then sweeps through it closed: the ball stays; the same sweep open pushes
    ee = _line(-5 * R, 5 * R, 0.0, R)
    closed = np.zeros(len(ee))
    pos, att = _push(ee, closed)
    np.testing.assert_array_equal(pos, np.repeat(BALL[None], len(ee), 0))
    assert not att.any()
    assert _push(ee)[0][-1, 0] == pytest.approx(5 * R + C)


def test_pushing_off_is_the_rule_as_it_was():
    # an open sweep through the ball: without pushing the ball never moves (the rule before the option)
    ee = _line(-5 * R, 5 * R, 0.0, R)
    pos, att = carry_object(ee, np.ones(len(ee)), BALL, R, GRAB_RADII * R)
    np.testing.assert_array_equal(pos, np.repeat(BALL[None], len(ee), 0))
    assert not att.any()
    pos2, _ = carry_object(ee, np.ones(len(ee)), BALL, R, GRAB_RADII * R, push_contact=None)
    np.testing.assert_array_equal(pos2, pos)


@pytest.mark.parametrize("bad", [0.0, -0.1, float("nan"), float("inf"), "0.08", True, [0.08]])
def test_a_bad_contact_distance_is_refused_naming_the_field(bad):
    ee = _line(-5 * R, 5 * R, 0.0, R)
    with pytest.raises(ToyWorldError, match="push_contact: expected"):
        carry_object(ee, np.ones(len(ee)), BALL, R, GRAB_RADII * R, push_contact=bad)


def test_a_bad_push_setting_is_refused_before_anything_is_written(tmp_path):
    out = tmp_path / "sets"
    with pytest.raises(ToyWorldError, match="push: expected True or False, found 'yes'"):
        write_counterfactual_sets(out, ["toyarm"], 1, frames=17, push="yes")
    assert not out.exists()
    with pytest.raises(ToyWorldError, match="push: expected True or False, found 1"):  # before any work
        simulate_variant(get_embodiment("toyarm"), None, BALL, R, 1.0, push=1)


def _plan(emb, index: int, frames: int = 33, push: bool = True):
    for attempt in range(30):
        try:
            rng = set_rng(0, emb.name, index, attempt)
            return plan_counterfactual_set(emb, rng, 64, 64, frames, attempt=attempt, push=push)
        except _Redraw:
            continue
    raise AssertionError("no set planned")


@pytest.mark.parametrize("name", ["toyarm", "kuka"])
def test_open_push_is_a_push_where_stay_open_nudges_and_close_at_ball_carries(name):
    emb = get_embodiment(name)
    cs = _plan(emb, 0)
    plain = _plan(emb, 0, push=False)
    t = cs.truth
    assert list(t) == list(variants_of(True)) and variants_of(True)[-1] == PUSH_VARIANT
    assert {n: t[n]["outcome"] for n in t} == {
        "close_at_ball": 1,
        "stay_open": 0,
        "close_early": 0,
        "close_late": 0,
        "miss_1R": 1,
        "miss_3R": 0,
        "open_push": 1,
    }
    push, stay, carry = t["open_push"], t["stay_open"], t["close_at_ball"]
    assert push["pushed"] and not push["grabbed"] and push["displacement_radii"] >= PUSH_MIN_RADII
    assert stay["pushed"] and not stay["grabbed"] and stay["displacement_radii"] <= PUSH_CONTACT_RADII
    assert carry["grabbed"] and carry["displacement_radii"] >= 3.0
    assert not t["close_early"]["pushed"] and t["close_early"]["displacement_radii"] == 0.0  # closed fingers
    # open_push differs from stay_open by the path only: the gripper never closes in either, and the path goes
    # through the ball's start at the contact height, where stay_open's does not pass it
    m, s = cs.motions["open_push"], cs.motions["stay_open"]
    np.testing.assert_array_equal(m.trajectory.gripper, s.trajectory.gripper)
    assert (emb.gripper_openness(m.trajectory.gripper)[:, 0] >= 0.5).all()
    np.testing.assert_array_equal(m.trajectory.q[0], cs.base.q[0])
    horizontal = np.linalg.norm(m.ee[:, :2] - cs.ball[:2], axis=1) / cs.radius
    assert horizontal.min() < 0.5 and (m.ee[:, 2] - cs.ball[2]).min() < PUSH_CONTACT_RADII * cs.radius
    assert not m.attached.any()
    # the ball ends where the sweep left it: pushed along the sweep, resting on the floor
    assert m.object[-1, 2] == pytest.approx(cs.radius)
    # the set's other variants are the same decisions as without pushing (open_push draws nothing more)
    for n in VARIANTS:
        assert cs.transforms[n] == plain.transforms[n]
        np.testing.assert_array_equal(cs.motions[n].trajectory.q, plain.motions[n].trajectory.q)
    for n in ("close_early", "miss_3R"):  # never open within the contact distance: as without pushing
        np.testing.assert_array_equal(cs.motions[n].object, plain.motions[n].object)


def _frame_hashes(folder) -> dict:
    from oscar_core.media.video import read_video

    out = {}
    for f in sorted(folder.rglob("*")):
        if not f.is_file():
            continue
        rel = str(f.relative_to(folder))
        if f.suffix == ".mkv":  # the container's bytes carry muxer metadata; the frames are what counts
            out[rel + ":frames"] = hashlib.sha256(read_video(f).tobytes()).hexdigest()[:16]
        else:
            out[rel] = hashlib.sha256(f.read_bytes()).hexdigest()[:16]
    return out


# Written at d6c4fc0, before pushing existed: write_counterfactual_sets(out, ["toyarm"], 1, seed=0, frames=17).
GOLDEN_WITHOUT_PUSH = {
    "fingerprint.json": "1cc333f2db72c4bb",
    "manifest.json": "80f3314b716402fc",
    "toyarm-0000/camera.json": "fd07784fd5b36b20",
    "toyarm-0000/first.png": "515c38987b90142b",
    "toyarm-0000/set.json": "1833832d3fcb9383",
    "toyarm-0000/trajectory.npz": "f7f5637119d4f651",
    "toyarm-0000/true/close_at_ball.mkv:frames": "ca153036e4996d4d",
    "toyarm-0000/true/close_early.mkv:frames": "817073d845fc3b38",
    "toyarm-0000/true/close_late.mkv:frames": "b19a15e3e2fc7191",
    "toyarm-0000/true/miss_1R.mkv:frames": "c10ba54d9b60af8d",
    "toyarm-0000/true/miss_3R.mkv:frames": "69173b2c9d2271dc",
    "toyarm-0000/true/stay_open.mkv:frames": "4ad1e28a80ffc06d",
}


def test_sets_made_without_pushing_are_written_as_before_the_option(tmp_path):
    write_counterfactual_sets(tmp_path, ["toyarm"], 1, seed=0, frames=17)
    assert _frame_hashes(tmp_path) == GOLDEN_WITHOUT_PUSH


def test_a_set_made_with_pushing_records_it_and_its_true_frames_show_the_push(tmp_path):
    from oscar_core.evaluation.action_following_manifest import load_action_following
    from oscar_core.media.video import read_video
    from oscar_core.toyworld.judge import _to_floor, ball_moved
    from oscar_core.toyworld.locate import ball_position

    path = write_counterfactual_sets(tmp_path, ["toyarm"], 1, seed=0, frames=33, push=True)
    m = json.loads(path.read_text())
    assert m["variants"] == list(variants_of(True)) and m["push_contact_radii"] == PUSH_CONTACT_RADII
    assert json.loads((tmp_path / "fingerprint.json").read_text())["parts"]["push_contact_radii"] == 1.6
    row = json.loads((tmp_path / "toyarm-0000" / "set.json").read_text())
    assert row["push_contact_radii"] == PUSH_CONTACT_RADII
    s = m["sets"][0]
    sim = {v["name"]: v for v in s["variants"]}
    info = s["info"]
    H = np.asarray(info["px_to_floor_radii"])
    for name in ("open_push", "stay_open", "close_at_ball"):
        video = read_video(tmp_path / sim[name]["video"])
        verdict = ball_moved(video, SimpleNamespace(info=info))
        assert verdict["binary"] == sim[name]["outcome"], (name, verdict["reason"])
        if name == "close_at_ball":  # the carried ball may lie partly under the arm: its centroid moves
            continue
        # the located ball's end against its start, floor radii, is the simulator's displacement
        px = ball_position(video[[0, -1]])
        moved = float(np.linalg.norm(_to_floor(H, px[1]) - _to_floor(H, px[0])))
        assert moved == pytest.approx(sim[name]["simulator"]["displacement_radii"], abs=0.5), name
    assert sim["open_push"]["outcome"] == 1 and sim["open_push"]["simulator"]["grabbed"] is False
    assert sim["open_push"]["simulator"]["pushed"] is True
    # the benchmark reads the set (every transform applies) and the folder refuses a re-run without pushing
    assert [v.name for v in load_action_following(path).sets[0].variants] == list(variants_of(True))
    with pytest.raises(Exception, match="push_contact_radii|variants"):
        write_counterfactual_sets(tmp_path, ["toyarm"], 1, seed=0, frames=33)


def test_decision_accuracy_counts_open_push_like_every_other_variant():
    from oscar_core.evaluation.action_following_scores import score_records

    truth = {"close_at_ball": 1, "stay_open": 0, "close_early": 0, "close_late": 0, "miss_1R": 1, "miss_3R": 0}
    truth["open_push"] = 1

    def record(sid, push_verdict):
        return {
            "set": sid,
            "variants": [
                {"name": n, "outcome": o, "verdict": (push_verdict if n == "open_push" else o)}
                for n, o in truth.items()
            ],
        }

    s = score_records([record("a", 1), record("b", 0)], resamples=50)
    assert s["decision_accuracy"]["value"] == 0.5  # set b: every verdict right but open_push's
    assert s["variants"]["open_push"]["agreement"]["value"] == 0.5
    # open_push (1) against the four variants whose outcome is 0: 12 pairs per set, 4 of set b's missed
    assert s["pairwise"]["pairs"] == 24 and s["pairwise"]["value"] == pytest.approx(20 / 24)


def test_the_command_passes_push_to_the_sets(monkeypatch, tmp_path):
    # --push reaches write_counterfactual_sets (stopped there: no set is made; the model's card is not read)
    import oscar_core.evaluation.loop as loop
    import oscar_core.toyworld.cli_counterfactual as cli_cf
    import oscar_core.toyworld.counterfactual as cf
    from oscar_core.cli import main

    monkeypatch.setattr(cli_cf, "_card", lambda spec: None)
    monkeypatch.setattr(loop, "card_sampler_of", lambda spec, revision=None: None)

    seen = []

    def stop(*args, **kwargs):
        seen.append(kwargs.get("push"))
        raise ToyWorldError("stopped by the test")

    monkeypatch.setattr(cf, "write_counterfactual_sets", stop)
    base = ["toyworld", "action-following", "--model", "oscar-toy", "--sets", "1", "--embodiments", "toyarm"]
    assert main([*base, "--out", str(tmp_path / "a"), "--push"]) == 2
    assert main([*base, "--out", str(tmp_path / "b")]) == 2
    assert seen == [True, False]


def _motion(name, i, **kw):
    from oscar_core.toyworld.episode import episode_rng, miss_rng
    from oscar_core.toyworld.motion import sample_motion

    emb = get_embodiment(name)
    return sample_motion(emb, episode_rng(0, name, i), 17, miss_rng=miss_rng(0, name, i), **kw)


def test_training_motions_with_pushing_move_the_arm_the_same_and_an_open_pick_pushes_its_ball():
    pushed = 0
    for name in ("toyarm", "kuka"):
        for i in range(4):
            plain, push = _motion(name, i, pick_open=1.0), _motion(name, i, pick_open=1.0, push=True)
            np.testing.assert_array_equal(push.trajectory.q, plain.trajectory.q)  # pushing draws nothing
            np.testing.assert_array_equal(push.trajectory.gripper, plain.trajectory.gripper)
            assert not push.attached.any() or push.kind != "pick_place"
            if push.kind == "pick_place":  # the open gripper comes down on the ball: it is nudged aside
                np.testing.assert_array_equal(plain.object, np.repeat(plain.object[:1], 17, 0))
                moved = np.linalg.norm(push.object[-1, :2] - push.object[0, :2]) / push.object_radius
                assert 0 < moved and push.object[-1, 2] == pytest.approx(push.object_radius)
                pushed += 1
            closed = _motion(name, i, push=True)
            if closed.kind == "pick_place":  # a closing gripper still grabs and carries
                assert closed.attached.any()
    assert pushed >= 3
    with pytest.raises(ToyWorldError, match="--push: expected True or False"):
        _motion("toyarm", 0, push="yes")


def test_generate_records_pushing_and_keeps_the_fingerprint_without_it(tmp_path):
    from oscar_core.plugin.registry import default_registry
    from oscar_core.toyworld.generate import GenerateConfig, generate_clipset

    reg = default_registry()

    def made(out, **kw):
        generate_clipset(GenerateConfig(("toyarm",), 1, 32, 32, 9, seed=1, skeleton=False, **kw), out, reg)
        rec = json.loads((out / "shard-toyarm-000000" / "clips.jsonl").read_text().splitlines()[0])
        return json.loads((out / "fingerprint.json").read_text())["parts"], rec["meta"]["toyworld"]

    parts, gt = made(tmp_path / "plain")
    assert "push_contact_radii" not in parts and "push_contact_radii" not in gt
    parts, gt = made(tmp_path / "push", push=True)
    assert parts["push_contact_radii"] == gt["push_contact_radii"] == PUSH_CONTACT_RADII
    with pytest.raises(ToyWorldError, match="--push: expected True or False"):
        generate_clipset(GenerateConfig(("toyarm",), 1, push=1), tmp_path / "bad", reg)
