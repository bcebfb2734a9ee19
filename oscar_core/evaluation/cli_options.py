"""The options shared by ``oscar eval run``, ``oscar eval closed-loop`` and ``oscar eval benchmark run``: the sampler
flags (one flag set, one resolution: the same flags give the same sampler under every eval command) and where the
cells run (:func:`add_engine_options`: ``--engine``, ``--workers``, ``--batch-cells``).

:func:`add_sampler_options` adds ``--steps``, ``--preset``, ``--guidance-interval``, ``--shift``, ``--guidance``
and ``--guidance-form``; :func:`resolve_sampler_flags` checks them before any model is looked up and resolves
them over the model card's sampler (:func:`oscar_core.model.sampler.resolve_sampler`: a flag beats the card,
the card beats the defaults).

``--shift`` is among them for all three (default 5, the shift the paper and Cosmos train with, and
:class:`~oscar_core.model.sampler_config.SamplerConfig`'s): a model trained on another schedule shift is sampled
on its own by saying so, and a benchmark row's fingerprint records the shift it ran with. The flag sets the Euler
grid and UniPC's flow shift; a checkpoint whose scheduler config is a ``UniPCMultistepScheduler`` keeps that
config's own ``flow_shift`` (the model card holds no shift).
"""

from __future__ import annotations

from collections.abc import Callable

from .._util.arg_types import count, interval, number
from ..model.presets import SAMPLER_PRESETS

__all__ = ["add_decoder_options", "add_engine_options", "add_sampler_options", "resolve_sampler_flags"]


def add_decoder_options(parser) -> None:
    """Add ``--tiny-decoder FILE`` / ``--full-decoder`` (:mod:`oscar_core.model.decoder_options`, which ``oscar
    rollout`` uses too); read them with its ``decoder_choice(args)``."""
    from ..model.decoder_options import add_decoder_options as add

    add(parser)


def add_sampler_options(parser) -> None:
    """Add the sampler flags to ``parser``."""
    parser.add_argument(
        "--steps",
        type=count(1),
        help="denoising steps per chunk (default: the --preset's when given, else the model card's, e.g. 20 for "
        "oscar-toy, else 35)",
    )
    parser.add_argument("--preset", choices=sorted(SAMPLER_PRESETS), help="sampling budget (as oscar rollout --preset)")
    parser.add_argument(
        "--guidance-interval", metavar="LO,HI", type=interval, help="guide only the steps with noise level in [LO, HI]"
    )
    parser.add_argument(
        "--shift",
        type=number(above=0.0),
        default=5.0,
        help="flow schedule shift (default 5, the paper's training shift); a checkpoint's own UniPC scheduler "
        "config keeps its flow_shift",
    )
    parser.add_argument(
        "--cond-noise",
        type=number(0.0),
        default=0.0,
        help="feed each chunk's conditioning frame noised at this level in [0, 1) (default 0: clean), for a model "
        "trained with flow.cond_noise_max at least this",
    )
    parser.add_argument("--guidance", type=number(0.0), help="skeleton guidance w (default: the model card's, else 6)")
    parser.add_argument(
        "--guidance-form",
        choices=("standard", "diffusers"),
        help="v_u + w(v_c - v_u) (standard) or v_c + w(v_c - v_u) (diffusers); default: the model card's, "
        "else standard",
    )


def resolve_sampler_flags(args, card_sampler: Callable[[], object] | None):
    """The :class:`~oscar_core.model.sampler.SamplerChoice` of the flags in ``args`` over ``card_sampler()`` (the
    model card's sampler, looked up only after the flags passed their checks; None: no card)."""
    from ..model.card_sampler import resolve_sampler

    options = dict(
        steps=args.steps,
        preset=args.preset,
        guidance_interval=args.guidance_interval,
        shift=args.shift,
        cond_noise=args.cond_noise,
        guidance=args.guidance,
        guidance_form=args.guidance_form,
        defaults={"guidance_form": "standard"},
    )
    resolve_sampler(None, **options)  # the flags checked before the model is looked up
    return resolve_sampler(card_sampler() if card_sampler is not None else None, **options)


def add_engine_options(parser, *, what: str, batch_help: str) -> None:
    """Add ``--engine`` (local or ray), ``--workers`` and ``--batch-cells`` to ``parser``; ``what``: what runs
    (e.g. "rollouts"), ``batch_help``: what a batch of N cells does."""
    parser.add_argument(
        "--engine",
        choices=("local", "ray"),
        default="local",
        help=f"where {what} run: this process (default), or Ray actors (a running cluster via "
        'RAY_ADDRESS, else a local one), one model per GPU (pip install "oscar-wm[ray]")',
    )
    parser.add_argument(
        "--workers",
        type=count(1),
        default=1,
        metavar="N",
        help="--engine ray: actors, each loading the model once (one GPU each on CUDA; default 1)",
    )
    parser.add_argument("--batch-cells", type=count(1), default=1, metavar="N", help=batch_help)
