"""The report folder of ``oscar eval run``: JSON, a markdown summary, plots, contact sheets.

``OUT/report.json``
    ``policies`` (per policy: real and world-model success rate and episodes,
    mean partial progress, verdict counts, real score, Bradley–Terry Elo),
    ``comparison`` (MMRV in both forms, Spearman ρ, Pearson r, SISR_Δ, per-policy
    ranks; or ``comparison_error`` saying why there is none), ``bradley_terry``
    (the board fitted to the pairwise preferences), ``real_bradley_terry`` (the
    board fitted to the manifest's ``real_preferences``, which then ranks the
    real side; ``real_bradley_terry_error`` says why there is none), ``cells`` (one row per cell:
    real outcome, verdict, reason, video), ``pairs`` (the pairwise verdicts),
    ``counts``, and the model, judge and sampler settings.
``OUT/summary.md``
    The same as tables a person reads.
``OUT/plots/success_scatter.png``, ``OUT/plots/rank_slope.png``
    World-model against real success rate per policy; the two rankings
    (:func:`oscar_core.metrics.plots.plot_comparison`; needs matplotlib).
``OUT/report.html``
    The same as a page for the browser, with every rollout playing beside its
    real outcome (:mod:`oscar_core.evaluation.html`; media under ``OUT/media/``).
``OUT/contact_sheets/<session>.png``
    One row per policy (manifest order): :data:`SHEET_FRAMES` rollout frames
    sampled uniformly over time, and under them the same instants of the real
    episode when the cell has a ``real_video`` — the paper's qualitative
    figure. Rows are separated by grey bars; there is no text in the image
    (``summary.md`` lists the rows).
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from .._util.atomic import atomic_write_bytes
from .._util.log import get_logger
from ..metrics.common import MetricInputError, nan_to_none
from .manifest import Manifest

__all__ = [
    "SHEET_FRAMES",
    "SHEET_HEIGHT",
    "build_report",
    "write_report",
    "write_report_media",
    "contact_sheet",
    "format_summary",
]

_log = get_logger(__name__)

#: Frames per band of a contact sheet (the paper's qualitative figures show six time steps).
SHEET_FRAMES = 6
#: Height in pixels of one band of a contact sheet.
SHEET_HEIGHT = 96
_BAR = 4


def _pairwise_fit(pair_verdicts: Sequence, policies: list[str]):
    """``(bt, error, warnings)``: the Bradley-Terry fit of the pairwise verdicts' preferences (None without
    verdicts or with no valid one, then ``error`` says why) and the fit's :class:`BradleyTerryWarning` messages."""
    from ..metrics.judge import preferences_from_verdicts
    from ..metrics.policy import BradleyTerryWarning, fit_bradley_terry

    bt, bt_error, bt_warnings = None, None, []
    prefs = preferences_from_verdicts(pair_verdicts)
    if pair_verdicts:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", BradleyTerryWarning)
            try:
                bt = fit_bradley_terry(prefs, policies=policies, source="pairwise verdicts") if prefs else None
                if bt is None:
                    bt_error = "no valid pairwise verdicts"
            except MetricInputError as exc:
                bt_error = str(exc)
        bt_warnings = [str(w.message) for w in caught if issubclass(w.category, BradleyTerryWarning)]
    return bt, bt_error, bt_warnings


def _policy_row(manifest: Manifest, p: str, w: dict, real_scores: dict | None, bt) -> dict:
    """Policy ``p``'s row: its cells, real and world-model success (rates in [0, 1] and per episode), the real
    ranking score, the judge's counts and its Bradley-Terry Elo (None when the fit is degenerate or absent)."""
    real_eps = [c.real_success for c in manifest.cells if c.policy == p and c.real_success is not None]
    return {
        "policy": p,
        "cells": sum(c.policy == p for c in manifest.cells),
        "real_success_rate": float(np.mean(real_eps)) if real_eps else None,
        "real_episodes": real_eps,
        "real_score": (real_scores or {}).get(p),
        "wm_success_rate": w.get("success_rate"),
        "wm_episodes": w.get("episodes", []),
        "wm_mean_partial": w.get("mean_partial"),
        "judged": w.get("judged", 0),
        "not_judged": w.get("not_judged", 0),
        "bt_elo": bt.scores("elo")[p] if bt is not None and bt.degenerate is None else None,
    }


