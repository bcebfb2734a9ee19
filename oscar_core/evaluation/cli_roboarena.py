"""``oscar eval roboarena DUMP --out STUDY``: a RoboArena evaluation dump → an ``oscar eval run`` study.

A thin handler over :func:`oscar_core.evaluation.roboarena.convert_roboarena` (docs/roboarena.md).
"""

from __future__ import annotations

import argparse
import json

from .._util.arg_types import number
from .._util.outputs import output_option

EXAMPLES = """examples:
  oscar eval roboarena DataDump_02-03-2026/ --out study/ --calibration cams/
  oscar eval roboarena DataDump_02-03-2026/ --out study/ --calibration cams/ --min-score 0.3 --model oscar-2b
  oscar eval run study/manifest.json --model oscar-2b --out eval_out/ --judge vlm --pairwise

Sessions without a camera in --calibration (cams/<session>.json), and bad or partial
sessions, are listed with their reason in study/rejected.json; the others go on.
"""


def cmd_roboarena(args) -> int:
    from .roboarena import convert_roboarena

    result = convert_roboarena(
        args.dump,
        args.out,
        view=args.view,
        fps=args.fps,
        model=args.model,
        embodiment=args.embodiment,
        calibration=args.calibration,
        min_score=args.min_score,
        source_fps=args.source_fps,
        size=args.size,
        plugin_paths=args.plugin or (),
    )
    if args.json:
        print(
            json.dumps(
                {
                    "kept": result.accepted,
                    "rejected": result.rejected,
                    "policies": result.policies,
                    "cells": result.cells,
                    "preferences": result.preferences,
                    "fps": result.fps,
                    "real_board_error": result.board_error,
                    "paths": {k: str(v) for k, v in result.paths.items()},
                },
                indent=1,
            )
        )
    else:
        print(result.summary())
        if "manifest" in result.paths:
            print(f"manifest: {result.paths['manifest']}")
    if not result.cells:
        print(f"error: no session left to evaluate; the reasons are in {result.paths['rejected']}")
        return 1
    return 0


def add_roboarena_parser(sub) -> argparse.ArgumentParser:
    """Add ``roboarena`` to the ``oscar eval`` sub-parsers."""
    from .roboarena import SOURCE_FPS, VIEWS

    r = sub.add_parser(
        "roboarena",
        help="turn a RoboArena evaluation dump into an eval-run manifest and the real results",
        description="Read a RoboArena dump (evaluation_sessions/<session>/metadata.yaml, A_<policy>/ videos and "
        "proprio_and_actions.npz) and write an `oscar eval run` manifest, the real success rates and the "
        "real A/B preference board; bad or uncalibrated sessions are listed in rejected.json.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    r.add_argument("dump", help="the dump folder (holds evaluation_sessions/)")
    output_option(r.add_argument("--out", required=True, help="study folder (created; a re-run rewrites it)"), "folder")
    r.add_argument("--view", choices=VIEWS, default="left_shoulder", help="camera of the first frames")
    r.add_argument("--fps", type=number(above=0.0), help="trajectory frame rate (default: --model's card, else 16)")
    r.add_argument("--model", help="world model whose card's fps to use (zoo name or folder; nothing is loaded)")
    r.add_argument("--embodiment", default="franka_robotiq", help="embodiment of the joints (default franka_robotiq)")
    r.add_argument("--calibration", metavar="DIR", help="one camera JSON per session: DIR/<session>.json")
    r.add_argument(
        "--min-score",
        type=number(0.0),
        metavar="X",
        help="drop sessions whose calibration score (oscar calibrate score) is below X",
    )
    r.add_argument(
        "--source-fps",
        type=number(above=0.0),
        default=SOURCE_FPS,
        help=f"rows per second of the npz files without timestamps (default {SOURCE_FPS:g}, the client's loop)",
    )
    r.add_argument("--size", metavar="WxH", help="rollout size written to the manifest (multiples of 16)")
    r.add_argument("--json", action="store_true", help="print the result as JSON")
    r.set_defaults(func=cmd_roboarena)
    return r
