"""``oscar render``: one trajectory, or many (a manifest or a folder) through a worker pool."""

from __future__ import annotations

import argparse
import json
import sys
import time

from .._util.arg_types import count, device, number
from .._util.outputs import output_option
from .._util.threads import threads_option
from ..errors import OscarError
from .conditions import CONDITIONS

EPILOG = """examples:
  oscar render --embodiment toyarm --trajectory traj.npz --camera cam.json --out skel.mp4 --size 512x288
  oscar render ... --out skel.mkv              (lossless FFV1)
  oscar render ... --condition mesh --out mesh.mp4   (the robot's URDF visual geometry instead of the skeleton)
  oscar render ... --out frames/               (PNG frames; or --format png)
  oscar render ... --condition-style '{"gripper_radius_open": 27}' --out bold.mp4   (a model card's condition_style)
  oscar render --manifest episodes.jsonl --workers 2 --json
  oscar render --embodiment franka --trajectories trajs/ --out videos/ --size 512x288 --workers 2

A manifest is JSONL or CSV with the fields embodiment, trajectory, camera, out
(and optionally size, fps, resize, format, condition); see docs/formats.md. With
--trajectories each DIR/<stem>.npz uses DIR/<stem>.json, else DIR/camera.json,
else --camera, and writes OUT/<stem>.mp4 (or .mkv, or <stem>/ with --format).
Exit status: 0 all written, 1 some episodes failed (listed), 2 bad arguments.
"""


def add_render_parser(sub) -> None:
    """Register ``oscar render`` on the sub-command parsers ``sub``."""
    from ..media.video_options import DEFAULT_PRESET, DEFAULT_YUV, PRESETS, YUV_PATHS

    r = sub.add_parser(
        "render",
        help="render skeleton (or mesh) condition videos from trajectories (one, or many with a worker pool)",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    r.add_argument("--embodiment", help="embodiment name (see `oscar embodiments`)")
    r.add_argument("--trajectory", help="trajectory .npz (docs/formats.md)")
    r.add_argument("--camera", help="camera calibration .json (docs/formats.md)")
    output_option(
        r.add_argument(
            "--out",
            help="output: .mp4 (H.264), .mkv (lossless FFV1) or a folder/ (PNG frames); "
            "with --trajectories, the output folder",
        ),
        "any",
    )
    r.add_argument("--manifest", help="render every episode of this .jsonl/.csv manifest (docs/formats.md)")
    r.add_argument("--trajectories", metavar="DIR", help="render every DIR/*.npz (cameras beside them) into --out")
    r.add_argument(
        "--format",
        choices=("mp4", "mkv", "png"),
        help="output format instead of the suffix (png: a folder of PNG frames)",
    )
    r.add_argument(
        "--condition",
        choices=CONDITIONS,
        default="skeleton",
        help="condition video: the skeleton (default), the robot's visual geometry (mesh; "
        "needs <visual> elements and the mesh extra: docs/mesh-condition.md) or capsules along "
        "the skeleton with fingers (capsules; any kinematic tree)",
    )
    r.add_argument(
        "--condition-style",
        metavar="JSON",
        help="how the skeleton is drawn, a JSON mapping of skeleton style fields (sizes in pixels at 288 px of "
        "height), as a model card's condition_style, e.g. '{\"gripper_radius_open\": 27}' (default: the standard "
        "look; the skeleton condition only)",
    )
    r.add_argument("--size", help="output WIDTHxHEIGHT, e.g. 512x288 (default: the calibration's image size)")
    r.add_argument(
        "--resize",
        choices=("crop", "stretch"),
        default="crop",
        help="how the calibration is fitted to --size of another aspect ratio (default: centre crop)",
    )
    r.add_argument("--overlay", metavar="RGB_VIDEO", help="blend the skeleton over this video to check the calibration")
    r.add_argument("--alpha", type=number(0.0, 1.0), default=0.8, help="overlay opacity of the skeleton (default 0.8)")
    r.add_argument("--fps", type=number(above=0.0), help="output frame rate (default: the trajectory's)")
    r.add_argument(
        "--device", type=device, default="cpu", help="device for forward kinematics (cpu: NumPy; cuda: torch)"
    )
    r.add_argument("--workers", type=count(1), default=1, help="processes rendering episodes in parallel (default 1)")
    threads_option(r, "torch CPU threads per process (forward kinematics, meshes)")
    # only a batch (--manifest / --trajectories) with --resume keeps finished episodes for the same command
    r.set_defaults(_resumes=lambda a: bool(a.manifest or a.trajectories) and a.resume)
    r.add_argument(
        "--preset",
        choices=PRESETS,
        default=DEFAULT_PRESET,
        help=f"x264 speed preset for .mp4 (default {DEFAULT_PRESET}; README lists speed and quality)",
    )
    r.add_argument("--crf", type=count(0), default=18, help="x264 quality, lower is better (default 18)")
    r.add_argument(
        "--yuv",
        choices=YUV_PATHS,
        default=DEFAULT_YUV,
        help=f"RGB to yuv420p conversion for .mp4 (default {DEFAULT_YUV}; both BT.601 limited range)",
    )
    r.add_argument(
        "--strict",
        action="store_true",
        help="a frame where the camera sees nothing of the robot is an error (default: a warning)",
    )
    r.add_argument("--json", action="store_true", help="print a machine-readable summary")
    r.add_argument(
        "--resume",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="batches: skip episodes whose output and its .<name>.oscar-render.json record match the "
        "inputs and settings (default); --no-resume renders every episode again",
    )
    r.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar on stderr (default: when stderr is a terminal)",
    )
    r.set_defaults(func=cmd_render)


