"""The ``oscar toyworld`` sub-commands: ``example``, ``generate``, ``train-vae``, ``train-tiny-decoder``, ``train-tiny-encoder``, ``reconstruct``, ``baseline`` and ``eval``.

Wire into the main parser with ``add_toyworld_parser(subparsers)``; each leaf
parser sets ``func`` (returns an exit code). Heavy imports happen inside the
commands. The policy-evaluation sub-commands (``policy-eval``,
``closed-loop-sessions``, ``carry``) live in :mod:`oscar_core.toyworld.cli_policies`;
this module adds them to the parser and re-exports their commands.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .._util.arg_types import count, interval, number
from .._util.log import log_result, run_log
from .._util.outputs import output_option
from .._util.threads import threads_option
from ..model.presets import SAMPLER_PRESETS
from .cli_counterfactual import add_counterfactual_parser
from .cli_decision_fit import add_decision_fit_parser
from .cli_policies import (
    add_policy_parsers,
    cmd_carry,
    cmd_closed_loop_sessions as cmd_closed_loop_sessions,
    cmd_policy_eval,
)
from .cli_tiny_decoder import add_tiny_decoder_parser
from .cli_tiny_encoder import add_tiny_encoder_parser
from .cli_train_vae import add_train_vae_parser, cmd_train_vae

__all__ = [
    "add_toyworld_parser",
    "cmd_example",
    "cmd_generate",
    "cmd_train_vae",
    "cmd_reconstruct",
    "cmd_baseline",
    "cmd_eval",
    "cmd_policy_eval",
    "cmd_carry",
]


EXAMPLES = """examples:
  oscar toyworld example --out toy_example     (first_frame.png, trajectory.npz, camera.json for oscar rollout)
  oscar toyworld generate --embodiments toyarm,franka,kuka --episodes 400 --size 64x64 --frames 17 \\
      --seed 0 --out clipsets/toyworld
  oscar toyworld generate --embodiments toyarm,franka,kuka --episodes 400 --pick-miss 0.3 --seed 0 \\
      --out clipsets/toyworld-miss   (30 % of pick-and-place episodes miss the ball)
  oscar toyworld generate --embodiments mano --episodes 400 --seed 0 --out clipsets/toyworld-hands
      (human hands: the mano plugin's skeleton; they pick up or push the ball)
  oscar toyworld train-vae clipsets/toyworld --out runs/toyworld-vae --steps 2500 --batch 3 --window 9 --seed 0
  oscar toyworld train-tiny-decoder clipsets/toyworld-latents --vae oscar-toy --out runs/toy-tiny-decoder --seed 0
  oscar toyworld reconstruct clipsets/toyworld --vae runs/toyworld-vae --out preds/vae
  oscar toyworld baseline clipsets/toyworld --out preds/first_frame
  oscar toyworld rollout clipsets/toyworld --model oscar-toy --condition true --out preds/true
  oscar toyworld rollout clipsets/toyworld --model oscar-toy --condition shuffled --out preds/shuffled
  oscar toyworld eval --gt clipsets/toyworld --pred true=preds/true --pred shuffled=preds/shuffled \\
      --pred vae=preds/vae --pred first_frame=preds/first_frame --out table.json --plot table.png
      (also writes table.html: the table and rollouts under each condition beside the truth)
  oscar toyworld eval --gt clipsets/long --pred teacher=preds/teacher --pred student=preds/student \\
      --paired teacher --per-chunk 17 --out drift.json   (97-frame rollouts: metrics per 17-frame chunk)
  oscar toyworld package runs/toyworld/export --out my-toy --table table.json
  oscar toyworld policy-eval --embodiments toyarm,franka,kuka --sessions 10 --seed 0 --out toy_policies
  oscar toyworld carry toy_policies/manifest.json toy_eval/ --json toy_eval/carry.json
  oscar toyworld closed-loop-sessions --embodiments toyarm,franka,kuka --sessions 10 --out toy_cl
      (then: oscar eval closed-loop toy_cl/manifest.json --model oscar-toy --out cl_wm/)
  oscar toyworld action-following --model oscar-toy --quick --seed 0 --out af_toy
"""


def _add_toyworld_generate_parser(sub, fmt) -> None:
    """Register ``oscar toyworld generate`` and its options on ``sub``."""
    g = sub.add_parser(
        "generate", help="write toy-world episodes as a training clip set", epilog=EXAMPLES, formatter_class=fmt
    )
    g.add_argument(
        "--embodiments",
        required=True,
        help="comma-separated embodiment names (plugins included; mano: human hands, source toyworld_hand)",
    )
    g.add_argument("--episodes", type=count(1), required=True, help="episodes per embodiment")
    g.add_argument("--size", default="64x64", help="WIDTHxHEIGHT pixels (default 64x64)")
    g.add_argument("--frames", type=count(1), default=17, help="frames per episode (default 17; 4k+1 for the VAE)")
    g.add_argument("--fps", type=number(above=0.0), default=10.0, help="frame rate written to the clips (default 10)")
    g.add_argument(
        "--seed", type=count(0), default=0, help="seed: episode i of embodiment e depends on (seed, e, i) only"
    )
    output_option(
        g.add_argument("--out", required=True, help="clip-set folder (re-running resumes: finished shards are kept)"),
        "folder",
    )
    g.add_argument("--shard-size", type=count(1), default=50, help="episodes per shard (default 50)")
    g.add_argument("--supersample", type=count(1), default=2, help="anti-aliasing factor (default 2)")
    g.add_argument("--no-skeleton", action="store_true", help="do not store the skeleton videos")
    g.add_argument(
        "--pick-miss",
        type=number(0.0, 1.0),
        default=0.0,
        metavar="F",
        help="fraction in [0, 1] of pick-and-place episodes whose ball lies out of the gripper's reach "
        "(it closes beside the ball, lifts, and the ball stays); default 0 (sets as before)",
    )
    g.add_argument(
        "--pick-open",
        type=number(0.0, 1.0),
        default=0.0,
        metavar="F",
        help="fraction in [0, 1] of the other pick-and-place episodes whose gripper never closes (the arm "
        "passes through the grasp, lifts and carries with open fingers, and the ball stays); default 0",
    )
    g.add_argument(
        "--pick-timing",
        type=number(0.0, 1.0),
        default=0.0,
        metavar="F",
        help="fraction in [0, 1] of the picks that neither miss nor stay open whose gripper closes early (before "
        "reaching the ball: it passes over it closed) or late (after leaving it), half each; the ball stays; "
        "default 0 (sets as before)",
    )
    g.add_argument(
        "--push",
        action="store_true",
        help="an open gripper moving into the ball pushes it along the floor (robots; recorded in the set); "
        "default off (sets as before)",
    )
    threads_option(g, "torch threads for forward kinematics")
    g.add_argument("--json", action="store_true", help="print the summary as JSON")
    g.set_defaults(func=cmd_generate)


def _add_toyworld_example_parser(sub, fmt) -> None:
    """Register ``oscar toyworld example`` and its options on ``sub``."""
    x = sub.add_parser(
        "example",
        help="write a first frame, trajectory and camera of one toy-world episode: "
        "the inputs of `oscar rollout --model oscar-toy`",
        epilog=EXAMPLES,
        formatter_class=fmt,
    )
    output_option(
        x.add_argument("--out", required=True, help="folder for first_frame.png, trajectory.npz and camera.json"),
        "folder",
    )
    x.add_argument("--embodiment", default="toyarm", help="embodiment name (default toyarm; plugins included)")
    x.add_argument(
        "--seed",
        type=count(0),
        default=0,
        help="seed: the example is held-out episode 9 of `toyworld generate --seed SEED` (default 0)",
    )
    x.add_argument("--size", default="64x64", help="WIDTHxHEIGHT pixels (default 64x64, oscar-toy's)")
    x.add_argument(
        "--frames", type=count(2), default=17, help="frames of the trajectory (default 17: one oscar-toy chunk)"
    )
    x.add_argument("--fps", type=number(above=0.0), default=10.0, help="frame rate of the trajectory (default 10)")
    x.add_argument("--json", action="store_true", help="print the summary as JSON")
    x.set_defaults(func=cmd_example)


def _add_toyworld_reconstruct_parser(sub, fmt) -> None:
    """Register ``oscar toyworld reconstruct`` and its options on ``sub``."""
    r = sub.add_parser(
        "reconstruct",
        help="write the VAE's reconstructions of clips (the table's VAE ceiling)",
        epilog=EXAMPLES,
        formatter_class=fmt,
    )
    r.add_argument("clips", help="clip set")
    r.add_argument("--vae", required=True, help="folder written by train-vae (holding vae/)")
    output_option(r.add_argument("--out", required=True, help="folder for <clip id>.npy reconstructions"), "folder")
    r.add_argument(
        "--split", default="heldout", help="clips of this meta.split (default heldout; 'all' for every clip)"
    )
    r.add_argument("--limit", type=count(1), help="at most this many clips, every k-th")
    threads_option(r, "torch threads")
    r.set_defaults(func=cmd_reconstruct)


def _add_toyworld_baseline_parser(sub, fmt) -> None:
    """Register ``oscar toyworld baseline`` and its options on ``sub``."""
    b = sub.add_parser(
        "baseline",
        help="write model-free reference predictions (first frame repeated)",
        epilog=EXAMPLES,
        formatter_class=fmt,
    )
    b.add_argument("clips", help="clip set")
    b.add_argument(
        "--kind", default="first_frame", choices=("first_frame",), help="which baseline (default first_frame)"
    )
    output_option(b.add_argument("--out", required=True, help="folder for <clip id>.npy predictions"), "folder")
    b.add_argument(
        "--split", default="heldout", help="clips of this meta.split (default heldout; 'all' for every clip)"
    )
    b.add_argument("--limit", type=count(1), help="at most this many clips, every k-th")
    b.set_defaults(func=cmd_baseline)


def _add_toyworld_rollout_parser(sub, fmt) -> None:
    """Register ``oscar toyworld rollout`` and its options on ``sub``."""
    o = sub.add_parser(
        "rollout",
        help="roll a world model out on every clip of a split (true / shuffled / zero "
        "skeleton) as predictions for eval",
        epilog=EXAMPLES,
        formatter_class=fmt,
    )
    o.add_argument("clips", help="clip set (first frames and skeletons come from it)")
    o.add_argument("--model", required=True, help="zoo name (oscar-toy) or model folder")
    o.add_argument(
        "--condition",
        default="true",
        choices=("true", "shuffled", "zero"),
        help="the skeleton the model sees (default true)",
    )
    output_option(
        o.add_argument("--out", required=True, help="folder for <clip id>.npy predictions (re-running resumes)"),
        "folder",
    )
    o.add_argument(
        "--split", default="heldout", help="clips of this meta.split (default heldout; 'all' for every clip)"
    )
    o.add_argument("--limit", type=count(1), help="at most this many clips")
    o.add_argument("--steps", type=count(1), default=None, help="sampler steps (default: the model card's, else 35)")
    o.add_argument("--guidance", type=number(0.0), default=None, help="guidance w (default: the model card's, else 6)")
    o.add_argument(
        "--guidance-form",
        choices=("diffusers", "standard"),
        default=None,
        help="v_c + w(v_c - v_u) (diffusers, default) or v_u + w(v_c - v_u) (standard)",
    )
    o.add_argument("--seed", type=count(0), default=0, help="noise seed (default 0; the same for every condition)")
    o.add_argument(
        "--guidance-interval",
        metavar="LO,HI",
        type=interval,
        help="guide only the steps with noise level in [LO, HI] (e.g. 0.3,1.0); the others run the "
        "conditional branch alone",
    )
    o.add_argument(
        "--preset",
        choices=sorted(SAMPLER_PRESETS),
        help="sampling budget: paper (35 steps, guidance everywhere) or fast (docs/world-model.md); "
        "sets the steps and the guidance interval",
    )
    threads_option(o, "torch threads")
    o.set_defaults(func=cmd_rollout)


def _add_toyworld_package_parser(sub, fmt) -> None:
    """Register ``oscar toyworld package`` and its options on ``sub``."""
    k = sub.add_parser(
        "package",
        help="turn an exported toy-world run into a shippable model folder (card, "
        "zero prompt, README model card, sha256 of every file)",
        epilog=EXAMPLES,
        formatter_class=fmt,
    )
    k.add_argument("export", help="the exported run (RUN_DIR/export)")
    output_option(
        k.add_argument("--out", required=True, help="the model folder to write (replaced atomically)"), "folder"
    )
    k.add_argument("--name", default="oscar-toy", help="model name in the card (default oscar-toy)")
    k.add_argument("--training", help="JSON file of training facts for the model card (commands, steps, wall time)")
    k.add_argument("--table", help="JSON file written by `oscar toyworld eval --out` (the measured table)")
    k.set_defaults(func=cmd_package)


def _add_toyworld_eval_parser(sub, fmt) -> None:
    """Register ``oscar toyworld eval`` and its options on ``sub``."""
    e = sub.add_parser(
        "eval",
        help="PSNR, SSIM, end-effector and object errors of generated videos",
        epilog=EXAMPLES,
        formatter_class=fmt,
    )
    e.add_argument(
        "--gt",
        required=True,
        action="append",
        help="the clip set holding the ground truth (repeat for several sets, e.g. held-out embodiments)",
    )
    e.add_argument(
        "--pred",
        action="append",
        required=True,
        metavar="[NAME=]FOLDER",
        help="folder of generated videos named <clip id>.mp4/.mkv/.npy (or a folder of PNGs per clip); "
        "repeat with NAME= for several conditions (rows of the table)",
    )
    e.add_argument(
        "--split",
        default=None,
        help="only clips of this meta.split (e.g. heldout; 'all', as the default: every clip that has a prediction)",
    )
    e.add_argument(
        "--clips",
        choices=("same", "common", "each"),
        default="same",
        help="when the --pred folders cover different clips: same (default) refuses, common scores the "
        "clips all of them have, each scores every row over its own clips and marks the table",
    )
    e.add_argument(
        "--paired",
        metavar="NAME",
        help="also give every other row minus row NAME per metric over the "
        "clips both scored, with a 95 %% paired bootstrap interval (2000 resamples of the clips, seed 0)",
    )
    e.add_argument(
        "--per-chunk",
        type=count(2),
        metavar="CHUNK_FRAMES",
        help="also score each chunk of a long rollout made in chunks of CHUNK_FRAMES frames, the seed frame "
        "included (17 for oscar-toy: frames 1-16, 17-32, ...): quality against chunk index, paired per chunk "
        "with --paired",
    )
    output_option(e.add_argument("--out", help="write the table as JSON here"), "file")
    output_option(e.add_argument("--plot", help="write a PNG bar chart of the table here"), "file")
    output_option(
        e.add_argument(
            "--html",
            help="write the page (table, plot, clips under each condition beside the truth) here; "
            "default: beside --out as <name>.html, media in <name>_media/",
        ),
        "file",
    )
    e.add_argument("--no-html", action="store_true", help="no page")
    e.add_argument("--html-clips", type=int, default=12, help="clips shown on the page (default 12, every k-th)")
    e.add_argument("--json", action="store_true", help="print JSON instead of a table")
    e.set_defaults(func=cmd_eval)


def add_toyworld_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``oscar toyworld`` and its sub-commands on ``subparsers``; returns the ``toyworld`` parser."""
    fmt = argparse.RawDescriptionHelpFormatter
    tw = subparsers.add_parser(
        "toyworld",
        help="the procedural toy world: generate clips, train its VAE, evaluate",
        description="A procedural world small enough to train OSCAR on a CPU.",
        epilog=EXAMPLES,
        formatter_class=fmt,
    )
    sub = tw.add_subparsers(dest="toyworld_command", required=True)
    _add_toyworld_generate_parser(sub, fmt)
    _add_toyworld_example_parser(sub, fmt)
    add_train_vae_parser(sub, fmt, EXAMPLES)
    add_tiny_decoder_parser(sub)
    add_tiny_encoder_parser(sub)
    _add_toyworld_reconstruct_parser(sub, fmt)
    _add_toyworld_baseline_parser(sub, fmt)
    _add_toyworld_rollout_parser(sub, fmt)
    _add_toyworld_package_parser(sub, fmt)
    add_policy_parsers(sub, EXAMPLES)
    add_counterfactual_parser(sub)
    add_decision_fit_parser(sub)
    _add_toyworld_eval_parser(sub, fmt)
    return tw


def _registry(args):
    from ..plugin.registry import Registry

    return Registry(plugin_paths=getattr(args, "plugin", None) or ())


def cmd_example(args) -> int:
    from ..render.skeleton_video import parse_size
    from .example import write_example

    w, h = parse_size(args.size)
    summary = write_example(
        args.out,
        args.embodiment,
        seed=args.seed,
        width=w,
        height=h,
        frames=args.frames,
        fps=args.fps,
        registry=_registry(args),
    )
    if args.json:
        print(json.dumps(summary))
        return 0
    print(
        f"{args.out}: {summary['episode']}, {args.frames} frames at {w}x{h}, {args.fps:g} fps: "
        + ", ".join(Path(f).name for f in summary["files"])
    )
    print(
        f"  oscar rollout --model oscar-toy --embodiment {summary['embodiment']} "
        f"--first-frame {summary['files'][0]} --trajectory {summary['files'][1]} --camera {summary['files'][2]} "
        f"--out toy_rollout.mp4"
    )
    return 0


def cmd_generate(args) -> int:
    from ..render.skeleton_video import parse_size
    from .generate import GenerateConfig, generate_clipset

    w, h = parse_size(args.size)
    names = tuple(n.strip() for n in args.embodiments.split(",") if n.strip())
    if not names:
        raise ValueError("--embodiments: expected comma-separated embodiment names, found none")
    cfg = GenerateConfig(
        names,
        args.episodes,
        w,
        h,
        args.frames,
        args.fps,
        args.seed,
        args.shard_size,
        args.supersample,
        not args.no_skeleton,
        args.pick_miss,
        args.pick_open,
        args.push,
        args.pick_timing,
    )
    with run_log(args.out, "toyworld-generate"):
        summary = generate_clipset(cfg, args.out, _registry(args))
        log_result(f"{summary['episodes_written']} episodes written, {summary['episodes_skipped']} kept")
    if args.json:
        print(json.dumps(summary))
    else:
        eps = summary["episodes_per_s"]
        print(
            f"{args.out}: {summary['episodes_written']} episodes written, {summary['episodes_skipped']} kept from "
            f"an earlier run, {summary['wall_s']:.1f} s" + (f" ({eps:.2f} episodes/s)" if eps else "")
        )
    return 0


def cmd_reconstruct(args) -> int:
    from .vae_train import write_reconstructions

    ids = write_reconstructions(
        args.clips, args.vae, args.out, None if args.split == "all" else args.split, args.limit, args.threads
    )
    print(f"{args.out}: {len(ids)} reconstructions")
    return 0


def cmd_baseline(args) -> int:
    from .baselines import write_baseline

    ids = write_baseline(args.clips, args.out, args.kind, None if args.split == "all" else args.split, args.limit)
    print(f"{args.out}: {len(ids)} {args.kind} predictions")
    return 0


def cmd_rollout(args) -> int:
    import oscar_zoo

    from .._util.stage import model_identity
    from ..model.card_sampler import resolve_sampler
    from .rollouts import write_rollouts

    model = oscar_zoo.load(args.model)
    choice = resolve_sampler(
        model.card.sampler,
        steps=args.steps,
        guidance=args.guidance,
        guidance_form=args.guidance_form,
        guidance_interval=args.guidance_interval,
        preset=args.preset,
    )
    sampler = choice.config
    print(f"sampler: {choice.describe('flag')}", file=sys.stderr)
    with run_log(args.out, f"toyworld-rollout-{args.condition}"):
        summary = write_rollouts(
            model,
            args.clips,
            args.out,
            args.condition,
            split=None if args.split == "all" else args.split,
            limit=args.limit,
            sampler=sampler,
            seed=args.seed,
            registry=_registry(args),
            model_id=model_identity(args.model),
        )
        log_result(f"{summary['written']} rollouts written, {summary['kept']} kept")
    per = f", {summary['s_per_rollout']:.2f} s per rollout" if summary["s_per_rollout"] else ""
    print(
        f"{args.out}: {summary['written']} {args.condition}-skeleton rollouts written, {summary['kept']} kept from "
        f"an earlier run{per}"
    )
    return 0


def cmd_package(args) -> int:
    from .evaluate import format_table
    from .package import package_toy_model

    training = json.loads(Path(args.training).read_text()) if args.training else None
    table = json.loads(Path(args.table).read_text()) if args.table else None
    if table is not None:
        table = {**table, "markdown": format_table(table)}
    hashes = package_toy_model(args.export, args.out, name=args.name, training=training, table=table)
    print(json.dumps(hashes, indent=2))
    return 0


def cmd_eval(args) -> int:
    from .._util.atomic import atomic_write_bytes
    from .evaluate import add_paired, evaluate_conditions, format_table, parse_pred_args, plot_table

    conditions = parse_pred_args(args.pred)
    if args.paired is not None and args.paired not in conditions:
        raise ValueError(f"--paired {args.paired}: expected the name of a --pred row ({', '.join(conditions)})")
    split = None if args.split == "all" else args.split  # 'all' means what it means to rollout and baseline
    table = evaluate_conditions(args.gt, conditions, split=split, clips_mode=args.clips, per_chunk=args.per_chunk)
    if args.paired is not None:
        add_paired(table, args.paired)
    if args.out:
        atomic_write_bytes(args.out, (json.dumps(table, indent=2) + "\n").encode())
    if args.plot:
        plot_table(table, args.plot)
    html = args.html or (str(Path(args.out).with_suffix(".html")) if args.out else None)
    if html and not args.no_html:
        from .html import write_eval_html

        write_eval_html(table, args.gt, conditions, html, plot=args.plot, max_clips=args.html_clips)
    print(json.dumps(table, indent=2) if args.json else format_table(table))
    if html and not args.no_html and not args.json:
        print(f"wrote {html}")
    return 0
