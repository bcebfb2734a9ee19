"""``OUT/report.html`` of ``oscar eval run``: the evaluation as a page a person looks at.

What it shows (all read from ``report.json``'s dictionary, so page and JSON
agree): the per-policy table (real and world-model success rate, mean partial
score, Bradley–Terry Elo), the rankings of the world model against the real
ones with their fidelity figures (MMRV, Spearman ρ, Pearson r, SISR_Δ), the
plots, and per session one card per policy: its rollout playing beside the
real outcome, the judge's verdict, partial score and reason, then the
session's pairwise preferences. Filters by session, policy and verdict; videos
load only when scrolled to (``preload="none"`` and an IntersectionObserver),
so hundreds of cells stay usable.

Media (:func:`oscar_core.metrics.report_html.browser_video`): the lossless rollouts
(``rollouts/<session>/<policy>.mkv``, FFV1, which no browser plays) and the
manifest's real videos are re-encoded once to H.264 MP4 under
``OUT/media/rollouts/…`` and ``OUT/media/real/…``; the page links them
relatively, so the folder can be moved or zipped whole.
"""

from __future__ import annotations

import json
from pathlib import Path

from .._util.log import get_logger, progress_bar
from ..metrics.report_html import browser_video, relative_url, render_page
from .manifest import Manifest

__all__ = ["write_html_report", "media_path"]

_log = get_logger(__name__)


def media_path(out: Path, video: str, kind: str) -> Path:
    """Where the browser copy of record video ``video`` (relative to ``out``) goes: ``out/media/<kind>/…mp4``."""
    rel = Path(video)
    if rel.parts and rel.parts[0] == "rollouts":
        rel = Path(*rel.parts[1:])
    return Path(out) / "media" / kind / rel.with_suffix(".mp4")


def _verdict(cell: dict) -> str:
    if cell["wm_success"] is None:
        return "none"
    return "success" if cell["wm_success"] else "failure"


def write_html_report(out, report: dict, manifest: Manifest, records: list[dict], *, plots=(), sheets=None,
                      progress: bool = True) -> Path:
    """Write ``out/report.html`` (and its browser media) for ``report`` (:func:`~.report.build_report`).

    plots: paths of PNG/SVG plots to show; sheets: ``{session: path}`` of the
    contact sheets. A real video that cannot be read is left out of its card
    with a warning (the rollout still shows). Returns the page's path.
    """
    out = Path(out)
    cells_by_id = {c.id: c for c in manifest.cells}
    fps_by_cell = {r["cell"]: r.get("fps") for r in records}
    sessions: dict[str, dict] = {}
    bar = progress_bar(report["cells"], desc="report.html: videos", unit="cell", enabled=progress)
    for cell in bar:
        src = out / cell["video"]
        rollout = browser_video(src, media_path(out, cell["video"], "rollouts"), fps=fps_by_cell.get(cell["cell"]))
        real_url = None
        mcell = cells_by_id.get(cell["cell"])
        if mcell is not None and mcell.real_video is not None:
            try:
                real = browser_video(mcell.real_video, media_path(out, cell["video"], "real"))
                real_url = relative_url(real, out)
            except (OSError, ValueError) as exc:  # MetricInputError is a ValueError
                _log.warning("report.html: cell %s: cannot read the real video %s: %s", cell["cell"],
                             mcell.real_video, exc)
        s = sessions.setdefault(cell["session"], {"name": cell["session"], "task": cell.get("task"), "cells": [],
                                                  "pairs": [], "sheet_url": None})
        s["cells"].append({**cell, "verdict": _verdict(cell), "rollout_url": relative_url(rollout, out),
                           "real_url": real_url})
    session_of = {c["cell"]: c["session"] for c in report["cells"]}
    for p in report["pairs"]:
        s = sessions.get(session_of.get(p["clip_a"]))
        if s is not None:
            s["pairs"].append(p)
    for name, path in (sheets or {}).items():
        if name in sessions and Path(path).is_file():
            sessions[name]["sheet_url"] = relative_url(path, out)
    judge = report.get("judge")
    judge_text = None
    if judge:
        judge_text = judge.get("name") or judge.get("model") if isinstance(judge, dict) else None
        judge_text = judge_text or json.dumps(judge)[:200]
    return render_page(out / "report.html", "eval_run.html.j2", generator="eval run",
                       title=f"oscar eval run — {report['model']}", report=report, judge_text=judge_text,
                       sessions=list(sessions.values()), policy_names=[p["policy"] for p in report["policies"]],
                       n_cells=len(report["cells"]),
                       plots=[{"name": Path(p).stem, "url": relative_url(p, out)} for p in plots
                              if Path(p).suffix.lower() in (".png", ".svg")])
