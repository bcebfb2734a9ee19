"""After a closed-loop run: judge every finished cell's video, compare cells pairwise, and write the report.

:func:`judge_and_report` is the last step of :func:`~oscar_core.evaluation.closed_loop.run_closed_loop`: the
judge's verdicts (stored in each cell's ``record.json`` and reused while the judge's description matches, as
``eval run`` does), the pairwise judge's comparisons, the judge's failures (a run with any exits 1), and the
reports of :mod:`.closed_loop_report` (``report.json``, ``summary.md``, ``report.html``).
"""

from __future__ import annotations

import json
from pathlib import Path

from .._util.atomic import atomic_write_bytes
from .._util.log import get_logger
from .closed_loop_manifest import ClosedLoopManifest, Session

__all__ = ["judge_and_report", "judge_failures", "write_json"]

# the run's last step: its messages keep the run's logger (``oscar.evaluation.closed_loop``), as before the split
_log = get_logger("oscar_core.evaluation.closed_loop")


def write_json(path: Path, data) -> None:
    """``data`` as indented JSON at ``path``, written atomically (its folder made if needed)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, (json.dumps(data, indent=1, default=str) + "\n").encode())


def _clip(out: Path, r: dict, session: Session):
    from ..metrics.judge import JudgeClip

    return JudgeClip(
        name=f"{r['session']}/{r['policy']}",
        video=out / r["video"],
        instruction=session.task,
        policy=r["policy"],
        session=r["session"],
        info=session.info,
    )


def _judge(out: Path, manifest: ClosedLoopManifest, records: list[dict], judge, progress: bool, log) -> list:
    """Judge every finished cell's video; a valid verdict is stored in its record and reused while the judge's
    description matches (as ``eval run`` does). Returns one :class:`~oscar_core.metrics.judge_records.SuccessVerdict`
    per record (a failed cell's: :func:`~.closed_loop_report.failed_verdict`)."""
    from ..metrics.judge_records import SuccessVerdict
    from .closed_loop_report import failed_verdict
    from .loop import _judge_id

    jid = _judge_id(judge)
    by_name = {s.session: s for s in manifest.sessions}
    verdicts: list = [None] * len(records)
    todo = []
    for k, r in enumerate(records):
        stored = r.get("verdict")
        if r["status"] != "ok":
            verdicts[k] = failed_verdict(r, by_name[r["session"]].task)
        elif isinstance(stored, dict) and stored.get("judge_id") == jid and isinstance(stored.get("verdict"), dict):
            v = dict(stored["verdict"])
            v["attempt_errors"] = tuple(v.get("attempt_errors") or ())
            verdicts[k] = SuccessVerdict(**v)
        else:
            todo.append(k)
    if todo:
        log(f"judging {len(todo)} closed-loop videos")
        clips = [_clip(out, records[k], by_name[records[k]["session"]]) for k in todo]
        for k, v in zip(todo, judge.judge_many(clips, progress=progress)):
            r = records[k]
            verdicts[k] = v
            if v.ok:
                r["verdict"] = {
                    "judge_id": jid,
                    "binary": v.binary,
                    "partial": v.partial,
                    "reason": v.reason,
                    "verdict": v.to_dict(),
                }
                write_json(out / r["dir"] / "record.json", r)
            else:
                r["verdict"] = {"judge_id": None, "binary": None, "status": v.status, "error": v.error}
    return verdicts


def _pairwise(
    out: Path, manifest: ClosedLoopManifest, records: list[dict], verdicts: list, judge, pairwise_judge, progress
):
    """The pairwise judge's verdicts on every two finished cells of a session (as ``eval run`` compares them)."""
    from ..metrics.judge import pairs_by_session

    by_name = {s.session: s for s in manifest.sessions}
    ok = [k for k, r in enumerate(records) if r["status"] == "ok"]
    pairs = pairs_by_session([_clip(out, records[k], by_name[records[k]["session"]]) for k in ok])
    if not pairs:
        return []
    kwargs = {}
    if getattr(pairwise_judge, "kind", None) == "programmatic" and judge is pairwise_judge:
        kwargs["verdicts"] = [verdicts[k] for k in ok if verdicts[k] is not None]
    return pairwise_judge.compare_many(pairs, progress=progress, **kwargs)


def judge_and_report(
    out: Path,
    manifest,
    specs,
    records,
    counts,
    world_id,
    judge,
    pairwise_judge,
    progress,
    plot_formats,
    log,
    reused_failed=(),
):
    """Judge, compare, and write the report (:mod:`.closed_loop_report`)."""
    from ..metrics.judge import success_by_policy
    from .closed_loop_report import build_closed_loop_report, eval_view, fidelity_intervals, write_closed_loop_report
    from .report import build_report

    verdicts = _judge(out, manifest, records, judge, progress, log) if judge is not None else [None] * len(records)
    pair_verdicts = (
        _pairwise(out, manifest, records, verdicts, judge, pairwise_judge, progress) if pairwise_judge else []
    )
    failures = judge_failures(records, verdicts) if judge is not None else []
    for f in failures:
        _log.error("the judge could not judge %s: %s", f["cell"], f["error"])
    report = build_closed_loop_report(
        manifest, specs, records, counts, world_id, judge, failures, reused_failed=list(reused_failed)
    )
    emanifest, erecords, everdicts = eval_view(manifest, specs, records, verdicts)
    ecounts = {
        "cells": counts["cells"],
        "rollouts_done": counts["done"],
        "rollouts_reused": counts["reused"],
        "verdicts_done": sum(v is not None for v in everdicts),
        "verdicts_reused": 0,
        "verdicts_not_ok": sum(1 for v in everdicts if v is not None and not v.ok),
    }
    judged = [v for v in everdicts if v is not None]
    report["eval"] = build_report(
        emanifest,
        erecords,
        everdicts,
        pair_verdicts,
        success_by_policy(judged) if judge is not None else {},
        counts=ecounts,
        model=world_id.get("model") or world_id.get("name"),
        judge=report["judge"],
        pairwise_judge=(
            pairwise_judge.describe() if pairwise_judge is not None and hasattr(pairwise_judge, "describe") else None
        ),
        sampler=world_id.get("sampler") or {},
    )
    report["intervals"] = fidelity_intervals(emanifest, everdicts) if report["eval"]["comparison"] else None
    paths = write_closed_loop_report(
        out, report, (emanifest, erecords), plot_formats=plot_formats, log=log, progress=progress
    )
    return report, paths


def judge_failures(records: list[dict], verdicts: list) -> list[dict]:
    """The finished cells the judge could not judge: ``[{"cell", "status", "error"}]`` (a verdict that is not
    ``ok``: the judge raised, or its answer could not be read). A run with any fails (exit 1): its success rates
    would silently leave those cells out."""
    out = []
    for r, v in zip(records, verdicts):
        if r["status"] == "ok" and (v is None or not v.ok):
            error = "no verdict" if v is None else (v.error or v.reason or v.status)
            out.append({"cell": f"{r['session']}/{r['policy']}", "status": getattr(v, "status", None), "error": error})
    return out
