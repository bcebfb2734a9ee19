"""The manifest of ``oscar eval action-following``: counterfactual sets, each one first frame and one trajectory with
variants that change one decision, and the true outcome of each variant.

```json
{"format": "oscar-action-following", "version": 1, "description": "...",
 "locator": "module:attr",                       (optional: where the object is in a frame, for the ball errors)
 "sets": [{"set": "toyarm-0000", "embodiment": "toyarm",
           "first_frame": "toyarm-0000/first.png", "camera": "toyarm-0000/camera.json",
           "trajectory": "toyarm-0000/trajectory.npz",
           "task": "pick up the yellow ball ...",  (optional: the judge's instruction)
           "prompt_embeds": "embeds.safetensors",  (optional: the model's prompt; default its empty prompt)
           "info": {...},                          (what the judge reads, e.g. ball_moved's px_to_floor_radii)
           "variants": [{"name": "close_at_ball", "transforms": [], "outcome": 1,
                         "video": "toyarm-0000/true/close_at_ball.mkv"},   (optional: the true frames)
                        {"name": "stay_open", "transforms": [{"gripper": "open", "from": 0}], "outcome": 0}]}]}
```

Paths are relative to the manifest's folder. ``transforms``: :mod:`oscar_core.evaluation.variant_transforms`;
``outcome``: the true outcome (1 success, 0 not) as the user knows it (the toy world's simulator writes its own).
:func:`load_action_following` checks every field, applies every transform (an arm that cannot follow a shift is
an error here) and refuses a set whose variants are all the same trajectory, before any model is looked up: a
:class:`~oscar_core.metrics.common.MetricInputError` naming the manifest, the field, what was expected and what
was found.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..metrics.common import MetricInputError

__all__ = ["FORMAT", "CounterfactualSet", "Variant", "ActionFollowingManifest", "load_action_following"]

FORMAT = "oscar-action-following"


@dataclass
class Variant:
    """name; transforms: as given; outcome: 0/1 the true outcome; video: the true frames' file or None;
    trajectory: the base trajectory with the transforms applied; extra: any other fields, kept as given."""

    name: str
    transforms: list
    outcome: int
    video: Path | None
    trajectory: object
    extra: dict = field(default_factory=dict)


@dataclass
class CounterfactualSet:
    """One set: ``set`` id, embodiment name, first frame / camera / trajectory paths, task, prompt embeddings path
    (or None), the judge's ``info`` and its variants; ``row``: its index in the manifest."""

    set: str
    embodiment: str
    first_frame: Path
    camera: Path
    trajectory: Path
    task: str
    prompt_embeds: Path | None
    info: dict
    variants: list[Variant]
    row: int

    @property
    def frames(self) -> int:
        return len(self.variants[0].trajectory.q)


@dataclass
class ActionFollowingManifest:
    path: Path
    description: str
    locator: str | None
    sets: list[CounterfactualSet]
    raw: dict


def _req(d: dict, key: str, where: str, path, kind=str):
    if key not in d:
        raise MetricInputError(path, f"{where}.{key}", f"a {kind.__name__}", "nothing (missing)")
    v = d[key]
    if not isinstance(v, kind) or (kind is str and not v.strip()):
        raise MetricInputError(path, f"{where}.{key}", f"a non-empty {kind.__name__}", repr(v)[:80])
    return v


def _file(root: Path, rel, where: str, path) -> Path:
    p = (root / rel).resolve() if not Path(rel).is_absolute() else Path(rel)
    if not p.exists():
        raise MetricInputError(path, where, "an existing file (relative to the manifest)", f"{rel!r}: no such file")
    return p


