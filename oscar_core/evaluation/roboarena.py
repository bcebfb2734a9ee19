"""A RoboArena evaluation dump → an ``oscar eval run`` study: manifest, real results, rejected sessions.

The dump's layout, as its dataset card documents it
(https://huggingface.co/datasets/RoboArena/DataDump_02-03-2026; docs/roboarena.md)::

    DUMP/
      global_metadata.yaml
      evaluation_sessions/<session>/
        metadata.yaml
        A_<policy>/ left_shoulder.mp4  right_shoulder.mp4  wrist.mp4  proprio_and_actions.npz
        B_<policy>/ ...
        C_<policy>/ ...          (sessions with more than two policies)

``metadata.yaml`` (fields as the RoboArena evaluation client records them): ``language_instruction``
(the task), ``preference`` (``A``, ``B`` or ``TIE``; the evaluator's A/B verdict) and ``policies``:
per letter ``policy_name``, ``binary_success`` (0/1) and ``partial_success`` (progress in [0, 1]).
``proprio_and_actions.npz`` is read with ``allow_pickle=False``: ``joint_position`` (T, J) radians and
``gripper_position`` (T,) or (T, 1), one row per control step at ``source_fps`` (15 Hz, the client's
control loop), optionally ``timestamps`` (T,) seconds. Object (pickled) arrays are never read.

:func:`convert_roboarena` writes into ``out``:

``manifest.json``
    An ``oscar eval run`` manifest: one session per evaluation session, one cell per policy episode
    (first frame of ``view``, the joint trajectory resampled to ``fps``, the instruction, the real binary
    success; partial progress in the cell's ``info``), and ``real_preferences`` (the A/B verdicts).
``real.json``
    Per policy: ``success_rate``, ``episodes`` (0/1), ``mean_partial`` and ``score`` (the real
    Bradley–Terry Elo, when the preferences rank the policies) — ``oscar eval policies --real`` reads it.
``real_board.json``
    The Bradley–Terry–Davidson board fitted to the real preferences (or why there is none).
``rejected.json``
    One row per session left out: ``{session, stage, reason}`` (``stage``: ``layout``, ``calibration`` or
    ``score``; ``score`` rows also hold the score).
``sessions/<session>/``
    ``<policy>_first.png``, ``<policy>.npz`` (at ``fps``), ``<policy>_source.npz`` (at the dump's rate,
    frame t = video frame t: what ``oscar calibrate score`` needs) and ``camera.json``.

Every file is written atomically; the folder's ``fingerprint.json`` records the inputs and settings, and a
re-run with the same ones rewrites the same files (a different one is refused: use another ``--out``).
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._util.atomic import atomic_output, atomic_write_bytes
from .._util.log import get_logger
from ..errors import OscarError
from ..policy.spaces import resample_joints  # kept importable from here: it was this module's before the fold
from .roboarena_read import NPZ_NAME, SOURCE_FPS, VIEWS, RoboArenaError, read_session

__all__ = [
    "CARD_URL",
    "SOURCE_FPS",
    "VIEWS",
    "RoboArenaError",
    "RoboArenaResult",
    "convert_roboarena",
    "resample_joints",
    "read_session",
]

_log = get_logger(__name__)

#: Where the dump's layout is documented.
CARD_URL = "https://huggingface.co/datasets/RoboArena/DataDump_02-03-2026"
#: Frame rate of the manifest's trajectories when neither ``fps`` nor a model card gives one.
DEFAULT_FPS = 16.0


@dataclass
class RoboArenaResult:
    """What :func:`convert_roboarena` wrote: ``accepted`` session names, ``rejected`` rows, output paths."""

    out: Path
    accepted: list[str] = field(default_factory=list)
    rejected: list[dict] = field(default_factory=list)
    policies: list[str] = field(default_factory=list)
    cells: int = 0
    preferences: int = 0
    fps: float = DEFAULT_FPS
    board_error: str | None = None
    paths: dict[str, Path] = field(default_factory=dict)

    def summary(self) -> str:
        """One line: sessions kept and left out (by stage), cells, preferences."""
        by_stage: dict[str, int] = {}
        for row in self.rejected:
            by_stage[row["stage"]] = by_stage.get(row["stage"], 0) + 1
        left = ", ".join(f"{n} {s}" for s, n in sorted(by_stage.items())) or "none"
        return (
            f"{len(self.accepted)} sessions kept ({self.cells} cells, {len(self.policies)} policies, "
            f"{self.preferences} A/B preferences); {len(self.rejected)} left out ({left}): "
            f"{self.paths.get('rejected', self.out / 'rejected.json')}"
        )


def _rel(path: Path, start: Path) -> str:
    return os.path.relpath(Path(path).resolve(), start.resolve())


def _write_json(path: Path, data) -> Path:
    return atomic_write_bytes(path, (json.dumps(data, indent=1) + "\n").encode())


def _write_png(path: Path, rgb: np.ndarray) -> None:
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise OscarError(f"{path}: could not encode the first frame as PNG")
    atomic_write_bytes(path, buf.tobytes())


def _save_traj(traj, path: Path) -> None:
    from ..trajectory import save_trajectory

    with atomic_output(path) as tmp:
        save_trajectory(traj, tmp)


def model_fps(model) -> float | None:
    """The frame rate a world model's card states (a folder's ``oscar_model.json`` or a zoo entry; nothing is
    downloaded or loaded), else None; an unknown name raises ``oscar_zoo.UnknownModelError``."""
    if model is None:
        return None
    import oscar_zoo

    got = oscar_zoo.resolve(model)
    if got.folder is None:
        return got.spec.fps if got.spec is not None else None
    f = got.folder / "oscar_model.json"
    if not f.is_file():
        return None
    try:
        return json.loads(f.read_text())["card"].get("fps")
    except (OSError, ValueError, KeyError, AttributeError):
        raise RoboArenaError(f, "card.fps", "an OSCAR model card (JSON)", "an unreadable file") from None


def _real_board(preferences: list[dict], policies: list[str]):
    import warnings

    from ..metrics.bradley_terry import BradleyTerryWarning, fit_bradley_terry
    from ..metrics.common import MetricInputError

    if not preferences:
        return None, "no A/B preference in the kept sessions"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BradleyTerryWarning)
        try:
            bt = fit_bradley_terry(preferences, policies=policies, source="real preferences")
        except MetricInputError as exc:
            return None, str(exc)
    return bt, bt.degenerate


def _session_folders(dump: Path, view: str, calibration, min_score) -> list[Path]:
    """The dump's session folders, sorted, with the options checked: :class:`RoboArenaError` for a folder that
    is not a RoboArena dump or holds no session, an unknown view, a missing calibration folder, or
    ``min_score`` without one."""
    root = dump / "evaluation_sessions"
    if not root.is_dir():
        found = "no such folder" if dump.is_dir() else "no such dump folder"
        raise RoboArenaError(
            dump,
            "evaluation_sessions",
            f"a RoboArena dump: global_metadata.yaml and evaluation_sessions/<session>/metadata.yaml ({CARD_URL})",
            found,
        )
    folders = sorted(p for p in root.iterdir() if p.is_dir())
    if not folders:
        raise RoboArenaError(root, "sessions", "at least one <session>/ folder", "none")
    if view not in VIEWS:
        raise RoboArenaError("--view", "view", f"one of {list(VIEWS)}", repr(view))
    if calibration is not None and not Path(calibration).is_dir():
        raise RoboArenaError(calibration, "--calibration", "a folder of <session>.json cameras", "no such folder")
    if min_score is not None and calibration is None:
        raise RoboArenaError("--min-score", "--calibration", "a calibration folder to score", "none")
    return folders


def _write_real_side(out: Path, cells: list[dict], prefs: list[dict], result: RoboArenaResult) -> None:
    """Writes ``real.json`` (per policy its real success rate, episodes, mean partial success and, with a
    Bradley-Terry board, its Elo) and ``real_board.json`` (the board fitted to the real preferences, or why
    there is none), recording the paths and the board's error in ``result``."""
    bt, board_error = _real_board(prefs, result.policies)
    result.board_error = board_error
    elo = bt.ranking_scores() if bt is not None else None
    real = {}
    for p in result.policies:
        eps = [c["real_success"] for c in cells if c["policy"] == p]
        parts = [c["info"]["real_partial"] for c in cells if c["policy"] == p]
        real[p] = {"success_rate": float(np.mean(eps)), "episodes": eps, "mean_partial": float(np.mean(parts))}
        if elo is not None:
            real[p]["score"] = elo[p]
    result.paths["real"] = _write_json(out / "real.json", real)
    result.paths["real_board"] = _write_json(
        out / "real_board.json",
        {"board": bt.to_dict() if bt is not None else None, "error": board_error, "preferences": prefs},
    )


