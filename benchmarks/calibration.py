"""Calibration accuracy against clicking noise, and the calibration score's separation of right from wrong cameras.

    python benchmarks/calibration.py pnp   [--seeds 10] [--json benchmarks/results/calibration_pnp.json]
    python benchmarks/calibration.py score [--episodes 6] [--size 160x120] [--json benchmarks/results/calibration_score.json]

``pnp``: for franka and kuka, ``--seeds`` synthetic problems each
(:func:`oscar_core.calibration.synthetic.problem`): a random smooth trajectory (49 frames
through 5 random configurations inside the joint limits), a 640x480 camera (fx = fy =
600 px) looking at the workspace from 1.6-2.0 m at a random azimuth and elevation, every
4th frame observed with 80 % of its visible skeleton points, Gaussian pixel noise
sigma = 0.5, 1, 2 px per axis and the outlier threshold max(4, 4 sigma) px. It recovers the camera with the intrinsics known and estimated and
reports the rotation error (degrees), the optical-centre error (mm) and, when
estimated, the focal length error (%) and principal point error (px): median and
maximum over the seeds. The naive way, in the same run: RANSAC PnP alone (OpenCV's
``solvePnPRansac`` with its own refinement on its inliers), no least squares over all frames.

``score``: toy-world episodes (:mod:`oscar_core.toyworld`, seed 0, ``--size`` (default 160x120), 24 frames)
of toyarm, franka and kuka with their true cameras; the score of the true camera and of
cameras moved by 2, 5, 10 cm along each of the camera's axes and turned by 2, 5 degrees
about each axis
(:func:`oscar_core.calibration.score.perturb_camera`). Reports the mean score per
perturbation (with its range over the episodes) and the fraction of episodes where the true camera scores higher,
and the CPU seconds beside the wall time.

Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

from oscar_core.calibration.synthetic import SIZE, problem  # noqa: E402
from oscar_core.camera import Camera  # noqa: E402
from oscar_core.plugin.registry import default_registry  # noqa: E402

SIGMAS = (0.5, 1.0, 2.0)


def threshold_for(sigma: float) -> float:
    """The outlier threshold used with clicking noise ``sigma`` (pixels)."""
    return max(4.0, 4.0 * sigma)


def ransac_only(emb, traj, points, intr, threshold):
    """The naive way: OpenCV's RANSAC PnP alone; returns the camera."""
    import cv2

    from oscar_core.calibration.pnp import build_correspondences

    corr = build_correspondences(emb, traj, points, SIZE)
    cv2.setRNGSeed(0)
    ok, rvec, tvec, _ = cv2.solvePnPRansac(
        corr.xyz.reshape(-1, 1, 3),
        corr.uv.reshape(-1, 1, 2),
        intr.matrix(),
        np.zeros(0),
        iterationsCount=2000,
        reprojectionError=threshold,
        confidence=0.999,
    )
    R, _ = cv2.Rodrigues(rvec)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = R.T, -R.T @ tvec.ravel()
    return Camera(intr, pose)


def bench_pnp(seeds: int) -> dict:
    from oscar_core.calibration.pnp import calibrate, position_error_mm, rotation_error_deg

    reg = default_registry()
    runs = []
    for name in ("franka", "kuka"):
        emb = reg.get(name)
        for seed in range(seeds):
            for sigma in SIGMAS:
                traj, cam, pts = problem(emb, seed, sigma)
                thr = threshold_for(sigma)
                for method in ("ransac only", "known intrinsics", "estimated intrinsics"):
                    t0 = time.perf_counter()
                    if method == "ransac only":
                        got = ransac_only(emb, traj, pts, cam.intrinsics, thr)
                    else:
                        intr = cam.intrinsics if method == "known intrinsics" else None
                        got = calibrate(emb, traj, pts, SIZE, intr, threshold_px=thr).camera
                    i, t = got.intrinsics, cam.intrinsics
                    runs.append(
                        {
                            "embodiment": name,
                            "seed": seed,
                            "sigma": sigma,
                            "method": method,
                            "points": len(pts),
                            "seconds": time.perf_counter() - t0,
                            "rotation_deg": rotation_error_deg(got, cam),
                            "position_mm": position_error_mm(got, cam),
                            "focal_pct": 100 * max(abs(i.fx - t.fx), abs(i.fy - t.fy)) / t.fx,
                            "principal_px": float(np.hypot(i.cx - t.cx, i.cy - t.cy)),
                        }
                    )
    rows = []
    for method in ("ransac only", "known intrinsics", "estimated intrinsics"):
        for sigma in SIGMAS:
            sel = [r for r in runs if r["method"] == method and r["sigma"] == sigma]
            row = {"method": method, "sigma": sigma, "runs": len(sel)}
            for k in ("rotation_deg", "position_mm", "focal_pct", "principal_px"):
                v = np.array([r[k] for r in sel])
                row[f"{k}_median"], row[f"{k}_max"] = float(np.median(v)), float(v.max())
            row["seconds_median"] = float(np.median([r["seconds"] for r in sel]))
            rows.append(row)
    return {"rows": rows, "runs": runs}


