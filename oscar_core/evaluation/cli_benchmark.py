"""``oscar eval benchmark build | run | table``: the paper's benchmark protocol as commands.

Registered under ``oscar eval`` by :func:`add_benchmark_parser` (the top-level
CLI passes it to ``add_eval_parser``). The rules are
:mod:`oscar_core.evaluation.benchmark_rules`, the set file
:mod:`~oscar_core.evaluation.benchmark_set`, the rollouts
:mod:`~oscar_core.evaluation.benchmark_run`, the table
:mod:`~oscar_core.evaluation.benchmark_table`; docs/evaluation.md, "The benchmark protocol".
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .._util.arg_types import count, default_device, device, number
from .._util.log import log_result, run_log
from .._util.outputs import output_option
from .._util.threads import threads_option
from .cli_options import add_sampler_options

__all__ = ["add_benchmark_parser"]

EXAMPLES = """examples:
  oscar eval benchmark build clips/droid clips/rh20t --out bench.json --total 200
  oscar eval benchmark build /tmp/bench_clips --out bench.json --total 9 --frames 17
  oscar eval benchmark run bench.json --model oscar-2b --out preds/oscar-2b --device cuda --dtype bfloat16
  oscar eval benchmark run bench.json --model oscar-toy --out preds/toy --steps 20 --guidance 3
  oscar eval benchmark table --set bench.json --pred toy=preds/toy --pred other=preds/other --out table.json
