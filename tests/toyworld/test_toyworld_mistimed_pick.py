"""Mistimed picks in the toy world's training data (``pick_timing``): the gripper closes before the end-effector
reaches the ball (early) or after it has left it (late), the arm moves as in the on-time pick, and the ball stays
where it lay; sets made without the option are unchanged."""

from __future__ import annotations

import json

import numpy as np
import pytest

from oscar_core.plugin.registry import default_registry
from oscar_core.toyworld.counterfactual import margin
from oscar_core.toyworld.episode import episode_rng, miss_rng
from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
from oscar_core.toyworld.motion import (
    GRAB_RADII,
    ToyWorldError,
    decision_margin,
    mistimed_openness,
    sample_motion,
)
from oscar_core.train.clips import clip_openness

REG = default_registry()
ARMS = ("toyarm", "franka", "kuka")
T = 33


def motion(name, i, **kw):
    return sample_motion(REG.get(name), episode_rng(0, name, i), T, miss_rng=miss_rng(0, name, i), **kw)


def _inside(m):
    return np.linalg.norm(m.ee - m.object[0], axis=1) <= GRAB_RADII * m.object_radius


def test_a_straight_pass_closes_exactly_the_margin_before_entering_and_after_leaving():
    """Analytic case: the end-effector moves along x at 0.1 R per frame through a ball at x = 3 R; the grab distance
    (2.2 R) holds it inside on frames 8..52; the plan closes on frame 30 and releases on frame 50."""
    R, n = 1.0, 61
    ee = np.stack([np.arange(n) * 0.1 * R, np.zeros(n), np.full(n, R)], 1)
    ball = np.array([3.0 * R, 0.0, R])
    inside = np.flatnonzero(np.linalg.norm(ee - ball, axis=1) <= GRAB_RADII * R)
    assert (inside[0], inside[-1]) == (8, 52)
    plan = np.ones((n, 1))
    plan[30:50] = 0.0
    plan[29] = 0.6
    m = decision_margin(n)  # 3 frames at 61
    early = mistimed_openness(plan, ee, ball, R, "early")
    want = np.ones(n)
    want[8 - m : 50] = 0.0
    want[8 - m - 1] = 0.6
    np.testing.assert_array_equal(early[:, 0], want)
    # late: it leaves on frame 53, after the release: no room
    assert mistimed_openness(plan, ee, ball, R, "late") is None
    plan = np.ones((n, 1))
    plan[30:59] = 0.0  # released on frame 59: room for a close on 53 + m = 56
    late = mistimed_openness(plan, ee, ball, R, "late")
    want = np.ones(n)
    want[53 + m : 59] = 0.0
    want[53 + m - 1] = 0.6
    np.testing.assert_array_equal(late[:, 0], want)
    with pytest.raises(ValueError, match="side"):
        mistimed_openness(plan, ee, ball, R, "never")


def test_every_on_ball_pick_is_mistimed_at_one_and_the_ball_stays():
    sides = {"early": 0, "late": 0}
    for name in ARMS:
        for i in range(8):
            on_time, m = motion(name, i), motion(name, i, pick_timing=1.0)
            np.testing.assert_array_equal(m.trajectory.q, on_time.trajectory.q)  # the same arm motion
            np.testing.assert_array_equal(m.object[0], on_time.object[0])
            if on_time.kind != "pick_place":
                assert m.mistimed is None
                continue
            assert m.mistimed in sides, f"{name} {i}: no room for either side"
            sides[m.mistimed] += 1
            assert on_time.attached.any() and not m.attached.any()
            np.testing.assert_allclose(m.object, np.repeat(m.object[:1], T, 0))  # never moves
            o = clip_openness(REG.get(name), m.trajectory)[:, 0]
            o0 = clip_openness(REG.get(name), on_time.trajectory)[:, 0]
            inside = _inside(m)
            close = int(np.flatnonzero(o < 0.5)[0])
            release = int(np.flatnonzero(o0 < 0.5)[-1]) + 1
            assert int(np.flatnonzero(o < 0.5)[-1]) + 1 == release  # it lets go where the on-time pick does
            k = decision_margin(T)
            if m.mistimed == "early":
                assert close == int(np.argmax(inside)) - k and not inside[: close + k].any()
                assert (o[close:release] < 0.5).all()  # closed through the whole pass over the ball
            else:
                assert (o[inside] >= 0.5).all()  # open on every frame within the grab distance
                assert not inside[close - k : release].any()
    assert sides["early"] >= 2 and sides["late"] >= 2, sides


