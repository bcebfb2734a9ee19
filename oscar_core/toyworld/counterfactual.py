"""Counterfactual sets of the toy world for the action-following benchmark (``oscar toyworld action-following``).

A set is one scene, one first frame and one pick-and-place path, planned as the closed-loop sessions are
(:func:`~oscar_core.toyworld.policy_eval.plan_session` with an exact grasp: the ball, the start pose, a place at least
6 ball radii away, minimum-jerk segments through joint keyframes, the carry rule of
:func:`~oscar_core.toyworld.motion.carry_object`), and :data:`VARIANTS` of it, each changing one decision through the
transforms of :mod:`oscar_core.evaluation.variant_transforms` (so a toy set is a manifest of the same format a user
writes for their own robot):

- ``close_at_ball``: the path as planned; the gripper closes at the ball (the base, no transform);
- ``stay_open``: the gripper never closes;
- ``close_early``: it closes :func:`margin` frames before the end-effector first comes within the grab distance
  (2.2 ball radii) and stays closed through the grasp;
- ``close_late``: it stays open through the grasp and closes :func:`margin` frames after the end-effector has
  left the grab distance;
- ``miss_<k>R`` (k in :data:`MISS_RADII`): the end-effector's path shifted horizontally so that at the closing frame
  it is k ball radii (horizontally) from the ball's centre, at full shift for :func:`margin` frames on each side of
  the closing frame and blended in from frame 1 and out over as many frames after.

The toy simulator gives each variant's truth: the carry rule on the variant's end-effector path and gripper
(outcome 1 when the ball was grabbed and ends at least :data:`~oscar_core.toyworld.policy_eval.SUCCESS_RADII` radii
from its start) and its frames (the toy renderer). As designed — the grasp end-effector 1.4–2.6 radii above the
floor — the outcomes are 1, 0, 0, 0, 1, 0 (a 1-radius miss is within the grab distance, a 3-radius one is not);
the generator records the simulator's, whatever they are. The camera is chosen after the variants, seeing every
variant's skeleton and ball. A set is re-drawn (another attempt) when the plan's own grasp misses, an arm cannot
follow a shift, a shifted arm goes under the floor, no camera sees it all, or the judge
(:func:`~oscar_core.toyworld.judge.ball_moved`) on the simulator's frames disagrees with the simulator on any
variant: the benchmark then measures the model, not the judge.

**Pushing** (``push=True``, ``--push``; off by default, so a set made without it is the set made before the option
existed, bit for bit): the simulator of every variant of the set runs with the push rule of
:func:`~oscar_core.toyworld.motion.carry_object` (an open gripper that holds nothing shoves the ball along the floor
to :data:`~oscar_core.toyworld.motion.PUSH_CONTACT_RADII` = 1.6 radii from the end-effector: the ball's radius plus
the end-effector's) and the set has a seventh variant:

- ``open_push``: the gripper never closes (as ``stay_open``) and the end-effector's path goes through the ball
  horizontally at the grasp height: shifted (as a miss, blended in from frame 1) to :data:`PUSH_BEHIND_RADII`
  behind the ball's centre along a horizontal direction ``u`` (the plan's own approach direction first, then 45°
  turns) :func:`margin` frames before the closing frame, swept along ``u`` to :data:`PUSH_BEYOND_RADII` beyond it
  by the closing frame (while the plan holds the grasp pose), and blended back into the plan (transforms:
  :func:`push_transforms`). Its truth is a ball pushed, not carried: never grabbed, ending at least
  :data:`PUSH_MIN_RADII` radii from its start (a direction where the simulator says otherwise is not taken).

With pushing, the outcome is what the judge measures: 1 when the ball ends at least
:data:`~oscar_core.toyworld.policy_eval.SUCCESS_RADII` radii from its start, carried or pushed there (without
pushing a ball that is not grabbed never moves, so it is the same outcome); the truth adds ``pushed`` (the ball
moved on a frame where it was not held) beside ``grabbed``, so a push is told from a carry. The other variants keep
their designed outcomes: an open gripper that comes down on the ball from above nudges it aside, to the contact
distance from the grasp end-effector (``stay_open``, ``close_late``: about 1.25 radii with the end-effector 1
radius above the ball's centre; ``close_at_ball`` and ``miss_1R`` still grab it within 2.2), closed fingers push
nothing (``close_early``), so as designed the outcomes are 1, 0, 0, 0, 1, 0, 1 (the generator records the
simulator's, whatever they are).

:func:`write_counterfactual_sets` writes the sets and ``manifest.json`` (format ``oscar-action-following``);
set i of embodiment e depends only on (seed, e, i), each set is written whole (atomically) and kept on a re-run.
"""

