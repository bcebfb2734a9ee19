"""The toy-world closed-loop study of docs/closed-loop.md: its open-loop manifest, its table and its figure.

    python docs/closed_loop_study.py openloop --sessions toy_cl/manifest.json --sim cl_sim --out openloop.json \\
        [--only toyarm-0000,franka-0000]
    python docs/closed_loop_study.py table --sessions toy_cl/manifest.json --sim cl_sim \\
        --wm cl_wm_s0 [--wm cl_wm_s0b ...] [--wm-seed1 cl_wm_s1 ...] [--openloop ol_wm ...] [--json table.json]
    python docs/closed_loop_study.py figure --sessions toy_cl/manifest.json --sim cl_sim --wm cl_wm_s0 \\
        --wm-seed1 cl_wm_s1 --openloop ol_wm --session toyarm-0001 --policy exact \\
        --out docs/images/closed_loop_toy_frames.png

``openloop`` writes an ``oscar eval run`` manifest replaying the simulator's episodes (its ``trajectory.npz``
per cell, the simulator's outcome as ``real_success``). ``table`` compares, per policy and on the sessions every
given run finished (all policies judged), the simulator's success (ground truth) with ``oscar-toy``'s verdicts
closed loop (seed 0; seed 0 and 1 averaged where ``--wm-seed1`` is given) and open loop: per-policy success,
Spearman ρ with its 95 % session-bootstrap interval (2000 resamples, seed 0), Pearson r, MMRV (rank form) and
SISR_Δ, from ``oscar_core.metrics.policy_seeds``; and per cell, how often two runs' verdicts agree. A run may be
split over several folders (``--wm A --wm B``: cells of the same run, e.g. one folder per embodiment).
``figure`` draws frames 0, 8, …, 48 of one cell: simulator, closed loop seed 0, seed 1, open loop (rows), each
64×64 frame scaled 2× by nearest neighbour, on white.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

FRAMES = (0, 8, 16, 24, 32, 40, 48)


def _cells(folders) -> dict:
    """(session, policy) → (folder, cell dict) over the ``report.json`` of ``folders`` (one run, split)."""
    out = {}
    for f in folders or ():
        for c in json.loads((Path(f) / "report.json").read_text())["cells"]:
            out[c["session"], c["policy"]] = (Path(f), c)
    return out


def openloop_manifest(sessions: Path, sim: Path, only=None) -> dict:
    """An ``oscar eval run`` manifest replaying ``sim``'s episodes of the sessions of ``sessions`` (or ``only``)."""
    man = json.loads(sessions.read_text())
    by = _cells([sim])
    root = sessions.parent
    cells = []
    for s in man["sessions"]:
        if only and s["session"] not in only:
            continue
        for p in man["policies"]:
            if (s["session"], p["name"]) not in by:
                continue
            f, c = by[s["session"], p["name"]]
            cells.append(
                {
                    "session": s["session"],
                    "policy": p["name"],
                    "task": s["task"],
                    "embodiment": s["embodiment"],
                    "first_frame": str((root / s["first_frame"]).resolve()),
                    "camera": str((root / s["camera"]).resolve()),
                    "trajectory": str((f / c["dir"] / "trajectory.npz").resolve()),
                    "real_success": c["sim_success"],
                    "info": s["info"],
                }
            )
    return {
        "format": "oscar-eval-manifest",
        "policies": [p["name"] for p in man["policies"]],
        "defaults": {"size": man["defaults"]["size"]},
        "cells": cells,
    }


def _fidelity(real: np.ndarray, wm: np.ndarray) -> dict:
    from oscar_core.metrics.policy import mmrv_rank, pearson_r, sisr_delta, spearman_rho
    from oscar_core.metrics.policy_seeds import session_bootstrap

    r, w = np.nanmean(real, 0), np.nanmean(wm, 0)
    boot = session_bootstrap(real, wm, 2000, 0)
    ok = boot[np.isfinite(boot)]
    return {
        "wm_success": [round(float(v), 4) for v in w],
        "spearman_rho": spearman_rho(r, w),
        "spearman_ci95": [float(np.percentile(ok, 2.5)), float(np.percentile(ok, 97.5))] if ok.size else None,
        "pearson_r": pearson_r(r, w),
        "mmrv": mmrv_rank(r, w),
        "sisr_delta_pp": sisr_delta(r, w),
    }