def convert_roboarena(
    dump,
    out,
    *,
    view: str = "left_shoulder",
    fps: float | None = None,
    model=None,
    embodiment: str = "franka_robotiq",
    calibration=None,
    min_score: float | None = None,
    source_fps: float = SOURCE_FPS,
    size: str | None = None,
    plugin_paths=(),
) -> RoboArenaResult:
    """Turn a RoboArena dump into an ``oscar eval run`` study in ``out`` (module docstring).

    view: the camera of the first frames (``left_shoulder`` or ``right_shoulder``).
    fps: frame rate of the manifest's trajectories; default the card's of ``model`` (a zoo name or folder),
        else 16.
    embodiment: the installed embodiment the joints belong to (DROID's Franka with the Robotiq gripper).
    calibration: a folder with one camera JSON per session, ``<session>.json`` (docs/formats.md); without it
        every session is listed in ``rejected.json`` as without calibration.
    min_score: drop sessions whose calibration score (:func:`oscar_core.calibration.calibration_score` of the
        first episode's video, trajectory and camera) is below it, or undefined.
    source_fps: rows per second of the npz files when they carry no ``timestamps``.
    size: the manifest's rollout size ``"WIDTHxHEIGHT"`` (multiples of 16); default: left to ``eval run`` (the
        model card's size, else the camera's).

    A dump that is not a RoboArena dump raises :class:`RoboArenaError` before anything is written; a bad
    session is a row of ``rejected.json`` and the others go on.
    """
    from .._util.stage import check_stage
    from ..plugin.registry import get_embodiment

    dump, out = Path(dump), Path(out)
    folders = _session_folders(dump, view, calibration, min_score)
    fps = float(fps) if fps is not None else float(model_fps(model) or DEFAULT_FPS)
    if not (np.isfinite(fps) and fps > 0):
        raise RoboArenaError("--fps", "fps", "a positive frame rate", repr(fps))
    if size is not None:
        from .manifest import _size

        _size(size, "--size")
    emb = get_embodiment(embodiment, plugin_paths)
    J, G = len(emb.joint_names), len(emb.grippers)
    gripper_names = tuple(g.name for g in emb.grippers)

    check_stage(
        out,
        {
            "dump": str(dump.resolve()),
            "view": view,
            "fps": fps,
            "embodiment": embodiment,
            "calibration": None if calibration is None else str(Path(calibration).resolve()),
            "min_score": min_score,
            "source_fps": source_fps,
            "size": size,
            "format": 1,
        },
        redo="use another --out (or delete it)",
    )
    result = RoboArenaResult(out=out, fps=fps)
    cells, prefs, scores = [], [], {}
    for folder in folders:
        reject = _convert_session(
            folder, out, view, fps, emb, J, G, gripper_names, calibration, min_score, source_fps, cells, prefs, scores
        )
        if reject is None:
            result.accepted.append(folder.name)
        else:
            result.rejected.append({"session": folder.name, **reject})
            _log.info("session %s left out (%s): %s", folder.name, reject["stage"], reject["reason"])
    result.policies = sorted({c["policy"] for c in cells})
    result.cells, result.preferences = len(cells), len(prefs)
    result.paths["rejected"] = _write_json(out / "rejected.json", result.rejected)
    result.paths["sessions"] = _write_json(
        out / "sessions.json",
        {"kept": result.accepted, "calibration_scores": scores, "fps": fps, "view": view, "dump": str(dump)},
    )
    if not cells:
        return result
    _write_real_side(out, cells, prefs, result)
    manifest = {
        "format": "oscar-eval-manifest",
        "description": f"RoboArena dump {dump.name}: {len(result.accepted)} sessions, view {view}, {fps:g} fps",
        "policies": result.policies,
        "defaults": {"embodiment": embodiment, **({"size": size} if size else {})},
        "cells": cells,
    }
    if prefs:
        manifest["real_preferences"] = prefs
    result.paths["manifest"] = _write_json(out / "manifest.json", manifest)
    return result


