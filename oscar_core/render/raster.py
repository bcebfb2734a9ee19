"""Skeleton rasteriser: draws already-projected 2D points and edges into RGB frames.

No kinematics or projection happens here.  Coordinates are float pixels with x to
the right, y down, and pixel *centres* at integer coordinates (OpenCV convention).

Drawing is done with OpenCV's anti-aliased polygon filler on sub-pixel (fixed-point)
coordinates.  OpenCV's AA edges make every filled shape about 0.65 px fatter on each
side than its geometric outline, and its built-in thick lines round their thickness to
even integers; both would make the skeleton look different at different resolutions.
So segments are drawn as capsule polygons and dots as regular polygons whose geometric
size is shrunk by a calibrated amount, so that the *effective* stroke width / dot radius
(ink area / length, or sqrt(ink area / pi)) matches the requested size within ~0.1 px,
continuously, at any resolution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import cv2
import numpy as np

__all__ = ["SkeletonStyle", "GripperMarks", "rasterise"]

# Fixed-point fractional bits handed to cv2 (`shift`).  8 bits keeps the sizes
# continuous to 1/256 px; coordinates are clipped to near the image first, so the
# int32 range (2**23 px at 8 bits) is never approached.
_SHIFT = 8
_ONE = float(1 << _SHIFT)

# Calibration of cv2.fillConvexPoly(..., LINE_AA) on opencv 5.0 (mean over random
# sub-pixel positions and angles).  Left column: effective size, right: geometric size
# to draw.  Beyond the last row the relation is linear (see _calibrated).
# Capsule: effective full width -> geometric half-width.
_CAPSULE_CAL = np.array(
    [
        [1.673, 0.0],
        [1.746, 0.125],
        [1.892, 0.25],
        [2.108, 0.375],
        [2.332, 0.5],
        [2.830, 0.75],
        [3.325, 1.0],
        [4.326, 1.5],
    ]
)
# Regular polygon disc: effective radius -> geometric (area-equivalent) radius.
_DISC_CAL = np.array(
    [
        [0.223, 0.0],
        [0.884, 0.25],
        [1.179, 0.5],
        [1.427, 0.75],
        [1.671, 1.0],
        [2.164, 1.5],
        [2.647, 2.0],
        [3.143, 2.5],
        [3.640, 3.0],
    ]
)
# Effective width of cv2's 1-px anti-aliased line (the thinnest stroke available).
_THIN_LINE_WIDTH = 1.345
# Effective width of cv2 AA strokes with integer thickness t (t=1, then 2, 4, 6, ...).
_AA_STROKE_WIDTHS = {1: 1.345, 2: 3.435, 4: 5.435, 6: 7.435, 8: 9.435}


@dataclass(frozen=True)
class SkeletonStyle:
    """Look of the rendered skeleton.  Sizes are in pixels at `reference_height`.

    All sizes are multiplied by `scale_for(width, height)` so that a render at
    another resolution looks like a resized render at the reference resolution.
    line_width: effective stroke width (at least 1 px after scaling; 0 disables edges).
    point_radius: effective radius of the dot at each point (0 disables dots).
    gripper_radius_open / _closed: gripper-indicator disc radius at openness 1 / 0.
    gripper_color_open / _closed: RGB colour of the indicator at openness 1 / 0.
    antialias: anti-aliased drawing (the default); False draws hard-edged pixels.
    """

    line_width: float = 2.0
    point_radius: float = 3.0
    gripper_radius_open: float = 9.0
    gripper_radius_closed: float = 4.0
    gripper_color_open: tuple[int, int, int] = (0, 255, 0)
    gripper_color_closed: tuple[int, int, int] = (255, 0, 0)
    reference_height: int = 288
    antialias: bool = True

    @classmethod
    def from_overrides(cls, overrides, source: str = "condition_style") -> SkeletonStyle:
        """The default style with ``overrides`` (a mapping of field name → value, e.g. ``{"gripper_radius_open":
        27}``; None or empty: the default) applied; a ``ValueError`` names ``source``'s key, what was expected and
        what was found. Sizes must be finite numbers > 0 (``line_width`` and ``point_radius`` ≥ 0), colours three
        integers in [0, 255]."""
        if overrides is None:
            return cls()
        if not isinstance(overrides, dict):
            raise ValueError(f"{source}: expected a mapping of SkeletonStyle fields, found {overrides!r}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ValueError(f"{source}: expected keys among {sorted(known)}, found unknown keys {unknown}")
        out = {}
        for key, value in overrides.items():
            where = f"{source}.{key}"
            if key.startswith("gripper_color"):
                ok = (
                    isinstance(value, (list, tuple))
                    and len(value) == 3
                    and all(isinstance(c, int) and not isinstance(c, bool) and 0 <= c <= 255 for c in value)
                )
                if not ok:
                    raise ValueError(f"{where}: expected three integers in [0, 255] (RGB), found {value!r}")
                value = tuple(value)
            elif key == "antialias":
                if not isinstance(value, bool):
                    raise ValueError(f"{where}: expected true or false, found {value!r}")
            else:
                least = 0.0 if key in ("line_width", "point_radius") else None
                number = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
                if not number or (value < least if least is not None else value <= 0):
                    bound = ">= 0" if least is not None else "> 0"
                    raise ValueError(f"{where}: expected a finite number {bound}, found {value!r}")
            out[key] = value
        return cls(**out)

    def scale_for(self, width: int, height: int) -> float:
        """Size multiplier for a (width, height) image: min(width, height) / reference_height.

        The shorter side is used so portrait and landscape frames of the same
        "size class" get the same stroke sizes.
        """
        if self.reference_height <= 0:
            raise ValueError(f"reference_height must be positive, got {self.reference_height}")
        return min(int(width), int(height)) / float(self.reference_height)


@dataclass(frozen=True)
class GripperMarks:
    """Gripper indicators to draw on top of the skeleton.

    uv: (T, G, 2) float pixels, where each gripper's indicator is centred.
    visible: (T, G) bool; False (or non-finite uv) hides the indicator.
    openness: (T, G) float, 0 = closed, 1 = fully open; clipped to [0, 1]; NaN hides it.
    """

    uv: np.ndarray
    visible: np.ndarray
    openness: np.ndarray


# --------------------------------------------------------------------------- sizes


def _calibrated(effective, table: np.ndarray, slope: float) -> np.ndarray:
    """Geometric size to draw so the AA-rendered size equals `effective` (pixels).

    Interpolates `table`; beyond its last row the geometric size grows by `slope`
    per pixel of effective size.
    """
    eff = np.asarray(effective, dtype=np.float64)
    eff_col, geo_col = table[:, 0], table[:, 1]
    beyond = geo_col[-1] + slope * (eff - eff_col[-1])
    return np.where(eff <= eff_col[-1], np.interp(eff, eff_col, geo_col), beyond)


def _capsule_half_width(width_px: float, antialias: bool) -> float:
    """Geometric half-width of the capsule polygon giving an effective width `width_px`."""
    if not antialias:
        return max(width_px - 1.0, 0.0) / 2.0  # LINE_8 fill includes both boundary pixels
    return float(_calibrated(width_px, _CAPSULE_CAL, 0.5))


def _disc_radius(radius_px, antialias: bool) -> np.ndarray:
    """Geometric radius of the polygon disc giving an effective radius `radius_px`."""
    if not antialias:
        return np.maximum(np.asarray(radius_px, dtype=np.float64) - 0.5, 0.0)
    return _calibrated(radius_px, _DISC_CAL, 1.0)


def _stroke_thickness(width_px: float) -> int:
    """Integer cv2 thickness whose AA stroke width is closest to `width_px`."""
    t_max = 2 * max(1, int(math.ceil(width_px / 2.0)) + 1)
    cands = {1: _THIN_LINE_WIDTH, **{t: t + 1.435 for t in range(2, t_max + 1, 2)}}
    return min(cands, key=lambda t: abs(cands[t] - width_px))


def _polygon_vertex_count(radius_px: float) -> int:
    """Vertices for a polygonal circle of this radius (edges of about 1 px)."""
    return int(min(max(math.ceil(2.0 * math.pi * radius_px), 8), 64))


def _unit_polygon(n: int) -> np.ndarray:
    """(n, 2) vertices of a regular n-gon with the same area as the unit circle."""
    circumradius = math.sqrt(2.0 * math.pi / (n * math.sin(2.0 * math.pi / n)))
    ang = np.arange(n) * (2.0 * math.pi / n)
    return circumradius * np.stack([np.cos(ang), np.sin(ang)], axis=-1)


# ------------------------------------------------------------------------ geometry


def clip_segments(p0: np.ndarray, p1: np.ndarray, lo: float | np.ndarray, hi: np.ndarray):
    """Liang–Barsky clip of segments p0->p1 (..., 2) to the box [lo, hi] (float64).

    Returns (ok, c0, c1): ok (...) bool, clipped endpoints (..., 2).  Works for
    arbitrarily distant (finite) endpoints; non-finite results are rejected.
    """
    lo = np.broadcast_to(np.asarray(lo, dtype=np.float64), (2,))
    d = p1 - p0
    t0 = np.zeros(p0.shape[:-1])
    t1 = np.ones(p0.shape[:-1])
    ok = np.ones(p0.shape[:-1], dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for a in (0, 1):
            for p, q in ((-d[..., a], p0[..., a] - lo[a]), (d[..., a], hi[a] - p0[..., a])):
                ok &= ~((p == 0) & (q < 0))
                r = q / p
                t0 = np.where(p < 0, np.maximum(t0, r), t0)
                t1 = np.where(p > 0, np.minimum(t1, r), t1)
        ok &= t0 <= t1
        c0 = p0 + t0[..., None] * d
        c1 = p0 + t1[..., None] * d
    ok &= np.isfinite(c0).all(-1) & np.isfinite(c1).all(-1)
    return ok, c0, c1


def _capsule_vertices(c0, c1, direction, half_width: float, n_cap: int) -> np.ndarray:
    """(..., 2*n_cap, 2) float vertices of convex capsules around segments c0->c1."""
    ang = np.linspace(math.pi / 2, -math.pi / 2, n_cap)  # cap at the c1 end
    cos, sin = np.cos(ang), np.sin(ang)
    u = direction[..., None, :]
    nrm = np.stack([-direction[..., 1], direction[..., 0]], axis=-1)[..., None, :]
    off = half_width * (cos[:, None] * u + sin[:, None] * nrm)  # (..., n_cap, 2)
    return np.concatenate([c1[..., None, :] + off, c0[..., None, :] - off], axis=-2)


def _to_fixed(x: np.ndarray) -> np.ndarray:
    return np.rint(x * _ONE).astype(np.int32)


def _color_tuples(colors, n: int, what: str) -> list[tuple[int, int, int]]:
    arr = np.asarray(colors)
    if arr.shape == (3,):
        arr = np.broadcast_to(arr, (n, 3))
    if arr.shape != (n, 3):
        raise ValueError(f"{what} must have shape ({n}, 3), got {arr.shape}")
    if arr.size and (np.min(arr) < 0 or np.max(arr) > 255):
        raise ValueError(f"{what} must be in 0..255")
    return [tuple(int(v) for v in row) for row in arr.tolist()]


# ------------------------------------------------------------------------- drawing


def _checked_drawing_inputs(uv, visible, edges, size):
    """``(uv, visible, edges, width, height)`` as arrays of :func:`rasterise`'s shapes ((T, K, 2) float64, (T, K)
    bool, (E, 2) int64) and the output size in pixels; ValueError naming the argument for a wrong shape or index."""
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim != 3 or uv.shape[-1] != 2:
        raise ValueError(f"uv must have shape (T, K, 2), got {uv.shape}")
    T, K = uv.shape[:2]
    visible = np.asarray(visible, dtype=bool)
    if visible.shape != (T, K):
        raise ValueError(f"visible must have shape {(T, K)}, got {visible.shape}")
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2) if np.size(edges) else np.zeros((0, 2), np.int64)
    if edges.shape[0] and (edges.min() < 0 or edges.max() >= K):
        raise ValueError(f"edges index out of range for K={K} points")
    width, height = (int(s) for s in size)
    if width <= 0 or height <= 0:
        raise ValueError(f"size must be positive (width, height), got {size}")
    return uv, visible, edges, width, height


def _blank_frames(out: np.ndarray | None, shape: tuple[int, int, int, int]) -> np.ndarray:
    """Black (T, H, W, 3) uint8 frames of ``shape``: a new array (checked to fit in memory), or ``out`` zeroed."""
    if out is None:
        from .._util.memory import check_fits

        check_fits(
            shape, 1, "the skeleton video (T, H, W, 3) uint8", "use a smaller --size (or render fewer frames at a time)"
        )
        return np.zeros(shape, dtype=np.uint8)
    if out.shape != shape or out.dtype != np.uint8 or not out.flags.c_contiguous:
        raise ValueError(
            f"out must be a C-contiguous uint8 array of shape {shape}, "
            f"got {out.dtype} {out.shape} (contiguous={out.flags.c_contiguous})"
        )
    out[...] = 0
    return out


def _edge_endpoints(uv, usable, edges, segments):
    """``(p0, p1, ok)``: each edge's endpoints (T, E, 2) float pixels and whether it can be drawn (T, E) bool, from
    ``uv`` and ``usable`` ((T, K) bool), or from :func:`rasterise`'s ``segments`` when given."""
    T, E = uv.shape[0], edges.shape[0]
    if segments is None:
        return uv[:, edges[:, 0]], uv[:, edges[:, 1]], usable[:, edges[:, 0]] & usable[:, edges[:, 1]]
    p0, p1 = (np.asarray(a, dtype=np.float64) for a in segments[:2])
    seg_ok = np.asarray(segments[2], dtype=bool)
    if p0.shape != (T, E, 2) or p1.shape != (T, E, 2) or seg_ok.shape != (T, E):
        raise ValueError(
            f"segments must be (T, E, 2), (T, E, 2), (T, E) arrays with T={T}, E={E}, "
            f"got {p0.shape}, {p1.shape}, {seg_ok.shape}"
        )
    return p0, p1, seg_ok & np.isfinite(p0).all(-1) & np.isfinite(p1).all(-1)


