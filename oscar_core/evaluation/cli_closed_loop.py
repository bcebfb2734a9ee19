"""``oscar eval closed-loop MANIFEST``: policies act on the world model's frames; their actions drive it.

Registered under ``oscar eval`` by :func:`add_closed_loop_parser`; the loop is
:func:`oscar_core.evaluation.closed_loop.run_closed_loop`, the manifest
:mod:`oscar_core.evaluation.closed_loop_manifest`. ``--simulator NAME`` runs the same cells in a simulator
registered under the entry point group ``oscar.simulators`` (:mod:`oscar_core.evaluation.simulators`; the toy world
registers ``toy``, its ground truth) instead of a world model.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .._util.arg_types import count, default_device, device_name, number
from .._util.log import log_result, progress_bars_enabled, run_log
from .._util.outputs import output_option
from .._util.threads import threads_option
from ..metrics.common import MetricInputError
from .cli_options import add_decoder_options, add_engine_options, add_sampler_options

__all__ = ["add_closed_loop_parser", "cmd_closed_loop"]

EXAMPLES = """examples:
  oscar toyworld closed-loop-sessions --embodiments toyarm,franka,kuka --sessions 10 --out toy_cl
  oscar eval closed-loop toy_cl/manifest.json --model oscar-toy --out cl_wm/ \\
      --judge oscar_core.toyworld.judge:ball_moved --steps 20 --guidance 3 --guidance-form diffusers
  oscar eval closed-loop toy_cl/manifest.json --simulator toy --out cl_sim/      (ground truth, no model)
  oscar eval closed-loop manifest.json --model oscar-2b --out cl/ --policy pi05=ws://127.0.0.1:8000 \\
      --replan-every 8 --policy-timeout 10
  (re-running the same command resumes: finished cells are reused; --retry-failed redoes failed ones)
