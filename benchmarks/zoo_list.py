"""Wall and CPU time of ``oscar zoo list`` (no torch) against the naive way (the same command after importing torch).

    python benchmarks/zoo_list.py [--repeats 7] [--json benchmarks/results/zoo_list.json]

Each row runs a fresh interpreter ``--repeats`` times, alternating the two
ways so a load change on a shared machine hits both, and reports the median
wall time and the median user+system CPU time of the child.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

WAYS = {
    "oscar zoo list": [sys.executable, "-m", "oscar_core.cli", "zoo", "list"],
    "naive: torch + diffusers imported first": [
        sys.executable,
        "-c",
        "import torch, diffusers, sys; from oscar_core.cli import main; sys.exit(main(['zoo', 'list']))",
    ],
}


def _one(cmd) -> tuple[float, float]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(
        cmd,
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--json", help="write the rows here")
    args = ap.parse_args()
    runs = {name: [] for name in WAYS}
    for _ in range(args.repeats):
        for name, cmd in WAYS.items():
            runs[name].append(_one(cmd))
    rows = [
        {
            "way": name,
            "repeats": args.repeats,
            "wall_s_median": statistics.median(w for w, _ in r),
            "cpu_s_median": statistics.median(c for _, c in r),
            "wall_s_max": max(w for w, _ in r),
        }
        for name, r in runs.items()
    ]
    print(f"{'way':<42} {'wall s (median)':>16} {'wall s (max)':>13} {'CPU s (median)':>15}")
    for r in rows:
        print(f"{r['way']:<42} {r['wall_s_median']:>16.3f} {r['wall_s_max']:>13.3f} {r['cpu_s_median']:>15.3f}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({"rows": rows, "os_cpus": os.cpu_count()}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
