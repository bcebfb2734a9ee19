"""``oscar eval benchmark table``: the paper's table over a benchmark set, one row per model.

Rows are run folders of :mod:`oscar_core.evaluation.benchmark_run`. A row is
refused, before any scoring, when its folder was made for another benchmark
set (its fingerprint names another set) or lacks predictions of clips of the
set (the error names the row and the clips): rows of a table are always means
over the same clips.

Per clip, on the first ``frames`` frames (the set's horizon): PSNR, SSIM,
LPIPS, tLPIPS, latent L2 (:func:`oscar_core.metrics.video.evaluate_videos`);
per row: FVD and FID over all the set's clips (the paper's per-embodiment
tables carry no FVD / FID, so they are set-level only), frames/s (the mean of
the rollouts' completion records). Per-clip metrics are averaged per
embodiment and then over embodiments, unweighted (the paper's Table 1
"averaged over all embodiments"); the mean over clips is kept in the JSON too.
A metric whose network is not given is ``null`` with the reason in
``missing``, never a number.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..errors import OscarError

__all__ = ["BenchmarkTableError", "benchmark_table", "format_benchmark_table", "COLUMNS"]

COLUMNS = (
    ("psnr", "PSNR ↑"),
    ("ssim", "SSIM ↑"),
    ("lpips", "LPIPS ↓"),
    ("tlpips", "tLPIPS ↓"),
    ("fvd", "FVD ↓"),
    ("fid", "FID ↓"),
    ("latent_l2", "L2 latent ↓"),
    ("frames_per_s", "frames/s ↑"),
)


class BenchmarkTableError(OscarError, ValueError):
    """A row cannot join the table: another set, or predictions for other clips."""


def _check_row(name: str, folder: Path, bench: dict) -> dict:
    """The row's fingerprint parts; refuses a folder of another set or with missing clips."""
    from .benchmark_run import read_timing

    fp = folder / "fingerprint.json"
    if not fp.is_file():
        raise BenchmarkTableError(
            f"--pred {name}={folder}: expected a folder written by `oscar eval benchmark run` "
            "(with fingerprint.json), found none"
        )
    parts = json.loads(fp.read_text()).get("parts", {})
    if parts.get("set") != bench["fingerprint"]:
        raise BenchmarkTableError(
            f"--pred {name}={folder}: expected rollouts of the benchmark set {bench['path']} "
            f"(fingerprint {bench['fingerprint'][:12]}), found rollouts of another set "
            f"({str(parts.get('set'))[:12]})"
        )
    missing = [
        c["id"]
        for c in bench["clips"]
        if read_timing(folder, c["id"]) is None or not (folder / f"{c['id']}.npy").is_file()
    ]
    if missing:
        few = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
        raise BenchmarkTableError(
            f"--pred {name}={folder}: expected predictions of all {len(bench['clips'])} clips "
            f"of the set, found {len(bench['clips']) - len(missing)} (lacking {few}); "
            "finish the run (`oscar eval benchmark run` resumes)"
        )
    extra = sorted(p.stem for p in folder.glob("*.npy") if p.stem not in {c["id"] for c in bench["clips"]})
    if extra:
        raise BenchmarkTableError(
            f"--pred {name}={folder}: expected predictions of the set's clips only, found "
            f"others ({', '.join(extra[:5])})"
        )
    return parts


