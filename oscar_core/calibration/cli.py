"""``oscar calibrate``: a fixed camera from skeleton points clicked (or detected) on video frames."""

from __future__ import annotations

import argparse
import json

import numpy as np

from .._util.arg_types import count, number
from ..errors import OscarError

EPILOG = """examples:
  oscar calibrate --embodiment franka --trajectory traj.npz --points points.json --size 1280x720 \\
      --intrinsics intrinsics.json --out cam.json
  oscar calibrate --embodiment franka --trajectory traj.npz --points points.json --size 1280x720 \\
      --estimate-intrinsics --out cam.json --video rgb.mp4 --overlay check.mp4 --json
  oscar calibrate --embodiment franka --trajectory traj.npz --click rgb.mp4 --points points.json \
      --intrinsics intrinsics.json --out cam.json      (click the points on a local web page first)

The points file holds pixel positions of skeleton points per frame (docs/formats.md, "Calibration
points"); with --click VIDEO a page on 127.0.0.1 (its address is printed) shows a few
frames of VIDEO, the clicks are written to --points, then the calibration runs; --intrinsics is a camera JSON (its extrinsic, if any, is ignored) or an object with only
image_size, intrinsics and distortion. Exit status: 0 calibrated, 2 bad input (one line says why).
See docs/calibration.md.
"""


def add_calibrate_parser(sub) -> None:
    """Register ``oscar calibrate`` (and ``oscar calibrate score``) on the top-level sub-parser collection."""
    fmt = argparse.RawDescriptionHelpFormatter
    c = sub.add_parser(
        "calibrate",
        help="estimate a fixed camera from skeleton points on video frames (PnP); "
        "`calibrate score`: how well a camera lines the robot up with a video",
        epilog=EPILOG,
        formatter_class=fmt,
    )
    # required in practice; checked in cmd_calibrate so that `oscar calibrate score ...` parses without them
    c.add_argument("--embodiment", help="embodiment name (see `oscar embodiments`)")
    c.add_argument("--trajectory", help="trajectory .npz (docs/formats.md)")
    c.add_argument("--points", help="pixel positions of skeleton points per frame (.json)")
    c.add_argument("--size", help="WIDTHxHEIGHT of the images the points were read on (with --click: the video's)")
    c.add_argument(
        "--click",
        metavar="VIDEO",
        help="click the points on frames of VIDEO in a local web page first; they are written to --points",
    )
    c.add_argument("--click-frames", type=count(1), default=4, help="frames shown for clicking (default 4)")
    c.add_argument("--port", type=count(0), default=0, help="the click page's port on 127.0.0.1 (default: a free one)")
    how = c.add_mutually_exclusive_group()
    how.add_argument("--intrinsics", metavar="FILE", help="known intrinsics: a camera .json (kept fixed)")
    how.add_argument("--estimate-intrinsics", action="store_true", help="estimate fx, fy, cx, cy too (no distortion)")
    c.add_argument("--out", help="camera .json to write (docs/formats.md)")
    c.add_argument(
        "--threshold",
        type=number(above=0.0),
        default=None,
        help="reprojection error (pixels) above which a point is an outlier (default 4; about 4x the clicking noise)",
    )
    c.add_argument("--video", help="the RGB video the points were read on (for --overlay)")
    c.add_argument("--overlay", metavar="OUT_VIDEO", help="write the skeleton seen by the new camera over --video")
    c.add_argument("--seed", type=count(0), default=0, help="RANSAC seed (default 0)")
    c.add_argument("--json", action="store_true", help="print the full report (per frame, per point) as JSON")
    c.set_defaults(func=cmd_calibrate)

    cs = c.add_subparsers(dest="calibrate_command", metavar="score")
    s = cs.add_parser(
        "score",
        help="how well the robot rendered through a camera lines up with a video, in [0, 1]",
        epilog=SCORE_EPILOG,
        formatter_class=fmt,
    )
    s.add_argument("--video", required=True, help="the RGB video (file or PNG folder), frame t = trajectory frame t")
    s.add_argument("--trajectory", required=True, help="trajectory .npz (docs/formats.md)")
    s.add_argument("--camera", required=True, help="camera .json to score (docs/formats.md)")
    s.add_argument("--embodiment", required=True, help="embodiment name (see `oscar embodiments`)")
    s.add_argument(
        "--threshold",
        type=number(0.0, 255.0),
        default=None,
        help="a pixel moves when one of its R, G, B values (0-255) changes by more (default 20)",
    )
    s.add_argument("--gap", type=count(1), default=None, help="frames between the two frames of a pair (default 1)")
    s.add_argument("--width", type=count(8), default=None, help="working width in pixels (default 160)")
    s.add_argument("--json", action="store_true", help="print the score with every pair's value as JSON")
    s.set_defaults(func=cmd_score)


