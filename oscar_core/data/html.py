"""``RUN/stats.html`` of ``oscar data stats``: the funnel of a run, with a few thumbnails per rejection reason.

The page shows the numbers of ``stats.json`` (:func:`~oscar_core.data.stats.compute_stats`):
public episodes, each rejection column (``stage:filter``) as a bar, the kept
ones, then the per source × embodiment table; and for every rejection column
(and for the kept episodes) up to :data:`THUMBS` examples: the episode's
middle frame (``RUN/stats_media/<column>/<k>.png``), its id and the full
reason with the measured value. An episode whose video cannot be read shows
its reason without a picture. Filters by column.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from .._util.log import get_logger
from ..metrics.report_html import browser_image, relative_url, render_page
from . import _fs
from .engine import read_stage
from .stats import column_of

__all__ = ["write_stats_html", "THUMBS"]

#: Example episodes shown per rejection column.
THUMBS = 3
_log = get_logger(__name__)


def _examples(run: str, stage: str | None, n: int) -> dict[str, list[dict[str, Any]]]:
    """column (or "kept") → up to n final-stage rows, in manifest order."""
    out: dict[str, list[dict[str, Any]]] = {}
    if stage is None:
        return out
    for row in read_stage(_fs.join(run, stage)):
        col = column_of(row) or "kept"
        if len(out.setdefault(col, [])) < n:
            out[col].append(row)
    return out


def _thumb(row: dict[str, Any], dest: Path, plugin_paths) -> bool:
    from ._episode import EPISODE_ERRORS, load_row

    try:
        ep, _ = load_row(row, tuple(plugin_paths))
        if ep.video is None:
            return False
        frame = ep.video.read([ep.video.n_frames // 2])[0]
    except EPISODE_ERRORS as exc:
        _log.debug("stats.html: no thumbnail for %s: %s", row["id"], exc)
        return False
    browser_image(frame, dest)
    return True


def _reason(row: dict[str, Any]) -> str:
    from .manifest import rejection

    rej = rejection(row)
    if rej is None:
        return ""
    stage, reason = rej
    value = row.get(f"{stage}_value")
    return f"{stage}: {reason}" + (f" (measured {value:.4g})" if isinstance(value, (int, float)) else "")


def write_stats_html(stats: dict[str, Any], run: str, *, thumbs: int = THUMBS, plugin_paths=()) -> Path | None:
    """Write ``run/stats.html`` for ``stats``; returns its path (None for a remote run: the page is for a disk)."""
    if "://" in str(run) and not str(run).startswith("file://"):
        _log.info("stats.html: not written for the remote run %s (copy the run to a disk to look at it)", run)
        return None
    folder = Path(str(run).removeprefix("file://"))
    media = folder / "stats_media"
    examples = []
    for col in [*stats["columns"], "kept"]:
        items = []
        for k, row in enumerate(_examples(str(folder), stats["stage"], thumbs).get(col, [])):
            dest = media / re.sub(r"[^A-Za-z0-9_.-]+", "_", col) / f"{k}.png"
            has = _thumb(row, dest, plugin_paths)
            items.append(
                {
                    "id": row["id"],
                    "reason": _reason(row),
                    "task": row.get("task"),
                    "url": relative_url(dest, folder) if has else None,
                }
            )
        examples.append({"column": col, "episodes": items})
    public = stats["total"]["public"] or 1
    return render_page(
        folder / "stats.html",
        "data_stats.html.j2",
        generator="data stats",
        title=f"oscar data stats — {folder.name}",
        stats=stats,
        examples=examples,
        public=public,
    )
