"""The page of ``oscar toyworld eval``: the table, the plot, and rollouts under each condition beside the truth.

``write_eval_html(table, gt, conditions, path)`` writes ``path`` (e.g.
``table.html`` beside ``table.json``) and its media under
``<path stem>_media/``: for up to ``max_clips`` clips (every k-th evaluated
clip, so every embodiment shows), one row with the ground-truth video and each
condition's generated video (H.264 MP4, scaled up by an integer factor so a
64 x 64 clip is visible), each captioned with its PSNR, motion IoU and
object error from ``table["clips"]`` — the numbers of the table, not
recomputed. Filters by embodiment; videos load when scrolled to.

The page names the model behind each row: what ``oscar toyworld rollout``
recorded in the prediction folder's ``fingerprint.json`` (the model card's
name and the weights' identity, :func:`oscar_core._util.stage.model_identity`);
a folder without one (reconstructions, baselines, predictions from elsewhere)
says so.
"""

from __future__ import annotations

from pathlib import Path

from .._util.log import progress_bar
from ..metrics.report_html import browser_video, relative_url, render_page

__all__ = ["write_eval_html", "made_by", "MAX_CLIPS"]

#: Clips shown by default (the table covers them all; the page is for looking).
MAX_CLIPS = 12


def made_by(folder) -> dict:
    """``{"model": card name or None, "identity": weights' identity or None, "text": one line}`` of a prediction
    folder, read from the ``fingerprint.json`` that ``oscar toyworld rollout`` writes."""
    import json

    path = Path(folder) / "fingerprint.json"
    try:
        parts = json.loads(path.read_text()).get("parts", {})
    except (OSError, ValueError, AttributeError):
        parts = None
    if not isinstance(parts, dict) or parts.get("stage") != "toyworld-rollout":
        return {"model": None, "identity": None, "text": "no model recorded (not written by oscar toyworld rollout)"}
    card = parts.get("card") if isinstance(parts.get("card"), dict) else {}
    name, ident = card.get("name"), parts.get("model")
    cond = parts.get("condition")
    text = f"{name or 'unnamed model'}" + (f" ({ident})" if ident else "") + (f", {cond} skeleton" if cond else "")
    return {"model": name, "identity": ident, "text": text}


def write_eval_html(
    table: dict, gt_clipsets, conditions: dict[str, str], path, *, plot=None, max_clips: int = MAX_CLIPS
) -> Path:
    """Write the page for ``table`` (:func:`~oscar_core.toyworld.evaluate.evaluate_conditions`); returns its path.

    gt_clipsets: the clip set(s) the table was computed on; conditions: name →
    prediction folder (as given to ``evaluate_conditions``); plot: the PNG of
    :func:`~oscar_core.toyworld.evaluate.plot_table`, shown if given.
    """
    from ..metrics.video import load_video
    from ..train.clips import ClipSet
    from .evaluate import find_prediction
    from .rollouts import spread

    path = Path(path)
    media = path.parent / f"{path.stem}_media"
    sets = [ClipSet(g) for g in (gt_clipsets if isinstance(gt_clipsets, (list, tuple)) else [gt_clipsets])]
    owner = {r.id: (c, r) for c in sets for r in c}
    names = list(table["rows"])
    evaluated = sorted({cid for per in table["clips"].values() for cid in per})
    shown = spread(evaluated, max_clips)
    models = {name: made_by(conditions[name]) for name in names}
    clips = []
    for cid in progress_bar(shown, desc="toyworld eval: page videos", unit="clip"):
        cs, rec = owner[cid]
        gt = browser_video(cs.load(rec, skeleton=False).rgb, media / "ground_truth" / f"{cid}.mp4", fps=rec.fps)
        row = {"id": cid, "embodiment": rec.embodiment, "gt_url": relative_url(gt, path.parent), "cells": []}
        for name in names:
            m = table["clips"][name].get(cid)
            pred = find_prediction(conditions[name], cid) if m is not None else None
            url = None
            if pred is not None:
                out = browser_video(load_video(pred), media / name / f"{cid}.mp4", fps=rec.fps)
                url = relative_url(out, path.parent)
            row["cells"].append({"condition": name, "url": url, "metrics": m})
        clips.append(row)
    return render_page(
        path,
        "toyworld_eval.html.j2",
        generator="toyworld eval",
        title="oscar toyworld eval",
        table=table,
        names=names,
        clips=clips,
        n_evaluated=len(evaluated),
        models=models,
        model_names=sorted({m["model"] for m in models.values() if m["model"]}),
        embodiments=sorted({c["embodiment"] for c in clips}),
        plot_url=relative_url(plot, path.parent) if plot else None,
    )
