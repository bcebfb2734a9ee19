"""``oscar toyworld train-vae``: train the toy world's AutoencoderKLWan on a clip set
(:mod:`oscar_core.toyworld.vae_train`); its parser and command, wired in by :mod:`oscar_core.toyworld.cli`."""

from __future__ import annotations

from .._util.log import log_result, run_log
from .._util.outputs import output_option
from .._util.threads import threads_option

__all__ = ["add_train_vae_parser", "cmd_train_vae"]


def add_train_vae_parser(sub, fmt, epilog: str) -> None:
    """Add ``train-vae`` to the sub-parsers of ``oscar toyworld`` (fmt: its help formatter; epilog: its examples)."""
    """Register ``oscar toyworld train-vae`` and its options on ``sub``."""
    v = sub.add_parser(
        "train-vae", help="train the toy world's AutoencoderKLWan on a clip set", epilog=epilog, formatter_class=fmt
    )
    v.add_argument("clips", help="clip set written by `oscar toyworld generate`")
    output_option(v.add_argument("--out", required=True, help="output folder (vae/ + vae_card.json)"), "folder")
    from .vae_train import BALL_REGIONS, VAETrainConfig

    d = VAETrainConfig()
    for name in ("steps", "stop_at", "batch", "window", "seed", "base_dim", "eval_every", "eval_clips"):
        v.add_argument(
            "--" + name.replace("_", "-"), type=int, default=getattr(d, name), help=f"default {getattr(d, name)}"
        )
    threads_option(v, "torch threads")
    for name in ("lr", "kl", "chroma", "foreground", "ball", "max_minutes"):
        v.add_argument(
            "--" + name.replace("_", "-"), type=float, default=getattr(d, name), help=f"default {getattr(d, name)}"
        )
    v.add_argument(
        "--ball-region",
        choices=BALL_REGIONS,
        default=d.ball_region,
        help="where --ball weights the error: the truth's ball pixels (truth, default) or those and the "
        "reconstruction's own ball-coloured pixels (union: a smear of the ball's colour elsewhere costs as much)",
    )
    v.add_argument(
        "--resume",
        action="store_true",
        help="carry on from --out's last checkpoint (its vae/ and resume/), exactly where it stood; give the same "
        "options as the first run (--steps, --stop-at, --max-minutes, --threads, --eval-every, --eval-clips may differ)",
    )
    v.add_argument("--init", default="", help="start from this train-vae output folder (fine-tune; --base-dim ignored)")
    v.add_argument(
        "--residual",
        action="store_true",
        help="the Wan 2.2 variant of the class (is_residual=True): pixel-averaging shortcuts around each "
        "down/up-sampling block, which carry colour to the latent from the first step",
    )
    v.add_argument(
        "--sample-posterior",
        action="store_true",
        help="decode a sample of the posterior in training (the textbook VAE); default: its mean",
    )
    v.set_defaults(func=cmd_train_vae)


def cmd_train_vae(args) -> int:
    """Run ``oscar toyworld train-vae``; returns the exit code."""
    from .vae_train import VAETrainConfig, train_vae

    cfg = VAETrainConfig(
        steps=args.steps,
        stop_at=args.stop_at,
        batch=args.batch,
        window=args.window,
        lr=args.lr,
        kl=args.kl,
        chroma=args.chroma,
        foreground=args.foreground,
        ball=args.ball,
        ball_region=args.ball_region,
        seed=args.seed,
        threads=args.threads,
        base_dim=args.base_dim,
        max_minutes=args.max_minutes,
        eval_every=args.eval_every,
        eval_clips=args.eval_clips,
        init=args.init,
        resume=args.resume,
        config={"is_residual": True} if args.residual else {},
        sample_posterior=args.sample_posterior,
    )
    with run_log(args.out, "toyworld-train-vae"):
        card = train_vae(args.clips, args.out, cfg)
        log_result(f"held-out PSNR {card['heldout_psnr_db']:.2f} dB after {card['steps_done']} steps")
    print(
        f"{args.out}/vae: held-out PSNR {card['heldout_psnr_db']:.2f} dB after {card['steps_done']} steps, "
        f"{card['wall_s']:.0f} s"
    )
    return 0
