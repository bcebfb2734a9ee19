"""The ``oscar eval`` sub-commands: ``video``, ``policies``, ``judge``, ``pairwise``, ``weights``.

Wire into the main parser with ``add_eval_parser(subparsers, extra_commands)``; each leaf
parser sets ``func`` (returns an exit code), like the other sub-commands. ``extra_commands``
are functions that add more sub-commands to ``oscar eval``: the top-level CLI passes
:func:`oscar_core.evaluation.cli.add_run_parser` (``oscar eval run``), so this module
never imports the layer above it. ``judge`` and ``pairwise`` live in
:mod:`oscar_core.metrics.cli_judge`, the file readers in :mod:`oscar_core.metrics.cli_inputs`.

``oscar eval video PRED GT``
----------------------------
PRED and GT are either two videos (one clip) or two folders (many clips).
A video is a file PyAV reads (``.mp4``, ``.mkv``, ...), a ``.npy`` array
(T, H, W, 3) uint8, or a folder of PNG frames. In a folder of clips, every
video (searched recursively) is one clip, named by its path relative to the
folder without the extension; predictions and ground truth are matched by
that name and every clip must be on both sides. A clip under a sub-folder
(``franka/ep001.mp4``) is tagged with the sub-folder's name as its embodiment
(``--embodiment`` sets one tag for all clips instead). Networks are given as a
TorchScript file (``.pt``) or as ``module:attr`` — ``attr`` is called with no
arguments and must return the network (a function of yours that builds, say,
``lpips.LPIPS(net="alex")`` from weights on disk).

``oscar eval policies --real real.json --wm wm.json [--preferences prefs.jsonl]``
--------------------------------------------------------------------------------
``real.json`` and ``wm.json`` map each policy to its result, either a success
rate or an object::

    {"pi0_fast": {"success_rate": 0.42, "score": 1633.0},
     "pg_bin":   {"episodes": [1, 0, 0, 1, 0]},
     "pg_flow":  0.31}

``success_rate`` is a fraction in [0, 1]; ``episodes`` lists binary per-episode
verdicts (the rate is their mean); ``score`` is an optional ranking score,
higher = better (e.g. the RoboArena Elo). Both files must name the same
policies. MMRV (rank form) and Spearman ρ rank each side by ``score`` when
every policy of that side has one, else by success rate; Pearson r, SISR_Δ and
SIMPLER's MMRV use success rates.

``prefs.jsonl`` holds one world-model pairwise preference per line::

    {"a": "pi0_fast", "b": "pg_bin", "winner": "a", "session": "81a85b7c"}

``winner`` is ``"a"``, ``"b"`` or ``"tie"`` (or RoboArena's 2 / 0 / 1); other
keys are ignored; blank lines are skipped. With preferences, the world-model
side is ranked by the Bradley–Terry–Davidson Elo fitted to them (like
RoboArena's leaderboard), and that board is printed too.

``--plot DIR`` writes ``DIR/success_scatter.png`` (world-model against real
success rate per policy, with the identity line) and ``DIR/rank_slope.png``
(the two rankings side by side); ``--plot-format png,pdf`` adds other formats.
"""

from __future__ import annotations

import argparse
import json
import sys

from .._util.arg_types import count, device
from .._util.log import progress_bars_enabled
from .._util.outputs import output_option
from .cli_inputs import (
    _write_json,
    collect_clips,
    collect_judge_videos,
    read_policy_results,
    read_preferences,
    read_tasks,
)
from .cli_judge import JUDGE_EXAMPLES, PAIRWISE_EXAMPLES, _add_judge_args, cmd_eval_judge, cmd_eval_pairwise
from .common import MetricInputError

__all__ = [
    "add_eval_parser",
    "cmd_eval_video",
    "cmd_eval_policies",
    "cmd_eval_judge",
    "cmd_eval_pairwise",
    "read_policy_results",
    "read_preferences",
    "collect_clips",
    "collect_judge_videos",
    "read_tasks",
]

