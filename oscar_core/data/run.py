"""The stages as functions of a run folder: what ``oscar data …`` calls, and what Python users call.

A run folder (local path or fsspec URL) holds one sub-folder per stage
(``ingest/``, ``filter/``, ``dedup/``, ``caption/``, ``export/``), each with its
shards, completion records and ``manifest.parquet`` (see
:mod:`oscar_core.data.engine`). Each stage reads the manifest of the last
finished stage before it — so ``export`` right after ``filter`` works — and
writes its own; a re-run skips what is done.
"""

from __future__ import annotations

import json
from typing import Any

from . import _fs
from .engine import StageRun, read_stage, run_sharded
from .manifest import rows_to_parquet
from .stats import latest_stage

__all__ = ["run_ingest", "run_filter", "run_dedup", "run_caption", "run_export", "input_rows"]


def input_rows(run: str, stage: str) -> tuple[str, list[dict]]:
    """(stage read, its rows): the last finished stage before ``stage``; ValueError naming the run when none."""
    prev = latest_stage(run, before=stage)
    if prev is None:
        raise ValueError(f"{run}: expected a finished stage before '{stage}' (run `oscar data ingest` first), found none")
    return prev, read_stage(_fs.join(run, prev))


def _opts(kw: dict[str, Any]) -> dict[str, Any]:
    return {k: kw[k] for k in ("engine", "workers", "shard_size", "progress") if k in kw}


def run_ingest(source: str, reader: str, run: str, *, plugin_paths: tuple[str, ...] = (),
               reader_options: dict | None = None, **kw) -> StageRun:
    """List ``source`` with ``reader`` (built with ``reader_options``) and probe every episode into ``RUN/ingest``."""
    from .ingest import IngestStage, list_rows

    rows = list_rows(source, reader, tuple(plugin_paths), reader_options)
    if not rows:
        raise ValueError(f"{source}: expected episodes for reader {reader!r}, found none")
    return run_sharded(IngestStage(tuple(plugin_paths)), rows, _fs.join(run, "ingest"), desc="ingest", **_opts(kw))


def run_filter(run: str, config=None, *, plugin_paths: tuple[str, ...] = (), **kw) -> StageRun:
    from .filters import FilterConfig, FilterStage

    _, rows = input_rows(run, "filter")
    stage = FilterStage(config or FilterConfig(), tuple(plugin_paths))
    url = _fs.join(run, "filter")
    _fs.write_bytes_atomic(_fs.join(url, "config.json"), json.dumps(stage.config.to_dict()).encode())
    return run_sharded(stage, rows, url, desc="filter", **_opts(kw))


def run_dedup(run: str, embedder, config=None, *, plugin_paths: tuple[str, ...] = (), **kw) -> tuple[StageRun, dict]:
    """Embed every live episode (sharded, resumable), then find, verify and merge duplicates into ``RUN/dedup``."""

    from .dedup import DedupConfig, EmbedStage, dedup_rows

    cfg = config or DedupConfig()
    _, rows = input_rows(run, "dedup")
    url = _fs.join(run, "dedup")
    res = run_sharded(EmbedStage(embedder, cfg, tuple(plugin_paths)), rows, _fs.join(url, "embed"), desc="dedup embed",
                      **_opts(kw))
    out, summary = dedup_rows(res.table, cfg)
    _fs.write_bytes_atomic(_fs.join(url, "summary.json"), json.dumps(summary).encode())
    _fs.write_bytes_atomic(_fs.join(url, "manifest.parquet"), rows_to_parquet(out))
    res.table, res.rows = None, out
    return res, summary


def run_caption(run: str, config, *, plugin_paths: tuple[str, ...] = (), **kw) -> StageRun:
    """Caption every live episode through ``config``'s endpoint; a budget defers the rest to the next run."""
    from .caption import CaptionStage, plan_budget

    _, rows = input_rows(run, "caption")
    url = _fs.join(run, "caption")
    cache = _fs.join(url, "cache")
    allowed = plan_budget(rows, config, cache)
    return run_sharded(CaptionStage(config, cache, allowed, tuple(plugin_paths)), rows, url, desc="caption", **_opts(kw))


def run_export(run: str, out: str, *, size=None, render_skeleton: bool = False, video_codec: str = "ffv1",
               plugin_paths: tuple[str, ...] = (), **kw) -> StageRun:
    """Write every live episode as a training clip into the clip set ``out`` (a local folder or an fsspec URL)."""
    from .engine import check_workers_see
    from .export import ExportStage

    check_workers_see(out, kw.get("engine", "local"), kw.get("workers"))
    _, rows = input_rows(run, "export")
    if size:  # refuse a --size no episode fits in memory at before any work (--size 100000x100000: 447 GiB)
        from .._memory import check_fits
        from .manifest import is_alive

        longest = max((int(r.get("length") or 0) for r in rows if is_alive(r)), default=0)
        check_fits((max(longest, 1), int(size[1]), int(size[0]), 3), 1,
                   "the longest live episode at --size (T, H, W, 3) uint8", "use a smaller --size")
    stage = ExportStage(str(out), tuple(size) if size else None, render_skeleton, video_codec, tuple(plugin_paths))
    return run_sharded(stage, rows, _fs.join(run, "export"), desc="export", **_opts(kw))
