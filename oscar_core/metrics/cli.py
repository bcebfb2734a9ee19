"""The ``oscar eval`` sub-commands: ``video``, ``policies``, ``judge``, ``pairwise``, ``weights``; ``run`` is
registered here from :mod:`oscar_core.evaluation.cli`.

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

``--plot DIR`` writes ``DIR/success_scatter.png`` (world-model against real
success rate per policy, with the identity line) and ``DIR/rank_slope.png``
(the two rankings side by side); ``--plot-format png,pdf`` adds other formats.

``oscar eval judge --videos DIR_OR_GLOB --tasks tasks.json``
-------------------------------------------------------------
Asks a vision-language model behind an OpenAI-compatible endpoint whether
each rollout completed its task (:mod:`oscar_core.metrics.judge`). ``--videos``
is a folder (every video or PNG-frame folder under it, recursively, as for
``eval video``), a glob such as ``'rollouts/*/*.mp4'`` (quote it), or one
video. A clip is named by its path relative to the folder (for a glob: to the
pattern's leading folders without wildcards) without the extension, e.g.
``81a85b7c/pi0_fast``. The default layout is ``<session>/<policy>.<ext>``:
the clip's file name is its policy and its folder its session.

``tasks.json`` maps clip names, or folders of clips, to tasks::

    {"81a85b7c": "put the food on the plate",
     "7ac4ded2": {"instruction": "press a button on the phone"},
     "7ac4ded2/pg_bin": {"policy": "pg_bin_v2"},
     "policy_first/pi0/ep1": {"instruction": "fold the towel", "session": "ep1", "policy": "pi0"}}

A value is the instruction, or an object with any of ``instruction``,
``policy`` and ``session`` (other keys are an error). Every key that is the
clip's name or one of its folders applies to the clip, deeper keys overriding
shallower ones; every clip must end up with a non-empty instruction (checked
before any request). Keys that match no clip are ignored.

Results (``--out``): ``{"judge": settings, "summary": counts, "policies":
{policy: {"success_rate", "episodes", "mean_partial", "judged",
"not_judged"}}, "clips": [one verdict per clip]}``; ``--wm-out`` writes just
the per-policy success in the format ``eval policies --wm`` reads (policies
without a valid verdict are left out, with a warning). Malformed and failed
verdicts are reported per clip and never counted as successes or failures.
The exit code is 0 when every clip got a valid verdict, else 1 (the results
are written either way).

``oscar eval pairwise --videos DIR_OR_GLOB --tasks tasks.json``
----------------------------------------------------------------
Same inputs; every two clips of different policies in one session are
compared (pairs are formed within a session; clips without one are grouped by
instruction), the shown order randomised per pair by ``--seed``. Prints and
writes (``--out``) the verdicts and the Bradley–Terry–Davidson board fitted to
the valid ones; ``--preferences-out prefs.jsonl`` writes them in the format
``eval policies --preferences`` reads. The exit code is 1 when a pair has no
valid verdict or no Bradley–Terry fit is possible, else 0.

The endpoint comes from ``--base-url`` / ``--model`` or ``$OSCAR_JUDGE_BASE_URL``
/ ``$OSCAR_JUDGE_MODEL``; the API key only from the environment
(``$OSCAR_JUDGE_API_KEY``, or the variable named by ``--api-key-env``) so it
never appears in the process list or shell history. Answers are cached in
``--cache DIR`` (default ``$XDG_CACHE_HOME/oscar/judge``, i.e.
``~/.cache/oscar/judge``; ``--no-cache`` disables it), so a rerun sends only
the requests that got no answer before.
"""

from __future__ import annotations

import argparse
import glob
import importlib
import json
import os
import sys
from pathlib import Path

from ._common import MetricInputError, finite_float

__all__ = ["add_eval_parser", "cmd_eval_video", "cmd_eval_policies", "cmd_eval_judge", "cmd_eval_pairwise",
           "read_policy_results", "read_preferences", "collect_clips", "collect_judge_videos", "read_tasks"]

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
  oscar eval policies --real real.json --wm wm.json --plot figs/ --plot-format png,pdf
