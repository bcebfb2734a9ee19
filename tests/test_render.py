"""The rasteriser: lines, dots, clipping, visibility, scaling, gripper indicator."""

import numpy as np
import pytest

from oscar_core.render import GripperMarks, SkeletonStyle, rasterise

RED, GREEN, BLUE = (255, 0, 0), (0, 255, 0), (0, 0, 255)


def draw(uv, visible=None, edges=((0, 1),), size=(512, 288), ecol=None, pcol=None, **kw):
    uv = np.asarray(uv, float)
    if uv.ndim == 2:
        uv = uv[None]
    T, K = uv.shape[:2]
    visible = np.ones((T, K), bool) if visible is None else np.asarray(visible).reshape(T, K)
    edges = np.asarray(edges).reshape(-1, 2)
    ecol = np.array(ecol or [RED] * len(edges), np.uint8).reshape(-1, 3)
    pcol = np.array(pcol or [BLUE] * K, np.uint8).reshape(-1, 3)
    return rasterise(uv, visible, edges, size, edge_colors=ecol, point_colors=pcol, **kw)


def test_shape_dtype_and_black_background():
    out = draw([[100.0, 100.0], [400.0, 100.0]])
    assert out.shape == (1, 288, 512, 3) and out.dtype == np.uint8
    assert out[0, :90].max() == 0 and out[0, 111:].max() == 0  # nothing away from the line


def test_horizontal_segment_lies_on_its_row_with_its_colour():
    out = draw([[100.0, 100.0], [400.0, 100.0]], pcol=[RED, RED])[0]
    rows = np.flatnonzero(out[:, 250].any(axis=-1))
    assert rows.min() >= 97 and rows.max() <= 103 and 100 in rows
    # the line centre has the edge's hue at (nearly) full strength: anti-aliasing
    # of a 2 px line leaves the centre pixel a few levels short of 255
    assert out[100, 250, 0] >= 230 and out[100, 250, 1] == 0 and out[100, 250, 2] == 0


def test_each_edge_keeps_its_colour():
    uv = [[50.0, 50.0], [250.0, 50.0], [250.0, 250.0]]
    out = draw(uv, edges=[(0, 1), (1, 2)], ecol=[RED, GREEN], pcol=[BLUE] * 3)[0]
    red, green = out[50, 150], out[150, 250]
    assert red[0] >= 230 and red[1:].max() == 0 and green[1] >= 230 and green[[0, 2]].max() == 0


def test_invisible_or_nan_point_removes_only_its_own_segments():
    uv = np.array([[50.0, 50.0], [250.0, 50.0], [250.0, 250.0], [450.0, 250.0]])
    edges = [(0, 1), (1, 2), (2, 3)]
    full = draw(uv, edges=edges)[0]
    hidden = draw(uv, visible=[True, True, True, False], edges=edges)[0]
    nan = uv.copy()
    nan[3] = np.nan
    with_nan = draw(nan, edges=edges)[0]
    np.testing.assert_array_equal(hidden, with_nan)
    # segment 2-3 and dot 3 are gone ...
    assert full[250, 350].any() and not hidden[250, 350].any() and not hidden[250, 450].any()
    # ... the rest is drawn exactly as before
    without_last = draw(uv[:3], edges=edges[:2])[0]
    np.testing.assert_array_equal(hidden, without_last)


def test_far_off_image_endpoint_is_clipped():
    near = np.array([[100.0, 100.0], [700.0, 100.0 + 600.0 * 0.25]])  # off the right edge
    far = np.array([[100.0, 100.0], [100.0 + 1e9, 100.0 + 0.25e9]])    # same line, 1e9 px away
    a, b = draw(near)[0], draw(far)[0]
    assert a[:, :500].any()
    diff = np.abs(a.astype(int) - b.astype(int))
    assert diff.max() <= 40 and (diff > 0).mean() < 0.001  # the same pixels up to sub-pixel rounding


def test_segment_between_two_off_image_points_crossing_the_image_is_drawn():
    out = draw([[-100.0, 144.0], [700.0, 144.0]])[0]
    assert out[144, 5].any() and out[144, 500].any()


def test_thickness_scales_with_resolution():
    def lit_column(scale):
        W, H = 512 * scale, 288 * scale
        out = draw([[50.0 * scale, 140.3 * scale], [450.0 * scale, 140.3 * scale]], size=(W, H), pcol=[(0, 0, 0)] * 2)[0]
        return out[:, 250 * scale, 0].astype(float).sum() / 255.0  # ink across the line
    assert lit_column(2) / lit_column(1) == pytest.approx(2.0, rel=0.15)


def marks(openness, uv=(256.0, 144.0)):
    return GripperMarks(uv=np.array([[uv]]), visible=np.array([[True]]), openness=np.array([[openness]]))


def test_gripper_indicator_changes_continuously_and_grows_with_openness():
    base = np.array([[10.0, 10.0], [20.0, 10.0]])
    a = draw(base, grippers=marks(0.30))[0]
    b = draw(base, grippers=marks(0.31))[0]
    assert np.any(a != b)
    areas = [(draw(base, grippers=marks(o))[0][100:190, 200:310] > 0).any(-1).sum() for o in np.linspace(0, 1, 6)]
    assert all(x <= y for x, y in zip(areas, areas[1:])) and areas[-1] > areas[0]


def test_gripper_colour_goes_from_closed_to_open():
    style = SkeletonStyle()
    base = np.array([[10.0, 10.0], [20.0, 10.0]])
    closed = draw(base, grippers=marks(0.0))[0][144, 256]
    opened = draw(base, grippers=marks(1.0))[0][144, 256]
    assert tuple(closed) == style.gripper_color_closed and tuple(opened) == style.gripper_color_open


def test_nan_openness_hides_the_indicator():
    base = np.array([[10.0, 10.0], [20.0, 10.0]])
    with_nan = draw(base, grippers=marks(np.nan))[0]
    without = draw(base)[0]
    np.testing.assert_array_equal(with_nan, without)


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="uv must have shape"):
        rasterise(np.zeros((3, 2)), np.ones((3, 2), bool), [(0, 1)], (64, 64), edge_colors=[RED], point_colors=[RED] * 2)
    with pytest.raises(ValueError, match="edges index out of range"):
        draw([[1.0, 1.0], [2.0, 2.0]], edges=[(0, 5)])