#: ``oscar eval --help``: one example per sub-command (each sub-command's ``--help`` shows its own, more).
EVAL_EXAMPLES = """examples:
  oscar eval video preds/ gts/ --frames 49 --json --out video_metrics.json
  oscar eval policies --real real.json --wm wm.json --preferences prefs.jsonl
  oscar eval judge --videos rollouts/ --tasks tasks.json --out judge.json --wm-out wm.json
  oscar eval pairwise --videos rollouts/ --tasks tasks.json --out pairwise.json --preferences-out prefs.jsonl
  oscar eval run manifest.json --model oscar-2b --out eval_out/ --judge vlm --pairwise
  oscar eval closed-loop toy_cl/manifest.json --model oscar-toy --out cl_wm/ \\
      --judge oscar_core.toyworld.judge:ball_moved
  oscar eval roboarena DataDump_02-03-2026/ --out study/ --calibration cams/
  oscar eval action-following my_sets.json --model oscar-2b --judge my_judges.py:cube_in_bin --out af_2b
  oscar eval benchmark build clips/droid clips/rh20t --out bench.json --total 200
  oscar eval weights pull

Each sub-command's --help shows its own examples (oscar eval closed-loop --help, ...).
"""

VIDEO_EXAMPLES = """examples:
  oscar eval video pred.mp4 gt.mp4
  oscar eval video preds/ gts/ --frames 49 --json --out video_metrics.json
  oscar eval video preds/ gts/ --lpips lpips_alex.pt --vae my_pkg.vae:encoder --i3d i3d_torchscript.pt \\
      --inception inception-2015-12-05.pt
  (preds/franka/ep001.mp4 is matched with gts/franka/ep001.mp4 and tagged embodiment "franka")
"""

POLICY_EXAMPLES = """examples:
  oscar eval policies --real real.json --wm wm.json
  oscar eval policies --real real.json --wm wm.json --preferences prefs.jsonl --json
  real.json / wm.json: {"pi0_fast": {"success_rate": 0.42, "score": 1633}, "pg_bin": {"episodes": [1, 0, 1]}}
  prefs.jsonl:         {"a": "pi0_fast", "b": "pg_bin", "winner": "a"}      (one per line; "tie" allowed)
  oscar eval policies --real real.json --wm wm.json --plot figs/ --plot-format png,pdf
"""


# --------------------------------------------------------------------------- #
# commands
# --------------------------------------------------------------------------- #
def cmd_eval_video(args) -> int:
    from .video import evaluate_videos

    if args.frames < 0:
        raise MetricInputError("--frames", "value", "a frame count >= 0 (0 = all frames)", args.frames)
    clips = collect_clips(args.pred, args.gt, embodiment=args.embodiment)
    from .networks import resolve_networks

    nets, used_cache, notes = resolve_networks(
        lpips=args.lpips,
        i3d=args.i3d,
        inception=args.inception,
        vae=args.vae,
        vae_model=args.vae_model,
        use_cache=not args.no_cached_networks,
        device=args.device,
    )
    notes = {k: v for k, v in notes.items() if k == "latent_l2"}  # this command's notes: as before
    vae = nets["vae"]
    report = evaluate_videos(
        clips,
        n_frames=None if args.frames == 0 else args.frames,
        lpips_net=nets["lpips"],
        vae=vae,
        fvd_extractor=nets["i3d"] if len(clips) > 1 or args.i3d else None,
        fid_extractor=nets["inception"],
        device=args.device,
        progress=not args.json and progress_bars_enabled(),
    )
    data = report.to_dict()
    data["networks_from_cache"] = used_cache
    data["notes"] = notes
    if args.out:
        _write_json(args.out, data)
    if args.json:
        print(json.dumps(data, indent=2))
    else:
        print(report.format_table())
        for what, note in notes.items():
            print(f"note: {what}: {note}")
        if used_cache:
            print(f"networks from the weights cache: {', '.join(used_cache)}")
        if args.out:
            print(f"wrote {args.out}")
    return 0