"""

JUDGE_EXAMPLES = """examples:
  export OSCAR_JUDGE_BASE_URL=http://127.0.0.1:8000/v1 OSCAR_JUDGE_MODEL=Qwen/Qwen2.5-VL-7B-Instruct
  oscar eval judge --videos rollouts/ --tasks tasks.json --out judge.json --wm-out wm.json
  oscar eval judge --videos 'rollouts/*/*.mp4' --tasks tasks.json --base-url https://api.openai.com/v1 \\
      --model gpt-5-2025-08-07 --api-key-env OPENAI_API_KEY --extra-body '{"reasoning_effort": "high"}' --concurrency 8
  oscar eval policies --real real.json --wm wm.json
  rollouts/81a85b7c/pi0_fast.mp4 is clip "81a85b7c/pi0_fast": session 81a85b7c, policy pi0_fast
  tasks.json: {"81a85b7c": "put the food on the plate", "7ac4ded2": "press a button on the phone"}
"""

PAIRWISE_EXAMPLES = """examples:
  oscar eval pairwise --videos rollouts/ --tasks tasks.json --out pairwise.json --preferences-out prefs.jsonl
  oscar eval pairwise --videos rollouts/ --tasks tasks.json --frames 8 --layout side_by_side --seed 1
  oscar eval policies --real real.json --wm wm.json --preferences prefs.jsonl
  (every two policies of a session are compared: 7 policies -> 21 pairs per session)
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


def _glob_base(pattern: str) -> Path:
    """The leading folders of a glob pattern that hold no wildcard."""
    parts = Path(pattern).parts
    base = []
    for part in parts[:-1]:
        if glob.has_magic(part):
            break
        base.append(part)
    return Path(*base) if base else Path(".")


def collect_judge_videos(spec) -> dict[str, Path]:
    """``--videos`` of ``eval judge`` / ``eval pairwise`` → ``{clip name: path}`` (rules in the module docstring)."""
    raw = str(spec)
    path = Path(raw)
    if path.is_dir() and not _is_frame_folder(path):
        found = _find_clips(path)
        where = f"video files ({', '.join(VIDEO_EXTS)}) or PNG-frame folders under it"
    elif path.exists():
        if path.is_file() and path.suffix.lower() not in VIDEO_EXTS:
            raise MetricInputError(raw, "--videos", f"a video file ({', '.join(VIDEO_EXTS)}), a folder or a glob",
                                   f"a {path.suffix or 'suffix-less'} file")
        return {path.stem if path.is_file() else path.name: path}
    elif glob.has_magic(raw):
        base = _glob_base(raw)
        found = {}
        for m in sorted(glob.glob(raw, recursive=True)):
            p = Path(m)
            if (p.is_file() and p.suffix.lower() in VIDEO_EXTS) or _is_frame_folder(p):
                rel = p.relative_to(base) if p.is_relative_to(base) else p
                found[(rel.with_suffix("") if p.is_file() else rel).as_posix()] = p
        where = f"matches that are video files ({', '.join(VIDEO_EXTS)}) or PNG-frame folders"
    else:
        raise MetricInputError(raw, "--videos", "an existing folder, video file or glob pattern",
                               "no such file or folder")
    if not found:
        raise MetricInputError(raw, "--videos", where, "none")
    return found


_TASK_KEYS = ("instruction", "policy", "session")