from __future__ import annotations

import dataclasses
import json
import zlib
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .._util.log import get_logger
from ..evaluation.variant_transforms import VariantError, apply_transforms
from .motion import (
    GRAB_RADII,
    PUSH_CONTACT_RADII,
    Motion,
    ToyWorldError,
    carry_object,
    decision_margin,
    ee_points,
    grab_window,
)

__all__ = [
    "VARIANTS",
    "PUSH_VARIANT",
    "PUSH_BEHIND_RADII",
    "PUSH_BEYOND_RADII",
    "PUSH_MIN_RADII",
    "MISS_RADII",
    "QUICK",
    "ToyCounterfactualSet",
    "margin",
    "plan_counterfactual_set",
    "push_transforms",
    "simulate_variant",
    "variants_of",
    "write_counterfactual_sets",
    "set_rng",
]

_log = get_logger(__name__)

#: The horizontal misses, ball radii: one inside the grab distance (2.2), one outside.
MISS_RADII = (1.0, 3.0)
VARIANTS = ("close_at_ball", "stay_open", "close_early", "close_late", *(f"miss_{k:g}R" for k in MISS_RADII))
#: The variant a set made with pushing adds (module docstring).
PUSH_VARIANT = "open_push"
#: ``open_push``: where the end-effector waits before the sweep (ball radii behind the ball's centre, horizontally;
#: out of contact: the contact reaches at most :data:`~oscar_core.toyworld.motion.PUSH_CONTACT_RADII` = 1.6) and
#: where the sweep ends (radii beyond it), at the grasp height.
PUSH_BEHIND_RADII = 2.5
PUSH_BEYOND_RADII = 3.0
#: ``open_push`` is kept only where the simulator pushes the ball at least this far (ball radii): the judge's
#: 3 radii with a margin, so the judge on the true frames is not at its threshold.
PUSH_MIN_RADII = 3.75
#: The quick set: sets per embodiment and embodiments (what ``--quick`` generates).
QUICK = {"sets": 3, "embodiments": ("toyarm", "franka", "kuka")}
MAX_ATTEMPTS = 30
_TAG = 0xCF5E7  # this generator's word in the seed: its sets are unrelated to the closed-loop sessions of one seed


class _Redraw(Exception):
    """This attempt's plan cannot make a set; another attempt is drawn."""


def set_rng(seed: int, embodiment: str, index: int, attempt: int) -> np.random.Generator:
    """The generator of attempt ``attempt`` at set ``index`` of ``embodiment``."""
    words = [int(seed), zlib.crc32(embodiment.encode()), int(index), _TAG, int(attempt)]
    return np.random.default_rng(np.random.SeedSequence(words))


def variants_of(push: bool) -> tuple[str, ...]:
    """The variants of a set made with or without pushing, in the order they are written."""
    return (*VARIANTS, PUSH_VARIANT) if push else VARIANTS


def margin(frames: int) -> int:
    """Frames between a decision and the grab-distance boundary (close early / late) and the half-width of a miss's
    full shift: :func:`~oscar_core.toyworld.motion.decision_margin`, the rule mistimed training picks use too."""
    return decision_margin(frames)


@dataclasses.dataclass
class ToyCounterfactualSet:
    """A planned set. base: the plan's :class:`~oscar_core.kinematics.trajectory.Trajectory` (T frames);
    transforms: variant name → list of transforms; truth: variant name → :func:`simulate_variant` dict; motions:
    variant name → :class:`~oscar_core.toyworld.motion.Motion`; ball (3,), radius, scale: metres; scene, camera;
    close_at: the base's closing frame; attempt: which attempt made it; push: made with the push rule (the
    variants are :func:`variants_of` it)."""

    embodiment: str
    base: object
    transforms: dict
    truth: dict
    motions: dict
    ball: np.ndarray
    radius: float
    scale: float
    scene: object
    camera: object
    close_at: int
    attempt: int
    push: bool = False


