"""A vectorised NumPy z-buffer triangle rasteriser (the mesh condition's renderer).

Pixel centres are at integer coordinates, as :func:`oscar_core.camera.projection.project`
puts them. A pixel is covered by a triangle when its centre is inside or on an
edge. Each edge function is evaluated with the edge's endpoints in a canonical
order (lexicographic in (u, v)), so two triangles sharing an edge compute the
same value with opposite signs: no pixel on a shared edge is missed (no cracks)
whatever the rounding. Depth is the nearest 1/z, interpolated linearly in the
image (exact for a planar triangle under a pinhole camera), so depth order is
per pixel, not per triangle.

Each frame is rasterised on its own (a frame's pixels never depend on other
frames), in batches of triangles with at most ``max_fragments`` candidate
pixels each, so memory is bounded whatever the triangles' size on screen.
"""

from __future__ import annotations

import numpy as np

__all__ = ["shade_faces", "clip_near", "rasterise_mesh", "NEAR", "CLIP_Z", "MAX_FRAGMENTS"]

NEAR = 1e-3  # metres: triangles with a corner nearer the camera than this are not drawn
CLIP_Z = 2 * NEAR  # metres: :func:`clip_near` cuts triangles at this depth
MAX_FRAGMENTS = 1 << 20  # candidate pixels per batch of triangles (bounds memory: ~150 MB)


def shade_faces(points_cv: np.ndarray, faces: np.ndarray, base_rgb: np.ndarray, ambient: float = 0.3) -> np.ndarray:
    """Lambert shading with a light at the camera (a headlight), flat per face, two-sided.

    points_cv: (V, 3) camera-frame vertices, metres (OpenCV axes); faces: (F, 3);
    base_rgb: (F, 3) uint8 colour of each face at full light. Returns (F, 3) uint8:
    ``base * (ambient + (1 - ambient) * |n · v|)`` with n the face's unit normal and
    v the unit direction from the face's centroid to the camera.
    """
    a, b, c = points_cv[faces[:, 0]], points_cv[faces[:, 1]], points_cv[faces[:, 2]]
    n = np.cross(b - a, c - a)
    view = -(a + b + c)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs(np.einsum("fi,fi->f", n, view)) / (np.linalg.norm(n, axis=1) * np.linalg.norm(view, axis=1))
    cos = np.nan_to_num(cos, nan=0.0)
    light = ambient + (1.0 - ambient) * np.clip(cos, 0.0, 1.0)
    return np.clip(base_rgb * light[:, None] + 0.5, 0, 255).astype(np.uint8)


def clip_near(points_cv: np.ndarray, faces: np.ndarray, z: float = CLIP_Z) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cut triangles at the plane ``depth = z`` in front of the camera (camera frame, OpenCV axes).

    points_cv: (V, 3) metres; faces: (F, 3). Returns (V', 3) points (the V
    given, then the cut points), (F', 3) faces and (F',) index of the face each
    came from. Faces wholly in front are kept as they are; wholly behind are
    dropped; one corner behind gives two triangles, two give one, wound as the
    face was. A cut point depends only on its edge's two vertex indices (taken
    smaller first), so neighbours sharing a cut edge share its point exactly.
    """
    behind = ~(points_cv[:, 2] > z)  # NaN counts as behind
    nb = behind[faces].sum(1)
    keep = np.flatnonzero(nb == 0)
    one, two = np.flatnonzero(nb == 1), np.flatnonzero(nb == 2)
    if len(one) == 0 and len(two) == 0:
        return points_cv, faces[keep], keep
    new_points, new_faces, src = [points_cv], [faces[keep]], [keep]
    count = len(points_cv)

    def rotated(idx, odd):
        """Faces idx rotated so their odd-one-out corner (behind for one, in front for two) comes first."""
        f = faces[idx]
        k = np.argmax(behind[f] == odd, axis=1)
        return f[np.arange(len(f))[:, None], (k[:, None] + np.arange(3)) % 3]

    def cut(p, q):
        """Points (n, 3) where edges p-q (vertex indices) cross the plane, from the smaller index's end."""
        lo, hi = np.minimum(p, q), np.maximum(p, q)
        a, b = points_cv[lo], points_cv[hi]
        t = (z - a[:, 2]) / (b[:, 2] - a[:, 2])
        out = a + t[:, None] * (b - a)
        out[:, 2] = z
        return out

    for idx, odd in ((one, True), (two, False)):
        if not len(idx):
            continue
        f = rotated(idx, odd)
        ab, ac = cut(f[:, 0], f[:, 1]), cut(f[:, 0], f[:, 2])
        n = len(f)
        i_ab, i_ac = count + np.arange(n), count + n + np.arange(n)
        new_points += [ab, ac]
        count += 2 * n
        if odd:  # a behind: the quad ab, b, c, ac in the face's order
            new_faces += [np.stack([i_ab, f[:, 1], f[:, 2]], 1), np.stack([i_ab, f[:, 2], i_ac], 1)]
            src += [idx, idx]
        else:  # b and c behind: a, ab, ac
            new_faces.append(np.stack([f[:, 0], i_ab, i_ac], 1))
            src.append(idx)
    return np.concatenate(new_points), np.concatenate(new_faces), np.concatenate(src)