"""


def _policy_sources(items) -> dict:
    out = {}
    for item in items or ():
        name, sep, src = item.partition("=")
        if not sep or not name or not src:
            raise MetricInputError(
                "--policy", "value", "NAME=module:attr (or file.py:attr, an entry point)", repr(item)
            )
        out[name] = src
    return out


def cmd_closed_loop(args) -> int:
    import torch

    from ..model.decoder_options import decoder_choice
    from ..model.encoder_options import encoder_choice
    from .cli_options import resolve_sampler_flags
    from .closed_loop import run_closed_loop
    from .closed_loop_manifest import load_closed_loop_manifest
    from .loop import card_sampler_of

    manifest = load_closed_loop_manifest(args.manifest)  # every row checked before anything else
    sources = _policy_sources(args.policy)
    simulator = None
    if args.simulator is not None:
        from .simulators import load_simulator

        simulator = load_simulator(
            args.simulator
        )  # a plugin (entry point group oscar.simulators), e.g. the toy world's
    elif args.model is None:
        raise MetricInputError(
            "--model", "value", "a world model (zoo name, Hub id or folder), or --simulator toy", "none"
        )
    judge = None
    if args.judge != "none":
        from .cli import load_judge

        judge = load_judge(args.judge)
    pairwise = None
    if args.pairwise:
        if judge is None or not hasattr(judge, "compare_many"):
            raise MetricInputError(
                "--pairwise", "--judge", "a judge with compare_many (module:attr)", type(judge).__name__
            )
        pairwise = judge
    choice = resolve_sampler_flags(
        args, None if simulator is not None else (lambda: card_sampler_of(args.model, args.revision))
    )
    decoder = decoder_choice(args)  # checked before any model is looked up
    encoder = encoder_choice(args)
    sampler = choice.config
    if simulator is None:
        print(f"sampler: {choice.describe('flag')}", file=sys.stderr)
    with run_log(args.out, "eval-closed-loop"):
        result = run_closed_loop(
            manifest,
            args.out,
            model_spec=args.model if simulator is None else None,
            revision=args.revision,
            simulator=simulator,
            judge=judge,
            pairwise_judge=pairwise,
            sampler=sampler,
            chunk_frames=args.chunk_frames or (17 if simulator else None),
            fps=args.fps,
            replan_every=args.replan_every,
            policy_timeout=args.policy_timeout,
            retry_failed=args.retry_failed,
            policy_sources=sources,
            batch_cells=args.batch_cells,
            engine=args.engine,
            workers=args.workers,
            device=args.device or default_device(),
            dtype=None if args.dtype == "auto" else getattr(torch, args.dtype),
            tiny_decoder=decoder,
            tiny_encoder=encoder,
            plugin_paths=getattr(args, "plugin", None) or (),
            progress=not args.no_progress and progress_bars_enabled(),
        )
        jf = result.report["judge_failures"]
        log_result(
            f"wrote {result.paths['report']}; failed cells: {result.counts['failed']}"
            + (f"; the judge could not judge {len(jf)} cells" if jf else "")
        )
    if args.json:
        print(json.dumps({**result.report, "files": result.paths}, indent=1))
    else:
        print(Path(result.paths["summary"]).read_text())
        print(f"wrote {result.paths['report']}, {result.paths['summary']}")
        if "html" in result.paths:
            print(f"open {result.paths['html']} in a browser: the ranking, failures, latency and every cell's video")
    if jf:
        print(
            f"error: the judge could not judge {len(jf)} of {result.counts['cells'] - result.counts['failed']} "
            f"finished cells, so their success is unknown; first: {jf[0]['cell']}: {jf[0]['error']}",
            file=sys.stderr,
        )
    return 1 if result.counts["failed"] or jf else 0


def add_closed_loop_parser(sub) -> argparse.ArgumentParser:
    """Add ``closed-loop`` to the ``oscar eval`` sub-parsers."""
    r = sub.add_parser(
        "closed-loop",
        help="run policies closed loop in the world model (or the toy simulator)",
        description="Closed-loop policy evaluation: every (session, policy) cell of the manifest runs "
        "with the policy acting on the world model's generated frames and its actions "
        "driving the next chunk; resumable; writes a report ranking the policies.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    r.add_argument("manifest", help="closed-loop manifest JSON (docs/closed-loop.md)")
    r.add_argument("--model", help="world model: zoo name, Hub id owner/name, or folder")
    r.add_argument("--revision", help="Hub revision overriding the zoo's pinned one")
    r.add_argument(
        "--simulator",
        metavar="NAME",
        help="run in an installed simulator instead of a model (entry point group oscar.simulators; the toy world's: "
        "toy)",
    )
    output_option(
        r.add_argument("--out", required=True, help="run folder (created; re-running resumes in it)"), "folder"
    )
    r.add_argument(
        "--policy",
        action="append",
        metavar="NAME=SOURCE",
        help="replace (or add) policy NAME's source: module:attr, file.py:attr or an oscar.policies "
        "entry point (repeatable)",
    )
    r.add_argument(
        "--replan-every",
        type=count(1),
        metavar="K",
        help="actions executed per policy call (default: each policy's actions_per_call)",
    )
    r.add_argument(
        "--policy-timeout",
        type=number(above=0.0),
        metavar="S",
        help="seconds a policy call may take (default: each policy's timeout_s, 30)",
    )
    r.add_argument("--retry-failed", action="store_true", help="redo cells recorded as failed")
    r.add_argument("--judge", default="none", help="success judge: none or module:attr / file.py:attr (default none)")
    r.add_argument(
        "--pairwise",
        action="store_true",
        help="pairwise preferences within sessions (the judge's compare_many) + Bradley-Terry",
    )
    add_sampler_options(r)
    add_decoder_options(r)
    from ..model.encoder_options import add_encoder_option

    add_encoder_option(r)
    r.add_argument(
        "--chunk-frames", type=count(5), help="frames per chunk, 4k+1 (default: the model's; 17 for --simulator)"
    )
    r.add_argument(
        "--fps",
        type=number(above=0.0),
        default=10.0,
        help="frame rate of a --simulator world (a model's is its card's; default 10)",
    )
    add_engine_options(
        r,
        what="cells",
        batch_help="advance up to N cells in lock-step, one batched world-model call per chunk, their policy "
        "calls on threads of their own (each video equals its one-at-a-time run up to float rounding; default 1)",
    )
    r.add_argument("--device", type=device_name, help="torch device (default: cuda when available, else cpu)")
    r.add_argument("--dtype", choices=("auto", "float32", "bfloat16", "float16"), default="auto")
    threads_option(r, "torch CPU threads of the world model")
    r.add_argument("--no-progress", action="store_true", help="no progress bars")
    r.add_argument("--json", action="store_true", help="print the report JSON")
    r.set_defaults(func=cmd_closed_loop)
    return r
