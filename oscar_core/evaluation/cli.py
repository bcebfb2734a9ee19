"""``oscar eval run MANIFEST``: the whole policy-evaluation loop in one command.

Registered under ``oscar eval`` by :func:`add_run_parser`; the loop itself is
:func:`oscar_core.evaluation.loop.run_evaluation`, the manifest format
:mod:`oscar_core.evaluation.manifest`, the report :mod:`oscar_core.evaluation.report`.

``--judge`` picks the success judge:

* ``vlm`` — :class:`~oscar_core.metrics.judge.SuccessJudge` (the paper's
  prompt) behind ``--judge-base-url`` / ``--judge-model`` (or
  ``$OSCAR_JUDGE_BASE_URL`` / ``$OSCAR_JUDGE_MODEL``), key from
  ``$OSCAR_JUDGE_API_KEY`` (or the variable ``--api-key-env`` names);
* ``module:attr`` or ``path/to/file.py:attr`` — a judge object (anything with
  ``judge_many``) or a function ``(video, clip) -> {"binary", "partial",
  "reason"}``, wrapped in :class:`~oscar_core.metrics.programmatic.ProgrammaticJudge`
  (its ``version`` attribute, default ``"1"``, is the judge's version: bump it
  when the function changes, or a re-run reuses the old verdicts);
* ``none`` — rollouts and contact sheets only.

``--pairwise`` also compares every two policies of a session (a VLM
:class:`~oscar_core.metrics.judge.PairwiseJudge`, or the programmatic judge's
``compare_many``) and ranks the world-model side by their Bradley–Terry Elo.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from .._util.arg_types import count, default_device, device_name, number
from .._util.log import log_result, progress_bars_enabled, run_log
from .._util.outputs import output_option
from .._util.threads import threads_option
from ..metrics.common import MetricInputError
from ..model.compile_policy import add_compile_options
from .cli_options import add_engine_options, add_sampler_options

__all__ = ["add_run_parser", "cmd_eval_run", "load_judge"]

RUN_EXAMPLES = """examples:
  oscar eval run manifest.json --model oscar-2b --out eval_out/ --judge vlm \\
      --judge-base-url http://127.0.0.1:8000/v1 --judge-model Qwen/Qwen2.5-VL-7B-Instruct --pairwise
  oscar eval run manifest.json --model ./my-finetune --out eval_out/ --judge my_judges.py:cube_in_bin --pairwise
  oscar eval run manifest.json --model oscar-2b --out eval_out/ --judge none --steps 20 --device cuda --dtype bfloat16
  oscar eval run manifest.json --model oscar-2b --out eval_out/ --device cuda --no-compile     (eager DiT)
  (re-running the same command resumes: finished rollouts and valid verdicts are reused)
