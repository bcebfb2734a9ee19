"""The report of a closed-loop run: ``OUT/report.json``, ``OUT/summary.md`` and ``OUT/report.html``.

Per policy: cells, cells that ran to the end (``ok``) and that failed (with their reasons), the success rate
from the judge's verdicts on the videos (``success_rate``) and, in a simulator world, from the simulator's own
outcome (``sim_success_rate``), mean and worst policy latency, clipped actions and the worst IK residual.
Policies are ranked by success rate (the judge's, else the simulator's; failed cells count as failures, since
a policy that crashes does not succeed): ``ranking`` lists them best first and ``ranks`` gives each its rank, equal
rates sharing one (1, 1, 3). ``views`` says what each observation field received; one row per cell.

``eval`` holds what ``oscar eval run``'s report holds for the same cells (:func:`eval_view` builds its inputs;
:func:`~.report.build_report` computes it): the world model's success rates from the judge's verdicts (a
failed cell is a failure, its reason the verdict's), pairwise preferences and their Bradley–Terry fit when a
pairwise judge ran, and — where every policy has a real outcome in the manifest's ``real_success`` — the
comparison with reality (MMRV, Spearman ρ, Pearson r, SISR_Δ; :func:`~oscar_core.metrics.policy.compare_policies`)
with 95 % session-bootstrap intervals (``intervals``,
:func:`~oscar_core.metrics.policy_seeds.session_intervals`). ``report.html`` is ``eval run``'s page
(:func:`~.html.write_html_report`) over those cells, with a closed-loop section: the world, what every view
received, the ranking with clipped actions and latency per policy and per cell, and the failed cells with their
reasons.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._util.atomic import atomic_write_bytes
from ..metrics.common import nan_to_none

__all__ = [
    "VIEWS",
    "build_closed_loop_report",
    "eval_view",
    "competition_ranks",
    "failed_verdict",
    "fidelity_intervals",
    "write_closed_loop_report",
    "format_closed_loop_summary",
]


#: What each observation field receives: the world generates one view (the session camera's).
VIEWS = {
    "image": "the latest generated frame of the session camera, resized to the policy's image_size",
    "wrist_image": "black (0) at the policy's image_size: the world model generates one view only",
    "joint_position": "the end of the joint path the policy commanded so far (J,), radians / metres",
    "gripper_position": "the commanded gripper closure (1,) in [0, 1], 1 = closed",
    "prompt": "the session's task",
}


def _mean(vals):
    vals = [v for v in vals if v is not None]
    return float(np.mean(vals)) if vals else None


def build_closed_loop_report(
    manifest,
    specs,
    records: list[dict],
    counts: dict,
    world: dict,
    judge,
    judge_failures: list | None = None,
    *,
    reused_failed: list | None = None,
) -> dict:
    """Everything ``report.json`` holds (module docstring); judge_failures: the finished cells the judge could not
    judge (:func:`~.closed_loop.judge_failures`), kept under ``judge_failures``; reused_failed: the failed cells
    reused from an earlier run (``--retry-failed`` redoes them), kept under ``reused_failed``."""
    from .closed_loop_cell import never_loaded

    simulator = world.get("kind") == "simulator"
    rows = []
    for spec in specs:
        mine = [r for r in records if r["policy"] == spec.name]
        ok = [r for r in mine if r["status"] == "ok"]
        verdicts = [(r.get("verdict") or {}).get("binary") for r in mine]
        judged = [v if r["status"] == "ok" else 0 for v, r in zip(verdicts, mine)]
        # only a simulator has outcomes of its own: a world model's failed cell is no simulator failure
        sim = (
            [((r.get("outcome") or {}).get("success") if r["status"] == "ok" else 0) for r in mine] if simulator else []
        )
        ik = [r["ik_max_position_error_m"] for r in mine if r.get("ik_max_position_error_m") is not None]
        latencies = [(r.get("latency_s") or {}).get("max") for r in mine]
        loaded = not mine or not all(never_loaded(r) for r in mine)
        rows.append(
            {
                "policy": spec.name,
                "source": spec.source,
                "action_space": spec.action_space,
                "control_hz": spec.control_hz,
                "cells": len(mine),
                "ok": len(ok),
                "failed": len(mine) - len(ok),
                "loaded": loaded,
                "success_rate": _mean(judged) if judge is not None and all(v is not None for v in judged) else None,
                "sim_success_rate": _mean(sim) if sim and all(v is not None for v in sim) else None,
                "mean_latency_s": _mean([(r.get("latency_s") or {}).get("mean") for r in mine]),
                "max_latency_s": max([v for v in latencies if v is not None], default=None),
                "clipped_actions": int(sum(r.get("clipped_actions") or 0 for r in mine)),
                "ik_max_position_error_m": max(ik, default=None),
                "fault_reasons": sorted({r["reason"] for r in mine if r["reason"]}),
            }
        )
    for r in rows:
        r["why_not"] = _why_not(r, judge, simulator)
    ranked = [r for r in rows if r["loaded"]]
    by = (
        "success_rate"
        if ranked and all(r["success_rate"] is not None for r in ranked)
        else ("sim_success_rate" if ranked and all(r["sim_success_rate"] is not None for r in ranked) else None)
    )
    ranking = sorted(ranked, key=lambda r: -r[by]) if by else []
    cells = [
        {
            "session": r["session"],
            "policy": r["policy"],
            "status": r["status"],
            "reason": r["reason"],
            "frames": r["frames"],
            "calls": r["calls"],
            "clipped_actions": r["clipped_actions"],
            "success": (r.get("verdict") or {}).get("binary"),
            "judge_reason": (r.get("verdict") or {}).get("reason"),
            "sim_success": (r.get("outcome") or {}).get("success"),
            "mean_latency_s": (r.get("latency_s") or {}).get("mean"),
            "video": r.get("video"),
            "dir": r["dir"],
        }
        for r in records
    ]
    return nan_to_none(
        {
            "format": "oscar-closed-loop-report",
            "manifest": str(manifest.path),
            "world": world,
            "judge": judge.describe() if judge is not None and hasattr(judge, "describe") else None,
            "views": VIEWS,
            "counts": counts,
            "ranked_by": by,
            "unranked_why": None if by else _unranked_why(rows, judge, judge_failures or []),
            "judge_failures": judge_failures or [],
            "never_loaded": [r["policy"] for r in rows if not r["loaded"]],
            "reused_failed": list(reused_failed or []),
            "ranking": [r["policy"] for r in ranking],
            "ranks": competition_ranks({r["policy"]: r[by] for r in ranking}) if by else {},
            "policies": rows,
            "cells": cells,
        }
    )


def _why_not(row: dict, judge, simulator: bool) -> dict:
    """Per figure of a policy's row that is undefined, why (a few words for the table)."""
    why = {}
    if not row["loaded"]:
        why["rank"] = "not ranked: the policy never loaded"
    if row["success_rate"] is None:
        why["success_rate"] = "no judge ran" if judge is None else "not judged (see the judge's failures)"
    if row["sim_success_rate"] is None:
        why["sim_success_rate"] = (
            "no simulator (a world model has no outcome of its own)" if not simulator else "no outcome"
        )
    if row["mean_latency_s"] is None:
        why["mean_latency_s"] = why["max_latency_s"] = "no policy call answered"
    if row["ik_max_position_error_m"] is None:
        why["ik_max_position_error_m"] = (
            f"no IK: {row['action_space']} actions are joint positions"
            if row["action_space"].startswith("joint")
            else "no IK solved (no call answered)"
        )
    return why


