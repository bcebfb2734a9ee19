"""The report of a closed-loop run: ``OUT/report.json`` and ``OUT/summary.md``.

Per policy: cells, cells that ran to the end (``ok``) and that failed (with their reasons), the success rate
from the judge's verdicts on the videos (``success_rate``) and, in a simulator world, from the simulator's own
outcome (``sim_success_rate``), mean and worst policy latency, clipped actions and the worst IK residual.
Policies are ranked by success rate (the judge's, else the simulator's; failed cells count as failures, since
a policy that crashes does not succeed). ``views`` says what each observation field received; one row per cell.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._util.atomic import atomic_write_bytes
from ..metrics.common import nan_to_none

__all__ = ["VIEWS", "build_closed_loop_report", "write_closed_loop_report", "format_closed_loop_summary"]


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


def build_closed_loop_report(manifest, specs, records: list[dict], counts: dict, world: dict, judge) -> dict:
    """Everything ``report.json`` holds (module docstring)."""
    rows = []
    for spec in specs:
        mine = [r for r in records if r["policy"] == spec.name]
        ok = [r for r in mine if r["status"] == "ok"]
        verdicts = [(r.get("verdict") or {}).get("binary") for r in mine]
        judged = [v if r["status"] == "ok" else 0 for v, r in zip(verdicts, mine)]
        sim = [((r.get("outcome") or {}).get("success") if r["status"] == "ok" else 0) for r in mine]
        rows.append(
            {
                "policy": spec.name,
                "source": spec.source,
                "action_space": spec.action_space,
                "control_hz": spec.control_hz,
                "cells": len(mine),
                "ok": len(ok),
                "failed": len(mine) - len(ok),
                "success_rate": _mean(judged) if judge is not None and all(v is not None for v in judged) else None,
                "sim_success_rate": _mean(sim) if sim and all(v is not None for v in sim) else None,
                "mean_latency_s": _mean([(r.get("latency_s") or {}).get("mean") for r in mine]),
                "max_latency_s": max([(r.get("latency_s") or {}).get("max") or 0.0 for r in mine], default=None),
                "clipped_actions": int(sum(r.get("clipped_actions") or 0 for r in mine)),
                "ik_max_position_error_m": max([r.get("ik_max_position_error_m") or 0.0 for r in mine], default=None),
                "fault_reasons": sorted({r["reason"] for r in mine if r["reason"]}),
            }
        )
    by = (
        "success_rate"
        if all(r["success_rate"] is not None for r in rows)
        else ("sim_success_rate" if all(r["sim_success_rate"] is not None for r in rows) else None)
    )
    ranking = sorted(rows, key=lambda r: -(r[by] if by else 0.0)) if by else []
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
            "ranking": [r["policy"] for r in ranking],
            "policies": rows,
            "cells": cells,
        }
    )


def _fmt(v, spec: str) -> str:
    return "n/a" if v is None else format(v, spec)


def format_closed_loop_summary(report: dict) -> str:
    """``summary.md``: the per-policy table, what the views received, the failed cells."""
    c = report["counts"]
    lines = [
        "# Closed-loop policy evaluation",
        "",
        f"- manifest: `{report['manifest']}`",
        f"- world: `{json.dumps(report['world'])}`",
        f"- cells: {c['cells']} (run {c['done']}, reused {c['reused']}, failed {c['failed']})",
        f"- ranked by: {report['ranked_by'] or 'nothing (no success figures)'}",
        "",
        "| rank | policy | cells | failed | success rate | sim success rate | mean latency (s) | clipped | "
        "worst IK residual (m) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    order = report["ranking"] or [p["policy"] for p in report["policies"]]
    by_name = {p["policy"]: p for p in report["policies"]}
    for k, name in enumerate(order):
        p = by_name[name]
        lines.append(
            f"| {k + 1 if report['ranking'] else '-'} | {name} | {p['cells']} | {p['failed']} | "
            f"{_fmt(p['success_rate'], '.3f')} | {_fmt(p['sim_success_rate'], '.3f')} | "
            f"{_fmt(p['mean_latency_s'], '.4f')} | {p['clipped_actions']} | "
            f"{_fmt(p['ik_max_position_error_m'], '.2e')} |"
        )
    lines += ["", "## What the policy receives", ""]
    lines += [f"- `{k}`: {v}" for k, v in report["views"].items()]
    bad = [x for x in report["cells"] if x["status"] != "ok"]
    if bad:
        lines += ["", "## Failed cells", ""]
        lines += [f"- `{x['session']}/{x['policy']}`: {x['reason']}" for x in bad]
    return "\n".join(lines) + "\n"


def write_closed_loop_report(out: Path, report: dict) -> dict:
    """Write ``report.json`` and ``summary.md`` atomically; returns their paths."""
    out = Path(out)
    paths = {"report": str(out / "report.json"), "summary": str(out / "summary.md")}
    atomic_write_bytes(out / "report.json", (json.dumps(report, indent=1) + "\n").encode())
    atomic_write_bytes(out / "summary.md", format_closed_loop_summary(report).encode())
    return paths
