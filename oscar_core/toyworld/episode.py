"""One toy-world episode: motion + scene + camera → RGB frames and the ground truth the evaluator needs.

The RGB renderer uses the same forward kinematics (``Embodiment.frames``) and
projection (:func:`oscar_core.camera.projection.project`) as the skeleton renderer: every
skeleton edge is a shaded capsule between the same projected points, so the
skeleton video is an exact abstraction of the RGB video.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera, project
from ..kinematics.trajectory import Trajectory
from ..plugin.embodiment import Embodiment
from ..render.capsules import link_radii  # the capsule body's radii: the mesh condition of this world
from .motion import Motion, check_supported, is_hand, sample_motion
from .raster import Canvas
from .scene import EE_RGB, OBJECT_RGB, Scene, background, sample_camera, sample_scene

__all__ = [
    "Episode",
    "RenderResult",
    "render_world",
    "plan_episode",
    "make_episode",
    "episode_rng",
    "miss_rng",
    "link_radii",
]


@dataclass
class RenderResult:
    """Rendered frames and what is where.

    rgb: (T, H, W, 3) uint8; label: (T, H·ss, W·ss) int32 at the supersampled
    render size (-1 background, e in [0, E) edge e, E object, E + 1
    end-effector marker); ss: supersampling factor; object_px, ee_px: (T, 2)
    projected centres in output pixels; object_area, ee_area: (T,) visible
    area in output pixels² (0 = hidden).
    """

    rgb: np.ndarray
    label: np.ndarray
    ss: int
    object_px: np.ndarray
    ee_px: np.ndarray
    object_area: np.ndarray
    ee_area: np.ndarray


def render_world(
    emb: Embodiment,
    motion: Motion,
    scene: Scene,
    camera: Camera,
    ss: int = 2,
    draw_robot: bool = True,
    full_frame: bool = False,
) -> RenderResult:
    """Render ``motion`` seen by a static ``camera`` (output size = the camera's image size).

    ss: supersampling factor (the frame is drawn at ss× the size and area-averaged
    down: anti-aliasing). draw_robot=False draws the scene without the robot
    (tests use it to find which pixels the robot changed). full_frame: draw each
    primitive over the whole image (the naive way, for benchmarks; same pixels).
    """
    import cv2

    if camera.mount_link is not None:
        raise ValueError(
            f"toyworld render: expected a static camera (mount: null), found one mounted on {camera.mount_link!r}"
        )
    W, H = camera.intrinsics.width, camera.intrinsics.height
    cam = camera.resized(W * ss, H * ss, mode="stretch") if ss != 1 else camera
    f = cam.intrinsics.fx
    bg, bg_depth, floor_xy = background(scene, cam)
    T = len(motion.points)
    edges = emb.edge_index()
    E = len(edges)
    pts = project(motion.points, cam)
    obj = project(motion.object, cam)
    ee = project(motion.ee, cam)
    radii = link_radii(E, motion.scale) if motion.link_radii is None else motion.link_radii
    R = motion.object_radius
    marker_r = 0.6 * R
    light = scene.light
    rgb = np.empty((T, H, W, 3), dtype=np.uint8)
    labels = np.empty((T, H * ss, W * ss), dtype=np.int32)
    obj_area, ee_area = np.zeros(T), np.zeros(T)
    on_floor = np.isfinite(floor_xy[..., 0])
    for t in range(T):
        # soft shadow of the ball on the floor, fading as it is lifted
        o = motion.object[t]
        d2 = np.where(on_floor, ((floor_xy - o[:2]) ** 2).sum(-1), np.inf)
        sigma = 1.3 * R + 0.5 * max(o[2] - R, 0.0)
        strength = 0.55 * np.exp(-max(o[2] - R, 0.0) / (4 * R))
        shade = 1.0 - strength * np.exp(-d2 / (2 * sigma * sigma))
        canvas = Canvas(bg * shade[..., None], bg_depth, full_frame=full_frame)
        if draw_robot:
            for e, (a, b) in enumerate(edges):
                za, zb = pts.depth[t, a], pts.depth[t, b]
                if not (za > 1e-3 and zb > 1e-3):  # behind the camera, or NaN: a hand that is absent
                    continue
                canvas.capsule(pts.uv[t, a], pts.uv[t, b], za, zb, radii[e], f, scene.link_colors[e], light, e)
            if motion.marker and len(emb.grippers) and ee.depth[t] > 1e-3:
                canvas.sphere(ee.uv[t], ee.depth[t], marker_r, f, EE_RGB, light, E + 1)
        if obj.depth[t] > 1e-3:
            canvas.sphere(obj.uv[t], obj.depth[t], R, f, OBJECT_RGB, light, E)
        img = canvas.rgb
        if ss != 1:
            img = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)
        rgb[t] = np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)
        labels[t] = canvas.label
        obj_area[t] = (canvas.label == E).sum() / ss**2
        ee_area[t] = (canvas.label == E + 1).sum() / ss**2

    def to_out(uv):  # supersampled pixel centres → output pixel centres
        return (uv + 0.5) / ss - 0.5

    return RenderResult(rgb, labels, ss, to_out(obj.uv), to_out(ee.uv), obj_area, ee_area)


@dataclass
class Episode:
    """A generated episode: inputs (trajectory, camera), frames and ground truth.

    rgb: (T, H, W, 3) uint8; motion: the :class:`Motion`; scene: the
    :class:`Scene`; render: the :class:`RenderResult`.
    """

    embodiment: str
    trajectory: Trajectory
    camera: Camera
    rgb: np.ndarray
    motion: Motion
    scene: Scene
    render: RenderResult
    meta: dict = field(default_factory=dict)

    def ground_truth(self, miss_fields: bool = False, open_field: bool = False, timing_field: bool = False) -> dict:
        """JSON-ready ground truth (the ``meta.toyworld`` of a clip record; docs/formats.md).

        miss_fields: also write ``missed`` (a pick_place episode whose ball lay out of reach) and ``grabbed``
        (the ball attached on some frame); open_field: also ``never_closed`` (one whose gripper stayed open) and
        ``grabbed``; timing_field: also ``mistimed`` ("early" / "late" / None: a close moved off the ball) and
        ``grabbed``. The generator writes them for sets made with ``pick_miss`` (``pick_open``, ``pick_timing``) > 0
        only, so the records of a set made without the option stay byte-identical to those written before it existed.
        """
        r, m = self.render, self.motion

        def rows(a):
            return [[round(float(x), 3) for x in row] for row in a]

        extra = {"missed": bool(m.missed)} if miss_fields else {}
        if open_field:
            extra["never_closed"] = bool(m.never_closed)
        if timing_field:
            extra["mistimed"] = m.mistimed
        if miss_fields or open_field or timing_field:
            extra["grabbed"] = bool(np.any(m.attached))
        return {
            "kind": m.kind,
            "ee_px": rows(r.ee_px),
            "ee_area": [round(float(a), 2) for a in r.ee_area],
            "object_px": rows(r.object_px),
            "object_area": [round(float(a), 2) for a in r.object_area],
            "attached": [bool(a) for a in m.attached],
            "object_radius_m": round(m.object_radius, 5),
            "reach_m": round(m.scale, 5),
            **extra,
        }


def _episode_generator(seed: int, embodiment: str, index: int, *tag: int) -> np.random.Generator:
    """A generator seeded by (seed, crc32 of the embodiment's name, episode index, *tag)."""
    import zlib

    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(embodiment.encode()), int(index), *tag]))


