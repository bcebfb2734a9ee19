"""The action-following benchmark's quick set on a world model (default the bundled oscar-toy): its scores and its cost.

    python benchmarks/action_following.py [--model oscar-toy] [--seed 0] [--threads 1] [--steps N]
                                          [--out DIR] [--json benchmarks/measured/action_following.json]

Runs ``oscar toyworld action-following --model M --quick --seed S`` as a user would (a fresh process, into a fresh
folder unless ``--out`` names one to keep): 3 counterfactual sets per embodiment (toyarm, franka, kuka), 6 variants
each (the gripper closes at the ball / stays open / closes early / closes late; the path misses the ball by 1 and 3
radii), 97 frames = 6 chunks of oscar-toy, 64x64, 10 sampler steps (``--quick``'s) unless ``--steps``. Prints a
table — decision accuracy with its interval, the pairwise rate, per-variant verdict agreement, per-chunk PSNR and
ball error — and the wall and CPU seconds of the whole command (set generation included; CPU = user + system of the
child) beside the machine's load average before and after, and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import REPO, with_provenance


def _stat(s: dict, scale: float = 1.0, fmt: str = "{:.2f}") -> str:
    if "undefined" in s:
        return s["undefined"]
    text = fmt.format(s["value"] * scale)
    if "ci" in s:
        text += " [" + ", ".join(fmt.format(x * scale) for x in s["ci"]) + "]"
    return text


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default="oscar-toy")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--steps", type=int, default=None, help="sampler steps (default: --quick's 10)")
    ap.add_argument("--out", default=None, help="run folder to keep (default: a temporary one)")
    ap.add_argument("--json", default="benchmarks/measured/action_following.json")
    args = ap.parse_args()

    tmp = None
    if args.out is None:
        tmp = tempfile.TemporaryDirectory()
        out = Path(tmp.name) / "af"
    else:
        out = Path(args.out)
    cmd = [sys.executable, "-m", "oscar_core.cli", "toyworld", "action-following", "--model", args.model, "--quick"]
    cmd += ["--seed", str(args.seed), "--out", str(out), "--threads", str(args.threads), "--no-progress"]
    if args.steps is not None:
        cmd += ["--steps", str(args.steps)]
    env = {**os.environ, "OMP_NUM_THREADS": str(args.threads)}
    load_before = round(os.getloadavg()[0], 2)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    load_after = round(os.getloadavg()[0], 2)
    if proc.returncode != 0:
        print(proc.stdout[-3000:], proc.stderr[-3000:], sep="\n", file=sys.stderr)
        return proc.returncode
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    report = json.loads((out / "report.json").read_text())
    s = report["scores"]
    print(
        f"{args.model}: {s['sets']} sets x 6 variants, {report['sampler']}, seed {args.seed}, {args.threads} thread(s)"
    )
    print(f"decision accuracy {_stat(s['decision_accuracy'], 100, '{:.1f}')} %")
    print(f"pairwise rate     {_stat(s['pairwise'], 100, '{:.1f}')} % of {s['pairwise'].get('pairs', 0)} pairs")
    print(f"{'variant':<14s} {'true SR':>7s} {'model SR':>22s} {'verdict = truth':>22s} {'ball end error (R)':>24s}")
    for name, v in s["variants"].items():
        print(
            f"{name:<14s} {v['true_rate']:7.2f} {_stat(v['model_rate']):>22s} {_stat(v['agreement']):>22s} "
            f"{_stat(v['end_error']):>24s}"
        )
    print(f"{'chunk':>5s} {'PSNR dB':>22s} {'ball error (R)':>24s}")
    for c in s["chunks"]:
        print(f"{c['chunk']:5d} {_stat(c['psnr_db']):>22s} {_stat(c['object_error']):>24s}")
    print(f"wall {wall:.0f} s, CPU {cpu:.0f} s (whole command); load average {load_before} before, {load_after} after")
    result = with_provenance(
        {
            "model": args.model,
            "quick": True,
            "seed": args.seed,
            "threads": args.threads,
            "sampler": report["sampler"],
            "sets": s["sets"],
            "variants": list(s["variants"]),
            "frames": 97,
            "wall_s": round(wall, 1),
            "cpu_s": round(cpu, 1),
            "benchmark_wall_s": report["timing"]["wall_s"],
            "benchmark_cpu_s": report["timing"]["cpu_s"],
            "load_average_before": load_before,
            "load_average_after": load_after,
            "decision_accuracy": s["decision_accuracy"],
            "pairwise": s["pairwise"],
            "per_variant": [
                {
                    "variant": n,
                    "true_rate": v["true_rate"],
                    "model_rate": v["model_rate"].get("value"),
                    "agreement": v["agreement"].get("value"),
                    "agreement_ci": v["agreement"].get("ci"),
                    "ball_end_error_radii": v["end_error"].get("value"),
                }
                for n, v in s["variants"].items()
            ],
            "per_chunk": [
                {
                    "chunk": c["chunk"],
                    "psnr_db": c["psnr_db"].get("value"),
                    "psnr_ci": c["psnr_db"].get("ci"),
                    "ball_error_radii": c["object_error"].get("value"),
                    "ball_error_ci": c["object_error"].get("ci"),
                }
                for c in s["chunks"]
            ],
        }
    )
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.json}")
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
