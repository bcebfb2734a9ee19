"""Quality against chunk index: the toy-world metrics of a long rollout, split by the chunk that made each frame.

An autoregressive rollout of ``T`` frames in chunks of ``C`` frames
(:func:`oscar_core.model.chunks.chunk_plan`: one frame of overlap) makes
frames ``[1 + (C − 1)(k − 1), (C − 1) k]`` (inclusive, clipped to ``T − 1``)
in chunk k = 1, 2, …; chunk k starts from the last frame chunk k − 1 made,
so errors carried from chunk to chunk show up as quality falling with k
(drift). Frame 0 is the clip's own first frame and belongs to no chunk.

Per chunk, over that chunk's frames only (:func:`chunk_metrics`): PSNR and
SSIM (frame means, capped as :func:`oscar_core.toyworld.evaluate.evaluate_clip`
caps), motion IoU (the changed-from-frame-0 masks of
:func:`~oscar_core.toyworld.frame_metrics.motion_mask` pooled over the chunk's
frames), end-effector and object errors (pixels, mean over the chunk's frames
that show the target in the truth; NaN when none does) and the moved-object
error (over the chunk's frames where the true ball has left its frame-0
position). The same definitions as the whole-clip metrics, restricted to a
range of frames.
"""

from __future__ import annotations

import numpy as np

from ..model.chunks import chunk_windows
from .frame_metrics import METRICS, frame_series, mask_iou, moved_frames

__all__ = [
    "check_chunk_frames",
    "chunk_windows",  # from model/chunks.py, beside the rollout's chunk_plan
    "chunk_metrics",
    "split_by_chunk",
    "chunk_rows",
    "add_paired_chunks",
    "format_chunks",
]


def check_chunk_frames(chunk_frames: int) -> None:
    """Raise ValueError unless a chunk holds at least 2 frames (the seed and one new)."""
    if chunk_frames < 2:
        raise ValueError(
            f"--per-chunk: expected a chunk of at least 2 frames (the seed and one new), found {chunk_frames}"
        )


def chunk_metrics(pred: np.ndarray, gt: np.ndarray, chunk_frames: int) -> list[dict]:
    """One dict of metrics per chunk (see the module): pred, gt (T, H, W, 3) uint8 of the same shape.

    Each dict holds ``frames`` ([first, last], inclusive) and the keys of
    :data:`oscar_core.toyworld.frame_metrics.METRICS` (PSNR in dB, SSIM and motion IoU in [0, 1], errors in
    pixels).
    """
    pred, gt = np.asarray(pred), np.asarray(gt)
    if pred.shape != gt.shape:
        raise ValueError(f"per-chunk metrics: expected a prediction of shape {gt.shape}, found {pred.shape}")
    return split_by_chunk(frame_series(pred, gt), chunk_frames)


def split_by_chunk(series: dict, chunk_frames: int) -> list[dict]:
    """:func:`chunk_metrics` from a clip's per-frame series
    (:func:`oscar_core.toyworld.frame_metrics.frame_series`), as the whole-clip table computed it."""
    p, s, mp, mg = series["psnr"], series["ssim"], series["motion_pred"], series["motion_gt"]
    ee, ob = series["ee"]["per_frame"], series["object"]["per_frame"]
    moved = moved_frames(series["object"]["gt_px"])
    out = []
    check_chunk_frames(chunk_frames)
    if len(p) < 2:
        raise ValueError(f"--per-chunk: expected a video of at least 2 frames, found {len(p)}")
    for a, b in chunk_windows(len(p), chunk_frames):
        w = slice(a, b + 1)
        out.append(
            {
                "frames": [a, b],
                "psnr_db": float(p[w].mean()),
                "ssim": float(s[w].mean()),
                "motion_iou": mask_iou(mp[a - 1 : b], mg[a - 1 : b]),
                "ee_error_px": _finite_mean(ee[w]),
                "object_error_px": _finite_mean(ob[w]),
                "moved_object_error_px": _finite_mean(ob[w][moved[w]]),
            }
        )
    return out


def _finite_mean(values) -> float:
    a = np.asarray(values, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else float("nan")


def chunk_rows(clips: dict[str, dict]) -> list[dict]:
    """Row means per chunk index over the clips (clip id → metrics with ``chunks``) that reach that chunk."""
    n = max((len(m["chunks"]) for m in clips.values()), default=0)
    rows = []
    for k in range(n):
        have = [m["chunks"][k] for m in clips.values() if len(m["chunks"]) > k]
        row = {m: _finite_mean([c[m] for c in have]) for m in METRICS}
        row["clips"] = len(have)
        rows.append(row)
    return rows


def add_paired_chunks(table: dict, reference: str, resamples: int = 2000, seed: int = 0) -> dict:
    """Add ``table["paired"]["chunks"]``: per row (not ``reference``) a list over chunk index of
    {metric: paired difference (mean, 95 % bootstrap interval, clips)} against ``reference`` over the clips
    both scored (:func:`oscar_core.metrics.paired.paired_difference`). Needs ``table["paired"]`` (from
    :func:`~oscar_core.toyworld.evaluate.add_paired`) and per-chunk clips. Returns the table."""
    from ..metrics.paired import paired_difference

    def by_chunk(per: dict, k: int) -> dict:
        return {cid: m["chunks"][k] for cid, m in per.items() if len(m["chunks"]) > k}

    ref = table["clips"][reference]
    n = len(table["rows"][reference]["chunks"])
    table["paired"]["chunks"] = {
        name: [
            {m: paired_difference(by_chunk(per, k), by_chunk(ref, k), m, resamples, seed) for m in METRICS}
            for k in range(n)
        ]
        for name, per in table["clips"].items()
        if name != reference
    }
    return table


def format_chunks(table: dict, metrics=("motion_iou", "psnr_db", "object_error_px")) -> str:
    """Markdown: per condition and chunk index, the row means of ``metrics`` and, when paired, the
    difference from the reference row with its 95 % interval (empty without per-chunk rows)."""
    rows = table["rows"]
    if not rows or "chunks" not in next(iter(rows.values())):
        return ""
    paired = (table.get("paired") or {}).get("chunks", {})
    ref = (table.get("paired") or {}).get("reference")
    names = {"motion_iou": "motion IoU", "psnr_db": "PSNR (dB)", "object_error_px": "object error (px)"}
    head = ["condition", "chunk", "frames", "clips"]
    for m in metrics:
        head.append(names.get(m, m))
        if paired:
            head.append(f"Δ {names.get(m, m)} vs {ref} [95 %]")
    lines = ["\nper chunk:", "| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    clips = table["clips"]
    for name, r in rows.items():
        first = next(iter(clips[name].values()))["chunks"]
        for k, c in enumerate(r["chunks"]):
            span = first[k]["frames"] if k < len(first) else ["?", "?"]
            cells = [name, str(k + 1), f"{span[0]}-{span[1]}", str(c["clips"])]
            for m in metrics:
                digits = 3 if m in ("ssim", "motion_iou") else 2
                cells.append(f"{c[m]:.{digits}f}")
                if paired:
                    d = paired[name][k][m] if name in paired else None
                    cells.append(
                        f"{d['mean']:+.{digits}f} [{d['ci'][0]:+.{digits}f}, {d['ci'][1]:+.{digits}f}]" if d else "—"
                    )
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