def simulate_variant(
    emb, traj, ball: np.ndarray, radius: float, scale: float, *, push: bool = False
) -> tuple[Motion, dict]:
    """The toy simulator on one variant: its :class:`Motion` (the ball under the carry rule, and the push rule when
    ``push``) and truth ``{"outcome", "grabbed", "displacement_radii", "close_distance_radii"}`` (the last: the
    end-effector's distance from the ball at the first closing frame, ball radii; None when the gripper never
    closes), with ``"pushed"`` (the ball moved horizontally on a frame it was not held) when ``push``. ball (3,), radius, scale:
    metres. Outcome (module docstring): the ball grabbed and ending >= SUCCESS_RADII radii from its start; with
    ``push``, ending there however it got there."""
    from .policy_eval import SUCCESS_RADII

    if not isinstance(push, bool):
        raise ToyWorldError(f"toyworld action-following: push: expected True or False, found {push!r}")
    points, ee = ee_points(emb, traj)
    o = emb.gripper_openness(traj.gripper)[:, 0]
    contact = PUSH_CONTACT_RADII * radius if push else None
    obj, attached = carry_object(ee, o, ball, radius, grab_distance=GRAB_RADII * radius, push_contact=contact)
    disp = float(np.linalg.norm(obj[-1, :2] - ball[:2]) / radius)
    grabbed = bool(attached.any())
    closes = np.flatnonzero((o < 0.5) & np.concatenate([[True], o[:-1] >= 0.5]))
    close_d = float(np.linalg.norm(ee[closes[0]] - ball) / radius) if len(closes) else None
    truth = {
        "outcome": int((grabbed or push) and disp >= SUCCESS_RADII),
        "grabbed": grabbed,
        "displacement_radii": round(disp, 4),
        "close_distance_radii": None if close_d is None else round(close_d, 4),
    }
    if push:
        prev = np.concatenate([np.asarray(ball, dtype=np.float64)[None, :2], obj[:-1, :2]])
        truth["pushed"] = bool(np.any(~attached & (np.linalg.norm(obj[:, :2] - prev, axis=1) > 1e-12)))
    return Motion(traj, "pick_place", points, ee, obj, attached, radius, scale), truth


def push_transforms(ee: np.ndarray, ball: np.ndarray, R: float, close_at: int, frames: int, u: np.ndarray) -> list:
    """The ``open_push`` variant's transforms (module docstring) for the push direction ``u`` (2,) (unit,
    horizontal): the gripper open throughout; the end-effector shifted from the plan's ``ee[close_at]`` ((T, 3)
    metres) to :data:`PUSH_BEHIND_RADII` ``R`` behind ``ball`` ((3,) metres) along ``u`` on frames
    [close_at - m, close_at] (m = :func:`margin`), blended in from frame 1 and out over as many frames after; on
    top, the sweep along ``u`` of (:data:`PUSH_BEHIND_RADII` + :data:`PUSH_BEYOND_RADII`) ``R``, blended in over
    [close_at - m, close_at), full at close_at and blended out over the next m frames. R: metres."""
    m = margin(frames)
    e = ee[close_at]
    v = np.array([*(ball[:2] - PUSH_BEHIND_RADII * R * u - e[:2]), 0.0])
    dist = float(np.linalg.norm(v))
    behind = {
        "shift_m": round(dist, 6),
        "axis": [round(float(x), 6) for x in v / dist],
        "from": close_at - m,
        "to": close_at + 1,
        "ramp": close_at - m - 1,
    }
    sweep = {
        "shift_m": round((PUSH_BEHIND_RADII + PUSH_BEYOND_RADII) * R, 6),
        "axis": [round(float(u[0]), 6), round(float(u[1]), 6), 0.0],
        "from": close_at,
        "to": close_at + 1,
        "ramp": m,
    }
    return [{"gripper": "open", "from": 0}, behind, sweep]


