"""The paper's latent-action baseline (Appendix "Latent-action conditioning pathway").

Features (:func:`latent_actions`): per arm a 7-D action per transition t−1 → t —
the end-effector translation delta expressed in the previous end-effector
frame, R_{t−1}ᵀ (p_t − p_{t−1}), the rotation delta R_{t−1}ᵀ R_t as Euler
angles (scipy's extrinsic ``"xyz"``: roll, pitch, yaw about the fixed axes;
the paper does not name its convention), both ×20, and the gripper openness
at t unchanged. Arms are the embodiment's ``end_effector_links`` (one or
two); a single arm fills dims 0–6 and leaves 7–13 zero; the result is
(T − 1, 14) for every robot. Hands (no kinematic tree) have no end effector
and are refused.

Model (:class:`LatentActionTransformer`): an ``OscarTransformer3DModel`` plus
two MLPs (1120 → 4D → D and 1120 → 4D → 3D, GELU) of the flattened (80, 14)
chunk; the D-token is added to the timestep embedding and the 3D-token to
the AdaLN modulation input, at every token (a clip-level signal, no extra
tokens), as Cosmos' ``action_embedder_B_D`` / ``_B_3D``. Their output layers
start at zero (explicitly, so FSDP's meta-device materialisation cannot leave
them random or zero by accident): at step 0 the model is the base model.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from .errors import ModelInputError
from .transformer import OscarTransformer3DModel

__all__ = [
    "ACTION_DIM",
    "ACTION_SCALE",
    "latent_actions",
    "actions_from_poses",
    "hold_actions",
    "LatentActionTransformer",
]

ACTION_DIM = 14
ACTION_SCALE = 20.0
EULER = "xyz"


def actions_from_poses(poses: np.ndarray, openness: np.ndarray) -> np.ndarray:
    """(T, A, 4, 4) end-effector poses (metres) and (T, G) openness → (T − 1, 14) actions.

    Arm a uses gripper a's openness when there is one (else 0).
    """
    from scipy.spatial.transform import Rotation

    poses = np.asarray(poses, dtype=np.float64)
    T, A = poses.shape[:2]
    if A not in (1, 2):
        raise ModelInputError(f"latent actions: expected 1 or 2 end-effector links, found {A}")
    out = np.zeros((T - 1, ACTION_DIM), dtype=np.float64)
    for a in range(A):
        R, p = poses[:, a, :3, :3], poses[:, a, :3, 3]
        dp = np.einsum("tji,tj->ti", R[:-1], p[1:] - p[:-1])  # R_{t-1}^T (p_t - p_{t-1})
        dR = np.einsum("tji,tjk->tik", R[:-1], R[1:])  # R_{t-1}^T R_t
        euler = Rotation.from_matrix(dR).as_euler(EULER)
        out[:, 7 * a : 7 * a + 3] = ACTION_SCALE * dp
        out[:, 7 * a + 3 : 7 * a + 6] = ACTION_SCALE * euler
        if a < openness.shape[1]:
            out[:, 7 * a + 6] = openness[1:, a]
    return out


def latent_actions(embodiment, trajectory) -> np.ndarray:
    """(T − 1, 14) float64 latent actions of a trajectory through its embodiment's FK."""
    links = tuple(getattr(embodiment, "end_effector_links", ()) or ())
    if not embodiment.uses_kinematic_tree() or not links:
        raise ModelInputError(
            f"embodiment {embodiment.name!r}: expected end_effector_links (1 or 2 links of its "
            f"kinematic tree) for latent actions, found {links or 'none'}"
        )
    traj = embodiment.check_trajectory(trajectory)
    poses = embodiment.fk(embodiment.full_configuration(traj), traj.base_pose, links=list(links)).to(torch.float64)
    openness = embodiment.gripper_openness(traj.gripper, traj.source)
    return actions_from_poses(poses.cpu().numpy(), openness)


def hold_actions(actions: np.ndarray, transitions: int) -> np.ndarray:
    """(N, 14) actions extended to (``transitions``, 14) by a robot that holds its last pose.

    The added rows are exactly what :func:`latent_actions` gives for a
    trajectory padded with copies of its last frame (as a rollout pads the
    skeleton video of its last chunk): zero translation and rotation deltas,
    the last openness of each arm (dims 6 and 13). N ≥ 1; fewer rows than N
    are refused (this only extends).
    """
    actions = np.asarray(actions)
    if actions.ndim != 2 or actions.shape[1] != ACTION_DIM or len(actions) < 1:
        raise ModelInputError(f"latent actions: expected (N >= 1, {ACTION_DIM}), found {actions.shape}")
    if transitions < len(actions):
        raise ModelInputError(
            f"latent actions: expected at most {transitions} rows to extend to {transitions}, found {len(actions)}"
        )
    hold = np.zeros((transitions - len(actions), ACTION_DIM), dtype=actions.dtype)
    hold[:, 6::7] = actions[-1, 6::7]
    return np.concatenate([actions, hold])


def _mlp(d_in: int, d_hidden: int, d_out: int) -> nn.Sequential:
    mlp = nn.Sequential(nn.Linear(d_in, d_hidden), nn.GELU(), nn.Linear(d_hidden, d_out))
    with torch.no_grad():
        nn.init.xavier_uniform_(mlp[0].weight)
        mlp[0].bias.zero_()
        mlp[2].weight.zero_()
        mlp[2].bias.zero_()
    return mlp


class LatentActionTransformer(OscarTransformer3DModel):
    """``OscarTransformer3DModel`` + the two action MLPs; ``forward`` takes ``actions`` (B, action_frames, 14).

    action_frames: transitions per chunk (window − 1; the paper's 80);
    action_dim: 14. Other arguments are ``OscarTransformer3DModel``'s.
    """

    config_class_name = "LatentActionTransformer"

    def __init__(self, *, action_frames: int = 80, action_dim: int = ACTION_DIM, **kwargs: Any) -> None:
        # kwargs: OscarTransformer3DModel's settings, recorded from its signature (see configured.py)
        super().__init__(**kwargs)
        hidden = self.config.num_attention_heads * self.config.attention_head_dim
        flat = int(action_frames) * int(action_dim)
        self.action_embed_d = _mlp(flat, 4 * hidden, hidden)
        self.action_embed_3d = _mlp(flat, 4 * hidden, 3 * hidden)
        self._action_tokens = None

    def forward(self, *args, actions: torch.Tensor | None = None, **kwargs):
        """As ``OscarTransformer3DModel.forward`` plus ``actions`` (B, action_frames, action_dim) or None."""
        if actions is None:
            return super().forward(*args, **kwargs)
        want = (self.config.action_frames, self.config.action_dim)
        if actions.ndim != 3 or tuple(actions.shape[1:]) != want:
            raise ModelInputError(f"actions: expected (B, {want[0]}, {want[1]}), found {tuple(actions.shape)}")
        flat = actions.flatten(1).to(self.action_embed_d[0].weight.dtype)
        self._action_tokens = (self.action_embed_d(flat), self.action_embed_3d(flat))
        try:
            return super().forward(*args, **kwargs)
        finally:
            self._action_tokens = None

    def _time_embedding(self, tokens, timestep, batch, t, h, w):
        temb, embedded = super()._time_embedding(tokens, timestep, batch, t, h, w)
        if self._action_tokens is None:
            return temb, embedded
        tok_d, tok_3d = self._action_tokens
        if embedded.ndim == 3:  # per token (B, N, .)
            tok_d, tok_3d = tok_d[:, None, :], tok_3d[:, None, :]
        return temb + tok_3d.to(temb.dtype), embedded + tok_d.to(embedded.dtype)