def _ranking_comparison(policies, rows, real_sr, judge, pairwise_judge, bt, bt_error, real_scores, real_label):
    """``(comparison, error, wm_fallback)``: the real and world-model rankings compared
    (:func:`~oscar_core.metrics.policy.compare_policies`), or None and why not; ``wm_fallback`` says when the world
    model is ranked by success rates instead of its Bradley-Terry fit."""
    from ..metrics.bradley_terry import world_model_ranking
    from ..metrics.policy import compare_policies

    wm_sr = {p: rows[p]["wm_success_rate"] for p in policies}
    if len(policies) < 2:
        return None, "fewer than 2 policies", None
    if real_sr is None:
        missing = [p for p in policies if rows[p]["real_success_rate"] is None]
        return None, f"no real outcome (real_success) for policies {missing}", None
    if judge is None:
        return None, "no success judge", None
    if any(v is None for v in wm_sr.values()):
        missing = [p for p, v in wm_sr.items() if v is None]
        return None, f"no valid world-model verdict for policies {missing}", None
    # one ranking rule with `oscar eval policies`: tied Elo (to ELO_TIE_DECIMALS) are tied ranks, and a
    # degenerate fit or no fit at all falls back to success rates, saying so
    wm_elo, wm_label, wm_fallback = (
        world_model_ranking(bt, bt_error) if pairwise_judge is not None else (None, "success_rate", None)
    )
    comparison = compare_policies(
        real_sr,
        wm_sr,
        real_score=real_scores,
        wm_score=wm_elo,
        real_score_label=real_label,
        wm_score_label=wm_label,
    )
    return comparison, None, wm_fallback


def _cell_rows(manifest: Manifest, records: list[dict], verdicts: Sequence) -> list[dict]:
    """One row per cell: the real outcome, the judge's verdict on the rollout (None where there is none) and the
    rollout's video, frames and seconds."""
    by_cell = {v.clip: v for v in verdicts if v is not None}
    cells = []
    for cell, rec in zip(manifest.cells, records):
        v = by_cell.get(cell.id)
        cells.append(
            {
                "cell": cell.id,
                "session": cell.session,
                "policy": cell.policy,
                "task": cell.task,
                "real_success": cell.real_success,
                "wm_success": v.binary if v is not None else None,
                "wm_partial": v.partial if v is not None else None,
                "reason": v.reason if v is not None else None,
                "status": v.status if v is not None else None,
                "error": v.error if v is not None else None,
                "video": rec["video"],
                "frames": rec["frames"],
                "rollout_seconds": rec.get("seconds"),
            }
        )
    return cells


def build_report(
    manifest: Manifest,
    records: list[dict],
    verdicts: Sequence,
    pair_verdicts: Sequence,
    wm: dict,
    *,
    counts: dict,
    model,
    judge,
    pairwise_judge,
    sampler: dict,
) -> dict:
    """Everything ``report.json`` holds (module docstring)."""
    policies = list(manifest.policies)
    real_sr = manifest.real_success_rates()
    bt, bt_error, bt_warnings = _pairwise_fit(pair_verdicts, policies)
    real_bt, real_bt_error, real_scores, real_label, real_fallback = _real_side(manifest)
    rows = {p: _policy_row(manifest, p, wm.get(p, {}), real_scores, bt) for p in policies}
    comparison, comparison_error, wm_fallback = _ranking_comparison(
        policies, rows, real_sr, judge, pairwise_judge, bt, bt_error, real_scores, real_label
    )
    pair_rows = [v.to_dict() for v in pair_verdicts]
    cells = _cell_rows(manifest, records, verdicts)
    return nan_to_none(
        {
            "manifest": str(manifest.path),
            "model": model,
            "sampler": sampler,
            "judge": judge,
            "pairwise_judge": pairwise_judge,
            "counts": counts,
            "policies": [rows[p] for p in policies],
            "comparison": (
                {
                    **comparison.to_dict(),
                    "partial": _partial(cells, "cells"),
                    "wm_ranking_fallback": wm_fallback,
                    "real_ranking_fallback": real_fallback,
                }
                if comparison is not None
                else None
            ),
            "comparison_error": comparison_error,
            "bradley_terry": (
                {**bt.to_dict(), "warnings": bt_warnings, "partial": _partial(pair_rows, "pairs")}
                if bt is not None
                else None
            ),
            "bradley_terry_error": bt_error,
            "real_bradley_terry": real_bt.to_dict() if real_bt is not None else None,
            "real_bradley_terry_error": real_bt_error,
            "cells": cells,
            "pairs": pair_rows,
        }
    )


