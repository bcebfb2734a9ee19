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


def _mmrv_max(report: dict) -> float | None:
    """The largest rank-form MMRV for the compared policies (shown beside its definition), None without a comparison."""
    from ..metrics.policy import mmrv_rank_max

    comp = report.get("comparison")
    return mmrv_rank_max(len(comp["policies"])) if comp else None


def _verdict(cell: dict) -> str:
    if cell["wm_success"] is None:
        return "none"
    return "success" if cell["wm_success"] else "failure"


def _media(
    source, dest: Path, page_dir: Path, *, expected: int | None = None, fps: float | None = None
) -> tuple[str | None, str | None]:
    """The browser copy of video ``source`` and what is wrong with it: ``(url or None, problem or None)``.

    A missing or unreadable file, or one without frames, gives no url and says why; a video with fewer
    frames than ``expected`` (a truncated file) keeps its url and says how many frames it holds.
    """
    from ..media.video import video_info

    src = Path(source)
    if not src.exists():
        return None, f"missing: {src} does not exist"
    try:
        copy = browser_video(src, dest, fps=fps)
        n = int(video_info(copy)["frames"])
    except (OSError, ValueError) as exc:  # MetricInputError is a ValueError
        return None, f"unreadable: {exc}"
    if n == 0:
        return None, f"{src} holds no frames"
    url = relative_url(copy, page_dir)
    if expected is not None and n < expected:
        return url, f"truncated: {src} holds {n} of the {expected} frames the rollout made"
    return url, None


def write_html_report(
    out,
    report: dict,
    manifest: Manifest,
    records: list[dict],
    *,
    plots=(),
    sheets=None,
    progress: bool = True,
    generator: str = "eval run",
    closed_loop: dict | None = None,
) -> Path:
    """Write ``out/report.html`` (and its browser media) for ``report`` (:func:`~.report.build_report`).

    plots: paths of PNG/SVG plots to show; sheets: ``{session: path}`` of the
    contact sheets. A rollout or real video that is missing, unreadable or
    truncated is checked here and named on its card (and in a warning); a
    real video that cannot be read is dropped from its card, which says so.
    The page's script also names on its card any video the browser then fails
    to play. generator: the command named on the page; closed_loop: a closed-loop run's own report
    (:func:`~.closed_loop_report.build_closed_loop_report`), shown above the rankings: what the world generates
    and what the other views receive, the ranking with per-cell clipped actions, failures with their reasons and
    the policies' latency, and the fidelity figures' session intervals. Returns the page's path.
    """
    out = Path(out)
    cells_by_id = {c.id: c for c in manifest.cells}
    fps_by_cell = {r["cell"]: r.get("fps") for r in records}
    sessions: dict[str, dict] = {}
    bar = progress_bar(report["cells"], desc="report.html: videos", unit="cell", enabled=progress)
    for cell in bar:
        rollout_url, rollout_problem = _media(
            out / cell["video"],
            media_path(out, cell["video"], "rollouts"),
            out,
            expected=cell.get("frames"),
            fps=fps_by_cell.get(cell["cell"]),
        )
        if rollout_problem:
            _log.warning("report.html: cell %s: rollout video %s: %s", cell["cell"], cell["video"], rollout_problem)
        real_url = real_problem = None
        mcell = cells_by_id.get(cell["cell"])
        if mcell is not None and mcell.real_video is not None:
            real_url, real_problem = _media(mcell.real_video, media_path(out, cell["video"], "real"), out)
            if real_problem:
                _log.warning("report.html: cell %s: real video %s: %s", cell["cell"], mcell.real_video, real_problem)
        s = sessions.setdefault(
            cell["session"],
            {"name": cell["session"], "task": cell.get("task"), "cells": [], "pairs": [], "sheet_url": None},
        )
        s["cells"].append(
            {
                **cell,
                "verdict": _verdict(cell),
                "rollout_url": rollout_url,
                "rollout_problem": rollout_problem,
                "real_url": real_url,
                "real_problem": real_problem,
            }
        )
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
    return render_page(
        out / "report.html",
        "eval_run.html.j2",
        generator=generator,
        title=f"oscar {generator} — {report['model']}",
        closed_loop=closed_loop,
        report=report,
        judge_text=judge_text,
        sessions=list(sessions.values()),
        policy_names=[p["policy"] for p in report["policies"]],
        n_cells=len(report["cells"]),
        mmrv_max=_mmrv_max(report),
        plots=[
            {"name": Path(p).stem, "url": relative_url(p, out)}
            for p in plots
            if Path(p).suffix.lower() in (".png", ".svg")
        ],
    )