def episode_rng(seed: int, embodiment: str, index: int) -> np.random.Generator:
    """The generator of episode ``index`` of ``embodiment`` under ``seed``: independent of every other
    episode, so any subset (a shard) is regenerated identically."""
    return _episode_generator(seed, embodiment, index)


#: The last seed word of :func:`miss_rng` ("miss" in ASCII): its stream is unrelated to :func:`episode_rng`'s.
_MISS_TAG = 0x6D697373


def miss_rng(seed: int, embodiment: str, index: int) -> np.random.Generator:
    """The generator of episode ``index``'s missed pick (:func:`~oscar_core.toyworld.motion.sample_motion`'s
    ``miss_rng``): separate from :func:`episode_rng`, so the miss fraction changes no other draw."""
    return _episode_generator(seed, embodiment, index, _MISS_TAG)


def plan_episode(
    emb: Embodiment,
    rng: np.random.Generator,
    width: int,
    height: int,
    frames: int,
    fps: float = 10.0,
    pick_miss: float = 0.0,
    miss_rng: np.random.Generator | None = None,
    pick_open: float = 0.0,
    push: bool = False,
    pick_timing: float = 0.0,
) -> tuple[Motion, Scene, Camera]:
    """Sample the motion, the scene and a camera that sees it all (``width`` x ``height`` pixels); a hand
    embodiment (:func:`~oscar_core.toyworld.motion.is_hand`) gets a hand motion and skin-coloured capsules.

    pick_miss, miss_rng, pick_open, push, pick_timing: as in :func:`~oscar_core.toyworld.motion.sample_motion` (a missed pick's
    ball is among the points the camera must see, like every ball; a hand has its own push and ignores ``push``)."""
    from .hand import sample_hand_motion, sample_hand_scene

    if is_hand(emb):  # a keypoint hand (docs/toyworld.md, "Hands"): no missed picks; the arm's shoulder at 0
        motion = sample_hand_motion(emb, rng, frames, fps)
        scene = sample_hand_scene(rng, len(emb.edges), motion.scale)
        base_xy = np.zeros(2)
    else:
        check_supported(emb)
        motion = sample_motion(
            emb,
            rng,
            frames,
            fps,
            pick_miss=pick_miss,
            miss_rng=miss_rng,
            pick_open=pick_open,
            push=push,
            pick_timing=pick_timing,
        )
        scene = sample_scene(rng, len(emb.edges), motion.scale)
        base_xy = motion.points[0, 0, :2]
    R = motion.object_radius
    # everything that must be in view: skeleton points, the ball (its top and bottom), its resting place
    pts = motion.points.reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(1)]  # an absent hand's points are NaN
    seen = np.concatenate([pts, motion.object + [0, 0, R], motion.object - [0, 0, R]])
    camera = sample_camera(rng, seen, width, height, base_xy=base_xy, embodiment=emb.name)
    return motion, scene, camera


def make_episode(
    emb: Embodiment,
    rng: np.random.Generator,
    width: int,
    height: int,
    frames: int,
    fps: float = 10.0,
    ss: int = 2,
    pick_miss: float = 0.0,
    miss_rng: np.random.Generator | None = None,
    pick_open: float = 0.0,
    push: bool = False,
    pick_timing: float = 0.0,
) -> Episode:
    """Sample motion, scene and camera, and render one episode of ``frames`` frames at ``width`` x ``height``
    (``pick_miss``, ``miss_rng``, ``pick_open``, ``push``, ``pick_timing``: :func:`plan_episode`)."""
    motion, scene, camera = plan_episode(
        emb, rng, width, height, frames, fps, pick_miss, miss_rng, pick_open, push, pick_timing=pick_timing
    )
    render = render_world(emb, motion, scene, camera, ss=ss)
    return Episode(emb.name, motion.trajectory, camera, render.rgb, motion, scene, render)
