"""``stats``: the paper's Table 1 for a run — public vs kept episodes per source and embodiment, rejections per filter.

Computed from the manifests only: "public" is every episode the reader
listed at ingest; "kept" is every episode no stage has rejected in the last
finished stage; each rejection is counted once, under the first stage that
rejected it and the filter named at the start of its reason
(``ingest:unreadable``, ``filter:length``, ``filter:camera_motion``,
``filter:action``, ``filter:visible``, ``filter:spike_joint``,
``filter:spike_point``, ``dedup:duplicate``, …).
"""

from __future__ import annotations

import json
from typing import Any

from . import _fs
from .engine import read_stage, stage_done
from .manifest import STAGES, is_alive, rejection

__all__ = ["compute_stats", "format_table", "plot_stats", "latest_stage", "column_of"]


def latest_stage(run: str, before: str | None = None) -> str | None:
    """The last finished stage of ``run`` (only stages before ``before`` when given), or None."""
    order = STAGES if before is None else STAGES[: STAGES.index(before)]
    for stage in reversed(order):
        if stage_done(_fs.join(run, stage)):
            return stage
    return None


def column_of(row: dict[str, Any]) -> str | None:
    """The rejection column (``stage:filter``) a final-stage row is counted under, or None when it is kept."""
    rej = rejection(row)
    if rej is None and is_alive(row):
        return None
    st, reason = rej if rej else ("?", "unknown")
    return f"{st}:{reason.split(':', 1)[0].strip()}"


def compute_stats(run: str) -> dict[str, Any]:
    """Table 1 of ``run`` as a dict: ``rows`` (one per source × embodiment), ``total``, ``columns``, ``stage``."""
    listed = read_stage(_fs.join(run, "ingest"))
    stage = latest_stage(run)
    final = {r["id"]: r for r in read_stage(_fs.join(run, stage))}
    columns: list[str] = []
    groups: dict[tuple[str, str], dict[str, Any]] = {}
    for r in listed:
        key = (r["source"], r["embodiment"])
        g = groups.setdefault(key, {"source": key[0], "embodiment": key[1], "public": 0, "kept": 0, "rejected": {}})
        g["public"] += 1
        col = column_of(final.get(r["id"], r))
        if col is None:
            g["kept"] += 1
            continue
        if col not in columns:
            columns.append(col)
        g["rejected"][col] = g["rejected"].get(col, 0) + 1
    order = {f"{s}:": i for i, s in enumerate(STAGES)}
    columns.sort(key=lambda c: (order.get(c.split(":")[0] + ":", 99), c))
    rows = [groups[k] for k in sorted(groups)]
    total = {
        "source": "total",
        "embodiment": "",
        "public": sum(g["public"] for g in rows),
        "kept": sum(g["kept"] for g in rows),
        "rejected": {c: sum(g["rejected"].get(c, 0) for g in rows) for c in columns},
    }
    return {"run": str(run), "stage": stage, "columns": columns, "rows": rows, "total": total}


def format_table(stats: dict[str, Any]) -> str:
    """A plain-text table: source, embodiment, public, one column per rejection kind, kept."""
    head = ["source", "embodiment", "public", *stats["columns"], "kept"]
    body = [
        [
            g["source"],
            g["embodiment"],
            str(g["public"]),
            *[str(g["rejected"].get(c, 0)) for c in stats["columns"]],
            str(g["kept"]),
        ]
        for g in [*stats["rows"], stats["total"]]
    ]
    widths = [max(len(h), *(len(b[i]) for b in body)) for i, h in enumerate(head)]

    def line(cells):
        return "  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths)))

    out = [line(head), "  ".join("-" * w for w in widths)]
    out += [line(b) for b in body[:-1]]
    out += ["  ".join("-" * w for w in widths), line(body[-1])]
    return "\n".join(out) + f"\n(kept after stage: {stats['stage']})\n"


def plot_stats(stats: dict[str, Any], path: str) -> str:
    """A bar chart per source × embodiment: public, kept, and the rejections stacked by kind; saved to ``path``."""
    try:
        import matplotlib
    except ImportError:
        raise ImportError(
            'matplotlib is needed for the stats plot; install it with: pip install "oscar-wm[plots]"'
        ) from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rows = stats["rows"]
    labels = [f"{g['source']}\n{g['embodiment']}" for g in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(5.0, 1.4 * len(rows) + 2), 4.0))
    ax.bar(x - 0.3, [g["public"] for g in rows], 0.28, label="public", color="#999999")
    ax.bar(x, [g["kept"] for g in rows], 0.28, label="kept", color="#2a7ab0")
    bottom = np.zeros(len(rows))
    cmap = plt.get_cmap("tab10")
    for i, c in enumerate(stats["columns"]):
        v = np.array([g["rejected"].get(c, 0) for g in rows], dtype=float)
        ax.bar(x + 0.3, v, 0.28, bottom=bottom, label=f"rejected {c}", color=cmap(i % 10))
        bottom += v
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_ylabel("episodes")
    ax.set_title(f"episodes per source (kept after {stats['stage']})", fontsize=10)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fs, p = _fs.url_to_fs(path)
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format=path.rsplit(".", 1)[-1] if "." in path else "png", dpi=120)
    plt.close(fig)
    _fs.write_bytes_atomic(path, buf.getvalue())
    return path


def stats_json(stats: dict[str, Any]) -> str:
    return json.dumps(stats, indent=2, sort_keys=True)
