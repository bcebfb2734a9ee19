"""``RUN_DIR/curves.png``: the training curves of a run (loss, gradient norm, learning rate against step).

Read from ``RUN_DIR/metrics.jsonl`` (the records with a ``loss``); written by
:func:`oscar_core.train.loop.train` at the end of every run (rank 0), and by
``plot_training_curves`` on any run folder. Needs matplotlib
(``pip install "oscar-wm[plots]"``); without it the plot is skipped with an
INFO line, the run is unaffected.
"""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["CURVES_FILE", "read_curves", "plot_training_curves"]

CURVES_FILE = "curves.png"


def read_curves(metrics_jsonl) -> dict[str, list[float]]:
    """``{"step", "loss", "grad_norm", "lr"}`` lists from a metrics file (records without a loss are skipped)."""
    out: dict[str, list[float]] = {"step": [], "loss": [], "grad_norm": [], "lr": []}
    for line in Path(metrics_jsonl).read_text().splitlines():
        if not line.strip():
            continue
        rec = json.loads(line)
        if "loss" not in rec:
            continue
        for k in out:
            v = rec.get(k)
            out[k].append(float("nan") if v is None else float(v))
    return out


def plot_training_curves(run_dir, out=None) -> Path | None:
    """Write the three-panel PNG for ``run_dir`` to ``out`` (default ``RUN_DIR/curves.png``); None when there is
    nothing to plot yet. Raises ImportError naming the extra when matplotlib is missing."""
    from .._util.atomic import atomic_write_bytes
    from ..metrics.plots import new_figure

    run_dir = Path(run_dir)
    c = read_curves(run_dir / "metrics.jsonl")
    if not c["step"]:
        return None
    fig = new_figure((10.5, 3.0), 100)
    for i, (key, label, log) in enumerate(
        (("loss", "loss", True), ("grad_norm", "gradient norm (before clipping)", True), ("lr", "learning rate", False))
    ):
        ax = fig.add_subplot(1, 3, i + 1)
        ax.plot(c["step"], c[key], linewidth=1.2, color=f"C{i}", gid=f"curve:{key}")
        if log and all(v > 0 for v in c[key] if v == v):
            ax.set_yscale("log")
        ax.set_xlabel("step")
        ax.set_title(label, fontsize=10)
        ax.grid(True, linewidth=0.4, alpha=0.5)
    fig.subplots_adjust(left=0.06, right=0.98, bottom=0.17, top=0.88, wspace=0.3)
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    out = Path(out) if out is not None else run_dir / CURVES_FILE
    atomic_write_bytes(out, buf.getvalue())
    return out