"""


def _import_attr(spec: str):
    from .._util.user_code import import_attr

    try:
        return import_attr(spec, "judge")
    except ValueError:
        raise MetricInputError(spec, "--judge", "vlm, none, module:attr or path/to/file.py:attr", repr(spec)) from None
    except FileNotFoundError as exc:
        raise MetricInputError(str(exc), "--judge", "an existing Python file", "no such file") from None
    except (ImportError, AttributeError) as exc:
        raise MetricInputError(spec, "--judge", "an importable module:attr", f"{type(exc).__name__}: {exc}") from None


def load_judge(spec: str):
    """A judge object from ``module:attr`` / ``file.py:attr`` (rules in the module docstring)."""
    from ..metrics.programmatic import ProgrammaticJudge

    obj = _import_attr(spec)
    if hasattr(obj, "judge_many"):
        return obj
    if callable(obj):  # a function's ``version`` attribute (default "1") keys the verdicts stored for resume
        return ProgrammaticJudge(obj, name=spec.replace(os.sep, "/"), version=str(getattr(obj, "version", "1")))
    raise MetricInputError(
        spec, "--judge", "a judge object (with judge_many) or a function (video, clip) -> verdict", type(obj).__name__
    )


def _extra_body(text: str | None) -> dict | None:
    """``--judge-extra-body``: a JSON object of extra request fields, e.g. ``{"reasoning_effort": "high"}``."""
    if text is None:
        return None
    try:
        extra = json.loads(text)
    except json.JSONDecodeError as exc:
        raise MetricInputError("--judge-extra-body", "value", "a JSON object", f"invalid JSON ({exc.msg})") from None
    if not isinstance(extra, dict):
        raise MetricInputError("--judge-extra-body", "value", "a JSON object", type(extra).__name__)
    return extra


def _vlm_kwargs(args) -> dict:
    api_key = os.environ.get(args.api_key_env) or None
    return dict(
        base_url=args.judge_base_url,
        model=args.judge_model,
        api_key=api_key,
        max_tokens=args.judge_max_tokens,
        timeout=args.judge_timeout,
        extra_body=_extra_body(args.judge_extra_body),
        cache_dir=Path(args.out) / "judge_cache",
        max_requests=args.max_requests,
    )


def cmd_eval_run(args) -> int:
    import torch

    from .cli_options import resolve_sampler_flags
    from .loop import card_sampler_of, run_evaluation
    from .manifest import load_manifest

    if args.engine != "ray" and args.device is not None:  # local rollouts: the device must be this machine's
        from .._util.devices import device_problem

        problem = device_problem(args.device)
        if problem is not None:  # --engine ray's workers may run where this machine's devices do not matter
            raise MetricInputError(
                "--device", "device", "a device this machine has (with --engine local)", problem.split("found ", 1)[-1]
            )
    manifest = load_manifest(args.manifest)  # every row checked before anything else
    judge = pairwise = None
    if args.judge == "vlm":
        from ..metrics.judge import PairwiseJudge, SuccessJudge

        judge = SuccessJudge(**_vlm_kwargs(args))
        if args.pairwise:  # one client: --max-requests is the budget of the whole run
            pairwise = PairwiseJudge(
                both_orders=args.both_orders, client=judge.client, cache_dir=Path(args.out) / "judge_cache"
            )
    elif args.judge != "none":
        judge = load_judge(args.judge)
        if args.pairwise:
            if not hasattr(judge, "compare_many"):
                raise MetricInputError(args.judge, "--pairwise", "a judge with compare_many", type(judge).__name__)
            pairwise = judge
    elif args.pairwise:
        raise MetricInputError("--pairwise", "--judge", "a judge (vlm or module:attr)", "none")
    choice = resolve_sampler_flags(args, lambda: card_sampler_of(args.model, args.revision))
    sampler = choice.config
    print(f"sampler: {choice.describe('flag')}", file=sys.stderr)
    with run_log(args.out, "eval-run"):
        result = run_evaluation(
            manifest,
            args.out,
            model_spec=args.model,
            revision=args.revision,
            judge=judge,
            pairwise_judge=pairwise,
            sampler=sampler,
            chunk_frames=args.chunk_frames,
            device=args.device or default_device(),
            dtype=None if args.dtype == "auto" else getattr(torch, args.dtype),
            compile=args.compile,
            plugin_paths=getattr(args, "plugin", None) or (),
            progress=not args.no_progress and progress_bars_enabled(),
            plot_formats=[f.strip() for f in args.plot_format.split(",") if f.strip()],
            batch_cells=args.batch_cells,
            engine=args.engine,
            workers=args.workers,
        )
        log_result(f"wrote {result.paths['report']}; verdicts not ok: {result.report['counts']['verdicts_not_ok']}")
    report = result.report
    if args.json:
        print(json.dumps({**report, "files": result.paths}, indent=2))
    else:
        print(Path(result.paths["summary"]).read_text())
        print(f"wrote {result.paths['report']}, {result.paths['summary']}")
        print(f"open {result.paths['html']} in a browser: the rankings, and every rollout beside the real outcome")
    bad = report["counts"]["verdicts_not_ok"]
    return 0 if bad == 0 else 1


def add_run_parser(sub) -> argparse.ArgumentParser:
    """Add ``run`` to the ``oscar eval`` sub-parsers."""
    from ..metrics.judge import ENV_API_KEY

    r = sub.add_parser(
        "run",
        help="roll out every (session, policy) of a manifest, judge, compare with reality",
        description="The policy-evaluation loop: roll the world model out for every cell of the "
        "manifest (resumable), judge success and pairwise preferences, compare with the "
        "real outcomes (MMRV, Spearman rho, Pearson r, SISR_delta), write a report folder.",
        epilog=RUN_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    r.add_argument("manifest", help="manifest JSON (docs/evaluation.md)")
    r.add_argument("--model", required=True, help="world model: zoo name, Hub id owner/name, or folder")
    r.add_argument("--revision", help="Hub revision overriding the zoo's pinned one")
    output_option(
        r.add_argument("--out", required=True, help="report folder (created; re-running resumes in it)"), "folder"
    )
    r.add_argument("--judge", default="none", help="vlm, none, module:attr or file.py:attr (default none)")
    r.add_argument("--pairwise", action="store_true", help="pairwise preferences within sessions + Bradley-Terry")
    r.add_argument("--both-orders", action="store_true", help="VLM pairwise: ask A/B and B/A, reconcile")
    r.add_argument("--judge-base-url", help="VLM endpoint (default $OSCAR_JUDGE_BASE_URL)")
    r.add_argument("--judge-model", help="VLM model name (default $OSCAR_JUDGE_MODEL)")
    r.add_argument(
        "--api-key-env",
        default=ENV_API_KEY,
        metavar="VAR",
        help=f"variable holding the API key (default {ENV_API_KEY})",
    )
    r.add_argument("--judge-max-tokens", type=count(1), help="VLM max_completion_tokens (default: not sent)")
    r.add_argument(
        "--judge-timeout", type=number(above=0.0), default=120.0, help="VLM seconds per request (default 120)"
    )
    r.add_argument(
        "--judge-extra-body",
        metavar="JSON",
        help='extra request fields for the VLM, e.g. \'{"reasoning_effort": "high"}\' (the paper\'s GPT-5 '
        "judge ran at high reasoning effort)",
    )
    r.add_argument("--max-requests", type=count(0), help="VLM request budget for this run (default: unlimited)")
    add_sampler_options(r)
    r.add_argument("--chunk-frames", type=count(1), help="frames per chunk, 4k+1 (default: the model's)")
    add_engine_options(
        r,
        what="rollouts",
        batch_help="roll out up to N cells in one batch (same frame count and size; each video equals its "
        "one-at-a-time rollout up to float rounding; default 1)",
    )
    threads_option(r, "torch CPU threads of the local rollouts")
    r.add_argument(
        "--device",
        type=device_name,
        help="torch device of the rollouts (default: cuda when available, "
        "else cpu); checked against this machine unless --engine ray (the workers' machines)",
    )
    r.add_argument(
        "--dtype",
        choices=("auto", "float32", "bfloat16", "float16"),
        default="auto",
        help="DiT dtype (default auto: bfloat16 on CUDA, float32 on the CPU)",
    )
    add_compile_options(r)
    r.add_argument("--plot-format", default="png", help="comma-separated plot formats (png, pdf, svg)")
    r.add_argument("--no-progress", action="store_true", help="no progress bars")
    r.add_argument("--json", action="store_true", help="print the report JSON")
    r.set_defaults(func=cmd_eval_run)
    return r