def _episode_frames_and_trajectories(session, emb, fps: float, source_fps: float, gripper_names):
    """``(firsts, trajectories)`` per episode letter: its first (H, W, 3) uint8 frame and ``(source, resampled)``
    trajectories (joints in radians, gripper in [0, 1]; the source at its own times, the other at ``fps``).
    Raises an OscarError, OSError or ValueError for an episode that cannot be read."""
    from ..media.video import read_video
    from ..trajectory import Trajectory

    J = len(emb.joint_names)
    firsts, trajs = {}, {}
    for ep in session.episodes:
        first = read_video(ep.video, max_frames=1)
        if len(first) == 0:
            raise RoboArenaError(ep.video, "frames", "at least one frame", "none")
        firsts[ep.letter] = first[0]
        src = Trajectory(
            emb.joint_names,
            ep.q,
            source_fps,
            gripper=ep.gripper,
            gripper_names=gripper_names or None,
            timestamps=ep.times,
            source=str(ep.folder / NPZ_NAME),
        )
        src = emb.check_trajectory(src)
        q, at = resample_joints(np.concatenate([ep.q, ep.gripper], axis=1), ep.times, fps)
        res = Trajectory(
            emb.joint_names,
            q[:, :J],
            fps,
            gripper=q[:, J:],
            gripper_names=gripper_names or None,
            timestamps=at,
            source=str(ep.folder / NPZ_NAME),
        )
        trajs[ep.letter] = (src, res)
    return firsts, trajs


