"""Hands in the toy world: the closed rule, grasp / carry / release and push against hand-computed positions,
deterministic episodes whose skeleton is the mano plugin's rendering, and named refusals."""

import numpy as np
import pytest

from oscar_core.plugin.registry import Registry
from oscar_core.toyworld.hand import (
    BALL_RADIUS_M,
    PINCH_CLOSED_M,
    PUSH_CONTACT_M,
    hand_carry,
    hand_closed,
    pinch_distance,
    pinch_point,
    push_object,
)
from oscar_core.toyworld.motion import ToyWorldError, check_supported, is_hand
from oscar_embodiments.mano.synthetic import hand_keypoints

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py

R = BALL_RADIUS_M


def _hand_path(pinch_targets, curls, side="right"):
    """(T, 21, 3) keypoints of a palm-down hand whose pinch point is at ``pinch_targets`` (T, 3) exactly."""
    out = []
    for target, c in zip(np.asarray(pinch_targets, float), curls):
        kp = hand_keypoints(c, side=side)
        out.append(kp - pinch_point(kp) + target)
    return np.stack(out)


def test_closed_is_the_thumb_index_distance_below_the_threshold():
    open_kp, grasp_kp = hand_keypoints(0.0), hand_keypoints(0.6)
    # the procedural hand's tips: 7.3 cm apart open, 2.1 cm at the grasp curl (both away from the threshold)
    assert pinch_distance(open_kp) == pytest.approx(0.0732, abs=5e-4)
    assert pinch_distance(grasp_kp) == pytest.approx(0.0209, abs=5e-4)
    assert not hand_closed(open_kp) and hand_closed(grasp_kp)
    # exactly at the threshold is open; just under it is closed
    kp = np.zeros((21, 3))
    kp[8] = [PINCH_CLOSED_M, 0, 0]
    assert not hand_closed(kp)
    kp[8] = [PINCH_CLOSED_M * 0.999, 0, 0]
    assert hand_closed(kp)


# frames: above the ball, at it (open), closed at it, lifted 0.1 m, carried 0.1 m along x, opened there
TARGETS = [[0.3, 0, 0.1], [0.3, 0, R], [0.3, 0, R], [0.3, 0, R + 0.1], [0.4, 0, R + 0.1], [0.4, 0, R + 0.1]]
BALL0 = np.array([0.3, 0.0, R])


def test_a_closed_hand_grasps_carries_and_releases_the_ball():
    kp = _hand_path(TARGETS, [0.0, 0.0, 0.6, 0.6, 0.6, 0.0])
    pos, attached = hand_carry(kp, BALL0, R)
    want = [[0.3, 0, R], [0.3, 0, R], [0.3, 0, R], [0.3, 0, R + 0.1], [0.4, 0, R + 0.1], [0.4, 0, R]]
    np.testing.assert_allclose(pos, want, atol=1e-12)
    assert attached.tolist() == [False, False, True, True, True, False]


def test_an_open_hand_leaves_the_ball_where_it_lies():
    kp = _hand_path(TARGETS, [0.0] * 6)
    pos, attached = hand_carry(kp, BALL0, R)
    np.testing.assert_allclose(pos, np.repeat(BALL0[None], 6, 0), atol=1e-12)
    assert not attached.any()


def test_closing_away_from_the_ball_and_moving_over_it_does_not_pick_it_up():
    far = [[0.3, 0.2, R], [0.3, 0.2, R], [0.3, 0.0, R], [0.3, 0.0, R + 0.1]]
    pos, attached = hand_carry(_hand_path(far, [0.0, 0.6, 0.6, 0.6]), BALL0, R)
    assert not attached.any()
    np.testing.assert_allclose(pos[-1], BALL0)


def test_a_low_hand_pushes_the_ball_ahead_of_its_finger_tips():
    xs = np.linspace(0.0, 0.3, 31)
    contact = np.stack([xs, np.zeros_like(xs), np.full_like(xs, 0.5 * R)], 1)
    pos = push_object(contact, np.array([0.1, 0.0, R]), R)
    # untouched until the tips come within R + contact; then kept exactly that far ahead
    reach = R + PUSH_CONTACT_M
    assert pos[0].tolist() == [0.1, 0.0, R]
    np.testing.assert_allclose(pos[-1], [0.3 + reach, 0.0, R], atol=1e-12)
    first = int(np.argmax(pos[:, 0] > 0.1))
    assert xs[first] > 0.1 - reach and xs[first - 1] <= 0.1 - reach
    # a hand that crosses the ball between two frames still pushes it (the rule sub-steps the contact's path)
    jump = np.array([[0.0, 0.0, 0.5 * R], [0.3, 0.0, 0.5 * R]])
    np.testing.assert_allclose(push_object(jump, np.array([0.1, 0.0, R]), R)[-1], [0.3 + reach, 0.0, R], atol=1e-12)
    # the same sweep 2 radii up passes over the ball
    high = contact + [0, 0, 2 * R]
    np.testing.assert_allclose(push_object(high, np.array([0.1, 0.0, R]), R)[-1], [0.1, 0.0, R])