def _draw_edges(frames, p0, p1, seg_ok, ecol, width_px: float, aa: bool, line_type, width: int, height: int):
    """Draws every edge that can be drawn into ``frames`` (T views (H, W, 3) uint8): clipped in float to the image
    plus a margin, as capsule polygons ``width_px`` pixels wide (a 1-pixel anti-aliased line when thinner than
    the capsule's calibrated range), in fixed point. p0, p1: (T, E, 2) float pixels; seg_ok: (T, E) bool."""
    T = len(frames)
    lo = np.array([0.0, 0.0])
    hi = np.array([width - 1.0, height - 1.0])
    thin = aa and width_px < 0.5 * (_THIN_LINE_WIDTH + _CAPSULE_CAL[0, 0])
    half = 0.0 if thin else _capsule_half_width(width_px, aa)
    margin = half + 4.0
    p0 = np.where(seg_ok[..., None], p0, 0.0)
    p1 = np.where(seg_ok[..., None], p1, 0.0)
    clip_ok, c0, c1 = clip_segments(p0, p1, lo - margin, hi + margin)
    seg_ok = seg_ok & clip_ok
    idx = [np.flatnonzero(r).tolist() for r in seg_ok]
    if thin:
        a = _to_fixed(np.where(seg_ok[..., None], c0, 0.0)).tolist()
        b = _to_fixed(np.where(seg_ok[..., None], c1, 0.0)).tolist()
        for t in range(T):
            img, at, bt = frames[t], a[t], b[t]
            for e in idx[t]:
                cv2.line(img, at[e], bt[e], ecol[e], 1, line_type, _SHIFT)
        return
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        d = p1 - p0
        length = np.hypot(d[..., 0], d[..., 1])
        direction = d / length[..., None]
    good_dir = np.isfinite(direction).all(-1) & (length > 0)
    direction = np.where(good_dir[..., None], direction, np.array([1.0, 0.0]))
    n_cap = max(2, _polygon_vertex_count(half) // 2 + 1)
    verts = _capsule_vertices(c0, c1, direction, half, n_cap)
    verts = _to_fixed(np.where(seg_ok[..., None, None], verts, 0.0))
    for t in range(T):
        img, vt = frames[t], verts[t]
        for e in idx[t]:
            cv2.fillConvexPoly(img, vt[e], ecol[e], line_type, _SHIFT)


def rasterise(
    uv,
    visible,
    edges,
    size,
    *,
    edge_colors,
    point_colors,
    grippers: GripperMarks | None = None,
    style: SkeletonStyle = SkeletonStyle(),
    out: np.ndarray | None = None,
    segments: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Draw skeleton frames on black.

    uv: (T, K, 2) float pixels (x right, y down, pixel centres at integers).
    visible: (T, K) bool, "the point is usable" (in front of the camera), NOT "inside
        the image".  A point that is not visible or has non-finite coordinates removes
        only its own segments and dot.  Segments to points outside the image are drawn,
        clipped to the image.
    edges: (E, 2) int indices into K.
    size: (width, height) of the output in pixels.
    edge_colors: (E, 3) uint8 RGB per edge; point_colors: (K, 3) uint8 RGB per point.
    grippers: optional GripperMarks drawn after the skeleton: a filled disc whose
        radius and colour interpolate linearly between the closed and open style
        values with openness, plus a thin ring in the open colour at the open radius.
    style: SkeletonStyle; sizes scale with `style.scale_for(width, height)`.
    out: optional preallocated C-contiguous (T, H, W, 3) uint8 array; it is zeroed
        and drawn into and returned.
    segments: optional (p0, p1, ok) giving each edge's endpoints directly:
        p0, p1 (T, E, 2) float pixels, ok (T, E) bool.  Used instead of
        ``uv[:, edges]`` and ``visible`` for the edges (dots still follow uv and
        visible), e.g. for an edge cut at the camera's near plane
        (:mod:`oscar_core.render.skeleton_stream`).

    Returns (T, H, W, 3) uint8 RGB frames.
    """
    uv, visible, edges, width, height = _checked_drawing_inputs(uv, visible, edges, size)
    T, K = uv.shape[:2]
    E = edges.shape[0]
    ecol = _color_tuples(edge_colors, E, "edge_colors")
    pcol = _color_tuples(point_colors, K, "point_colors")
    out = _blank_frames(out, (T, height, width, 3))
    if T == 0:
        return out

    scale = style.scale_for(width, height)
    aa = style.antialias
    line_type = cv2.LINE_AA if aa else cv2.LINE_8
    usable = visible & np.isfinite(uv).all(-1)
    frames = list(out)  # contiguous (H, W, 3) views, one per frame

    # ---- edges: clip in float, build capsule polygons, convert to fixed point.
    if E and style.line_width > 0:
        p0, p1, seg_ok = _edge_endpoints(uv, usable, edges, segments)
        _draw_edges(frames, p0, p1, seg_ok, ecol, max(1.0, style.line_width * scale), aa, line_type, width, height)

    # ---- dots at usable points that touch the image.
    if K and style.point_radius > 0:
        r_px = max(0.5, style.point_radius * scale)
        _draw_discs(frames, uv, usable, np.full((T, K), r_px), [pcol] * T, width, height, aa, line_type)

    if grippers is not None:
        _draw_grippers(frames, grippers, T, style, scale, width, height, line_type)
    return out


def _draw_discs(frames, centres, usable, radius_px, colors, width, height, aa, line_type):
    """Filled polygon discs.  centres (T, N, 2); radius_px (T, N) effective radii;
    colors: per frame, a list of N RGB tuples.

    Each disc's polygon resolution follows its own radius only, so a frame's
    pixels never depend on the other frames drawn in the same call.
    """
    T, N = usable.shape
    radius_px = np.broadcast_to(np.asarray(radius_px, dtype=np.float64), (T, N))
    geo = _disc_radius(radius_px, aa)
    near = (
        usable
        & (centres[..., 0] > -radius_px - 2)
        & (centres[..., 0] < width - 1 + radius_px + 2)
        & (centres[..., 1] > -radius_px - 2)
        & (centres[..., 1] < height - 1 + radius_px + 2)
    )
    if not near.any():
        return
    counts = np.minimum(np.maximum(np.ceil(2.0 * math.pi * radius_px), 8), 64).astype(np.int64)
    counts = np.where(near, counts, 0)
    c = np.where(near[..., None], centres, 0.0)
    polys: dict[tuple[int, int], np.ndarray] = {}
    for n in np.unique(counts[near]).tolist():
        sel = near & (counts == n)
        verts = _to_fixed(c[sel][:, None, :] + geo[sel][:, None, None] * _unit_polygon(n))  # (M, n, 2)
        for (t, k), v in zip(np.argwhere(sel).tolist(), verts):
            polys[t, k] = v
    for t in range(T):
        img, ct = frames[t], colors[t]
        for k in np.flatnonzero(near[t]).tolist():
            cv2.fillConvexPoly(img, polys[t, k], ct[k], line_type, _SHIFT)


def _draw_grippers(frames, g: GripperMarks, T, style, scale, width, height, line_type):
    guv = np.asarray(g.uv, dtype=np.float64)
    if guv.ndim != 3 or guv.shape[0] != T or guv.shape[-1] != 2:
        raise ValueError(f"grippers.uv must have shape ({T}, G, 2), got {guv.shape}")
    G = guv.shape[1]
    gvis = np.asarray(g.visible, dtype=bool)
    gopen = np.asarray(g.openness, dtype=np.float64)
    if gvis.shape != (T, G) or gopen.shape != (T, G):
        raise ValueError(
            f"grippers.visible and grippers.openness must have shape {(T, G)}, got {gvis.shape} and {gopen.shape}"
        )
    if G == 0:
        return
    ok = gvis & np.isfinite(guv).all(-1) & np.isfinite(gopen)
    o = np.clip(np.where(ok, gopen, 0.0), 0.0, 1.0)
    r_open = style.gripper_radius_open * scale
    r_closed = style.gripper_radius_closed * scale
    radius = np.maximum(r_closed + o * (r_open - r_closed), 0.5)
    c_open = np.asarray(style.gripper_color_open, dtype=np.float64)
    c_closed = np.asarray(style.gripper_color_closed, dtype=np.float64)
    rgb = np.rint(c_closed + o[..., None] * (c_open - c_closed)).astype(np.int64)
    colors = [[tuple(c) for c in row] for row in rgb.tolist()]
    _draw_discs(frames, guv, ok, radius, colors, width, height, style.antialias, line_type)

    # Reference ring at the fully-open radius (culled per indicator, never per batch).
    ring_r = np.maximum(r_open, radius)
    near = (
        ok
        & (guv[..., 0] > -ring_r - 3)
        & (guv[..., 0] < width + ring_r + 2)
        & (guv[..., 1] > -ring_r - 3)
        & (guv[..., 1] < height + ring_r + 2)
    )
    thickness = _stroke_thickness(max(1.0, scale)) if style.antialias else max(1, round(scale))
    ring_col = tuple(int(v) for v in style.gripper_color_open)
    centres = _to_fixed(np.where(near[..., None], guv, 0.0)).tolist()
    r_fixed = int(round(r_open * _ONE))
    for t, k in zip(*np.nonzero(near)):
        cv2.circle(frames[t], centres[t][k], r_fixed, ring_col, thickness, line_type, _SHIFT)
