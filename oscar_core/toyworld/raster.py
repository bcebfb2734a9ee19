"""Z-buffered shaded primitives for the toy world: capsules (links) and spheres (object, markers).

Everything here works in one image of ``height`` x ``width`` pixels with the
OpenCV camera frame: pixel centres at integer coordinates, x right, y down,
depth z forward in metres. A primitive is drawn where it is nearer than what
the depth buffer holds (true per-pixel depth ordering, not painter's order).

Shading: Lambert diffuse + Blinn-Phong specular from one directional light
given in the camera frame, plus ambient. Normals are exact for a sphere and
for a capsule seen side-on (the capsule's cross-section is treated as facing
the camera, which is exact at the silhouette and close elsewhere).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Light", "Canvas"]


@dataclass(frozen=True)
class Light:
    """One directional light in the OpenCV camera frame.

    direction: (3,) unit vector from the surface towards the light (y down, so
    a light from above has negative y); ambient, diffuse, specular: weights;
    shininess: Blinn-Phong exponent; tint: (3,) RGB multiplier of the light.
    """

    direction: tuple[float, float, float] = (0.3, -0.6, -0.74)
    ambient: float = 0.35
    diffuse: float = 0.7
    specular: float = 0.25
    shininess: float = 24.0
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def shade(self, normals: np.ndarray, base: np.ndarray) -> np.ndarray:
        """normals: (N, 3) unit, camera frame; base: (3,) or (N, 3) RGB in [0, 1] → (N, 3) RGB in [0, 1]."""
        L = np.asarray(self.direction, dtype=np.float64)
        L = L / np.linalg.norm(L)
        Hv = L + np.array([0.0, 0.0, -1.0])  # viewer looks along +z: towards the viewer is -z
        Hv = Hv / np.linalg.norm(Hv)
        lam = np.clip(normals @ L, 0.0, None)
        spec = np.clip(normals @ Hv, 0.0, None) ** self.shininess
        tint = np.asarray(self.tint)
        rgb = np.asarray(base) * (self.ambient + self.diffuse * lam)[:, None] * tint + (self.specular * spec)[:, None]
        return np.clip(rgb, 0.0, 1.0)


class Canvas:
    """An RGB image (float, [0, 1]) with a depth buffer and a label map.

    rgb: (H, W, 3); depth: (H, W) metres (inf = empty); label: (H, W) int32,
    -1 where nothing but the background was drawn, else the id passed to the
    draw call that won the pixel. full_frame: evaluate every primitive over
    the whole image instead of its bounding box (the naive way; benchmarks
    compare against it; same pixels).
    """

    def __init__(self, background: np.ndarray, depth: np.ndarray | None = None, full_frame: bool = False):
        self.rgb = np.array(background, dtype=np.float64, copy=True)
        H, W = self.rgb.shape[:2]
        self.depth = np.full((H, W), np.inf) if depth is None else np.array(depth, dtype=np.float64, copy=True)
        self.label = np.full((H, W), -1, dtype=np.int32)
        self.height, self.width = H, W
        self.full_frame = full_frame

    def _box(self, u0, u1, v0, v1):
        if self.full_frame:
            u0, u1, v0, v1 = 0, self.width - 1, 0, self.height - 1
        x0, x1 = max(int(np.floor(u0)), 0), min(int(np.ceil(u1)) + 1, self.width)
        y0, y1 = max(int(np.floor(v0)), 0), min(int(np.ceil(v1)) + 1, self.height)
        if x0 >= x1 or y0 >= y1:
            return None
        ys, xs = np.mgrid[y0:y1, x0:x1]
        return (slice(y0, y1), slice(x0, x1)), xs.astype(np.float64), ys.astype(np.float64)

    def _write(self, sl, inside, depth, normals, color, light: Light, label: int) -> None:
        zb = self.depth[sl]
        win = inside & (depth < zb)
        if not win.any():
            return
        self.rgb[sl][win] = light.shade(normals[win], color)
        zb[win] = depth[win]
        self.label[sl][win] = label

    def capsule(
        self, p0, p1, z0: float, z1: float, radius: float, focal: float, color, light: Light, label: int
    ) -> None:
        """A capsule between pixels ``p0``, ``p1`` (2,) at depths ``z0``, ``z1`` (metres, > 0).

        radius: metres; focal: pixels (its on-screen radius is radius·focal/z,
        interpolated along the segment); color: (3,) RGB in [0, 1].
        """
        p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
        r0, r1 = radius * focal / z0, radius * focal / z1
        rmax = max(r0, r1)
        box = self._box(
            min(p0[0], p1[0]) - rmax, max(p0[0], p1[0]) + rmax, min(p0[1], p1[1]) - rmax, max(p0[1], p1[1]) + rmax
        )
        if box is None:
            return
        sl, xs, ys = box
        d = p1 - p0
        dd = float(d @ d)
        if dd > 1e-12:
            t = np.clip(((xs - p0[0]) * d[0] + (ys - p0[1]) * d[1]) / dd, 0.0, 1.0)
        else:
            t = np.zeros_like(xs)
        qx, qy = p0[0] + t * d[0], p0[1] + t * d[1]
        ex, ey = xs - qx, ys - qy
        dist = np.hypot(ex, ey)
        zt = z0 + t * (z1 - z0)
        rp = radius * focal / zt
        inside = dist < rp
        s = np.where(inside, dist / rp, 0.0)
        nz = np.sqrt(np.clip(1.0 - s * s, 0.0, 1.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            ux = np.where(dist > 0, ex / dist, 0.0)
            uy = np.where(dist > 0, ey / dist, 0.0)
        normals = np.stack([s * ux, s * uy, -nz], axis=-1)
        depth = zt - radius * nz
        self._write(sl, inside, depth, normals, np.asarray(color, dtype=np.float64), light, label)

    def sphere(self, c, z: float, radius: float, focal: float, color, light: Light, label: int) -> None:
        """A sphere of ``radius`` metres centred on pixel ``c`` (2,) at depth ``z`` metres."""
        c = np.asarray(c, dtype=np.float64)
        rp = radius * focal / z
        box = self._box(c[0] - rp, c[0] + rp, c[1] - rp, c[1] + rp)
        if box is None:
            return
        sl, xs, ys = box
        ex, ey = (xs - c[0]) / rp, (ys - c[1]) / rp
        s2 = ex * ex + ey * ey
        inside = s2 < 1.0
        nz = np.sqrt(np.clip(1.0 - s2, 0.0, 1.0))
        normals = np.stack([ex, ey, -nz], axis=-1)
        depth = z - radius * nz
        self._write(sl, inside, depth, normals, np.asarray(color, dtype=np.float64), light, label)