def _unranked_why(rows: list[dict], judge, failures: list) -> str:
    """Why no policy is ranked, as a sentence."""
    if not any(r["loaded"] for r in rows):
        return "no policy loaded"
    if failures:
        return f"the judge could not judge {len(failures)} of {sum(r['ok'] for r in rows)} finished cells"
    if judge is None:
        return "no judge ran (--judge) and the world has no outcome of its own"
    return "some policy has no success figure"


def competition_ranks(scores: dict) -> dict:
    """``{policy: rank}`` for ``{policy: score}``, higher first; equal scores share a rank and the next rank skips
    over them (1, 1, 3: two policies at 1.000 are both first, the one below them third)."""
    return {name: 1 + sum(other > v for other in scores.values()) for name, v in scores.items()}


def _fmt(v, spec: str) -> str:
    return "n/a" if v is None else format(v, spec)


def _figure(row: dict, key: str, spec: str) -> str:
    """A policy row's figure formatted, or — undefined — the words saying why (``why_not``)."""
    if row[key] is not None:
        return format(row[key], spec)
    return (row.get("why_not") or {}).get(key, "n/a")


def format_closed_loop_summary(report: dict) -> str:
    """``summary.md``: the per-policy table, what the views received, the failed cells."""
    c = report["counts"]
    lines = [
        "# Closed-loop policy evaluation",
        "",
        f"- manifest: `{report['manifest']}`",
        f"- world: `{json.dumps(report['world'])}`",
        f"- cells: {c['cells']} (run {c['done']}, reused {c['reused']}, failed {c['failed']})"
        + (
            f"; {len(report['reused_failed'])} failed cells reused from an earlier run as they are: "
            "--retry-failed redoes them"
            if report.get("reused_failed")
            else ""
        ),
        f"- ranked by: {report['ranked_by'] or 'nothing: ' + report['unranked_why']}",
        "",
    ]
    jf = report.get("judge_failures") or []
    if jf:
        lines += [
            f"**FAILED: the judge could not judge {len(jf)} of {c['cells'] - c['failed']} finished cells**; "
            "their success is unknown:",
            "",
            *[f"- `{f['cell']}`: {f['error']}" for f in jf],
            "",
        ]
    lines += [
        "| rank | policy | cells | failed | success rate | sim success rate | mean latency (s) | clipped | "
        "worst IK residual (m) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    by_name = {p["policy"]: p for p in report["policies"]}
    order = report["ranking"] + [p["policy"] for p in report["policies"] if p["policy"] not in report["ranking"]]
    for name in order:
        p = by_name[name]
        rank = report["ranks"].get(name, (p.get("why_not") or {}).get("rank", "-"))
        lines.append(
            f"| {rank} | {name} | {p['cells']} | {p['failed']} | "
            f"{_figure(p, 'success_rate', '.3f')} | {_figure(p, 'sim_success_rate', '.3f')} | "
            f"{_figure(p, 'mean_latency_s', '.4f')} | {p['clipped_actions']} | "
            f"{_figure(p, 'ik_max_position_error_m', '.2e')} |"
        )
    ev = report.get("eval") or {}
    comp = ev.get("comparison")
    if comp:
        iv = report.get("intervals") or {}
        lines += ["", "## World model against the real outcomes", ""]
        for key, label in (
            ("spearman_rho", "Spearman ρ"),
            ("pearson_r", "Pearson r"),
            ("mmrv", "MMRV"),
            ("sisr_delta_pp", "SISR_Δ (pp)"),
        ):
            lo_hi = iv.get(key)
            band = f" [{lo_hi[0]:.3f}, {lo_hi[1]:.3f}]" if lo_hi else ""
            lines.append(f"- {label}: {_fmt(comp['metrics'].get(key), '.3f')}{band}")
        if iv:
            lines.append(f"- intervals: 95 % session bootstrap, {iv['resamples']} resamples")
    elif ev.get("comparison_error"):
        lines += ["", f"No comparison with real outcomes: {ev['comparison_error']}."]
    bt = ev.get("bradley_terry")
    if bt and bt.get("board"):
        lines += ["", "## Pairwise preferences (Bradley–Terry)", ""]
        lines += [f"- {b['policy']}: Elo {_fmt(b.get('elo'), '.1f')}" for b in bt["board"]]
    lines += ["", "## What the policy receives", ""]
    lines += [f"- `{k}`: {v}" for k, v in report["views"].items()]
    bad = [x for x in report["cells"] if x["status"] != "ok"]
    if bad:
        lines += ["", "## Failed cells", ""]
        lines += [f"- `{x['session']}/{x['policy']}`: {x['reason']}" for x in bad]
    return "\n".join(lines) + "\n"


def failed_verdict(rec: dict, task: str):
    """The success verdict of a cell whose policy failed: a failure (a policy that crashes does not succeed),
    its reason the fault."""
    from ..metrics.judge_records import SuccessVerdict

    return SuccessVerdict(
        clip=f"{rec['session']}/{rec['policy']}",
        policy=rec["policy"],
        session=rec["session"],
        instruction=task,
        status="ok",
        binary=0,
        partial=0,
        reason=f"the policy failed: {rec['reason']}",
    )


def eval_view(manifest, specs, records: list[dict], verdicts: list) -> tuple:
    """The closed-loop cells as ``oscar eval run`` sees cells: ``(Manifest, records, verdicts)`` for
    :func:`~.report.build_report` and :func:`~.report.write_report_media`.

    One :class:`~.manifest.Cell` per record (its trajectory the integrated one, else the initial state; its
    ``real_success`` the session's for that policy); records with ``video``, ``frames``, ``fps``, ``seconds``
    (a failed cell's video path names the file it did not make); verdicts: the judge's, a failed cell's
    :func:`failed_verdict` (None where nothing was judged).
    """
    from .manifest import Cell, Manifest

    by_name = {s.session: s for s in manifest.sessions}
    cells, erecords, everdicts = [], [], []
    for k, rec in enumerate(records):
        s = by_name[rec["session"]]
        cells.append(
            Cell(
                session=s.session,
                policy=rec["policy"],
                task=s.task,
                embodiment=s.embodiment,
                first_frame=s.first_frame,
                trajectory=Path(rec["trajectory"]) if rec.get("trajectory") else s.initial_state,
                camera=s.camera,
                row=k,
                real_success=s.real_success.get(rec["policy"]),
                prompt_embeds=s.prompt_embeds,
                seed=s.seed,
                info=s.info,
            )
        )
        erecords.append(
            {
                "video": rec.get("video") or f"{rec['dir']}/video.mkv",
                "frames": rec["frames"],
                "fps": rec.get("fps"),
                "seconds": rec.get("seconds"),
                "cell": cells[-1].id,
            }
        )
        v = verdicts[k] if k < len(verdicts) else None
        everdicts.append(v if v is not None or rec["status"] == "ok" else None)
    emanifest = Manifest(manifest.path, tuple(p.name for p in specs), tuple(cells), manifest.size, None)
    return emanifest, erecords, everdicts


def fidelity_intervals(emanifest, verdicts: list, resamples: int = 2000, seed: int = 0) -> dict | None:
    """95 % session-bootstrap intervals of ρ, r, MMRV and SISR_Δ between the real outcomes and the world model's
    verdicts, per (session, policy) (:func:`~oscar_core.metrics.policy_seeds.session_intervals`); None unless every
    policy has a real outcome and a verdict."""
    from ..metrics.policy_seeds import session_intervals

    policies, sessions = list(emanifest.policies), emanifest.sessions
    real = np.full((len(sessions), len(policies)), np.nan)
    wm = np.full_like(real, np.nan)
    for cell, v in zip(emanifest.cells, verdicts):
        i, j = sessions.index(cell.session), policies.index(cell.policy)
        if cell.real_success is not None:
            real[i, j] = cell.real_success
        if v is not None and v.ok:
            wm[i, j] = v.binary
    if len(policies) < 2 or np.isnan(real).all(0).any() or np.isnan(wm).all(0).any():
        return None
    return session_intervals(real, wm, resamples, seed)


def write_closed_loop_report(
    out: Path,
    report: dict,
    eval_inputs: tuple | None = None,
    *,
    plot_formats=("png",),
    log=None,
    progress: bool = False,
) -> dict:
    """Write ``report.json`` and ``summary.md`` atomically, and — given ``eval_inputs`` ((Manifest, records)
    of :func:`eval_view`) — ``report.html`` with its media, contact sheets and plots; returns their paths."""
    out = Path(out)
    paths: dict = {}
    if eval_inputs is not None and report.get("eval") is not None:
        from .report import write_report_media

        emanifest, erecords = eval_inputs
        media, _ = write_report_media(
            out,
            report["eval"],
            emanifest,
            erecords,
            plot_formats=plot_formats,
            log=log,
            html_options={"generator": "eval closed-loop", "closed_loop": report, "progress": progress},
        )
        paths.update(media)
    paths.update(report=str(out / "report.json"), summary=str(out / "summary.md"))
    atomic_write_bytes(out / "report.json", (json.dumps({**report, "files": paths}, indent=1) + "\n").encode())
    atomic_write_bytes(out / "summary.md", format_closed_loop_summary(report).encode())
    return paths