SCORE_EPILOG = """examples:
  oscar calibrate score --video rgb.mp4 --trajectory traj.npz --camera cam.json --embodiment franka
  oscar calibrate score ... --json

The score is the median, over pairs of consecutive frames where the robot moves, of the
intersection over union of the pixels that change in the video and the pixels that change in
the robot's capsule body rendered through the camera. 1: they coincide; a camera off by a few
centimetres or degrees scores lower. docs/calibration.md.
"""


def _intrinsics(path):
    """Intrinsics from a camera JSON file, with or without an extrinsic."""
    from .._util.json_file import read_json
    from ..camera import camera_from_dict
    from ..errors import CameraFileError

    doc = read_json(path, CameraFileError)
    if isinstance(doc, dict) and "extrinsic" not in doc:  # the extrinsic is not used: any rigid transform will do
        doc = {**doc, "extrinsic": {"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}}
    return camera_from_dict(doc, str(path)).intrinsics


def cmd_calibrate(args) -> int:
    from .._util.outputs import check_writable
    from ..camera import save_camera
    from ..kinematics.trajectory import load_trajectory
    from ..media.video import check_output
    from ..plugin.registry import Registry
    from ..render.skeleton_video import parse_size
    from .pnp import calibrate
    from .points import load_points

    missing = [
        f"--{n.replace('_', '-')}"
        for n in ("embodiment", "trajectory", "points", "size", "out")
        if not getattr(args, n) and not (n == "size" and args.click)
    ]
    if missing:
        raise OscarError(f"calibrate: expected {', '.join(missing)} (see oscar calibrate --help)")
    if not args.intrinsics and not args.estimate_intrinsics:
        raise OscarError("calibrate: expected --intrinsics FILE or --estimate-intrinsics")
    if bool(args.video) != bool(args.overlay):
        raise OscarError("calibrate: --video and --overlay go together (the overlay is drawn over the video)")
    if args.click:
        from ..media.video import video_info

        check_writable(args.points, "file")
        info = video_info(args.click)
        size = (info["width"], info["height"])
        if args.size and parse_size(args.size) != size:
            raise OscarError(f"--size {args.size}: expected the size of --click {args.click}, {size[0]}x{size[1]}")
    else:
        size = parse_size(args.size)
    if args.overlay:
        check_output(args.overlay)
    check_writable(args.out, "file")
    emb = Registry(plugin_paths=args.plugin or ()).get(args.embodiment)
    traj = load_trajectory(args.trajectory)
    if args.overlay:  # the video the overlay is drawn over is checked before anything is fitted or written
        _check_video_length(args.video, len(traj), args.trajectory)
    intr = None if args.estimate_intrinsics else _intrinsics(args.intrinsics)
    if args.click:
        from .click import click_points_on_video

        def ready(url):
            print(f"click the points at {url} (then Save)", flush=True)

        click_points_on_video(
            emb, len(traj), args.click, args.points, count=args.click_frames, port=args.port, on_ready=ready
        )
        print(f"wrote {args.points}")
    points = load_points(args.points)
    kwargs = {} if args.threshold is None else {"threshold_px": args.threshold}
    result = calibrate(emb, traj, points, size, intr, seed=args.seed, **kwargs)
    report = result.to_dict()
    report["out"] = str(args.out)
    if args.overlay:  # the overlay first: a run that fails while drawing it leaves no camera behind
        from ..render.overlay import write_overlay

        path, frames, _, _ = write_overlay(
            emb, traj, result.camera, args.video, args.overlay, size=size, camera_source=str(args.out)
        )
        report["overlay"] = str(path)
    save_camera(result.camera, args.out)
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    _print_report(result, args)
    return 0


def _check_video_length(video, frames: int, trajectory) -> None:
    """``video`` (the overlay's background) is readable and holds at least the trajectory's ``frames`` frames."""
    from ..errors import InputFileError
    from ..media.video import video_info

    try:
        n = int(video_info(video)["frames"])
    except (OSError, ValueError) as exc:
        raise InputFileError(video, "video", "a readable video or folder of PNG frames", str(exc)) from None
    if n < frames:
        raise InputFileError(
            video, "frames", f"at least {frames} frames (the length of {trajectory}, for --overlay)", f"{n} frames"
        )


def _print_report(result, args) -> None:
    i = result.camera.intrinsics
    print(
        f"wrote {args.out}: {int(result.inlier.sum())} of {len(result.residual_px)} points within "
        f"{result.threshold_px:g} px, rms {result.rms_px:.2f} px; fx {i.fx:.1f} fy {i.fy:.1f} cx {i.cx:.1f} "
        f"cy {i.cy:.1f}{' (estimated)' if result.estimated_intrinsics else ''}"
    )
    print("per point:")
    for r in result.per_point:
        print(
            f"  {r['point']:<24} {r['points']:4d} points  mean {r['mean_px']:6.2f} px  max {r['max_px']:6.2f} px"
            f"  {r['outliers']} outliers"
        )
    worst = sorted(result.per_frame, key=lambda r: -r["mean_px"])[:5]
    print("worst frames: " + ", ".join(f"{r['frame']} ({r['mean_px']:.2f} px)" for r in worst))
    for r in result.outliers[:20]:
        print(
            f"outlier: points[{r['index']}] frame {r['frame']} {r['point']}: {r['residual_px']:.1f} px",
        )
    if len(result.outliers) > 20:
        print(f"outlier: … and {len(result.outliers) - 20} more (--json lists them all)")
    if getattr(args, "overlay", None):
        print(f"wrote {args.overlay}")


def cmd_score(args) -> int:
    from dataclasses import fields

    from ..kinematics.trajectory import load_trajectory
    from ..plugin.registry import Registry
    from .score import ScoreConfig, calibration_score

    emb = Registry(plugin_paths=args.plugin or ()).get(args.embodiment)
    traj = load_trajectory(args.trajectory)
    cam = emb.load_camera(args.camera)
    overrides = {f.name: getattr(args, f.name) for f in fields(ScoreConfig) if getattr(args, f.name, None) is not None}
    result = calibration_score(args.video, emb, traj, cam, ScoreConfig(**overrides), camera_source=str(args.camera))
    if args.json:
        print(json.dumps({"video": str(args.video), "camera": str(args.camera), **result.to_dict()}, indent=2))
        return 0
    if result.pairs == 0:
        print(f"score: none (the robot does not move between any pair of frames of {args.trajectory})")
        return 0
    values = [r["iou"] for r in result.per_pair if r["counted"]]
    print(
        f"score {result.score:.3f} (median over {result.pairs} frame pairs where the robot moves; "
        f"quartiles {float(np.percentile(values, 25)):.3f}-{float(np.percentile(values, 75)):.3f})"
    )
    return 0
