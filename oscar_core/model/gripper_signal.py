"""An explicit per-frame gripper signal beside the condition video (a model card's ``gripper_signal``).

Why: in the skeleton video the gripper's state is a small indicator (18 of 4,096 pixels per frame at 64 × 64,
one or two cells of the VAE's latent grid), and a model trained on it moved the ball along the arm whether or
not the gripper closed (docs/closed-loop.md). Action-conditioned Cosmos models embed their actions per latent
frame; here the gripper's openness is embedded per latent frame the same way, while the skeleton video stays
the primary condition.

The features of latent frame k are the openness of each gripper at the pixel frames that latent frame covers
(the causal VAE: latent frame 0 is pixel frame 0, latent frame k ≥ 1 covers pixel frames 4k − 3 … 4k for a
temporal factor of 4; frame 0's value is repeated to fill its slots), for :data:`GRIPPER_SLOTS` grippers:
``GRIPPER_SLOTS × temporal`` channels (8 for the WAN 2.1 and toy VAEs), each ``1 − 2·openness`` (+1 closed,
−1 open) and 0 for a slot the robot does not have, so 0 means "no information" — which is also what the
unconditional branch (a dropped condition) sees. They are appended to the condition latent as channels
constant over the image (:func:`with_gripper_channels`) and go through PE_s with it: a learnt linear map of
the frame's gripper features added to every token of that frame.
"""

from __future__ import annotations

import numpy as np
import torch

from ..plugin.openness import trajectory_openness  # the clip records' signal, so rollouts see what training saw
from .errors import ModelInputError

__all__ = [
    "GRIPPER_SLOTS",
    "gripper_channels",
    "gripper_features",
    "with_gripper_channels",
    "batch_features",
    "trajectory_openness",
    "gripper_input",
    "check_gripper_given",
]

#: Grippers a signal has room for (two arms); a robot with more uses its first two.
GRIPPER_SLOTS = 2


def gripper_channels(temporal: int) -> int:
    """Channels the signal adds to the condition latent for a VAE of temporal factor ``temporal``."""
    return GRIPPER_SLOTS * int(temporal)


def gripper_input(card, embodiment, trajectory, frames: int | None = None) -> dict:
    """The rollout keyword a model's card asks for beside its condition video: ``{"gripper": (T, G) openness}``
    (:func:`trajectory_openness`, its first ``frames`` rows when given) for a card with ``gripper_signal``, else
    ``{}`` (any card: one without the field takes no signal)."""
    if not getattr(card, "gripper_signal", False):
        return {}
    return {"gripper": trajectory_openness(embodiment, trajectory)[:frames]}


def gripper_features(openness, temporal: int) -> np.ndarray:
    """(C_g, T') float32 features of a window's gripper openness.

    openness: (L, G) in [0, 1] per pixel frame (1 = open), L = temporal·k + 1 frames, G ≥ 0 grippers;
    returns C_g = :func:`gripper_channels` rows (slot-major: slot g's ``temporal`` sub-frames, then the next)
    and T' = (L − 1) / temporal + 1 latent frames.
    """
    a = np.asarray(openness, dtype=np.float64)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2 or len(a) < 1 or (len(a) - 1) % temporal:
        raise ModelInputError(
            f"gripper signal: expected openness (L, G) with L = {temporal}k + 1 frames, found shape {a.shape}"
        )
    if a.size and not np.isfinite(a).all():
        raise ModelInputError("gripper signal: expected finite openness values, found NaN or inf")
    frames = len(a)
    latent = (frames - 1) // temporal + 1
    # pixel frame of each (latent frame, sub-frame): frame 0 repeated, then 4k-3 .. 4k
    index = np.empty((latent, temporal), dtype=np.int64)
    index[0] = 0
    for k in range(1, latent):
        index[k] = np.arange(temporal * (k - 1) + 1, temporal * k + 1)
    out = np.zeros((GRIPPER_SLOTS, temporal, latent), dtype=np.float32)
    for g in range(min(GRIPPER_SLOTS, a.shape[1])):
        out[g] = (1.0 - 2.0 * np.clip(a[index, g], 0.0, 1.0)).T
    return out.reshape(GRIPPER_SLOTS * temporal, latent)


def batch_features(openness_list, temporal: int) -> torch.Tensor:
    """(B, C_g, T') features of B windows' openness arrays (each (L, G), one L)."""
    return torch.stack([torch.from_numpy(gripper_features(o, temporal)) for o in openness_list])


def with_gripper_channels(latent: torch.Tensor, features: torch.Tensor | None) -> torch.Tensor:
    """The condition latent (B, C, T', h, w) with the gripper features (B, C_g, T') appended as channels constant
    over the image: (B, C + C_g, T', h, w). The unconditional branch passes zero features; None is refused (the
    number of channels to add would be unknown)."""
    if features is None:
        raise ModelInputError("gripper signal: expected features (B, C_g, T'), found None")
    b, _, t, h, w = latent.shape
    if features.ndim != 3 or features.shape[0] != b or features.shape[2] != t:
        raise ModelInputError(
            f"gripper signal: expected features of shape (B={b}, C_g, T'={t}), found {tuple(features.shape)}"
        )
    planes = features.to(latent.device, latent.dtype)[:, :, :, None, None].expand(-1, -1, -1, h, w)
    return torch.cat([latent, planes], dim=1)


def check_gripper_given(card, given: bool) -> None:
    """A rollout of the model ``card`` describes is given a gripper signal exactly when the card says the model takes
    one (``card.gripper_signal``); ModelInputError otherwise."""
    if given != bool(card.gripper_signal):
        raise ModelInputError(
            f"rollout: model {card.name or ''} "
            + (
                "takes a gripper signal (card gripper_signal): expected gripper (T, G) openness "
                "(rollout_inputs builds it), found none"
                if card.gripper_signal
                else "takes no gripper signal (card gripper_signal false): expected gripper=None, found one"
            )
        )
