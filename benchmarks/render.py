"""Skeleton-video rendering speed: oscar's batched pipeline against the naive way.

    python benchmarks/render.py [--repeats 7] [--json benchmarks/results/render.json]

For 81-frame trajectories at 512x288 and 1280x704, on one CPU core
(torch, OpenCV and BLAS limited to one thread), it times per frame:
FK, projection, rasterisation and H.264 encoding, and the same job done the
naive way (yourdfpy FK frame by frame, cv2.projectPoints and a fresh canvas
per frame). Prints a table and writes JSON. Timings on shared machines
swing; compare the ratios within one run.

The mesh condition (docs/mesh-condition.md) is timed beside it at 512x288:
render_mesh_video over the same trajectories with the full meshes and without
back-face culling (the naive way), then culled, then simplified at several
vertex-clustering cells, each with its silhouette IoU against the full meshes
and its triangle count; and the peak traced memory of the streamed renderer
for a trajectory and the same trajectory five times as long.

    python benchmarks/render.py --skip-skeleton --mesh-embodiments franka toyarm

The capsules condition (docs/mesh-condition.md, "The capsules condition") is timed on each
``--capsule-embodiments`` example trajectory at 512x288 and at the toy world's 64x64
(``--skip-capsules`` leaves it out).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from oscar_core import get_embodiment, load_camera, load_trajectory  # noqa: E402
from oscar_core.camera import project  # noqa: E402
from oscar_core.media.video import write_video  # noqa: E402
from oscar_core.render.raster import GripperMarks, SkeletonStyle, rasterise  # noqa: E402

SIZES = ((512, 288), (1280, 704))
FRAMES = 81


def best_and_median(fn, repeats: int) -> tuple[float, float]:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times), statistics.median(times)


class NaiveUnavailable(Exception):
    """The naive reference cannot render this embodiment (its reason is the message)."""


def naive_render(emb, traj, cam, size):
    """yourdfpy FK per frame, cv2.projectPoints per frame, lines and circles on a new canvas."""
    import io

    import yourdfpy

    from oscar_core.kinematics.urdf import expand_xacro

    source = (
        str(emb.urdf) if emb.urdf is not None else io.StringIO(expand_xacro(emb.xacro, emb.xacro_args, emb.packages))
    )
    robot = yourdfpy.URDF.load(
        source,
        load_meshes=False,
        build_scene_graph=True,
        load_collision_meshes=False,
        build_collision_scene_graph=False,
    )
    links = list(emb.skeleton.links)
    missing = [link for link in links if link not in robot.link_map]
    if missing:  # e.g. franka_robotiq: its tree is composed in code, its `urdf` is the arm alone
        raise NaiveUnavailable(f"the plugin's URDF lacks skeleton links {missing[:3]}")
    q_full = emb.full_configuration(traj)
    offsets = emb.skeleton.point_offsets()
    edges = emb.edge_index()
    pc, ec = emb.colors()
    K = cam.intrinsics.matrix()
    dist = np.array(cam.intrinsics.distortion or [0, 0, 0, 0], float)
    W, H = size
    scale = min(W, H) / 288
    thick, rad = max(1, round(2 * scale)), max(1, round(3 * scale))
    frames = []
    for t in range(len(traj)):
        robot.update_cfg(q_full[t])
        pts = np.array(
            [(robot.get_transform(l, robot.base_link) @ np.append(o, 1.0))[:3] for l, o in zip(links, offsets)]
        )
        mount = None if cam.mount_link is None else robot.get_transform(cam.mount_link, robot.base_link)
        T_cv_world = cam.world_to_cv(mount)
        rvec, _ = cv2.Rodrigues(T_cv_world[:3, :3])
        uv, _ = cv2.projectPoints(pts, rvec, T_cv_world[:3, 3], K, dist)
        uv = uv.reshape(-1, 2)
        img = np.zeros((H, W, 3), np.uint8)
        for e, (a, b) in enumerate(edges):
            cv2.line(
                img,
                tuple(int(round(v)) for v in uv[a]),
                tuple(int(round(v)) for v in uv[b]),
                tuple(int(c) for c in ec[e]),
                thick,
                cv2.LINE_AA,
            )
        for k in range(len(links)):
            cv2.circle(img, tuple(int(round(v)) for v in uv[k]), rad, tuple(int(c) for c in pc[k]), -1, cv2.LINE_AA)
        frames.append(img)
    return np.stack(frames)


def bench_embodiment(name: str, repeats: int) -> list[dict]:
    emb = get_embodiment(name)
    traj = emb.check_trajectory(load_trajectory(emb.example_trajectory))
    traj = traj.time_slice(0, FRAMES)
    base_cam = load_camera(emb.example_camera)
    T = len(traj)
    rows = []
    for size in SIZES:
        cam = base_cam.resized(*size)
        frames = emb.frames(traj, mount_link=cam.mount_link)
        fk_s, fk_m = best_and_median(lambda: emb.frames(traj, mount_link=cam.mount_link), repeats)

        def do_project():
            p = project(frames.points, cam, mount_pose=frames.mount_pose)
            g = project(frames.gripper_points, cam, mount_pose=frames.mount_pose)
            return p, g

        proj_s, proj_m = best_and_median(do_project, repeats)
        p, g = do_project()
        marks = GripperMarks(g.uv, g.in_front, frames.openness)
        pc, ec = emb.colors()
        edges = emb.edge_index()
        style = SkeletonStyle()

        def raster():
            return rasterise(
                p.uv, p.in_front, edges, size, edge_colors=ec, point_colors=pc, grippers=marks, style=style
            )

        ras_s, ras_m = best_and_median(raster, repeats)
        video = raster()
        with tempfile.TemporaryDirectory() as tmp:
            enc_s, enc_m = best_and_median(
                lambda: write_video(Path(tmp) / "b.mp4", video, traj.fps, threads=1), max(2, repeats // 2)
            )
            mp4_kb = (Path(tmp) / "b.mp4").stat().st_size / 1024
        try:
            naive_s, _ = best_and_median(lambda: naive_render(emb, traj, cam, size), max(2, repeats // 3))
            naive = {"naive_us": naive_s / T * 1e6, "naive_fps": T / naive_s}
        except NaiveUnavailable as e:
            naive_s, naive = None, {"naive_us": None, "naive_fps": None, "naive_skipped": str(e)}
        pipeline = fk_s + proj_s + ras_s
        rows.append(
            {
                "embodiment": name,
                "size": f"{size[0]}x{size[1]}",
                "frames": T,
                "points": len(emb.skeleton.links),
                "fk_us": fk_s / T * 1e6,
                "project_us": proj_s / T * 1e6,
                "raster_us": ras_s / T * 1e6,
                "encode_us": enc_s / T * 1e6,
                "pipeline_fps": T / pipeline,
                "pipeline_with_h264_fps": T / (pipeline + enc_s),
                **naive,
                "speedup_vs_naive": None if naive_s is None else naive_s / pipeline,
                "mp4_kb": mp4_kb,
                "median_pipeline_fps": T / (fk_m + proj_m + ras_m),
            }
        )
    return rows


MESH_CELLS = (None, 0.005, 0.008, 0.01)  # metres; None: the meshes as given


def _mesh_fps(emb, traj, cam, style, repeats: int) -> tuple[float, float, np.ndarray]:
    from oscar_core.render.mesh import render_mesh_video

    render_mesh_video(emb, traj.time_slice(0, 1), cam, style=style)  # loads and simplifies the meshes once
    video = None

    def run():
        nonlocal video
        video = render_mesh_video(emb, traj, cam, style=style)

    best, median = best_and_median(run, repeats)
    return len(traj) / best, len(traj) / median, video


def _stream_peak_mb(emb, traj, cam) -> float:
    """Peak traced memory (MB) of streaming ``traj`` chunk by chunk, each chunk dropped as a writer would."""
    import tracemalloc

    from oscar_core.render.mesh import iter_mesh_chunks

    tracemalloc.start()
    for _ in iter_mesh_chunks(emb, traj, cam, chunk_frames=16):
        pass
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / 2**20


def bench_mesh(name: str, repeats: int, size=(512, 288)) -> list[dict]:
    """The mesh condition of ``name``'s example trajectory at ``size``, per simplification."""
    from oscar_core.kinematics.trajectory import Trajectory
    from oscar_core.render.mesh import MeshStyle, mesh_geometry

    emb = get_embodiment(name)
    traj = emb.check_trajectory(load_trajectory(emb.example_trajectory)).time_slice(0, FRAMES)
    cam = load_camera(emb.example_camera).resized(*size)
    rows, full = [], None
    for cell, cull in [(None, False)] + [(c, True) for c in MESH_CELLS]:
        style = MeshStyle(simplify=cell, cull_back=cull)
        fps, median_fps, video = _mesh_fps(emb, traj, cam, style, repeats)
        sil = video.any(-1)
        if full is None:
            full = sil
        inter, union = (sil & full).sum((1, 2)), (sil | full).sum((1, 2))
        iou = inter / np.maximum(union, 1)
        rows.append(
            {
                "embodiment": name,
                "size": f"{size[0]}x{size[1]}",
                "frames": len(traj),
                "simplify_m": cell,
                "cull_back": cull,
                "triangles": mesh_geometry(emb, cell).face_count,
                "fps": fps,
                "median_fps": median_fps,
                "us_per_frame": 1e6 / fps,
                "silhouette_iou_mean": float(iou.mean()),
                "silhouette_iou_min": float(iou.min()),
                "silhouette_pixels_differing": float((sil != full).sum((1, 2)).mean()),
                "silhouette_pixels": float(full.sum((1, 2)).mean()),
            }
        )
    long = Trajectory(
        traj.joint_names, np.concatenate([traj.q] * 5), traj.fps, np.concatenate([traj.gripper] * 5), traj.gripper_names
    )
    rows[-1]["stream_peak_mb"] = {
        len(traj): _stream_peak_mb(emb, traj, cam),
        len(long): _stream_peak_mb(emb, long, cam),
    }
    return rows


