"""``oscar eval action-following MANIFEST``: does a world model's outcome change exactly when one decision does?

Registered under ``oscar eval`` by :func:`add_action_following_parser`; the benchmark is
:func:`oscar_core.evaluation.action_following.run_action_following`, the manifest
:mod:`oscar_core.evaluation.action_following_manifest` (docs/action-following.md). ``oscar toyworld
action-following`` makes toy-world sets and runs the same benchmark on them.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .._util.arg_types import count, default_device, device_name
from .._util.log import log_result, progress_bars_enabled, run_log
from .._util.outputs import output_option
from .._util.threads import threads_option
from ..metrics.common import MetricInputError
from .cli_options import add_decoder_options, add_sampler_options

__all__ = ["add_action_following_parser", "cmd_action_following"]

EXAMPLES = """examples:
  oscar toyworld action-following --model oscar-toy --quick --seed 0 --out af_toy     (toy sets made and scored)
  oscar eval action-following af_toy/sets/manifest.json --model runs/toy49/export --out af_toy49 \\
      --judge oscar_core.toyworld.judge:ball_moved --steps 10 --guidance 3 --guidance-form diffusers --paired af_toy
  oscar eval action-following af_toy/sets/manifest.json --model oscar-toy --ceiling \\
      --judge oscar_core.toyworld.judge:ball_moved --out af_toy_ceiling   (the VAE's reconstruction of the true frames)
  oscar eval action-following my_sets.json --model oscar-2b --judge my_judges.py:cube_in_bin --out af_2b \\
      --device cuda --dtype bfloat16
  (re-running the same command resumes: finished sets are kept)
"""


def cmd_action_following(args) -> int:
    import torch

    from ..model.decoder_options import decoder_choice
    from ..model.encoder_options import encoder_choice
    from .action_following import ActionFollowingSettings, check_encoder_mode, run_action_following
    from .action_following_manifest import load_action_following
    from .cli import load_judge
    from .cli_options import resolve_sampler_flags
    from .loop import card_sampler_of

    manifest = load_action_following(args.manifest, getattr(args, "plugin", None) or ())  # before any model
    judge = load_judge(args.judge)
    if args.paired is not None and not (Path(args.paired) / "report.json").is_file():
        raise MetricInputError(args.paired, "--paired", "another action-following run's folder (report.json)", "none")
    decoder = decoder_choice(args)  # checked before any model is looked up
    encoder = encoder_choice(args)
    check_encoder_mode(encoder, args.ceiling, "--tiny-encoder")
    if args.ceiling:
        from .action_following_ceiling import CEILING, check_true_videos

        check_true_videos(manifest)  # before the model's card is even read
        sampler = None
        print(f"mode: {CEILING} (only the model's VAE is loaded; sampler flags and --seed unused)", file=sys.stderr)
    else:
        choice = resolve_sampler_flags(args, lambda: card_sampler_of(args.model, args.revision))
        sampler = choice.config
        print(f"sampler: {choice.describe('flag')}", file=sys.stderr)
    settings = ActionFollowingSettings(
        model_spec=args.model,
        revision=args.revision,
        sampler=sampler,
        seed=args.seed,
        chunk_frames=args.chunk_frames,
        device=args.device or default_device(),
        dtype=None if args.dtype == "auto" else getattr(torch, args.dtype),
        plugin_paths=tuple(getattr(args, "plugin", None) or ()),
        progress=not args.no_progress and progress_bars_enabled(),
        tiny_decoder=decoder,
        ceiling=args.ceiling,
        tiny_encoder=encoder,
    )
    with run_log(args.out, "eval-action-following"):
        result = run_action_following(
            manifest, args.out, judge=judge, settings=settings, locator=args.locator, paired=args.paired
        )
        log_result(f"wrote {result.paths['report']}")
    if args.json:
        print(json.dumps({k: v for k, v in result.report.items() if k != "records"}, indent=1))
    else:
        print(Path(result.paths["summary"]).read_text())
        print(f"wrote {result.paths['report']}, {result.paths['summary']}")
    return 0


def add_action_following_parser(sub) -> argparse.ArgumentParser:
    """Add ``action-following`` to the ``oscar eval`` sub-parsers."""
    r = sub.add_parser(
        "action-following",
        help="counterfactual sets: does the world model's outcome change exactly when one decision does",
        description="The action-following benchmark: every variant of every counterfactual set is rolled out "
        "(one first frame, one path, one decision changed), judged, and compared with its true outcome; "
        "decision accuracy, the pairwise rate, per-variant agreement and per-chunk drift with bootstrap "
        "intervals over sets; resumable.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    r.add_argument("manifest", help="action-following manifest JSON (docs/action-following.md)")
    r.add_argument("--model", required=True, help="world model: zoo name, Hub id owner/name, or folder")
    r.add_argument("--revision", help="Hub revision overriding the zoo's pinned one")
    r.add_argument("--judge", required=True, help="success judge: module:attr or file.py:attr")
    r.add_argument(
        "--locator",
        help="where the object is in a frame: module:attr, frames -> (T, 2) pixels (default: the manifest's)",
    )
    output_option(
        r.add_argument("--out", required=True, help="run folder (created; re-running resumes in it)"), "folder"
    )
    r.add_argument(
        "--ceiling",
        action="store_true",
        help="the autoencoder ceiling: score the model's VAE reconstruction of every variant's true frames (chunk "
        "by chunk as its rollout decodes) instead of its rollouts; needs every variant's video; loads only the VAE",
    )
    r.add_argument("--paired", help="another run's folder on the same manifest: report this run minus it, per set")
    r.add_argument("--seed", type=count(0), default=0, help="noise seed of every variant (default 0)")
    add_sampler_options(r)
    add_decoder_options(r)
    from ..model.encoder_options import add_encoder_option

    add_encoder_option(r)
    r.add_argument("--chunk-frames", type=count(5), help="frames per chunk, 4k+1 (default: the model's)")
    r.add_argument("--device", type=device_name, help="torch device (default: cuda when available, else cpu)")
    r.add_argument("--dtype", choices=("auto", "float32", "bfloat16", "float16"), default="auto")
    threads_option(r, "torch CPU threads of the world model")
    r.add_argument("--no-progress", action="store_true", help="no progress bars")
    r.add_argument("--json", action="store_true", help="print the report JSON (without the per-set records)")
    r.set_defaults(func=cmd_action_following)
    return r