def _size(text):
    from .skeleton_video import parse_size

    return parse_size(text) if text else None


def _specs(args):
    from .batch_specs import EpisodeSpec, read_manifest, specs_from_folder

    if args.manifest and args.trajectories:
        raise OscarError("render: give --manifest or --trajectories, not both")
    if args.manifest:
        extra = [f"--{n}" for n in ("embodiment", "trajectory", "camera", "out") if getattr(args, n)]
        if extra:
            raise OscarError(f"render --manifest: the manifest names each episode's files; drop {' '.join(extra)}")
        specs = read_manifest(args.manifest)
        size, fmt = _size(args.size), args.format
        if size or fmt or args.fps:
            from dataclasses import replace

            specs = [replace(s, size=s.size or size, format=s.format or fmt, fps=s.fps or args.fps) for s in specs]
        return specs, True
    if args.trajectories:
        missing = [f"--{n}" for n in ("embodiment", "out") if not getattr(args, n)]
        if missing:
            raise OscarError(f"render --trajectories: expected {' and '.join(missing)}")
        suffix = {"mkv": ".mkv", "png": "/", "mp4": ".mp4", None: ".mp4"}[args.format]
        return specs_from_folder(
            args.trajectories,
            args.embodiment,
            args.out,
            camera=args.camera,
            suffix=suffix,
            size=_size(args.size),
            fps=args.fps,
            resize=args.resize,
        ), True
    missing = [f"--{n}" for n in ("embodiment", "trajectory", "camera", "out") if not getattr(args, n)]
    if missing:
        raise OscarError(f"render: expected {', '.join(missing)} (or --manifest FILE / --trajectories DIR)")
    return [
        EpisodeSpec(
            args.embodiment,
            args.trajectory,
            args.camera,
            args.out,
            _size(args.size),
            args.fps,
            args.resize,
            args.format,
        )
    ], False


def _options(args):
    from .batch import RenderOptions
    from .conditions import parse_condition_style

    return RenderOptions(
        preset=args.preset,
        crf=args.crf,
        yuv=args.yuv,
        strict=args.strict,
        device=args.device,
        plugin_paths=tuple(args.plugin or ()),
        condition=args.condition,
        condition_style=parse_condition_style(args.condition_style),
    )


def cmd_render(args) -> int:
    specs, batch = _specs(args)
    if args.overlay:
        if batch:
            raise OscarError("render --overlay: checks one calibration; give --trajectory, not a batch")
        return _render_overlay(args, specs[0])
    from .batch import render_episode, render_many, summarise

    options = _options(args)
    if not batch:
        result = render_episode(specs[0], options)
        for w in result.warnings:
            print(f"warning: {w}", file=sys.stderr)
        if args.json:
            print(json.dumps(result.to_dict(), indent=2))
        else:
            print(f"wrote {result.out}: {result.frames} frames, {result.width}x{result.height}, {result.fps:g} fps")
        return 0
    t0 = time.perf_counter()
    from .._util.log import progress_bars_enabled

    # --progress / --no-progress of this command, else the one progress setup (-q, OSCAR_DISABLE_PROGRESS_BARS, tty)
    progress = args.progress if args.progress is not None else progress_bars_enabled()
    results = render_many(specs, options, workers=args.workers, progress=progress, resume=args.resume)
    summary = summarise(results, time.perf_counter() - t0)
    if args.json:
        print(json.dumps({"summary": summary, "episodes": [r.to_dict() for r in results]}, indent=2))
    else:
        for r in results:
            for w in r.warnings:
                print(f"warning: episode {r.index} ({r.spec.trajectory}): {w}", file=sys.stderr)
            if not r.ok:
                print(f"error: episode {r.index} ({r.spec.trajectory} -> {r.spec.out}): {r.error}", file=sys.stderr)
        skipped = f", {summary['skipped']} unchanged and skipped" if summary["skipped"] else ""
        print(
            f"rendered {summary['ok']} of {summary['episodes']} episodes ({summary['failed']} failed{skipped}), "
            f"{summary['frames']} frames in {summary['seconds']:.2f} s: "
            f"{summary['episodes_per_second'] or 0:.2f} episodes/s, {summary['frames_per_second'] or 0:.0f} frames/s"
        )
    return 0 if summary["failed"] == 0 else 1


def _render_overlay(args, spec) -> int:
    """One video blended over real frames (checks a calibration); output checked first."""
    from ..kinematics.trajectory import load_trajectory
    from .batch import _registry
    from .conditions import parse_condition_style
    from .overlay import write_overlay

    emb = _registry(tuple(args.plugin or ())).get(spec.embodiment)
    traj = load_trajectory(spec.trajectory)
    cam = emb.load_camera(spec.camera)
    path, frames, size, fps = write_overlay(
        emb,
        traj,
        cam,
        args.overlay,
        spec.out,
        condition=args.condition,
        style=parse_condition_style(args.condition_style),
        size=spec.size,
        resize_mode=spec.resize,
        alpha=args.alpha,
        fps=spec.fps,
        format=spec.format,
        preset=args.preset,
        crf=args.crf,
        yuv=args.yuv,
        device=args.device,
        camera_source=str(spec.camera),
        strict=args.strict,
    )
    print(f"wrote {path}: {frames} frames, {size[0]}x{size[1]}, {fps:g} fps")
    return 0