def _push_variant(emb, base, ee: np.ndarray, ball: np.ndarray, R: float, scale: float, close_at: int):
    """``(transforms, trajectory, motion, truth)`` of ``open_push``: the first of 8 directions (the plan's approach,
    then 45° turns) whose arm follows the shifts and whose simulator truth is a push of at least
    :data:`PUSH_MIN_RADII` without a grab; raises ``_Redraw`` when none is."""
    T = len(base.q)
    come = ee[close_at, :2] - ee[0, :2]
    start = float(np.arctan2(come[1], come[0])) if np.linalg.norm(come) > 1e-9 else 0.0
    why = "the arm cannot follow the sweep in any of 8 directions"
    for ang in start + np.arange(8) * np.pi / 4:
        u = np.array([np.cos(ang), np.sin(ang)])
        transforms = push_transforms(ee, ball, R, close_at, T, u)
        try:
            traj = apply_transforms(base, emb, transforms)
        except VariantError:
            continue
        motion, truth = simulate_variant(emb, traj, ball, R, scale, push=True)
        if truth["grabbed"] or truth["displacement_radii"] < PUSH_MIN_RADII:
            why = f"the sweep pushes the ball {truth['displacement_radii']:.2f} radii (grabbed: {truth['grabbed']})"
            continue
        return transforms, traj, motion, truth
    raise _Redraw(f"open_push: {why}")


def _variant_transforms(emb, base, ee: np.ndarray, ball: np.ndarray, R: float, rng) -> tuple[dict, int]:
    """The transforms of :data:`VARIANTS` (module docstring) and the plan's closing frame; raises ``_Redraw``."""
    T = len(base.q)
    o = emb.gripper_openness(base.gripper)[:, 0]
    closed = np.flatnonzero(o < 0.5)
    if not len(closed):
        raise _Redraw("the plan never closes")
    close_at = int(closed[0])
    after = np.flatnonzero(o[close_at:] >= 0.5)
    release = close_at + int(after[0]) if len(after) else T
    inside, enter, leave = grab_window(ee, ball, R, close_at)
    if not inside[close_at] or leave is None:
        raise _Redraw("the plan does not close within the grab distance, or never leaves it")
    m = margin(T)
    early, late = enter - m, leave + m
    if early < 1 or late >= release - 1 or close_at - m - 1 < 1:
        raise _Redraw("no room before the grasp or after it for an early or late close")
    out = {
        "close_at_ball": [],
        "stay_open": [{"gripper": "open", "from": 0}],
        "close_early": [{"gripper": "closed", "from": early, "to": close_at}],
        "close_late": [{"gripper": "open", "from": close_at - 1, "to": late}],
    }
    e = ee[close_at]
    start = rng.uniform(-np.pi, np.pi)
    for ang in start + np.arange(8) * np.pi / 4:
        u = np.array([np.cos(ang), np.sin(ang)])
        shifts = {}
        for k in MISS_RADII:
            v = np.array([*(ball[:2] + k * R * u - e[:2]), 0.0])
            dist = float(np.linalg.norm(v))
            shifts[f"miss_{k:g}R"] = [
                {
                    "shift_m": round(dist, 6),
                    "axis": [round(float(x), 6) for x in v / dist],
                    "from": close_at - m,
                    "to": close_at + m + 1,
                    "ramp": close_at - m - 1,
                }
            ]
        try:
            for t in shifts.values():
                apply_transforms(base, emb, t)
        except VariantError:
            continue
        out.update(shifts)
        return out, close_at
    raise _Redraw("the arm cannot follow a miss in any of 8 directions")


