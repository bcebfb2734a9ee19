"""``oscar eval judge`` and ``oscar eval pairwise``: VLM verdicts on rollouts from the command line.

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

import json
import os
import sys
from pathlib import Path

from .._util.arg_types import count, number
from .._util.log import progress_bars_enabled
from .._util.outputs import output_option
from .cli_inputs import _write_json, collect_judge_videos, read_tasks
from .common import MetricInputError

__all__ = ["cmd_eval_judge", "cmd_eval_pairwise", "JUDGE_EXAMPLES", "PAIRWISE_EXAMPLES"]

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
    return dict(
        base_url=args.base_url,
        model=args.model,
        api_key=api_key,
        n_frames=args.frames,
        max_side=args.max_side or None,
        image_format=args.image_format,
        jpeg_quality=args.jpeg_quality,
        temperature=args.temperature,
        max_tokens=args.max_tokens,
        extra_body=extra,
        timeout=args.timeout,
        max_attempts=args.max_attempts,
        backoff=args.backoff,
        concurrency=args.concurrency,
        token_field=args.token_field,
        max_timeout_retries=args.max_timeout_retries,
        max_requests=args.max_requests,
        cache_dir=None if args.no_cache else (args.cache or _default_cache_dir()),
    )


def _status_summary(verdicts) -> dict:
    counts = {status: sum(v.status == status for v in verdicts) for status in ("ok", "malformed", "error")}
    requests = sum(v.attempts for v in verdicts)
    usage = {
        k: sum((v.usage or {}).get(k, 0) for v in verdicts if not v.cached)
        for k in ("prompt_tokens", "completion_tokens", "total_tokens")
    }
    return {
        "total": len(verdicts),
        **counts,
        "cached": sum(v.cached for v in verdicts),
        "requests": requests,
        "retries": sum(max(0, v.attempts - 1) for v in verdicts),
        "usage": usage,
    }


def _summary_line(summary: dict, what: str) -> str:
    u = summary["usage"]
    return (
        f"{summary['total']} {what}: {summary['ok']} ok, {summary['malformed']} malformed, "
        f"{summary['error']} failed; {summary['requests']} requests ({summary['retries']} retries), "
        f"{summary['cached']} from the cache; tokens {u['prompt_tokens']} prompt + {u['completion_tokens']} "
        f"completion = {u['total_tokens']}"
    )


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
        raise MetricInputError(
            spec, "--prompt", "paper, oscar or a text file with a {instruction} template", "no such file"
        )
    return path.read_text()


def _print_plan(plan: list[dict], judge, as_json: bool) -> int:
    """``--dry-run``: the requests and images that would be sent; nothing is sent."""
    todo = [p for p in plan if not p["cached"]]
    if as_json:
        print(
            json.dumps(
                {"judge": judge.describe(), "requests": todo, "cached": [p["clip"] for p in plan if p["cached"]]},
                indent=2,
            )
        )
        return 0
    for p in plan:
        if p["cached"]:
            print(f"{p['clip']}: cached, no request")
            continue
        w, h = p["image_size"]
        print(
            f"{p['clip']}: 1 request to {judge.model}: {p['images']} images {w}x{h} "
            f"({p['image_bytes'] / 1e6:.2f} MB base64) of {p['frames_total']} frames; sampling {p['sampling']}"
        )
        for t in p["texts"]:
            print("    | " + t.replace("\n", "\n    | "))
    print(
        f"dry run: {len(todo)} requests would be sent ({len(plan) - len(todo)} cached), "
        f"{sum(p['images'] for p in todo)} images, {sum(p['image_bytes'] for p in todo) / 1e6:.2f} MB; "
        "nothing was sent"
    )
    return 0


def cmd_eval_judge(args) -> int:
    from .judge import SuccessJudge, success_by_policy

    kwargs = _judge_kwargs(args)
    clips = read_tasks(args.tasks, collect_judge_videos(args.videos))
    judge = SuccessJudge(prompt=_prompt(args.prompt), **kwargs)
    if args.dry_run:
        return _print_plan(judge.plan(clips), judge, args.json)
    verdicts = judge.judge_many(clips, progress=not args.json and progress_bars_enabled())
    policies = success_by_policy(verdicts)
    summary = _status_summary(verdicts)
    data = {
        "judge": judge.describe(),
        "summary": summary,
        "policies": policies,
        "clips": [v.to_dict() for v in verdicts],
    }
    if args.out:
        _write_json(args.out, data)
    if args.wm_out:
        wm = {
            p: {"success_rate": r["success_rate"], "episodes": r["episodes"], "mean_partial": r["mean_partial"]}
            for p, r in policies.items()
            if r["judged"]
        }
        skipped = sorted(p for p, r in policies.items() if not r["judged"])
        if skipped:
            print(f"warning: {args.wm_out}: left out policies without any valid verdict: {skipped}", file=sys.stderr)
        _write_json(args.wm_out, wm)
    if args.json:
        print(json.dumps(data, indent=2))
    else:
        rows = [("policy", "success", "mean partial", "judged", "not judged")] + [
            (
                p,
                "n/a" if r["success_rate"] is None else f"{r['success_rate']:.3f}",
                "n/a" if r["mean_partial"] is None else f"{r['mean_partial']:.1f}",
                str(r["judged"]),
                str(r["not_judged"]),
            )
            for p, r in policies.items()
        ]
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
        raise MetricInputError(
            args.tasks,
            "sessions",
            "at least one session with clips of two different policies",
            f"{len(clips)} clips and no such session",
        )
    judge = PairwiseJudge(seed=args.seed, layout=args.layout, both_orders=args.both_orders, **kwargs)
    if args.dry_run:
        per = 2 if args.both_orders else 1
        print(
            json.dumps(
                {
                    "judge": judge.describe(),
                    "pairs": [p.id for p in pairs],
                    "requests": per * len(pairs),
                    "images_per_request": f"up to 2 x {judge.n_frames}",
                },
                indent=2,
            )
            if args.json
            else f"dry run: {per * len(pairs)} requests would be sent for {len(pairs)} pairs (cached ones are not "
            f"re-sent), up to 2 x {judge.n_frames} images each; nothing was sent"
        )
        return 0
    verdicts = judge.compare_many(pairs, progress=not args.json and progress_bars_enabled())
    prefs = preferences_from_verdicts(verdicts)
    summary = _status_summary(verdicts)
    data = {
        "judge": judge.describe(),
        "summary": summary,
        "bradley_terry": None,
        "bradley_terry_error": None,
        "pairs": [v.to_dict() for v in verdicts],
    }
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
        from .._util.atomic import atomic_write_bytes

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

    p.add_argument(
        "--videos",
        required=True,
        metavar="DIR_OR_GLOB",
        help="folder of rollouts (searched recursively), a quoted glob, or one video",
    )
    p.add_argument("--tasks", required=True, metavar="JSON", help="task instruction per clip or folder of clips")
    p.add_argument(
        "--base-url", help=f"OpenAI-compatible endpoint, e.g. http://127.0.0.1:8000/v1 (default ${ENV_BASE_URL})"
    )
    p.add_argument("--model", help=f"model name (default ${ENV_MODEL})")
    p.add_argument(
        "--api-key-env",
        default=ENV_API_KEY,
        metavar="VAR",
        help=f"environment variable holding the API key (default {ENV_API_KEY}; unset = no key)",
    )
    p.add_argument(
        "--frames",
        type=count(1),
        default=default_frames,
        help=f"frames sampled uniformly per rollout (default {default_frames}; shorter clips send all their frames)",
    )
    p.add_argument(
        "--max-side",
        type=count(0),
        default=DEFAULT_MAX_SIDE,
        help=f"downscale frames whose longer side exceeds this (default {DEFAULT_MAX_SIDE}; 0 = never)",
    )
    p.add_argument("--image-format", choices=("jpeg", "png"), default="jpeg", help="image encoding (default jpeg)")
    p.add_argument("--jpeg-quality", type=count(1), default=90, help="JPEG quality 1-100 (default 90)")
    p.add_argument("--temperature", type=number(0.0), help="sampling temperature (default: not sent)")
    p.add_argument(
        "--max-tokens", type=count(1), help="answer token limit, sent as max_completion_tokens (default: not sent)"
    )
    p.add_argument(
        "--token-field",
        choices=("max_completion_tokens", "max_tokens"),
        default="max_completion_tokens",
        help="request field for --max-tokens (max_tokens for older servers)",
    )
    p.add_argument(
        "--max-requests",
        type=count(0),
        help="request budget of this run: requests beyond it are not sent "
        "(those items fail, uncached; a re-run continues)",
    )
    p.add_argument(
        "--max-timeout-retries",
        type=count(0),
        default=1,
        help="retries of a timed-out request at most (default 1: a timed-out request may be billed)",
    )
    p.add_argument(
        "--dry-run", action="store_true", help="print the requests and images that would be sent; send nothing"
    )
    p.add_argument("--extra-body", metavar="JSON", help='extra request fields, e.g. \'{"reasoning_effort": "high"}\'')
    p.add_argument("--concurrency", type=count(1), default=4, help="requests in flight at once (default 4)")
    p.add_argument("--timeout", type=number(above=0.0), default=120.0, help="seconds per request (default 120)")
    p.add_argument(
        "--max-attempts",
        type=count(1),
        default=5,
        help="requests per item at most, retrying 429/5xx/timeouts (default 5)",
    )
    p.add_argument("--backoff", type=number(0.0), default=1.0, help="first retry delay in seconds, doubled each time")
    output_option(
        p.add_argument("--cache", metavar="DIR", help="answer cache folder (default ~/.cache/oscar/judge)"), "folder"
    )
    p.add_argument("--no-cache", action="store_true", help="neither read nor write the cache")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    output_option(p.add_argument("--out", metavar="FILE", help="write the JSON results here"), "file")