def benchmark_table(
    bench: dict, rows: dict[str, str], *, networks: dict | None = None, notes: dict | None = None, device: str = "cpu"
) -> dict:
    """The table: ``rows`` maps a row name to its run folder; ``bench`` is a loaded set.

    networks: ``lpips``, ``vae``, ``i3d``, ``inception`` (as
    :func:`~oscar_core.metrics.video.evaluate_videos` takes them; None:
    missing); notes: metric → why it is missing. Returns a JSON-ready dict:
    ``rows`` (name → ``per_embodiment``, ``mean_over_embodiments``,
    ``mean_over_clips``, ``fvd``, ``fid``, ``frames_per_s``), ``clips``
    (name → per-clip rows) and ``missing``.
    """
    from ..metrics.video import Clip, evaluate_videos
    from ..train.clips import ClipSet
    from .benchmark_run import read_timing

    networks, notes = dict(networks or {}), dict(notes or {})
    frames = int(bench["settings"]["frames"])
    folders = {name: Path(f) for name, f in rows.items()}
    fingerprints = {name: _check_row(name, f, bench) for name, f in folders.items()}  # every row before any work
    sets: dict[str, ClipSet] = {}
    gt_cache: dict[str, np.ndarray] = {}

    def truth(entry) -> np.ndarray:
        if entry["id"] not in gt_cache:
            cs = sets.get(entry["clipset"]) or sets.setdefault(entry["clipset"], ClipSet(entry["clipset"]))
            gt_cache[entry["id"]] = cs.load(entry["id"], frames=frames, skeleton=False).rgb
        return gt_cache[entry["id"]]

    missing = {}
    for key, metrics in (
        ("lpips", ("lpips", "tlpips")),
        ("vae", ("latent_l2",)),
        ("i3d", ("fvd",)),
        ("inception", ("fid",)),
    ):
        if networks.get(key) is None:
            for m in metrics:
                missing[m] = notes.get(m) or notes.get(key) or f"no {key} network given"
    if networks.get("i3d") is not None and len(bench["clips"]) < 2:
        networks["i3d"] = None
        missing["fvd"] = "FVD needs at least 2 clips"
    out_rows, out_clips = {}, {}
    for name, folder in folders.items():
        clips = [
            Clip(
                name=e["id"], pred=np.load(folder / f"{e['id']}.npy")[:frames], gt=truth(e), embodiment=e["embodiment"]
            )
            for e in bench["clips"]
        ]
        rep = evaluate_videos(
            clips,
            n_frames=frames,
            lpips_net=networks.get("lpips"),
            vae=networks.get("vae"),
            fvd_extractor=networks.get("i3d"),
            fid_extractor=networks.get("inception"),
            device=device,
        ).to_dict()
        timing = {e["id"]: read_timing(folder, e["id"]) for e in bench["clips"]}  # each record read once
        fps = [t["frames_per_s"] for t in timing.values() if t and t["frames_per_s"]]
        speed = float(np.mean(fps)) if fps else None
        per = {
            emb: {
                **vals,
                "frames_per_s": _mean(
                    [timing[e["id"]]["frames_per_s"] for e in bench["clips"] if e["embodiment"] == emb]
                ),
            }
            for emb, vals in rep["per_embodiment"].items()
        }
        out_rows[name] = {
            "folder": str(folder),
            "model": fingerprints[name].get("model"),
            "per_embodiment": per,
            "mean_over_embodiments": {
                **rep["mean_over_embodiments"],
                "fvd": rep["aggregate"].get("fvd"),
                "fid": rep["aggregate"].get("fid"),
                "frames_per_s": speed,
            },
            "mean_over_clips": rep["aggregate"],
        }
        for block in (out_rows[name]["mean_over_embodiments"], out_rows[name]["mean_over_clips"], *per.values()):
            for key, _ in COLUMNS:  # a metric not computed is null (its reason in "missing"), never absent
                block.setdefault(key, None)
        out_clips[name] = rep["clips"]
    return {
        "set": bench["path"],
        "set_fingerprint": bench["fingerprint"],
        "frames": frames,
        "clips": len(bench["clips"]),
        "embodiments": sorted({c["embodiment"] for c in bench["clips"]}),
        "average": "per-clip metrics: mean per embodiment, then the unweighted mean over embodiments; "
        "FVD / FID: over all clips; frames/s: mean over clips",
        "rows": out_rows,
        "per_clip": out_clips,
        "missing": missing,
    }


def _mean(values) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


def _fmt(v, key) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    return f"{v:.2f}" if key in ("psnr", "fvd", "fid", "frames_per_s") else f"{v:.3f}"


def format_benchmark_table(table: dict) -> str:
    """Markdown: the averaged table (one line per row), then one table per embodiment, then what is missing."""
    head = "| model | " + " | ".join(label for _, label in COLUMNS) + " |"
    rule = "|---" * (len(COLUMNS) + 1) + "|"
    lines = [
        f"Averaged over {len(table['embodiments'])} embodiments ({table['clips']} clips, first "
        f"{table['frames']} frames)",
        "",
        head,
        rule,
    ]
    for name, r in table["rows"].items():
        m = r["mean_over_embodiments"]
        lines.append(f"| {name} | " + " | ".join(_fmt(m.get(k), k) for k, _ in COLUMNS) + " |")
    per_cols = [(k, lab) for k, lab in COLUMNS if k not in ("fvd", "fid")]
    for emb in table["embodiments"]:
        n = next((r["per_embodiment"][emb]["clips"] for r in table["rows"].values()), 0)
        lines += [
            "",
            f"{emb} ({n} clips)",
            "",
            "| model | " + " | ".join(lab for _, lab in per_cols) + " |",
            "|---" * (len(per_cols) + 1) + "|",
        ]
        for name, r in table["rows"].items():
            m = r["per_embodiment"].get(emb, {})
            lines.append(f"| {name} | " + " | ".join(_fmt(m.get(k), k) for k, _ in per_cols) + " |")
    if table["missing"]:
        lines += [""] + [f"missing: {k}: {why}" for k, why in table["missing"].items()]
    return "\n".join(lines)
