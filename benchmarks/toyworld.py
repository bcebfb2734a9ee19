"""Toy-world clip generation speed: episodes per second, against the naive way in the same run.

    python benchmarks/toyworld.py [--episodes 12] [--json benchmarks/results/toyworld.json]

On one CPU thread (torch, OpenCV and BLAS limited to one), for 64x64 episodes of
17 frames of toyarm, franka and kuka, it times:

* ``episode``: motion + scene + camera + RGB render (2x supersampled), per episode;
* ``episode, naive raster``: the same, drawing every capsule and sphere over the
  whole image instead of its bounding box (identical pixels, checked);
* ``motion, all cores``: the motion sampler (768-pose FK) with torch on
  every core instead of one thread, which is what oscar's CLI avoids;
* ``clip set``: `generate_clipset` end to end (render + skeleton video + FFV1 files).

Prints a table and writes JSON. Timings on shared machines swing up to 3x;
compare the ratios within one run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from oscar_core.plugin.registry import default_registry  # noqa: E402
from oscar_core.toyworld.episode import episode_rng, make_episode, plan_episode, render_world  # noqa: E402
from oscar_core.toyworld.generate import GenerateConfig, generate_clipset  # noqa: E402
from oscar_core.toyworld.motion import sample_motion  # noqa: E402

EMBODIMENTS = ("toyarm", "franka", "kuka")


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=12, help="episodes per embodiment per measurement")
    ap.add_argument("--json", default=str(Path(__file__).parent / "results" / "toyworld.json"))
    args = ap.parse_args()
    cv2.setNumThreads(1)
    default_threads = os.cpu_count() or 1  # what torch uses when OMP_NUM_THREADS is unset
    torch.set_num_threads(1)
    reg = default_registry()
    embs = [reg.get(n) for n in EMBODIMENTS]
    for e in embs:  # warm up: URDF parsing, FK chain building
        make_episode(e, episode_rng(99, e.name, 0), 64, 64, 17)
    n = args.episodes
    rows = []

    def per_episode(fn):
        total = 0.0
        for e in embs:
            for i in range(n):
                dt, _ = timed(lambda: fn(e, i))
                total += dt
        return len(embs) * n / total

    fast = per_episode(lambda e, i: make_episode(e, episode_rng(0, e.name, i), 64, 64, 17))
    rows.append(("episode (bounding-box raster)", fast))

    # naive raster: same episodes, every primitive over the whole image
    def naive(e, i):
        motion, scene, camera = plan_episode(e, episode_rng(0, e.name, i), 64, 64, 17)
        return render_world(e, motion, scene, camera, ss=2, full_frame=True)

    slow = per_episode(naive)
    ep = make_episode(embs[1], episode_rng(0, embs[1].name, 0), 64, 64, 17)
    check = render_world(embs[1], ep.motion, ep.scene, ep.camera, ss=2, full_frame=True)
    assert np.array_equal(check.rgb, ep.rgb), "naive raster must draw the same pixels"
    rows.append(("episode, naive raster (whole image per primitive)", slow))
    m1 = per_episode(lambda e, i: sample_motion(e, episode_rng(0, e.name, i), 17))
    rows.append(("motion only, 1 torch thread", m1))
    torch.set_num_threads(default_threads)
    md = per_episode(lambda e, i: sample_motion(e, episode_rng(0, e.name, i), 17))
    torch.set_num_threads(1)
    rows.append((f"motion only, torch on all {default_threads} cores", md))
    with tempfile.TemporaryDirectory() as tmp:
        cfg = GenerateConfig(EMBODIMENTS, episodes=n, width=64, height=64, frames=17, seed=0)
        s = generate_clipset(cfg, Path(tmp) / "clips", reg)
    rows.append(("clip set (render + skeleton + FFV1 files)", s["episodes_per_s"]))
    print(f"toy world, 64x64x17 episodes of {', '.join(EMBODIMENTS)}, {n} each, 1 thread")
    print(f"{'measurement':<55} {'episodes/s':>10}")
    for name, eps in rows:
        print(f"{name:<55} {eps:>10.2f}")
    print(f"bounding-box raster vs naive: {fast / slow:.1f}x; 1 thread vs all cores (motion): {m1 / md:.1f}x")
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "episodes_per_embodiment": n,
        "size": "64x64",
        "frames": 17,
        "torch_default_threads": default_threads,
    }
    out.write_text(json.dumps({"meta": meta, "rows": [{"name": a, "episodes_per_s": b} for a, b in rows]}, indent=2))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