def table(sessions: Path, sim, wm, wm_seed1=(), openloop=()) -> dict:
    """The study's numbers (module docstring) as a dict."""
    man = json.loads(sessions.read_text())
    policies = [p["name"] for p in man["policies"]]
    truth = _cells([sim])
    runs = {"closed loop, seed 0": _cells(wm)}
    if wm_seed1:
        runs["closed loop, seed 1"] = _cells(wm_seed1)
    if openloop:
        runs["open loop"] = {k: (f, {**c, "success": c.get("wm_success")}) for k, (f, c) in _cells(openloop).items()}

    def verdict(c):
        return 0 if c.get("status") == "failed" else c.get("success")

    def complete(run, s):
        return all((s, p) in run and verdict(run[s, p][1]) is not None for p in policies)

    def rows(run, ss):
        return np.array([[float(verdict(run[s, p][1])) for p in policies] for s in ss])

    real_of = {s["session"]: s for s in man["sessions"]}
    out = {"policies": policies, "runs": {}}
    all_sessions = [s for s in real_of if complete(truth_as(truth), s)]
    out["simulator"] = {
        "sessions": len(all_sessions),
        "success": [round(float(v), 4) for v in np.mean(rows(truth_as(truth), all_sessions), 0)],
    }
    for name, run in runs.items():
        ss = [s for s in all_sessions if complete(run, s)]
        if not ss:
            continue
        real, w = rows(truth_as(truth), ss), rows(run, ss)
        out["runs"][name] = {
            "sessions": len(ss),
            "session_ids": ss,
            "sim_success_same_sessions": [round(float(v), 4) for v in real.mean(0)],
            **_fidelity(real, w),
            "cells_agreeing_with_sim": [int(v) for v in (real == w).sum(0)],
        }
    if wm_seed1:  # the fix: both seeds averaged, on the sessions both finished
        a, b = runs["closed loop, seed 0"], runs["closed loop, seed 1"]
        ss = [s for s in all_sessions if complete(a, s) and complete(b, s)]
        if ss:
            real = rows(truth_as(truth), ss)
            w0, w1 = rows(a, ss), rows(b, ss)
            out["runs"]["closed loop, seeds 0+1 averaged"] = {
                "sessions": len(ss),
                "session_ids": ss,
                "sim_success_same_sessions": [round(float(v), 4) for v in real.mean(0)],
                **_fidelity(real, (w0 + w1) / 2),
                "seed0_on_these_sessions": _fidelity(real, w0),
                "cells_seed0_equals_seed1": [int(v) for v in (w0 == w1).sum(0)],
            }
    if openloop:
        a, b = runs["closed loop, seed 0"], runs["open loop"]
        ss = [s for s in all_sessions if complete(a, s) and complete(b, s)]
        if ss:
            out["closed_vs_open"] = {
                "sessions": len(ss),
                "cells_same_verdict": [int(v) for v in (rows(a, ss) == rows(b, ss)).sum(0)],
            }
    return out


def truth_as(truth: dict) -> dict:
    """The simulator's cells with its ground truth as their verdict."""
    return {k: (f, {**c, "success": c.get("sim_success")}) for k, (f, c) in truth.items()}


def figure(
    sessions: Path, sim, wm, wm_seed1, openloop, session: str, policy: str, scale: int = 2, gap: int = 3, also=()
):
    """(rows·(64·scale + gap), 7·(64·scale + gap), 3) uint8: the cell's frames, one row per run and policy
    (``policy``: comma-separated; ``also``: more run folders, a row each, after the others; docstring)."""
    from oscar_core.media.video import read_video

    rows = []
    keys = [(folders, p) for folders in (sim, wm, wm_seed1, openloop, *[[f] for f in also]) for p in policy.split(",")]
    for folders, pol in keys:
        cells = _cells(folders)
        if (session, pol) not in cells:
            continue
        f, c = cells[session, pol]
        video = read_video(f / c["video"])
        tiles = [np.repeat(np.repeat(video[i], scale, 0), scale, 1) for i in FRAMES]
        h, w = tiles[0].shape[:2]
        row = np.full((h + gap, len(tiles) * (w + gap), 3), 255, np.uint8)
        for k, t in enumerate(tiles):
            row[:h, k * (w + gap) : k * (w + gap) + w] = t
        rows.append(row)
    return np.concatenate(rows)[:-gap, :-gap]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    for name in ("openloop", "table", "figure"):
        p = sub.add_parser(name)
        p.add_argument("--sessions", type=Path, required=True, help="the closed-loop manifest")
        p.add_argument("--sim", action="append", required=True, help="the simulator's run folder(s)")
        if name != "openloop":
            p.add_argument("--wm", action="append", required=True, help="oscar-toy closed loop, seed 0, folder(s)")
            p.add_argument("--wm-seed1", action="append", default=[], help="oscar-toy closed loop, seed 1, folder(s)")
            p.add_argument("--openloop", action="append", default=[], help="oscar eval run folder(s) of the replay")
        if name == "openloop":
            p.add_argument("--only", help="comma-separated sessions (default: all)")
        if name == "figure":
            p.add_argument("--session", required=True)
            p.add_argument("--policy", required=True, help="a policy, or several, comma-separated (a row each)")
            p.add_argument("--also", action="append", default=[], help="another run folder: its rows come last")
        p.add_argument("--out", type=Path, help="openloop: manifest; figure: PNG")
        p.add_argument("--json", type=Path, help="table: also write it as JSON")
    a = ap.parse_args(argv)
    if a.cmd == "openloop":
        man = openloop_manifest(a.sessions, Path(a.sim[0]), a.only.split(",") if a.only else None)
        a.out.write_text(json.dumps(man, indent=1) + "\n")
        print(f"wrote {a.out}: {len(man['cells'])} cells")
    elif a.cmd == "table":
        t = table(a.sessions, a.sim[0], a.wm, a.wm_seed1, a.openloop)
        text = json.dumps(t, indent=1)
        if a.json:
            a.json.write_text(text + "\n")
        print(text)
    else:
        import cv2

        img = figure(a.sessions, a.sim, a.wm, a.wm_seed1, a.openloop, a.session, a.policy, also=a.also)
        cv2.imwrite(str(a.out), img[..., ::-1])
        print(f"wrote {a.out}: {img.shape[1]}x{img.shape[0]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