def _real_side(manifest: Manifest):
    """``(board, error, scores, label, fallback)`` of the real side: the Bradley–Terry board of the manifest's
    ``real_preferences`` ranks it (Elo rounded as the world model's); without preferences, ``real_scores``; a
    degenerate or failed fit falls back to the success rates and ``fallback`` says so."""
    from ..metrics.bradley_terry import world_model_ranking
    from ..metrics.policy import BradleyTerryWarning, fit_bradley_terry

    if not manifest.real_preferences:
        return None, None, manifest.real_scores, "real_scores", None
    bt, error = None, None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BradleyTerryWarning)
        try:
            bt = fit_bradley_terry(
                manifest.real_preferences, policies=list(manifest.policies), source="real_preferences"
            )
        except MetricInputError as exc:
            error = str(exc)
    scores, label, fallback = world_model_ranking(bt, error)
    if fallback is not None:
        fallback = fallback.replace("the world model is", "the real side is")
    return bt, error, scores, "real_bradley_terry_elo" if scores is not None else "success_rate", fallback


def _not_judged_reason(status: str | None, error: str | None) -> str:
    if status is None:
        return "no verdict"
    if status == "error" and error and "not sent" in error:
        return "not sent (request budget spent)"
    return status


def _partial(rows: list[dict], what: str) -> dict | None:
    """None when every row has an "ok" verdict, else ``{"judged", "total", "what", "not_judged": {reason: n}}``:
    figures computed from the judged subset must say so wherever they are shown."""
    reasons: dict[str, int] = {}
    for r in rows:
        if r.get("status") != "ok":
            why = _not_judged_reason(r.get("status"), r.get("error"))
            reasons[why] = reasons.get(why, 0) + 1
    if not reasons:
        return None
    return {"judged": len(rows) - sum(reasons.values()), "total": len(rows), "what": what, "not_judged": reasons}


def _partial_note(partial: dict | None) -> str:
    if not partial:
        return ""
    why = ", ".join(f"{n} {reason}" for reason, n in partial["not_judged"].items())
    return f"PARTIAL: {partial['judged']} of {partial['total']} {partial['what']} judged ({why})"


def _fmt(v, spec: str) -> str:
    return "n/a" if v is None else format(v, spec)


