"""Reading a RoboArena evaluation dump, one session at a time: its task, its policy episodes (joint paths at their
control times, the real binary and partial success) and the A/B preference, each field checked as the dataset card
documents it (module :mod:`.roboarena` turns the sessions into an ``oscar eval run`` study).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputFileError

__all__ = ["SOURCE_FPS", "VIEWS", "NPZ_NAME", "RoboArenaError", "Episode", "Session", "read_session"]

#: Control steps per second of the RoboArena evaluation client (its loop sleeps to 1/15 s), = rows of the npz.
SOURCE_FPS = 15.0
#: The static (third-person) camera views of an episode; the wrist camera moves and has no fixed calibration.
VIEWS = ("left_shoulder", "right_shoulder")
NPZ_NAME = "proprio_and_actions.npz"
_NAME = re.compile(r"\A[A-Za-z0-9][A-Za-z0-9._-]*\Z")
_EPISODE = re.compile(r"\A([A-Z])_(.+)\Z")


class RoboArenaError(InputFileError):
    """The dump (or a file of one session) is not what the card describes; names file, field, expected, found."""


@dataclass(frozen=True)
class Episode:
    """One policy episode of a session: ``q`` (T, J) radians, ``gripper`` (T, G), at ``times`` (T,) seconds."""

    letter: str
    policy: str
    folder: Path
    video: Path
    binary_success: int
    partial_success: float
    q: np.ndarray
    gripper: np.ndarray
    times: np.ndarray


@dataclass(frozen=True)
class Session:
    """One evaluation session: its task, its episodes (letter order) and the A/B preference (or None)."""

    name: str
    folder: Path
    task: str
    episodes: tuple[Episode, ...]
    preference: str | None


# --------------------------------------------------------------------------- reading one session


def _yaml(path: Path):
    import yaml

    from .._util.inputs import read_text_file

    text = read_text_file(path, "a RoboArena session metadata.yaml (utf-8 text)", error=RoboArenaError, field="file")
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise RoboArenaError(path, "file", "valid YAML", f"{getattr(exc, 'problem', None) or exc}{where}") from None


def _binary(value, path: Path, fld: str) -> int:
    if isinstance(value, str) and value.strip() in ("0", "1"):
        value = int(value.strip())
    if isinstance(value, bool):
        value = int(value)
    if not isinstance(value, (int, np.integer)) or value not in (0, 1):
        raise RoboArenaError(path, fld, "0 or 1", repr(value))
    return int(value)


def _partial(value, path: Path, fld: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise RoboArenaError(path, fld, "a number in [0, 1] (task progress)", repr(value)) from None
    if isinstance(value, bool) or not (0.0 <= v <= 1.0):
        raise RoboArenaError(path, fld, "a number in [0, 1] (task progress)", repr(value))
    return v


def _proprio(path: Path, joints: int, grippers: int, source_fps: float):
    """(q (T, joints), gripper (T, grippers), times (T,)) of one ``proprio_and_actions.npz``."""
    if not path.is_file():
        raise RoboArenaError(path, "file", f"the episode's {NPZ_NAME}", "no such file")
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise RoboArenaError(path, "file", "a NumPy .npz archive", str(exc).splitlines()[0]) from None
    with data:
        try:
            arrays = {k: data[k] for k in data.files}
        except ValueError as exc:  # object arrays need pickle: never read
            raise RoboArenaError(
                path, "file", "numeric arrays (read without pickle)", f"object arrays ({exc})".splitlines()[0]
            ) from None
    for key in ("joint_position", "gripper_position"):
        if key not in arrays:
            raise RoboArenaError(path, key, "an array (see docs/roboarena.md)", f"no such key; keys {sorted(arrays)}")
    q = np.asarray(arrays["joint_position"])
    if q.ndim != 2 or q.shape[1] != joints or len(q) < 1 or q.dtype.kind not in "fiu":
        raise RoboArenaError(path, "joint_position", f"numbers of shape (T, {joints})", f"{q.dtype} {q.shape}")
    g = np.asarray(arrays["gripper_position"])
    if g.ndim == 1:
        g = g[:, None]
    if g.ndim != 2 or g.shape != (len(q), 1) or g.dtype.kind not in "fiu":
        raise RoboArenaError(path, "gripper_position", f"numbers of shape ({len(q)},) or ({len(q)}, 1)", f"{g.shape}")
    if grippers == 0:
        g = g[:, :0]
    elif grippers != 1:
        raise RoboArenaError(path, "gripper_position", "an embodiment with one gripper", f"{grippers} grippers")
    for key, a in (("joint_position", q), ("gripper_position", g)):
        if not np.isfinite(a).all():
            t = int(np.argwhere(~np.isfinite(a))[0][0])
            raise RoboArenaError(path, key, "finite values", f"{a[t].tolist()} at step {t}")
    if "timestamps" in arrays:
        times = np.asarray(arrays["timestamps"], dtype=np.float64).reshape(-1)
        if times.shape != (len(q),) or not np.isfinite(times).all() or np.any(np.diff(times) <= 0):
            raise RoboArenaError(path, "timestamps", f"({len(q)},) increasing seconds", f"shape {times.shape}")
    else:
        times = np.arange(len(q)) / float(source_fps)
    return q.astype(np.float64), g.astype(np.float64), times


def read_session(folder, *, view: str, joints: int, grippers: int, source_fps: float = SOURCE_FPS) -> Session:
    """Read and check one ``evaluation_sessions/<session>`` folder; :class:`RoboArenaError` says what is wrong.

    joints / grippers: the embodiment's joint count J and gripper count (0 or 1).
    """
    folder = Path(folder)
    name = folder.name
    if not _NAME.match(name):
        raise RoboArenaError(folder, "session", "a name of letters, digits, '.', '_' or '-'", repr(name))
    meta_path = folder / "metadata.yaml"
    if not meta_path.is_file():
        raise RoboArenaError(meta_path, "file", "the session's metadata.yaml", "no such file")
    meta = _yaml(meta_path)
    if not isinstance(meta, dict):
        raise RoboArenaError(meta_path, "top level", "a mapping", type(meta).__name__)
    task = meta.get("language_instruction")
    if not isinstance(task, str) or not task.strip():
        raise RoboArenaError(meta_path, "language_instruction", "a non-empty instruction", repr(task))
    pols = meta.get("policies")
    if not isinstance(pols, dict) or not pols:
        raise RoboArenaError(meta_path, "policies", "a mapping of letter -> policy outcome", repr(pols)[:80])
    dirs = {}
    for d in sorted(p for p in folder.iterdir() if p.is_dir()):
        m = _EPISODE.match(d.name)
        if m:
            dirs.setdefault(m.group(1), d)
    episodes = []
    for letter in sorted(pols, key=str):
        entry, where = pols[letter], f"policies.{letter}"
        if not isinstance(entry, dict):
            raise RoboArenaError(meta_path, where, "a mapping with binary_success and partial_success", repr(entry))
        d = dirs.get(str(letter))
        if d is None:
            raise RoboArenaError(folder, f"{letter}_<policy>", f"the episode folder of policy {letter}", "none")
        policy = entry.get("policy_name", _EPISODE.match(d.name).group(2))
        if not isinstance(policy, str) or not _NAME.match(policy):
            raise RoboArenaError(meta_path, f"{where}.policy_name", "a policy name (letters, digits, . _ -)", policy)
        binary = _binary(entry.get("binary_success"), meta_path, f"{where}.binary_success")
        partial = _partial(entry.get("partial_success"), meta_path, f"{where}.partial_success")
        video = d / f"{view}.mp4"
        if not video.is_file():
            raise RoboArenaError(video, "file", f"the {view} video of policy {letter}", "no such file")
        q, g, times = _proprio(d / NPZ_NAME, joints, grippers, source_fps)
        episodes.append(Episode(str(letter), policy, d, video, binary, partial, q, g, times))
    if len(episodes) < 2:
        raise RoboArenaError(meta_path, "policies", "at least two policy episodes (an A/B session)", len(episodes))
    names = [e.policy for e in episodes]
    if len(set(names)) != len(names):
        raise RoboArenaError(meta_path, "policies", "distinct policies", f"{names}")
    pref = meta.get("preference")
    if pref is not None:
        key = str(pref).strip().upper()
        if key not in ("A", "B", "TIE"):
            raise RoboArenaError(meta_path, "preference", "A, B, TIE or null", repr(pref))
        if not {"A", "B"} <= {e.letter for e in episodes}:
            raise RoboArenaError(meta_path, "policies", "episodes A and B (the preference compares them)", names)
        pref = key
    return Session(name, folder, task.strip(), tuple(episodes), pref)


# --------------------------------------------------------------------------- writing
