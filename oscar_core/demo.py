"""The main job on bundled defaults: render every embodiment's example."""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ._util.atomic import atomic_output, atomic_write_bytes
from .errors import OscarError
from .kinematics.trajectory import load_trajectory
from .media.video import write_video
from .plugin.registry import Registry
from .render.skeleton_video import render_skeleton_video

__all__ = ["run_demo", "contact_sheet"]


def contact_sheet(
    rows: list[np.ndarray],
    columns: int = 4,
    gap: int = 4,
    labels: list[str] | None = None,
    panels: list[Sequence[str] | None] | None = None,
) -> np.ndarray:
    """One PNG-ready image: per row, ``columns`` evenly spaced frames of a (T, H, W, 3) video.

    Rows of different sizes are placed on a grid of the largest frame size.
    labels: one name per row (the embodiment), written in a band left of the
    row's frames, centred on them; panels: per row None, or the names of the
    equal-width videos its frames hold side by side (e.g. rollout | ground
    truth | skeleton), written under each frame. Text goes only on the sheet:
    the frames themselves are copied untouched (no text in them).
    """
    import cv2

    H = max(r.shape[1] for r in rows)
    W = max(r.shape[2] for r in rows)
    font_scale = max(0.4, H / 288 * 0.7)
    font = cv2.FONT_HERSHEY_SIMPLEX
    panels = list(panels) if panels is not None else [None] * len(rows)
    if len(panels) != len(rows):
        raise ValueError(f"contact_sheet: expected {len(rows)} panel lists (one per row), found {len(panels)}")
    caption_h = cv2.getTextSize("Ag", font, font_scale * 0.8, 1)[0][1] + 2 * gap
    H = max([H] + [r.shape[1] + caption_h for r, p in zip(rows, panels) if p])
    band = 0
    if labels is not None:
        if len(labels) != len(rows):
            raise ValueError(f"contact_sheet: expected {len(rows)} labels (one per row), found {len(labels)}")
        band = max(cv2.getTextSize(t, font, font_scale, 1)[0][0] for t in labels) + 2 * gap
    sheet = np.full((len(rows) * (H + gap) + gap, band + columns * (W + gap) + gap, 3), 40, np.uint8)
    for i, video in enumerate(rows):
        picks = np.linspace(0, len(video) - 1, columns).round().astype(int)
        y = gap + i * (H + gap)
        for j, t in enumerate(picks):
            f = video[t]
            x = band + gap + j * (W + gap)
            sheet[y : y + f.shape[0], x : x + f.shape[1]] = f
            for k, name in enumerate(panels[i] or ()):  # centred under panel k of the frame
                (tw, th), _ = cv2.getTextSize(name, font, font_scale * 0.8, 1)
                cx = x + int((k + 0.5) * f.shape[1] / len(panels[i]))
                cv2.putText(
                    sheet,
                    name,
                    (cx - tw // 2, y + f.shape[0] + gap + th),
                    font,
                    font_scale * 0.8,
                    (230, 230, 230),
                    1,
                    cv2.LINE_AA,
                )
        if labels is not None:
            (tw, th), _ = cv2.getTextSize(labels[i], font, font_scale, 1)
            cv2.putText(
                sheet,
                labels[i],
                (gap, y + (video.shape[1] + th) // 2),
                font,
                font_scale,
                (230, 230, 230),
                1,
                cv2.LINE_AA,
            )
    return sheet


def _write_png(path: Path, image: np.ndarray) -> None:
    import cv2

    with atomic_output(path) as tmp:
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(image[..., ::-1])):
            raise OSError(f"could not encode {path}")


#: The videos side by side in the toy world's row (``toyworld.demo.side_by_side``'s order).
TOY_PANELS = ("rollout", "ground truth", "skeleton")


def _toy_world_row(out_dir: Path, toy_model, registry, rows, labels, panels, summary, log) -> None:
    """Add the toy world's rollout (rollout | ground truth | skeleton) as a video and a contact-sheet row."""
    from .toyworld.demo import toy_rollout_demo

    try:
        video, info = toy_rollout_demo(out_dir, toy_model, registry)
    except (OscarError, OSError, ValueError) as exc:
        summary["skipped"].append({"toy_world": str(toy_model), "reason": str(exc)})
        log(f"skipped the toy-world rollout: {exc}")
        return
    rows.append(video)
    labels.append("oscar-toy")
    panels.append(TOY_PANELS)
    summary["toy_world"] = info
    log(
        f"toy world: {info['model']} rolled out on held-out episode {info['episode']} in {info['rollout_seconds']:.1f} s "
        f"(PSNR {info['psnr_db']:.1f} dB) -> {info['path']} (rollout | ground truth | skeleton)"
    )


def run_demo(
    out_dir: str | Path,
    size: tuple[int, int] = (512, 288),
    registry: Registry | None = None,
    names: list[str] | None = None,
    log=print,
    toy_model: str | None = "oscar-toy",
) -> dict:
    """Render each embodiment's bundled example to ``out_dir/<name>.mp4`` plus ``contact_sheet.png``.

    toy_model: also roll this toy-world model (zoo name or folder) out on a
    held-out episode (``toyworld_rollout.mp4`` + a contact-sheet row); None
    skips it.

    Returns a summary dict (also written as ``out_dir/summary.json``).
    """
    registry = registry or Registry()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows, labels, panels, summary = [], [], [], {"size": list(size), "videos": [], "skipped": []}
    for failure in registry.failures:
        summary["skipped"].append(
            {"plugin": failure.plugin, "distribution": failure.distribution, "reason": failure.error}
        )
        log(f"skipped plugin {failure.plugin} ({failure.distribution}): {failure.error}")
    for name in names or registry.names():
        try:
            emb = registry.get(name)
        except OscarError as exc:
            summary["skipped"].append({"embodiment": name, "reason": str(exc)})
            log(f"skipped {name}: {exc}")
            continue
        if emb.example_trajectory is None or emb.example_camera is None:
            summary["skipped"].append({"embodiment": name, "reason": "no bundled example"})
            log(f"skipped {name}: no bundled example")
            continue
        traj = load_trajectory(emb.example_trajectory)
        cam = emb.load_camera(emb.example_camera)
        t0 = time.perf_counter()
        video = render_skeleton_video(emb, traj, cam, size, camera_source=str(emb.example_camera))
        t_render = time.perf_counter() - t0
        path = write_video(out_dir / f"{name}.mp4", video, traj.fps)
        rows.append(video)
        labels.append(name)
        panels.append(None)
        summary["videos"].append(
            {"embodiment": name, "path": str(path), "frames": len(video), "render_seconds": round(t_render, 4)}
        )
        log(f"{name}: {len(video)} frames -> {path} (rendered in {t_render * 1000:.0f} ms)")
    if not rows:
        raise RuntimeError(f"no embodiment with a bundled example; registered: {registry.names()}")
    if toy_model:
        _toy_world_row(out_dir, toy_model, registry, rows, labels, panels, summary, log)
    sheet_path = out_dir / "contact_sheet.png"
    _write_png(sheet_path, contact_sheet(rows, labels=labels, panels=panels))
    summary["contact_sheet"] = str(sheet_path)
    atomic_write_bytes(out_dir / "summary.json", json.dumps(summary, indent=2).encode())
    log(f"contact sheet -> {sheet_path}")
    return summary
