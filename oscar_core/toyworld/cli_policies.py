"""The ``oscar toyworld`` sub-commands of the policy evaluation: ``policy-eval`` (scripted pick-and-place policies and
their true outcomes, an ``oscar eval run`` manifest), ``closed-loop-sessions`` (toy sessions and image-based policies,
an ``oscar eval closed-loop`` manifest) and ``carry`` (where the generated ball goes, per policy): their arguments and
the commands. :func:`add_policy_parsers` adds them to the sub-parsers of ``oscar toyworld``
(:mod:`oscar_core.toyworld.cli`, which re-exports the commands); each sets ``func`` (returns an exit code).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .._util.arg_types import count, number
from .._util.log import get_logger
from .._util.outputs import output_option

__all__ = ["add_policy_parsers", "cmd_carry", "cmd_closed_loop_sessions", "cmd_policy_eval"]

_log = get_logger(__name__)


def add_policy_parsers(sub, epilog: str) -> None:
    """Add ``policy-eval``, ``closed-loop-sessions`` and ``carry`` to ``sub`` (the sub-parsers of ``oscar toyworld``),
    each with ``epilog`` (the examples) under its help."""
    fmt = argparse.RawDescriptionHelpFormatter
    pe = sub.add_parser(
        "policy-eval",
        help="scripted pick-and-place policies: write an `oscar eval run` manifest with their real outcomes",
        epilog=epilog,
        formatter_class=fmt,
    )
    _add_policy_eval_arguments(pe)
    pe.set_defaults(func=cmd_policy_eval)
    cl = sub.add_parser(
        "closed-loop-sessions",
        help="toy sessions and image-based policies: write an `oscar eval closed-loop` manifest",
        epilog=epilog,
        formatter_class=fmt,
    )
    cl.add_argument("--embodiments", required=True, help="comma-separated embodiment names with a gripper")
    cl.add_argument("--sessions", type=count(1), required=True, help="sessions per embodiment")
    cl.add_argument("--seed", type=count(0), default=0, help="session i of embodiment e depends on (seed, e, i) only")
    cl.add_argument("--horizon", type=count(2), default=49, help="frames per episode, the first included (default 49)")
    cl.add_argument("--policies", help="comma-separated toy policies (default: exact,noisy,late,never_closes,random)")
    output_option(
        cl.add_argument("--out", required=True, help="folder for manifest.json and the session folders"), "folder"
    )
    cl.set_defaults(func=cmd_closed_loop_sessions)
    cy = sub.add_parser(
        "carry",
        help="where the generated ball goes: per-cell judge internals of an `oscar eval "
        "run` on a policy-eval manifest, per policy against the real grab",
        epilog=epilog,
        formatter_class=fmt,
    )
    _add_carry_arguments(cy)
    cy.set_defaults(func=cmd_carry)


def _add_policy_eval_arguments(p) -> None:
    """The options of ``oscar toyworld policy-eval`` (on the argparse parser ``p``)."""
    p.add_argument("--embodiments", required=True, help="comma-separated embodiment names with a gripper")
    p.add_argument("--sessions", type=count(1), required=True, help="sessions (scenes) per embodiment")
    p.add_argument(
        "--seed", type=count(0), default=0, help="seed: session i of embodiment e depends on (seed, e, i) only"
    )
    output_option(
        p.add_argument(
            "--out", required=True, help="folder for manifest.json, policy_eval.json and the session folders"
        ),
        "folder",
    )
    p.add_argument("--size", default="64x64", help="WIDTHxHEIGHT pixels, multiples of 16 (default 64x64)")
    p.add_argument("--frames", type=count(1), default=17, help="frames per episode (default 17: one oscar-toy chunk)")
    p.add_argument("--fps", type=number(above=0.0), default=10.0, help="frame rate of the trajectories (default 10)")
    p.add_argument(
        "--supersample", type=count(1), default=2, help="anti-aliasing factor of the real renders (default 2)"
    )
    p.add_argument("--json", action="store_true", help="print the summary (without per-episode rows) as JSON")


def cmd_policy_eval(args) -> int:
    """``oscar toyworld policy-eval``: write the manifest (:func:`~oscar_core.toyworld.policy_eval_write.write_policy_eval`)
    and print the true success rate per policy."""
    from ..plugin.registry import Registry
    from ..render.skeleton_video import parse_size
    from .policy_eval import SUCCESS_RADII
    from .policy_eval_write import write_policy_eval

    w, h = parse_size(args.size)
    names = tuple(n.strip() for n in args.embodiments.split(",") if n.strip())
    if not names:
        raise ValueError("--embodiments: expected comma-separated embodiment names, found none")
    summary = write_policy_eval(
        args.out,
        names,
        args.sessions,
        seed=args.seed,
        width=w,
        height=h,
        frames=args.frames,
        fps=args.fps,
        supersample=args.supersample,
        registry=Registry(plugin_paths=getattr(args, "plugin", None) or ()),
        progress=_log.info,
    )
    if args.json:
        print(json.dumps({k: v for k, v in summary.items() if k != "rows"}))
        return 0
    print(
        f"{args.out}/manifest.json: {len(summary['rows'])} cells, {args.sessions} sessions x "
        f"{len(names)} embodiments; true success rate per policy (ball grabbed and moved >= "
        f"{SUCCESS_RADII:g} ball radii):"
    )
    for p, v in summary["policies"].items():
        per = ", ".join(f"{e} {r:.2f}" for e, r in v["by_embodiment"].items())
        print(f"  {p:<8} aim sigma {v['aim_sigma_radii']:.2f} R: {v['success_rate']:.2f}  ({per})")
    return 0


def _add_carry_arguments(p) -> None:
    p.add_argument("manifest", help="manifest.json of oscar toyworld policy-eval (policy_eval.json beside it)")
    p.add_argument("eval_out", help="the --out folder of oscar eval run on that manifest (its rollouts)")
    output_option(
        p.add_argument("--json", default=None, help="also write every row and the summary to this JSON file"), "file"
    )


def cmd_carry(args) -> int:
    """``oscar toyworld carry``: print the per-policy table of :func:`~oscar_core.toyworld.carry.carry_table` (and
    write its rows and summary as JSON on request)."""
    from .._util.atomic import atomic_write_bytes
    from .carry import carry_table

    table = carry_table(args.manifest, args.eval_out)
    summary, rows = table["summary"], table["rows"]

    def f(x) -> str:
        return "n/a" if x is None else f"{x:.2f}"

    print(
        "| policy | cells | real SR | WM SR | real grabs | WM ball left start: grabbed / missed | "
        "WM success: grabbed / missed | blob to place (R) | blob to end-effector end (R) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for p, s in summary.items():
        print(
            f"| {p} | {s['cells']} | {f(s['real_sr'])} | {f(s['wm_sr'])} | {s['grabbed']} | "
            f"{f(s['left_if_grabbed'])} / {f(s['left_if_missed'])} | {f(s['success_if_grabbed'])} / "
            f"{f(s['success_if_missed'])} | {f(s['blob_to_place'])} | {f(s['blob_to_ee_end'])} |"
        )
    if args.json:
        atomic_write_bytes(Path(args.json), (json.dumps({"summary": summary, "rows": rows}, indent=1) + "\n").encode())
    return 0


def cmd_closed_loop_sessions(args) -> int:
    """``oscar toyworld closed-loop-sessions``: write toy sessions and a closed-loop manifest."""
    from ..plugin.registry import Registry
    from .closed_loop import write_closed_loop_sessions
    from .image_policies import POLICIES

    names = [n.strip() for n in args.embodiments.split(",") if n.strip()]
    pols = [p.strip() for p in args.policies.split(",") if p.strip()] if args.policies else None
    bad = [p for p in pols or () if p not in POLICIES]
    if not names or bad:
        raise ValueError(
            f"--embodiments/--policies: expected embodiment names and toy policies among "
            f"{list(POLICIES)}, found {names} / {bad}"
        )
    path = write_closed_loop_sessions(
        args.out,
        names,
        args.sessions,
        seed=args.seed,
        horizon=args.horizon,
        policies=pols,
        registry=Registry(plugin_paths=getattr(args, "plugin", None) or ()),
    )
    print(f"wrote {path}: {args.sessions} sessions x {len(names)} embodiments")
    return 0
