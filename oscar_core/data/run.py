"""The stages as functions of a run folder: what ``oscar data …`` calls, and what Python users call.

A run folder (local path or fsspec URL) holds one sub-folder per stage
(``ingest/``, ``filter/``, ``dedup/``, ``caption/``, ``export/``), each with its
shards, completion records and ``manifest.parquet`` (see
:mod:`oscar_core.data.engine`). Each stage reads the manifest of the last
finished stage before it — so ``export`` right after ``filter`` works — and
writes its own; a re-run skips what is done.

Each stage records its fingerprint (:mod:`oscar_core.data.engine`): its
input stage's fingerprint and episode ids, its effective settings (filter
thresholds; dedup's frames, steps and thresholds; caption's model and frame
sampling; export's ``--out``, ``--size``, codec and skeleton option), the
model (SigLIP's name and revision) and a format version. A stage re-run with
other settings is computed again; a later stage made from an input that has
since been recomputed is *stale*: reading it raises :class:`StaleStage`
naming the stage, what changed and the command that redoes it.
"""

from __future__ import annotations

import hashlib
import json
import os
from typing import Any

from .._util import stage as _stage
from . import _fs
from .engine import StageRun, read_fingerprint, read_stage, run_sharded, stage_parts, use_fingerprint
from .manifest import rows_to_parquet
from .stats import latest_stage

__all__ = [
    "run_ingest",
    "run_filter",
    "run_dedup",
    "run_caption",
    "run_export",
    "input_rows",
    "StaleStage",
    "stale_reason",
]


class StaleStage(_stage.StageChanged):
    """A finished stage was made from an input stage that has since been computed again under other settings."""


def stale_reason(run: str, stage: str) -> str | None:
    """Why ``RUN/stage`` no longer matches the stages it was made from (None: it matches, or has no record).

    Follows the chain of recorded inputs: a stage is stale when its input
    stage's fingerprint is no longer the one it recorded, or that stage is stale.
    """
    seen = set()
    while stage not in seen:
        seen.add(stage)
        mine = read_fingerprint(_fs.join(run, stage))
        src = ((mine or {}).get("parts") or {}).get("input") or {}
        prev = src.get("stage")
        if not prev:
            return None
        theirs = read_fingerprint(_fs.join(run, prev))
        if theirs is None or theirs["fingerprint"] != src.get("fingerprint"):
            return (
                f"{stage} was made from a '{prev}' output that has since been computed again "
                f"(under other inputs or settings)"
            )
        stage = prev
    return None


def input_rows(run: str, stage: str) -> tuple[str, list[dict]]:
    """(stage read, its rows): the last finished stage before ``stage``; ValueError naming the run when none,
    :class:`StaleStage` naming the command to re-run when that stage is stale."""
    prev = latest_stage(run, before=stage)
    if prev is None:
        raise ValueError(
            f"{run}: expected a finished stage before '{stage}' (run `oscar data ingest` first), found none"
        )
    why = stale_reason(run, prev)
    if why is not None:
        raise StaleStage(
            f"{_fs.join(run, prev)}: expected an input for '{stage}' made from the current earlier "
            f"stages, found a stale one ({why}); run `oscar data {prev} {run} …` again (it recomputes "
            f"with the settings you give it) or delete {_fs.join(run, prev)}"
        )
    return prev, read_stage(_fs.join(run, prev))


def _input(run: str, prev: str) -> dict[str, Any]:
    fp = read_fingerprint(_fs.join(run, prev))
    return {"stage": prev, "fingerprint": fp["fingerprint"] if fp else None}


def _opts(kw: dict[str, Any]) -> dict[str, Any]:
    return {k: kw[k] for k in ("engine", "workers", "shard_size", "progress") if k in kw}


def run_ingest(
    source: str, reader: str, run: str, *, plugin_paths: tuple[str, ...] = (), reader_options: dict | None = None, **kw
) -> StageRun:
    """List ``source`` with ``reader`` (built with ``reader_options``) and probe every episode into ``RUN/ingest``."""
    from .ingest import IngestStage, list_rows

    rows = list_rows(source, reader, tuple(plugin_paths), reader_options)
    if not rows:
        raise ValueError(f"{source}: expected episodes for reader {reader!r}, found none")
    listing = hashlib.sha256(json.dumps(rows, sort_keys=True, default=str).encode()).hexdigest()[:16]
    parts = stage_parts(
        "ingest",
        input={"source": str(source), "reader": reader, "listing": listing},
        settings={"plugin_paths": list(plugin_paths), "reader_options": dict(reader_options or {})},
    )
    return run_sharded(
        IngestStage(tuple(plugin_paths)), rows, _fs.join(run, "ingest"), desc="ingest", parts=parts, **_opts(kw)
    )


