"""The files ``oscar eval`` reads: clip folders, policy results, preferences, judge videos and tasks.

Their formats are in the docstrings of :mod:`oscar_core.metrics.cli` (``video``, ``policies``) and
:mod:`oscar_core.metrics.cli_judge` (``judge``, ``pairwise``).
"""

from __future__ import annotations

import glob
import json
from pathlib import Path

from .._util.inputs import read_text_file
from .common import MetricInputError, finite_float

__all__ = [
    "VIDEO_EXTS",
    "FRAME_EXTS",
    "collect_clips",
    "read_policy_results",
    "read_preferences",
    "collect_judge_videos",
    "read_tasks",
]

VIDEO_EXTS = (".mp4", ".mkv", ".avi", ".mov", ".webm", ".gif", ".npy")
FRAME_EXTS = (".png", ".jpg", ".jpeg")


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
        raise MetricInputError(pred, "clips", f"video files ({', '.join(VIDEO_EXTS)}) or PNG-frame folders", "none")
    missing, extra = sorted(set(pc) - set(gc)), sorted(set(gc) - set(pc))
    if missing:
        raise MetricInputError(
            gt,
            "clips",
            f"a ground truth for every prediction in {pred}",
            f"none for {missing[:10]}{' ...' if len(missing) > 10 else ''}",
        )
    if extra:
        raise MetricInputError(
            pred,
            "clips",
            f"a prediction for every ground truth in {gt}",
            f"none for {extra[:10]}{' ...' if len(extra) > 10 else ''}",
        )
    clips = []
    for name in sorted(pc):
        tag = embodiment if embodiment is not None else (name.split("/")[0] if "/" in name else None)
        clips.append(Clip(name, pc[name], gc[name], tag))
    return clips


def _read_json(path: Path):
    text = read_text_file(path, "a JSON file (utf-8 text)", error=MetricInputError, field="file")
    try:
        return json.loads(text)
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
    text = read_text_file(path, "a JSON-lines file (utf-8 text)", error=MetricInputError, field="file")
    prefs = []
    for lineno, line in enumerate(text.splitlines(), start=1):
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
            raise MetricInputError(
                raw,
                "--videos",
                f"a video file ({', '.join(VIDEO_EXTS)}), a folder or a glob",
                f"a {path.suffix or 'suffix-less'} file",
            )
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
        raise MetricInputError(
            raw, "--videos", "an existing folder, video file or glob pattern", "no such file or folder"
        )
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
            raise MetricInputError(
                path, key, 'an instruction, or an object with "instruction", "policy", "session"', repr(value)
            )
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
        clips.append(
            JudgeClip(
                name=name,
                video=video,
                instruction=merged["instruction"].strip(),
                policy=merged["policy"],
                session=merged["session"],
            )
        )
    if missing:
        raise MetricInputError(
            path,
            "instruction",
            "a task for every clip (keyed by the clip's name or a folder)",
            f"none for {missing[:10]}{' ...' if len(missing) > 10 else ''}",
        )
    return clips


def _write_json(path, data) -> None:
    from .._util.atomic import atomic_write_bytes

    atomic_write_bytes(Path(path), (json.dumps(data, indent=2) + "\n").encode())