# ---------------------------------------------------------------------- episodes
@pytest.fixture(scope="module")
def hand_sets(tmp_path_factory):
    from oscar_core.toyworld.generate import GenerateConfig, generate_clipset

    root = tmp_path_factory.mktemp("hand")
    cfg = GenerateConfig(("mano", "toyarm"), episodes=6, width=32, height=32, frames=9, shard_size=6, seed=3)
    for name in ("a", "b"):
        generate_clipset(cfg, root / name, Registry())
    return root / "a", root / "b"


def test_hand_episodes_are_deterministic_per_seed(hand_sets):
    from oscar_core.train.clips import ClipSet

    a, b = ClipSet(hand_sets[0]), ClipSet(hand_sets[1])
    ids = [r.id for r in a.records if r.embodiment == "mano"]
    assert len(ids) == 6
    kinds = set()
    for i in ids:
        ra, rb = a.record(i), b.record(i)
        assert ra == rb and ra.source == "toyworld_hand"
        kinds.add(ra.meta["toyworld"]["kind"])
        ca, cb = a.load(i), b.load(i)
        assert np.array_equal(ca.rgb, cb.rgb) and np.array_equal(ca.skeleton, cb.skeleton)
    assert kinds <= {"pick_place", "push"}


def test_the_stored_skeleton_is_the_mano_plugins_rendering_of_the_same_keypoints(hand_sets):
    from oscar_core.render.skeleton_video import render_skeleton_video
    from oscar_core.train.clips import ClipSet

    reg = Registry()
    mano = reg.get("mano")
    cs = ClipSet(hand_sets[0])
    for rec in (r for r in cs.records if r.embodiment == "mano"):
        clip = cs.load(rec.id, registry=reg)
        kp = clip.trajectory.keypoints.reshape(len(clip.trajectory), 2, 21, 3)
        hands = [h for h in range(2) if np.isfinite(kp[:, h]).all()]
        assert len(hands) == 1 and np.isnan(kp[:, 1 - hands[0]]).all()  # one hand, the other absent
        want = render_skeleton_video(mano, clip.trajectory, clip.camera)
        assert np.array_equal(clip.skeleton, want)
        assert (clip.skeleton.reshape(len(want), -1, 3).max(-1) > 0).any(1).all()  # a skeleton in every frame
        # the RGB frames differ from frame to frame where the hand moves
        assert np.abs(np.diff(clip.rgb.astype(int), axis=0)).max() > 0


def test_every_hand_episode_moves_its_ball():
    """Every hand pick_place grabs the ball (its pinch point is at the ball when it closes) and sets it down;
    every push moves it."""
    from oscar_core.toyworld.episode import episode_rng, plan_episode

    mano = Registry().get("mano")
    kinds = []
    for i in range(12):
        motion, _, _ = plan_episode(mano, episode_rng(0, "mano", i), 32, 32, 17)
        kinds.append(motion.kind)
        if motion.kind == "pick_place":
            assert motion.attached.any()
            assert motion.object[-1][2] == pytest.approx(R)  # released onto the floor
        else:
            assert not motion.attached.any()
        assert np.linalg.norm(motion.object[-1] - motion.object[0]) > 2 * R  # every hand moves its ball
    assert set(kinds) == {"pick_place", "push"}


# ---------------------------------------------------------------------- bad input
def test_keypoint_embodiments_other_than_hands_are_refused_by_name():
    mano = Registry().get("mano")
    assert is_hand(mano)
    check_supported(mano, hands=True)
    with pytest.raises(ToyWorldError, match="'mano'.*keypoints"):
        check_supported(mano)  # the joint-space motion sampler has no hand motions

    class Dots(type(mano)):
        name = "dots"
        skeleton = type(mano.skeleton)(links=("a", "b"), edges=(("a", "b"),))

    with pytest.raises(ToyWorldError, match="'dots'.*mano plugin's 2 x 21-point skeleton"):
        check_supported(Dots(), hands=True)


def test_cli_names_a_too_short_hand_episode(tmp_path, capsys):
    from oscar_core.cli import main

    code = main(
        ["toyworld", "generate", "--embodiments", "mano"]
        + ["--episodes", "1", "--frames", "7", "--size", "32x32", "--out", str(tmp_path / "o")]
    )
    err = capsys.readouterr().err
    assert code == 2, err
    assert "--frames: expected at least 9 frames for a hand episode (mano), found 7" in err
    assert not (tmp_path / "o").exists()  # before anything is written
