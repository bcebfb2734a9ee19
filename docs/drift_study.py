"""The long-rollout (drift) study of docs/distillation.md: its table and its figure, from one per-chunk eval.

    python docs/drift_study.py drift.json --out docs/images/distill_drift.png [--markdown]

``drift.json`` is written by ``oscar toyworld eval ... --paired teacher --per-chunk 17 --out drift.json`` (the
commands are in docs/distillation.md). The figure: motion IoU, PSNR and object error against chunk index, one
line per row of the table (sampler), each with the 95 % percentile-bootstrap interval of its mean over the
clips (2000 resamples, seed 0) as a band. ``--markdown`` prints the table of the docs: per chunk index and
sampler the mean, and the paired difference from the reference row with its 95 % interval (from the JSON).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from oscar_core.metrics.paired import paired_bootstrap_interval
from oscar_core.metrics.plots import new_figure, save_figure

PANELS = (
    ("motion_iou", "motion IoU ↑", 3),
    ("psnr_db", "PSNR (dB) ↑", 2),
    ("object_error_px", "object error (px) ↓", 1),
)


def bands(table: dict, metric: str) -> dict[str, np.ndarray]:
    """Row name → (K, 3) per chunk index: mean over clips, 95 % interval low, high."""
    out = {}
    for name, per in table["clips"].items():
        n = len(table["rows"][name]["chunks"])
        rows = []
        for k in range(n):
            v = np.array([m["chunks"][k][metric] for m in per.values() if len(m["chunks"]) > k], dtype=np.float64)
            v = v[np.isfinite(v)]
            lo, hi = paired_bootstrap_interval(v, 2000, 0)
            rows.append((v.mean() if v.size else np.nan, lo, hi))
        out[name] = np.array(rows)
    return out


def figure(table: dict, path: Path) -> Path:
    fig = new_figure((11.0, 3.4), 100)
    for i, (metric, label, _) in enumerate(PANELS):
        ax = fig.add_subplot(1, len(PANELS), i + 1)
        for j, (name, b) in enumerate(bands(table, metric).items()):
            x = np.arange(1, len(b) + 1)
            ax.plot(x, b[:, 0], marker="o", ms=3, color=f"C{j}", label=name)
            ax.fill_between(x, b[:, 1], b[:, 2], color=f"C{j}", alpha=0.18, lw=0)
        ax.set_xlabel(f"chunk index ({table['per_chunk'] - 1} new frames each)")
        ax.set_title(label, fontsize=10)
        ax.set_xticks(x)
        ax.grid(alpha=0.3)
        if i == 0:
            ax.legend(fontsize=8)
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.16, top=0.9, wspace=0.28)
    return save_figure(fig, path)


def markdown(table: dict) -> str:
    paired = table["paired"]
    ref = paired["reference"]
    head = ["chunk (frames)", "sampler"]
    for _, label, _ in PANELS:
        head += [label, f"Δ vs {ref} [95 %]"]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    first = next(iter(table["clips"][ref].values()))["chunks"]
    for k in range(len(table["rows"][ref]["chunks"])):
        a, b = first[k]["frames"]
        for name, row in table["rows"].items():
            cells = [f"{k + 1} ({a}–{b})", name]
            for metric, _, dg in PANELS:
                cells.append(f"{row['chunks'][k][metric]:.{dg}f}")
                if name == ref:
                    cells.append("—")
                else:
                    d = paired["chunks"][name][k][metric]
                    cells.append(f"{_s(d['mean'], dg)} [{_s(d['ci'][0], dg)}, {_s(d['ci'][1], dg)}]")
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _s(x: float, digits: int) -> str:
    """A signed number with a typographic minus."""
    return f"{x:+.{digits}f}".replace("-", "−")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("table", type=Path, help="JSON of `oscar toyworld eval --paired REF --per-chunk N --out`")
    ap.add_argument("--out", type=Path, help="the PNG to write")
    ap.add_argument("--markdown", action="store_true", help="print the per-chunk table as Markdown")
    args = ap.parse_args(argv)
    table = json.loads(args.table.read_text())
    if not table.get("per_chunk") or "paired" not in table:
        raise SystemExit(f"{args.table}: expected a table of `oscar toyworld eval --paired REF --per-chunk N`")
    if args.out:
        print(f"wrote {figure(table, args.out)}")
    if args.markdown:
        print(markdown(table))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