def plan_counterfactual_set(
    emb,
    rng: np.random.Generator,
    width: int,
    height: int,
    frames: int,
    fps: float = 10.0,
    attempt: int = 0,
    *,
    push: bool = False,
):
    """Plan one set (module docstring) or raise ``_Redraw``; nothing rendered. ``push``: every variant simulated
    with the push rule, and ``open_push`` added (it draws nothing from ``rng``)."""
    from .policy_eval import Policy, plan_session
    from .scene import sample_camera

    try:
        s = plan_session(emb, rng, width, height, frames, fps, (Policy("exact", 0.0),))
    except ValueError as exc:
        raise _Redraw(str(exc)) from None
    ep = s.episodes[0]
    if not ep.success:
        raise _Redraw("the planned grasp missed")
    base = ep.motion.trajectory
    transforms, close_at = _variant_transforms(emb, base, ep.motion.ee, s.ball, s.radius, rng)
    motions, truth = {}, {}
    floor = -0.02 * s.scale
    for name in VARIANTS:
        traj = apply_transforms(base, emb, transforms[name])
        motions[name], truth[name] = simulate_variant(emb, traj, s.ball, s.radius, s.scale, push=push)
    if push:
        name = PUSH_VARIANT
        transforms[name], _, motions[name], truth[name] = _push_variant(
            emb, base, ep.motion.ee, s.ball, s.radius, s.scale, close_at
        )
    for name in variants_of(push):
        if np.nanmin(motions[name].points[..., 2]) < floor:
            raise _Redraw(f"{name}: the arm goes under the floor")
    R = s.radius
    seen = np.concatenate(
        [
            np.concatenate([m.points.reshape(-1, 3), m.object + [0, 0, R], m.object - [0, 0, R]])
            for m in motions.values()
        ]
    )
    try:
        camera = sample_camera(rng, seen, width, height, base_xy=ep.motion.points[0, 0, :2], embodiment=emb.name)
    except ValueError as exc:
        raise _Redraw(str(exc)) from None
    return ToyCounterfactualSet(
        emb.name, base, transforms, truth, motions, s.ball, s.radius, s.scale, s.scene, camera, close_at, attempt, push
    )


def _render(emb, cs: ToyCounterfactualSet) -> tuple[dict, dict]:
    """(variant name → (T, H, W, 3) uint8 true frames, the judge's ``info``)."""
    from .episode import render_world
    from .judge import ball_moved
    from .policy_eval import SUCCESS_RADII, Session, _radius_px, floor_homography

    frames = {n: render_world(emb, m, cs.scene, cs.camera, ss=2) for n, m in cs.motions.items()}
    first = frames[VARIANTS[0]].rgb[0]
    if any(not np.array_equal(r.rgb[0], first) for r in frames.values()):
        raise _Redraw("the variants' first frames differ")
    sess = Session(cs.embodiment, cs.ball, cs.radius, cs.scale, cs.scene, cs.camera)
    info = {
        "ball_start_px": [round(float(v), 3) for v in frames[VARIANTS[0]].object_px[0]],
        "ball_radius_px": round(_radius_px(sess), 3),
        "px_to_floor_radii": floor_homography(cs.camera, cs.radius, cs.radius).tolist(),
        "success_radii": SUCCESS_RADII,
    }
    for n, r in frames.items():
        v = ball_moved(r.rgb, SimpleNamespace(info=info))
        if v["binary"] != cs.truth[n]["outcome"]:
            raise _Redraw(f"{n}: the judge on the simulator's frames says {v['binary']} ({v['reason']})")
    return {n: r.rgb for n, r in frames.items()}, info


def _make_set(emb, seed: int, index: int, width: int, height: int, frames: int, fps: float, push: bool = False):
    why = []
    for attempt in range(MAX_ATTEMPTS):
        try:
            cs = plan_counterfactual_set(
                emb, set_rng(seed, emb.name, index, attempt), width, height, frames, fps, attempt, push=push
            )
            videos, info = _render(emb, cs)
            return cs, videos, info
        except (_Redraw, ToyWorldError) as exc:
            why.append(str(exc))
    raise ToyWorldError(
        f"toyworld action-following: {emb.name} set {index}: no set in {MAX_ATTEMPTS} attempts (last: {why[-1]})"
    )


def _write_set(folder: Path, sid: str, emb, cs: ToyCounterfactualSet, videos: dict, info: dict) -> dict:
    from .._util.atomic import atomic_write_bytes
    from ..camera import save_camera
    from ..kinematics.trajectory import save_trajectory
    from ..media.video import write_video
    from .closed_loop import TASK
    from .policy_eval import _png_bytes

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "true").mkdir(exist_ok=True)
    save_trajectory(cs.base, folder / "trajectory.npz")
    save_camera(cs.camera, folder / "camera.json")
    atomic_write_bytes(folder / "first.png", _png_bytes(videos[VARIANTS[0]][0]))
    place = cs.motions["close_at_ball"].object[-1]
    variants = []
    for name in variants_of(cs.push):
        write_video(folder / "true" / f"{name}.mkv", videos[name], float(cs.base.fps))
        variants.append(
            {
                "name": name,
                "transforms": cs.transforms[name],
                "outcome": cs.truth[name]["outcome"],
                "video": f"{sid}/true/{name}.mkv",
                "simulator": {k: v for k, v in cs.truth[name].items() if k != "outcome"},
            }
        )
    row = {
        "set": sid,
        "embodiment": emb.name,
        "first_frame": f"{sid}/first.png",
        "camera": f"{sid}/camera.json",
        "trajectory": f"{sid}/trajectory.npz",
        "task": TASK.format(x=place[0], y=place[1]),
        "info": info,
        "variants": variants,
        "attempt": cs.attempt,
        "close_at": cs.close_at,
    }
    if cs.push:  # absent without pushing: those sets are written as before the option existed
        row["push_contact_radii"] = PUSH_CONTACT_RADII
    atomic_write_bytes(folder / "set.json", (json.dumps(row, indent=1) + "\n").encode())  # last: the set is whole
    return row


