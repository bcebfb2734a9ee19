"""MANO parameters → 21 keypoints per hand, through ``smplx.MANO``.

This path needs the optional dependency smplx (``pip install "oscar-wm[mano]"``)
and the licensed MANO model files ``MANO_RIGHT.pkl`` / ``MANO_LEFT.pkl``,
which oscar never ships: download them from https://mano.is.tue.mpg.de and
point ``model_dir=`` or the ``OSCAR_MANO_DIR`` environment variable at their
folder. The files are read by :func:`.mano_pickle.load_mano_pickle` (no
chumpy, no code from the pickle) and the arrays are handed to ``smplx.MANO``
through its ``data_struct`` argument, so smplx never opens the pickle itself.

smplx.MANO returns 16 joints (wrist and three per finger); the fingertips
are the mesh vertices of :data:`.topology.FINGERTIP_VERTICES`, and
:data:`.topology.MANO_TO_KEYPOINTS` puts the 21 points in keypoint order.
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from oscar_core.trajectory import Trajectory

from .convert import trajectory_from_keypoints
from .mano_pickle import MANOModelError, load_mano_pickle
from .topology import FINGERTIP_VERTICES, HANDS, MANO_TO_KEYPOINTS, NUM_KEYPOINTS

__all__ = [
    "SMPLX_MISSING",
    "ENV_MANO_DIR",
    "smplx_problem",
    "require_smplx",
    "model_path",
    "mano_keypoints",
    "trajectory_from_mano",
]

#: The one message of the ImportError raised when smplx is needed but missing.
SMPLX_MISSING = (
    "the MANO-parameter path of the mano embodiment needs the optional dependency smplx, "
    'which is not installed; install it with: pip install "oscar-wm[mano]"'
)
ENV_MANO_DIR = "OSCAR_MANO_DIR"
_FILES = {"right": "MANO_RIGHT.pkl", "left": "MANO_LEFT.pkl"}
_CHUNK = 2048  # frames per smplx forward pass


def smplx_problem() -> str | None:
    """None when smplx can be imported, else what is missing and how to get it.

    The one place that decides whether the optional dependency is there; it
    looks the module up without importing it (cheap enough for listings).
    """
    try:
        found = importlib.util.find_spec("smplx") is not None
    except (ImportError, ValueError):
        found = False
    return None if found else SMPLX_MISSING


def require_smplx():
    """Import and return smplx, or raise ImportError(:data:`SMPLX_MISSING`)."""
    if smplx_problem() is not None:
        raise ImportError(SMPLX_MISSING, name="smplx")
    try:
        return importlib.import_module("smplx")
    except ImportError as exc:
        raise ImportError(SMPLX_MISSING, name="smplx") from exc


def model_path(hand: str, model_dir=None) -> Path:
    """Path of ``MANO_RIGHT.pkl`` / ``MANO_LEFT.pkl`` in ``model_dir`` or ``$OSCAR_MANO_DIR``."""
    folder = model_dir if model_dir is not None else os.environ.get(ENV_MANO_DIR)
    if not folder:
        raise MANOModelError(
            _FILES[hand],
            "<file>",
            f"a folder with the licensed MANO model files (pass model_dir= or set {ENV_MANO_DIR}; "
            "download them from https://mano.is.tue.mpg.de)",
            "no folder given",
        )
    path = Path(folder).expanduser() / _FILES[hand]
    if not path.is_file():
        raise MANOModelError(
            str(path),
            "<file>",
            f"the licensed MANO model file {_FILES[hand]} (download it from https://mano.is.tue.mpg.de)",
            "no such file",
        )
    return path


@functools.lru_cache(maxsize=4)
def _layer(path: str, mtime: float, hand: str, flat_hand_mean: bool, fix_left_shapedirs: bool):
    smplx = require_smplx()
    import torch
    from smplx.utils import Struct

    model = load_mano_pickle(path)
    layer = smplx.MANO(
        model_path=path,
        is_rhand=(hand == "right"),
        data_struct=Struct(**model),
        use_pca=False,
        flat_hand_mean=flat_hand_mean,
        num_betas=model["shapedirs"].shape[-1],
        dtype=torch.float64,
    )
    if fix_left_shapedirs and hand == "left":
        with torch.no_grad():
            layer.shapedirs[:, 0, :] *= -1
    layer.eval()
    return layer, np.asarray(model["hands_components"], dtype=np.float64)


def _frames(x, T: int, width: int, name: str, hand: str, default: float = 0.0) -> np.ndarray:
    if x is None:
        return np.full((T, width), default)
    a = np.asarray(x, dtype=np.float64)
    if a.shape == (width,):
        a = np.broadcast_to(a, (T, width))
    if a.shape != (T, width):
        raise ValueError(
            f"mano params[{hand!r}][{name!r}]: expected shape ({T}, {width}) or ({width},), found {a.shape}"
        )
    return a


def _hand_keypoints(
    p: Mapping, hand: str, model_dir, hand_pose_space: str, flat_hand_mean: bool, fix_left_shapedirs: bool
) -> np.ndarray:
    import torch

    go = np.asarray(p["global_orient"], dtype=np.float64)
    if go.ndim != 2 or go.shape[1] != 3:
        raise ValueError(f"mano params[{hand!r}]['global_orient']: expected shape (T, 3) axis-angle, found {go.shape}")
    T = go.shape[0]
    pose = np.asarray(p["hand_pose"], dtype=np.float64)
    if pose.ndim != 2 or pose.shape[0] != T:
        raise ValueError(
            f"mano params[{hand!r}]['hand_pose']: expected shape ({T}, 45) axis-angle or ({T}, n) PCA, "
            f"found {pose.shape}"
        )
    path = model_path(hand, model_dir)
    layer, components = _layer(str(path), path.stat().st_mtime, hand, flat_hand_mean, fix_left_shapedirs)
    space = hand_pose_space if hand_pose_space != "auto" else ("axis_angle" if pose.shape[1] == 45 else "pca")
    if space == "pca":
        if not 1 <= pose.shape[1] <= components.shape[0]:
            raise ValueError(
                f"mano params[{hand!r}]['hand_pose']: expected 1..{components.shape[0]} PCA coefficients, "
                f"found {pose.shape[1]}"
            )
        pose = pose @ components[: pose.shape[1]]
    elif space != "axis_angle" or pose.shape[1] != 45:
        raise ValueError(
            f"mano params[{hand!r}]['hand_pose']: expected 45 axis-angle values (hand_pose_space="
            f"'axis_angle') or PCA coefficients ('pca'), found {pose.shape[1]} values with {hand_pose_space!r}"
        )
    B = layer.num_betas
    betas = np.asarray(p.get("betas", np.zeros(B)), dtype=np.float64)
    if betas.shape[-1] > B:
        raise ValueError(
            f"mano params[{hand!r}]['betas']: the model has {B} shape coefficients, found {betas.shape[-1]}"
        )
    betas = np.concatenate([betas, np.zeros(betas.shape[:-1] + (B - betas.shape[-1],))], axis=-1)
    betas = _frames(betas, T, B, "betas", hand)
    transl = _frames(p.get("transl"), T, 3, "transl", hand)
    valid = np.ones(T, dtype=bool) if p.get("valid") is None else np.asarray(p["valid"], dtype=bool).reshape(T)
    inputs = [go, pose, betas, transl]
    valid &= np.all([np.isfinite(a).all(axis=1) for a in inputs], axis=0)
    inputs = [np.where(valid[:, None], a, 0.0) for a in inputs]
    out = np.full((T, NUM_KEYPOINTS, 3), np.nan)
    tips = list(FINGERTIP_VERTICES.values())
    with torch.no_grad():
        for s in range(0, T, _CHUNK):
            g, hp, b, tr = (torch.from_numpy(np.ascontiguousarray(a[s : s + _CHUNK])) for a in inputs)
            res = layer(global_orient=g, hand_pose=hp, betas=b, transl=tr)
            joints = torch.cat([res.joints, res.vertices[:, tips]], dim=1)  # (n, 21, 3): 16 joints + 5 tips
            out[s : s + _CHUNK] = joints[:, list(MANO_TO_KEYPOINTS)].numpy()
    out[~valid] = np.nan
    return out


def mano_keypoints(
    params: Mapping,
    model_dir=None,
    *,
    hand_pose_space: str = "auto",
    flat_hand_mean: bool = False,
    fix_left_shapedirs: bool = False,
) -> np.ndarray:
    """MANO parameters of both hands → keypoints (T, 2, 21, 3), metres, in the parameters' frame.

    params: {"left": {...}, "right": {...}}; a hand may be absent or None
    (its keypoints are NaN). Per hand:

    ``global_orient`` (T, 3) axis-angle of the wrist; ``hand_pose`` (T, 45)
    axis-angle of the 15 finger joints, or (T, n) PCA coefficients;
    ``betas`` (10,) or (T, 10) shape (optional, default 0); ``transl`` (T, 3)
    metres (optional, default 0); ``valid`` (T,) bool (optional): frames
    where the hand was not seen. Frames with non-finite inputs are missing too.

    hand_pose_space: "auto" (45 values → axis-angle, fewer → PCA), "axis_angle"
        or "pca" (needed for 45 PCA coefficients).
    flat_hand_mean: False (smplx's default and MANO's convention) adds the
        model's mean hand pose to ``hand_pose``; True when the dataset's poses
        are absolute (zero = flat hand).
    fix_left_shapedirs: flip the x component of the left model's shape blend
        shapes (a known defect of MANO_LEFT.pkl, smplx issue #48); leave it off
        to reproduce fits made with the files as published.
    """
    require_smplx()
    unknown = sorted(set(params) - set(HANDS))
    if unknown:
        raise ValueError(f"mano params: expected the keys 'left' and/or 'right', found {unknown}")
    given = {h: params[h] for h in HANDS if params.get(h) is not None}
    if not given:
        raise ValueError("mano params: expected parameters for at least one hand ('left', 'right')")
    per_hand = {
        h: _hand_keypoints(p, h, model_dir, hand_pose_space, flat_hand_mean, fix_left_shapedirs)
        for h, p in given.items()
    }
    lengths = {h: len(k) for h, k in per_hand.items()}
    if len(set(lengths.values())) != 1:
        raise ValueError(f"mano params: both hands need the same number of frames, found {lengths}")
    T = next(iter(lengths.values()))
    out = np.full((T, 2, NUM_KEYPOINTS, 3), np.nan)
    for h, k in per_hand.items():
        out[:, HANDS.index(h)] = k
    return out


def trajectory_from_mano(
    params: Mapping,
    fps: float,
    model_dir=None,
    *,
    camera_poses=None,
    camera_convention: str = "opencv",
    hand_pose_space: str = "auto",
    flat_hand_mean: bool = False,
    fix_left_shapedirs: bool = False,
    timestamps=None,
    source: str = "<mano params>",
) -> Trajectory:
    """A ``mano`` trajectory from MANO parameters (see :func:`mano_keypoints` for ``params``
    and the model options, :func:`.convert.trajectory_from_keypoints` for ``camera_poses``).

    Raises ImportError(:data:`SMPLX_MISSING`) without smplx, before anything else.
    """
    kp = mano_keypoints(
        params,
        model_dir,
        hand_pose_space=hand_pose_space,
        flat_hand_mean=flat_hand_mean,
        fix_left_shapedirs=fix_left_shapedirs,
    )
    return trajectory_from_keypoints(
        kp, fps, camera_poses=camera_poses, camera_convention=camera_convention, timestamps=timestamps, source=source
    )
