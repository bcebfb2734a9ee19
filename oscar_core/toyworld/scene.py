"""The look of one toy-world episode: floor, backdrop, lighting, colours, and a camera that sees the robot.

Units: metres and radians in the world (z up, the floor/table plane is z = 0,
the robot's base sits on it); pixels in images.

Colours the evaluator relies on are reserved: the object is always
:data:`OBJECT_RGB` (yellow) and the end-effector marker :data:`EE_RGB`
(magenta). Link colours avoid those hues and the floor and backdrop are
desaturated, so the two can be found in any frame by colour alone
(:mod:`oscar_core.toyworld.locate`).
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass

import numpy as np

from ..camera import Camera, Intrinsics, look_at
from .raster import Light

__all__ = [
    "OBJECT_RGB",
    "EE_RGB",
    "OBJECT_HUE",
    "EE_HUE",
    "LINK_HUES",
    "Scene",
    "sample_scene",
    "background",
    "sample_camera",
]

#: Object colour, RGB in [0, 1], and its hue in degrees.
OBJECT_RGB = (1.0, 0.82, 0.0)
OBJECT_HUE = 49.0
#: End-effector marker colour, RGB in [0, 1], and its hue in degrees.
EE_RGB = (1.0, 0.0, 1.0)
EE_HUE = 300.0
#: Hues (degrees) links are drawn in: at least 40 degrees from the reserved hues.
LINK_HUES = (205.0, 175.0, 235.0, 140.0, 5.0, 190.0, 155.0, 220.0, 250.0, 120.0)


def _hsv(h_deg: float, s: float, v: float) -> np.ndarray:
    return np.array(colorsys.hsv_to_rgb((h_deg % 360.0) / 360.0, s, v))


@dataclass(frozen=True)
class Scene:
    """Appearance of one episode (all colours RGB in [0, 1]).

    floor_colors: (2, 3) checker colours; tile: checker tile size, metres;
    noise_seed: seeds the floor's value noise; sky_top, sky_bottom: (3,)
    backdrop gradient; light: the directional light; link_colors: (E, 3)
    one colour per skeleton edge; fog: metres over which the floor fades to
    the backdrop.
    """

    floor_colors: np.ndarray
    tile: float
    noise_seed: int
    sky_top: np.ndarray
    sky_bottom: np.ndarray
    light: Light
    link_colors: np.ndarray
    fog: float


def sample_scene(rng: np.random.Generator, n_edges: int, scale: float) -> Scene:
    """A random scene for a robot of ``n_edges`` skeleton edges and reach ``scale`` metres."""
    h = rng.uniform(0, 360)
    c1 = _hsv(h, rng.uniform(0.0, 0.3), rng.uniform(0.45, 0.85))
    c2 = _hsv(h + rng.uniform(-40, 40), rng.uniform(0.0, 0.3), rng.uniform(0.2, 0.6))
    hs = rng.uniform(0, 360)
    sky_top = _hsv(hs, rng.uniform(0.0, 0.3), rng.uniform(0.5, 0.95))
    sky_bottom = _hsv(hs + rng.uniform(-60, 60), rng.uniform(0.0, 0.3), rng.uniform(0.3, 0.8))
    lx, ly = rng.uniform(-0.8, 0.8), rng.uniform(-0.9, -0.1)
    d = np.array([lx, ly, -1.0])
    light = Light(
        direction=tuple(d / np.linalg.norm(d)),
        ambient=float(rng.uniform(0.25, 0.45)),
        diffuse=float(rng.uniform(0.55, 0.8)),
        specular=float(rng.uniform(0.1, 0.35)),
        shininess=float(rng.uniform(12, 40)),
        tint=tuple(rng.uniform(0.88, 1.0, 3)),
    )
    offset = int(rng.integers(len(LINK_HUES)))
    links = (
        np.stack(
            [
                _hsv(
                    LINK_HUES[(offset + e) % len(LINK_HUES)] + rng.uniform(-8, 8),
                    rng.uniform(0.45, 0.7),
                    rng.uniform(0.7, 0.95),
                )
                for e in range(n_edges)
            ]
        )
        if n_edges
        else np.zeros((0, 3))
    )
    return Scene(
        np.stack([c1, c2]),
        float(scale * rng.uniform(0.3, 0.6)),
        int(rng.integers(2**31)),
        sky_top,
        sky_bottom,
        light,
        links,
        float(scale * rng.uniform(3.0, 6.0)),
    )


def _value_noise(seed: int, xy: np.ndarray, cell: float) -> np.ndarray:
    """Smooth noise in [0, 1] at world points ``xy`` (..., 2) metres, bilinear over a ``cell``-metre lattice."""
    rng = np.random.default_rng(seed)
    lattice = rng.uniform(0, 1, (64, 64))
    g = xy / cell
    i = np.floor(g).astype(np.int64)
    f = g - i
    f = f * f * (3 - 2 * f)
    i0, i1 = i % 64, (i + 1) % 64
    a = lattice[i0[..., 0], i0[..., 1]]
    b = lattice[i1[..., 0], i0[..., 1]]
    c = lattice[i0[..., 0], i1[..., 1]]
    d = lattice[i1[..., 0], i1[..., 1]]
    fx, fy = f[..., 0], f[..., 1]
    return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy


def background(scene: Scene, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The static part of every frame: textured floor plane z = 0 and backdrop.

    camera: a static camera (no mount link). Returns rgb (H, W, 3) in [0, 1],
    depth (H, W) metres along the optical axis (inf where no floor: the
    backdrop), and floor_xy (H, W, 2) world xy of the floor under each pixel
    (NaN off the floor), used for shadows.
    """
    K = camera.intrinsics
    H, W = K.height, K.width
    T_wc = np.linalg.inv(camera.world_to_cv())  # camera (OpenCV) → world
    R, eye = T_wc[:3, :3], T_wc[:3, 3]
    vs, us = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([(us - K.cx) / K.fx, (vs - K.cy) / K.fy, np.ones_like(us)], axis=-1)  # z = 1: t is depth
    dirs = rays @ R.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dirs[..., 2] < -1e-9, -eye[2] / dirs[..., 2], np.inf)
    hit = np.isfinite(t) & (t > 0)
    xy = eye[:2] + np.where(hit[..., None], t[..., None], 0.0) * dirs[..., :2]
    # backdrop: vertical gradient by the ray's elevation
    elev = dirs[..., 2] / np.linalg.norm(dirs, axis=-1)
    g = np.clip((elev + 0.3) / 1.0, 0.0, 1.0)[..., None]
    sky = scene.sky_bottom * (1 - g) + scene.sky_top * g
    # floor: checker tiles with faint value noise, lit by the light (floor normal is world +z); tiles of
    # 0.3-0.6 reach and noise at 1.5 tiles keep the floor low-frequency, which a small VAE can reproduce
    checker = ((np.floor(xy[..., 0] / scene.tile) + np.floor(xy[..., 1] / scene.tile)) % 2).astype(int)
    base = scene.floor_colors[checker]
    base = base * (0.9 + 0.2 * _value_noise(scene.noise_seed, xy, scene.tile * 1.5))[..., None]
    n_cam = R.T @ np.array([0.0, 0.0, 1.0])
    floor = scene.light.shade(np.broadcast_to(n_cam, (H * W, 3)), base.reshape(-1, 3)).reshape(H, W, 3)
    fog = np.clip(np.where(hit, t, np.inf) / scene.fog, 0.0, 1.0)[..., None] ** 2
    rgb = np.where(hit[..., None], floor * (1 - fog) + sky * fog, sky)
    depth = np.where(hit, t, np.inf)
    floor_xy = np.where(hit[..., None], xy, np.nan)
    return np.clip(rgb, 0, 1), depth, floor_xy


