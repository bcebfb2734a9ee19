"""The ``oscar eval`` sub-commands: ``oscar eval video`` and ``oscar eval policies``.

Wire into the main parser with ``add_eval_parser(subparsers)``; each leaf
parser sets ``func`` (returns an exit code), like the other sub-commands.

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
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from pathlib import Path

from ._common import MetricInputError, finite_float

__all__ = ["add_eval_parser", "cmd_eval_video", "cmd_eval_policies", "read_policy_results", "read_preferences",
           "collect_clips"]

VIDEO_EXTS = (".mp4", ".mkv", ".avi", ".mov", ".webm", ".gif", ".npy")
FRAME_EXTS = (".png", ".jpg", ".jpeg")

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
"""


# --------------------------------------------------------------------------- #
# inputs
# --------------------------------------------------------------------------- #
def _is_frame_folder(p: Path) -> bool:
    return p.is_dir() and any(f.suffix.lower() in FRAME_EXTS for f in p.iterdir() if f.is_file())


def _find_clips(root: Path) -> dict[str, Path]:
    found = {}
    for path in sorted(root.rglob("*")):
        if path.is_file() and path.suffix.lower() in VIDEO_EXTS:
            if _is_frame_folder(path.parent) and path.parent != root:
                continue
            found[path.relative_to(root).with_suffix("").as_posix()] = path
        elif path.is_dir() and _is_frame_folder(path):
            found[path.relative_to(root).as_posix()] = path
    return found


def collect_clips(pred, gt, *, embodiment: str | None = None) -> list:
    """Clips for ``oscar eval video`` from two videos or two folders (rules in the module docstring)."""
    from .video import Clip

    pred, gt = Path(pred), Path(gt)
    for p in (pred, gt):
        if not p.exists():
            raise MetricInputError(p, "path", "an existing video file or folder", "no such file or folder")
    single = [not p.is_dir() or _is_frame_folder(p) for p in (pred, gt)]
    if single[0] != single[1]:
        kinds = {True: "one video", False: "a folder of clips"}
        raise MetricInputError(pred, "path", f"{kinds[single[1]]}, like GT {gt}", kinds[single[0]])
    if single[0]:
        return [Clip(pred.stem, pred, gt, embodiment)]
    pc, gc = _find_clips(pred), _find_clips(gt)
    if not pc:
        raise MetricInputError(pred, "clips", f"video files ({', '.join(VIDEO_EXTS)}) or PNG-frame folders",
                               "none")
    missing, extra = sorted(set(pc) - set(gc)), sorted(set(gc) - set(pc))
    if missing:
        raise MetricInputError(gt, "clips", f"a ground truth for every prediction in {pred}",
                               f"none for {missing[:10]}{' ...' if len(missing) > 10 else ''}")
    if extra:
        raise MetricInputError(pred, "clips", f"a prediction for every ground truth in {gt}",
                               f"none for {extra[:10]}{' ...' if len(extra) > 10 else ''}")
    clips = []
    for name in sorted(pc):
        tag = embodiment if embodiment is not None else (name.split("/")[0] if "/" in name else None)
        clips.append(Clip(name, pc[name], gc[name], tag))
    return clips


def _load_network(spec: str | None, what: str):
    """A TorchScript path is returned as is (loaded by the metric); ``module:attr`` is imported and called."""
    if spec is None:
        return None
    if spec.endswith((".pt", ".pth", ".ts")) or Path(spec).is_file():
        if not Path(spec).is_file():
            raise MetricInputError(spec, what, "an existing TorchScript file", "no such file")
        return spec
    if ":" not in spec:
        raise MetricInputError(spec, what, "a TorchScript file (.pt) or module:attr", repr(spec))
    mod_name, attr = spec.split(":", 1)
    try:
        obj = getattr(importlib.import_module(mod_name), attr)
    except (ImportError, AttributeError) as exc:
        raise MetricInputError(spec, what, "an importable module:attr", f"{type(exc).__name__}: {exc}") from exc
    if not callable(obj):
        raise MetricInputError(spec, what, "a callable that returns the network", type(obj).__name__)
    return obj()


def _read_json(path: Path):
    if not path.is_file():
        raise MetricInputError(path, "file", "an existing JSON file", "no such file")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise MetricInputError(path, f"line {exc.lineno}", "valid JSON", exc.msg) from exc


def read_policy_results(path) -> tuple[dict[str, float], dict[str, float] | None]:
    """``real.json`` / ``wm.json`` → (success rates, ranking scores or None if any policy lacks one)."""
    from .policy import success_rates

    path = Path(path)
    data = _read_json(path)
    if not isinstance(data, dict) or not data:
        raise MetricInputError(path, "top level", "an object {policy: result}", type(data).__name__)
    rates, scores = {}, {}
    for name, entry in data.items():
        if isinstance(entry, (int, float)) and not isinstance(entry, bool):
            rates[name] = finite_float(entry, str(path), name)
        elif isinstance(entry, dict):
            if "success_rate" in entry:
                rates[name] = finite_float(entry["success_rate"], str(path), f"{name}.success_rate")
            elif "episodes" in entry:
                rates[name] = success_rates({name: entry["episodes"]}, source=str(path))[name]
            else:
                raise MetricInputError(path, name, 'a "success_rate" or an "episodes" list', sorted(entry))
            if "score" in entry:
                scores[name] = finite_float(entry["score"], str(path), f"{name}.score")
        else:
            raise MetricInputError(path, name, "a success rate or an object", repr(entry))
        if not 0.0 <= rates[name] <= 1.0:
            raise MetricInputError(path, f"{name}.success_rate", "a fraction in [0, 1]", rates[name])
    return rates, (scores if len(scores) == len(rates) else None)


