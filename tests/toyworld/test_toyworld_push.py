"""The toy simulator's push rule (``carry_object(..., push_contact=...)``) against analytic cases."""

from __future__ import annotations

import numpy as np
import pytest

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
