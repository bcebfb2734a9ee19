"""Rolling several evaluation cells out in one batch against one at a time, on the bundled toy model.

    python benchmarks/batch_cells.py [--cells 8] [--threads 1] [--json benchmarks/results/batch_cells.json]

The cells are the toy model's size (64x64, one 17-frame chunk, 20 UniPC steps, guidance 3): random first
frames and condition videos, one seed each. It times ``OscarWorldModel.rollout`` per cell (the naive way,
what ``oscar eval run`` does with ``--batch-cells 1``) against ``rollout_batch`` of 2, 4 and all cells, in the
same run, and checks that every batched video equals its one-at-a-time rollout within one uint8 level.
Prints a table (wall and CPU seconds per cell) and writes JSON. On a CPU the gain is modest (the batch only
amortises per-call overhead); on a GPU a batch fills the device a small chunk leaves idle — not measured here.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cells", type=int, default=8)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", default="benchmarks/results/batch_cells.json")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)

    import oscar_zoo
    from oscar_core.model import SamplerConfig

    model = oscar_zoo.load("oscar-toy")
    card = model.card
    rng = np.random.default_rng(0)
    firsts = [rng.integers(0, 255, (card.height, card.width, 3), dtype=np.uint8) for _ in range(args.cells)]
    videos = [
        rng.integers(0, 255, (card.chunk_frames, card.height, card.width, 3), dtype=np.uint8) for _ in range(args.cells)
    ]
    seeds = list(range(args.cells))
    sampler = SamplerConfig(steps=20, guidance=3.0)

    def timed(fn):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        return out, time.perf_counter() - t0, time.process_time() - c0

    alone, wall1, cpu1 = timed(
        lambda: [
            model.rollout(f, v, sampler=sampler, seed=s, progress=False).frames
            for f, v, s in zip(firsts, videos, seeds)
        ]
    )
    rows = [
        {"batch": 1, "wall_s_per_cell": wall1 / args.cells, "cpu_s_per_cell": cpu1 / args.cells, "max_uint8_diff": 0}
    ]
    for b in sorted({2, 4, args.cells}):

        def run(b=b):
            out = []
            for i in range(0, args.cells, b):
                out += model.rollout_batch(
                    firsts[i : i + b], videos[i : i + b], sampler=sampler, seeds=seeds[i : i + b]
                )
            return out

        batched, wall, cpu = timed(run)
        diff = max(int(np.abs(a.astype(int) - c.astype(int)).max()) for a, c in zip(alone, batched))
        rows.append(
            {
                "batch": b,
                "wall_s_per_cell": wall / args.cells,
                "cpu_s_per_cell": cpu / args.cells,
                "max_uint8_diff": diff,
            }
        )
    print(f"{'batch':>5s} {'wall s/cell':>12s} {'cpu s/cell':>11s} {'speed-up':>9s} {'max diff':>9s}")
    for r in rows:
        print(
            f"{r['batch']:5d} {r['wall_s_per_cell']:12.2f} {r['cpu_s_per_cell']:11.2f} "
            f"{rows[0]['wall_s_per_cell'] / r['wall_s_per_cell']:8.2f}x {r['max_uint8_diff']:9d}"
        )
    out = {
        "machine": platform.platform(),
        "python": sys.version.split()[0],
        "torch": torch.__version__,
        "threads": args.threads,
        "cells": args.cells,
        "model": "oscar-toy",
        "steps": 20,
        "guidance": 3.0,
        "rows": rows,
    }
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