def run_filter(run: str, config=None, *, plugin_paths: tuple[str, ...] = (), **kw) -> StageRun:
    from .filters import FilterConfig, FilterStage

    prev, rows = input_rows(run, "filter")
    stage = FilterStage(config or FilterConfig(), tuple(plugin_paths))
    url = _fs.join(run, "filter")
    parts = stage_parts(
        "filter", input=_input(run, prev), settings={**stage.config.to_dict(), "plugin_paths": list(plugin_paths)}
    )
    res = run_sharded(stage, rows, url, desc="filter", parts=parts, **_opts(kw))
    # config.json names the thresholds of the verdicts now in the stage (after a recompute, never before)
    _fs.write_bytes_atomic(_fs.join(url, "config.json"), json.dumps(stage.config.to_dict()).encode())
    return res


def run_dedup(run: str, embedder, config=None, *, plugin_paths: tuple[str, ...] = (), **kw) -> tuple[StageRun, dict]:
    """Embed every live episode (sharded, resumable), then find, verify and merge duplicates into ``RUN/dedup``."""

    from .dedup import DedupConfig, EmbedStage, dedup_rows

    cfg = config or DedupConfig()
    prev, rows = input_rows(run, "dedup")
    url = _fs.join(run, "dedup")
    # a model that cannot be found or loaded fails here, before any episode (nothing is recorded as done)
    model = embedder.identity() if hasattr(embedder, "identity") else {"model": type(embedder).__qualname__}
    src = _input(run, prev)
    embed_parts = stage_parts(
        "dedup-embed",
        input=src,
        model=model,
        settings={"frames": cfg.frames, "steps": cfg.steps, "plugin_paths": list(plugin_paths)},
    )
    use_fingerprint(
        url,
        stage_parts("dedup", input=src, model=model, settings={**cfg.__dict__, "plugin_paths": list(plugin_paths)}),
        clear=("summary.json",),
    )
    res = run_sharded(
        EmbedStage(embedder, cfg, tuple(plugin_paths)),
        rows,
        _fs.join(url, "embed"),
        desc="dedup embed",
        parts=embed_parts,
        **_opts(kw),
    )
    out, summary = dedup_rows(res.table, cfg)
    _fs.write_bytes_atomic(_fs.join(url, "summary.json"), json.dumps(summary).encode())
    _fs.write_bytes_atomic(_fs.join(url, "manifest.parquet"), rows_to_parquet(out))
    res.table, res.rows = None, out
    return res, summary


def run_caption(run: str, config, *, plugin_paths: tuple[str, ...] = (), **kw) -> StageRun:
    """Caption every live episode through ``config``'s endpoint; a budget defers the rest to the next run."""
    from .caption import CaptionStage, plan_budget

    prev, rows = input_rows(run, "caption")
    url = _fs.join(run, "caption")
    cache = _fs.join(url, "cache")  # kept across recomputes: its keys carry the request's own fingerprint
    allowed = plan_budget(rows, config, cache)
    if allowed:  # requests to send: a down endpoint fails the stage now, not every episode after its retries
        from .caption import check_endpoint

        check_endpoint(config.base_url, min(float(config.timeout), 10.0))
    parts = stage_parts(
        "caption", input=_input(run, prev), settings={**config.key_fields(), "plugin_paths": list(plugin_paths)}
    )
    return run_sharded(
        CaptionStage(config, cache, allowed, tuple(plugin_paths)), rows, url, desc="caption", parts=parts, **_opts(kw)
    )


def run_export(
    run: str,
    out: str,
    *,
    size=None,
    render_skeleton: bool = False,
    video_codec: str = "ffv1",
    plugin_paths: tuple[str, ...] = (),
    **kw,
) -> StageRun:
    """Write every live episode as a training clip into the clip set ``out`` (a local folder or an fsspec URL)."""
    from .engine import check_workers_see
    from .export import ExportStage

    check_workers_see(out, kw.get("engine", "local"), kw.get("workers"))
    prev, rows = input_rows(run, "export")
    if size:  # refuse a --size no episode fits in memory at before any work (--size 100000x100000: 447 GiB)
        from .._util.memory import check_fits
        from .manifest import is_alive

        longest = max((int(r.get("length") or 0) for r in rows if is_alive(r)), default=0)
        check_fits(
            (max(longest, 1), int(size[1]), int(size[0]), 3),
            1,
            "the longest live episode at --size (T, H, W, 3) uint8",
            "use a smaller --size",
        )
    out = str(out)
    where = os.path.abspath(_fs.local_path(out)) if _fs.is_local(out) else out
    if _fs.is_local(out):
        from .._util.atomic import sweep_dead_temporaries

        sweep_dead_temporaries(where)  # shard folders of killed exports
    stage = ExportStage(out, tuple(size) if size else None, render_skeleton, video_codec, tuple(plugin_paths))
    parts = stage_parts(
        "export",
        input=_input(run, prev),
        settings={
            "out": where,
            "size": list(size) if size else None,
            "render_skeleton": render_skeleton,
            "video_codec": video_codec,
            "plugin_paths": list(plugin_paths),
        },
    )
    return run_sharded(stage, rows, _fs.join(run, "export"), desc="export", parts=parts, **_opts(kw))