def read_tasks(path, videos) -> list:
    """``tasks.json`` + ``{clip name: video}`` → :class:`~oscar_core.metrics.judge.JudgeClip` s (module docstring).

    Every clip must get a non-empty instruction; all problems are reported
    before any request is sent.
    """
    from .judge import JudgeClip

    path = Path(path)
    data = _read_json(path)
    if not isinstance(data, dict) or not data:
        raise MetricInputError(path, "top level", 'an object {"clip name or folder": task}', type(data).__name__)
    entries = {}
    for key, value in data.items():
        plain = isinstance(value, str)
        if plain:
            value = {"instruction": value}
        if not isinstance(value, dict):
            raise MetricInputError(path, key, 'an instruction, or an object with "instruction", "policy", "session"',
                                   repr(value))
        extra = sorted(k for k in value if k not in _TASK_KEYS)
        if extra:
            raise MetricInputError(path, key, f"only the keys {list(_TASK_KEYS)}", f"extra keys {extra}")
        for k, v in value.items():
            if not isinstance(v, str) or not v.strip():
                what = "a non-empty task instruction" if k == "instruction" else f"a non-empty {k} name"
                raise MetricInputError(path, key if plain else f"{key}.{k}", what, repr(v))
        entries[key.strip("/")] = {k: v.strip() for k, v in value.items()}
    clips, missing = [], []
    for name, video in videos.items():
        parts = name.split("/")
        merged = {"policy": parts[-1], "session": "/".join(parts[:-1]) or None}
        for depth in range(1, len(parts) + 1):  # folders first, the clip itself last
            merged.update(entries.get("/".join(parts[:depth]), {}))
        if "instruction" not in merged:
            missing.append(name)
            continue
        clips.append(JudgeClip(name=name, video=video, instruction=merged["instruction"].strip(),
                               policy=merged["policy"], session=merged["session"]))
    if missing:
        raise MetricInputError(path, "instruction", "a task for every clip (keyed by the clip's name or a folder)",
                               f"none for {missing[:10]}{' ...' if len(missing) > 10 else ''}")
    return clips


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
    nets = {"lpips": _load_network(args.lpips, "--lpips"), "i3d": _load_network(args.i3d, "--i3d"),
            "inception": _load_network(args.inception, "--inception")}
    used_cache = []
    if not args.no_cached_networks:  # the standard networks from `oscar eval weights pull`, hash-checked
        from .weights import cached_networks

        for key, net in cached_networks(device=args.device).items():
            if nets[key] is None:
                nets[key] = net
                used_cache.append(key)
    vae, notes = _load_network(args.vae, "--vae"), {}
    if vae is None and args.vae_model != "none":  # the project's own VAE, from the local cache only
        from .project_vae import load_project_vae

        try:
            vae = load_project_vae(args.vae_model, device=args.device)
        except Exception as exc:  # noqa: BLE001 - not cached / not a checkpoint: latent L2 is skipped, and said so
            notes["latent_l2"] = (f"skipped: the VAE of {args.vae_model!r} is not available locally "
                                  f"({type(exc).__name__}: {str(exc)[:200]}); `oscar zoo pull {args.vae_model}` or "
                                  "--vae / --vae-model FOLDER")
    report = evaluate_videos(
        clips, n_frames=None if args.frames == 0 else args.frames,
        lpips_net=nets["lpips"], vae=vae,
        fvd_extractor=nets["i3d"] if len(clips) > 1 or args.i3d else None, fid_extractor=nets["inception"],
        device=args.device, progress=not args.json and sys.stderr.isatty(),
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
        raise MetricInputError("--plot-format", "formats", f"a comma-separated list of {', '.join(FORMATS)}",
                               repr(spec))
    return formats


# --------------------------------------------------------------------------- #
# VLM judges
# --------------------------------------------------------------------------- #
def _default_cache_dir() -> Path:
    root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "oscar" / "judge"


def _judge_kwargs(args) -> dict:
    if args.frames < 1:
        raise MetricInputError("--frames", "value", "a frame count >= 1", args.frames)
    extra = None
    if args.extra_body:
        try:
            extra = json.loads(args.extra_body)
        except json.JSONDecodeError as exc:
            raise MetricInputError("--extra-body", "value", "a JSON object", f"invalid JSON ({exc.msg})") from None
        if not isinstance(extra, dict):
            raise MetricInputError("--extra-body", "value", "a JSON object", type(extra).__name__)
    api_key = os.environ.get(args.api_key_env) or None
    return dict(base_url=args.base_url, model=args.model, api_key=api_key, n_frames=args.frames,
                max_side=args.max_side or None, image_format=args.image_format, jpeg_quality=args.jpeg_quality,
                temperature=args.temperature, max_tokens=args.max_tokens, extra_body=extra, timeout=args.timeout,
                max_attempts=args.max_attempts, backoff=args.backoff, concurrency=args.concurrency,
                token_field=args.token_field, max_timeout_retries=args.max_timeout_retries,
                max_requests=args.max_requests,
                cache_dir=None if args.no_cache else (args.cache or _default_cache_dir()))


def _status_summary(verdicts) -> dict:
    counts = {status: sum(v.status == status for v in verdicts) for status in ("ok", "malformed", "error")}
    requests = sum(v.attempts for v in verdicts)
    usage = {k: sum((v.usage or {}).get(k, 0) for v in verdicts if not v.cached)
             for k in ("prompt_tokens", "completion_tokens", "total_tokens")}
    return {"total": len(verdicts), **counts, "cached": sum(v.cached for v in verdicts), "requests": requests,
            "retries": sum(max(0, v.attempts - 1) for v in verdicts), "usage": usage}


def _summary_line(summary: dict, what: str) -> str:
    u = summary["usage"]
    return (f"{summary['total']} {what}: {summary['ok']} ok, {summary['malformed']} malformed, "
            f"{summary['error']} failed; {summary['requests']} requests ({summary['retries']} retries), "
            f"{summary['cached']} from the cache; tokens {u['prompt_tokens']} prompt + {u['completion_tokens']} "
            f"completion = {u['total_tokens']}")


def _print_problems(verdicts, name_of) -> None:
    for v in verdicts:
        if v.ok:
            continue
        line = f"{v.status:9s} {name_of(v)}: {v.error}"
        if v.raw:
            raw = " ".join(v.raw.split())
            line += f"  [raw: {raw[:160]}{'...' if len(raw) > 160 else ''}]"
        print(line)


def _prompt(spec: str) -> str:
    """``--prompt``: "paper", "oscar", or a text file holding a template with {instruction}."""
    if spec in ("paper", "oscar"):
        return spec
    path = Path(spec)
    if not path.is_file():
        raise MetricInputError(spec, "--prompt", "paper, oscar or a text file with a {instruction} template",
                               "no such file")
    return path.read_text()


def _print_plan(plan: list[dict], judge, as_json: bool) -> int:
    """``--dry-run``: the requests and images that would be sent; nothing is sent."""
    todo = [p for p in plan if not p["cached"]]
    if as_json:
        print(json.dumps({"judge": judge.describe(), "requests": todo,
                          "cached": [p["clip"] for p in plan if p["cached"]]}, indent=2))
        return 0
    for p in plan:
        if p["cached"]:
            print(f"{p['clip']}: cached, no request")
            continue
        w, h = p["image_size"]
        print(f"{p['clip']}: 1 request to {judge.model}: {p['images']} images {w}x{h} "
              f"({p['image_bytes'] / 1e6:.2f} MB base64) of {p['frames_total']} frames; sampling {p['sampling']}")
        for t in p["texts"]:
            print("    | " + t.replace("\n", "\n    | "))
    print(f"dry run: {len(todo)} requests would be sent ({len(plan) - len(todo)} cached), "
          f"{sum(p['images'] for p in todo)} images, {sum(p['image_bytes'] for p in todo) / 1e6:.2f} MB; "
          "nothing was sent")
    return 0


def cmd_eval_judge(args) -> int:
    from .judge import SuccessJudge, success_by_policy

    kwargs = _judge_kwargs(args)
    clips = read_tasks(args.tasks, collect_judge_videos(args.videos))
    judge = SuccessJudge(prompt=_prompt(args.prompt), **kwargs)
    if args.dry_run:
        return _print_plan(judge.plan(clips), judge, args.json)
    verdicts = judge.judge_many(clips, progress=not args.json and sys.stderr.isatty())
    policies = success_by_policy(verdicts)
    summary = _status_summary(verdicts)
    data = {"judge": judge.describe(), "summary": summary, "policies": policies,
            "clips": [v.to_dict() for v in verdicts]}
    if args.out:
        _write_json(args.out, data)
    if args.wm_out:
        wm = {p: {"success_rate": r["success_rate"], "episodes": r["episodes"], "mean_partial": r["mean_partial"]}
              for p, r in policies.items() if r["judged"]}
        skipped = sorted(p for p, r in policies.items() if not r["judged"])
        if skipped:
            print(f"warning: {args.wm_out}: left out policies without any valid verdict: {skipped}", file=sys.stderr)
        _write_json(args.wm_out, wm)
    if args.json:
        print(json.dumps(data, indent=2))
    else:
        rows = [("policy", "success", "mean partial", "judged", "not judged")] + [
            (p, "n/a" if r["success_rate"] is None else f"{r['success_rate']:.3f}",
             "n/a" if r["mean_partial"] is None else f"{r['mean_partial']:.1f}", str(r["judged"]),
             str(r["not_judged"])) for p, r in policies.items()]
        widths = [max(len(r[i]) for r in rows) for i in range(5)]
        for r in rows:
            print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
        print()
        _print_problems(verdicts, lambda v: v.clip)
        print(_summary_line(summary, "clips"))
        for path in (args.out, args.wm_out):
            if path:
                print(f"wrote {path}")
    return 0 if summary["ok"] == summary["total"] else 1


def cmd_eval_pairwise(args) -> int:
    import warnings

    from .judge import PairwiseJudge, pairs_by_session, preferences_from_verdicts
    from .policy import BradleyTerryWarning, fit_bradley_terry

    kwargs = _judge_kwargs(args)
    clips = read_tasks(args.tasks, collect_judge_videos(args.videos))
    pairs = pairs_by_session(clips)
    if not pairs:
        raise MetricInputError(args.tasks, "sessions", "at least one session with clips of two different policies",
                               f"{len(clips)} clips and no such session")
    judge = PairwiseJudge(seed=args.seed, layout=args.layout, both_orders=args.both_orders, **kwargs)
    if args.dry_run:
        per = 2 if args.both_orders else 1
        print(json.dumps({"judge": judge.describe(), "pairs": [p.id for p in pairs], "requests": per * len(pairs),
                          "images_per_request": f"up to 2 x {judge.n_frames}"}, indent=2) if args.json else
              f"dry run: {per * len(pairs)} requests would be sent for {len(pairs)} pairs (cached ones are not "
              f"re-sent), up to 2 x {judge.n_frames} images each; nothing was sent")
        return 0
    verdicts = judge.compare_many(pairs, progress=not args.json and sys.stderr.isatty())
    prefs = preferences_from_verdicts(verdicts)
    summary = _status_summary(verdicts)
    data = {"judge": judge.describe(), "summary": summary, "bradley_terry": None, "bradley_terry_error": None,
            "pairs": [v.to_dict() for v in verdicts]}
    bt = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", BradleyTerryWarning)
        try:
            bt = fit_bradley_terry(prefs, source="pairwise verdicts") if prefs else None
        except MetricInputError as exc:
            data["bradley_terry_error"] = str(exc)
    bt_warnings = [str(w.message) for w in caught if issubclass(w.category, BradleyTerryWarning)]
    if bt is not None:
        data["bradley_terry"] = {**bt.to_dict(), "warnings": bt_warnings}
    elif not prefs:
        data["bradley_terry_error"] = "no valid pairwise verdicts"
    if args.out:
        _write_json(args.out, data)
    if args.preferences_out:
        from .._atomic import atomic_write_bytes

        lines = [json.dumps({"a": v.a, "b": v.b, "winner": v.winner, "pair": v.pair}) for v in verdicts if v.ok]
        atomic_write_bytes(Path(args.preferences_out), "".join(line + "\n" for line in lines).encode())
    if args.json:
        print(json.dumps(data, indent=2))
    else:
        for w in bt_warnings:
            print(f"warning: {w}", file=sys.stderr)
        if bt is not None:
            print("world-model Bradley-Terry (Davidson ties) from the pairwise verdicts")
            print(bt.format_table())
        else:
            print(f"no Bradley-Terry fit: {data['bradley_terry_error']}")
        print()
        _print_problems(verdicts, lambda v: v.pair)
        print(_summary_line(summary, "pairs"))
        for path in (args.out, args.preferences_out):
            if path:
                print(f"wrote {path}")
    return 0 if summary["ok"] == summary["total"] and bt is not None else 1


def _add_judge_args(p, default_frames: int) -> None:
    from .judge import DEFAULT_MAX_SIDE, ENV_API_KEY, ENV_BASE_URL, ENV_MODEL

    p.add_argument("--videos", required=True, metavar="DIR_OR_GLOB",
                   help="folder of rollouts (searched recursively), a quoted glob, or one video")
    p.add_argument("--tasks", required=True, metavar="JSON", help="task instruction per clip or folder of clips")
    p.add_argument("--base-url", help=f"OpenAI-compatible endpoint, e.g. http://127.0.0.1:8000/v1 "
                                      f"(default ${ENV_BASE_URL})")
    p.add_argument("--model", help=f"model name (default ${ENV_MODEL})")
    p.add_argument("--api-key-env", default=ENV_API_KEY, metavar="VAR",
                   help=f"environment variable holding the API key (default {ENV_API_KEY}; unset = no key)")
    p.add_argument("--frames", type=int, default=default_frames,
                   help=f"frames sampled uniformly per rollout (default {default_frames}; "
                        "shorter clips send all their frames)")
    p.add_argument("--max-side", type=int, default=DEFAULT_MAX_SIDE,
                   help=f"downscale frames whose longer side exceeds this (default {DEFAULT_MAX_SIDE}; 0 = never)")
    p.add_argument("--image-format", choices=("jpeg", "png"), default="jpeg", help="image encoding (default jpeg)")
    p.add_argument("--jpeg-quality", type=int, default=90, help="JPEG quality 1-100 (default 90)")
    p.add_argument("--temperature", type=float, help="sampling temperature (default: not sent)")
    p.add_argument("--max-tokens", type=int, help="answer token limit, sent as max_completion_tokens "
                                                  "(default: not sent)")
    p.add_argument("--token-field", choices=("max_completion_tokens", "max_tokens"), default="max_completion_tokens",
                   help="request field for --max-tokens (max_tokens for older servers)")
    p.add_argument("--max-requests", type=int, help="request budget of this run: requests beyond it are not sent "
                                                    "(those items fail, uncached; a re-run continues)")
    p.add_argument("--max-timeout-retries", type=int, default=1,
                   help="retries of a timed-out request at most (default 1: a timed-out request may be billed)")
    p.add_argument("--dry-run", action="store_true", help="print the requests and images that would be sent; "
                                                          "send nothing")
    p.add_argument("--extra-body", metavar="JSON",
                   help='extra request fields, e.g. \'{"reasoning_effort": "high"}\'')
    p.add_argument("--concurrency", type=int, default=4, help="requests in flight at once (default 4)")
    p.add_argument("--timeout", type=float, default=120.0, help="seconds per request (default 120)")
    p.add_argument("--max-attempts", type=int, default=5,
                   help="requests per item at most, retrying 429/5xx/timeouts (default 5)")
    p.add_argument("--backoff", type=float, default=1.0, help="first retry delay in seconds, doubled each time")
    p.add_argument("--cache", metavar="DIR", help="answer cache folder (default ~/.cache/oscar/judge)")
    p.add_argument("--no-cache", action="store_true", help="neither read nor write the cache")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    p.add_argument("--out", metavar="FILE", help="write the JSON results here")


def add_eval_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``eval`` (``video``, ``policies``, ``judge``, ``pairwise``) to an argparse sub-parser collection."""
    from .judge import DEFAULT_JUDGE_FRAMES, DEFAULT_PAIRWISE_FRAMES  # standard library + numpy only

    ev = subparsers.add_parser("eval", help="evaluate world-model videos or policy rankings",
                               description="Evaluate world-model rollouts: video quality against ground truth, "
                                           "policy rankings against real-robot results, and VLM judges of "
                                           "rollouts (success per clip, pairwise preferences).",
                               epilog=VIDEO_EXAMPLES + "\n" + POLICY_EXAMPLES + "\n" + JUDGE_EXAMPLES + "\n"
                                      + PAIRWISE_EXAMPLES,
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
    v.add_argument("--vae-model", default="oscar-2b", metavar="MODEL",
                   help="checkpoint (zoo name, Hub id or folder) whose VAE computes latent L2 when --vae is not "
                        "given, if it is in the local cache (default oscar-2b; none = skip)")
    v.add_argument("--no-cached-networks", action="store_true",
                   help="do not use the networks fetched by `oscar eval weights pull` (used by default when cached)")
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
    p.add_argument("--plot", metavar="DIR", help="write success_scatter.png and rank_slope.png to DIR (created)")
    p.add_argument("--plot-format", default="png", metavar="FMTS",
                   help="comma-separated plot formats: png, pdf, svg (default png)")
    p.set_defaults(func=cmd_eval_policies)

    j = sub.add_parser("judge", help="VLM success verdict per rollout (OpenAI-compatible endpoint)",
                       description="Ask a vision-language model whether each rollout completed its task: "
                                   "binary success, partial progress 0-100 and a reason per clip.",
                       epilog=JUDGE_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_judge_args(j, DEFAULT_JUDGE_FRAMES)
    j.add_argument("--wm-out", metavar="FILE", help="write per-policy success rates for `eval policies --wm`")
    j.add_argument("--prompt", default="paper", help="paper (the paper's prompt, word for word; default), oscar "
                                                     "(a more detailed one), or a text file with an {instruction} "
                                                     "template")
    j.set_defaults(func=cmd_eval_judge)

    pw = sub.add_parser("pairwise", help="VLM pairwise preferences within sessions + Bradley-Terry",
                        description="Ask a vision-language model which of two policies' rollouts of the same "
                                    "session is better, for every pair, and fit Bradley-Terry-Davidson scores.",
                        epilog=PAIRWISE_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_judge_args(pw, DEFAULT_PAIRWISE_FRAMES)
    pw.add_argument("--seed", type=int, default=0, help="seed of the per-pair A/B order (default 0)")
    pw.add_argument("--both-orders", action="store_true",
                    help="ask every pair in both orders; disagreeing orders count as a tie (position bias)")
    pw.add_argument("--layout", choices=("sets", "side_by_side"), default="sets",
                    help="all frames of A then all of B (sets, default), or A|B side by side per time step")
    pw.add_argument("--preferences-out", metavar="JSONL",
                    help="write the valid verdicts as preferences for `eval policies --preferences`")
    pw.set_defaults(func=cmd_eval_pairwise)

    from ..evaluation.cli import add_run_parser

    add_run_parser(sub)

    w = sub.add_parser("weights", help="fetch the standard metric networks (I3D, Inception, LPIPS) into a cache",
                       description="Download the FVD / FID / LPIPS networks from their canonical URLs, check their "
                                   "sha256 (pinned, or recorded on first use), and keep them in the cache that "
                                   "`oscar eval video` uses by default.",
                       epilog=WEIGHTS_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    wsub = w.add_subparsers(dest="weights_command", required=True)
    wp = wsub.add_parser("pull", help="download and verify", epilog=WEIGHTS_EXAMPLES,
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    wp.add_argument("names", nargs="*", help="i3d, inception, lpips-alex, lpips-vgg, alexnet, vgg16 "
                                             "(default: i3d inception lpips-alex alexnet; 'all' for every file)")
    wp.add_argument("--cache", metavar="DIR", help="cache folder (default $OSCAR_WEIGHTS_CACHE or "
                                                   "~/.cache/oscar/weights)")
    wp.add_argument("--force", action="store_true", help="download again even if cached")
    wp.add_argument("--json", action="store_true", help="machine-readable output")
    wp.set_defaults(func=cmd_eval_weights_pull)
    wl = wsub.add_parser("list", help="the pinned files and what the cache holds")
    wl.add_argument("--cache", metavar="DIR", help="cache folder")
    wl.add_argument("--json", action="store_true", help="machine-readable output")
    wl.set_defaults(func=cmd_eval_weights_list)
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
    result = pull_weights(names, cache_dir=args.cache, force=args.force,
                          log=(lambda m: None) if args.json else (lambda m: print(m, file=sys.stderr)))
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
    rows = [{"name": w.name, "file": w.filename, "url": w.url, "pin": w.pin,
             "sha256": w.sha256 or (lock.get(w.name) or {}).get("sha256"), "sha256_prefix": w.sha256_prefix,
             "cached": (cache / w.filename).is_file(), "source": w.source} for w in WEIGHTS.values()]
    if args.json:
        print(json.dumps({"cache": str(cache), "weights": rows}, indent=2))
    else:
        for r in rows:
            print(f"{r['name']:11s} {'cached' if r['cached'] else '-':7s} {r['pin']:18s} {r['url']}")
        print(f"cache: {cache}")
    return 0
