"""Closed-loop policy evaluation on the toy model: where a step's CPU time goes, and cells per CPU-minute at batch 1 vs N.

    python benchmarks/closed_loop.py [--sessions 4] [--horizon 33] [--steps 10] [--batch 4 [8 ...]] [--repeats 1]
                                     [--json benchmarks/results/closed_loop.json]

The cells: ``--sessions`` toyarm sessions (``oscar toyworld closed-loop-sessions``, 64x64) x 2 image-based toy
policies (``exact``, ``never_closes``: ``ee_position`` through IK, 8 actions per call at 10 Hz), ``--horizon``
frames (17-frame chunks of ``oscar-toy``, 16 new frames per step), ``--steps`` denoising steps, guidance 3 in the
diffusers form, one torch thread (``OMP_NUM_THREADS=1``). The same cells run in one process, into fresh folders,
one at a time (``batch_cells=1``, the naive way) and in lock-step at each ``--batch`` (one batched world-model
call per chunk), the batch sizes interleaved (1, N, M, 1, N, M, ... for ``--repeats`` rounds) so that a change in
the machine's load falls on all of them alike. Cells per CPU-minute is cells / (process CPU seconds / 60), beside
wall time; each batch size's figures sum its rounds. Per closed-loop step (one chunk of one cell) the CPU time
of the thread doing the work (``time.thread_time``, so the policy threads of a batch count too) is split into
the policy's calls, the action adapter (IK), the condition render, the VAE encodes (seed frame and condition
video), the DiT's denoising loop, the VAE decode, writing the cell's files, the report, and the rest (``other``:
the loop itself, thread hand-offs, the interpreter); the wall milliseconds per step from each cell's record
(``timing_s``: policy, adapter, render, model — a batched call's time shared among its cells) stay beside it.
It checks that every batch's videos agree with batch 1's within one uint8 level. Prints a table, writes JSON.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import with_provenance  # noqa: E402

PARTS = ("policy", "adapter", "render", "model")
#: the CPU split: part -> (module, attribute) of the function whose calls it sums
CPU_PARTS = {
    "policy": ("oscar_core.evaluation.closed_loop_cell", "call_policy"),
    "adapter": ("oscar_core.policy.spaces", "ActionAdapter.apply"),
    "render": ("oscar_core.evaluation.closed_loop_cell", "ModelWorld._condition"),
    "vae_encode": ("oscar_core.model.vae", "VideoVAE.encode"),
    "dit": ("oscar_core.model.rollout", "sample_chunk"),
    "vae_decode": ("oscar_core.model.vae", "VideoVAE.decode"),
    "write": ("oscar_core.evaluation.closed_loop", "_write_cell"),
    "report": ("oscar_core.evaluation.closed_loop", "_report"),
}


@contextlib.contextmanager
def cpu_split(totals: dict):
    """Add the thread CPU seconds of every call of each :data:`CPU_PARTS` function to ``totals[part]``."""
    import importlib

    lock = threading.Lock()
    undo = []

    def timed(part, fn):
        def wrapper(*args, **kwargs):
            c0 = time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                with lock:
                    totals[part] = totals.get(part, 0.0) + time.thread_time() - c0

        return wrapper

    for part, (module, attr) in CPU_PARTS.items():
        owner = importlib.import_module(module)
        *path, name = attr.split(".")
        for p in path:
            owner = getattr(owner, p)
        fn = getattr(owner, name)
        setattr(owner, name, timed(part, fn))
        undo.append((owner, name, fn))
    try:
        yield totals
    finally:
        for owner, name, fn in undo:
            setattr(owner, name, fn)


def _run(manifest, out, model, sampler, batch: int) -> dict:
    from oscar_core.evaluation.closed_loop import run_closed_loop

    cpu_parts: dict = {}
    with cpu_split(cpu_parts):
        t0, c0 = time.perf_counter(), time.process_time()
        res = run_closed_loop(manifest, out, model=model, sampler=sampler, batch_cells=batch, log=lambda m: None)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    chunk = model.card.chunk_frames - 1
    steps = sum(-(-(r["frames"] - 1) // chunk) for r in res.records)
    return {
        "batch_cells": batch,
        "cells": len(res.records),
        "steps": steps,
        "failed": res.counts["failed"],
        "wall_s": wall,
        "cpu_s": cpu,
        "wall_ms": {p: 1e3 * sum(r["timing_s"].get(p, 0.0) for r in res.records) for p in PARTS},
        "cpu_parts_s": cpu_parts,
        "records": res.records,
    }


def _sum_rounds(runs: list[dict]) -> dict:
    """One row per batch size: its rounds summed, the rates and per-step figures computed from the sums."""
    cells, steps = sum(r["cells"] for r in runs), sum(r["steps"] for r in runs)
    wall, cpu = sum(r["wall_s"] for r in runs), sum(r["cpu_s"] for r in runs)
    parts = {p: sum(r["cpu_parts_s"].get(p, 0.0) for r in runs) for p in CPU_PARTS}
    row = {
        "batch_cells": runs[0]["batch_cells"],
        "rounds": len(runs),
        "cells": cells,
        "steps": steps,
        "failed": sum(r["failed"] for r in runs),
        "wall_s": wall,
        "cpu_s": cpu,
        "cells_per_cpu_minute": cells / (cpu / 60.0),
        "cells_per_wall_minute": cells / (wall / 60.0),
        "cpu_ms_per_step": {
            **{p: 1e3 * v / steps for p, v in parts.items()},
            "other": 1e3 * (cpu - sum(parts.values())) / steps,
            "total": 1e3 * cpu / steps,
        },
    }
    row.update({f"{p}_wall_ms_per_step": sum(r["wall_ms"][p] for r in runs) / steps for p in PARTS})
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sessions", type=int, default=4)
    ap.add_argument("--horizon", type=int, default=33)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--batch", type=int, nargs="+", default=[4], help="lock-step batch sizes beside batch 1")
    ap.add_argument("--repeats", type=int, default=1, help="interleaved rounds of every batch size")
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
        sizes = [1, *[b for b in args.batch if b != 1]]
        runs: dict[int, list] = {b: [] for b in sizes}
        for k in range(args.repeats):
            for b in sizes:
                runs[b].append(_run(manifest, Path(tmp) / f"r{k}b{b}", model, sampler, b))
        diff = 0
        for b in sizes[1:]:
            for ra, rb in zip(runs[1][0]["records"], runs[b][0]["records"]):
                if ra["status"] == rb["status"] == "ok":
                    a = read_video(Path(tmp) / "r0b1" / ra["video"]).astype(int)
                    v = read_video(Path(tmp) / f"r0b{b}" / rb["video"]).astype(int)
                    diff = max(diff, int(np.abs(a - v).max()))
    rows = [_sum_rounds(runs[b]) for b in sizes]
    speedups = [
        {
            "batch_cells": r["batch_cells"],
            "cells_per_cpu_minute": r["cells_per_cpu_minute"] / rows[0]["cells_per_cpu_minute"],
            "cells_per_wall_minute": r["cells_per_wall_minute"] / rows[0]["cells_per_wall_minute"],
        }
        for r in rows[1:]
    ]
    cols = [*CPU_PARTS, "other", "total"]
    print(f"{'batch':>5s} {'cells':>5s} {'cells/CPU-min':>13s} {'cells/wall-min':>14s}  CPU ms per step:")
    print(" " * 41 + "".join(f" {c:>10s}" for c in cols))
    for r in rows:
        print(
            f"{r['batch_cells']:5d} {r['cells']:5d} {r['cells_per_cpu_minute']:13.2f} {r['cells_per_wall_minute']:14.2f}"
            + "".join(f" {r['cpu_ms_per_step'][c]:10.1f}" for c in cols)
        )
    for sp in speedups:
        print(f"batch {sp['batch_cells']} / batch 1, cells per CPU-minute: {sp['cells_per_cpu_minute']:.2f}x")
    print(f"videos differ from batch 1's by at most {diff} uint8 level")
    out = with_provenance(
        {
            "model": "oscar-toy",
            "threads": 1,
            "sessions": args.sessions,
            "policies": ["exact", "never_closes"],
            "horizon": args.horizon,
            "steps": args.steps,
            "guidance": "3, diffusers form",
            "repeats": args.repeats,
            "rows": rows,
            "speedup_vs_batch_1": speedups,
            "max_uint8_diff": diff,
        }
    )
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
