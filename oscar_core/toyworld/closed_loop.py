"""The toy world closed loop: sessions for ``oscar eval closed-loop``, and the toy simulator as a world.

:func:`write_closed_loop_sessions` plans sessions as ``oscar toyworld policy-eval`` does
(:func:`~oscar_core.toyworld.policy_eval.plan_session`, with the expert's episode alone: the ball, the start
pose, a reachable place point at least 6 ball radii away, the scene and a camera that sees them) and keeps a plan
only if at least a fifth of the ball's disc (:data:`FIRST_FRAME_BALL`) is visible in the first frame from the
session's camera (the start pose's arm can hide it; such a plan is drawn again, the next attempt of
:func:`session_rng`), then writes
per session ``first.png``, ``camera.json``, ``state.npz`` (the start pose, gripper open), ``sim.json`` (the
simulator's state: ball, radii, scene) and a closed-loop manifest naming the toy image policies
(:mod:`oscar_core.toyworld.image_policies`). The task names the place point (``... at x=… y=…``, metres in the
robot's base frame); ``extras`` give the policies the robot's name and the camera's calibration; ``info``
gives the judge (:func:`oscar_core.toyworld.judge.ball_moved`) what it needs, as in ``policy-eval``.

:class:`ToySimulator` is a world for :func:`oscar_core.evaluation.closed_loop.run_closed_loop`: it renders the
true state (the robot's commanded joints, the ball under the carry rule) with the toy world's own renderer, so
its outcome is ground truth: success = the ball was grabbed and ends at least
:data:`~oscar_core.toyworld.policy_eval.SUCCESS_RADII` ball radii (horizontally) from its start.
:func:`toy_simulator` is the factory ``run_closed_loop(simulator=...)`` takes.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..kinematics.trajectory import Trajectory
from .image_policies import policy_specs
from .motion import GRAB_RADII, Motion, carry_object, ee_points
from .policy_eval import SUCCESS_RADII, Policy, floor_homography, plan_session, session_rng

__all__ = ["ToySimulator", "toy_simulator", "write_closed_loop_sessions", "scene_to_dict", "scene_from_dict"]

TASK = "pick up the yellow ball and put it down at x={x:.4f} y={y:.4f}"


def scene_to_dict(scene) -> dict:
    """A :class:`~oscar_core.toyworld.scene.Scene` as JSON-ready lists (floats round-trip exactly)."""
    l = scene.light
    return {
        "floor_colors": np.asarray(scene.floor_colors).tolist(),
        "tile": scene.tile,
        "noise_seed": scene.noise_seed,
        "sky_top": np.asarray(scene.sky_top).tolist(),
        "sky_bottom": np.asarray(scene.sky_bottom).tolist(),
        "light": {
            "direction": list(l.direction),
            "ambient": l.ambient,
            "diffuse": l.diffuse,
            "specular": l.specular,
            "shininess": l.shininess,
            "tint": list(l.tint),
        },
        "link_colors": np.asarray(scene.link_colors).tolist(),
        "fog": scene.fog,
    }


def scene_from_dict(d: dict):
    from .raster import Light
    from .scene import Scene

    li = d["light"]
    light = Light(
        direction=tuple(li["direction"]),
        ambient=li["ambient"],
        diffuse=li["diffuse"],
        specular=li["specular"],
        shininess=li["shininess"],
        tint=tuple(li["tint"]),
    )
    return Scene(
        np.array(d["floor_colors"]),
        d["tile"],
        d["noise_seed"],
        np.array(d["sky_top"]),
        np.array(d["sky_bottom"]),
        light,
        np.array(d["link_colors"]).reshape(-1, 3),
        d["fog"],
    )


class ToySimulator:
    """The toy world's true state rendered as frames (module docstring); a world of the closed loop.

    emb, camera: the session's; first: (H, W, 3) uint8 the first frame; sim: ``sim.json``'s dict; q0 (J,),
    g0 (G,): the start state; fps; chunk_frames: L (L − 1 new frames per step); ss: supersampling.
    """

    name = "toy-simulator"

    def __init__(self, emb, camera, first, sim: dict, q0, g0, fps: float, chunk_frames: int, ss: int = 2):
        self.emb, self.camera, self.first = emb, camera, first
        self.ball, self.R, self.scale = np.array(sim["ball"], float), float(sim["radius"]), float(sim["scale"])
        self.scene = scene_from_dict(sim["scene"])
        self.fps, self.chunk, self.ss = float(fps), int(chunk_frames) - 1, ss
        self.q, self.g = np.asarray(q0, float)[None], np.asarray(g0, float)[None]
        self._state()

    def _state(self):
        traj = Trajectory(
            self.emb.joint_names, self.q, self.fps, self.g, self.emb.gripper_names or None, source="<toy simulator>"
        )
        points, ee = ee_points(self.emb, traj)
        openness = self.emb.gripper_openness(self.g)
        obj, attached = carry_object(ee, openness[:, 0], self.ball, self.R, grab_distance=GRAB_RADII * self.R)
        return traj, points, ee, obj, attached

    def step(self, q: np.ndarray, gripper: np.ndarray) -> np.ndarray:
        """(n, H, W, 3) uint8 frames of the true state after joint positions ``q`` (n, J), gripper (n, G)."""
        from .episode import render_world

        n = len(q)
        self.q, self.g = np.concatenate([self.q, q]), np.concatenate([self.g, gripper])
        traj, points, ee, obj, attached = self._state()
        motion = Motion(
            traj.time_slice(-n), "pick_place", points[-n:], ee[-n:], obj[-n:], attached[-n:], self.R, self.scale
        )
        return render_world(self.emb, motion, self.scene, self.camera, ss=self.ss).rgb

    def outcome(self) -> dict:
        """``success`` (0/1), ``grabbed``, ``displacement_radii``: the ground truth of the episode so far."""
        _, _, _, obj, attached = self._state()
        disp = float(np.linalg.norm(obj[-1, :2] - self.ball[:2]) / self.R)
        grabbed = bool(attached.any())
        return {
            "success": int(grabbed and disp >= SUCCESS_RADII),
            "grabbed": grabbed,
            "displacement_radii": round(disp, 4),
        }


def toy_simulator(session, emb, camera, first, size, fps, chunk_frames):
    """The factory ``run_closed_loop(simulator=...)`` takes: a :class:`ToySimulator` for ``session``."""
    from ..kinematics.trajectory import load_trajectory

    if session.simulator is None:
        raise ValueError(
            f"session {session.session!r}: field 'simulator': expected the toy world's sim.json, found none"
        )
    if (camera.intrinsics.width, camera.intrinsics.height) != tuple(size):
        raise ValueError(
            f"session {session.session!r}: the toy simulator renders at the camera's size "
            f"{camera.intrinsics.width}x{camera.intrinsics.height}, found rollout size {size}"
        )
    state = load_trajectory(session.initial_state)
    sim = json.loads(Path(session.simulator).read_text())
    return ToySimulator(emb, camera, first, sim, state.q[0], state.gripper[0], fps, chunk_frames)


toy_simulator.identity = "oscar_core.toyworld.closed_loop:toy_simulator v1"


#: Plans drawn per session before giving up (each from its own generator, :func:`session_rng`'s ``attempt``).
ATTEMPTS = 20
#: The fraction of the ball's disc that must be visible in the first frame (the arm may hide the rest). A fifth:
#: the least visible ball of the 30 sessions of seed 0 the closed-loop study used (docs/closed-loop.md) shows 0.26
#: of its disc, so those sessions are unchanged, while the arm's hiding all but 0.08 and 0.00 of it (franka-0008
#: and kuka-0004 of seed 1) is redrawn.
FIRST_FRAME_BALL = 0.2


def _first_frame(emb, s, fps: float, sid: str):
    """The start state (a one-frame :class:`Trajectory`) of the expert's plan in session ``s``, and the first
    frame rendered from the session's camera (:class:`~oscar_core.toyworld.episode.RenderResult`)."""
    from .episode import render_world

    ep = s.episodes[0]
    traj = ep.motion.trajectory
    start = Trajectory(traj.joint_names, traj.q[:1], fps, traj.gripper[:1], traj.gripper_names, source=f"<{sid} start>")
    motion = Motion(
        start, "pick_place", ep.motion.points[:1], ep.motion.ee[:1], np.array([s.ball]), np.zeros(1, bool), s.radius,
        s.scale,
    )  # fmt: skip
    return start, render_world(emb, motion, s.scene, s.camera, ss=2)


