"""The latent-action baseline: features against hand-computed trajectories, and the model's two injection points."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from oscar_core.model.errors import ModelInputError
from oscar_core.model.latent_action import LatentActionTransformer, actions_from_poses, latent_actions
from oscar_core.model.tiny import TINY_TRANSFORMER_CONFIG


def pose(R, p):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def test_features_of_a_hand_computed_screw_motion():
    # the end effector turns 0.1 rad about its own z each frame and moves 1 cm along its own x:
    # in the previous frame's coordinates every step is the same: translation (0.01, 0, 0), rotation (0, 0, 0.1)
    T = 6
    R0 = Rotation.from_euler("xyz", [0.3, -0.2, 0.5]).as_matrix()  # an arbitrary starting orientation
    poses, R, p = [], R0, np.array([0.4, 0.1, 0.3])
    for _ in range(T):
        poses.append(pose(R, p))
        p = p + R @ np.array([0.01, 0.0, 0.0])
        R = R @ Rotation.from_euler("z", 0.1).as_matrix()
    openness = np.linspace(1, 0, T)[:, None]
    a = actions_from_poses(np.array(poses)[:, None], openness)
    assert a.shape == (T - 1, 14)
    np.testing.assert_allclose(a[:, 0:3], np.tile([0.2, 0.0, 0.0], (T - 1, 1)), atol=1e-12)  # x20
    np.testing.assert_allclose(a[:, 3:6], np.tile([0.0, 0.0, 2.0], (T - 1, 1)), atol=1e-12)  # 0.1 rad x20
    np.testing.assert_allclose(a[:, 6], openness[1:, 0])  # openness at t, unscaled
    assert np.all(a[:, 7:] == 0)  # single arm: zero-padded


def test_two_arms_fill_both_halves_and_rotation_deltas_are_local():
    T = 3
    # arm 0 is still; arm 1 rotates about the world x axis while yawed 90 degrees: locally that is a pitch
    yaw = Rotation.from_euler("z", np.pi / 2).as_matrix()
    arm0 = [pose(np.eye(3), np.zeros(3))] * T
    arm1 = [pose(Rotation.from_euler("x", 0.05 * t).as_matrix() @ yaw, np.zeros(3)) for t in range(T)]
    a = actions_from_poses(np.stack([np.array(arm0), np.array(arm1)], axis=1), np.array([[1.0, 0.0]] * T))
    assert np.all(a[:, :6] == 0) and np.all(a[:, 6] == 1.0)
    # R_{t-1}^T R_t = yaw^T Rx(0.05) yaw = a rotation of -0.05 about local y
    np.testing.assert_allclose(a[:, 10:13], np.tile([0.0, -1.0, 0.0], (T - 1, 1)), atol=1e-12)
    assert np.all(a[:, 13] == 0.0)


def test_features_through_the_embodiment_fk():
    from oscar_core import load_trajectory
    from oscar_core.plugin.registry import Registry

    emb = Registry().get("toyarm")
    traj = load_trajectory(emb.example_trajectory).time_slice(0, 9)
    a = latent_actions(emb, traj)
    assert a.shape == (8, 14) and np.all(a[:, 7:] == 0)
    poses = emb.fk(emb.full_configuration(traj), links=["tool"]).double().numpy()
    dp = poses[1, 0, :3, :3].T @ (poses[2, 0, :3, 3] - poses[1, 0, :3, 3])
    np.testing.assert_allclose(a[1, :3], 20 * dp, atol=1e-12)
    mano = Registry().get("mano")
    with pytest.raises(ModelInputError, match="'mano'.*end_effector_links"):
        latent_actions(mano, traj)


def _inputs(b=2, t=3):
    g = torch.Generator().manual_seed(0)
    return dict(
        hidden_states=torch.randn(b, 16, t, 4, 4, generator=g),
        timestep=torch.rand(b, 1, t, 1, 1, generator=g),
        encoder_hidden_states=torch.randn(b, 2, 48, generator=g),
        condition_mask=torch.zeros(b, 1, t, 4, 4),
        return_dict=False,
    )


def test_model_starts_as_the_base_and_injects_both_tokens():
    torch.manual_seed(0)
    model = LatentActionTransformer(action_frames=8, **TINY_TRANSFORMER_CONFIG).eval()
    actions = torch.randn(2, 8, 14)
    with torch.no_grad():
        base = model(**_inputs())[0]
        with_actions = model(**_inputs(), actions=actions)[0]
    assert torch.equal(base, with_actions)  # the output layers start at zero: the base model exactly
    # the D-token reaches the timestep embedding, the 3D-token the AdaLN modulation: each alone changes the output
    for mlp in (model.action_embed_d, model.action_embed_3d):
        with torch.no_grad():
            mlp[2].weight.normal_(0, 0.02)
            out = model(**_inputs(), actions=actions)[0]
            assert not torch.allclose(out, base)
            mlp[2].weight.zero_()
    with pytest.raises(ModelInputError, match=r"actions: expected \(B, 8, 14\)"):
        model(**_inputs(), actions=torch.randn(2, 80, 14))
