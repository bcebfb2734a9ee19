"""Closed-loop policy evaluation on the toy model: where a step's time goes, and cells per CPU-minute at batch 1 vs N.

    python benchmarks/closed_loop.py [--sessions 4] [--horizon 33] [--steps 10] [--batch 4]
                                     [--json benchmarks/results/closed_loop.json]

The cells: ``--sessions`` toyarm sessions (``oscar toyworld closed-loop-sessions``, 64x64) x 2 image-based toy
policies (``exact``, ``never_closes``: ``ee_position`` through IK, 8 actions per call at 10 Hz), ``--horizon``
frames (17-frame chunks of ``oscar-toy``, 16 new frames per step), ``--steps`` denoising steps, guidance 3 in the
diffusers form, one torch thread (``OMP_NUM_THREADS=1``). The same cells run twice in one process, into fresh
folders: one at a time (``batch_cells=1``, the naive way) and in lock-step (``batch_cells=N``, one batched
world-model call per chunk). Per closed-loop step (one chunk of one cell) the time is split, from each cell's
record (``timing_s``), into the policy's calls, the action adapter (IK), the condition render and the world model
(a batched call's time shared among its cells); cells per CPU-minute is cells / (process CPU seconds / 60),
beside wall time. It checks that the two runs' videos agree within one uint8 level. Prints a table, writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import with_provenance  # noqa: E402

PARTS = ("policy", "adapter", "render", "model")


def _run(manifest, out, model, sampler, batch: int) -> dict:
    from oscar_core.evaluation.closed_loop import run_closed_loop

    t0, c0 = time.perf_counter(), time.process_time()
    res = run_closed_loop(manifest, out, model=model, sampler=sampler, batch_cells=batch, log=lambda m: None)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    chunk = model.card.chunk_frames - 1
    steps = sum(-(-(r["frames"] - 1) // chunk) for r in res.records)
    per_step = {p: 1e3 * sum(r["timing_s"].get(p, 0.0) for r in res.records) / steps for p in PARTS}
    cells = len(res.records)
    return {
        "batch_cells": batch,
        "cells": cells,
        "steps": steps,
        "failed": res.counts["failed"],
        "wall_s": wall,
        "cpu_s": cpu,
        "cells_per_cpu_minute": cells / (cpu / 60.0),
        "cells_per_wall_minute": cells / (wall / 60.0),
        **{f"{p}_ms_per_step": v for p, v in per_step.items()},
        "records": res.records,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sessions", type=int, default=4)
    ap.add_argument("--horizon", type=int, default=33)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--json", default="benchmarks/results/closed_loop.json")
    args = ap.parse_args()
    torch.set_num_threads(1)

    import oscar_zoo
    from oscar_core.media.video import read_video
    from oscar_core.model import SamplerConfig
    from oscar_core.toyworld.closed_loop import write_closed_loop_sessions

    model = oscar_zoo.load("oscar-toy")
    sampler = SamplerConfig(steps=args.steps, guidance=3.0, guidance_form="diffusers")
    with tempfile.TemporaryDirectory() as tmp:
        manifest = write_closed_loop_sessions(
            Path(tmp) / "sessions",
            ["toyarm"],
            args.sessions,
            seed=0,
            horizon=args.horizon,
            policies=["exact", "never_closes"],
        )
        rows = [_run(manifest, Path(tmp) / f"b{b}", model, sampler, b) for b in (1, args.batch)]
        diff = 0
        for ra, rb in zip(rows[0]["records"], rows[1]["records"]):
            if ra["status"] == rb["status"] == "ok":
                a = read_video(Path(tmp) / "b1" / ra["video"]).astype(int)
                b = read_video(Path(tmp) / f"b{args.batch}" / rb["video"]).astype(int)
                diff = max(diff, int(np.abs(a - b).max()))
    for r in rows:
        r.pop("records")
    speedup = rows[1]["cells_per_cpu_minute"] / rows[0]["cells_per_cpu_minute"]
    head = f"{'batch':>5s} {'cells':>5s} {'cells/CPU-min':>13s} {'cells/wall-min':>14s}" + "".join(
        f" {p + ' ms/step':>16s}" for p in PARTS
    )
    print(head)
    for r in rows:
        print(
            f"{r['batch_cells']:5d} {r['cells']:5d} {r['cells_per_cpu_minute']:13.2f} {r['cells_per_wall_minute']:14.2f}"
            + "".join(f" {r[p + '_ms_per_step']:16.1f}" for p in PARTS)
        )
    print(f"batch {args.batch} / batch 1, cells per CPU-minute: {speedup:.2f}x; videos differ by at most {diff} level")
    out = with_provenance(
        {
            "model": "oscar-toy",
            "threads": 1,
            "sessions": args.sessions,
            "policies": ["exact", "never_closes"],
            "horizon": args.horizon,
            "steps": args.steps,
            "guidance": "3, diffusers form",
            "rows": rows,
            "speedup_cells_per_cpu_minute": speedup,
            "max_uint8_diff": diff,
        }
    )
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