def print_mesh_table(rows: list[dict]) -> None:
    cols = [
        ("embodiment", "{}"),
        ("size", "{}"),
        ("simplify_m", "{}"),
        ("cull_back", "{}"),
        ("triangles", "{}"),
        ("us_per_frame", "{:.0f}"),
        ("fps", "{:.0f}"),
        ("median_fps", "{:.0f}"),
        ("silhouette_iou_mean", "{:.4f}"),
        ("silhouette_iou_min", "{:.4f}"),
    ]
    table = [[c for c, _ in cols]] + [["n/a" if r[c] is None else f.format(r[c]) for c, f in cols] for r in rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(cols))]
    print(
        f"mesh condition, {FRAMES}-frame trajectories, one CPU thread (best of repeats); "
        "IoU of the silhouette against the full meshes"
    )
    for row in table:
        print("  ".join(v.rjust(w) for v, w in zip(row, widths)))
    for r in rows:
        if "stream_peak_mb" in r:
            print(
                f"{r['embodiment']}: streamed peak traced memory (MB) by trajectory length: "
                + ", ".join(f"{n} frames {mb:.1f}" for n, mb in r["stream_peak_mb"].items())
            )


def bench_capsules(name: str, repeats: int, sizes=((512, 288), (64, 64))) -> list[dict]:
    """render_capsule_video of ``name``'s example trajectory, per size: microseconds per frame, frames/s."""
    from oscar_core.render.capsules import body_reach, render_capsule_video

    emb = get_embodiment(name)
    traj, cam = load_trajectory(emb.example_trajectory), load_camera(emb.example_camera)
    body_reach(emb)  # computed once per embodiment and cached: not part of a frame's cost
    rows = []
    for size in sizes:
        best, median = best_and_median(lambda: render_capsule_video(emb, traj, cam, size), repeats)
        rows.append(
            {
                "embodiment": name,
                "size": f"{size[0]}x{size[1]}",
                "frames": len(traj),
                "edges": len(emb.edges),
                "us_per_frame": best / len(traj) * 1e6,
                "fps": len(traj) / best,
                "median_fps": len(traj) / median,
            }
        )
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--embodiments", nargs="*", help="default: every registered embodiment with a bundled example")
    ap.add_argument("--json", default=str(Path(__file__).parent / "results" / "render.json"))
    ap.add_argument(
        "--mesh-embodiments",
        nargs="*",
        default=["franka", "toyarm"],
        help="embodiments whose mesh condition is timed (default: franka toyarm)",
    )
    ap.add_argument("--skip-skeleton", action="store_true", help="time the mesh condition only")
    ap.add_argument("--skip-mesh", action="store_true", help="time the skeleton only")
    ap.add_argument(
        "--capsule-embodiments",
        nargs="*",
        default=["toyarm", "franka", "kuka", "hsr", "agibot_g1"],
        help="embodiments whose capsules condition is timed",
    )
    ap.add_argument("--skip-capsules", action="store_true", help="leave the capsules condition out")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    from oscar_core import default_registry

    reg = default_registry()
    names = args.embodiments or [
        n for n in reg.names() if reg.get(n).example_trajectory is not None and reg.get(n).uses_kinematic_tree()
    ]
    rows = [] if args.skip_skeleton else [r for n in names for r in bench_embodiment(n, args.repeats)]
    cols = [
        ("embodiment", "{}"),
        ("size", "{}"),
        ("points", "{}"),
        ("fk_us", "{:.1f}"),
        ("project_us", "{:.1f}"),
        ("raster_us", "{:.1f}"),
        ("encode_us", "{:.0f}"),
        ("pipeline_fps", "{:.0f}"),
        ("pipeline_with_h264_fps", "{:.0f}"),
        ("naive_fps", "{:.0f}"),
        ("speedup_vs_naive", "{:.1f}x"),
    ]
    table = [[c for c, _ in cols]] + [["n/a" if r[c] is None else f.format(r[c]) for c, f in cols] for r in rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(cols))]
    print(f"per-frame costs in microseconds, {FRAMES}-frame trajectories, one CPU thread (best of repeats)")
    for row in table:
        print("  ".join(v.rjust(w) for v, w in zip(row, widths)))
    mesh_rows = [] if args.skip_mesh else [r for n in args.mesh_embodiments for r in bench_mesh(n, args.repeats)]
    if mesh_rows:
        print_mesh_table(mesh_rows)
    capsule_rows = (
        [] if args.skip_capsules else [r for n in args.capsule_embodiments for r in bench_capsules(n, args.repeats)]
    )
    if capsule_rows:
        print(f"capsules condition, example trajectories, one CPU thread (best of {args.repeats}; median beside it)")
        for r in capsule_rows:
            print(
                f"  {r['embodiment']:>10s} {r['size']:>8s} {r['edges']:>3d} edges  {r['us_per_frame']:8.0f} us/frame  "
                f"{r['fps']:6.0f} fps  (median {r['median_fps']:.0f})"
            )
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "python": sys.version.split()[0],
        "torch": torch.__version__,
        "opencv": cv2.__version__,
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "threads": 1,
        "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
    }
    sys.path.insert(0, str(Path(__file__).resolve().parent))  # benchmarks/: also when a test loads this file
    from _provenance import with_provenance

    out.write_text(
        json.dumps(
            with_provenance({"meta": meta, "rows": rows, "mesh_rows": mesh_rows, "capsule_rows": capsule_rows}),
            indent=2,
        )
    )
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
