"""The episodes of a batch render: :class:`EpisodeSpec` (embodiment, trajectory ``.npz``, camera ``.json``, output
path, optional (width, height) pixels, fps, resize, format and condition), read from a manifest
(:func:`read_manifest`: JSONL or CSV, docs/formats.md) or made for a folder of trajectories
(:func:`specs_from_folder`). Rendering them is :mod:`oscar_core.render.batch`, which re-exports these names.
"""

from __future__ import annotations

import csv
import io
import json
import os
from dataclasses import dataclass
from pathlib import Path

from .._util.inputs import read_text_file
from ..errors import InputFileError

__all__ = ["EpisodeSpec", "read_manifest", "specs_from_folder"]

MANIFEST_FIELDS = ("embodiment", "trajectory", "camera", "out", "size", "fps", "resize", "format", "condition")
REQUIRED_FIELDS = ("embodiment", "trajectory", "camera", "out")


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode to render.

    embodiment: registered name; trajectory: ``.npz`` path; camera: ``.json`` path;
    out: output path (``.mp4``, ``.mkv`` or a name ending in ``/``);
    size: (width, height) pixels or None (the calibration's); fps: None (the
    trajectory's); resize: "crop" or "stretch"; format: None (from ``out``), "mp4", "mkv", "png";
    condition: None (``RenderOptions.condition``), "skeleton", "mesh" or "capsules" (see :mod:`oscar_core.render.conditions`).
    """

    embodiment: str
    trajectory: str
    camera: str
    out: str
    size: tuple[int, int] | None = None
    fps: float | None = None
    resize: str = "crop"
    format: str | None = None
    condition: str | None = None


# ------------------------------------------------------------------ manifests


def _parse_size(value, where: str, source: str) -> tuple[int, int] | None:
    if value in (None, ""):
        return None
    if isinstance(value, (list, tuple)) and len(value) == 2:
        w, h = value
    else:
        try:
            w, h = (int(v) for v in str(value).lower().split("x"))
        except ValueError:
            raise InputFileError(
                source, f"{where}.size", "WIDTHxHEIGHT such as 512x288 (or [512, 288])", repr(value)
            ) from None
    if not (isinstance(w, int) and isinstance(h, int)) or w < 2 or h < 2:
        raise InputFileError(source, f"{where}.size", "a size of at least 2x2 pixels", repr(value))
    return int(w), int(h)


def _spec_from_row(row: dict, where: str, source: str, base: Path) -> EpisodeSpec:
    unknown = [k for k in row if k not in MANIFEST_FIELDS]
    if unknown:
        raise InputFileError(
            source,
            f"{where}.{unknown[0]}",
            f"only the fields {', '.join(MANIFEST_FIELDS)}",
            f"unknown field(s) {unknown}",
        )
    for k in REQUIRED_FIELDS:
        v = row.get(k)
        if not isinstance(v, str) or not v.strip():
            raise InputFileError(source, f"{where}.{k}", "a non-empty string", repr(v))

    def resolve(p: str) -> str:
        keep_slash = p.endswith(("/", os.sep))
        q = Path(os.path.expanduser(p))
        out = str(q if q.is_absolute() else base / q)
        return out + "/" if keep_slash and not out.endswith("/") else out

    fps = row.get("fps")
    if fps in ("", None):
        fps = None
    else:
        try:
            fps = float(fps)
        except (TypeError, ValueError):
            raise InputFileError(source, f"{where}.fps", "a positive number", repr(fps)) from None
        if not fps > 0:
            raise InputFileError(source, f"{where}.fps", "a positive number", repr(fps))
    resize = row.get("resize") or "crop"
    if resize not in ("crop", "stretch"):
        raise InputFileError(source, f"{where}.resize", "crop or stretch", repr(resize))
    fmt = row.get("format") or None
    if fmt not in (None, "mp4", "mkv", "png"):
        raise InputFileError(source, f"{where}.format", "mp4, mkv or png", repr(fmt))
    from .conditions import CONDITIONS

    condition = row.get("condition") or None
    if condition not in (None, *CONDITIONS):
        raise InputFileError(source, f"{where}.condition", " or ".join(CONDITIONS), repr(condition))
    return EpisodeSpec(
        row["embodiment"].strip(),
        resolve(row["trajectory"]),
        resolve(row["camera"]),
        resolve(row["out"]),
        _parse_size(row.get("size"), where, source),
        fps,
        resize,
        fmt,
        condition,
    )


def read_manifest(path) -> list[EpisodeSpec]:
    """Episode specs from a ``.jsonl`` (one JSON object per line) or ``.csv`` (header row) manifest.

    Fields: embodiment, trajectory, camera, out (required); size, fps, resize,
    format, condition (optional). Relative paths are relative to the manifest's folder.
    Blank lines and JSONL lines starting with ``#`` are skipped. Raises
    :class:`InputFileError` naming the file, the line and the field.
    """
    path = Path(path)
    source = str(path)
    text = read_text_file(path, "a render manifest (.jsonl or .csv, utf-8 text; docs/formats.md)")
    base = path.parent
    specs = []
    suffix = path.suffix.lower()
    if suffix in (".jsonl", ".ndjson"):
        for n, line in enumerate(text.splitlines(), start=1):
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            try:
                row = json.loads(line)
            except json.JSONDecodeError as exc:
                raise InputFileError(
                    source, f"line {n}", "one JSON object per line", f"invalid JSON ({exc.msg})"
                ) from None
            if not isinstance(row, dict):
                raise InputFileError(source, f"line {n}", "a JSON object", type(row).__name__)
            specs.append(_spec_from_row(row, f"line {n}", source, base))
    elif suffix == ".csv":
        reader = csv.DictReader(io.StringIO(text))
        if reader.fieldnames is None:
            raise InputFileError(source, "header", f"a header row naming {', '.join(REQUIRED_FIELDS)}", "an empty file")
        for row in reader:
            if not any((v or "").strip() for v in row.values() if isinstance(v, str)):
                continue
            if None in row:
                raise InputFileError(
                    source, f"line {reader.line_num}", "as many values as header columns", f"extra values {row[None]}"
                )
            specs.append(
                _spec_from_row(
                    {
                        k: (v.strip() if isinstance(v, str) else v)
                        for k, v in row.items()
                        if k is not None and v not in ("", None)
                    },
                    f"line {reader.line_num}",
                    source,
                    base,
                )
            )
    else:
        raise InputFileError(source, "suffix", ".jsonl or .csv", repr(path.suffix))
    if not specs:
        raise InputFileError(source, "rows", "at least one episode", "none")
    return specs


def specs_from_folder(
    folder,
    embodiment: str,
    out_dir,
    *,
    camera=None,
    suffix: str = ".mp4",
    size: tuple[int, int] | None = None,
    fps: float | None = None,
    resize: str = "crop",
) -> list[EpisodeSpec]:
    """One spec per ``*.npz`` trajectory in ``folder`` (sorted by name).

    Each trajectory's camera is ``camera`` when given, else ``<stem>.json``
    beside it, else the folder's ``camera.json``. Outputs are
    ``out_dir/<stem><suffix>`` (suffix ".mp4", ".mkv" or "/" for PNG folders).
    Raises :class:`InputFileError` listing trajectories without a camera.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder of trajectories")
    trajs = sorted(folder.glob("*.npz"))
    if not trajs:
        raise InputFileError(str(folder), "*.npz", "at least one trajectory file", "none")
    shared = folder / "camera.json"
    specs, missing = [], []
    for t in trajs:
        cam = (
            Path(camera)
            if camera
            else (t.with_suffix(".json") if t.with_suffix(".json").is_file() else shared if shared.is_file() else None)
        )
        if cam is None:
            missing.append(t.name)
            continue
        out = str(Path(out_dir) / t.stem) + suffix
        specs.append(EpisodeSpec(embodiment, str(t), str(cam), out, size, fps, resize))
    if missing:
        raise InputFileError(
            str(folder),
            "camera",
            "<stem>.json beside each trajectory, a camera.json in the folder, or --camera",
            f"no camera for {missing[:5]}" + (" …" if len(missing) > 5 else ""),
        )
    return specs
