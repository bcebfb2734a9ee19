"""The rasteriser: lines, dots, clipping, visibility, scaling, gripper indicator."""

import numpy as np
import pytest

from oscar_core.render.raster import GripperMarks, SkeletonStyle, rasterise

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
    far = np.array([[100.0, 100.0], [100.0 + 1e9, 100.0 + 0.25e9]])  # same line, 1e9 px away
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
        out = draw([[50.0 * scale, 140.3 * scale], [450.0 * scale, 140.3 * scale]], size=(W, H), pcol=[(0, 0, 0)] * 2)[
            0
        ]
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
        rasterise(
            np.zeros((3, 2)), np.ones((3, 2), bool), [(0, 1)], (64, 64), edge_colors=[RED], point_colors=[RED] * 2
        )
    with pytest.raises(ValueError, match="edges index out of range"):
        draw([[1.0, 1.0], [2.0, 2.0]], edges=[(0, 5)])


# ---------------------------------------------------------------- further details


def segment(p0, p1, *, size=(512, 288), line_width=2.0):
    """(H, W) intensity image of one white segment without dots."""
    out = rasterise(
        np.array([[p0, p1]], float),
        np.ones((1, 2), bool),
        [(0, 1)],
        size,
        edge_colors=[(255, 255, 255)],
        point_colors=[(0, 0, 0)] * 2,
        style=SkeletonStyle(line_width=line_width, point_radius=0),
    )
    return out[0, ..., 0]


def test_sub_pixel_position_moves_the_line_centroid():
    centroids = []
    for y in np.arange(50.0, 51.01, 0.125):
        profile = segment((100.0, y), (400.0, y))[:, 250].astype(float)
        centroids.append((profile * np.arange(288)).sum() / profile.sum())
        assert centroids[-1] == pytest.approx(y, abs=0.12)  # OpenCV's AA fill is good to ~0.1 px
    assert all(b > a for a, b in zip(centroids, centroids[1:]))


@pytest.mark.parametrize("far", [1e9, 1e15])
def test_far_endpoint_matches_a_near_off_image_point_on_the_same_line(far):
    p0 = np.array([120.25, 90.75])
    direction = np.array([3.0, 1.0]) / np.sqrt(10.0)
    far_img = segment(p0, p0 + far * direction).astype(int)
    near_img = segment(p0, p0 + 800.0 * direction).astype(int)
    assert far_img.max() > 200 and np.abs(far_img - near_img).max() <= 2
    across = segment((-far, 144.0), (far, 144.0))  # both ends far away, on opposite sides
    assert across[144].min() > 0 and across[:140].max() == 0 and across[149:].max() == 0


def test_degenerate_segments_do_not_fail():
    blob = segment((200.0, 100.0), (200.0, 100.0))  # zero length: a small blob
    assert blob[100, 200] > 0 and blob[110:].max() == 0
    assert segment((-50.0, -10.0), (-30.0, 400.0)).max() == 0  # wholly outside


def test_off_image_point_gets_no_dot_but_its_segment_is_drawn():
    uv = [[100.0, 100.0], [700.0, 100.0]]
    assert draw(uv)[0][100, 300:512].any(-1).all()
    assert not draw(uv, edges=np.zeros((0, 2), int))[0][:, 400:].any()


def test_invisible_point_in_one_frame_leaves_other_frames_alone():
    uv = np.array([[[50.0, 50.0], [250.0, 60.0], [300.0, 200.0]]] * 2)
    visible = np.array([[True, True, False], [True, True, True]])
    out = draw(uv, visible=visible, edges=[(0, 1), (1, 2)])
    np.testing.assert_array_equal(out[1], draw(uv[1], edges=[(0, 1), (1, 2)])[0])
    np.testing.assert_array_equal(out[0], draw(uv[0, :2], edges=[(0, 1)])[0])


