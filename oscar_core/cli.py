"""The ``oscar`` command."""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

from .errors import OscarError

EXAMPLES = """examples:
  oscar embodiments
  oscar embodiments --json
  oscar render --embodiment toyarm --trajectory traj.npz --camera cam.json --out skel.mp4 --size 512x288
  oscar render --embodiment toyarm --trajectory traj.npz --camera cam.json --out check.mp4 --overlay rgb.mp4
  oscar render ... --out skel.mkv          (lossless FFV1, for training data)
  oscar render ... --out frames/           (lossless PNG frames)
  oscar demo --out demo_out
  oscar zoo list
  oscar rollout --model oscar-2b --embodiment franka --first-frame img.png --trajectory traj.npz --camera cam.json --out rollout.mp4
  oscar eval video pred.mp4 gt.mp4
  oscar --plugin ./my_robot.py embodiments (load a one-file plugin)
"""


def _registry(args):
    from .registry import Registry

    return Registry(plugin_paths=args.plugin or ())


def cmd_embodiments(args) -> int:
    reg = _registry(args)
    rows = []
    for name in reg.names():
        entry = reg.entries[name]
        row = {"name": name, "distribution": entry.distribution, "version": entry.version, "plugin": entry.plugin}
        try:
            row.update(reg.get(name).info())
        except OscarError as exc:
            row["error"] = str(exc)
        rows.append(row)
    failures = [{"plugin": f.plugin, "distribution": f.distribution, "error": f.error} for f in reg.failures]
    if args.json:
        print(json.dumps({"embodiments": rows, "failures": failures}, indent=2))
        return 0
    header = ("name", "joints", "grippers", "datasets", "license", "distribution")
    table = [header] + [(r["name"], str(r.get("joints", "?")), ",".join(r.get("grippers", [])) or "-",
                         ",".join(r.get("datasets", [])) or "-", r.get("license") or "-",
                         f"{r['distribution']} {r['version']}".strip()) for r in rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(header))]
    for row in table:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip())
    for r in rows:
        if "error" in r:
            print(f"error: {r['name']}: {r['error']}", file=sys.stderr)
    for f in reg.failures:
        print(f"failed plugin: {f}", file=sys.stderr)
    return 0


def cmd_render(args) -> int:
    import numpy as np

    from .pipeline import fit_image, overlay_skeleton, parse_size, render_skeleton_video
    from .trajectory import load_trajectory
    from .video import read_video, video_info, write_video

    size = parse_size(args.size) if args.size else None
    emb = _registry(args).get(args.embodiment)
    traj = load_trajectory(args.trajectory)
    cam = emb.load_camera(args.camera)
    rgb = None
    if args.overlay:
        info = video_info(args.overlay)
        if size is None:
            size = (info["width"], info["height"])
        rgb = read_video(args.overlay, max_frames=len(traj))
        if len(rgb) < len(traj):
            raise OscarError(f"{args.overlay}: expected at least {len(traj)} frames (the trajectory's length), found {len(rgb)}")
    video = render_skeleton_video(emb, traj, cam, size, resize_mode=args.resize, device=args.device, camera_source=args.camera)
    if rgb is not None:
        H, W = video.shape[1:3]
        # the real frames are fitted to the output size exactly as the calibration was (--resize)
        rgb = np.stack([fit_image(f, W, H, args.resize) for f in rgb])
        video = overlay_skeleton(video, rgb, alpha=args.alpha)
    fps = args.fps or traj.fps
    out = write_video(args.out, video, fps)
    print(f"wrote {out}: {len(video)} frames, {video.shape[2]}x{video.shape[1]}, {fps:g} fps")
    return 0


def cmd_demo(args) -> int:
    from .demo import run_demo
    from .pipeline import parse_size
    from .registry import Registry

    run_demo(args.out, size=parse_size(args.size), registry=Registry(plugin_paths=args.plugin or ()))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="oscar", description="Skeleton videos for any robot body, and the OSCAR world model.",
                                epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--plugin", action="append", metavar="PATH",
                   help="load a one-file plugin (.py) or a folder of them; repeatable (also: OSCAR_PLUGINS)")
    sub = p.add_subparsers(dest="command", required=True)

    e = sub.add_parser("embodiments", help="list installed embodiments",
                       epilog="example: oscar embodiments --json", formatter_class=argparse.RawDescriptionHelpFormatter)
    e.add_argument("--json", action="store_true", help="machine-readable output")
    e.set_defaults(func=cmd_embodiments)

    r = sub.add_parser("render", help="render a skeleton video from a trajectory",
                       epilog="example: oscar render --embodiment toyarm --trajectory traj.npz --camera cam.json "
                              "--out skel.mp4 --size 512x288", formatter_class=argparse.RawDescriptionHelpFormatter)
    r.add_argument("--embodiment", required=True, help="embodiment name (see `oscar embodiments`)")
    r.add_argument("--trajectory", required=True, help="trajectory .npz (docs/formats.md)")
    r.add_argument("--camera", required=True, help="camera calibration .json (docs/formats.md)")
    r.add_argument("--out", required=True, help="output: .mp4 (H.264), .mkv (lossless FFV1) or a folder/ (PNG frames)")
    r.add_argument("--size", help="output WIDTHxHEIGHT, e.g. 512x288 (default: the calibration's image size)")
    r.add_argument("--resize", choices=("crop", "stretch"), default="crop",
                   help="how the calibration is fitted to --size of another aspect ratio (default: centre crop)")
    r.add_argument("--overlay", metavar="RGB_VIDEO", help="blend the skeleton over this video to check the calibration")
    r.add_argument("--alpha", type=float, default=0.8, help="overlay opacity of the skeleton (default 0.8)")
    r.add_argument("--fps", type=float, help="output frame rate (default: the trajectory's)")
    r.add_argument("--device", default="cpu", help="torch device for forward kinematics (cpu, cuda)")
    r.set_defaults(func=cmd_render)

    d = sub.add_parser("demo", help="render every embodiment's bundled example (MP4s + contact sheet)")
    d.add_argument("--out", default="demo_out", help="output folder (default demo_out)")
    d.add_argument("--size", default="512x288", help="output WIDTHxHEIGHT (default 512x288)")
    d.set_defaults(func=cmd_demo)

    from .metrics.cli import add_eval_parser
    from .model.cli import add_model_parsers

    add_eval_parser(sub)
    add_model_parsers(sub)
    __import__("oscar_core.toyworld.cli", fromlist=["x"]).add_toyworld_parser(sub)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    warnings.simplefilter("default")
    try:
        return args.func(args)
    except (OscarError, ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