def sample_camera(
    rng: np.random.Generator,
    points: np.ndarray,
    width: int,
    height: int,
    *,
    base_xy=(0.0, 0.0),
    margin_px: float = 2.0,
    embodiment: str | None = None,
) -> Camera:
    """A static camera around the robot that sees every point in ``points`` (N, 3) metres.

    Looks at the points' bounding-box centre from a random azimuth within 110
    degrees of the robot's front (the side of the workspace away from its
    base) and an elevation of 20-60 degrees, field of view 45-65 degrees; the
    distance is the smallest of a few candidates that keeps every point at
    least ``margin_px`` inside the image. Returns an OpenCV camera-to-world
    :class:`~oscar_core.camera.pinhole.Camera` of ``width`` x ``height`` pixels.
    """
    from ..camera import project

    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = P.min(0), P.max(0)
    target = (lo + hi) / 2
    radius = max(float(np.linalg.norm(P - target, axis=1).max()), 1e-3)
    front = np.arctan2(target[1] - base_xy[1], target[0] - base_xy[0])
    fov = np.deg2rad(rng.uniform(45, 65))
    f = 0.5 * min(width, height) / np.tan(fov / 2)
    K = Intrinsics(fx=f, fy=f, cx=(width - 1) / 2, cy=(height - 1) / 2, width=width, height=height)
    for _ in range(20):
        az = front + np.deg2rad(rng.uniform(-110, 110))
        el = np.deg2rad(rng.uniform(20, 60))
        view = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        far = radius / np.sin(fov / 2) * 1.05
        for scale in (0.55, 0.65, 0.75, 0.85, 1.0, 1.2):
            eye = target + far * scale * view
            cam = Camera(K, look_at(eye, target), embodiment=embodiment)
            pr = project(P, cam)
            u, v = pr.uv[:, 0], pr.uv[:, 1]
            if (
                pr.in_front.all()
                and (pr.depth > 0.05 * radius).all()
                and (u >= margin_px).all()
                and (u <= width - 1 - margin_px).all()
                and (v >= margin_px).all()
                and (v <= height - 1 - margin_px).all()
            ):
                return cam
    raise ValueError(
        f"toyworld camera: expected a view that sees all {len(P)} points, found none in 20 tries "
        f"(workspace radius {radius:.3g} m)"
    )