def cmd_eval_policies(args) -> int:
    from .bradley_terry import world_model_ranking
    from .policy import compare_policies, fit_bradley_terry

    real_sr, real_score = read_policy_results(args.real)
    wm_sr, wm_score = read_policy_results(args.wm)
    compare_policies(real_sr, wm_sr)  # the two files must name the same policies before anything else
    bt, wm_label, fallback = None, "score", None
    if args.preferences:
        bt = fit_bradley_terry(read_preferences(args.preferences), policies=list(real_sr), source=str(args.preferences))
        wm_score, wm_label, fallback = world_model_ranking(bt)
    comparison = compare_policies(real_sr, wm_sr, real_score=real_score, wm_score=wm_score, wm_score_label=wm_label)
    data = comparison.to_dict()
    if bt is not None:
        data["bradley_terry"] = bt.to_dict()
        data["wm_ranking_fallback"] = fallback
    if args.plot:
        from .plots import plot_comparison

        written = plot_comparison(comparison, args.plot, formats=_plot_formats(args.plot_format))
        data["plots"] = {k: [str(p) for p in v] for k, v in written.items()}
    if args.out:
        _write_json(args.out, data)
    if args.json:
        print(json.dumps(data, indent=2))
        return 0
    if bt is not None:
        print("world-model Bradley-Terry (Davidson ties) from", args.preferences)
        print(bt.format_table())
        print()
    print(comparison.format_table())
    if fallback:
        print(fallback)
    for paths in data.get("plots", {}).values():
        print("wrote " + ", ".join(paths))
    if args.out:
        print(f"wrote {args.out}")
    return 0


def _plot_formats(spec: str) -> list[str]:
    from .plots import FORMATS

    formats = [f.strip().lower().lstrip(".") for f in spec.split(",") if f.strip()]
    bad = [f for f in formats if f not in FORMATS]
    if not formats or bad:
        raise MetricInputError(
            "--plot-format", "formats", f"a comma-separated list of {', '.join(FORMATS)}", repr(spec)
        )
    return formats


