"""Sampler and autoregressive rollouts with a tiny DiT and a tiny WAN VAE (CPU, seconds)."""

import numpy as np
import pytest
import torch
from _models import tiny_world_model

from oscar_core.model import (
    ModelCard,
    ModelInputError,
    OscarWorldModel,
    SamplerConfig,
    chunk_plan,
    chunk_windows,
    flow_sigmas,
    guided_velocity,
    sample_chunk,
)
from oscar_core.model.tiny import build_tiny_transformer, build_tiny_vae

H, W = 32, 64
STEPS = 3


@pytest.fixture(scope="module")
def model():
    return tiny_world_model(skeleton_scale=0.05, name="tiny", chunk_frames=9)


@pytest.fixture(scope="module")
def clip():
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, (H, W, 3), dtype=np.uint8), rng.integers(0, 256, (20, H, W, 3), dtype=np.uint8)


def _latents(model, seed=0, frames=9):
    g = torch.Generator().manual_seed(seed)
    first = torch.randn(1, 16, 1, H // 8, W // 8, generator=g)
    skel = torch.randn(1, 16, (frames - 1) // 4 + 1, H // 8, W // 8, generator=g)
    return first, skel, model.prompt_embeds()


def _sample(model, config, seed=0):
    first, skel, text = _latents(model)
    return sample_chunk(model.transformer, first, skel, text, config, generator=torch.Generator().manual_seed(seed))


# --------------------------------------------------------------------------- sampler


def test_flow_sigmas_are_shifted_and_end_at_zero():
    s = flow_sigmas(4, shift=5.0)
    assert s[0] == 1.0 and s[-1] == 0.0 and torch.all(s[1:] < s[:-1])
    assert torch.isclose(s[2], torch.tensor(5 * 0.5 / (1 + 4 * 0.5), dtype=torch.float64))


def test_guidance_w1_equals_the_conditional_branch(model):
    cond_only = _sample(model, SamplerConfig(steps=STEPS, guidance=None))
    for config in (
        SamplerConfig(steps=STEPS, guidance=1.0, guidance_form="standard"),  # v_u + 1 (v_c - v_u)
        SamplerConfig(steps=STEPS, guidance=1.0, batched_cfg=False, guidance_form="standard"),
        SamplerConfig(steps=STEPS, guidance=0.0, guidance_form="diffusers"),
    ):  # v_c + 0 (v_c - v_u)
        torch.testing.assert_close(_sample(model, config), cond_only, rtol=1e-5, atol=1e-5)
    assert (_sample(model, SamplerConfig(steps=STEPS, guidance=6.0)) - cond_only).abs().max() > 1e-4


def test_batched_cfg_equals_two_passes(model):
    a = _sample(model, SamplerConfig(steps=STEPS, guidance=6.0, batched_cfg=True))
    b = _sample(model, SamplerConfig(steps=STEPS, guidance=6.0, batched_cfg=False))
    torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-4)


class _Spy(torch.nn.Module):
    """Stands in for the DiT: velocity = 2·skeleton + 0.5·x; records what it is called with."""

    def __init__(self):
        super().__init__()
        self.anchor = torch.nn.Parameter(torch.zeros(1))
        self.calls = []

    @property
    def dtype(self):
        return torch.float32

    def project_text(self, text):
        return text

    def forward(
        self,
        hidden_states,
        timestep,
        encoder_hidden_states,
        condition_mask,
        padding_mask,
        fps,
        skeleton_latents,
        return_dict,
        text_projected=False,
    ):
        self.calls.append((hidden_states.clone(), timestep.clone(), skeleton_latents.clone(), condition_mask.clone()))
        return (2 * skeleton_latents + 0.5 * hidden_states,)


def test_guidance_forms_and_unconditional_branch():
    spy = _Spy()
    x = torch.randn(1, 4, 3, 2, 2)
    s = torch.randn(1, 4, 3, 2, 2)
    t, mask, text = torch.rand(1, 1, 3, 1, 1), torch.zeros(1, 1, 3, 2, 2), torch.zeros(1, 1, 8)
    v_c, v_u = 2 * s + 0.5 * x, 0.5 * x
    std = guided_velocity(
        spy, x, t, text, s, mask, None, SamplerConfig(guidance=6.0, batched_cfg=False, guidance_form="standard")
    )
    torch.testing.assert_close(std, v_u + 6 * (v_c - v_u))
    assert torch.count_nonzero(spy.calls[-1][2]) == 0  # the unconditional branch sees a zero skeleton
    dif = guided_velocity(spy, x, t, text, s, mask, None, SamplerConfig(guidance=6.0, guidance_form="diffusers"))
    torch.testing.assert_close(dif, v_c + 6 * (v_c - v_u))
    assert spy.calls[-1][0].shape[0] == 2  # batched: one forward of batch 2B


def test_first_latent_frame_is_clean_at_every_step_and_at_the_end():
    spy = _Spy()
    first = torch.randn(1, 4, 1, 2, 2)
    skel = torch.randn(1, 4, 3, 2, 2)
    out = sample_chunk(
        spy,
        first,
        skel,
        torch.zeros(1, 1, 8),
        SamplerConfig(steps=4, guidance=None),
        generator=torch.Generator().manual_seed(0),
    )
    assert len(spy.calls) == 4
    for x, t, _, mask in spy.calls:
        assert torch.equal(x[:, :, :1], first)
        assert torch.all(t[:, :, 0] == 1e-4) and torch.all(t[:, :, 1:] > 0)
        assert torch.all(mask[:, :, 0] == 1) and torch.all(mask[:, :, 1:] == 0)
    assert torch.equal(out[:, :, :1], first)


# --------------------------------------------------------------------------- rollout


@pytest.mark.parametrize("frames,chunk", [(97, 17), (17, 17), (25, 9), (30, 9), (5, 5), (81, 81), (100, 13)])
def test_chunk_windows_are_the_frames_each_rollout_chunk_makes(frames, chunk):
    starts = chunk_plan(frames, chunk)  # the rollout's own plan: chunk c starts (seed frame) at starts[c]
    want = [(s + 1, min(s + chunk - 1, frames - 1)) for s in starts]
    assert chunk_windows(frames, chunk) == want
    covered = [t for a, b in want for t in range(a, b + 1)]
    assert covered == list(range(1, frames))  # every generated frame once, frame 0 in none


def test_chunk_windows_of_a_97_frame_rollout_in_17_frame_chunks():
    assert chunk_windows(97, 17) == [(1, 16), (17, 32), (33, 48), (49, 64), (65, 80), (81, 96)]
    with pytest.raises(ModelInputError, match="chunk_frames: expected at least 2 frames"):
        chunk_windows(97, 1)
    with pytest.raises(ModelInputError, match="video: expected at least 2 frames"):
        chunk_windows(1, 17)


def test_chunk_plan_covers_any_length():
    assert chunk_plan(9, 9) == [0]
    assert chunk_plan(17, 9) == [0, 8]
    assert chunk_plan(20, 9) == [0, 8, 16]
    assert chunk_plan(81, 81) == [0]


def test_rollout_length_seeds_and_no_duplicated_frame(model, clip):
    first, skel = clip
    result = model.rollout(first, skel, sampler=SamplerConfig(steps=STEPS), seed=3, progress=False)
    assert result.frames.shape == (20, H, W, 3) and result.frames.dtype == np.uint8
    assert result.starts == [0, 8, 16] and len(result.chunks) == 3
    for chunk, seed in zip(result.chunks, result.seeds):
        # frame 0 of every chunk is the VAE reconstruction of its seed frame
        torch.testing.assert_close(chunk[:, :, :1], model.vae.reconstruct(seed), rtol=0, atol=1e-5)
    for prev, seed in zip(result.chunks[:-1], result.seeds[1:]):
        assert torch.equal(seed, prev[:, :, -1:])  # the last generated frame seeds the next chunk
    to_u8 = model.vae.to_uint8
    expected = np.concatenate(
        [to_u8(result.chunks[0])[0], to_u8(result.chunks[1])[0, 1:], to_u8(result.chunks[2])[0, 1:]]
    )
    np.testing.assert_array_equal(result.frames, expected[:20])


def test_bf16_with_offloaded_vae_and_text_runs_and_matches_float32_shape(clip):
    model = OscarWorldModel.from_modules(
        build_tiny_transformer(seed=0, skeleton_scale=0.05),
        build_tiny_vae(seed=0),
        ModelCard(chunk_frames=5),
        dtype=torch.bfloat16,
        offload_vae=True,
        offload_text=True,
    )
    assert model.transformer.dtype == torch.bfloat16
    assert model.transformer.learnable_pos_embed.pos_emb_t.dtype == torch.float32  # kept float32
    frames = model.rollout(clip[0], clip[1][:9], sampler=SamplerConfig(steps=2), progress=False).frames
    assert frames.shape == (9, H, W, 3)


def test_same_seed_same_video(model, clip):
    first, skel = clip[0], clip[1][:9]
    config = SamplerConfig(steps=STEPS)
    a = model.rollout(first, skel, sampler=config, seed=7, progress=False).frames
    b = model.rollout(first, skel, sampler=config, seed=7, progress=False).frames
    c = model.rollout(first, skel, sampler=config, seed=8, progress=False).frames
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_progress_bars_per_chunk_and_step(model, clip, capsys, monkeypatch):
    import oscar_core.model.rollout as rollout_module

    model.rollout(clip[0], clip[1][:17], sampler=SamplerConfig(steps=2), progress=True)
    assert "rollout chunks" not in capsys.readouterr().err  # stderr is no terminal here: no bars
    monkeypatch.setattr(rollout_module, "progress_bars_enabled", lambda: True)  # as on a terminal
    model.rollout(clip[0], clip[1][:17], sampler=SamplerConfig(steps=2), progress=True)
    err = capsys.readouterr().err
    assert "rollout chunks" in err and "chunk 2/2" in err


@pytest.mark.parametrize(
    "case,match",
    [
        ("size", "first frame: expected the skeleton video's size 64x32"),
        ("short", "expected at least one chunk of 9 frames, found 7 frames; use chunk_frames=5"),
        ("chunk", "chunk_frames: expected a frame count of the form 4k\\+1"),
        ("divisible", "divisible by 16"),
    ],
)
def test_bad_rollout_inputs_are_clear_errors(model, clip, case, match):
    first, skel = clip
    kwargs = dict(sampler=SamplerConfig(steps=1), progress=False)
    with pytest.raises(ModelInputError, match=match):
        if case == "size":
            model.rollout(first[:16], skel, **kwargs)
        elif case == "short":
            model.rollout(first, skel[:7], **kwargs)
        elif case == "chunk":
            model.rollout(first, skel, chunk_frames=8, **kwargs)
        else:
            model.rollout(first[:, :40], skel[:, :, :40], **kwargs)
