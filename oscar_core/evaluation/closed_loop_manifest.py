"""The closed-loop manifest: sessions (a first frame, a camera, a robot state, a task, a horizon) × policies.

One JSON file::

    {"format": "oscar-closed-loop-manifest",
     "policies": [{"name": "pi05_droid", "policy": "ws://127.0.0.1:8000", "action_space": "joint_velocity",
                   "control_hz": 15, "image_size": [224, 224], "actions_per_call": 8, "gripper": "position"}],
     "defaults": {"embodiment": "franka", "camera": "cams/ext1.json", "size": "512x288", "horizon": 121},
     "sessions": [
       {"session": "kitchen-01", "task": "put the marker in the cup", "first_frame": "kitchen-01/first.png",
        "initial_state": "kitchen-01/state.npz"}]}

``policies``: one object per policy (:meth:`~oscar_core.policy.protocol.PolicySpec.from_dict`: ``name``,
``policy`` and the declarations the protocol cannot carry; DROID's values by default). A session has
``session`` (a name), ``task`` (the instruction, sent as the prompt), ``embodiment``, ``first_frame`` (PNG/JPEG
taken by ``camera``), ``camera`` (calibration ``.json``), ``initial_state`` (a trajectory ``.npz``: its frame 0
is the robot's joint positions and gripper signals at the first frame) and ``horizon`` (frames of the
episode at the model's frame rate, the first frame included), and optionally ``prompt_embeds`` (the model's
text embedding ``.safetensors``), ``seed`` (default 0), ``info`` (handed to programmatic judges),
``extras`` (an object added as it is to every observation sent to the policies, e.g. a camera matrix a toy
policy needs), ``simulator`` (a file a simulator world reads, e.g. the toy world's state) and ``real_success``
(``{policy name: 0 or 1}``, the real outcome of that policy from this session, where known: the report then
compares the world model's ranking with the real one). Any session key
may be set once in ``defaults``; ``size`` (``WIDTHxHEIGHT``, multiples of 16, in ``defaults`` only) is the
rollout size (default: the model card's). Relative paths — a policy's ``file.py:attr`` too — are relative to
the manifest's folder; every check
runs before any work and an error names the session and the field.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

from ..policy.loading import resolve_policy_source
from ..policy.protocol import PolicySpec, PolicySpecError
from .manifest import _NAME, ManifestError, _size, resolve_paths

__all__ = ["FORMAT", "Session", "ClosedLoopManifest", "load_closed_loop_manifest"]

FORMAT = "oscar-closed-loop-manifest"
SESSION_KEYS = (
    "session",
    "task",
    "embodiment",
    "first_frame",
    "camera",
    "initial_state",
    "horizon",
    "prompt_embeds",
    "seed",
    "info",
    "extras",
    "simulator",
    "real_success",
)
REQUIRED = ("session", "task", "embodiment", "first_frame", "camera", "initial_state", "horizon")
PATH_KEYS = ("first_frame", "camera", "initial_state", "prompt_embeds", "simulator")
TOP_KEYS = ("format", "policies", "defaults", "sessions", "description")


@dataclass(frozen=True)
class Session:
    """One closed-loop session; paths absolute; ``horizon`` in frames at the model's rate (first frame included)."""

    session: str
    task: str
    embodiment: str
    first_frame: Path
    camera: Path
    initial_state: Path
    horizon: int
    row: int
    prompt_embeds: Path | None = None
    seed: int = 0
    info: dict = field(default_factory=dict, compare=False)
    extras: dict = field(default_factory=dict, compare=False)
    simulator: Path | None = None
    real_success: dict = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class ClosedLoopManifest:
    path: Path
    policies: tuple[PolicySpec, ...]
    sessions: tuple[Session, ...]
    size: tuple[int, int] | None = None

    def policy(self, name: str) -> PolicySpec:
        return next(p for p in self.policies if p.name == name)


