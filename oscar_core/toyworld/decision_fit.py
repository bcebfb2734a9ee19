"""Does a world model obey the gripper on the episodes it was trained on, and on held-out ones of the same data?

The action-following benchmark (:mod:`oscar_core.evaluation.action_following`) says whether a model's outcomes
follow the policy's decision on counterfactual sets it never saw. When they do not, the next question is which
kind of failure it is: a model that gets its *training* episodes wrong as often as held-out ones has not fitted
the decision (capacity, resolution, optimisation: more of the same data will not help), while one that gets its
training episodes right and held-out ones wrong has fitted them without learning the rule (more and more varied
data is the lever). This module measures that gap on a toy world clip set (``oscar toyworld generate``, whose
records keep every pick's outcome in ``meta.toyworld``).

Per pick-and-place episode, its class from the simulator's record: ``carried`` (the ball attached to the gripper
in some frame), ``beside`` (the gripper closed but the ball stayed: a miss or an early or late close) or ``open``
(the gripper never closed). One window of the model's chunk length per episode starts ``lead`` frames before the
*decision frame*: the first frame with the gripper closed (openness below 0.5, the carry rule's threshold), or for
an open hand the frame where the end effector passes nearest the ball. The model rolls out one chunk from the
window's true first frame, along its true trajectory (the card's condition video and gripper signal). The toy
world's judge (:func:`~oscar_core.toyworld.judge.ball_moved`, the action-following benchmark's) reads the model's
chunk and the simulator's frames of the same window with the window's own ``info`` (the ball's start and radius
in pixels, the floor homography of the clip's camera); a window *agrees* when the two verdicts are the same.

Reported per split (``train``, ``heldout``: every tenth episode, as the generator splits) and class: windows,
agreements and the rate with its Wilson 95 % interval, over the windows whose true verdict is what the class
implies; those whose is not (a carried ball that has not yet left its start within the window: about a quarter
of the carried windows at the default lead of 2 frames) are counted apart and left out, so each class asks one
question, carry the ball or leave it. Per class, the train − held-out difference of the rates with Newcombe's
hybrid score interval (his method 10). A window whose rollout or judge fails is
recorded with its reason and left out of the rates; the rest go on.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..errors import OscarError
from .motion import OPEN_THRESHOLD, ToyWorldError

__all__ = [
    "CLASSES",
    "SPLITS",
    "FitWindow",
    "choose_windows",
    "decision_fit",
    "episode_class",
    "judge_info",
    "newcombe_difference",
    "wilson_interval",
]

CLASSES = ("carried", "beside", "open")
SPLITS = ("train", "heldout")
#: The fields of a record's ``meta.toyworld`` a window needs (``oscar toyworld generate`` writes them; a set made
#: without ``--pick-open`` has no ``never_closed``, and no pick of it stays open).
NEEDED = ("kind", "attached", "object_px", "ee_px", "object_radius_m")
Z95 = 1.959963984540054


@dataclass(frozen=True)
class FitWindow:
    """One episode's window: its clip set folder, clip id, embodiment, split, class, decision frame and the window's
    first frame (frames of the clip)."""

    root: str
    clip_id: str
    embodiment: str
    split: str
    cls: str
    decision: int
    start: int


def episode_class(toy: dict) -> str | None:
    """``"carried"``, ``"beside"`` or ``"open"`` for a pick-and-place record's ``meta.toyworld``; None for another
    kind of episode (a reach, a push)."""
    if toy["kind"] != "pick_place":
        return None
    if any(toy["attached"]):
        return "carried"
    if toy.get("never_closed", False):
        return "open"
    return "beside"


def _decision_frame(toy: dict, openness: np.ndarray) -> int:
    """The first frame with the gripper closed; for a hand that never closes, the frame where the end effector is
    nearest the ball in the image."""
    closed = np.flatnonzero(np.asarray(openness)[:, 0] < OPEN_THRESHOLD) if openness.shape[1] else []
    if len(closed):
        return int(closed[0])
    gap = np.linalg.norm(np.asarray(toy["ee_px"], float) - np.asarray(toy["object_px"], float), axis=1)
    return int(np.nanargmin(gap))


def choose_windows(
    roots: Sequence, frames: int, per_class: int | None, registry, *, seed: int = 0, lead: int = 2
) -> list[FitWindow]:
    """The windows to score: per clip set, embodiment, split and class, ``per_class`` episodes drawn with ``seed``
    (None: all), each the ``frames``-frame window starting ``lead`` frames before its decision frame (moved inside
    the clip). Every record is checked first: a clip set without a pick-and-place record that carries
    :data:`NEEDED`, or a clip shorter than ``frames``, is refused naming the file and field, before any model loads.
    """
    from ..plugin.openness import trajectory_openness
    from ..train.clips import ClipSet

    groups: dict[tuple, list] = {}
    for root in roots:
        cs = ClipSet(root)
        index = Path(root) / "oscar_clips.json"
        found = 0
        for rec in cs:
            toy = (rec.meta or {}).get("toyworld")
            if not isinstance(toy, dict) or toy.get("kind") != "pick_place":
                continue
            missing = [k for k in NEEDED if k not in toy]
            if missing:
                raise ToyWorldError(
                    f"{index}: {rec.id}: meta.toyworld: expected {', '.join(NEEDED)} (as oscar toyworld generate "
                    f"writes them), found no {', '.join(missing)}"
                )
            if rec.n_frames < frames:
                raise ToyWorldError(
                    f"{index}: {rec.id}: n_frames: expected at least the model's {frames}-frame chunk, "
                    f"found {rec.n_frames}"
                )
            split = (rec.meta or {}).get("split")
            if split not in SPLITS:
                raise ToyWorldError(f"{index}: {rec.id}: meta.split: expected one of {SPLITS}, found {split!r}")
            found += 1
            groups.setdefault((str(root), rec.embodiment, split, episode_class(toy)), []).append((cs, rec))
        if not found:
            raise ToyWorldError(
                f"{index}: meta.toyworld: expected pick-and-place records (oscar toyworld generate), found none"
            )
    rng = np.random.default_rng(seed)
    windows = []
    for key in sorted(groups):
        members = sorted(groups[key], key=lambda m: m[1].id)
        if per_class is not None and len(members) > per_class:
            members = [members[i] for i in sorted(rng.choice(len(members), per_class, replace=False))]
        root, embodiment, split, cls = key
        emb = registry.get(embodiment)
        for cs, rec in members:
            toy = rec.meta["toyworld"]
            decision = _decision_frame(toy, trajectory_openness(emb, cs.read_trajectory(rec)))
            start = int(np.clip(decision - lead, 0, rec.n_frames - frames))
            windows.append(FitWindow(root, rec.id, embodiment, split, cls, decision, start))
    return windows


def judge_info(camera, toy: dict, start: int) -> dict:
    """The judge's ``info`` for a window starting at frame ``start``: the ball's start (``object_px``) and radius in
    pixels (focal length × radius / depth of the ball's centre, found on the plane z = radius through the floor
    homography), the pixel → floor homography in ball radii, and the success distance."""
    from ..camera.projection import project
    from .policy_eval import SUCCESS_RADII, floor_homography

    radius = float(toy["object_radius_m"])
    cam = camera.time_slice(0, 1) if getattr(camera, "num_frames", None) else camera
    H = floor_homography(cam, radius, radius)
    start_px = np.asarray(toy["object_px"][start], dtype=np.float64)
    p = H @ np.array([start_px[0], start_px[1], 1.0])
    centre = np.array([p[0] / p[2] * radius, p[1] / p[2] * radius, radius])
    depth = float(project(centre[None], cam).depth[0])
    return {
        "ball_start_px": [round(float(v), 3) for v in start_px],
        "ball_radius_px": round(float(cam.intrinsics.fx) * radius / max(depth, 1e-9), 3),
        "px_to_floor_radii": H.tolist(),
        "success_radii": SUCCESS_RADII,
    }


def wilson_interval(k: int, n: int, z: float = Z95) -> list[float] | None:
    """The Wilson score interval of ``k`` successes in ``n`` trials (None for n = 0)."""
    if n <= 0:
        return None
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return [max(0.0, centre - half), min(1.0, centre + half)]


def newcombe_difference(k1: int, n1: int, k2: int, n2: int, z: float = Z95) -> list[float] | None:
    """Newcombe's hybrid score interval (method 10) for p1 − p2 of two independent proportions (None when either
    sample is empty)."""
    a, b = wilson_interval(k1, n1, z), wilson_interval(k2, n2, z)
    if a is None or b is None:
        return None
    p1, p2 = k1 / n1, k2 / n2
    d = p1 - p2
    return [d - math.hypot(p1 - a[0], b[1] - p2), d + math.hypot(a[1] - p1, p2 - b[0])]


def decision_fit(
    windows: Iterable[FitWindow], roll: Callable, frames: int, *, registry=None, progress: Callable | None = None
) -> dict:
    """Score every ``frames``-frame window (module docstring). ``roll(clip, embodiment_name) -> (T, H, W, 3)
    uint8``: the model's chunk for a loaded window (:class:`~oscar_core.train.clip_format.Clip`, its first frame, trajectory and camera
    the window's; its camera read with ``registry``'s embodiment defaults when given). Returns ``{"rows": [...],
    "table": [...], "gaps": [...]}``: :func:`summarise` of the rows."""
    from types import SimpleNamespace

    from ..train.clips import ClipSet
    from .judge import ball_moved

    sets: dict[str, ClipSet] = {}
    rows = []
    for w in windows:
        row = asdict(w)
        try:
            cs = sets.setdefault(w.root, ClipSet(w.root))
            rec = cs.record(w.clip_id)
            clip = cs.load(rec, start=w.start, frames=frames, registry=registry)
            info = judge_info(clip.camera, rec.meta["toyworld"], w.start)
            pred = np.asarray(roll(clip, w.embodiment))
            truth_v = ball_moved(clip.rgb, SimpleNamespace(info=info))
            pred_v = ball_moved(pred, SimpleNamespace(info=info))
            row.update(
                truth=int(truth_v["binary"]),
                model=int(pred_v["binary"]),
                truth_reason=truth_v["reason"],
                model_reason=pred_v["reason"],
            )
        except (OscarError, ValueError, OSError) as exc:  # one window's fault is recorded; the others go on
            row["error"] = f"{type(exc).__name__}: {exc}"
        rows.append(row)
        if progress is not None:
            progress(row)
    return {"rows": rows, **summarise(rows)}


def summarise(rows: list[dict]) -> dict:
    """The table (per split and class) and the train − held-out gaps (per class and over all classes) of scored
    rows. A row with an ``error`` counts only in ``failed``; one whose true verdict is not what its class implies
    (a carried ball that has not yet left its start within the window, a ball that moved without a carry) counts
    only in ``truth_not_as_class``, so each class asks one question: carry the ball, or leave it."""
    table, gaps = [], []
    cell = {}
    for split in SPLITS:
        for cls in (*CLASSES, "all"):
            mine = [r for r in rows if r["split"] == split and (cls == "all" or r["cls"] == cls)]
            ok = [r for r in mine if "error" not in r]
            clean = [r for r in ok if r["truth"] == int(r["cls"] == "carried")]
            k = sum(r["model"] == r["truth"] for r in clean)
            cell[split, cls] = (k, len(clean))
            table.append(
                {
                    "split": split,
                    "class": cls,
                    "windows": len(clean),
                    "failed": len(mine) - len(ok),
                    "truth_not_as_class": len(ok) - len(clean),
                    "agree": k,
                    "rate": k / len(clean) if clean else None,
                    "interval": wilson_interval(k, len(clean)),
                    "model_moved": sum(r["model"] for r in clean),
                }
            )
    for cls in (*CLASSES, "all"):
        (k1, n1), (k2, n2) = cell["train", cls], cell["heldout", cls]
        gaps.append(
            {
                "class": cls,
                "train_minus_heldout": k1 / n1 - k2 / n2 if n1 and n2 else None,
                "interval": newcombe_difference(k1, n1, k2, n2),
                "undefined": None if n1 and n2 else "no scored window in one of the splits",
            }
        )
    return {"table": table, "gaps": gaps}