"""


def cmd_build(args) -> int:
    from ..plugin.registry import Registry
    from .benchmark_set import build_benchmark_set

    data = build_benchmark_set(
        args.clipsets,
        args.out,
        args.total,
        frames=args.frames,
        clusters=args.clusters,
        seed=args.seed,
        split=None if args.split == "all" else args.split,
        margin=args.margin,
        text=args.text,
        registry=Registry(plugin_paths=getattr(args, "plugin", None) or ()),
    )
    if args.json:
        print(json.dumps({k: data[k] for k in ("counts", "quotas", "fingerprint")}, indent=2))
        return 0
    c = data["counts"]
    print(
        f"{args.out}: {c['chosen']} clips of {c['candidates']} (dropped: {c['forward_window']} by the forward "
        f"window, {c['dedup']} as near-duplicates, {c['quota']} by the quotas)"
    )
    for g, q in data["quotas"].items():
        print(f"  {g}: corpus {q['corpus']}, passed {q['passed']}, quota {q['quota']}")
    return 0


def cmd_run(args) -> int:
    import torch

    import oscar_zoo

    from .._util.stage import model_identity
    from ..plugin.registry import Registry
    from .benchmark_run import run_benchmark
    from .benchmark_set import load_benchmark_set
    from .cli_options import resolve_sampler_flags

    bench = load_benchmark_set(args.set)  # a bad set file fails before the model loads
    dtype = getattr(torch, args.dtype) if args.dtype else None
    loaded = []

    def card_sampler():  # called once the sampler flags passed their checks
        loaded.append(oscar_zoo.load(args.model, device=args.device or default_device(), dtype=dtype))
        return loaded[0].card.sampler

    choice = resolve_sampler_flags(args, card_sampler)
    model = loaded[0]
    sampler = choice.config
    print(f"sampler: {choice.describe('flag')}", file=sys.stderr)
    with run_log(args.out, "benchmark-run"):
        s = run_benchmark(
            model,
            bench,
            args.out,
            sampler=sampler,
            seed=args.seed,
            prompt=args.prompt,
            registry=Registry(plugin_paths=getattr(args, "plugin", None) or ()),
            model_id=model_identity(args.model),
        )
        log_result(f"{s['written']} rollouts written, {s['kept']} kept, {s['clips']} in the set")
    speed = f", {s['frames_per_s']:.2f} frames/s" if s["frames_per_s"] else ""
    print(
        f"{args.out}: {s['written']} rollouts written, {s['kept']} kept from an earlier run, "
        f"{s['clips']} in the set{speed}"
    )
    return 0


def _parse_rows(values) -> dict[str, str]:
    rows: dict[str, str] = {}
    for v in values:
        name, sep, path = v.partition("=")
        if not sep:
            name, path = Path(v).name or v, v
        if not name or not path:
            raise ValueError(f"--pred: expected NAME=FOLDER or FOLDER, found {v!r}")
        if name in rows:
            raise ValueError(f"--pred: row {name!r} given twice")
        rows[name] = path
    return rows


def cmd_table(args) -> int:
    from .._util.atomic import atomic_write_bytes
    from ..metrics.networks import resolve_networks
    from .benchmark_set import load_benchmark_set
    from .benchmark_table import benchmark_table, format_benchmark_table

    bench = load_benchmark_set(args.set)
    rows = _parse_rows(args.pred)
    nets, used_cache, notes = resolve_networks(
        lpips=args.lpips,
        i3d=args.i3d,
        inception=args.inception,
        vae=args.vae,
        vae_model=args.vae_model,
        use_cache=not args.no_cached_networks,
        device=args.device,
    )
    table = benchmark_table(bench, rows, networks=nets, notes=notes, device=args.device)
    table["networks_from_cache"] = used_cache
    md = format_benchmark_table(table)
    if args.out:
        atomic_write_bytes(args.out, (json.dumps(table, indent=1) + "\n").encode())
        atomic_write_bytes(Path(args.out).with_suffix(".md"), (md + "\n").encode())
    print(json.dumps(table, indent=1) if args.json else md)
    return 0


def _add_benchmark_build_parser(bs, fmt) -> None:
    """Register ``oscar eval benchmark build`` and its options on ``bs``."""
    g = bs.add_parser(
        "build", help="choose the evaluation clips by the paper's rules", epilog=EXAMPLES, formatter_class=fmt
    )
    g.add_argument("clipsets", nargs="+", help="clip sets to draw from (clip ids unique across them)")
    output_option(g.add_argument("--out", required=True, help="the set file to write (JSON)"), "file")
    g.add_argument("--total", type=count(1), required=True, help="clips in the set (the paper: 200)")
    g.add_argument(
        "--frames",
        type=count(2),
        default=49,
        help="evaluation horizon in frames (default 49, the paper's; the toy world's clips have 17)",
    )
    g.add_argument(
        "--clusters",
        type=count(1),
        help="k-means clusters per (embodiment, source) group before the quota (default: the group's quota)",
    )
    g.add_argument("--seed", type=count(0), default=0, help="k-means and quota-draw seed (default 0)")
    g.add_argument(
        "--split", default="heldout", help="clips of this meta.split (default heldout; 'all' for every clip)"
    )
    g.add_argument(
        "--margin",
        type=number(0.0),
        default=0.0,
        help="pixels the end effector must keep from the image edges (default 0)",
    )
    g.add_argument(
        "--text",
        choices=("prompt", "hash"),
        default="prompt",
        help="caption embedding: the clip's prompt_embeds pooled, else hashed words of its caption/task "
        "(prompt, default), or always the hashed words (hash)",
    )
    g.add_argument("--json", action="store_true", help="print counts, quotas and fingerprint as JSON")
    g.set_defaults(func=cmd_build)


def _add_benchmark_run_parser(bs, fmt) -> None:
    """Register ``oscar eval benchmark run`` and its options on ``bs``."""
    r = bs.add_parser(
        "run", help="roll a model out on every clip of a set (resumable)", epilog=EXAMPLES, formatter_class=fmt
    )
    r.add_argument("set", help="set file written by `oscar eval benchmark build`")
    r.add_argument("--model", required=True, help="world model: zoo name (oscar-toy), Hub id or folder")
    output_option(
        r.add_argument("--out", required=True, help="folder for <clip id>.npy predictions (re-running resumes)"),
        "folder",
    )
    add_sampler_options(r)  # the flags of eval run and closed-loop, --shift among them (cli_options.py)
    r.add_argument("--seed", type=count(0), default=0, help="noise seed (default 0)")
    r.add_argument(
        "--prompt",
        choices=("clip", "empty"),
        default="clip",
        help="text condition: the clip's stored prompt_embeds, else the empty prompt (clip, default); "
        "or always the empty prompt",
    )
    r.add_argument("--device", type=device, help="torch device (default: cuda when available, else cpu)")
    r.add_argument(
        "--dtype",
        choices=("float32", "bfloat16", "float16"),
        help="DiT dtype (default: bfloat16 on CUDA, else float32)",
    )
    threads_option(r)
    r.set_defaults(func=cmd_run)


def _add_benchmark_table_parser(bs, fmt) -> None:
    """Register ``oscar eval benchmark table`` and its options on ``bs``."""
    t = bs.add_parser(
        "table", help="the paper's table over a set: one row per model", epilog=EXAMPLES, formatter_class=fmt
    )
    t.add_argument("--set", required=True, help="set file")
    t.add_argument(
        "--pred",
        action="append",
        required=True,
        metavar="NAME=DIR",
        help="a row: a folder written by `benchmark run` (repeatable)",
    )
    t.add_argument("--lpips", metavar="NET", help="LPIPS network (.pt or module:attr; default: the weights cache)")
    t.add_argument("--i3d", metavar="NET", help="FVD feature extractor (default: the weights cache)")
    t.add_argument("--inception", metavar="NET", help="FID feature extractor (default: the weights cache)")
    t.add_argument("--vae", metavar="NET", help="VAE encoder for latent L2 (.pt or module:attr)")
    t.add_argument(
        "--vae-model",
        default="none",
        metavar="MODEL",
        help="checkpoint whose VAE computes latent L2 when --vae is not given, from the local cache "
        "(e.g. oscar-toy, oscar-2b; default none)",
    )
    t.add_argument(
        "--no-cached-networks", action="store_true", help="do not use the networks of `oscar eval weights pull`"
    )
    t.add_argument("--device", type=device, default="cpu", help="torch device for the networks (default cpu)")
    output_option(
        t.add_argument("--out", metavar="FILE", help="write the table as JSON here and as Markdown beside it (.md)"),
        "file",
    )
    t.add_argument("--json", action="store_true", help="print JSON instead of Markdown")
    t.set_defaults(func=cmd_table)


def add_benchmark_parser(sub) -> argparse.ArgumentParser:
    """Add ``benchmark`` (``build``, ``run``, ``table``) to the ``oscar eval`` sub-parsers."""
    fmt = argparse.RawDescriptionHelpFormatter
    b = sub.add_parser(
        "benchmark",
        help="the paper's benchmark: build a set from clip sets, roll models out, table",
        description="The paper's evaluation protocol on your clips: choose a set (forward-window "
        "check, k-means near-duplicate removal, sqrt(N) quotas), roll any model out on "
        "every clip, report PSNR, SSIM, LPIPS, tLPIPS, FVD, FID, latent L2 and frames/s "
        "per embodiment and averaged.",
        epilog=EXAMPLES,
        formatter_class=fmt,
    )
    bs = b.add_subparsers(dest="benchmark_command", required=True)
    _add_benchmark_build_parser(bs, fmt)
    _add_benchmark_run_parser(bs, fmt)
    _add_benchmark_table_parser(bs, fmt)
    return b