@pytest.mark.parametrize("line_width", [2.0, 3.0, 4.5, 8.0])
def test_effective_line_width_matches_the_style(line_width):
    """Ink per unit length equals the requested width (OpenCV's AA fattening is compensated)."""
    rng = np.random.default_rng(int(line_width * 10))
    ys, xs = np.mgrid[0:288, 0:288]
    widths = []
    for _ in range(12):
        c = rng.uniform(130, 150, 2)
        ang = rng.uniform(0, np.pi)
        d = np.array([np.cos(ang), np.sin(ang)])
        img = segment(c - 60 * d, c + 60 * d, size=(288, 288), line_width=line_width)
        band = np.abs((xs - c[0]) * d[0] + (ys - c[1]) * d[1]) < 30
        widths.append(img[band].astype(float).sum() / 255.0 / 60.0)
    assert np.mean(widths) == pytest.approx(line_width, abs=0.2)


def test_line_is_still_visible_at_a_tiny_resolution():
    assert segment((5.0, 10.0), (60.0, 10.0), size=(64, 36))[:, 30].max() >= 200


def test_dots_have_the_point_colour():
    out = draw([[100.0, 100.0], [300.0, 200.0]], edges=np.zeros((0, 2), int), pcol=[(10, 20, 30), (200, 100, 0)])[0]
    assert tuple(out[100, 100]) == (10, 20, 30) and tuple(out[200, 300]) == (200, 100, 0)
    assert not out[100, 110].any()  # radius 3 px at the reference height


def test_out_array_is_zeroed_and_drawn_into():
    uv = np.array([[[100.0, 100.0], [300.0, 120.0]]] * 2)
    buf = np.full((2, 288, 512, 3), 7, np.uint8)
    assert draw(uv, out=buf) is buf
    np.testing.assert_array_equal(buf, draw(uv))
    with pytest.raises(ValueError, match="out must be"):
        draw(uv, out=np.zeros((2, 288, 512, 3), np.float32))


def test_empty_inputs():
    assert draw(np.zeros((0, 2, 2))).shape == (0, 288, 512, 3)
    assert not draw(np.zeros((2, 0, 2)), edges=np.zeros((0, 2), int)).any()


def test_without_antialiasing_only_pure_colours_appear():
    out = draw([[100.0, 100.0], [300.0, 150.0]], style=SkeletonStyle(antialias=False))[0]
    colours = {tuple(c) for c in out.reshape(-1, 3).tolist()}
    assert colours == {(0, 0, 0), RED, BLUE}


def test_gripper_ring_marks_the_open_size_and_openness_is_clipped():
    style = SkeletonStyle()
    base = np.array([[10.0, 10.0], [20.0, 10.0]])
    closed = draw(base, grippers=marks(0.0))[0]
    ring = closed[144, 256 + 7 : 256 + 12]  # 9 px out: the open-size ring, in the open colour
    assert ring[:, 1].max() > 100 and not ring[:, 0].any()
    assert not closed[144, 256 + 6].any()  # black between the closed disc and the ring
    np.testing.assert_array_equal(draw(base, grippers=marks(1.7))[0], draw(base, grippers=marks(1.0))[0])
    np.testing.assert_array_equal(draw(base, grippers=marks(-0.5))[0], closed)
    ink = [draw(base, grippers=marks(o))[0].astype(np.int64).sum() for o in np.linspace(0, 1, 11)]
    assert all(b > a for a, b in zip(ink, ink[1:]))
    assert tuple(style.gripper_color_closed) == tuple(closed[144, 256])


def test_gripper_is_drawn_over_the_skeleton_and_hidden_when_not_visible():
    uv = np.array([[256.0 - 100, 144.0], [256.0, 144.0]])
    base = draw(uv, ecol=[BLUE])[0]
    hidden = GripperMarks(uv=np.array([[[256.0, 144.0]]]), visible=np.array([[False]]), openness=np.array([[1.0]]))
    np.testing.assert_array_equal(draw(uv, ecol=[BLUE], grippers=hidden)[0], base)
    shown = draw(uv, ecol=[BLUE], grippers=marks(0.0))[0]
    assert tuple(shown[144, 256]) == SkeletonStyle().gripper_color_closed


def test_style_scale_for():
    style = SkeletonStyle()
    assert style.scale_for(512, 288) == 1.0
    assert style.scale_for(1280, 704) == pytest.approx(704 / 288)
    assert style.scale_for(288, 1024) == 1.0  # portrait: the shorter side counts