def _write_session(out: Path, name: str, session, cam_path: Path, firsts, trajs, cells: list, prefs: list) -> None:
    """Writes a kept session's files under ``out/sessions/<name>/`` (camera, first frames, source and resampled
    trajectories) and appends its cells and its preference (if any) to ``cells`` and ``prefs``."""
    sdir = out / "sessions" / name
    sdir.mkdir(parents=True, exist_ok=True)
    with atomic_output(sdir / "camera.json") as tmp:
        shutil.copyfile(cam_path, tmp)
    for ep in session.episodes:
        _write_png(sdir / f"{ep.policy}_first.png", firsts[ep.letter])
        src, res = trajs[ep.letter]
        _save_traj(src, sdir / f"{ep.policy}_source.npz")
        _save_traj(res, sdir / f"{ep.policy}.npz")
        cells.append(
            {
                "session": name,
                "policy": ep.policy,
                "task": session.task,
                "first_frame": f"sessions/{name}/{ep.policy}_first.png",
                "trajectory": f"sessions/{name}/{ep.policy}.npz",
                "camera": f"sessions/{name}/camera.json",
                "real_success": ep.binary_success,
                "real_video": _rel(ep.video, out),
                "info": {"real_partial": ep.partial_success, "letter": ep.letter},
            }
        )
    if session.preference is not None:
        by = {e.letter: e.policy for e in session.episodes}
        winner = {"A": "a", "B": "b", "TIE": "tie"}[session.preference]
        prefs.append({"session": name, "a": by["A"], "b": by["B"], "winner": winner})


def _convert_session(
    folder, out, view, fps, emb, J, G, gripper_names, calibration, min_score, source_fps, cells, prefs, scores
) -> dict | None:
    """Write one session's files and append its cells and preference; a dict ``{stage, reason}`` if left out."""
    from ..camera.file import load_camera

    name = folder.name
    try:
        session = read_session(folder, view=view, joints=J, grippers=G, source_fps=source_fps)
    except OscarError as exc:
        return {"stage": "layout", "reason": str(exc)}
    try:
        firsts, trajs = _episode_frames_and_trajectories(session, emb, fps, source_fps, gripper_names)
    except (OscarError, OSError, ValueError) as exc:
        return {"stage": "layout", "reason": str(exc).splitlines()[0]}
    if calibration is None:
        return {"stage": "calibration", "reason": "no calibration (pass --calibration DIR with DIR/<session>.json)"}
    cam_path = Path(calibration) / f"{name}.json"
    if not cam_path.is_file():
        return {"stage": "calibration", "reason": f"no calibration: {cam_path} does not exist"}
    try:
        camera = load_camera(cam_path)
        emb.check_camera(camera, str(cam_path))
        size = (camera.intrinsics.width, camera.intrinsics.height)
        for ep in session.episodes:
            h, w = firsts[ep.letter].shape[:2]
            if (w, h) != size:
                raise RoboArenaError(
                    cam_path, "intrinsics.width/height", f"the {view} video's size {w}x{h} ({ep.video})", size
                )
    except (OscarError, OSError, ValueError) as exc:
        return {"stage": "calibration", "reason": str(exc).splitlines()[0]}
    if min_score is not None:
        from ..calibration.score import calibration_score

        ep = session.episodes[0]
        try:
            sc = calibration_score(ep.video, emb, trajs[ep.letter][0], camera, camera_source=str(cam_path)).score
        except (OscarError, OSError, ValueError) as exc:
            return {"stage": "score", "reason": f"no calibration score: {str(exc).splitlines()[0]}", "score": None}
        scores[name] = None if not np.isfinite(sc) else sc
        if not (np.isfinite(sc) and sc >= min_score):
            shown = "undefined (the robot does not move)" if not np.isfinite(sc) else f"{sc:.3f}"
            return {
                "stage": "score",
                "reason": f"calibration score {shown} below --min-score {min_score:g} ({ep.video.name}, {cam_path})",
                "score": scores[name],
            }
    _write_session(out, name, session, cam_path, firsts, trajs, cells, prefs)
    return None