def format_summary(report: dict, sheets: dict[str, list[str]] | None = None) -> str:
    """``summary.md``: per-policy table, fidelity metrics, Bradley–Terry board, cells that are not ``ok``."""
    lines = [
        "# Policy evaluation in the world model",
        "",
        f"- manifest: `{report['manifest']}`",
        f"- model: `{report['model']}`",
        f"- judge: `{json.dumps(report['judge'])}`" if report["judge"] else "- judge: none",
        f"- cells: {report['counts']['cells']} (rollouts done {report['counts']['rollouts_done']}, reused "
        f"{report['counts']['rollouts_reused']}; verdicts done {report['counts']['verdicts_done']}, reused "
        f"{report['counts']['verdicts_reused']}, not ok {report['counts']['verdicts_not_ok']})",
        "",
        "## Per policy",
        "",
        "| policy | cells | real SR | world-model SR | mean partial | not judged | real score | BT Elo |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in report["policies"]:
        lines.append(
            f"| {r['policy']} | {r['cells']} | {_fmt(r['real_success_rate'], '.3f')} | "
            f"{_fmt(r['wm_success_rate'], '.3f')} | {_fmt(r['wm_mean_partial'], '.1f')} | "
            f"{r['not_judged']} | {_fmt(r['real_score'], '.4g')} | {_fmt(r['bt_elo'], '.1f')} |"
        )
    lines += ["", "## Fidelity (world model against real)", ""]
    comp = report["comparison"]
    if comp is None:
        lines.append(f"Not computed: {report['comparison_error']}.")
    else:
        m, n = comp["metrics"], comp["n_policies"]
        from ..metrics.policy import mmrv_rank_max

        partial = _partial_note(comp.get("partial"))
        if partial:
            lines += [f"**{partial}**: every figure below comes from the judged cells only.", ""]
        lines += [
            f"| metric | value{' (partial)' if partial else ''} |",
            "|---|---|",
            f"| MMRV (rank form, range [0, {mmrv_rank_max(n):.3f}]) ↓ | {_fmt(m['mmrv'], '.3f')} |",
            f"| MMRV (SIMPLER, success-rate gap) ↓ | {_fmt(m['mmrv_simpler'], '.3f')} |",
            f"| Spearman ρ ↑ | {_fmt(m['spearman_rho'], '+.3f')} |",
            f"| Pearson r ↑ | {_fmt(m['pearson_r'], '+.3f')} |",
            f"| SISR_Δ (pp) ↓ | {_fmt(m['sisr_delta_pp'], '.2f')} |",
            "",
            f"Ranked by: real = {comp['ranked_by']['real']}, world model = {comp['ranked_by']['wm']}.",
        ]
        for key in ("wm_ranking_fallback", "real_ranking_fallback"):
            if comp.get(key):
                lines.append(f"\n{comp[key][0].upper()}{comp[key][1:]}.")
    bt = report["bradley_terry"]
    if bt is not None and bt.get("degenerate"):
        lines += [
            "",
            "## Bradley–Terry–Davidson (world-model pairwise preferences)",
            "",
            f"No ranking: {bt['degenerate']} ({bt['n_comparisons']} comparisons).",
        ]
    elif bt is not None:
        partial = _partial_note(bt.get("partial"))
        lines += ["", "## Bradley–Terry–Davidson (world-model pairwise preferences)", ""]
        lines += [f"**{partial}**.", ""] if partial else []
        lines += ["| policy | Elo | ± std |", "|---|---|---|"]
        lines += [f"| {b['policy']} | {b['elo']:.1f} | {b['elo_std']:.1f} |" for b in bt["board"]]
        lines.append(
            f"\n{bt['n_comparisons']} comparisons, tie ν {bt['tie_nu']:.4f}"
            + ("" if bt["converged"] else " (NOT converged)")
        )
        lines += [f"\nwarning: {w}" for w in bt.get("warnings", [])]
    elif report.get("bradley_terry_error"):
        lines += ["", f"No Bradley–Terry fit: {report['bradley_terry_error']}."]
    real_bt = report.get("real_bradley_terry")
    if real_bt is not None:
        lines += ["", "## Bradley–Terry–Davidson (real pairwise preferences)", ""]
        if real_bt.get("degenerate"):
            lines.append(f"No ranking: {real_bt['degenerate']} ({real_bt['n_comparisons']} comparisons).")
        else:
            lines += ["| policy | Elo | ± std |", "|---|---|---|"]
            lines += [f"| {b['policy']} | {b['elo']:.1f} | {b['elo_std']:.1f} |" for b in real_bt["board"]]
            lines.append(f"\n{real_bt['n_comparisons']} comparisons, tie ν {real_bt['tie_nu']:.4f}")
    elif report.get("real_bradley_terry_error"):
        lines += ["", f"No Bradley–Terry fit of the real preferences: {report['real_bradley_terry_error']}."]
    bad = [c for c in report["cells"] if c["status"] not in (None, "ok")]
    if bad:
        lines += ["", "## Cells without a valid verdict", ""]
        lines += [f"- `{c['cell']}`: {c['status']}: {c['error']}" for c in bad]
    if sheets:
        lines += [
            "",
            "## Contact sheets",
            "",
            "Rows top to bottom (each: rollout band, then the real band when there is a real video):",
            "",
        ]
        lines += [f"- `contact_sheets/{s}.png`: {', '.join(rows)}" for s, rows in sheets.items()]
    return "\n".join(lines) + "\n"


def _thumbs(video: np.ndarray, n: int, height: int) -> np.ndarray:
    import cv2

    from ..metrics.judge import sample_frame_indices

    idx = sample_frame_indices(len(video), n)
    h, w = video.shape[1:3]
    width = max(1, round(w * height / h))
    tiles = [cv2.resize(np.ascontiguousarray(video[i]), (width, height), interpolation=cv2.INTER_AREA) for i in idx]
    while len(tiles) < n:  # a clip shorter than n frames: pad with black tiles
        tiles.append(np.zeros_like(tiles[0]))
    bar = np.full((height, _BAR, 3), 128, np.uint8)
    parts = []
    for k, t in enumerate(tiles):
        parts += [t] if k == 0 else [bar, t]
    return np.concatenate(parts, axis=1)


def contact_sheet(
    rows: Sequence[tuple[np.ndarray, np.ndarray | None]], *, frames: int = SHEET_FRAMES, height: int = SHEET_HEIGHT
) -> np.ndarray:
    """Stack ``(rollout, real or None)`` video pairs into one (H, W, 3) uint8 image (module docstring)."""
    bands = []
    for rollout, real in rows:
        bands.append(_thumbs(rollout, frames, height))
        if real is not None:
            bands.append(_thumbs(real, frames, height))
        bands.append(None)  # a thicker bar between policies
    width = max(b.shape[1] for b in bands if b is not None)
    out = []
    for b in bands[:-1]:
        if b is None:
            out.append(np.full((2 * _BAR, width, 3), 128, np.uint8))
            continue
        if b.shape[1] < width:
            b = np.concatenate([b, np.zeros((b.shape[0], width - b.shape[1], 3), np.uint8)], axis=1)
        out.append(b)
    return np.concatenate(out, axis=0)


def _write_png(path: Path, image: np.ndarray) -> None:
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))
    if not ok:
        raise MetricInputError(path, "image", "an encodable (H, W, 3) image", str(image.shape))
    atomic_write_bytes(path, buf.tobytes())


