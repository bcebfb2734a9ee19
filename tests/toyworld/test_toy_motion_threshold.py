"""The toy world's motion mask at its threshold: a grey-level change of exactly MOTION_THRESHOLD does not count,
just above it does, just below it does not; darker and brighter count alike; changes are measured from frame 0."""

import numpy as np
import pytest

from oscar_core.toyworld.evaluate import MOTION_THRESHOLD, motion_iou, motion_mask


def _video(deltas, base=100.0, dtype=np.float32):
    """(2, 1, N, 3): frame 0 all ``base``; frame 1 pixel i at ``base + deltas[i]`` (the same in R, G and B)."""
    v = np.full((2, 1, len(deltas), 3), base, dtype=np.float64)
    v[1, 0, :, :] += np.asarray(deltas, dtype=np.float64)[:, None]
    return v.astype(dtype)


def test_the_threshold_is_24_grey_levels_strictly_exceeded():
    assert MOTION_THRESHOLD == 24.0  # the documented value (docs/toyworld.md)
    t = MOTION_THRESHOLD
    deltas = [t, t + 0.01, t - 0.01, -t, -(t + 0.01), 0.0]
    assert motion_mask(_video(deltas))[0, 0].tolist() == [False, True, False, False, True, False]


def test_the_threshold_on_uint8_frames():
    deltas = [23, 24, 25, -25, 100]
    assert motion_mask(_video(deltas, dtype=np.uint8))[0, 0].tolist() == [False, False, True, True, True]


def test_the_grey_level_is_the_mean_of_rgb():
    v = np.full((2, 1, 2, 3), 100.0, np.float32)
    v[1, 0, 0] = (100 + 3 * 24, 100, 100)  # one channel up by 72: mean up by exactly 24 → not counted
    v[1, 0, 1] = (100 + 3 * 24 + 0.3, 100, 100)  # mean up by 24.1 → counted
    assert motion_mask(v)[0, 0].tolist() == [False, True]


def test_changes_are_measured_from_the_first_frame():
    v = np.full((3, 1, 1, 3), 100.0, np.float32)
    v[1:] = 130.0  # changed at frame 1, then still: still different from frame 0 at frame 2
    assert motion_mask(v)[:, 0, 0].tolist() == [True, True]


def test_motion_iou_moves_across_the_threshold():
    gt = _video([30.0, 30.0, 0.0, 0.0])
    at = _video([24.0, 30.0, 0.0, 0.0])  # the first pixel exactly at the threshold: not moving
    above = _video([24.0 + 1e-3, 30.0, 0.0, 0.0])
    assert motion_iou(at, gt) == pytest.approx(1 / 2)
    assert motion_iou(above, gt) == 1.0
    assert motion_iou(at, gt, threshold=23.9) == 1.0


def test_exact_threshold_changes_with_sums_not_divisible_by_3_do_not_count():
    """RGB sums that are not multiples of 3: a float32 mean rounds and once counted these exact 24-level changes."""
    pairs = [
        ((62, 48, 41), (87, 67, 69)),
        ((170, 132, 57), (197, 155, 79)),
        ((96, 50, 174), (126, 67, 199)),
        ((123, 125, 72), (152, 147, 93)),
    ]
    v = np.zeros((2, 1, len(pairs), 3), np.uint8)
    for i, (a, b) in enumerate(pairs):
        assert sum(a) % 3 and sum(b) - sum(a) == 3 * 24  # mean up by exactly 24 levels
        v[0, 0, i], v[1, 0, i] = a, b
    assert not motion_mask(v).any()
    v[1, 0, :, 0] += 1  # one level more in one channel: the mean is up by 24 1/3 > 24
    assert motion_mask(v).all()
    # the same frames as float32 (the extra level taken back off): an exact 24-level change again, not counted
    back = v.astype(np.float32)
    back[1, 0, :, 0] -= 1
    assert not motion_mask(back).any()
