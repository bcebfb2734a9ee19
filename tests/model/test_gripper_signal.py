"""The per-frame gripper signal beside the condition video (oscar_core/model/gripper_signal.py): its features
against the causal VAE's frame grouping worked out by hand, its channels in the condition latent, and a model
with it rolling out (the signal changes the video; it is required exactly when the card says so)."""

import numpy as np
import pytest
import torch
from _models import tiny_world_model

from oscar_core.model import ModelInputError
from oscar_core.model.gripper_signal import (
    GRIPPER_SLOTS,
    gripper_channels,
    gripper_features,
    with_gripper_channels,
)
from oscar_core.model.tiny import TINY_TRANSFORMER_CONFIG

H, W = 32, 64
STEPS = 2


def test_features_group_frames_as_the_causal_vae_does():
    # 9 frames, temporal 4: latent frame 0 = pixel frame 0 (repeated), 1 = frames 1..4, 2 = frames 5..8
    openness = np.zeros((9, 1))
    openness[[2, 7], 0] = 1.0  # open on pixel frames 2 and 7 only
    f = gripper_features(openness, 4)
    assert f.shape == (GRIPPER_SLOTS * 4, 3)
    slot0 = f[:4]  # (sub-frame, latent frame)
    np.testing.assert_array_equal(slot0[:, 0], [1, 1, 1, 1])  # frame 0 closed, four times
    np.testing.assert_array_equal(slot0[:, 1], [1, -1, 1, 1])  # frames 1, 2, 3, 4: frame 2 open
    np.testing.assert_array_equal(slot0[:, 2], [1, 1, -1, 1])  # frames 5, 6, 7, 8: frame 7 open
    np.testing.assert_array_equal(f[4:], 0.0)  # no second gripper: "no information"


def test_features_of_two_grippers_and_half_open_values():
    openness = np.stack([np.linspace(0, 1, 5), np.full(5, 0.25)], axis=1)
    f = gripper_features(openness, 4)
    np.testing.assert_allclose(f[:4, 1], 1 - 2 * openness[1:5, 0])
    np.testing.assert_allclose(f[4:, 1], 0.5)
    assert gripper_channels(4) == f.shape[0]


@pytest.mark.parametrize(
    "openness, match",
    [(np.ones((8, 1)), "4k \\+ 1"), (np.full((5, 1), np.nan), "finite"), (np.ones((5, 1, 1)), "openness")],
)
def test_bad_openness_is_refused(openness, match):
    with pytest.raises(ModelInputError, match=match):
        gripper_features(openness, 4)


def test_channels_are_constant_over_the_image_and_appended_last():
    latent = torch.randn(2, 16, 3, 4, 8)
    feats = torch.randn(2, 8, 3)
    out = with_gripper_channels(latent, feats)
    assert out.shape == (2, 24, 3, 4, 8)
    torch.testing.assert_close(out[:, :16], latent)
    torch.testing.assert_close(out[:, 16:, :, 2, 5], feats)
    torch.testing.assert_close(out[:, 16:].amax((-2, -1)), out[:, 16:].amin((-2, -1)))
    with pytest.raises(ModelInputError, match="T'=3"):
        with_gripper_channels(latent, torch.randn(2, 8, 2))


@pytest.fixture(scope="module")
def gripper_model():
    latent = TINY_TRANSFORMER_CONFIG["out_channels"]
    from oscar_core.model import ModelCard, OscarWorldModel
    from oscar_core.model.tiny import build_tiny_transformer, build_tiny_vae

    transformer = build_tiny_transformer(seed=0, skeleton_scale=0.05, skeleton_channels=latent + gripper_channels(4))
    with torch.no_grad():  # a strong gripper embedding, so that the signal visibly changes the video
        transformer.skeleton_embed.proj.weight[:, latent * 4 :] *= 40.0
    card = ModelCard(name="tiny-gripper", chunk_frames=9, gripper_signal=True)
    return OscarWorldModel.from_modules(transformer, build_tiny_vae(seed=0), card)


@pytest.fixture(scope="module")
def clip():
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, (H, W, 3), dtype=np.uint8), rng.integers(0, 256, (13, H, W, 3), dtype=np.uint8)


def _roll(model, clip, gripper, seed=0):
    from oscar_core.model import SamplerConfig

    first, skel = clip
    sampler = SamplerConfig(steps=STEPS, guidance=2.0)
    return model.rollout(first, skel, sampler=sampler, seed=seed, progress=False, gripper=gripper).frames


def test_the_gripper_signal_changes_the_video_and_only_it(gripper_model, clip):
    closed, opened = np.zeros((13, 1)), np.ones((13, 1))
    a, b = _roll(gripper_model, clip, closed), _roll(gripper_model, clip, closed)
    np.testing.assert_array_equal(a, b)
    c = _roll(gripper_model, clip, opened)
    assert a.shape == c.shape == (13, H, W, 3)
    assert np.abs(a.astype(int) - c.astype(int)).mean() > 1.0


def test_batch_equals_one_at_a_time_with_the_signal(gripper_model, clip):
    from oscar_core.model import SamplerConfig

    first, skel = clip
    grips = [np.zeros((13, 1)), np.ones((13, 1))]
    batch = gripper_model.rollout_batch(
        [first, first], [skel, skel], sampler=SamplerConfig(steps=STEPS, guidance=2.0), seeds=[0, 0], grippers=grips
    )
    for video, g in zip(batch, grips):
        single = _roll(gripper_model, clip, g)
        assert np.abs(video.astype(int) - single.astype(int)).max() <= 1


def test_the_signal_is_required_exactly_when_the_card_says(gripper_model, clip):
    with pytest.raises(ModelInputError, match="takes a gripper signal"):
        _roll(gripper_model, clip, None)
    plain = tiny_world_model(skeleton_scale=0.05, name="tiny", chunk_frames=9)
    with pytest.raises(ModelInputError, match="takes no gripper signal"):
        _roll(plain, clip, np.zeros((13, 1)))
    with pytest.raises(ModelInputError, match="T=13"):
        _roll(gripper_model, clip, np.zeros((12, 1)))


def test_card_refuses_a_gripper_signal_without_a_condition_video():
    from oscar_core.model import ModelCard

    with pytest.raises(ModelInputError, match="condition video"):
        ModelCard(condition="latent_action", gripper_signal=True)
    with pytest.raises(ModelInputError, match="true or false"):
        ModelCard(gripper_signal="yes")
