"""Focus weights: more loss where a small object decides the outcome (``data.focus_mask``, ``flow.focus_weight``).

The flow-matching loss averages over every latent element, and a 3–5 px object that the gripper's decision moves
or leaves (the toy world's ball) is one or two latent cells of 16 × 16: its error is lost in the floor's. A run
may name a *focus mask* — a function ``mask(frames) -> (T, H, W) bool`` of the window's RGB frames
``(T, H, W, 3) uint8``, given as ``module:attr`` or ``path/to/file.py:attr`` — and a weight ``w``; the loss of
every latent element whose cell the mask touches is then weighted ``1 + w`` (1 elsewhere). The toy world's mask
is its ball by reserved colour (:func:`oscar_core.toyworld.locate.ball_mask`); a user's may read segmentation
masks of their own.

Latent cells follow the causal VAE's layout: latent frame 0 is pixel frame 0, latent frame ``t ≥ 1`` covers pixel
frames ``4t − 3 … 4t``; a latent cell covers a ``s × s`` block of pixels (``s`` = pixel size / latent size). A cell
is in focus when any of its pixels in any of its frames is.
"""

from __future__ import annotations

import numpy as np
import torch

from .._util.user_code import import_attr

__all__ = ["load_focus_mask", "latent_focus"]


def load_focus_mask(spec: str):
    """The mask function named by ``spec`` (``module:attr`` or ``path/to/file.py:attr``); ValueError naming
    ``data.focus_mask`` when it cannot be imported or is not callable."""
    try:
        fn = import_attr(spec, "focus_mask")
    except Exception as e:  # an import error of the user's module is reported with the field that named it
        raise ValueError(f"data.focus_mask: expected an importable module:attr, found {spec!r} ({e})") from e
    if not callable(fn):
        raise ValueError(f"data.focus_mask: expected a function (frames) -> (T, H, W) bool, found {type(fn).__name__}")
    return fn


def latent_focus(mask: np.ndarray, latent_shape: tuple[int, int, int], temporal: int = 4) -> torch.Tensor:
    """(1, T', h, w) float32 in {0, 1}: which latent cells of a window the pixel mask touches.

    mask: (T, H, W) bool with T = temporal·(T' − 1) + 1 and H, W multiples of h, w; latent_shape: (T', h, w).
    """
    m = np.asarray(mask)
    tl, h, w = latent_shape
    if m.ndim != 3 or m.shape[0] != temporal * (tl - 1) + 1 or m.shape[1] % h or m.shape[2] % w:
        raise ValueError(
            f"focus mask: expected (T, H, W) with T = {temporal * (tl - 1) + 1} frames and H, W multiples of "
            f"{h} x {w} (the latent window), found shape {m.shape}"
        )
    sy, sx = m.shape[1] // h, m.shape[2] // w
    cells = m.astype(bool).reshape(m.shape[0], h, sy, w, sx).any(axis=(2, 4))  # (T, h, w)
    first = cells[:1]
    rest = cells[1:].reshape(tl - 1, temporal, h, w).any(axis=1)
    return torch.from_numpy(np.concatenate([first, rest]).astype(np.float32))[None]
