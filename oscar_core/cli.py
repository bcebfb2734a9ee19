"""The ``oscar`` command."""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from collections.abc import Callable
from typing import Any

from ._util.log import cli_output, set_command_line
from ._util.outputs import check_writable, output_kind, output_option
from .errors import OscarError

EXAMPLES = """examples:
  oscar embodiments
  oscar embodiments --json
  oscar render --embodiment toyarm --trajectory traj.npz --camera cam.json --out skel.mp4 --size 512x288
  oscar render --embodiment toyarm --trajectory traj.npz --camera cam.json --out check.mp4 --overlay rgb.mp4
  oscar render ... --out skel.mkv          (lossless FFV1, for training data)
  oscar render ... --out frames/           (lossless PNG frames)
  oscar calibrate --embodiment franka --trajectory traj.npz --points points.json --size 1280x720 --estimate-intrinsics --out cam.json
  oscar demo --out demo_out
  oscar zoo list
  oscar rollout --model oscar-2b --embodiment franka --first-frame img.png --trajectory traj.npz --camera cam.json --out rollout.mp4
  oscar eval video pred.mp4 gt.mp4
  oscar eval benchmark build clips/ --out bench.json --total 200   (then: benchmark run, benchmark table)
  oscar train configs/train/tiny-cpu.yaml
  oscar --plugin ./my_robot.py embodiments (load a one-file plugin)
  oscar -q toyworld generate ...   (warnings and results only; -v for debug lines, also: OSCAR_VERBOSITY)
  oscar toyworld generate ... --no-progress   (no progress bars; also when stderr is not a terminal)
"""


def _registry(args):
    from .plugin.registry import Registry

    return Registry(plugin_paths=args.plugin or ())


def cmd_embodiments(args) -> int:
    reg = _registry(args)
    rows = []
    for name in reg.names():
        entry = reg.entries[name]
        row = {"name": name, "distribution": entry.distribution, "version": entry.version, "plugin": entry.plugin}
        try:
            emb = reg.get(name)
            row.update(emb.info())
            row["joint_names"] = list(emb.joint_names)  # the order trajectory columns are put in
        except OscarError as exc:
            row["error"] = str(exc)
        rows.append(row)
    failures = [{"plugin": f.plugin, "distribution": f.distribution, "error": f.error} for f in reg.failures]
    if args.json:
        print(json.dumps({"embodiments": rows, "failures": failures}, indent=2))
        return 0
    header = ("name", "joints", "grippers", "datasets", "license", "distribution")
    table = [header] + [
        (
            r["name"],
            str(r.get("joints", "?")),
            ",".join(r.get("grippers", [])) or "-",
            ",".join(r.get("datasets", [])) or "-",
            r.get("license") or "-",
            f"{r['distribution']} {r['version']}".strip(),
        )
        for r in rows
    ]
    widths = [max(len(row[i]) for row in table) for i in range(len(header))]
    for row in table:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip())
    for r in rows:
        if "error" in r:
            print(f"error: {r['name']}: {r['error']}", file=sys.stderr)
    for f in reg.failures:
        print(f"failed plugin: {f}", file=sys.stderr)
    return 0


def cmd_demo(args) -> int:
    from .demo import run_demo
    from .plugin.registry import Registry
    from .render.skeleton_video import parse_size

    run_demo(
        args.out,
        size=parse_size(args.size),
        registry=Registry(plugin_paths=args.plugin or ()),
        toy_model=None if args.no_toy_world else args.toy_model,
    )
    return 0


