"""``oscar toyworld action-following``: make the toy world's counterfactual sets and run the action-following
benchmark on them (:mod:`oscar_core.toyworld.counterfactual`, :mod:`oscar_core.evaluation.action_following`).

The sets are made for the model: its card's size and ``--chunks`` of its chunk length (1 + chunks x (L − 1)
frames), into ``OUT/sets`` (kept on a re-run; ``--push``: with the simulator's push rule and the ``open_push``
variant); the benchmark writes ``OUT/report.json`` and ``OUT/summary.md``
with the toy world's judge (:func:`~oscar_core.toyworld.judge.ball_moved`) and ball locator; ``--ceiling`` scores
the model's VAE reconstruction of the true frames instead of its rollouts (the autoencoder ceiling).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .._util.arg_types import count, default_device, device_name, interval, number
from .._util.log import log_result, progress_bars_enabled, run_log
from .._util.outputs import output_option
from .._util.threads import threads_option
from ..model.presets import SAMPLER_PRESETS

__all__ = ["add_counterfactual_parser", "cmd_action_following", "QUICK_STEPS"]

#: ``--quick`` samples with this many steps unless ``--steps`` says otherwise.
QUICK_STEPS = 10

EXAMPLES = """examples:
  oscar toyworld action-following --model oscar-toy --quick --seed 0 --out af_toy
  oscar toyworld action-following --model runs/toy49/export --quick --seed 0 --out af_toy49 --paired af_toy
  oscar toyworld action-following --model oscar-toy --quick --seed 0 --ceiling --out af_toy_ceiling
      (the autoencoder ceiling: the VAE's reconstruction of the true frames, scored the same way)
  oscar toyworld action-following --model oscar-toy --sets 10 --seed 1 --steps 20 --out af_toy_full
  oscar toyworld action-following --model oscar-toy --quick --seed 0 --push --out af_toy_push
      (the simulator pushes the ball with an open gripper; a seventh variant, open_push, sweeps through it)
  (re-running the same command resumes: finished sets are kept)
"""


def add_counterfactual_parser(sub, epilog: str = "") -> argparse.ArgumentParser:
    """Add ``action-following`` to the sub-parsers of ``oscar toyworld``."""
    a = sub.add_parser(
        "action-following",
        help="counterfactual toy sets (gripper early / late / open, path missing the ball) and the "
        "action-following benchmark of a world model on them",
        epilog=EXAMPLES + epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    a.add_argument("--model", required=True, help="world model: zoo name (oscar-toy) or folder (a run's export)")
    size = a.add_mutually_exclusive_group()
    size.add_argument(
        "--quick",
        action="store_true",
        help=f"3 sets per embodiment (toyarm, franka, kuka) and {QUICK_STEPS} sampler steps unless --steps",
    )
    size.add_argument("--sets", type=count(1), help="sets per embodiment (default 10)")
    a.add_argument("--embodiments", default="toyarm,franka,kuka", help="comma-separated (default toyarm,franka,kuka)")
    a.add_argument("--chunks", type=count(1), default=6, help="chunks of the model per episode (default 6)")
    a.add_argument(
        "--seed", type=count(0), default=0, help="set i of embodiment e depends on (seed, e, i); the noise seed"
    )
    output_option(
        a.add_argument("--out", required=True, help="run folder (sets/ inside; re-running resumes)"), "folder"
    )
    a.add_argument(
        "--ceiling",
        action="store_true",
        help="the autoencoder ceiling: score the model's VAE reconstruction of every variant's true frames (chunk "
        "by chunk as its rollout decodes) instead of its rollouts; loads only the VAE, no sampling",
    )
    a.add_argument(
        "--push",
        action="store_true",
        help="the toy simulator's push rule on for every variant (an open gripper moving into the ball shoves it "
        "along the floor) and the open_push variant (the open gripper sweeps through the ball); off by default, "
        "so sets made without it are unchanged; recorded in the sets' manifest",
    )
    a.add_argument("--paired", help="another run's folder on the same sets: report this run minus it, per set")
    a.add_argument("--steps", type=count(1), help="denoising steps per chunk (default: the card's; --quick: 10)")
    a.add_argument("--preset", choices=sorted(SAMPLER_PRESETS), help="sampling budget (as oscar rollout --preset)")
    a.add_argument("--guidance-interval", metavar="LO,HI", type=interval, help="guide only noise levels in [LO, HI]")
    a.add_argument("--shift", type=number(above=0.0), default=5.0, help="flow schedule shift (default 5)")
    a.add_argument(
        "--cond-noise",
        type=number(0.0),
        default=0.0,
        help="conditioning frame fed noised at this level in [0, 1) (default 0: clean; for a model trained with "
        "flow.cond_noise_max)",
    )
    a.add_argument("--guidance", type=number(0.0), help="skeleton guidance w (default: the model card's, else 6)")
    a.add_argument("--guidance-form", choices=("standard", "diffusers"), help="default: the model card's")
    a.add_argument("--device", type=device_name, help="torch device (default: cuda when available, else cpu)")
    from ..model.decoder_options import add_decoder_options

    add_decoder_options(a)
    from ..model.encoder_options import add_encoder_option

    add_encoder_option(a)
    threads_option(a, "torch CPU threads of the world model")
    a.add_argument("--no-progress", action="store_true", help="no progress bars")
    a.add_argument("--json", action="store_true", help="print the report JSON (without the per-set records)")
    a.set_defaults(func=cmd_action_following)
    return a


def cmd_action_following(args) -> int:
    """Make the sets for the model's card, then run the benchmark (module docstring)."""
    from ..errors import OscarError
    from ..evaluation.action_following import ActionFollowingSettings, check_encoder_mode, run_action_following
    from ..evaluation.loop import card_sampler_of
    from ..metrics.programmatic import ProgrammaticJudge
    from ..model.card_sampler import resolve_sampler
    from ..model.decoder_options import decoder_choice
    from ..model.encoder_options import encoder_choice
    from ..plugin.registry import Registry
    from .counterfactual import QUICK, write_counterfactual_sets
    from .judge import VERSION, ball_moved
    from .motion import ToyWorldError

    names = [n.strip() for n in args.embodiments.split(",") if n.strip()]
    if not names:
        raise ToyWorldError("--embodiments: expected comma-separated embodiment names, found none")
    if args.paired is not None and not (Path(args.paired) / "report.json").is_file():
        raise ToyWorldError(
            f"{args.paired}: --paired: expected another action-following run's folder, found no report.json"
        )
    options = dict(
        steps=args.steps if args.steps is not None or not args.quick else QUICK_STEPS,
        preset=args.preset,
        guidance_interval=args.guidance_interval,
        shift=args.shift,
        cond_noise=args.cond_noise,
        guidance=args.guidance,
        guidance_form=args.guidance_form,
        defaults={"guidance_form": "standard"},
    )
    resolve_sampler(None, **options)  # the flags checked before the model is looked up
    decoder = decoder_choice(args)
    encoder = encoder_choice(args)
    check_encoder_mode(encoder, args.ceiling, "--tiny-encoder")
    card = _card(args.model)
    choice = resolve_sampler(card_sampler_of(args.model), **options)
    L = int(card.chunk_frames) if card is not None and card.chunk_frames else 17
    w, h = (card.width, card.height) if card is not None and card.width and card.height else (64, 64)
    sets = QUICK["sets"] if args.quick else (args.sets or 10)
    registry = Registry(plugin_paths=getattr(args, "plugin", None) or ())
    try:
        for n in names:
            registry.get(n)
    except (OscarError, KeyError) as exc:
        raise ToyWorldError(f"--embodiments: {exc}") from None
    if args.ceiling:
        from ..evaluation.action_following_ceiling import CEILING

        print(f"mode: {CEILING} (only the model's VAE is loaded; sampler flags unused)", file=sys.stderr)
    else:
        print(f"sampler: {choice.describe('flag')}", file=sys.stderr)
    progress = not args.no_progress and progress_bars_enabled()
    with run_log(args.out, "toyworld-action-following"):
        manifest = write_counterfactual_sets(
            Path(args.out) / "sets",
            names,
            sets,
            seed=args.seed,
            width=w,
            height=h,
            frames=1 + args.chunks * (L - 1),
            registry=registry,
            progress=progress,
            push=args.push,
        )
        judge = ProgrammaticJudge(ball_moved, name="oscar_core.toyworld.judge:ball_moved", version=VERSION)
        settings = ActionFollowingSettings(
            model_spec=args.model,
            sampler=None if args.ceiling else choice.config,
            seed=args.seed,
            device=args.device or default_device(),
            plugin_paths=tuple(getattr(args, "plugin", None) or ()),
            progress=progress,
            tiny_decoder=decoder,
            ceiling=args.ceiling,
            tiny_encoder=encoder,
        )
        result = run_action_following(manifest, args.out, judge=judge, settings=settings, paired=args.paired)
        log_result(f"wrote {result.paths['report']}")
    if args.json:
        print(json.dumps({k: v for k, v in result.report.items() if k != "records"}, indent=1))
    else:
        print(Path(result.paths["summary"]).read_text())
        print(f"wrote {result.paths['report']}, {result.paths['summary']}")
    return 0


def _card(spec: str):
    """The model's card read from its folder without loading weights (None: a folder without an OSCAR card)."""
    import oscar_zoo

    from ..model.world_model import MODEL_FILE, read_card

    folder = Path(oscar_zoo.pull(spec))
    return read_card(folder) if (folder / MODEL_FILE).is_file() else None