def write_closed_loop_sessions(
    out,
    embodiments,
    sessions: int,
    *,
    seed: int = 0,
    width: int = 64,
    height: int = 64,
    horizon: int = 49,
    fps: float = 10.0,
    policies=None,
    registry=None,
) -> Path:
    """Write ``sessions`` toy sessions per embodiment and ``out/manifest.json`` (module docstring); returns the
    manifest's path. Session ``i`` of embodiment ``e`` depends only on (seed, e, i): its first plan (attempt 0,
    1, ... of :func:`session_rng`) that the expert carries out and whose first frame shows at least
    :data:`FIRST_FRAME_BALL` of the ball's disc from the session's camera."""
    from .._util.atomic import atomic_write_bytes
    from ..camera import save_camera
    from ..kinematics.trajectory import save_trajectory
    from ..plugin.registry import Registry
    from .policy_eval import _png_bytes, _radius_px

    registry = registry or Registry()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    expert = Policy("expert", 0.0)
    for name in embodiments:
        emb = registry.get(name)
        for i in range(sessions):
            sid = f"{emb.name}-{i:04d}"
            for attempt in range(ATTEMPTS):
                try:
                    s = plan_session(emb, session_rng(seed, emb.name, i, attempt), width, height, 17, fps, (expert,))
                except ValueError:
                    continue
                if not s.episodes[0].success:
                    continue
                start, render = _first_frame(emb, s, fps, sid)
                if render.object_area[0] >= FIRST_FRAME_BALL * np.pi * _radius_px(s) ** 2:
                    break  # the ball is in view of the session's camera at the first frame
            else:
                raise ValueError(
                    f"toyworld closed-loop: {emb.name} session {i}: no plan with the ball in view in {ATTEMPTS} attempts"
                )
            ep = s.episodes[0]
            folder = out / sid
            folder.mkdir(exist_ok=True)
            save_trajectory(start, folder / "state.npz")
            save_camera(s.camera, folder / "camera.json")
            atomic_write_bytes(folder / "first.png", _png_bytes(render.rgb[0]))
            sim = {"ball": s.ball.tolist(), "radius": s.radius, "scale": s.scale, "scene": scene_to_dict(s.scene)}
            atomic_write_bytes(folder / "sim.json", json.dumps(sim).encode())
            place = ep.motion.object[-1]  # where the expert's plan put the ball: reachable and in view
            K = s.camera.intrinsics
            rows.append(
                {
                    "session": sid,
                    "embodiment": emb.name,
                    "task": TASK.format(x=place[0], y=place[1]),
                    "first_frame": f"{sid}/first.png",
                    "camera": f"{sid}/camera.json",
                    "initial_state": f"{sid}/state.npz",
                    "simulator": f"{sid}/sim.json",
                    "extras": {
                        "toy/embodiment": emb.name,
                        "toy/intrinsics": [K.fx, K.fy, K.cx, K.cy],
                        "toy/world_to_cv": s.camera.world_to_cv().tolist(),
                    },
                    "info": {
                        "ball_start_px": [round(float(v), 3) for v in render.object_px[0]],
                        "ball_radius_px": round(_radius_px(s), 3),
                        "px_to_floor_radii": floor_homography(s.camera, s.radius, s.radius).tolist(),
                        "success_radii": SUCCESS_RADII,
                    },
                }
            )
    manifest = {
        "format": "oscar-closed-loop-manifest",
        "description": f"toy-world closed loop, {sessions} sessions x {list(embodiments)}, seed {seed}",
        "policies": policy_specs(policies),
        "defaults": {"size": f"{width}x{height}", "horizon": horizon},
        "sessions": rows,
    }
    path = out / "manifest.json"
    atomic_write_bytes(path, (json.dumps(manifest, indent=1) + "\n").encode())
    return path
