"""The evaluation manifest: sessions × policies, one row ("cell") per rollout.

A manifest is one JSON file (RoboArena-style: each session is one scene and
task, rolled out once per policy)::

    {"format": "oscar-eval-manifest",
     "policies": ["pi0_fast", "pg_bin"],
     "defaults": {"embodiment": "franka", "camera": "cams/zed.json", "size": "512x288"},
     "real_scores": {"pi0_fast": 1633.0, "pg_bin": 1402.5},
     "cells": [
       {"session": "81a85b7c", "policy": "pi0_fast", "task": "put the food on the plate",
        "first_frame": "81a85b7c/first.png", "trajectory": "81a85b7c/pi0_fast.npz", "real_success": 1,
        "real_video": "81a85b7c/pi0_fast_real.mp4"},
       ...]}

``policies`` lists every policy (its order is the report's order); every cell
names one of them. A cell has ``session``, ``policy``, ``task`` (the
instruction a rater reads), ``embodiment``, ``first_frame`` (PNG/JPEG, or a video
whose frame 0 is used, taken by ``camera``), ``trajectory`` (``.npz``, docs/formats.md), ``camera``
(calibration ``.json``), and optionally ``real_success`` (0/1, the real
outcome where known), ``real_video`` (the real episode, for the contact
sheets), ``prompt_embeds`` (a ``.safetensors`` text embedding; default: the
model's empty prompt), ``seed`` (rollout noise seed; default 0) and ``info``
(an object handed to programmatic judges, e.g. a target position). Any cell
key may instead be set once in ``defaults``. ``size`` (``WIDTHxHEIGHT``, in
``defaults`` only) is the rollout size; default: the model card's, else the
camera's. ``real_scores`` (optional) gives each policy's real ranking score,
higher = better (e.g. its RoboArena Elo); without it the real side is ranked
by its success rate. Relative paths are relative to the manifest's folder.

Every check runs before any rollout, and an error names the row:
``manifest.json: cells[3] (session '81a85b7c', policy 'pg_bin'): field
'first_frame': expected an existing image file, found no such file``.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from .._util.inputs import read_text_file
from ..metrics.common import MetricInputError, finite_float

__all__ = ["FORMAT", "Cell", "Manifest", "ManifestError", "load_manifest", "file_digest"]

FORMAT = "oscar-eval-manifest"
_NAME = re.compile(r"\A[A-Za-z0-9][A-Za-z0-9._-]*\Z")
CELL_KEYS = (
    "session",
    "policy",
    "task",
    "embodiment",
    "first_frame",
    "trajectory",
    "camera",
    "real_success",
    "real_video",
    "prompt_embeds",
    "seed",
    "info",
)
REQUIRED = ("session", "policy", "task", "embodiment", "first_frame", "trajectory", "camera")
PATH_KEYS = ("first_frame", "trajectory", "camera", "real_video", "prompt_embeds")
TOP_KEYS = ("format", "policies", "defaults", "real_scores", "real_preferences", "cells", "description")


class ManifestError(MetricInputError):
    """A manifest (or one of its rows) is malformed; the message names the file, the row and the field."""


@dataclass(frozen=True)
class Cell:
    """One (session, policy) rollout of a manifest.

    Paths are absolute; ``real_success`` is 0, 1 or None (unknown); ``row`` is
    the cell's index in the manifest's ``cells`` list.
    """

    session: str
    policy: str
    task: str
    embodiment: str
    first_frame: Path
    trajectory: Path
    camera: Path
    row: int
    real_success: int | None = None
    real_video: Path | None = None
    prompt_embeds: Path | None = None
    seed: int = 0
    info: dict = field(default_factory=dict, compare=False)

    @property
    def id(self) -> str:
        """``"<session>/<policy>"``: the cell's name in outputs."""
        return f"{self.session}/{self.policy}"


@dataclass(frozen=True)
class Manifest:
    """A checked manifest: ``policies`` in report order, ``cells`` in file order."""

    path: Path
    policies: tuple[str, ...]
    cells: tuple[Cell, ...]
    size: tuple[int, int] | None = None
    real_scores: dict | None = None
    real_preferences: tuple | None = None

    @property
    def sessions(self) -> list[str]:
        return list(dict.fromkeys(c.session for c in self.cells))

    def real_success_rates(self) -> dict[str, float] | None:
        """``{policy: mean real_success}`` if every policy has at least one known real outcome, else None."""
        out = {}
        for p in self.policies:
            vals = [c.real_success for c in self.cells if c.policy == p and c.real_success is not None]
            if not vals:
                return None
            out[p] = sum(vals) / len(vals)
        return out


