"""Open picks in the toy world's training data (``pick_open``): the arm passes through the grasp with its gripper
open, lifts and carries, and the ball stays where it lay; a set made without the option is unchanged."""

from __future__ import annotations

import json

import numpy as np
import pytest

from oscar_core.plugin.registry import default_registry
from oscar_core.toyworld.episode import episode_rng, make_episode, miss_rng
from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
from oscar_core.toyworld.motion import ToyWorldError, sample_motion
from oscar_core.train.clips import clip_openness

REG = default_registry()
ARMS = ("toyarm", "franka", "kuka")


def motion(name, i, **kw):
    return sample_motion(REG.get(name), episode_rng(0, name, i), 17, miss_rng=miss_rng(0, name, i), **kw)


def test_every_pick_is_open_at_one_the_gripper_never_closes_and_the_ball_stays_at_the_grasp():
    n = 0
    for name in ARMS:
        for i in range(6):
            closed, opened = motion(name, i), motion(name, i, pick_open=1.0)
            if closed.kind != "pick_place":
                assert not opened.never_closed and np.array_equal(opened.object, closed.object)
                continue
            n += 1
            assert opened.never_closed and not closed.never_closed
            np.testing.assert_array_equal(opened.trajectory.q, closed.trajectory.q)  # the same arm motion
            op = clip_openness(REG.get(name), opened.trajectory)[:, 0]
            assert op.min() >= 0.5, f"{name} {i}: the gripper closes (openness {op.min()})"
            assert not opened.attached.any()
            np.testing.assert_allclose(opened.object, np.repeat(closed.object[:1], 17, 0))  # never moves
            assert closed.attached.any()  # the same pick, closed, carries the ball away
            assert np.linalg.norm(closed.object[-1, :2] - closed.object[0, :2]) > closed.object_radius
    assert n >= 6


def test_open_picks_leave_the_missed_picks_and_the_default_as_they_were():
    for name in ARMS:
        for i in range(4):
            base = motion(name, i)
            np.testing.assert_array_equal(motion(name, i, pick_open=0.0).object, base.object)
            missed = motion(name, i, pick_miss=1.0)
            both = motion(name, i, pick_miss=1.0, pick_open=1.0)  # a missed pick is never also open
            assert both.missed == missed.missed and not (both.missed and both.never_closed)
            np.testing.assert_array_equal(both.object, missed.object)


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan"), "0.5"])
def test_a_bad_fraction_is_refused(bad):
    with pytest.raises(ToyWorldError, match="--pick-open"):
        motion("toyarm", 0, pick_open=bad)


def test_generate_records_the_option_and_keeps_old_fingerprints(tmp_path):
    def fingerprint(out, **kw):
        generate_clipset(GenerateConfig(("toyarm",), 2, 32, 32, 9, seed=1, **kw), out, REG)
        return json.loads((out / "fingerprint.json").read_text())["parts"]

    plain = fingerprint(tmp_path / "plain")
    assert "pick_open" not in plain  # a set made before the option keeps its fingerprint (resume still works)
    opened = fingerprint(tmp_path / "open", pick_open=1.0)
    assert opened["pick_open"] == 1.0
    rec = json.loads((tmp_path / "open" / "shard-toyarm-000000" / "clips.jsonl").read_text().splitlines()[0])
    gt = rec["meta"]["toyworld"]
    assert gt["never_closed"] == (gt["kind"] == "pick_place") and not gt["grabbed"]
    ep = make_episode(REG.get("toyarm"), episode_rng(1, "toyarm", 0), 32, 32, 9, ss=1)
    assert ep.motion.never_closed is False