def write_report(
    out: Path,
    report: dict,
    manifest: Manifest,
    records: list[dict],
    *,
    plot_formats=("png",),
    log: Callable[[str], None] | None = None,
) -> dict:
    """Write ``report.json``, ``summary.md``, the plots, the contact sheets and ``report.html``; returns their paths.

    Problems that do not stop the report (an unreadable real video, no
    matplotlib) are logged as warnings on the ``oscar`` logger and also passed
    to ``log`` if given.
    """
    out = Path(out)
    paths, sheets = write_report_media(out, report, manifest, records, plot_formats=plot_formats, log=log)
    report_path = out / "report.json"
    atomic_write_bytes(report_path, (json.dumps({**report, "files": paths}, indent=2) + "\n").encode())
    summary = out / "summary.md"
    atomic_write_bytes(summary, format_summary(report, sheets).encode())
    paths["report"], paths["summary"] = str(report_path), str(summary)
    return paths


def write_report_media(
    out: Path,
    report: dict,
    manifest: Manifest,
    records: list[dict],
    *,
    plot_formats=("png",),
    log: Callable[[str], None] | None = None,
    html_options: dict | None = None,
) -> tuple[dict, dict[str, list[str]]]:
    """Write the contact sheets (of the cells whose video exists), the comparison plots and ``report.html``
    (:func:`~.html.write_html_report`, given ``html_options`` too) for ``report`` (:func:`build_report`); returns
    ``(paths, {session: names of its sheet's rows})``."""

    def warn(msg: str) -> None:
        _log.warning(msg)
        if log is not None:
            log(f"warning: {msg}")

    from ..metrics.video import load_video

    out = Path(out)
    paths: dict = {}
    sheets: dict[str, list[str]] = {}
    (out / "contact_sheets").mkdir(parents=True, exist_ok=True)
    for session in manifest.sessions:
        rows, names = [], []
        for cell, rec in zip(manifest.cells, records):
            if cell.session != session:
                continue
            real = None
            if cell.real_video is not None:
                try:
                    real = load_video(cell.real_video)
                except (MetricInputError, OSError, ValueError) as exc:
                    warn(f"contact sheet {session}: cannot read {cell.real_video}: {exc}")
            if not (out / rec["video"]).is_file():  # a cell that made no video (a closed-loop policy's fault)
                continue
            rows.append((load_video(out / rec["video"]), real))
            names.append(cell.policy + (" (+ real)" if real is not None else ""))
        if not rows:
            continue
        path = out / "contact_sheets" / f"{session}.png"
        _write_png(path, contact_sheet(rows))
        sheets[session] = names
    paths["contact_sheets"] = [str(out / "contact_sheets" / f"{s}.png") for s in sheets]
    if report["comparison"] is not None:
        try:
            from ..metrics.plots import plot_comparison
            from ..metrics.policy import compare_policies

            comp = report["comparison"]
            pol = [p["policy"] for p in comp["policies"]]
            c = compare_policies(
                {p["policy"]: p["real_success"] for p in comp["policies"]},
                {p["policy"]: p["wm_success"] for p in comp["policies"]},
                real_score={p["policy"]: p["real_score"] for p in comp["policies"]},
                wm_score={p["policy"]: p["wm_score"] for p in comp["policies"]},
                names=pol,
                real_score_label=comp["ranked_by"]["real"],
                wm_score_label=comp["ranked_by"]["wm"],
            )
            written = plot_comparison(c, out / "plots", formats=plot_formats)
            paths["plots"] = {k: [str(p) for p in v] for k, v in written.items()}
        except ImportError as exc:
            warn(f"no plots: {exc}")
    from .html import write_html_report

    plots = [p for v in paths.get("plots", {}).values() for p in v]
    paths["html"] = str(
        write_html_report(
            out,
            report,
            manifest,
            records,
            plots=plots,
            sheets={s: out / "contact_sheets" / f"{s}.png" for s in sheets},
            **(html_options or {}),
        )
    )
    return paths, sheets
