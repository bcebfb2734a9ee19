"""The oscar-toy rollout beside a background load, with 1, 2 and the automatic number of torch threads.

    python benchmarks/threads.py [--busy 2] [--settle 60] [--repeats 2] [--clips 2]

What it measures: each row is a fresh ``python -m oscar_core.cli -v toyworld rollout`` process rolling the
bundled zoo model ``oscar-toy`` out on ``--clips`` clips of a small toy clip set (``oscar toyworld generate``,
built once into ``--work``), with the model card's sampler, while ``--busy`` background processes spin on the
CPU (pure-Python loops, one core each). Before the first row the script waits ``--settle`` seconds so the
1-minute load average — what the automatic choice reads (``oscar_core._util.threads.choose_threads``) — has
seen the background load. Modes: ``--threads 1``, ``--threads 2`` and no flag (automatic; the count the
process chose is read from its debug line ``torch threads: N``); the modes alternate repeat by repeat, so a
change of the machine's other load hits them alike. Per mode: the median wall seconds from spawn to exit and
the CPU seconds the process used (``resource.getrusage(RUSAGE_CHILDREN)``), and the ratio of the automatic
mode's wall to the best mode's (the goal: at most 1.10).

``OSCAR_NUM_THREADS`` and ``OMP_NUM_THREADS`` are removed from the children's environment (they would
override the choice). Writes ``benchmarks/results/threads.json`` (or ``--out``) with its provenance, every run, the
machine (CPU count, load averages before and after) and the table; a copy in ``benchmarks/measured/`` is rendered
into docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import with_provenance

REPO = Path(__file__).resolve().parents[1]
MODES = ("1", "2", "auto")


def _busy() -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def _cli(args: list[str], env: dict) -> tuple[float, float, str]:
    """Run ``python -m oscar_core.cli ARGS``; (wall s, CPU s, stderr). Raises with its stderr when it fails."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "oscar_core.cli", *args], capture_output=True, text=True, env=env, cwd=REPO
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"oscar {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, proc.stderr


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--busy", type=int, default=2, help="background busy processes (default 2)")
    p.add_argument("--settle", type=float, default=60.0, help="seconds of background load before the first row")
    p.add_argument("--repeats", type=int, default=2, help="runs per mode (default 2)")
    p.add_argument("--clips", type=int, default=2, help="clips rolled out per run (default 2)")
    p.add_argument("--work", type=Path, help="folder for the clip set and outputs (default: a temporary one)")
    p.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "threads.json")
    a = p.parse_args(argv)

    work = a.work or Path(tempfile.mkdtemp(prefix="oscar-threads-"))
    env = {k: v for k, v in os.environ.items() if k not in ("OSCAR_NUM_THREADS", "OMP_NUM_THREADS")}
    clips = work / "clips"
    if not clips.is_dir():
        _cli(
            [
                "-q",
                "toyworld",
                "generate",
                "--embodiments",
                "toyarm",
                "--episodes",
                str(a.clips),
                "--size",
                "64x64",
                "--frames",
                "17",
                "--out",
                str(clips),
                "--threads",
                "1",
            ],
            env,
        )
    load_before = os.getloadavg()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # `kill` ends the busy processes too (finally below)
    busy = [_busy() for _ in range(a.busy)]
    runs = []
    try:
        time.sleep(a.settle)
        for r in range(a.repeats):
            for mode in MODES:
                out = work / f"ro-{mode}-{r}"
                shutil.rmtree(out, ignore_errors=True)
                flags = [] if mode == "auto" else ["--threads", mode]
                load = os.getloadavg()[0]
                wall, cpu, err = _cli(
                    [
                        "-v",
                        "toyworld",
                        "rollout",
                        str(clips),
                        "--model",
                        "oscar-toy",
                        "--out",
                        str(out),
                        "--split",
                        "all",
                        "--limit",
                        str(a.clips),
                        *flags,
                    ],
                    env,
                )
                m = re.search(r"torch threads: (\d+)", err)
                runs.append(
                    {
                        "mode": mode,
                        "repeat": r,
                        "threads": int(m.group(1)) if m else None,
                        "wall_s": wall,
                        "cpu_s": cpu,
                        "load_1min_at_start": load,
                    }
                )
                print(
                    f"  {mode:>4} (threads {runs[-1]['threads']}): {wall:6.1f} s wall, {cpu:6.1f} CPU-s, "
                    f"load {load:.1f}",
                    file=sys.stderr,
                )
    finally:
        for b in busy:
            b.kill()
            b.wait()
    table = []
    for mode in MODES:
        rows = [x for x in runs if x["mode"] == mode]
        table.append(
            {
                "mode": mode,
                "threads": sorted({x["threads"] for x in rows}, key=str),
                "wall_s": statistics.median(x["wall_s"] for x in rows),
                "cpu_s": statistics.median(x["cpu_s"] for x in rows),
            }
        )
    best = min(t["wall_s"] for t in table)
    for t in table:
        t["wall_vs_best"] = t["wall_s"] / best
    print(
        f"oscar-toy rollout of {a.clips} clips beside {a.busy} busy processes on {os.cpu_count()} CPUs "
        f"(median of {a.repeats})"
    )
    print(f"{'mode':>6}  {'threads':>8}  {'wall s':>7}  {'CPU s':>7}  {'wall/best':>9}")
    for t in table:
        print(
            f"{t['mode']:>6}  {','.join(map(str, t['threads'])):>8}  {t['wall_s']:7.1f}  {t['cpu_s']:7.1f}  "
            f"{t['wall_vs_best']:9.2f}"
        )
    auto = next(t for t in table if t["mode"] == "auto")
    print(f"automatic within 10 % of the best: {'yes' if auto['wall_vs_best'] <= 1.10 else 'no'}")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(
        json.dumps(
            with_provenance(
                {
                    "machine": {
                        "cpus": os.cpu_count(),
                        "processor": platform.processor(),
                        "load_before": load_before,
                        "load_after": os.getloadavg(),
                    },
                    "settings": {"busy": a.busy, "settle_s": a.settle, "repeats": a.repeats, "clips": a.clips},
                    "runs": runs,
                    "table": table,
                }
            ),
            indent=1,
        )
        + "\n"
    )
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
