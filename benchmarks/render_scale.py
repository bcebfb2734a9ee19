"""Rendering at dataset scale: episodes/s through one command, encoder presets, peak memory, start-up.

    python benchmarks/render_scale.py [--episodes 40] [--long-frames 8100] [--json benchmarks/results/render_scale.json]

Everything runs as the user would run it, in subprocesses of this script:

1. start-up: wall time of ``python -c "import torch"`` beside ``oscar --help``,
   ``oscar embodiments`` and a one-frame ``oscar render`` (median of 3);
2. throughput: N 81-frame 512x288 H.264 franka episodes through one
   ``oscar render --manifest`` with 1 and 2 workers, against the naive way
   (one ``oscar render`` process per episode) and the in-process Python API;
   and the same batch run again unchanged (every episode skipped by its
   resume record: the cost of checking, start-up included);
3. encoder presets and the RGB→YUV path: seconds per 81-frame episode, MP4 size
   and PSNR of the decoded video against the rendered frames (= a lossless copy);
4. peak memory (ru_maxrss of the child) of a long 1280x704 render, streamed,
   beside the whole-array way (render_skeleton_video + write_video) at a tenth
   of the length.

Prints tables and writes JSON. Timings on shared machines swing up to 3x;
compare the ratios within one run (the load average is recorded).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
PY = sys.executable
OSCAR = [PY, "-m", "oscar_core.cli"]


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_timed(cmd: list[str]) -> tuple[float, float]:
    """(wall seconds, CPU seconds: user + system of it and its children) of running ``cmd``."""
    c0, t0 = _children_cpu(), time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0, _children_cpu() - c0


def wall(cmd: list[str], repeats: int = 3) -> dict:
    """Median wall and CPU seconds of running ``cmd`` to completion (it must succeed)."""
    runs = [run_timed(cmd) for _ in range(repeats)]
    return {"wall_s": statistics.median(r[0] for r in runs), "cpu_s": statistics.median(r[1] for r in runs)}


def child_peak_rss_mb(cmd: list[str]) -> tuple[float, float]:
    """(peak RSS MB, wall seconds) of ``cmd`` run in a fresh process via a small launcher."""
    launcher = (
        "import resource, subprocess, sys, time\n"
        "t0 = time.perf_counter(); subprocess.run(sys.argv[1:], check=True, stdout=subprocess.DEVNULL)\n"
        "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, time.perf_counter() - t0)"
    )
    out = subprocess.run([PY, "-c", launcher, *cmd], check=True, capture_output=True, text=True).stdout.split()
    return int(out[0]) / 1024.0, float(out[1])  # ru_maxrss is KiB on Linux


def make_episodes(tmp: Path, n: int, frames: int = 81) -> tuple[Path, list[dict]]:
    from oscar_core import get_embodiment, load_trajectory, save_trajectory

    emb = get_embodiment("franka")
    full = load_trajectory(emb.example_trajectory)
    rows = []
    for i in range(n):
        start = i % (len(full) - frames + 1)
        path = tmp / f"ep{i:04d}.npz"
        save_trajectory(full.time_slice(start, start + frames), path)
        rows.append(
            {
                "embodiment": "franka",
                "trajectory": str(path),
                "camera": str(emb.example_camera),
                "out": str(tmp / "out" / f"ep{i:04d}.mp4"),
                "size": "512x288",
            }
        )
    manifest = tmp / "episodes.jsonl"
    manifest.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    return manifest, rows


def bench_startup(tmp: Path) -> dict:
    from oscar_core import get_embodiment, load_trajectory, save_trajectory

    emb = get_embodiment("franka")
    one = tmp / "one.npz"
    save_trajectory(load_trajectory(emb.example_trajectory).time_slice(0, 1), one)
    render = OSCAR + [
        "render",
        "--embodiment",
        "franka",
        "--trajectory",
        str(one),
        "--camera",
        str(emb.example_camera),
        "--size",
        "512x288",
        "--out",
        str(tmp / "one.mp4"),
    ]
    return {
        "python_c_pass_s": wall([PY, "-c", "pass"]),
        "import_torch_s": wall([PY, "-c", "import torch"]),
        "oscar_help_s": wall(OSCAR + ["--help"]),
        "oscar_embodiments_s": wall(OSCAR + ["embodiments"]),
        "one_frame_render_s": wall(render),
    }


def bench_throughput(tmp: Path, n: int, naive_n: int, preset: str) -> dict:
    manifest, rows = make_episodes(tmp, n)
    out = {"episodes": n, "frames": 81, "size": "512x288", "preset": preset}
    for workers in (1, 2):  # the first run also writes the resume records; the second renders every episode again
        w, c = run_timed(
            OSCAR
            + ["render", "--manifest", str(manifest), "--workers", str(workers), "--preset", preset, "--no-progress"]
            + (["--no-resume"] if workers > 1 else [])
        )
        out[f"workers_{workers}_eps"] = n / w
        out[f"workers_{workers}_cpu_s_per_episode"] = c / n
    # the same command again with nothing changed: every episode's inputs hashed, its record read, nothing rendered
    w, c = run_timed(
        OSCAR + ["render", "--manifest", str(manifest), "--workers", "2", "--preset", preset, "--no-progress"]
    )
    out["rerun_unchanged_wall_s"], out["rerun_unchanged_cpu_s"] = w, c
    w = c = 0.0
    for r in rows[:naive_n]:
        dw, dc = run_timed(
            OSCAR
            + [
                "render",
                "--embodiment",
                r["embodiment"],
                "--trajectory",
                r["trajectory"],
                "--camera",
                r["camera"],
                "--size",
                r["size"],
                "--out",
                r["out"],
                "--preset",
                preset,
            ]
        )
        w, c = w + dw, c + dc
    out["naive_process_per_episode_eps"] = naive_n / w
    out["naive_cpu_s_per_episode"] = c / naive_n
    from oscar_core.render.batch import RenderOptions, read_manifest, render_many

    specs = read_manifest(manifest)
    opts = RenderOptions(preset=preset, threads=1)
    render_many(specs[:2], opts)  # warm: plugins loaded, FK built
    t0, c0 = time.perf_counter(), time.process_time()
    results = render_many(specs, opts)
    out["in_process_api_eps"] = n / (time.perf_counter() - t0)
    out["in_process_api_cpu_s_per_episode"] = (time.process_time() - c0) / n
    assert all(r.ok for r in results)
    return out


def bench_presets(tmp: Path, repeats: int) -> list[dict]:
    from oscar_core import get_embodiment, load_trajectory, render_skeleton_video
    from oscar_core.media.video import read_video, write_video

    emb = get_embodiment("franka")
    traj = load_trajectory(emb.example_trajectory).time_slice(0, 81)
    video = render_skeleton_video(emb, traj, emb.load_camera(emb.example_camera), (512, 288))
    rows = []
    for preset in ("ultrafast", "superfast", "veryfast", "faster", "medium"):
        for yuv in ("opencv", "swscale"):
            path = tmp / f"{preset}_{yuv}.mp4"
            times = []
            for _ in range(repeats):
                t0 = time.process_time()  # CPU seconds: steadier than wall time on a shared machine
                write_video(path, video, traj.fps, preset=preset, yuv=yuv, threads=1)
                times.append(time.process_time() - t0)
            back = read_video(path).astype(np.float64)
            mse = float(np.mean((back - video) ** 2))
            rows.append(
                {
                    "preset": preset,
                    "yuv": yuv,
                    "encode_s": min(times),
                    "kb": path.stat().st_size / 1024,
                    "psnr_db": 10 * np.log10(255**2 / mse),
                }
            )
    # the conversion alone, per frame
    import av

    from oscar_core.media.video import rgb_to_yuv420p

    for yuv, fn in (
        ("opencv", lambda f: rgb_to_yuv420p(f)),
        ("swscale", lambda f: av.VideoFrame.from_ndarray(f, format="rgb24").reformat(format="yuv420p")),
    ):
        t0 = time.process_time()
        for f in video:
            fn(f)
        for r in rows:
            if r["yuv"] == yuv:
                r["convert_ms_per_frame"] = (time.process_time() - t0) / len(video) * 1e3
    return rows


def bench_memory(tmp: Path, long_frames: int) -> dict:
    from oscar_core import get_embodiment, load_trajectory, save_trajectory

    emb = get_embodiment("franka")
    base = load_trajectory(emb.example_trajectory)
    reps = -(-long_frames // len(base))
    out = {"size": "1280x704"}
    for frames in (long_frames // 10, long_frames):
        traj = base.replace(
            q=np.tile(base.q, (reps, 1))[:frames], gripper=np.tile(base.gripper, (reps, 1))[:frames], timestamps=None
        )
        path = tmp / f"long{frames}.npz"
        save_trajectory(traj, path)
        cmd = OSCAR + [
            "render",
            "--embodiment",
            "franka",
            "--trajectory",
            str(path),
            "--camera",
            str(emb.example_camera),
            "--size",
            "1280x704",
            "--out",
            str(tmp / f"long{frames}.mp4"),
        ]
        mb, s = child_peak_rss_mb(cmd)
        out[f"streamed_{frames}_peak_mb"], out[f"streamed_{frames}_s"] = mb, s
    frames = long_frames // 10
    whole = (
        "import sys\nfrom oscar_core import get_embodiment, load_trajectory, render_skeleton_video, write_video\n"
        "e = get_embodiment('franka')\n"
        f"v = render_skeleton_video(e, load_trajectory({str(tmp / f'long{frames}.npz')!r}), "
        "e.load_camera(e.example_camera), (1280, 704))\n"
        f"write_video({str(tmp / 'whole.mp4')!r}, v, 15)\n"
    )
    mb, s = child_peak_rss_mb([PY, "-c", whole])
    out[f"whole_array_{frames}_peak_mb"], out[f"whole_array_{frames}_s"] = mb, s
    return out


def table(rows: list[dict], cols: list[tuple[str, str]]) -> str:
    text = [[c for c, _ in cols]] + [[f.format(r[c]) for c, f in cols] for r in rows]
    widths = [max(len(row[i]) for row in text) for i in range(len(cols))]
    return "\n".join("  ".join(v.rjust(w) for v, w in zip(row, widths)) for row in text)


def main(argv=None) -> int:
    from oscar_core.media.video import DEFAULT_PRESET

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=40, help="episodes for the throughput runs (default 40)")
    ap.add_argument("--naive-episodes", type=int, default=8, help="episodes for the process-per-episode run")
    ap.add_argument("--long-frames", type=int, default=8100, help="frames of the peak-memory render (default 8100)")
    ap.add_argument(
        "--preset", default=DEFAULT_PRESET, help=f"x264 preset for the throughput runs (default {DEFAULT_PRESET})"
    )
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip", nargs="*", default=(), choices=("startup", "throughput", "presets", "memory"))
    ap.add_argument("--json", default=str(HERE / "results" / "render_scale.json"))
    args = ap.parse_args(argv)
    result = {
        "meta": {
            "python": sys.version.split()[0],
            "machine": platform.machine(),
            "cpu_count": os.cpu_count(),
            "load_average_start": os.getloadavg(),
            "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
        }
    }
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if "startup" not in args.skip:
            s = result["startup"] = bench_startup(tmp)
            print("start-up: wall and CPU (user + system) seconds, median of 3")
            print(
                table(
                    [{"command": k, **v} for k, v in s.items()],
                    [("command", "{}"), ("wall_s", "{:.2f}"), ("cpu_s", "{:.2f}")],
                )
            )
        if "throughput" not in args.skip:
            t = result["throughput"] = bench_throughput(tmp, args.episodes, args.naive_episodes, args.preset)
            print(f"\nepisodes/s, {t['episodes']} x 81-frame 512x288 H.264 (preset {t['preset']})")
            print(
                table(
                    [t],
                    [
                        (k, "{:.2f}")
                        for k in (
                            "workers_1_eps",
                            "workers_2_eps",
                            "naive_process_per_episode_eps",
                            "in_process_api_eps",
                        )
                    ],
                )
            )
            print(
                table(
                    [t],
                    [
                        (k, "{:.3f}")
                        for k in (
                            "workers_1_cpu_s_per_episode",
                            "workers_2_cpu_s_per_episode",
                            "naive_cpu_s_per_episode",
                            "in_process_api_cpu_s_per_episode",
                        )
                    ],
                )
            )
            print(table([t], [(k, "{:.2f}") for k in ("rerun_unchanged_wall_s", "rerun_unchanged_cpu_s")]))
        if "presets" not in args.skip:
            p = result["presets"] = bench_presets(tmp, args.repeats)
            print("\nencoder presets, one 81-frame 512x288 franka episode, one thread: CPU seconds (best of repeats)")
            print(
                table(
                    p,
                    [
                        ("preset", "{}"),
                        ("yuv", "{}"),
                        ("encode_s", "{:.3f}"),
                        ("convert_ms_per_frame", "{:.2f}"),
                        ("kb", "{:.0f}"),
                        ("psnr_db", "{:.2f}"),
                    ],
                )
            )
        if "memory" not in args.skip:
            m = result["memory"] = bench_memory(tmp, args.long_frames)
            print("\npeak RSS (MB) and wall seconds, franka at 1280x704, H.264")
            print(table([m], [(k, "{:.1f}" if k.endswith(("mb", "_s")) else "{}") for k in m]))
    result["meta"]["load_average_end"] = os.getloadavg()
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(Path(__file__).resolve().parent))  # benchmarks/: also when a test loads this file
    from _provenance import with_provenance

    out.write_text(json.dumps(with_provenance(result), indent=2))
    print(
        f"\nload average {result['meta']['load_average_start'][0]:.1f} -> {result['meta']['load_average_end'][0]:.1f}; "
        f"wrote {out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