def print_pnp(res: dict) -> None:
    print(
        f"{'method':<22}{'sigma px':>9}{'rot deg med/max':>18}{'pos mm med/max':>17}{'f % med/max':>14}"
        f"{'c px med/max':>15}{'s':>7}"
    )
    for r in res["rows"]:
        print(
            f"{r['method']:<22}{r['sigma']:>9g}{r['rotation_deg_median']:>10.3f}/{r['rotation_deg_max']:<7.3f}"
            f"{r['position_mm_median']:>9.1f}/{r['position_mm_max']:<7.1f}{r['focal_pct_median']:>7.2f}/"
            f"{r['focal_pct_max']:<6.2f}{r['principal_px_median']:>7.1f}/{r['principal_px_max']:<7.1f}"
            f"{r['seconds_median']:>7.3f}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("part", choices=("pnp", "score"))
    ap.add_argument("--seeds", type=int, default=10, help="pnp: synthetic problems per embodiment")
    ap.add_argument("--episodes", type=int, default=6, help="score: toy-world episodes per embodiment")
    ap.add_argument("--size", default="160x120", help="score: WIDTHxHEIGHT of the toy-world videos (default 160x120)")
    ap.add_argument("--json", help="output JSON (default benchmarks/results/calibration_<part>.json)")
    args = ap.parse_args()
    t0, c0 = time.perf_counter(), time.process_time()
    if args.part == "pnp":
        res = bench_pnp(args.seeds)
        print_pnp(res)
    else:
        w, h = (int(v) for v in args.size.lower().split("x"))
        res = bench_score(args.episodes, (w, h))
        print_score(res)
    res["meta"] = {
        "command": f"python benchmarks/calibration.py {args.part}",
        "seeds": args.seeds,
        "episodes": args.episodes,
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "wall_s": time.perf_counter() - t0,
        "cpu_s": time.process_time() - c0,
        "load_1min": os.getloadavg()[0],
    }
    out = Path(args.json or Path(__file__).parent / "results" / f"calibration_{args.part}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1))
    print(f"wrote {out} ({res['meta']['wall_s']:.0f} s)")


SHIFTS_CM = (2, 5, 10)
TURNS_DEG = (2, 5)
AXES = "xyz"
TOY_SIZE, TOY_FRAMES = (160, 120), 24


def perturbations():
    """(label, shift metres, rotation degrees) of every wrong camera scored, in the camera's OpenCV axes."""
    out = []
    for d in SHIFTS_CM:
        for k, axis in enumerate(AXES):
            shift = np.zeros(3)
            shift[k] = d / 100
            out.append((f"{d} cm along {axis}", shift, np.zeros(3)))
    for a in TURNS_DEG:
        for k, axis in enumerate(AXES):
            turn = np.zeros(3)
            turn[k] = a
            out.append((f"{a} deg about {axis}", np.zeros(3), turn))
    return out


def bench_score(episodes: int, size=TOY_SIZE) -> dict:
    from oscar_core.calibration.score import calibration_score, perturb_camera
    from oscar_core.toyworld.episode import episode_rng, make_episode

    reg = default_registry()
    runs = []
    for name in ("toyarm", "franka", "kuka"):
        emb = reg.get(name)
        for i in range(episodes):
            ep = make_episode(emb, episode_rng(0, name, i), *size, TOY_FRAMES, 10.0)
            t0 = time.perf_counter()
            true = calibration_score(ep.rgb, emb, ep.trajectory, ep.camera).score
            seconds = time.perf_counter() - t0
            row = {"embodiment": name, "episode": i, "true": true, "seconds": seconds, "perturbed": {}}
            for label, shift, turn in perturbations():
                row["perturbed"][label] = calibration_score(
                    ep.rgb, emb, ep.trajectory, perturb_camera(ep.camera, shift, turn)
                ).score
            runs.append(row)
            print(f"  {name} episode {i}: true {true:.3f}", flush=True)
    rows = [
        {
            "camera": "true",
            "mean": float(np.mean([r["true"] for r in runs])),
            "min": float(np.min([r["true"] for r in runs])),
            "max": float(np.max([r["true"] for r in runs])),
            "true_higher": None,
        }
    ]
    for label, _, _ in perturbations():
        v = np.array([r["perturbed"][label] for r in runs])
        t = np.array([r["true"] for r in runs])
        rows.append(
            {
                "camera": label,
                "mean": float(v.mean()),
                "min": float(v.min()),
                "max": float(v.max()),
                "true_higher": float((t > v).mean()),
                "margin_min": float((t - v).min()),
            }
        )
    return {
        "rows": rows,
        "runs": runs,
        "episodes": len(runs),
        "size": list(size),
        "seconds_per_score": float(np.median([r["seconds"] for r in runs])),
    }


def print_score(res: dict) -> None:
    print(f"{'camera':<18}{'mean score':>11}{'range':>14}{'true higher':>13}{'min margin':>12}")
    for r in res["rows"]:
        higher = "" if r["true_higher"] is None else f"{100 * r['true_higher']:.0f} %"
        margin = "" if r["true_higher"] is None else f"{r['margin_min']:+.3f}"
        span = f"{r['min']:.2f}-{r['max']:.2f}"
        print(f"{r['camera']:<18}{r['mean']:>11.3f}{span:>14}{higher:>13}{margin:>12}")
    w, h = res["size"]
    print(f"{res['episodes']} episodes at {w}x{h}, {res['seconds_per_score']:.2f} s per score")


if __name__ == "__main__":
    main()
