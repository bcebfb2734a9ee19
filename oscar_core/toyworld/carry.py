"""Where the generated ball goes: the toy policy evaluation's per-cell judge internals against the real episode.

``oscar toyworld carry MANIFEST EVAL_OUT`` reads a manifest of ``oscar toyworld
policy-eval`` (its ``policy_eval.json`` beside it: whether the real gripper
grabbed the ball) and the rollouts of ``oscar eval run`` into ``EVAL_OUT``
(any model), and reads every generated video with
:func:`~oscar_core.toyworld.judge.ball_reading`. Per cell: the real outcome
and grab, the judge's verdict, whether the generated ball left its start,
the compact blob's median distance from the start, and where that blob lies
(floor ball radii) against the real place position (the ball's end in the
session's successful real episodes) and the real end-effector's end (every
policy of a session ends at the same pose). Per policy: success rates, and
how often the generated ball left its start when the real gripper grabbed
it and when it did not — a world model that cannot tell a grasp from a near
miss moves the ball in both.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .judge import _to_floor, ball_moved, ball_reading
from .locate import EE_TARGET, OBJECT_TARGET, locate

__all__ = ["carry_rows", "carry_summary", "carry_table"]


def _mean(xs) -> float | None:
    xs = [float(x) for x in xs if x is not None]
    return float(np.mean(xs)) if xs else None


def carry_rows(manifest, eval_out) -> list[dict]:
    """One row per manifest cell (module docstring); floor distances in ball radii, None where not found."""
    from ..evaluation.loop import video_path
    from ..evaluation.manifest import load_manifest
    from ..media.video import read_video

    m = load_manifest(manifest)
    pe = Path(manifest).parent / "policy_eval.json"
    if not pe.is_file():
        raise FileNotFoundError(
            f"{pe}: expected the policy_eval.json of oscar toyworld policy-eval beside the "
            f"manifest (it says whether the real gripper grabbed the ball), found no such file"
        )
    grabbed = {(r["session"], r["policy"]): bool(r["grabbed"]) for r in json.loads(pe.read_text())["rows"]}
    missing = [c.id for c in m.cells if not video_path(Path(eval_out), c).is_file()]
    if missing:  # before any video is read
        raise FileNotFoundError(
            f"{eval_out}: expected the rollout of every cell written by oscar eval run, found "
            f"{len(missing)} of {len(m.cells)} missing (first: {missing[0]})"
        )
    place, ee_end = {}, {}
    for c in m.cells:  # the session's real place position and the end-effector's end pose, pixels
        real = read_video(c.real_video)
        if c.real_success and c.session not in place:
            place[c.session] = locate(real[-1:], OBJECT_TARGET)[0][0]
        ee_end.setdefault(c.session, locate(real[-1:], EE_TARGET)[0][0])
    rows = []
    for c in m.cells:
        video = read_video(video_path(Path(eval_out), c))
        H = np.asarray(c.info["px_to_floor_radii"], dtype=np.float64)
        r = ball_reading(video, c.info)
        v = ball_moved(video, SimpleNamespace(info=c.info))
        blob = next((b for b in reversed(r.get("blob") or []) if b and b["compact"]), None)

        def dist(p, blob=blob, H=H):
            if blob is None or p is None or not np.isfinite(p).all():
                return None
            return round(float(np.linalg.norm(_to_floor(H, np.asarray(blob["px"])) - _to_floor(H, p))), 3)

        rows.append(
            {
                "cell": c.id,
                "session": c.session,
                "policy": c.policy,
                "real_success": c.real_success,
                "real_grabbed": grabbed.get((c.session, c.policy)),
                "wm_success": v["binary"],
                "wm_left_start": r.get("left"),
                "wm_distance": r.get("distance"),
                "blob_to_place": dist(place.get(c.session)),
                "blob_to_ee_end": dist(ee_end.get(c.session)),
                "at_start": r.get("at_start"),
                "n0": r.get("n0"),
                "reason": v["reason"],
            }
        )
    return rows


def carry_summary(rows: list[dict], policies) -> dict:
    """Per policy: ``cells``, ``real_sr``, ``wm_sr``, ``grabbed`` (cells), ``left_if_grabbed`` /
    ``left_if_missed`` (fraction of cells whose generated ball left its start), ``success_if_grabbed`` /
    ``success_if_missed``, ``blob_to_place`` / ``blob_to_ee_end`` (median ball radii over cells with a compact
    blob in the last frame)."""
    out = {}
    for p in policies:
        mine = [r for r in rows if r["policy"] == p]
        g = [r for r in mine if r["real_grabbed"]]
        n = [r for r in mine if r["real_grabbed"] is False]

        def med(k, mine=mine):
            xs = [r[k] for r in mine if r[k] is not None]
            return float(np.median(xs)) if xs else None

        out[p] = {
            "cells": len(mine),
            "real_sr": _mean(r["real_success"] for r in mine),
            "wm_sr": _mean(r["wm_success"] for r in mine),
            "grabbed": len(g),
            "left_if_grabbed": _mean(r["wm_left_start"] for r in g),
            "left_if_missed": _mean(r["wm_left_start"] for r in n),
            "success_if_grabbed": _mean(r["wm_success"] for r in g),
            "success_if_missed": _mean(r["wm_success"] for r in n),
            "blob_to_place": med("blob_to_place"),
            "blob_to_ee_end": med("blob_to_ee_end"),
        }
    return out


def carry_table(manifest, eval_out) -> dict:
    """``{"summary": {policy: carry_summary row}, "rows": carry_rows(...)}`` of a policy-eval ``manifest`` and the
    ``oscar eval run`` folder ``eval_out`` (what ``oscar toyworld carry`` prints and writes)."""
    from ..evaluation.manifest import load_manifest

    rows = carry_rows(manifest, eval_out)
    return {"summary": carry_summary(rows, load_manifest(manifest).policies), "rows": rows}
