"""The toy world's table: PSNR, SSIM, end-effector and object errors of generated videos per condition.

A *condition* (a row: "true skeleton", "shuffled skeleton", ...) is a folder of
generated videos, one per ground-truth clip, named by the clip id:
``<id>.mp4``, ``<id>.mkv``, ``<id>.npy`` ((T, H, W, 3) uint8) or a folder
``<id>/`` of PNG frames. The ground truth is the clip set's RGB video of that
clip. Every frame is compared (the first one included); the prediction must
have the clip's frame count and size.

Per clip: PSNR and SSIM (:mod:`oscar_core.metrics`, frame means; a frame
identical to the truth scores :data:`PSNR_CAP` dB instead of infinity), and
the end-effector and object localisation errors of
:func:`~oscar_core.toyworld.locate.position_errors` (pixels, both located by
colour in both videos; a missed target counts as the image diagonal); the
*moved-object* error, the object error over only the frames where the true
ball has left its frame-0 position (carried by the gripper: the consequence
of an action, where the plain object error is mostly a ball lying still);
and motion IoU. A row is the mean over its clips (for the moved-object
error, over the clips whose ball moves).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .frame_metrics import (
    METRICS,
    MOTION_THRESHOLD,
    MOVED_OBJECT_SHIFT_PX,
    PSNR_CAP,
    frame_series,
    mask_iou,
    motion_mask,
    moved_frames,
)
from .locate import OBJECT_TARGET, position_errors
from .per_chunk import add_paired_chunks, check_chunk_frames, chunk_rows, format_chunks, split_by_chunk

__all__ = [
    "PSNR_CAP",
    "find_prediction",
    "evaluate_clip",
    "evaluate_conditions",
    "format_table",
    "add_paired",
    "format_paired",
    "plot_table",
    "parse_pred_args",
    "motion_iou",
    "motion_mask",
    "MOTION_THRESHOLD",
    "moved_object_error",
    "MOVED_OBJECT_SHIFT_PX",
]


def moved_object_error(
    pred: np.ndarray, gt: np.ndarray, min_shift: float = MOVED_OBJECT_SHIFT_PX, errors: dict | None = None
) -> dict:
    """The object error over the frames where the ground-truth object has moved, i.e. where an action moved it.

    pred, gt: (T, H, W, 3) uint8. A frame counts when the object is shown in
    ``gt`` at frame 0 and at frame t, more than ``min_shift`` pixels apart;
    its error is :func:`~oscar_core.toyworld.locate.position_errors`' (the
    image diagonal when the prediction lost the object). ``errors``: that
    function's result for (pred, gt, OBJECT_TARGET) when the caller has it
    already. Returns ``error_px`` (mean; NaN when the object never moves)
    and ``frames``.
    """
    if errors is None:
        errors = position_errors(pred, gt, OBJECT_TARGET)
    moved = moved_frames(errors["gt_px"], min_shift)  # False where either centroid is NaN
    if not moved.any():
        return {"error_px": float("nan"), "frames": 0}
    return {"error_px": float(errors["per_frame"][moved].mean()), "frames": int(moved.sum())}


def motion_iou(pred: np.ndarray, gt: np.ndarray, threshold: float = MOTION_THRESHOLD) -> float:
    """Intersection over union of the changed-pixel masks of ``pred`` and ``gt`` (frames 1…, pooled), in [0, 1].

    Where the robot and the ball moved, and nothing else: colour-free, so it
    scores a model whose VAE renders grey. NaN when neither video changes.
    """
    return mask_iou(motion_mask(pred, threshold), motion_mask(gt, threshold))


_SUFFIXES = (".mp4", ".mkv", ".npy")


def parse_pred_args(values) -> dict[str, str]:
    """``["true=dir1", "dir2"]`` → ``{"true": "dir1", "dir2": "dir2"}`` (a bare folder is named by itself)."""
    out: dict[str, str] = {}
    for v in values:
        name, sep, path = v.partition("=")
        if not sep:
            name, path = Path(v).name or v, v
        if not name or not path:
            raise ValueError(f"--pred: expected NAME=FOLDER or FOLDER, found {v!r}")
        if name in out:
            raise ValueError(f"--pred: condition {name!r} given twice")
        out[name] = path
    return out


def find_prediction(folder, clip_id: str) -> Path | None:
    """The generated video for ``clip_id`` in ``folder``, or None."""
    folder = Path(folder)
    for s in _SUFFIXES:
        if (folder / f"{clip_id}{s}").is_file():
            return folder / f"{clip_id}{s}"
    if (folder / clip_id).is_dir():
        return folder / clip_id
    return None


def evaluate_clip(pred: np.ndarray, gt: np.ndarray, where: str = "<pred>", chunk_frames: int | None = None) -> dict:
    """Metrics of one generated clip against its ground truth; both (T, H, W, 3) uint8.

    chunk_frames: also ``chunks``, the metrics of each chunk of a rollout in chunks of this many frames
    (:func:`oscar_core.toyworld.per_chunk.chunk_metrics`), from the same per-frame series."""
    pred, gt = np.asarray(pred), np.asarray(gt)
    if pred.shape != gt.shape or pred.dtype != np.uint8:
        raise ValueError(
            f"{where}: expected a uint8 video of shape {gt.shape} (the ground truth's), found {pred.dtype} {pred.shape}"
        )
    series = frame_series(pred, gt)
    ee, ob = series["ee"], series["object"]
    moved = moved_object_error(pred, gt, errors=ob)
    out = {
        "psnr_db": float(series["psnr"].mean()),
        "ssim": float(series["ssim"].mean()),
        "motion_iou": mask_iou(series["motion_pred"], series["motion_gt"]),
        "ee_error_px": ee["error_px"],
        "object_error_px": ob["error_px"],
        "ee_found": ee["found"],
        "object_found": ob["found"],
        "moved_object_error_px": moved["error_px"],
        "moved_object_frames": moved["frames"],
    }
    if chunk_frames is not None:
        out["chunks"] = split_by_chunk(series, chunk_frames)
    return out


CLIP_MODES = ("same", "common", "each")


def _ground_truth_clips(sets, split: str | None):
    """``(records, owner)``: the clips of the clip sets ``sets`` (of ``split`` when given) and, per clip id, the
    set holding it; ValueError when two sets hold one id."""
    recs, owner = [], {}
    for c in sets:
        for r in c:
            if split is None or r.meta.get("split") == split:
                if r.id in owner:
                    raise ValueError(f"--gt: clip id {r.id!r} is in both {owner[r.id].root} and {c.root}")
                owner[r.id] = c
                recs.append(r)
    return recs, owner


def _predictions(conditions: dict[str, str], recs, sets, split: str | None) -> dict[str, dict[str, Path]]:
    """Condition → clip id → its prediction's path, for every clip of ``recs`` with one in the condition's folder;
    an error naming the folder when it is missing or holds none."""
    found: dict[str, dict[str, Path]] = {}  # before any scoring
    for name, folder in conditions.items():
        if not Path(folder).is_dir():
            raise FileNotFoundError(f"--pred {name}={folder}: no such folder")
        found[name] = {r.id: p for r in recs if (p := find_prediction(folder, r.id)) is not None}
        if not found[name]:
            raise ValueError(
                f"--pred {name}={folder}: expected videos named <clip id>.mp4/.mkv/.npy for clips of "
                f"{', '.join(str(c.root) for c in sets)}" + (f" (split {split!r})" if split else "") + ", found none"
            )
    return found


def _same_clips(found: dict[str, dict[str, Path]], clips_mode: str) -> dict[str, dict[str, Path]]:
    """The predictions to score under ``clips_mode`` (see :func:`evaluate_conditions`): ``found`` as it is
    ("same", when every condition has the same clips, else ValueError naming the differences; "each"), or
    cut to the clips every condition has ("common")."""
    ids = {name: set(got) for name, got in found.items()}
    common = set.intersection(*ids.values()) if ids else set()
    same = all(v == common for v in ids.values())
    if not same and clips_mode == "same":
        first = next(iter(ids))
        diffs = []
        for name, v in ids.items():
            if v != ids[first]:
                lacks, extra = sorted(ids[first] - v), sorted(v - ids[first])
                diffs.append(
                    f"--pred {name} has {len(v)} clips against {len(ids[first])} of --pred {first}"
                    + (f", lacking {_few(lacks)}" if lacks else "")
                    + (f", adding {_few(extra)}" if extra else "")
                )
        raise ValueError(
            "the rows would be means over different clips: "
            + "; ".join(diffs)
            + f"; expected predictions for the same clips, or --clips common (score the {len(common)} "
            "clips all have) or --clips each (score each row over its own clips, marked)"
        )
    if clips_mode == "common":
        if not common:
            raise ValueError(f"--clips common: expected clips every condition has, found none ({', '.join(ids)})")
        found = {name: {i: p for i, p in got.items() if i in common} for name, got in found.items()}
    return found


def _condition_row(per: dict[str, dict], per_chunk: int | None) -> dict:
    """One row of the table: the means of the clips' metrics ``per`` (clip id → metrics; NaN-skipping), the clip
    count, the clips where the ball moved and, with ``per_chunk``, the means per chunk index."""
    row = {k: _nanmean([m[k] for m in per.values()]) for k in METRICS + ("ee_found", "object_found")}
    row["clips"] = len(per)
    row["moved_object_clips"] = sum(1 for m in per.values() if m.get("moved_object_frames", 0))
    if per_chunk is not None:
        row["chunks"] = chunk_rows(per)
    return row


def evaluate_conditions(
    gt_clipset,
    conditions: dict[str, str],
    split: str | None = None,
    clips_mode: str = "same",
    per_chunk: int | None = None,
) -> dict:
    """The table: one row per condition (name → folder of generated videos).

    gt_clipset: a clip set, or a list of them (clip ids must be unique across
    them; e.g. the training embodiments' and the held-out embodiments' sets).
    Clips evaluated: those of the clip set (with ``meta.split == split`` when
    given) that have a prediction in the condition's folder; a condition
    with none is an error naming its folder. Rows are means, comparable only
    over the same clips, so clips_mode says what happens when the folders
    hold predictions for different clips: "same" (default) refuses, naming
    the condition and the clips it lacks or adds; "common" scores every row
    over the clips all conditions have; "each" scores each row over its own
    clips and marks the table (``same_clips`` false, the rows' clip counts).
    per_chunk: the chunk length (frames, seed included) of the rollouts; every clip's metrics then also
    hold ``chunks`` and every row ``chunks``, its means per chunk index
    (:mod:`oscar_core.toyworld.per_chunk`: quality against chunk index, the drift of a long rollout).
    Returns a JSON-ready dict with ``rows`` (condition → mean metrics, clip
    count), ``clips`` (condition → clip id → metrics), ``same_clips`` and ``per_chunk``.
    """
    if clips_mode not in CLIP_MODES:
        raise ValueError(f"clips_mode: expected one of {CLIP_MODES}, found {clips_mode!r}")
    if per_chunk is not None:
        check_chunk_frames(per_chunk)  # before any clip is read
    from ..metrics.video import load_video
    from ..train.clips import ClipSet

    sets = [
        g if isinstance(g, ClipSet) else ClipSet(g)
        for g in (gt_clipset if isinstance(gt_clipset, (list, tuple)) else [gt_clipset])
    ]
    recs, owner = _ground_truth_clips(sets, split)
    found = _predictions(conditions, recs, sets, split)
    found = _same_clips(found, clips_mode)
    rows, clips = {}, {}
    cache: dict[str, np.ndarray] = {}
    by_id = {r.id: r for r in recs}
    for name, got in found.items():
        per = {}
        for rid, path in got.items():
            r = by_id[rid]
            if r.id not in cache:
                cache[r.id] = owner[r.id].load(r, skeleton=False).rgb
            per[r.id] = evaluate_clip(load_video(path), cache[r.id], str(path), per_chunk)
        rows[name] = _condition_row(per, per_chunk)
        clips[name] = per
    roots = [str(c.root) for c in sets]
    return {
        "ground_truth": roots[0] if len(roots) == 1 else roots,
        "split": split,
        "metrics": list(METRICS),
        "same_clips": len({frozenset(v) for v in clips.values()}) <= 1,
        "per_chunk": per_chunk,
        "rows": rows,
        "clips": clips,
    }


def _few(ids: list[str], n: int = 3) -> str:
    return ", ".join(ids[:n]) + (f" and {len(ids) - n} more" if len(ids) > n else "")


def _nanmean(values) -> float:
    """Mean over the finite values; NaN (no warning) when there are none (a target never shown)."""
    a = np.asarray(values, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else float("nan")


def add_paired(table: dict, reference: str, resamples: int = 2000, seed: int = 0) -> dict:
    """Add ``table["paired"]``: every other row minus the ``reference`` row, per metric, over the clips both
    scored (:func:`oscar_core.metrics.paired.paired_difference`: mean and 95 % percentile-bootstrap interval,
    ``resamples`` resamples of the clips, seeded); per chunk index too when the table has per-chunk rows
    (:func:`oscar_core.toyworld.per_chunk.add_paired_chunks`). Returns the table."""
    from ..metrics.paired import paired_difference

    if reference not in table["rows"]:
        raise ValueError(f"--paired {reference}: expected the name of a --pred row ({', '.join(table['rows'])})")
    ref = table["clips"][reference]
    table["paired"] = {
        "reference": reference,
        "resamples": resamples,
        "seed": seed,
        "level": 0.95,
        "rows": {
            name: {m: paired_difference(per, ref, m, resamples, seed) for m in METRICS}
            for name, per in table["clips"].items()
            if name != reference
        },
    }
    if table.get("per_chunk"):
        add_paired_chunks(table, reference, resamples, seed)
    return table


def format_paired(table: dict) -> str:
    """The paired differences as a Markdown table: mean [95 % interval] per metric (empty without them)."""
    paired = table.get("paired")
    if not paired:
        return ""
    names = (
        "PSNR (dB)",
        "SSIM",
        "motion IoU",
        "end-effector error (px)",
        "object error (px)",
        "moved-object error (px)",
    )
    lines = [
        f"\nminus {paired['reference']!r}, paired over the same clips (mean [95 % bootstrap interval]):",
        "| condition | " + " | ".join(names) + " |",
        "|---" * (len(names) + 1) + "|",
    ]
    for name, per in paired["rows"].items():
        cells = []
        for m in METRICS:
            d = per[m]
            digits = 3 if m in ("ssim", "motion_iou") else 2
            cells.append(f"{d['mean']:+.{digits}f} [{d['ci'][0]:+.{digits}f}, {d['ci'][1]:+.{digits}f}]")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_table(table: dict) -> str:
    """The rows as a Markdown table."""
    head = (
        "| condition | clips | PSNR (dB) ↑ | SSIM ↑ | motion IoU ↑ | end-effector error (px) ↓ | "
        "object error (px) ↓ | moved-object error (px) ↓ |"
    )
    lines = [head, "|---|---|---|---|---|---|---|---|"]
    nan = float("nan")
    for name, r in table["rows"].items():
        moved = r.get("moved_object_error_px", nan)
        lines.append(
            f"| {name} | {r['clips']} | {r['psnr_db']:.2f} | {r['ssim']:.3f} | {r.get('motion_iou', nan):.3f} | "
            f"{r['ee_error_px']:.2f} | {r['object_error_px']:.2f} | "
            f"{moved:.2f} ({r.get('moved_object_clips', 0)} clips) |"
        )
    if table.get("same_clips") is False:
        lines.append("\nnot comparable: the rows are means over different clips (see the clips column)")
    paired = format_paired(table)
    text = "\n".join(lines) + ("\n" + paired if paired else "")
    if table.get("per_chunk"):
        text += "\n" + format_chunks(table)
    return text


def plot_table(table: dict, path) -> Path:
    """A PNG with one bar chart per metric, one bar per condition (needs matplotlib: ``oscar-wm[plots]``)."""
    from ..metrics.plots import new_figure, save_figure

    names = list(table["rows"])
    labels = {
        "psnr_db": "PSNR (dB) ↑",
        "ssim": "SSIM ↑",
        "motion_iou": "motion IoU ↑",
        "ee_error_px": "end-effector error (px) ↓",
        "object_error_px": "object error (px) ↓",
        "moved_object_error_px": "moved-object error (px) ↓",
    }
    fig = new_figure((3.2 * len(METRICS), 3.2), 100)
    for i, m in enumerate(METRICS):
        ax = fig.add_subplot(1, len(METRICS), i + 1)
        vals = [table["rows"][n].get(m, float("nan")) for n in names]
        ax.bar(range(len(names)), vals, color=[f"C{j}" for j in range(len(names))])
        ax.set_xticks(range(len(names)))
        ax.set_xticklabels(names, rotation=30, ha="right", fontsize=8)
        ax.set_title(labels[m], fontsize=9)
    fig.subplots_adjust(bottom=0.3, wspace=0.35, left=0.05, right=0.98)
    return save_figure(fig, path)
