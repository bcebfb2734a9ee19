"""The ``oscar train`` sub-command (also ``python -m oscar_core.train`` for torchrun).

Wire into the main parser with ``add_train_parser(subparsers)``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os

from .._util.arg_types import count
from .._util.outputs import output_option
from .._util.threads import threads_option
from ..render.conditions import CONDITIONS

__all__ = ["add_train_parser", "cmd_train", "build_train_parser"]

EXAMPLES = """examples:
  oscar train configs/train/tiny-cpu.yaml
  oscar train configs/train/tiny-cpu.yaml --set run_dir=runs/try2 --set optim.lr=1e-4
  oscar train --resume runs/tiny-cpu                 (continue exactly where it stopped)
  oscar train --export runs/tiny-cpu --out my_model  (EMA weights of the latest checkpoint)
  torchrun --nproc-per-node 4 -m oscar_core.train configs/train/oscar-2b.yaml
  oscar rollout --model runs/tiny-cpu/export ...     (an exported run is a model folder)
  oscar train --cache-latents clipsets/toy --vae runs/toy-vae --window 17 --out clipsets/toy-latents
                                                     (a copy of a clip set with cached VAE latents)
"""


def _add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", nargs="?", help="training config (YAML; see configs/train/ and docs/training.md)")
    p.add_argument("--resume", metavar="RUN_DIR", help="continue a run from its latest checkpoint")
    p.add_argument("--export", metavar="RUN_DIR", help="export a run's checkpoint as a model folder and exit")
    p.add_argument(
        "--cache-latents",
        metavar="CLIPS",
        help="write a copy of a clip set with cached VAE latents (needs --vae, --window, --out) and exit",
    )
    p.add_argument("--vae", help="with --cache-latents: an AutoencoderKLWan folder or an OSCAR model folder")
    p.add_argument("--window", type=count(1), help="with --cache-latents: frames per window (4k+1)")
    p.add_argument(
        "--stride", type=count(1), help="with --cache-latents: frames between window starts (default: window)"
    )
    threads_option(p)
    p.add_argument("--split", help="with --cache-latents: copy only clips whose meta.split is this (e.g. train)")
    p.add_argument("--batch", type=count(1), default=8, help="with --cache-latents: windows per VAE call (default 8)")
    p.add_argument(
        "--condition",
        choices=CONDITIONS,
        default="skeleton",
        help="with --cache-latents: the condition video cached beside the video (default skeleton; "
        "mesh or capsules for a model trained on those)",
    )
    p.add_argument(
        "--condition-style",
        metavar="JSON",
        help="with --cache-latents: how the condition video is drawn, a JSON mapping of skeleton style fields "
        "(sizes in pixels at 288 px of height), the training config's condition_style, e.g. "
        '\'{"gripper_radius_open": 27, "gripper_radius_closed": 14}\' (default: the standard look)',
    )
    output_option(
        p.add_argument(
            "--out",
            help="with --export: output folder (default RUN_DIR/export); with --cache-latents: the new clip set",
        ),
        "folder",
    )
    p.add_argument("--step", type=count(0), help="with --export: the checkpoint's step (default: the latest)")
    p.add_argument(
        "--weights", choices=("ema", "model"), default="ema", help="with --export: EMA (default) or raw weights"
    )
    p.add_argument(
        "--sampler",
        metavar="JSON",
        help="with --export: the sampler the model card recommends, a JSON mapping of steps, guidance, "
        'guidance_form, preset, e.g. \'{"steps": 10, "guidance": 0}\' (default: the run config\'s '
        "export_sampler; when that is null none, so rollouts use the library's unless given flags; a distilled "
        "student's card always names its own)",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one config field, e.g. --set steps=100 --set data.window=17 (repeatable); with "
        "--resume only steps, save_every, log_every, keep_last and export_sampler (train a run further)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar (metrics still go to metrics.jsonl)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=cmd_train)


def add_train_parser(subparsers) -> None:
    """Add ``train`` to an ``argparse`` sub-parser set."""
    p = subparsers.add_parser(
        "train",
        help="train the world model (the paper's fine-tuning recipe)",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_arguments(p)


def build_train_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m oscar_core.train", epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    _add_arguments(p)
    return p


def _sampler_option(text: str) -> dict:
    """``--sampler``'s JSON, checked as a card's ``sampler`` is (one-line errors naming the flag and the key)."""
    from ..model.card_sampler import check_card_sampler
    from ..model.errors import ModelInputError

    try:
        value = json.loads(text)
    except json.JSONDecodeError as e:
        raise ModelInputError(f"--sampler: expected a JSON mapping, found {text!r} ({e.msg})") from None
    return check_card_sampler(value, "--sampler") or {}


def cmd_train(args) -> int:
    from .config import TrainConfigError, check_resume_overrides, load_config, parse_overrides

    modes = [bool(args.config), bool(args.resume), bool(args.export), bool(args.cache_latents)]
    if sum(modes) != 1:
        raise TrainConfigError(
            "<command line>",
            "config / --resume / --export / --cache-latents",
            "exactly one of them",
            f"{sum(modes)} given",
        )
    if args.cache_latents:
        return _cache_latents(args)
    if args.export:
        from .export import export_run

        sampler = _sampler_option(args.sampler) if args.sampler is not None else None
        out = export_run(args.export, args.out, step=args.step, weights=args.weights, sampler=sampler)
        print(json.dumps({"export": str(out)}) if args.json else f"exported {args.export} to {out}")
        return 0
    from .._util.log import log_result, run_log
    from .._util.outputs import check_writable
    from .loop import train

    main_rank = int(os.environ.get("RANK", "0")) == 0
    overrides = parse_overrides(args.set)
    if args.resume:
        check_resume_overrides(overrides)
        check_writable(args.resume, "folder")
        log = run_log(args.resume, "train") if main_rank else contextlib.nullcontext()
        with _resume_hint(args.resume), log:
            result = train(resume=args.resume, progress=not args.no_progress, overrides=overrides)
            log_result(_result_line(result))
    else:
        config = load_config(args.config, overrides)
        check_writable(config.run_dir, "folder")
        log = run_log(config.run_dir, "train") if main_rank else contextlib.nullcontext()
        with _resume_hint(config.run_dir), log:
            result = train(config, progress=not args.no_progress, source=args.config)
            log_result(_result_line(result))
    summary = {
        "run_dir": str(result.run_dir),
        "step": result.step,
        "loss": result.last_loss,
        "export": str(result.export) if result.export else None,
    }
    if int(os.environ.get("RANK", "0")) == 0:
        print(json.dumps(summary) if args.json else _result_line(result))
    return 0


def _result_line(result) -> str:
    loss = "no steps left to run" if result.last_loss is None else f"loss {result.last_loss:.4f}"
    return f"trained {result.run_dir} to step {result.step} ({loss})" + (
        f"; exported to {result.export}" if result.export else ""
    )


@contextlib.contextmanager
def _resume_hint(run_dir: str):
    """Ctrl-C in a training run: the saved checkpoints stay; the same command would refuse the used run folder."""
    from .._util.interrupt import Interrupted, interrupted

    try:
        yield
    except Interrupted:
        raise
    except BaseException as exc:
        if not (_is_interrupt(exc) or (interrupted() and not isinstance(exc, SystemExit))):
            raise
        raise Interrupted(f"{run_dir} (its saved checkpoints)", f"`oscar train --resume {run_dir}`") from None


def _is_interrupt(exc: BaseException) -> bool:
    """A KeyboardInterrupt, also one torch.distributed.checkpoint caught mid-save and wrapped in its
    ``CheckpointException`` (a BaseException holding each rank's exception)."""
    if isinstance(exc, KeyboardInterrupt):
        return True
    failures = getattr(exc, "failures", None) if type(exc).__name__ == "CheckpointException" else None
    return bool(failures) and all(isinstance(f[0], KeyboardInterrupt) for f in failures.values())


def _cache_latents(args) -> int:
    from dataclasses import asdict

    from .cache import cache_latents
    from .config import TrainConfig, TrainConfigError
    from .models import build_vae

    for flag in ("vae", "window", "out"):
        if getattr(args, flag) is None:
            raise TrainConfigError("<command line>", f"--{flag}", "given with --cache-latents", "missing")
    from ..render.conditions import parse_condition_style

    style = parse_condition_style(args.condition_style)  # decoded here, checked by cache_latents before any work
    config = TrainConfig()
    config.model.vae = args.vae
    vae = build_vae(config, source="--vae")
    summary = cache_latents(
        args.cache_latents,
        args.out,
        vae,
        args.window,
        args.stride,
        split=args.split,
        batch=args.batch,
        log=(lambda _m: None) if args.json else print,
        condition=args.condition,
        condition_style=style,
    )
    print(
        json.dumps(asdict(summary))
        if args.json
        else f"{summary.out}: {summary.clips_cached} clips cached, {summary.clips_too_short} too short for the window; "
        f"{summary.shards_written} shards written, {summary.shards_kept} kept from an earlier run ({summary.wall_s} s)"
    )
    return 0