def _edge_params(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, ...]:
    """Canonical edge (start (F, 2), direction (F, 2), sign (F,)): sign −1 where p, q were swapped."""
    swap = (p[:, 0] > q[:, 0]) | ((p[:, 0] == q[:, 0]) & (p[:, 1] > q[:, 1]))
    s = np.where(swap[:, None], q, p)
    e = np.where(swap[:, None], p, q)
    return s, e - s, np.where(swap, -1.0, 1.0)


def rasterise_mesh(
    uv: np.ndarray,
    depth: np.ndarray,
    faces: np.ndarray,
    face_rgb: np.ndarray,
    size: tuple[int, int],
    out: np.ndarray | None = None,
    *,
    usable: np.ndarray | None = None,
    cull_back: bool = False,
    max_fragments: int = MAX_FRAGMENTS,
) -> np.ndarray:
    """Draw one frame of triangles with a z-buffer.

    uv: (V, 2) pixels; depth: (V,) metres along the optical axis; faces: (F, 3)
    int; face_rgb: (F, 3) uint8, or a callable ``rgb(index (F',) of kept faces)
    -> (F', 3) uint8`` so that only faces that can be drawn are shaded;
    size: (width, height); out: optional (H, W, 3) uint8 canvas (drawn over, not
    cleared); usable: optional (V,) bool, False for vertices whose pixel position
    is not to be trusted (triangles using one are skipped); cull_back: skip
    triangles facing away from the camera (right only for closed meshes wound
    counter-clockwise seen from outside). Triangles with a corner nearer than
    :data:`NEAR` are skipped (cut them first with :func:`clip_near`). Returns the canvas.
    """
    W, H = int(size[0]), int(size[1])
    if out is None:
        out = np.zeros((H, W, 3), np.uint8)
    ok_v = np.isfinite(uv).all(1) & np.isfinite(depth) & (depth > NEAR)
    if usable is not None:
        ok_v &= usable
    idx = np.flatnonzero(ok_v[faces].all(1))
    if len(idx) == 0:
        return out
    f = faces[idx]
    a, b, c = uv[f[:, 0]], uv[f[:, 1]], uv[f[:, 2]]
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    lo = np.minimum(np.minimum(a, b), c)
    hi = np.maximum(np.maximum(a, b), c)
    x0 = np.maximum(np.ceil(lo[:, 0]), 0)
    y0 = np.maximum(np.ceil(lo[:, 1]), 0)
    x1 = np.minimum(np.floor(hi[:, 0]), W - 1)
    y1 = np.minimum(np.floor(hi[:, 1]), H - 1)
    # image v points down: a triangle wound counter-clockwise seen from the camera has area2 < 0
    keep = ((area2 < 0) if cull_back else (area2 != 0)) & (x1 >= x0) & (y1 >= y0)
    if not keep.any():
        return out
    idx, f, a, b, c, area2 = idx[keep], f[keep], a[keep], b[keep], c[keep], area2[keep]
    x0, y0 = x0[keep], y0[keep]
    bw, bh = (x1[keep] - x0 + 1).astype(np.int64), (y1[keep] - y0 + 1).astype(np.int64)
    rgb = face_rgb(idx) if callable(face_rgb) else face_rgb[idx]
    orient = np.sign(area2)
    iz = 1.0 / depth[f]  # (F, 3)
    gx = ((iz[:, 1] - iz[:, 0]) * (c[:, 1] - a[:, 1]) - (iz[:, 2] - iz[:, 0]) * (b[:, 1] - a[:, 1])) / area2
    gy = ((iz[:, 2] - iz[:, 0]) * (b[:, 0] - a[:, 0]) - (iz[:, 1] - iz[:, 0]) * (c[:, 0] - a[:, 0])) / area2
    cols = [gx, gy, iz[:, 0] - gx * a[:, 0] - gy * a[:, 1]]  # 1/z = gx*x + gy*y + g0
    for p, q in ((a, b), (b, c), (c, a)):
        s, d, sign = _edge_params(p, q)
        # e = d.x*(y - s.y) - d.y*(x - s.x) = A x + B y + C, from the canonical endpoints only, so that
        # a shared edge has the same A, B, C in both triangles (negation by ``sign * orient`` is exact)
        so = sign * orient
        cols += [-d[:, 1] * so, d[:, 0] * so, (d[:, 1] * s[:, 0] - d[:, 0] * s[:, 1]) * so]
    # float32 from here: the same rounding for a shared edge in both triangles keeps it watertight, and
    # 1/z keeps ~1e-7 relative resolution; halves the memory traffic of the per-pixel work
    params = np.stack(cols, axis=1).astype(np.float32)  # (F, 12)
    x0, y0 = x0.astype(np.float32), y0.astype(np.float32)
    zbuf = np.full(H * W, -np.inf, np.float32)
    flat = out.reshape(-1, 3)
    # triangles whose box fits 2 x 2 or 4 x 4 pixels (most, on simplified meshes): broadcast, no gathers
    frags, rest = [], np.ones(len(bw), bool)
    for k in (2, 4):
        sel = np.flatnonzero(rest & (bw <= k) & (bh <= k))
        rest[sel] = False
        frags.append(_fixed_fragments(params[sel], x0[sel], y0[sel], bw[sel], bh[sel], sel, k))
    big = np.flatnonzero(rest)
    n = bw[big] * bh[big]
    ends = np.cumsum(n)
    start = 0
    while start < len(big):  # batches of whole triangles with at most max_fragments candidates
        base = ends[start - 1] if start else 0
        stop = max(start + 1, int(np.searchsorted(ends, base + max_fragments, side="right")))
        sel = big[start:stop]
        frags.append(_spread_fragments(params[sel], x0[sel], y0[sel], bw[sel], n[start:stop], sel))
        if sum(len(fr[0]) for fr in frags) > max_fragments:
            _resolve(frags, W, zbuf, flat, rgb)
            frags = []
        start = stop
    _resolve(frags, W, zbuf, flat, rgb)
    return out


