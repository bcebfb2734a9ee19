"""``oscar view``: an episode, a clip, a rollout or an evaluation cell in Rerun."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

from .._util.arg_types import count
from .._util.optional import require
from .._util.outputs import output_option
from ..errors import OscarError

EPILOG = """examples:
  oscar view --embodiment franka --trajectory traj.npz --camera cam.json --video rgb.mp4 --save ep.rrd
  oscar view --embodiment franka --trajectory traj.npz --camera cam.json --video rgb.mp4 \\
      --generated rollout.mp4 --spawn                      (a rollout beside the real video)
  oscar view CLIPSET --clip franka-000003 --save clip.rrd  (a clip of a clip set)
  oscar view OUT/cells/S1/pi0 --manifest manifest.json --save cell.rrd
                                                           (an `eval closed-loop` cell folder)
  oscar view OUT --manifest manifest.json --cell S1/pi0 --save cell.rrd
                                          (a cell of an `eval run` or `eval closed-loop` folder)

--save writes a recording without a viewer (open it later: rerun FILE.rrd); --spawn starts
the Rerun viewer. With neither, the recording is written to NAME.rrd in this folder (NAME: the
trajectory's, clip's or cell's name). Needs
pip install "oscar-wm[viz]". Exit status: 0 written, 2 bad input. See docs/viewing.md.
"""


def add_view_parser(sub) -> None:
    """Register ``oscar view`` on the top-level sub-parser collection."""
    v = sub.add_parser(
        "view",
        help="open an episode, a clip, a rollout or an eval cell in Rerun (or write an .rrd)",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    v.add_argument(
        "source", nargs="?", help="a clip set (with --clip), an `eval closed-loop` cell folder or an `eval run` folder"
    )
    v.add_argument("--embodiment", help="embodiment name (see `oscar embodiments`)")
    v.add_argument("--trajectory", help="trajectory .npz (docs/formats.md)")
    v.add_argument("--camera", help="camera .json (docs/formats.md)")
    v.add_argument("--video", help="the real RGB video (file or PNG folder)")
    v.add_argument("--generated", help="a generated video (a rollout) shown beside the real one")
    v.add_argument("--condition", help="a stored condition video (default: the skeleton rendered through --camera)")
    v.add_argument("--clip", help="clip id, when SOURCE is a clip set")
    v.add_argument(
        "--manifest",
        help="the manifest SOURCE was made from: an `eval run` manifest, or a closed-loop manifest (the session's "
        "embodiment and camera; --embodiment / --camera replace them)",
    )
    v.add_argument("--cell", help="SESSION/POLICY, a cell of --manifest")
    output_option(
        v.add_argument(
            "--save", metavar="FILE.rrd", help="write the recording to this file (default without --spawn: NAME.rrd)"
        )
    )
    v.add_argument("--spawn", action="store_true", help="start the Rerun viewer and send the recording to it")
    v.add_argument(
        "--jpeg-quality",
        type=count(0),
        default=90,
        help="JPEG quality of the video frames, 1-100; 0 logs raw frames (exact, large) (default 90)",
    )
    v.add_argument(
        "--meshes", action="store_true", help="also show the robot's visual meshes (its URDF <visual> elements)"
    )
    v.add_argument("--json", action="store_true", help="print what was logged as JSON")
    v.set_defaults(func=cmd_view)


def _source(args):
    from ..plugin.registry import Registry
    from .sources import (
        clip_source,
        closed_loop_cell_source,
        closed_loop_source,
        episode_source,
        eval_run_source,
        is_closed_loop_manifest,
    )

    reg = Registry(plugin_paths=args.plugin or ())
    src = Path(args.source) if args.source else None
    if src is not None and not src.is_dir():
        raise OscarError(f"{src}: expected a clip set, an `eval closed-loop` cell folder or an `eval run` folder")
    if src is not None and (src / "oscar_clips.json").exists():
        if not args.clip:
            raise OscarError(f"{src}: a clip set; expected --clip ID")
        return clip_source(src, args.clip, registry=reg)
    if src is not None and (src / "record.json").exists():
        if args.manifest:  # the closed-loop manifest the run was made from: the session's embodiment and camera
            return closed_loop_cell_source(
                src, args.manifest, embodiment=args.embodiment, camera=args.camera, registry=reg
            )
        missing = [f"--{n}" for n in ("embodiment", "camera") if not getattr(args, n)]
        if missing:
            raise OscarError(
                f"{src}: an `eval closed-loop` cell; expected --manifest FILE (the closed-loop manifest), "
                f"or {' and '.join(missing)}"
            )
        return closed_loop_source(src, args.embodiment, args.camera, registry=reg)
    if src is not None:
        if not (args.manifest and args.cell):
            raise OscarError(
                f"{src}: not a clip set (no oscar_clips.json) nor a closed-loop cell (no record.json); "
                "for an `eval run` or `eval closed-loop` folder expected --manifest FILE and --cell SESSION/POLICY"
            )
        if is_closed_loop_manifest(args.manifest):
            session, sep, policy = args.cell.partition("/")
            if not sep:
                raise OscarError(f"--cell: expected SESSION/POLICY, found {args.cell!r}")
            return closed_loop_cell_source(
                src / "cells" / session / policy,
                args.manifest,
                embodiment=args.embodiment,
                camera=args.camera,
                registry=reg,
            )
        return eval_run_source(src, args.manifest, args.cell, registry=reg)
    missing = [f"--{n}" for n in ("embodiment", "trajectory") if not getattr(args, n)]
    if missing:
        raise OscarError(f"view: expected SOURCE, or {' and '.join(missing)} (see oscar view --help)")
    return episode_source(
        args.embodiment, args.trajectory, args.camera, args.video, args.generated, args.condition, registry=reg
    )


def cmd_view(args) -> int:
    from .rerun_log import write_recording

    if args.jpeg_quality > 100:
        raise OscarError(f"--jpeg-quality: expected 0-100, found {args.jpeg_quality}")
    if args.save and Path(args.save).suffix != ".rrd":
        raise OscarError(f"--save: expected a file name ending in .rrd, found {args.save!r}")
    try:
        require("rerun", "viz")
    except ImportError as exc:
        raise OscarError(str(exc)) from None
    source = _source(args)
    if not args.save and not args.spawn:  # the viewer opens only when asked: a recording in this folder
        from .._util.outputs import check_writable

        args.save = re.sub(r"[^A-Za-z0-9._-]+", "_", source.name) + ".rrd"
        check_writable(args.save, "file")
    summary = write_recording(
        source, args.save, spawn=args.spawn, jpeg_quality=args.jpeg_quality or None, meshes=args.meshes
    )
    if args.json:
        from .sources import describe

        print(json.dumps({**describe(source), **summary}, indent=2))
    elif args.save:
        print(f"wrote {args.save}: {summary['frames']} frames, {len(summary['entities'])} entities")
    return 0
