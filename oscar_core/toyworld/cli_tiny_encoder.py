"""``oscar toyworld train-tiny-encoder``: distil the toy VAE's full encoder into a tiny condition encoder
(:mod:`oscar_core.toyworld.tiny_encoder_train`), from the skeleton videos of toy clips."""

from __future__ import annotations

import argparse

from .._util.arg_types import count, number
from .._util.log import log_result, run_log
from .._util.outputs import output_option

__all__ = ["add_tiny_encoder_parser", "cmd_train_tiny_encoder"]

EXAMPLES = """examples:
  OMP_NUM_THREADS=1 oscar toyworld train-tiny-encoder /work/exp/clipsets/cf49-latents \\
      /work/exp/clipsets/cf49-kuka-latents /work/exp/clipsets/cf49-toyarm-latents --vae oscar-toy \\
      --out runs/toy-tiny-encoder --steps 3000 --seed 0
      (clip sets whose clips hold a skeleton video; then:
      oscar rollout --model oscar-toy --tiny-encoder runs/toy-tiny-encoder/tiny_encoder.safetensors ...)
"""


def add_tiny_encoder_parser(sub) -> argparse.ArgumentParser:
    """Add ``train-tiny-encoder`` to the sub-parsers of ``oscar toyworld``."""
    from .tiny_encoder_train import TinyEncoderTrainConfig

    t = sub.add_parser(
        "train-tiny-encoder",
        help="distil the toy VAE's encoder into a tiny condition encoder (TAEHV design) on the clips' skeleton videos",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    t.add_argument("clips", nargs="+", help="clip sets whose clips hold a skeleton video")
    t.add_argument(
        "--vae",
        required=True,
        help="the VAE to distil: a vae/ folder, a model folder holding vae/, or a zoo name",
    )
    output_option(
        t.add_argument("--out", required=True, help="output folder (tiny_encoder.safetensors + card)"), "folder"
    )
    d = TinyEncoderTrainConfig()
    for name in (
        "steps",
        "batch",
        "window",
        "train_windows",
        "eval_windows",
        "heldout_every",
        "heldout_residue",
        "seed",
        "eval_every",
        "threads",
    ):
        low = 0 if name in ("seed", "eval_every", "heldout_residue") else 1
        t.add_argument(
            "--" + name.replace("_", "-"), type=count(low), default=getattr(d, name), help=f"default {getattr(d, name)}"
        )
    t.add_argument("--lr", type=number(0.0), default=d.lr, help=f"default {d.lr}")
    t.set_defaults(func=cmd_train_tiny_encoder)
    return t


def cmd_train_tiny_encoder(args) -> int:
    from ..model.chunks import check_frame_count
    from ..train.clips import ClipSet
    from .cli_tiny_decoder import _vae_folder
    from .tiny_encoder_train import TinyEncoderTrainConfig, train_tiny_encoder

    check_frame_count(args.window, 4, "--window")
    vae = _vae_folder(args.vae)
    for root in args.clips:  # each one a clip set before anything runs
        ClipSet(root)
    cfg = TinyEncoderTrainConfig(
        steps=args.steps,
        batch=args.batch,
        lr=args.lr,
        window=args.window,
        train_windows=args.train_windows,
        eval_windows=args.eval_windows,
        heldout_every=args.heldout_every,
        heldout_residue=args.heldout_residue,
        seed=args.seed,
        threads=args.threads,
        eval_every=args.eval_every,
    )
    with run_log(args.out, "toyworld-train-tiny-encoder"):
        card = train_tiny_encoder(args.clips, vae, args.out, cfg)
        log_result(f"held-out relative RMS {card['heldout_relative_rms']:.4f} against the full encoder")
    print(
        f"{args.out}/tiny_encoder.safetensors: held-out relative RMS {card['heldout_relative_rms']:.4f} against the "
        f"full encoder, {card['wall_s']:.0f} s wall, {card['cpu_s']:.0f} s CPU"
    )
    return 0