def write_counterfactual_sets(
    out,
    embodiments,
    sets: int,
    *,
    seed: int = 0,
    width: int = 64,
    height: int = 64,
    frames: int = 97,
    fps: float = 10.0,
    registry=None,
    progress: bool = False,
    push: bool = False,
) -> Path:
    """Write ``sets`` counterfactual sets per embodiment under ``out`` and ``out/manifest.json`` (module
    docstring); returns the manifest's path. A set whose ``set.json`` exists is kept (resume); the folder's
    fingerprint (seed, size, frames, fps, variants, pushing) refuses a re-run under other settings. push: the
    simulator's push rule on, and the ``open_push`` variant (module docstring); recorded as
    ``push_contact_radii`` in the manifest and every ``set.json`` (absent: made without pushing)."""
    from .._util import stage as _stage
    from .._util.atomic import atomic_write_bytes
    from .._util.log import progress_bar
    from ..evaluation.action_following_manifest import FORMAT
    from ..plugin.registry import Registry
    from .policy_eval import policy_eval_refusal

    if not isinstance(push, bool):
        raise ToyWorldError(f"toyworld action-following: push: expected True or False, found {push!r}")
    registry = registry or Registry()
    embs = [registry.get(n) for n in embodiments]
    for e in embs:
        why = policy_eval_refusal(e)
        if why is not None:
            raise ToyWorldError(f"toyworld action-following: --embodiments: {why}")
    if frames < 17:
        raise ToyWorldError(f"toyworld action-following: --frames: expected at least 17 frames, found {frames}")
    out = Path(out)
    parts = {
        "stage": "toyworld-action-following-sets",
        "format": _stage.FORMAT_VERSION,
        "seed": seed,
        "width": width,
        "height": height,
        "frames": frames,
        "fps": fps,
        "variants": list(variants_of(push)),
        "attempts": MAX_ATTEMPTS,
        **({"push_contact_radii": PUSH_CONTACT_RADII} if push else {}),  # absent: a set made before the option
    }
    _stage.check_stage(out, parts, redo="use another --out for these settings, or delete the folder to redo it")
    rows = []
    bar = progress_bar(total=len(embs) * sets, desc="counterfactual sets", unit="set", enabled=progress)
    for emb in embs:
        for i in range(sets):
            sid = f"{emb.name}-{i:04d}"
            folder = out / sid
            if (folder / "set.json").is_file():
                rows.append(json.loads((folder / "set.json").read_text()))
            else:
                cs, videos, info = _make_set(emb, seed, i, width, height, frames, fps, push)
                rows.append(_write_set(folder, sid, emb, cs, videos, info))
                _log.info(f"{sid}: attempt {cs.attempt}, outcomes {[cs.truth[n]['outcome'] for n in cs.truth]}")
            bar.update(1)
    bar.close()
    manifest = {
        "format": FORMAT,
        "version": 1,
        "description": f"toy-world counterfactual sets, {sets} per embodiment x {list(embodiments)}, seed {seed}, "
        f"{frames} frames at {width}x{height}" + (", an open gripper pushes the ball" if push else ""),
        "locator": "oscar_core.toyworld.locate:ball_position",
        "variants": list(variants_of(push)),
        **({"push_contact_radii": PUSH_CONTACT_RADII} if push else {}),
        "sets": [{k: v for k, v in r.items() if k not in ("attempt", "close_at", "push_contact_radii")} for r in rows],
    }
    path = out / "manifest.json"
    atomic_write_bytes(path, (json.dumps(manifest, indent=1) + "\n").encode())
    return path
