"""``oscar toyworld train-tiny-decoder``: distil the toy VAE's full decoder into a tiny decoder
(:mod:`oscar_core.toyworld.tiny_decoder_train`), from the cached latents of toy clips."""

from __future__ import annotations

import argparse
from pathlib import Path

from .._util.arg_types import count, number
from .._util.log import log_result, run_log
from .._util.outputs import output_option

__all__ = ["add_tiny_decoder_parser", "cmd_train_tiny_decoder"]

EXAMPLES = """examples:
  oscar toyworld train-tiny-decoder clipsets/toy-latents --vae oscar-toy --out runs/toy-tiny-decoder --seed 0
      (clip sets written by `oscar train --cache-latents` with that VAE; several may be given; then:
      oscar rollout --model oscar-toy --tiny-decoder runs/toy-tiny-decoder/tiny_decoder.safetensors ...)
"""


def add_tiny_decoder_parser(sub) -> argparse.ArgumentParser:
    """Add ``train-tiny-decoder`` to the sub-parsers of ``oscar toyworld``."""
    from .tiny_decoder_train import TinyDecoderTrainConfig

    t = sub.add_parser(
        "train-tiny-decoder",
        help="distil the toy VAE's decoder into a tiny decoder (TAEHV design) on cached latents",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    t.add_argument("clips", nargs="+", help="clip sets of cached latents (`oscar train --cache-latents`)")
    t.add_argument(
        "--vae",
        required=True,
        help="the VAE those latents were made with: a vae/ folder, a model folder holding vae/, or a zoo name",
    )
    output_option(
        t.add_argument("--out", required=True, help="output folder (tiny_decoder.safetensors + card)"), "folder"
    )
    d = TinyDecoderTrainConfig()
    for name in (
        "steps",
        "batch",
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
    for name in ("lr", "foreground"):
        t.add_argument("--" + name, type=number(0.0), default=getattr(d, name), help=f"default {getattr(d, name)}")
    t.set_defaults(func=cmd_train_tiny_decoder)
    return t


def _vae_folder(spec: str) -> Path:
    """The ``vae/`` folder that ``--vae`` names (a vae folder, a model folder, or a zoo name); ValueError (exit 2)
    naming the option otherwise."""
    path = Path(spec)
    if (path / "config.json").is_file():
        return path
    if (path / "vae" / "config.json").is_file():
        return path / "vae"
    if not path.exists():
        import oscar_zoo

        if spec in {m.name for m in oscar_zoo.list_models()}:
            return Path(oscar_zoo.pull(spec)) / "vae"
        raise ValueError(f"--vae {spec}: expected a vae/ folder, a model folder or a zoo name, found none of them")
    raise ValueError(f"--vae {spec}: expected a folder holding config.json or vae/config.json, found neither")


def cmd_train_tiny_decoder(args) -> int:
    from ..train.clips import ClipSet
    from .tiny_decoder_train import TinyDecoderTrainConfig, train_tiny_decoder

    vae = _vae_folder(args.vae)
    for root in args.clips:  # each one a clip set before anything runs
        ClipSet(root)
    cfg = TinyDecoderTrainConfig(
        steps=args.steps,
        batch=args.batch,
        lr=args.lr,
        foreground=args.foreground,
        train_windows=args.train_windows,
        eval_windows=args.eval_windows,
        heldout_every=args.heldout_every,
        heldout_residue=args.heldout_residue,
        seed=args.seed,
        threads=args.threads,
        eval_every=args.eval_every,
    )
    with run_log(args.out, "toyworld-train-tiny-decoder"):
        card = train_tiny_decoder(args.clips, vae, args.out, cfg)
        log_result(f"held-out PSNR {card['heldout_psnr_db']:.2f} dB against the full decode")
    print(
        f"{args.out}/tiny_decoder.safetensors: held-out PSNR {card['heldout_psnr_db']:.2f} dB against the full "
        f"decode, {card['wall_s']:.0f} s wall, {card['cpu_s']:.0f} s CPU"
    )
    return 0
