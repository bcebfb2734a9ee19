"""Does the persistent compile cache pay on the next run? Cold and warm processes rolling out ``oscar-toy``.

    python benchmarks/compile_cache.py [--steps 4] [--json benchmarks/results/compile_cache.json]

Each row is a fresh Python process that loads the bundled ``oscar-toy`` model (64x64, 17-frame chunks) and rolls
one chunk out with ``--steps`` denoising steps, the DiT compiled the way ``oscar rollout --compile always`` does
(``oscar_core.model.compile_policy``: inductor's cache under ``$OSCAR_CACHE/compile``):

* ``eager``: no compiling (the naive way, for reference);
* ``compile, cold cache``: a new, empty ``$OSCAR_CACHE`` (the first run on a machine);
* ``compile, warm cache``: the same ``$OSCAR_CACHE`` again (every later run) — twice.

It reports the rollout's wall seconds, its sampling seconds (compiling happens in the first DiT call, inside
them), the whole process's wall seconds and its CPU seconds (its own plus its compile workers'), and checks that every compiled rollout gives the eager
video. Measured on whatever runs it (a CPU here: inductor's C++ backend); a GPU compiles Triton kernels instead and
its numbers differ.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

_CHILD = r"""
import json, os, resource, sys, time
import numpy as np, torch
import oscar_zoo
from oscar_core.model import SamplerConfig

mode, steps, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
torch.set_num_threads(1)
model = oscar_zoo.load("oscar-toy").set_compile(mode)
rng = np.random.default_rng(0)
first = rng.integers(0, 256, (64, 64, 3), dtype=np.uint8)
skel = rng.integers(0, 256, (17, 64, 64, 3), dtype=np.uint8)

t0 = time.perf_counter()
result = model.rollout(first, skel, sampler=SamplerConfig(steps=steps), progress=False)
wall = time.perf_counter() - t0
usage = [resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]
np.save(out, result.frames)
print(json.dumps({"wall_s": wall, "sample_s": result.timings["sample"],
                  "cpu_s": sum(u.ru_utime + u.ru_stime for u in usage), "compile": model.compile_reason}))
"""


def _run(mode: str, steps: int, cache: Path, frames_out: Path) -> dict:
    env = {**os.environ, "OSCAR_CACHE": str(cache), "OMP_NUM_THREADS": "1"}
    env.pop("TORCHINDUCTOR_CACHE_DIR", None)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD, mode, str(steps), str(frames_out)],
        capture_output=True,
        text=True,
        env=env,
        cwd=REPO,
    )
    if proc.returncode:
        raise RuntimeError(f"{mode}: the child process failed:\n{proc.stderr[-3000:]}")
    row = json.loads(proc.stdout.strip().splitlines()[-1])
    row["process_wall_s"] = time.perf_counter() - t0
    return row


def main(argv=None) -> int:
    import numpy as np

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=4, help="denoising steps of the one chunk (default 4)")
    ap.add_argument("--json", default=str(REPO / "benchmarks" / "results" / "compile_cache.json"))
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="oscar-compile-cache-"))
    cache = work / "oscar-cache"
    plan = [
        ("eager", "never"),
        ("compile, cold cache", "always"),
        ("compile, warm cache", "always"),
        ("compile, warm cache (again)", "always"),
    ]
    rows = []
    for k, (name, mode) in enumerate(plan):
        row = _run(mode, args.steps, cache, work / f"frames{k}.npy")
        row["run"] = name
        rows.append(row)
    eager = np.load(work / "frames0.npy")
    for k, row in enumerate(rows):
        got = np.load(work / f"frames{k}.npy")
        row["max_abs_diff_vs_eager"] = int(np.abs(got.astype(int) - eager.astype(int)).max())
    print(
        f"\noscar-toy, one 17-frame 64x64 chunk, {args.steps} steps, fresh process per row (measured; "
        f"{os.cpu_count()} CPUs, one torch thread)"
    )
    print(f"{'run':<28} {'rollout s':>9} {'sampling s':>10} {'process s':>9} {'CPU s':>7} {'max |diff|':>10}")
    for r in rows:
        print(
            f"{r['run']:<28} {r['wall_s']:>9.1f} {r['sample_s']:>10.1f} {r['process_wall_s']:>9.1f} "
            f"{r['cpu_s']:>7.1f} {r['max_abs_diff_vs_eager']:>10}"
        )
    result = {
        "machine": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "steps": args.steps,
        "rows": rows,
    }
    from oscar_core._util.atomic import atomic_write_bytes

    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    print(f"\nwrote {atomic_write_bytes(args.json, (json.dumps(result, indent=2) + chr(10)).encode())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