def load_closed_loop_manifest(path) -> ClosedLoopManifest:
    """Read and check a closed-loop manifest (module docstring); raises :class:`ManifestError`."""
    path = Path(path).resolve()
    if not path.is_file():
        raise ManifestError(path, "file", "an existing closed-loop manifest JSON file", "no such file")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ManifestError(path, "text", "valid JSON", str(exc)) from None
    if not isinstance(data, dict):
        raise ManifestError(path, "top level", "a JSON object with 'policies' and 'sessions'", type(data).__name__)
    extra = sorted(k for k in data if k not in TOP_KEYS)
    if extra:
        raise ManifestError(path, "top level", f"only the keys {list(TOP_KEYS)}", f"unknown keys {extra}")
    if data.get("format") != FORMAT:
        raise ManifestError(path, "format", repr(FORMAT), repr(data.get("format")))
    raw_policies = data.get("policies")
    if not isinstance(raw_policies, list) or not raw_policies:
        raise ManifestError(path, "policies", "a non-empty list of policy objects", repr(raw_policies)[:80])
    policies = []
    for k, raw in enumerate(raw_policies):
        try:
            spec = PolicySpec.from_dict(raw, source=f"{path}: policies[{k}]")
            policies.append(dataclasses.replace(spec, source=resolve_policy_source(spec.source, path.parent)))
        except PolicySpecError as exc:
            raise ManifestError(f"{path}: policies[{k}]", "policy", "a valid policy declaration", str(exc)) from None
    names = [p.name for p in policies]
    if len(set(names)) != len(names):
        raise ManifestError(
            path, "policies", "unique names", f"duplicates {sorted({n for n in names if names.count(n) > 1})}"
        )
    defaults = data.get("defaults", {})
    if not isinstance(defaults, dict):
        raise ManifestError(path, "defaults", "an object of session keys", type(defaults).__name__)
    bad = sorted(k for k in defaults if k not in SESSION_KEYS + ("size",) or k == "session")
    if bad:
        raise ManifestError(path, "defaults", "session keys other than session, or size", f"keys {bad}")
    size = _size(defaults["size"], str(path)) if "size" in defaults else None
    rows = data.get("sessions")
    if not isinstance(rows, list) or not rows:
        raise ManifestError(path, "sessions", "a non-empty list of sessions", repr(rows)[:80])
    sessions, seen = [], set()
    for k, raw in enumerate(rows):
        s = _session(path, k, raw, defaults)
        if s.session in seen:
            raise ManifestError(f"{path}: sessions[{k}]", "session", "unique session names", f"{s.session!r} again")
        seen.add(s.session)
        sessions.append(s)
        unknown_policies = sorted(set(s.real_success) - set(names))
        if unknown_policies:
            raise ManifestError(
                f"{path}: sessions[{k}] ({s.session!r})",
                "real_success",
                f"policy names among {names}",
                unknown_policies,
            )
    return ClosedLoopManifest(path, tuple(policies), tuple(sessions), size)


def _session(path: Path, k: int, raw, defaults: dict) -> Session:
    row = f"{path}: sessions[{k}]" + (f" ({raw.get('session')!r})" if isinstance(raw, dict) else "")
    if not isinstance(raw, dict):
        raise ManifestError(row, "session", "an object", type(raw).__name__)
    unknown = sorted(key for key in raw if key not in SESSION_KEYS)
    if unknown:
        raise ManifestError(row, "keys", f"session keys among {list(SESSION_KEYS)}", f"unknown keys {unknown}")
    merged = {**{key: v for key, v in defaults.items() if key != "size"}, **raw}
    missing = [key for key in REQUIRED if key not in merged]
    if missing:
        raise ManifestError(row, missing[0], "a value (in the session or in 'defaults')", "none")
    for key in ("session", "task", "embodiment"):
        if not isinstance(merged[key], str) or not merged[key].strip():
            raise ManifestError(row, key, "a non-empty string", repr(merged[key]))
    if not _NAME.match(merged["session"]):
        raise ManifestError(row, "session", "a name of letters, digits, '.', '_' or '-'", repr(merged["session"]))
    horizon = merged["horizon"]
    if isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 2:
        raise ManifestError(row, "horizon", "an integer >= 2 (frames, the first included)", repr(horizon))
    seed = merged.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ManifestError(row, "seed", "an integer >= 0", repr(seed))
    for key in ("info", "extras"):
        if not isinstance(merged.get(key, {}), dict):
            raise ManifestError(row, key, "an object", type(merged[key]).__name__)
    real = merged.get("real_success", {})
    if not isinstance(real, dict) or any(isinstance(v, (bool, float)) or v not in (0, 1) for v in real.values()):
        raise ManifestError(row, "real_success", "an object {policy name: 0 or 1}", repr(real)[:80])
    paths = resolve_paths(path, row, merged, PATH_KEYS)
    return Session(
        session=merged["session"],
        task=merged["task"].strip(),
        embodiment=merged["embodiment"],
        first_frame=paths["first_frame"],
        camera=paths["camera"],
        initial_state=paths["initial_state"],
        horizon=horizon,
        row=k,
        prompt_embeds=paths["prompt_embeds"],
        seed=seed,
        info=dict(merged.get("info", {})),
        extras=dict(merged.get("extras", {})),
        simulator=paths["simulator"],
        real_success={str(k): int(v) for k, v in real.items()},
    )
