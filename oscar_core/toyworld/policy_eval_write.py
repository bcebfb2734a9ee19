"""``oscar toyworld policy-eval``'s files: per session a first frame, each scripted policy's trajectory and the
ground truth a judge needs, and the ``oscar eval run`` manifest over them (:func:`write_policy_eval`). The sessions
and policies are planned by :mod:`.policy_eval`; a session whose outcome a camera cannot see is drawn again.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .._util.log import get_logger
from .motion import GRAB_RADII, ToyWorldError
from .policy_eval import (
    POLICIES,
    SUCCESS_RADII,
    TASK,
    Session,
    _png_bytes,
    _radius_px,
    floor_homography,
    plan_session,
    policy_eval_refusal,
    session_rng,
)

__all__ = ["MAX_ATTEMPTS", "write_policy_eval"]

_log = get_logger(__name__)

#: Draws of one session before it is refused (its outcome hidden from every camera each time).
MAX_ATTEMPTS = 20


def _outcome_visible(s: Session, renders) -> bool:
    """Whether every episode shows at least half the ball at frame 0 and in its last frame (the arm or the robot's
    base can hide where the ball was put down; such a session cannot be judged from the video)."""
    full = np.pi * _radius_px(s) ** 2
    return all(r.object_area[0] >= 0.5 * full and r.object_area[-1] >= 0.5 * full for r in renders)


def _visible_session(emb, i: int, seed: int, width: int, height: int, frames: int, fps: float, policies, supersample):
    """``(session, renders, attempt)``: session ``i`` of ``emb`` planned from (seed, embodiment, i, attempt) with its
    episodes rendered, at the first attempt whose camera sees the ball at the start and the end of every episode
    (:data:`MAX_ATTEMPTS` at most, else :class:`ToyWorldError`)."""
    from .episode import render_world

    names = [p.name for p in policies]
    for attempt in range(MAX_ATTEMPTS):
        try:
            s = plan_session(
                emb,
                session_rng(seed, emb.name, i, attempt),
                width,
                height,
                frames,
                fps,
                policies,
                {n: session_rng(seed, emb.name, i, attempt, n) for n in names},
            )
        except ValueError as exc:  # no camera sees it all: draw the session again
            if isinstance(exc, ToyWorldError) or attempt == MAX_ATTEMPTS - 1:
                raise
            continue
        renders = [render_world(emb, ep.motion, s.scene, s.camera, ss=supersample) for ep in s.episodes]
        if _outcome_visible(s, renders):
            break
        if attempt == MAX_ATTEMPTS - 1:
            raise ToyWorldError(
                f"toyworld policy-eval: {emb.name} session {i}: expected a camera that sees "
                f"the ball at the start and the end of every episode, found none in "
                f"{MAX_ATTEMPTS} attempts"
            )
    return s, renders, attempt


def _write_session(out: Path, name: str, emb, s, renders, attempt: int, fps: float) -> tuple[list[dict], list[dict]]:
    """Writes session ``name``'s folder under ``out`` (first.png, camera.json, per policy its trajectory and real
    video). Returns ``(cells, rows)``: its manifest cells (what the world model is given, nothing about the
    outcome) and its summary rows (the true outcome; errors in ball radii)."""
    from .._util.atomic import atomic_write_bytes
    from ..camera import save_camera
    from ..kinematics.trajectory import save_trajectory
    from ..media.video import write_video

    folder = out / name
    folder.mkdir(exist_ok=True)
    save_camera(s.camera, folder / "camera.json")
    R = s.radius
    Hm = floor_homography(s.camera, R, R)
    first = renders[0].rgb[0]
    start_px = renders[0].object_px[0]
    r_px = _radius_px(s)
    atomic_write_bytes(folder / "first.png", _png_bytes(first))
    cells, rows = [], []
    for ep, render in zip(s.episodes, renders):
        if not np.array_equal(first, render.rgb[0]):
            raise AssertionError(f"{name}: policy {ep.policy.name!r} starts from a different first frame")
        save_trajectory(ep.motion.trajectory, folder / f"{ep.policy.name}.npz")
        write_video(folder / f"{ep.policy.name}_real.mkv", render.rgb, fps)
        info = {
            "ball_start_px": [round(float(v), 3) for v in start_px],
            "ball_radius_px": round(r_px, 3),
            "px_to_floor_radii": [[float(v) for v in row] for row in Hm],
            "success_radii": SUCCESS_RADII,
        }  # nothing about the outcome or the policy
        cells.append(
            {
                "session": name,
                "policy": ep.policy.name,
                "embodiment": emb.name,
                "first_frame": f"{name}/first.png",
                "trajectory": f"{name}/{ep.policy.name}.npz",
                "camera": f"{name}/camera.json",
                "real_success": ep.success,
                "real_video": f"{name}/{ep.policy.name}_real.mkv",
                "info": info,
            }
        )
        rows.append(
            {
                "session": name,
                "embodiment": emb.name,
                "policy": ep.policy.name,
                "attempt": attempt,
                "real_success": ep.success,
                "grabbed": ep.grabbed,
                "displacement_radii": round(ep.displacement, 3),
                "aim_error_radii": [round(float(v), 3) for v in ep.aim_error],
                "grasp_error_radii": [round(float(v), 3) for v in ep.grasp_error],
            }
        )
    return cells, rows


def _policy_eval_summary(rows, policies, embs, seed: int, sessions: int, frames: int, width: int, height: int) -> dict:
    """``policy_eval.json``: the settings, every row, and per policy its aim noise (ball radii) and true success
    rate, overall and per embodiment."""
    summary = {
        "seed": seed,
        "sessions": sessions,
        "embodiments": [e.name for e in embs],
        "frames": frames,
        "size": [width, height],
        "success_radii": SUCCESS_RADII,
        "grab_radii": GRAB_RADII,
        "policies": {p.name: {"aim_sigma_radii": p.aim_sigma} for p in policies},
        "rows": rows,
    }
    for p in [p.name for p in policies]:
        mine = [r for r in rows if r["policy"] == p]
        summary["policies"][p]["success_rate"] = float(np.mean([r["real_success"] for r in mine]))
        summary["policies"][p]["by_embodiment"] = {
            e.name: float(np.mean([r["real_success"] for r in mine if r["embodiment"] == e.name])) for e in embs
        }
    return summary


def write_policy_eval(
    out,
    embodiments,
    sessions: int,
    *,
    seed: int = 0,
    width: int = 64,
    height: int = 64,
    frames: int = 17,
    fps: float = 10.0,
    supersample: int = 2,
    policies=POLICIES,
    registry=None,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """Write ``sessions`` sessions per embodiment and ``out``/manifest.json; returns the summary also written
    to ``out``/policy_eval.json (true success rate per policy, per embodiment and overall).

    Layout: ``out/<embodiment>-<i>/first.png``, ``camera.json``, ``<policy>.npz``, ``<policy>_real.mkv``.
    Session ``i`` of embodiment ``e`` depends only on (seed, e, i); a session whose plan fails (no camera sees
    it all) is re-drawn with the next attempt number (recorded in the summary).
    """
    from .._util.atomic import atomic_write_bytes
    from ..plugin.registry import Registry

    if sessions < 1:
        raise ValueError(f"toyworld policy-eval: --sessions: expected at least 1, found {sessions}")
    if width % 16 or height % 16 or width <= 0 or height <= 0:
        raise ValueError(
            f"toyworld policy-eval: --size: expected WIDTHxHEIGHT, both multiples of 16 (the rollout "
            f"size of oscar eval run), found {width}x{height}"
        )
    names = [p.name for p in policies]
    if len(set(names)) != len(names) or not names:
        raise ValueError(f"toyworld policy-eval: policies: expected unique names, found {names}")
    registry = registry or Registry()
    embs = [registry.get(n) for n in embodiments]
    for e in embs:  # every body is checked before anything is written
        why = policy_eval_refusal(e)
        if why is not None:
            raise ToyWorldError(f"toyworld policy-eval: {why}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cells, rows = [], []
    for emb in embs:
        for i in range(sessions):
            s, renders, attempt = _visible_session(emb, i, seed, width, height, frames, fps, policies, supersample)
            name = f"{emb.name}-{i:04d}"
            session_cells, session_rows = _write_session(out, name, emb, s, renders, attempt, fps)
            cells += session_cells
            rows += session_rows
            (progress or _log.info)(f"{name}: " + ", ".join(f"{ep.policy.name} {ep.success}" for ep in s.episodes))
    manifest = {
        "format": "oscar-eval-manifest",
        "policies": names,
        "description": (
            f"toy-world pick-and-place, {sessions} sessions x {len(embs)} embodiments "
            f"({','.join(e.name for e in embs)}), seed {seed}; oscar toyworld policy-eval"
        ),
        "defaults": {"size": f"{width}x{height}", "task": TASK},
        "cells": cells,
    }
    atomic_write_bytes(out / "manifest.json", (json.dumps(manifest, indent=1) + "\n").encode())
    summary = _policy_eval_summary(rows, policies, embs, seed, sessions, frames, width, height)
    atomic_write_bytes(out / "policy_eval.json", (json.dumps(summary, indent=1) + "\n").encode())
    return summary