def test_timing_leaves_misses_open_picks_and_the_default_as_they_were():
    for name in ARMS:
        for i in range(5):
            base = motion(name, i, pick_miss=0.3, pick_open=0.4)
            same = motion(name, i, pick_miss=0.3, pick_open=0.4, pick_timing=0.0)
            np.testing.assert_array_equal(same.object, base.object)
            np.testing.assert_array_equal(same.trajectory.gripper, base.trajectory.gripper)
            assert same.mistimed is None
            t = motion(name, i, pick_miss=0.3, pick_open=0.4, pick_timing=1.0)
            assert (t.missed, t.never_closed) == (base.missed, base.never_closed)
            if base.missed or base.never_closed:  # never also mistimed: those keep their own gripper and ball
                assert t.mistimed is None
                np.testing.assert_array_equal(t.trajectory.gripper, base.trajectory.gripper)


def test_a_pick_mistimed_at_one_fraction_is_mistimed_at_every_larger_one():
    for name in ARMS:
        for i in range(8):
            low, high = motion(name, i, pick_timing=0.3), motion(name, i, pick_timing=0.8)
            if low.mistimed is not None:
                assert high.mistimed == low.mistimed


def test_the_counterfactual_margin_is_the_training_rule():
    for frames in (9, 17, 33, 49, 97):
        assert margin(frames) == decision_margin(frames) == max(2, round(0.05 * (frames - 1)))


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan"), "0.3"])
def test_a_bad_fraction_is_refused(bad):
    with pytest.raises(ToyWorldError, match="--pick-timing"):
        motion("toyarm", 0, pick_timing=bad)
    with pytest.raises(ToyWorldError, match="--pick-timing"):
        generate_clipset(GenerateConfig(("toyarm",), 1, 32, 32, 9, pick_timing=bad), "unused", REG)


def test_generate_records_the_option_and_keeps_old_records(tmp_path):
    def made(out, **kw):
        generate_clipset(GenerateConfig(("toyarm", "kuka"), 4, 32, 32, 17, seed=1, shard_size=4, **kw), out, REG)
        parts = json.loads((out / "fingerprint.json").read_text())["parts"]
        recs = [
            json.loads(line)
            for e in ("toyarm", "kuka")
            for line in (out / f"shard-{e}-000000" / "clips.jsonl").read_text().splitlines()
        ]
        return parts, recs

    plain_parts, plain = made(tmp_path / "plain")
    assert "pick_timing" not in plain_parts and all("mistimed" not in r["meta"]["toyworld"] for r in plain)
    parts, recs = made(tmp_path / "timed", pick_timing=1.0)
    assert parts["pick_timing"] == 1.0
    picks = [r["meta"]["toyworld"] for r in recs if r["meta"]["toyworld"]["kind"] == "pick_place"]
    assert picks and all(gt["mistimed"] in ("early", "late") and not gt["grabbed"] for gt in picks)
    for r in recs:
        if r["meta"]["toyworld"]["kind"] != "pick_place":
            assert r["meta"]["toyworld"]["mistimed"] is None


def test_the_command_refuses_a_bad_fraction_before_writing(tmp_path, capsys):
    from oscar_core.cli import main

    out = tmp_path / "set"
    with pytest.raises(SystemExit) as e:
        main(
            [
                "toyworld",
                "generate",
                "--embodiments",
                "toyarm",
                "--episodes",
                "1",
                "--pick-timing",
                "1.5",
                "--out",
                str(out),
            ]
        )
    assert e.value.code == 2 and "--pick-timing" in capsys.readouterr().err and not out.exists()
    rc = main(
        [
            "toyworld",
            "generate",
            "--embodiments",
            "toyarm",
            "--episodes",
            "2",
            "--size",
            "32x32",
            "--frames",
            "17",
            "--pick-timing",
            "1",
            "--out",
            str(out),
            "--json",
        ]
    )
    assert rc == 0 and json.loads((out / "fingerprint.json").read_text())["parts"]["pick_timing"] == 1.0
