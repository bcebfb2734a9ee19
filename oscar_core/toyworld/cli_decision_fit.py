"""``oscar toyworld decision-fit``: does a model obey the gripper on its training episodes and on held-out ones of
the same toy world clip set (:mod:`oscar_core.toyworld.decision_fit`)?"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .._util.arg_types import count, default_device, device_name, number
from .._util.log import log_result, progress_bars_enabled
from .._util.outputs import output_option
from .._util.threads import threads_option

__all__ = ["add_decision_fit_parser", "cmd_decision_fit"]

EXAMPLES = """examples:
  oscar toyworld decision-fit --model runs/obey-sf/export --clips clipsets/cf49b --per-class 10 \\
      --steps 10 --guidance 0 --out fit.json
      (10 episodes per embodiment, split and class: carried / closed beside the ball / open hand)
"""


def add_decision_fit_parser(sub) -> argparse.ArgumentParser:
    """Add ``decision-fit`` to the sub-parsers of ``oscar toyworld``."""
    a = sub.add_parser(
        "decision-fit",
        help="one chunk per pick episode of a toy clip set, from its true frame before the gripper's decision: "
        "does the model's outcome agree with the simulator's, on training and on held-out episodes?",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    a.add_argument("--model", required=True, help="world model: zoo name (oscar-toy) or folder (a run's export)")
    a.add_argument(
        "--clips", required=True, nargs="+", help="toy world clip set folders (oscar toyworld generate --pick-...)"
    )
    a.add_argument(
        "--per-class",
        type=count(1),
        help="episodes per clip set, embodiment, split and class, drawn with --seed (default: all)",
    )
    a.add_argument(
        "--lead", type=count(0), default=2, help="frames of the window before the decision frame (default 2)"
    )
    a.add_argument("--seed", type=count(0), default=0, help="which episodes are drawn; the sampler's noise seed")
    a.add_argument("--steps", type=count(1), help="denoising steps per chunk (default: the model card's)")
    a.add_argument("--guidance", type=number(0.0), help="skeleton guidance w (default: the model card's)")
    a.add_argument("--guidance-form", choices=("standard", "diffusers"), help="default: the model card's")
    a.add_argument("--device", type=device_name, help="torch device (default: cuda when available, else cpu)")
    threads_option(a, "torch CPU threads of the world model")
    output_option(a.add_argument("--out", required=True, help="report JSON (rows, table, gaps)"), "file")
    a.add_argument("--no-progress", action="store_true", help="no progress line per window")
    a.add_argument("--json", action="store_true", help="print the table and gaps as JSON")
    a.set_defaults(func=cmd_decision_fit)
    return a


def cmd_decision_fit(args) -> int:
    """Check the clip sets and the model's card, then score every window (module docstring)."""
    import oscar_zoo

    from .._util.atomic import atomic_write_bytes
    from ..evaluation.loop import card_sampler_of
    from ..model.card_sampler import resolve_sampler
    from ..plugin.registry import Registry
    from .cli_counterfactual import _card
    from .decision_fit import choose_windows, decision_fit
    from .motion import ToyWorldError

    options = dict(steps=args.steps, guidance=args.guidance, guidance_form=args.guidance_form)
    resolve_sampler(None, **options)  # the flags checked before the model is looked up
    card = _card(args.model)
    if card is None or not card.chunk_frames:
        raise ToyWorldError(f"{args.model}: oscar_model.json: chunk_frames: expected an OSCAR model card, found none")
    frames = int(card.chunk_frames)
    registry = Registry(plugin_paths=getattr(args, "plugin", None) or ())
    windows = choose_windows(args.clips, frames, args.per_class, registry, seed=args.seed, lead=args.lead)
    choice = resolve_sampler(card_sampler_of(args.model), **options)
    print(f"{len(windows)} windows of {frames} frames; sampler: {choice.describe('flag')}", file=sys.stderr)
    model = oscar_zoo.load(args.model, device=args.device or default_device())

    def roll(clip, embodiment: str):
        result = model.rollout_trajectory(
            clip.rgb[0],
            clip.trajectory,
            clip.camera,
            registry.get(embodiment),
            sampler=choice.config,
            seed=args.seed,
            progress=False,
            chunk_frames=frames,
        )
        return result.frames

    show = not args.no_progress and progress_bars_enabled()

    def progress(row: dict) -> None:
        if show:
            said = row.get("error") or f"truth {row['truth']}, model {row['model']}"
            print(f"{row['clip_id']} [{row['split']}, {row['cls']}]: {said}", file=sys.stderr)

    report = decision_fit(windows, roll, frames, registry=registry, progress=progress)
    report = {"model": args.model, "clips": [str(c) for c in args.clips], "sampler": choice.config.__dict__, **report}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)  # missing folders between are the writer's to make
    atomic_write_bytes(Path(args.out), (json.dumps(report, indent=1, default=str) + "\n").encode())
    log_result(f"wrote {args.out}")
    if args.json:
        print(json.dumps({k: report[k] for k in ("table", "gaps")}, indent=1))
    else:
        print(format_table(report))
    scored = sum(r["windows"] for r in report["table"] if r["class"] == "all")
    if not scored:
        print(f"error: no window could be scored ({len(windows)} failed; reasons in {args.out})", file=sys.stderr)
        return 1
    return 0


def format_table(report: dict) -> str:
    """The report's table and gaps as Markdown."""

    def pct(v) -> str:
        return "—" if v is None else f"{100 * v:.0f} %"

    def ci(v) -> str:
        return "" if v is None else f" [{100 * v[0]:.0f}, {100 * v[1]:.0f}]"

    lines = [
        "| split | class | windows scored | agree | model moved the ball | left out: truth not as its class / failed |",
        "|---|---|---|---|---|---|",
    ]
    for r in report["table"]:
        lines.append(
            f"| {r['split']} | {r['class']} | {r['windows']} | {r['agree']} = {pct(r['rate'])}{ci(r['interval'])} "
            f"| {r['model_moved']} | {r['truth_not_as_class']} / {r['failed']} |"
        )
    lines += ["", "| class | train − held-out agreement |", "|---|---|"]
    for g in report["gaps"]:
        value = g["undefined"] if g["undefined"] else f"{100 * g['train_minus_heldout']:+.0f} pp"
        lines.append(f"| {g['class']} | {value}{ci(g['interval'])} |")
    return "\n".join(lines)