def file_digest(path: Path) -> str:
    """SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def resolve_paths(path: Path, row: str, merged: Mapping, keys) -> dict:
    """``{key: absolute path or None}`` of the path fields ``keys`` of one row, relative to the manifest ``path``'s
    folder; :class:`ManifestError` naming ``row`` and the field for a non-string or a missing file."""
    paths = {}
    for key in keys:
        v = merged.get(key)
        if v is None:
            paths[key] = None
            continue
        if not isinstance(v, str) or not v:
            raise ManifestError(row, key, "a file path (relative to the manifest's folder)", repr(v))
        p = (path.parent / v).resolve()
        if not p.exists():
            raise ManifestError(row, key, f"an existing file ({v} relative to {path.parent})", "no such file")
        paths[key] = p
    return paths


def _row_name(path: Path, k: int, raw) -> str:
    if isinstance(raw, Mapping):
        return f"{path}: cells[{k}] (session {raw.get('session')!r}, policy {raw.get('policy')!r})"
    return f"{path}: cells[{k}]"


def _size(value, source: str) -> tuple[int, int]:
    if isinstance(value, str):
        m = re.fullmatch(r"\s*(\d+)\s*x\s*(\d+)\s*", value.lower())
        if m:
            w, h = int(m.group(1)), int(m.group(2))
            if w % 16 == 0 and h % 16 == 0 and w > 0 and h > 0:
                return w, h
    raise ManifestError(source, "defaults.size", 'WIDTHxHEIGHT with both multiples of 16, e.g. "512x288"', repr(value))


def load_manifest(path) -> Manifest:
    """Read and check a manifest (rules in the module docstring); raises :class:`ManifestError`."""
    path = Path(path).resolve()
    text = read_text_file(
        path, "an evaluation manifest JSON file (utf-8 text; docs/evaluation.md)", error=ManifestError, field="file"
    )
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ManifestError(path, f"line {exc.lineno}", "valid JSON", str(exc)) from None
    if not isinstance(data, dict):
        raise ManifestError(path, "top level", "a JSON object with 'policies' and 'cells'", type(data).__name__)
    extra = sorted(k for k in data if k not in TOP_KEYS)
    if extra:
        raise ManifestError(path, "top level", f"only the keys {list(TOP_KEYS)}", f"unknown keys {extra}")
    if data.get("format", FORMAT) != FORMAT:
        raise ManifestError(path, "format", repr(FORMAT), repr(data.get("format")))
    policies = data.get("policies")
    if (
        not isinstance(policies, list)
        or len(policies) < 1
        or not all(isinstance(p, str) and _NAME.match(p) for p in policies)
    ):
        raise ManifestError(
            path, "policies", "a non-empty list of policy names (letters, digits, . _ -)", repr(policies)
        )
    dup = sorted({p for p in policies if policies.count(p) > 1})
    if dup:
        raise ManifestError(path, "policies", "unique policy names", f"duplicates {dup}")
    defaults = data.get("defaults", {})
    if not isinstance(defaults, dict):
        raise ManifestError(path, "defaults", "an object of cell keys", type(defaults).__name__)
    bad = sorted(k for k in defaults if k not in CELL_KEYS + ("size",) or k in ("session", "policy"))
    if bad:
        raise ManifestError(path, "defaults", "cell keys other than session and policy, or size", f"keys {bad}")
    size = _size(defaults["size"], str(path)) if "size" in defaults else None
    real_scores = data.get("real_scores")
    if real_scores is not None:
        if not isinstance(real_scores, dict) or sorted(real_scores) != sorted(policies):
            raise ManifestError(
                path,
                "real_scores",
                f"a score for each of the policies {policies}",
                repr(sorted(real_scores) if isinstance(real_scores, dict) else real_scores),
            )
        real_scores = {p: finite_float(real_scores[p], str(path), f"real_scores.{p}") for p in policies}
    real_prefs = _real_preferences(path, data.get("real_preferences"), policies, real_scores)
    rows = data.get("cells")
    if not isinstance(rows, list) or not rows:
        raise ManifestError(path, "cells", "a non-empty list of cells", repr(rows)[:80])
    cells: list[Cell] = []
    seen: dict[tuple[str, str], int] = {}
    tasks: dict[str, tuple[str, int]] = {}
    for k, raw in enumerate(rows):
        cells.append(_cell(path, k, raw, defaults, policies, seen, tasks))
    return Manifest(
        path=path,
        policies=tuple(policies),
        cells=tuple(cells),
        size=size,
        real_scores=real_scores,
        real_preferences=real_prefs,
    )


def _real_preferences(path: Path, raw, policies: list, real_scores) -> tuple | None:
    """The checked ``real_preferences`` as :class:`~oscar_core.metrics.bradley_terry.Preference` records."""
    from ..metrics.bradley_terry import parse_preference

    if raw is None:
        return None
    if real_scores is not None:
        raise ManifestError(path, "real_preferences", "real_scores or real_preferences, not both", "both")
    if not isinstance(raw, list) or not raw:
        raise ManifestError(path, "real_preferences", "a non-empty list of {a, b, winner}", repr(raw)[:80])
    out = []
    for k, item in enumerate(raw):
        where = f"{path}: real_preferences[{k}]"
        if isinstance(item, dict):
            extra = sorted(key for key in item if key not in ("a", "b", "winner", "session"))
            if extra:
                raise ManifestError(where, "keys", "a, b, winner and optionally session", f"unknown keys {extra}")
        pref = parse_preference(item, source=where)
        for key in ("a", "b"):
            if getattr(pref, key) not in policies:
                raise ManifestError(where, key, f"one of the manifest's policies {policies}", repr(getattr(pref, key)))
        out.append(pref)
    return tuple(out)


def _cell(path: Path, k: int, raw, defaults: dict, policies: list, seen: dict, tasks: dict) -> Cell:
    row = _row_name(path, k, raw)
    if not isinstance(raw, dict):
        raise ManifestError(row, "cell", "an object", type(raw).__name__)
    unknown = sorted(key for key in raw if key not in CELL_KEYS)
    if unknown:
        raise ManifestError(row, "keys", f"cell keys among {list(CELL_KEYS)}", f"unknown keys {unknown}")
    merged = {**{key: v for key, v in defaults.items() if key != "size"}, **raw}
    missing = [key for key in REQUIRED if key not in merged]
    if missing:
        raise ManifestError(row, missing[0], "a value (in the cell or in 'defaults')", "none")
    for key in ("session", "policy", "task", "embodiment"):
        v = merged[key]
        if not isinstance(v, str) or not v.strip():
            raise ManifestError(row, key, "a non-empty string", repr(v))
    for key in ("session", "policy"):
        if not _NAME.match(merged[key]):
            raise ManifestError(
                row, key, "a name of letters, digits, '.', '_' or '-' (it becomes a file name)", repr(merged[key])
            )
    session, policy = merged["session"], merged["policy"]
    if policy not in policies:
        raise ManifestError(row, "policy", f"one of the manifest's policies {policies}", repr(policy))
    if (session, policy) in seen:
        raise ManifestError(
            row, "session/policy", "one cell per (session, policy)", f"a duplicate of cells[{seen[(session, policy)]}]"
        )
    seen[(session, policy)] = k
    task = merged["task"].strip()
    if session in tasks and tasks[session][0] != task:
        raise ManifestError(
            row, "task", f"the session's task {tasks[session][0]!r} (as in cells[{tasks[session][1]}])", repr(task)
        )
    tasks.setdefault(session, (task, k))
    paths = resolve_paths(path, row, merged, PATH_KEYS)
    real = merged.get("real_success")
    if real is not None and (isinstance(real, bool) or real not in (0, 1)):
        raise ManifestError(row, "real_success", "0, 1 or null (unknown)", repr(real))
    seed = merged.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ManifestError(row, "seed", "an integer >= 0", repr(seed))
    info = merged.get("info", {})
    if not isinstance(info, dict):
        raise ManifestError(row, "info", "an object (handed to programmatic judges)", type(info).__name__)
    return Cell(
        session=session,
        policy=policy,
        task=task,
        embodiment=merged["embodiment"],
        first_frame=paths["first_frame"],
        trajectory=paths["trajectory"],
        camera=paths["camera"],
        row=k,
        real_success=None if real is None else int(real),
        real_video=paths["real_video"],
        prompt_embeds=paths["prompt_embeds"],
        seed=seed,
        info=dict(info),
    )
