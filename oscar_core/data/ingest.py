"""``ingest``: list a source's episodes into rows, then probe each one (load it, decode its first and last frame).

A broken episode (missing file or field, NaN states, lengths that disagree,
a truncated or unreadable video) gets ``ingest_status = "rejected"`` with
``ingest_reason = "unreadable: <the reader's message>"``; the run goes on.
The probe measures ``length``/``fps`` (from the trajectory), ``width``/
``height`` (of the video) and sets ``camera``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from ._episode import EPISODE_ERRORS, load_row, reason_of
from .manifest import ref_to_row

__all__ = ["list_rows", "IngestStage"]


def list_rows(
    source: str, reader_name: str, plugin_paths: tuple[str, ...] = (), reader_options: dict[str, Any] | None = None
) -> list[dict[str, Any]]:
    """Base manifest rows of every episode the reader lists under ``source``, sorted by id.

    reader_options: the reader's constructor keywords (``--reader-option``),
    checked against its signature before listing and kept in every row's
    ``reader_options`` column (JSON) for the later stages.
    """
    from ._episode import registry
    from .reader_options import check_reader_options

    reg = registry(tuple(plugin_paths))
    entry = reg.reader_entries.get(reader_name)  # an unknown name: get_reader's error lists the registered ones
    options = check_reader_options(entry.cls, dict(reader_options or {})) if entry is not None else {}
    reader = reg.get_reader(reader_name, options)
    stored = json.dumps(options, sort_keys=True) if options else None
    rows = [dict(ref_to_row(ref), reader_options=stored) for ref in reader.list_episodes(source)]
    rows.sort(key=lambda r: r["id"])
    return rows


@dataclass(frozen=True)
class IngestStage:
    """Probe episodes: ``fn(rows, shard=...) -> rows`` with the ``ingest_*`` columns filled in."""

    plugin_paths: tuple[str, ...] = ()
    name: str = "ingest"

    def __call__(self, rows: list[dict], shard: str = "") -> list[dict]:
        return [self.one(r) for r in rows]

    def one(self, row: dict) -> dict:
        out = dict(row, ingest_status="ok", ingest_reason=None, ingest_value=None, width=None, height=None)
        try:
            ep, _ = load_row(row, self.plugin_paths)
            out.update(length=int(ep.n_frames), fps=float(ep.trajectory.fps), camera=ep.camera_name)
            if ep.video is None:
                raise ValueError(f"{row['id']}: field 'video': expected a video, found none")
            if abs(ep.video.n_frames - ep.n_frames) > 0:
                raise ValueError(
                    f"{ep.video.path}: expected {ep.n_frames} video frames (one per state), found {ep.video.n_frames}"
                )
            frames = ep.video.read([0, ep.video.n_frames - 1])
            out.update(height=int(frames.shape[1]), width=int(frames.shape[2]))
            out["ingest_value"] = float(ep.n_frames)
        except EPISODE_ERRORS as exc:
            out.update(ingest_status="rejected", ingest_reason=f"unreadable: {reason_of(exc)}")
        return out