def load_action_following(path, plugin_paths=()) -> ActionFollowingManifest:
    """Read and check an action-following manifest (module docstring); every variant's trajectory computed."""
    from ..errors import OscarError
    from ..kinematics.trajectory import load_trajectory
    from ..plugin.registry import get_embodiment
    from ..policy.ik import EndEffectorIK
    from .variant_transforms import VariantError, apply_transforms

    path = Path(path)
    if not path.is_file():
        raise MetricInputError(path, "<file>", "an action-following manifest JSON", "no such file")
    try:
        raw = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        raise MetricInputError(path, "<file>", "JSON", f"invalid JSON ({exc})") from None
    if not isinstance(raw, dict) or raw.get("format") != FORMAT:
        found = raw.get("format") if isinstance(raw, dict) else type(raw).__name__
        raise MetricInputError(path, "format", repr(FORMAT), repr(found))
    if raw.get("version") != 1:
        raise MetricInputError(path, "version", "1", repr(raw.get("version")))
    rows = raw.get("sets")
    if not isinstance(rows, list) or not rows:
        raise MetricInputError(path, "sets", "a non-empty list of counterfactual sets", repr(rows)[:80])
    locator = raw.get("locator")
    if locator is not None and (not isinstance(locator, str) or ":" not in locator):
        raise MetricInputError(path, "locator", "module:attr", repr(locator))
    root = path.parent
    sets, seen = [], set()
    for i, row in enumerate(rows):
        where = f"sets[{i}]"
        if not isinstance(row, dict):
            raise MetricInputError(path, where, "an object", type(row).__name__)
        sid = _req(row, "set", where, path)
        if sid in seen:
            raise MetricInputError(path, f"{where}.set", "a unique id", f"{sid!r} twice")
        seen.add(sid)
        emb_name = _req(row, "embodiment", where, path)
        try:
            emb = get_embodiment(emb_name, plugin_paths)
        except (OscarError, KeyError, ValueError) as exc:
            raise MetricInputError(
                path, f"{where}.embodiment", "an installed embodiment", f"{emb_name!r}: {exc}"
            ) from None
        first = _file(root, _req(row, "first_frame", where, path), f"{where}.first_frame", path)
        camera = _file(root, _req(row, "camera", where, path), f"{where}.camera", path)
        traj_path = _file(root, _req(row, "trajectory", where, path), f"{where}.trajectory", path)
        embeds = row.get("prompt_embeds")
        embeds = _file(root, embeds, f"{where}.prompt_embeds", path) if embeds is not None else None
        info = row.get("info", {})
        if not isinstance(info, dict):
            raise MetricInputError(path, f"{where}.info", "an object", type(info).__name__)
        task = row.get("task", "")
        if not isinstance(task, str):
            raise MetricInputError(path, f"{where}.task", "a string", type(task).__name__)
        base = load_trajectory(traj_path)
        variants_raw = row.get("variants")
        if not isinstance(variants_raw, list) or len(variants_raw) < 2:
            raise MetricInputError(path, f"{where}.variants", "a list of at least 2 variants", repr(variants_raw)[:80])
        ik = EndEffectorIK(emb) if emb.uses_kinematic_tree() else None
        variants, names = [], set()
        for j, v in enumerate(variants_raw):
            vw = f"{where}.variants[{j}]"
            if not isinstance(v, dict):
                raise MetricInputError(path, vw, "an object", type(v).__name__)
            name = _req(v, "name", vw, path)
            if name in names:
                raise MetricInputError(path, f"{vw}.name", "a name unique in the set", f"{name!r} twice")
            names.add(name)
            outcome = v.get("outcome")
            if outcome not in (0, 1) or isinstance(outcome, bool):
                raise MetricInputError(path, f"{vw}.outcome", "the true outcome, 0 or 1", repr(outcome))
            transforms = v.get("transforms", [])
            if not isinstance(transforms, list):
                raise MetricInputError(path, f"{vw}.transforms", "a list", type(transforms).__name__)
            try:
                traj = apply_transforms(base, emb, transforms, ik=ik)
            except VariantError as exc:
                field_name, _, msg = str(exc).partition(": ")
                raise MetricInputError(path, f"{vw}.{field_name}", "a transform that applies", msg) from None
            video = v.get("video")
            video = _file(root, video, f"{vw}.video", path) if video is not None else None
            extra = {k: x for k, x in v.items() if k not in ("name", "transforms", "outcome", "video")}
            variants.append(Variant(name, transforms, int(outcome), video, traj, extra))
        if all(_same(variants[0].trajectory, x.trajectory) for x in variants[1:]):
            raise MetricInputError(
                path,
                f"{where}.variants",
                "variants that differ in at least one decision (gripper or path)",
                f"all {len(variants)} give the same trajectory",
            )
        sets.append(CounterfactualSet(sid, emb_name, first, camera, traj_path, task, embeds, info, variants, i))
    return ActionFollowingManifest(path, str(raw.get("description", "")), locator, sets, raw)


def _same(a, b) -> bool:
    return a.q.shape == b.q.shape and np.array_equal(a.q, b.q) and np.array_equal(a.gripper, b.gripper)