def _add_embodiments(sub) -> None:
    e = sub.add_parser(
        "embodiments",
        help=COMMANDS["embodiments"][0],
        epilog="example: oscar embodiments --json",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    e.add_argument("--json", action="store_true", help="machine-readable output")
    e.set_defaults(func=cmd_embodiments)


def _add_demo(sub) -> None:
    d = sub.add_parser("demo", help=COMMANDS["demo"][0])
    output_option(d.add_argument("--out", default="demo_out", help="output folder (default demo_out)"), "folder")
    d.add_argument("--size", default="512x288", help="output WIDTHxHEIGHT (default 512x288)")
    d.add_argument(
        "--toy-model",
        default="oscar-toy",
        help="toy-world model rolled out on a held-out episode (default oscar-toy, bundled)",
    )
    d.add_argument("--no-toy-world", action="store_true", help="skip the toy-world rollout")
    d.set_defaults(func=cmd_demo)


def _add_render(sub) -> None:
    from .render.cli import add_render_parser

    add_render_parser(sub)


def _add_calibrate(sub) -> None:
    from .calibration.cli import add_calibrate_parser

    add_calibrate_parser(sub)


def _add_eval(sub) -> None:
    from .evaluation.cli import add_run_parser
    from .evaluation.cli_action_following import add_action_following_parser
    from .evaluation.cli_benchmark import add_benchmark_parser
    from .evaluation.cli_closed_loop import add_closed_loop_parser
    from .evaluation.cli_roboarena import add_roboarena_parser
    from .metrics.cli import add_eval_parser

    add_eval_parser(
        sub,
        extra_commands=(
            add_run_parser,
            add_benchmark_parser,
            add_closed_loop_parser,
            add_roboarena_parser,
            add_action_following_parser,
        ),
    )


def _add_model(sub) -> None:
    from .model.cli import add_model_parsers

    add_model_parsers(sub)


def _add_zoo(sub) -> None:
    from oscar_zoo.cli import add_zoo_parsers

    add_zoo_parsers(sub)


def _add_data(sub) -> None:
    from .data.cli import add_data_parser

    add_data_parser(sub)


def _add_train(sub) -> None:
    from .train.cli import add_train_parser

    add_train_parser(sub)


def _add_toyworld(sub) -> None:
    from .toyworld.cli import add_toyworld_parser

    add_toyworld_parser(sub)


def _add_view(sub) -> None:
    from .viz.cli import add_view_parser

    add_view_parser(sub)


#: The top-level commands in the order ``oscar --help`` lists them: name -> (the line ``oscar --help`` shows, the
#: function that adds the command's parser). Only the parser of the command being run is built, so ``oscar --help``
#: and a command's start import none of the other commands' modules (the rollout's diffusers, the data pipeline's
#: readers). Commands added by one function (``zoo`` and ``encode-prompt``) stand together.
#: tests/cli/test_cli_lazy.py keeps each line equal to the help its parser declares.
COMMANDS: dict[str, tuple[str, Callable[[Any], None]]] = {
    "embodiments": ("list installed embodiments", _add_embodiments),
    "render": (
        "render skeleton (or mesh) condition videos from trajectories (one, or many with a worker pool)",
        _add_render,
    ),
    "calibrate": (
        "estimate a fixed camera from skeleton points on video frames (PnP); `calibrate score`: how well a camera "
        "lines the robot up with a video",
        _add_calibrate,
    ),
    "demo": (
        "render every embodiment's bundled example and roll the toy world model out (MP4s + contact sheet)",
        _add_demo,
    ),
    "eval": ("evaluate world-model videos or policy rankings", _add_eval),
    "rollout": ("roll the world model out along a trajectory (skeleton-conditioned)", _add_model),
    "zoo": ("named world-model checkpoints: list, pull", _add_zoo),
    "encode-prompt": ("compute (and cache) the text embedding of a prompt", _add_zoo),
    "data": ("data pipeline: ingest, filter, dedup, caption, export, stats", _add_data),
    "train": ("train the world model (the paper's fine-tuning recipe)", _add_train),
    "toyworld": ("the procedural toy world: generate clips, train its VAE, evaluate", _add_toyworld),
    "view": ("open an episode, a clip, a rollout or an eval cell in Rerun (or write an .rrd)", _add_view),
}

#: ``build_parser(only=ALL)``: every command's parser built.
ALL = None


def build_parser(only: str | None = ALL, *, stubs: bool = False) -> argparse.ArgumentParser:
    """The ``oscar`` parser. ``only``: the one command whose parser is built (with the others of its group); every
    other command is a stand-in with its help line only, which takes any arguments. ``stubs``: every command a
    stand-in (enough for ``oscar --help`` and to find which command a command line runs). Default: all built."""
    p = argparse.ArgumentParser(
        prog="oscar",
        description="Skeleton videos for any robot body, and the OSCAR world model.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--plugin",
        action="append",
        metavar="PATH",
        help="load a one-file plugin (.py) or a folder of them; repeatable (also: OSCAR_PLUGINS)",
    )
    _add_output_flags(p, None)
    sub = p.add_subparsers(dest="command", required=True)
    built = set()
    for name, (help_line, add) in COMMANDS.items():
        if stubs or (only is not ALL and COMMANDS.get(only, (None, None))[1] is not add):
            sub.add_parser(name, help=help_line, add_help=False)  # a stand-in: never the command that runs
        elif add not in built:
            built.add(add)
            add(sub)
    for leaf in _leaves(p):
        _add_output_flags(leaf, argparse.SUPPRESS)
        leaf.set_defaults(
            _outputs=tuple((a.dest, output_kind(a)) for a in leaf._actions if output_kind(a)),
            _threads=any(getattr(a, "oscar_threads", False) for a in leaf._actions),
        )
    from ._util.cli_examples import own_examples

    own_examples(p)  # a sub-command's --help shows its own examples, not its group's
    return p


def command_of(argv: list[str]) -> str:
    """The top-level command ``argv`` runs (``oscar -q render ...`` -> ``render``), read by a parser of stand-ins
    (no command's module imported). ``oscar --help`` prints the help and exits here; a missing or unknown command
    is argparse's usual error (exit 2)."""
    return build_parser(stubs=True).parse_known_args(argv)[0].command


def check_outputs(args) -> None:
    """Check every output option of the parsed command (:func:`oscar_core._util.outputs.output_option`) can be
    written; raises :class:`~oscar_core.errors.OutputPathError` (one line, exit 2) before any work."""
    for dest, kind in getattr(args, "_outputs", ()):
        value = getattr(args, dest, None)
        for path in value if isinstance(value, list) else [value]:
            if path is not None:
                check_writable(path, kind)


def _add_output_flags(parser: argparse.ArgumentParser, default) -> None:
    """``-v/--verbose``, ``-q/--quiet`` and ``--no-progress``: the one flag family of every command.

    On the top parser they default to 0/False; on each sub-command they are
    repeated with ``default=SUPPRESS`` so ``oscar -q data run ...`` and
    ``oscar data run ... -q`` both work (argparse would otherwise let the
    sub-command's default overwrite the top-level value). A sub-command that
    already declares ``--no-progress`` keeps its help text; only its default
    is suppressed.
    """
    have = {opt for a in parser._actions for opt in a.option_strings}
    if "-v" not in have:
        parser.add_argument(
            "-v",
            "--verbose",
            action="count",
            default=0 if default is None else default,
            help="more output: debug lines (logging level DEBUG)",
        )
    if "-q" not in have:
        parser.add_argument(
            "-q",
            "--quiet",
            action="count",
            default=0 if default is None else default,
            help="less output: -q warnings and results only, -qq errors and results only",
        )
    if "--no-progress" in have:
        for a in parser._actions:  # `render` has its own --progress/--no-progress (dest "progress"): left alone
            if "--no-progress" in a.option_strings and a.dest == "no_progress":
                a.default = argparse.SUPPRESS
    else:
        parser.add_argument(
            "--no-progress",
            action="store_true",
            default=False if default is None else default,
            help="no progress bars (they are also off when stderr is not a terminal)",
        )


def _leaves(parser: argparse.ArgumentParser):
    """Every sub-command parser that runs a command: those with no sub-commands of their own, and those that
    run one without a sub-command (``oscar calibrate``, beside ``oscar calibrate score``)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs or parser.get_default("func") is not None:  # a command of its own as well as sub-commands
        yield parser
    if not subs:
        return
    seen = set()
    for action in subs:
        for child in action.choices.values():
            if id(child) not in seen:  # aliases map several names to one parser
                seen.add(id(child))
                yield from _leaves(child)


def apply_threads(args) -> None:
    """``--threads`` of a command that runs torch: the choice of :func:`oscar_core._util.threads.choose_threads`
    applied to torch (``args.threads`` becomes the count); a count above the idle cores warns."""
    if not getattr(args, "_threads", False):
        return
    from ._util.threads import check_threads, use_threads

    if args.threads is not None:
        check_threads(args.threads, "--threads")
    # render runs torch only for a CUDA device or meshes: the count goes to OMP_NUM_THREADS, torch stays unloaded
    args.threads = use_threads(args.threads, import_torch=args.command != "render")


def main(argv=None) -> int:
    from ._util.interrupt import interrupted, noting_interrupts, report
    from ._util.threads import passive_openmp

    passive_openmp()  # before anything loads torch (and its OpenMP runtime)
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(only=command_of(argv))
    args = parser.parse_args(argv)
    # what report pages name as their command, and the first line of run logs
    set_command_line(["oscar", *argv])
    warnings.simplefilter("default")
    with noting_interrupts():
        try:
            check_outputs(args)
            with cli_output(args.verbose, args.quiet, progress=not args.no_progress):
                apply_threads(args)
                code = args.func(args)
            sys.stdout.flush()
            return code
        except KeyboardInterrupt as exc:
            return report(exc, args)
        except (OscarError, ValueError, FileNotFoundError) as exc:
            if interrupted():  # an error Ctrl-C caused (e.g. a write cut short): report the interrupt
                return report(KeyboardInterrupt(), args)
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except MemoryError as exc:
            # numpy says "Unable to allocate 596. GiB for an array with shape …": one line, not a traceback
            detail = str(exc) or "an allocation failed"
            print(
                f"error: out of memory: {detail}; a smaller --size, fewer frames or fewer workers need less",
                file=sys.stderr,
            )
            return 2
        except BrokenPipeError:
            # the reader went away (`oscar ... | head`): stop quietly; point stdout at
            # devnull so the interpreter's final flush does not raise again
            import os

            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 1
        except BaseException:
            # a library that turns the KeyboardInterrupt into its own error (torch's checkpoint
            # writer: RuntimeError inside a CheckpointException) still ends as an interrupt
            if interrupted():
                return report(KeyboardInterrupt(), args)
            raise


def run() -> None:
    """The ``oscar`` command's entry point: :func:`main` on ``sys.argv``, then the process ends without the
    interpreter's module teardown (``oscar_core._util.fast_exit``; about 1 s after a rollout)."""
    from ._util.fast_exit import exit_process

    exit_process(main())


if __name__ == "__main__":
    run()