def read_preferences(path) -> list:
    """``prefs.jsonl`` → list of :class:`~oscar_core.metrics.policy.Preference`."""
    from .policy import parse_preference

    path = Path(path)
    if not path.is_file():
        raise MetricInputError(path, "file", "an existing JSON-lines file", "no such file")
    prefs = []
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as exc:
            raise MetricInputError(path, f"line {lineno}", "one JSON object", exc.msg) from exc
        prefs.append(parse_preference(record, f"{path}:{lineno}"))
    if not prefs:
        raise MetricInputError(path, "lines", "at least one preference", "none")
    return prefs


def _write_json(path, data) -> None:
    from .._atomic import atomic_write_bytes

    atomic_write_bytes(Path(path), (json.dumps(data, indent=2) + "\n").encode())


# --------------------------------------------------------------------------- #
# commands
# --------------------------------------------------------------------------- #
def cmd_eval_video(args) -> int:
    from .video import evaluate_videos

    if args.frames < 0:
        raise MetricInputError("--frames", "value", "a frame count >= 0 (0 = all frames)", args.frames)
    clips = collect_clips(args.pred, args.gt, embodiment=args.embodiment)
    report = evaluate_videos(
        clips, n_frames=None if args.frames == 0 else args.frames,
        lpips_net=_load_network(args.lpips, "--lpips"), vae=_load_network(args.vae, "--vae"),
        fvd_extractor=_load_network(args.i3d, "--i3d"), fid_extractor=_load_network(args.inception, "--inception"),
        device=args.device, progress=not args.json and sys.stderr.isatty(),
    )
    data = report.to_dict()
    if args.out:
        _write_json(args.out, data)
    if args.json:
        print(json.dumps(data, indent=2))
    else:
        print(report.format_table())
        if args.out:
            print(f"wrote {args.out}")
    return 0


def cmd_eval_policies(args) -> int:
    from .policy import compare_policies, fit_bradley_terry

    real_sr, real_score = read_policy_results(args.real)
    wm_sr, wm_score = read_policy_results(args.wm)
    compare_policies(real_sr, wm_sr)  # the two files must name the same policies before anything else
    bt, wm_label = None, "score"
    if args.preferences:
        bt = fit_bradley_terry(read_preferences(args.preferences), policies=list(real_sr),
                               source=str(args.preferences))
        wm_score, wm_label = bt.scores("elo"), "bradley_terry_elo"
    comparison = compare_policies(real_sr, wm_sr, real_score=real_score, wm_score=wm_score,
                                  wm_score_label=wm_label)
    data = comparison.to_dict()
    if bt is not None:
        data["bradley_terry"] = bt.to_dict()
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
    if args.out:
        print(f"wrote {args.out}")
    return 0


def add_eval_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``eval`` (with ``video`` and ``policies``) to an argparse sub-parser collection; returns it."""
    ev = subparsers.add_parser("eval", help="evaluate world-model videos or policy rankings",
                               description="Evaluate world-model rollouts: video quality against ground truth, "
                                           "or policy rankings against real-robot results.",
                               epilog=VIDEO_EXAMPLES + "\n" + POLICY_EXAMPLES,
                               formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ev.add_subparsers(dest="eval_command", required=True)

    v = sub.add_parser("video", help="PSNR, SSIM, LPIPS, tLPIPS, latent L2, FVD, FID",
                       description="Video quality of predictions against ground truth (first 49 frames).",
                       epilog=VIDEO_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    v.add_argument("pred", help="predicted video, or folder of predicted clips")
    v.add_argument("gt", help="ground-truth video, or folder of ground-truth clips")
    v.add_argument("--frames", type=int, default=49, help="compare the first N frames (default 49; 0 = all)")
    v.add_argument("--embodiment", help="tag every clip with this embodiment (default: the sub-folder name)")
    v.add_argument("--lpips", metavar="NET", help="LPIPS network: TorchScript .pt taking (x, y) in [-1, 1], "
                                                  "or module:attr (enables LPIPS and tLPIPS)")
    v.add_argument("--vae", metavar="NET", help="VAE encoder for latent L2: .pt or module:attr, "
                                                "input (1, 3, T, H, W) in [-1, 1]")
    v.add_argument("--i3d", metavar="NET", help="FVD feature extractor, e.g. i3d_torchscript.pt (StyleGAN-V)")
    v.add_argument("--inception", metavar="NET", help="FID feature extractor, e.g. inception-2015-12-05.pt")
    v.add_argument("--device", default="cpu", help="torch device for the networks (cpu, cuda)")
    v.add_argument("--json", action="store_true", help="print JSON instead of a table")
    v.add_argument("--out", metavar="FILE", help="also write the JSON results here")
    v.set_defaults(func=cmd_eval_video)

    p = sub.add_parser("policies", help="MMRV, Spearman rho, Pearson r, SISR_delta, Bradley-Terry",
                       description="Rank fidelity of world-model policy evaluation against real-robot results.",
                       epilog=POLICY_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--real", required=True, metavar="JSON", help="real-robot results per policy")
    p.add_argument("--wm", required=True, metavar="JSON", help="world-model results per policy")
    p.add_argument("--preferences", metavar="JSONL", help="world-model pairwise preferences (Bradley-Terry)")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    p.add_argument("--out", metavar="FILE", help="also write the JSON results here")
    p.set_defaults(func=cmd_eval_policies)
    return ev