def _add_eval_video_parser(sub) -> None:
    """Register ``oscar eval video`` and its options on ``sub``."""
    v = sub.add_parser(
        "video",
        help="PSNR, SSIM, LPIPS, tLPIPS, latent L2, FVD, FID",
        description="Video quality of predictions against ground truth (first 49 frames).",
        epilog=VIDEO_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    v.add_argument("pred", help="predicted video, or folder of predicted clips")
    v.add_argument("gt", help="ground-truth video, or folder of ground-truth clips")
    v.add_argument("--frames", type=count(0), default=49, help="compare the first N frames (default 49; 0 = all)")
    v.add_argument("--embodiment", help="tag every clip with this embodiment (default: the sub-folder name)")
    v.add_argument(
        "--lpips",
        metavar="NET",
        help="LPIPS network: TorchScript .pt taking (x, y) in [-1, 1], or module:attr (enables LPIPS and tLPIPS)",
    )
    v.add_argument(
        "--vae", metavar="NET", help="VAE encoder for latent L2: .pt or module:attr, input (1, 3, T, H, W) in [-1, 1]"
    )
    v.add_argument("--i3d", metavar="NET", help="FVD feature extractor, e.g. i3d_torchscript.pt (StyleGAN-V)")
    v.add_argument("--inception", metavar="NET", help="FID feature extractor, e.g. inception-2015-12-05.pt")
    v.add_argument(
        "--vae-model",
        default="oscar-2b",
        metavar="MODEL",
        help="checkpoint (zoo name, Hub id or folder) whose VAE computes latent L2 when --vae is not "
        "given, if it is in the local cache (default oscar-2b; none = skip)",
    )
    v.add_argument(
        "--no-cached-networks",
        action="store_true",
        help="do not use the networks fetched by `oscar eval weights pull` (used by default when cached)",
    )
    v.add_argument("--device", type=device, default="cpu", help="torch device for the networks (cpu, cuda)")
    v.add_argument("--json", action="store_true", help="print JSON instead of a table")
    output_option(v.add_argument("--out", metavar="FILE", help="also write the JSON results here"), "file")
    v.set_defaults(func=cmd_eval_video)


def _add_eval_policies_parser(sub) -> None:
    """Register ``oscar eval policies`` and its options on ``sub``."""
    p = sub.add_parser(
        "policies",
        help="MMRV, Spearman rho, Pearson r, SISR_delta, Bradley-Terry",
        description="Rank fidelity of world-model policy evaluation against real-robot results.",
        epilog=POLICY_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--real", required=True, metavar="JSON", help="real-robot results per policy")
    p.add_argument("--wm", required=True, metavar="JSON", help="world-model results per policy")
    p.add_argument("--preferences", metavar="JSONL", help="world-model pairwise preferences (Bradley-Terry)")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    output_option(p.add_argument("--out", metavar="FILE", help="also write the JSON results here"), "file")
    output_option(
        p.add_argument("--plot", metavar="DIR", help="write success_scatter.png and rank_slope.png to DIR (created)"),
        "folder",
    )
    p.add_argument(
        "--plot-format", default="png", metavar="FMTS", help="comma-separated plot formats: png, pdf, svg (default png)"
    )
    p.set_defaults(func=cmd_eval_policies)


def _add_eval_judge_parser(sub) -> None:
    """Register ``oscar eval judge`` and its options on ``sub``."""
    from .judge import DEFAULT_JUDGE_FRAMES  # standard library + numpy only

    j = sub.add_parser(
        "judge",
        help="VLM success verdict per rollout (OpenAI-compatible endpoint)",
        description="Ask a vision-language model whether each rollout completed its task: "
        "binary success, partial progress 0-100 and a reason per clip.",
        epilog=JUDGE_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_judge_args(j, DEFAULT_JUDGE_FRAMES)
    output_option(
        j.add_argument("--wm-out", metavar="FILE", help="write per-policy success rates for `eval policies --wm`"),
        "file",
    )
    j.add_argument(
        "--prompt",
        default="paper",
        help="paper (the paper's prompt, word for word; default), oscar "
        "(a more detailed one), or a text file with an {instruction} "
        "template",
    )
    j.set_defaults(func=cmd_eval_judge)


def _add_eval_pairwise_parser(sub) -> None:
    """Register ``oscar eval pairwise`` and its options on ``sub``."""
    from .judge import DEFAULT_PAIRWISE_FRAMES  # standard library + numpy only

    pw = sub.add_parser(
        "pairwise",
        help="VLM pairwise preferences within sessions + Bradley-Terry",
        description="Ask a vision-language model which of two policies' rollouts of the same "
        "session is better, for every pair, and fit Bradley-Terry-Davidson scores.",
        epilog=PAIRWISE_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_judge_args(pw, DEFAULT_PAIRWISE_FRAMES)
    pw.add_argument("--seed", type=count(0), default=0, help="seed of the per-pair A/B order (default 0)")
    pw.add_argument(
        "--both-orders",
        action="store_true",
        help="ask every pair in both orders; disagreeing orders count as a tie (position bias)",
    )
    pw.add_argument(
        "--layout",
        choices=("sets", "side_by_side"),
        default="sets",
        help="all frames of A then all of B (sets, default), or A|B side by side per time step",
    )
    output_option(
        pw.add_argument(
            "--preferences-out",
            metavar="JSONL",
            help="write the valid verdicts as preferences for `eval policies --preferences`",
        ),
        "file",
    )
    pw.set_defaults(func=cmd_eval_pairwise)


def _add_eval_weights_parser(sub) -> None:
    """Register ``oscar eval weights`` and its options on ``sub``."""
    w = sub.add_parser(
        "weights",
        help="fetch the standard metric networks (I3D, Inception, LPIPS) into a cache",
        description="Download the FVD / FID / LPIPS networks from their canonical URLs, check their "
        "sha256 (pinned, or recorded on first use), and keep them in the cache that "
        "`oscar eval video` uses by default.",
        epilog=WEIGHTS_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    wsub = w.add_subparsers(dest="weights_command", required=True)
    wp = wsub.add_parser(
        "pull",
        help="download and verify",
        epilog=WEIGHTS_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    wp.add_argument(
        "names",
        nargs="*",
        help="i3d, inception, lpips-alex, lpips-vgg, alexnet, vgg16 "
        "(default: i3d inception lpips-alex alexnet; 'all' for every file)",
    )
    output_option(
        wp.add_argument(
            "--cache", metavar="DIR", help="cache folder (default $OSCAR_WEIGHTS_CACHE or ~/.cache/oscar/weights)"
        ),
        "folder",
    )
    wp.add_argument("--force", action="store_true", help="download again even if cached")
    wp.add_argument("--json", action="store_true", help="machine-readable output")
    wp.set_defaults(func=cmd_eval_weights_pull)
    wl = wsub.add_parser("list", help="the pinned files and what the cache holds")
    wl.add_argument("--cache", metavar="DIR", help="cache folder")
    wl.add_argument("--json", action="store_true", help="machine-readable output")
    wl.set_defaults(func=cmd_eval_weights_list)


def add_eval_parser(subparsers, extra_commands=()) -> argparse.ArgumentParser:
    """Add ``eval`` (``video``, ``policies``, ``judge``, ``pairwise``, ``weights``) to a sub-parser collection.

    ``extra_commands``: functions called with ``eval``'s own sub-parser collection to add more sub-commands
    (the top-level CLI adds ``run`` from :mod:`oscar_core.evaluation.cli`).
    """
    ev = subparsers.add_parser(
        "eval",
        help="evaluate world-model videos or policy rankings",
        description="Evaluate world-model rollouts: video quality against ground truth, "
        "policy rankings against real-robot results, and VLM judges of "
        "rollouts (success per clip, pairwise preferences).",
        epilog=EVAL_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = ev.add_subparsers(dest="eval_command", required=True)
    _add_eval_video_parser(sub)
    _add_eval_policies_parser(sub)
    _add_eval_judge_parser(sub)
    _add_eval_pairwise_parser(sub)
    for add_command in extra_commands:
        add_command(sub)
    _add_eval_weights_parser(sub)
    return ev


WEIGHTS_EXAMPLES = """examples:
  oscar eval weights pull                  (I3D for FVD, Inception for FID, LPIPS-Alex: about 130 MB)
  oscar eval weights pull all --cache /data/oscar-weights
  oscar eval weights list --json
  oscar eval video preds/ gts/             (uses the cached networks)
"""


def cmd_eval_weights_pull(args) -> int:
    from .weights import GROUPS, pull_weights

    names = list(args.names) or list(GROUPS["default"])
    if names == ["all"]:
        names = list(GROUPS["all"])
    result = pull_weights(
        names,
        cache_dir=args.cache,
        force=args.force,
        log=(lambda m: None) if args.json else (lambda m: print(m, file=sys.stderr)),
    )
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        for name, r in result.items():
            print(f"{name:11s} {r['status']:10s} sha256 {r['sha256'][:16]}...  ({r['check']})  {r['path']}")
    return 0


def cmd_eval_weights_list(args) -> int:
    from .weights import WEIGHTS, _read_lock, weights_cache_dir

    cache = weights_cache_dir(args.cache)
    lock = _read_lock(cache) if cache.is_dir() else {}
    rows = [
        {
            "name": w.name,
            "file": w.filename,
            "url": w.url,
            "pin": w.pin,
            "sha256": w.sha256 or (lock.get(w.name) or {}).get("sha256"),
            "sha256_prefix": w.sha256_prefix,
            "cached": (cache / w.filename).is_file(),
            "source": w.source,
        }
        for w in WEIGHTS.values()
    ]
    if args.json:
        print(json.dumps({"cache": str(cache), "weights": rows}, indent=2))
    else:
        for r in rows:
            print(f"{r['name']:11s} {'cached' if r['cached'] else '-':7s} {r['pin']:18s} {r['url']}")
        print(f"cache: {cache}")
    return 0