def _inside(P: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Covered: all three edge functions ≥ 0 (P: per-candidate or broadcast (…, 12) params)."""
    inside = P[..., 3] * x + P[..., 4] * y + P[..., 5] >= 0
    inside &= P[..., 6] * x + P[..., 7] * y + P[..., 8] >= 0
    inside &= P[..., 9] * x + P[..., 10] * y + P[..., 11] >= 0
    return inside


def _fixed_fragments(params, x0, y0, bw, bh, tri, k: int):
    """Covered pixels of triangles whose box fits in k × k: (pixel x, y, 1/z, triangle) arrays."""
    oy, ox = (v.astype(np.float32) for v in np.divmod(np.arange(k * k), k))
    x = x0[:, None] + ox[None, :]
    y = y0[:, None] + oy[None, :]
    P = params[:, None, :]
    hit = _inside(P, x, y) & (ox[None, :] < bw[:, None]) & (oy[None, :] < bh[:, None])
    r, col = np.nonzero(hit)
    xs, ys = x[r, col], y[r, col]
    invz = params[r, 0] * xs + params[r, 1] * ys + params[r, 2]
    return xs, ys, invz, tri[r]


def _spread_fragments(params, x0, y0, bw, n, tri):
    """Covered pixels of triangles with any box (one candidate per pixel of each box)."""
    total = int(n.sum())
    rep = np.repeat(np.arange(len(n)), n)
    local = np.arange(total) - np.repeat(np.cumsum(n) - n, n)
    bwt = bw[rep]
    ly = local // bwt
    x = x0[rep] + (local - ly * bwt).astype(np.float32)
    y = y0[rep] + ly.astype(np.float32)
    P = params[rep]
    hit = _inside(P, x, y)
    x, y, P = x[hit], y[hit], P[hit]
    return x, y, P[:, 0] * x + P[:, 1] * y + P[:, 2], tri[rep[hit]]


def _resolve(frags, W: int, zbuf: np.ndarray, flat: np.ndarray, rgb: np.ndarray) -> None:
    """z-test fragments (in order) against ``zbuf`` (nearest 1/z wins; ties: the later) and paint winners."""
    frags = [fr for fr in frags if len(fr[0])]
    if not frags:
        return
    x, y, invz, tri = (np.concatenate(parts) for parts in zip(*frags))
    pix = y.astype(np.int64) * W + x.astype(np.int64)
    np.maximum.at(zbuf, pix, invz)
    win = invz >= zbuf[pix]
    flat[pix[win]] = rgb[tri[win]]
