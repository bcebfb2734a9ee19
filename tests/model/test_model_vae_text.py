"""The VAE wrapper (normalised latents, 4k+1 frames) and prompt embeddings (cache, empty fallback)."""

import numpy as np
import pytest
import torch
from _models import tiny_world_model
from safetensors import safe_open

from oscar_core.model import (
    CheckpointIntegrityError,
    ModelInputError,
    PromptEmbeddingCache,
    VideoVAE,
    check_frame_count,
    empty_prompt_embeds,
)
from oscar_core.model.text import prompt_key
from oscar_core.model.tiny import TINY_TRANSFORMER_CONFIG, build_tiny_vae

TEXT_DIM = TINY_TRANSFORMER_CONFIG["crossattn_proj_in_channels"]


@pytest.fixture(scope="module")
def vae():
    return VideoVAE(build_tiny_vae(seed=0))


def test_frame_counts_must_be_4k_plus_1():
    assert check_frame_count(1) == 1 and check_frame_count(81) == 21
    with pytest.raises(ModelInputError, match=r"found 80 \(nearest valid: 77 or 81\)"):
        check_frame_count(80, what="video")


def test_encode_normalises_with_the_vae_mean_and_std(vae):
    pixels = torch.rand(1, 3, 5, 32, 64) * 2 - 1
    z = vae.encode(pixels)
    assert z.shape == (1, 16, 2, 4, 8)
    raw = vae.vae.encode(pixels).latent_dist.mode()
    mean = torch.tensor(vae.vae.config.latents_mean).view(1, -1, 1, 1, 1)
    std = torch.tensor(vae.vae.config.latents_std).view(1, -1, 1, 1, 1)
    torch.testing.assert_close(z, (raw - mean) / std)
    torch.testing.assert_close(vae.decode(z), vae.vae.decode(raw).sample, rtol=1e-5, atol=1e-5)


def test_bad_frame_count_or_size_is_a_clear_error(vae):
    with pytest.raises(ModelInputError, match="4k\\+1"):
        vae.encode(torch.zeros(1, 3, 4, 32, 64))
    with pytest.raises(ModelInputError, match="divisible by 8, found 60x32"):
        vae.encode(torch.zeros(1, 3, 1, 32, 60))


def test_pixel_conversions_roundtrip_uint8():
    frames = np.random.default_rng(0).integers(0, 256, (5, 8, 16, 3), dtype=np.uint8)
    pixels = VideoVAE.to_pixels(frames)
    assert pixels.shape == (1, 3, 5, 8, 16) and pixels.min() >= -1 and pixels.max() <= 1
    np.testing.assert_array_equal(VideoVAE.to_uint8(pixels)[0], frames)


def test_cpu_offload_gives_the_same_latents():
    a, b = VideoVAE(build_tiny_vae(seed=1)), VideoVAE(build_tiny_vae(seed=1), offload=True)
    x = torch.rand(1, 3, 1, 16, 16) * 2 - 1
    torch.testing.assert_close(a.encode(x), b.encode(x))
    assert next(b.vae.parameters()).device.type == "cpu"


def test_prompt_cache_roundtrip_keyed_by_prompt_and_encoder(tmp_path):
    cache = PromptEmbeddingCache(tmp_path, encoder_id="enc-a")
    emb = torch.randn(1, 7, TEXT_DIM)
    assert cache.get("pick the cube") is None
    path = cache.put("pick the cube", emb)
    assert path.name == prompt_key("pick the cube", "enc-a") + ".safetensors"
    with safe_open(str(path), framework="pt") as fh:
        assert fh.metadata() == {"prompt": "pick the cube", "encoder_id": "enc-a"}
    assert torch.equal(cache.get("pick the cube"), emb)
    assert PromptEmbeddingCache(tmp_path, encoder_id="enc-b").get("pick the cube") is None
    calls = []
    got = cache.get_or_encode("open the drawer", lambda p: calls.append(p) or torch.ones(3, TEXT_DIM))
    again = cache.get_or_encode("open the drawer", lambda p: calls.append(p) or torch.zeros(3, TEXT_DIM))
    assert calls == ["open the drawer"] and got.shape == (1, 3, TEXT_DIM) and torch.equal(got, again)


def test_prompt_cache_detects_a_swapped_file(tmp_path):
    cache = PromptEmbeddingCache(tmp_path, encoder_id="enc")
    cache.put("a", torch.zeros(1, 2, 4))
    cache.path("a").replace(cache.path("b"))
    with pytest.raises(CheckpointIntegrityError, match="prompt 'b' by encoder 'enc'"):
        cache.get("b")


def test_empty_prompt_fallback_shapes_and_sequence_length_invariance():
    model = tiny_world_model(seed=2, chunk_frames=5)
    zero = model.prompt_embeds()
    assert zero.shape == (1, 1, TEXT_DIM) and torch.count_nonzero(zero) == 0
    assert torch.equal(zero, empty_prompt_embeds(TEXT_DIM))
    with pytest.raises(ModelInputError, match=f"last dimension {TEXT_DIM}"):
        model.prompt_embeds(torch.zeros(1, 4, TEXT_DIM + 1))
    # identical zero tokens: cross-attention gives the same result for L = 1 and L = 9
    g = torch.Generator().manual_seed(0)
    x, t, mask = torch.randn(1, 16, 2, 4, 8, generator=g), torch.rand(1), torch.zeros(1, 1, 2, 4, 8)
    with torch.no_grad():
        a = model.transformer(x, t, empty_prompt_embeds(TEXT_DIM, 1), condition_mask=mask).sample
        b = model.transformer(x, t, empty_prompt_embeds(TEXT_DIM, 9), condition_mask=mask).sample
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5)
    stored = torch.randn(1, 3, TEXT_DIM)
    model.empty_prompt = stored
    assert model.prompt_embeds() is stored
