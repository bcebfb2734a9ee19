"""The episode manifest: one row per source episode, one parquet table per stage.

Base columns (written by ``ingest`` from the reader's :class:`EpisodeRef`):

=============  ===========================================================
id             ``"<source>/<native id>"``, unique in a run
source         dataset name (``droid``, ``egodex``, …)
reader         reader name (``--reader``)
embodiment     embodiment plugin name
length         frames (from metadata at listing; measured at ingest)
fps            frames per second
cameras        camera names available (list of strings)
camera         the camera the episode is rendered from (set at ingest)
task           the dataset's task text, or null
paths          JSON object: role → path or URL of the episode's files
meta           JSON object: reader-specific small values
=============  ===========================================================

Each stage adds its own columns, always ``<stage>_status`` (``ok``,
``rejected``, or for captions ``deferred``/``failed``), ``<stage>_reason``
(why, null when ok) and ``<stage>_value`` (the measured value that decided,
null when none), plus stage-specific ones (``filter_<name>`` per filter,
``dedup_group``, ``caption``, ``export_clip`` …). A rejected row is carried
through later stages unchanged, so the last stage's table holds every
episode and ``stats`` counts from it.
"""

from __future__ import annotations

import io
import json
from collections.abc import Iterable
from typing import Any

from .._util.optional import require
from ..plugin.reader import EpisodeRef

__all__ = [
    "STAGES",
    "BASE_COLUMNS",
    "ref_to_row",
    "row_to_ref",
    "rows_to_parquet",
    "rows_from_parquet",
    "table_from_parquet",
    "table_to_parquet",
    "is_alive",
    "rejection",
]

STAGES = ("ingest", "filter", "dedup", "caption", "export")
BASE_COLUMNS = ("id", "source", "reader", "embodiment", "length", "fps", "cameras", "camera", "task", "paths", "meta")


def ref_to_row(ref: EpisodeRef) -> dict[str, Any]:
    """The base columns of one episode."""
    return {
        "id": ref.episode_id,
        "source": ref.source,
        "reader": ref.reader,
        "embodiment": ref.embodiment,
        "length": None if ref.n_frames is None else int(ref.n_frames),
        "fps": None if ref.fps is None else float(ref.fps),
        "cameras": list(ref.cameras),
        "camera": None,
        "task": ref.task,
        "paths": json.dumps(dict(ref.paths), sort_keys=True),
        "meta": json.dumps(ref.meta, sort_keys=True),
    }


def row_to_ref(row: dict[str, Any]) -> EpisodeRef:
    """Rebuild the reader's :class:`EpisodeRef` from a manifest row."""
    return EpisodeRef(
        episode_id=row["id"],
        source=row["source"],
        reader=row["reader"],
        embodiment=row["embodiment"],
        paths=json.loads(row["paths"]),
        n_frames=row.get("length"),
        fps=row.get("fps"),
        task=row.get("task"),
        cameras=tuple(row.get("cameras") or ()),
        meta=json.loads(row.get("meta") or "{}"),
    )


def is_alive(row: dict[str, Any]) -> bool:
    """True when no stage has rejected (or deferred, or failed) the episode."""
    return all(v in (None, "ok") for k, v in row.items() if k.endswith("_status"))


def rejection(row: dict[str, Any]) -> tuple[str, str] | None:
    """(stage, reason) of the first stage that did not pass the episode, or None."""
    for stage in STAGES:
        status = row.get(f"{stage}_status")
        if status not in (None, "ok"):
            return stage, row.get(f"{stage}_reason") or status
    return None


def rows_to_parquet(rows: Iterable[dict[str, Any]]) -> bytes:
    """Parquet bytes of rows (dicts of plain values; columns are the union, missing values null)."""
    pa = require("pyarrow", "data")
    import pyarrow.parquet as pq

    rows = list(rows)
    names: list[str] = []
    for r in rows:
        for k in r:
            if k not in names:
                names.append(k)
    table = pa.Table.from_pylist([{k: r.get(k) for k in names} for r in rows]) if rows else pa.table({})
    buf = io.BytesIO()
    pq.write_table(table, buf)
    return buf.getvalue()


def _arrow_owned(pa, data: bytes):
    """A copy of ``data`` in memory pyarrow owns (no reference back to the Python object).

    ``pq.read_table`` on a Python object (``io.BytesIO``, or a buffer that wraps
    ``bytes``) leaves read-ahead work on pyarrow's I/O threads after it returns;
    when that work ends during interpreter shutdown it drops its last reference
    to the Python buffer, which needs the GIL, and the thread is torn down inside
    a C++ destructor: ``terminate called without an active exception``, exit 134
    after the stage had finished (apache/arrow#33975). An arrow-owned copy read
    through the synchronous ``ParquetFile.read`` leaves nothing behind.
    """
    buf = pa.allocate_buffer(len(data))
    pa.FixedSizeBufferWriter(buf).write(data)
    return buf


def table_from_parquet(data: bytes, where: str = "<parquet>"):
    """The pyarrow Table of parquet bytes; ValueError naming ``where`` when unreadable."""
    pa = require("pyarrow", "data")
    import pyarrow.parquet as pq

    try:
        return pq.ParquetFile(pa.BufferReader(_arrow_owned(pa, data))).read()
    except (pa.ArrowInvalid, OSError) as exc:
        raise ValueError(f"{where}: expected a parquet manifest shard, found unreadable data ({exc})") from None


def table_to_parquet(table) -> bytes:
    import pyarrow.parquet as pq

    buf = io.BytesIO()
    pq.write_table(table, buf)
    return buf.getvalue()


def rows_from_parquet(data: bytes, where: str = "<parquet>") -> list[dict[str, Any]]:
    """Rows of a parquet table written by :func:`rows_to_parquet`; ValueError naming ``where`` when unreadable."""
    return table_from_parquet(data, where).to_pylist()
