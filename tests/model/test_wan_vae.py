"""oscar's Wan VAE against diffusers' ``AutoencoderKLWan`` (the reference): same keys, config, init and numbers.

Both models get the same state dict; float32 on the CPU, one thread. Small configurations (widths 8-16, 16x16
pixels) keep the file to seconds.
"""

import json

import pytest
import torch
from _paths import REPO

from oscar_core.model.errors import CheckpointLayoutError
from oscar_core.model.wan_vae import WanVAE
from oscar_core.model.weights import build_strict, load_state_dict, read_config

diffusers = pytest.importorskip("diffusers")
Reference = diffusers.AutoencoderKLWan

TOY_VAE = REPO / "zoo" / "assets" / "oscar-toy" / "vae"
TOL = 1e-5

#: Wan 2.1 (one and two res blocks), Wan 2.2 residual, time halved early/late/not at all, a wider decoder
CONFIGS = {
    "2.1": dict(base_dim=8, z_dim=4, dim_mult=[1, 2, 2, 2], num_res_blocks=1, temperal_downsample=[False, True, True]),
    "2.1-two-res": dict(base_dim=8, z_dim=4, dim_mult=[1, 2, 2], num_res_blocks=2, temperal_downsample=[True, False]),
    "2.2-residual": dict(
        base_dim=8, z_dim=4, dim_mult=[1, 2, 2], num_res_blocks=1, temperal_downsample=[True, True], is_residual=True
    ),
    "2.2-two-res-late": dict(
        base_dim=8, z_dim=4, dim_mult=[1, 2, 2], num_res_blocks=2, temperal_downsample=[False, True], is_residual=True
    ),
    "2.1-no-time-wide-decoder": dict(
        base_dim=8, z_dim=4, dim_mult=[1, 2], num_res_blocks=1, temperal_downsample=[False], decoder_base_dim=16
    ),
}


@pytest.fixture(autouse=True)
def one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _pair(config: dict, seed: int = 0):
    """(reference, ours) with the same weights: the reference's default init, every tensor then perturbed (so the
    RMS gains are not all ones)."""
    torch.manual_seed(seed)
    ref = Reference(**config).eval()
    g = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        for p in ref.parameters():
            p.add_(torch.randn(p.shape, generator=g) * 0.05)
    ours = WanVAE(**config).eval()
    ours.load_state_dict(ref.state_dict(), strict=True)
    return ref, ours


def _close(a: torch.Tensor, b: torch.Tensor) -> None:
    assert a.shape == b.shape
    assert (a - b).abs().max().item() <= TOL


@pytest.mark.parametrize("name", CONFIGS)
def test_keys_shapes_and_seeded_init_are_the_references(name):
    torch.manual_seed(3)
    ref = Reference(**CONFIGS[name]).state_dict()
    torch.manual_seed(3)
    ours = WanVAE(**CONFIGS[name]).state_dict()
    assert list(ours) == list(ref)
    for key, value in ref.items():  # the same draws in the same order: seeded builders keep their weights
        assert torch.equal(ours[key], value), key


def test_config_keys_and_defaults_are_the_references():
    with torch.device("meta"):
        ref, ours = Reference(), WanVAE()
    ref_cfg = {k: v for k, v in dict(ref.config).items() if not k.startswith("_")}
    assert list(ours.config) == list(ref_cfg)
    assert json.loads(json.dumps(dict(ours.config))) == json.loads(json.dumps(ref_cfg))
    assert set(ours.state_dict()) == set(ref.state_dict())


@pytest.mark.parametrize("name", CONFIGS)
def test_encode_mode_and_decode_match_the_reference(name):
    ref, ours = _pair(CONFIGS[name])
    for frames in (1, 5, 9):
        x = torch.rand(2, 3, frames, 16, 16, generator=torch.Generator().manual_seed(frames)) * 2 - 1
        with torch.no_grad():
            z_ref, z = ref.encode(x).latent_dist.mode(), ours.encode(x).latent_dist.mode()
            _close(z, z_ref)
            _close(ours.decode(z_ref).sample, ref.decode(z_ref).sample)


def test_a_partial_last_group_of_frames_is_left_out_as_the_reference_does():
    ref, ours = _pair(CONFIGS["2.1"])
    x = torch.rand(1, 3, 7, 16, 16) * 2 - 1
    with torch.no_grad():
        z = ours.encode(x).latent_dist.mode()
        _close(z, ref.encode(x).latent_dist.mode())
    assert z.shape[2] == 2


def test_posterior_statistics_and_seeded_samples_match():
    ref, ours = _pair(CONFIGS["2.2-residual"])
    x = torch.rand(1, 3, 5, 16, 16) * 2 - 1
    with torch.no_grad():
        a, b = ref.encode(x).latent_dist, ours.encode(x).latent_dist
    for field in ("mean", "logvar", "std", "var"):
        _close(getattr(b, field), getattr(a, field))
    _close(b.sample(torch.Generator().manual_seed(7)), a.sample(torch.Generator().manual_seed(7)))


def test_tiling_and_slicing_match_the_reference():
    ref, ours = _pair(CONFIGS["2.1"])
    for model in (ref, ours):
        model.enable_tiling(32, 32, 24, 24)
        model.enable_slicing()
    x = torch.rand(2, 3, 5, 48, 40) * 2 - 1
    with torch.no_grad():
        z_ref = ref.encode(x).latent_dist.mode()
        _close(ours.encode(x).latent_dist.mode(), z_ref)
        _close(ours.decode(z_ref).sample, ref.decode(z_ref).sample)
    ours.disable_tiling()
    ours.disable_slicing()
    assert not ours.use_tiling and not ours.use_slicing


def test_gradients_match_the_reference():
    """train-vae's step: reconstruction of a sampled posterior, back to every weight."""
    ref, ours = _pair(CONFIGS["2.2-residual"])
    x = torch.rand(2, 3, 5, 16, 16) * 2 - 1
    for model in (ref, ours):
        model.train()
        post = model.encode(x).latent_dist
        y = model.decode(post.sample(torch.Generator().manual_seed(1))).sample
        (((y - x) ** 2).mean() + post.mean.pow(2).mean()).backward()
    ref_grads = dict(ref.named_parameters())
    for name, p in ours.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name
        assert (p.grad - ref_grads[name].grad).abs().max().item() <= TOL, name


def test_the_onednn_path_runs_our_layers_and_agrees():
    from oscar_core.model.cpu_conv import onednn_available, use_onednn_conv3d

    if not onednn_available():
        pytest.skip("this PyTorch has no oneDNN")
    ref, ours = _pair(CONFIGS["2.1"])
    assert use_onednn_conv3d(ours) == use_onednn_conv3d(ref) > 0
    x = torch.rand(1, 3, 5, 16, 16) * 2 - 1
    with torch.no_grad():
        z = ref.encode(x).latent_dist.mode()
        _close(ours.encode(x).latent_dist.mode(), z)
        _close(ours.decode(z).sample, ref.decode(z).sample)


def test_bfloat16_matches_the_reference():
    ref, ours = _pair(CONFIGS["2.2-residual"])
    ref, ours = ref.to(torch.bfloat16), ours.to(torch.bfloat16)
    x = (torch.rand(1, 3, 5, 16, 16) * 2 - 1).to(torch.bfloat16)
    with torch.no_grad():
        z = ref.encode(x).latent_dist.mode()
        assert torch.equal(ours.encode(x).latent_dist.mode(), z)
        assert torch.equal(ours.decode(z).sample, ref.decode(z).sample)


def test_the_toy_vae_folder_loads_strictly_and_codes_a_toy_clip_as_the_reference(monkeypatch):
    """Bit for bit, with the RMS norm's sum-of-squares path taken (64x64 pixels: test_wan_vae_norm.py)."""
    from oscar_core.model import _wan_vae_layers as layers
    from oscar_core.model.cpu_conv import use_onednn_conv3d
    from oscar_core.model.vae import VideoVAE
    from oscar_core.plugin.registry import Registry
    from oscar_core.toyworld.episode import episode_rng, make_episode

    ours = WanVAE.from_folder(TOY_VAE)
    ref = build_strict(Reference, read_config(TOY_VAE, ("AutoencoderKLWan",)), load_state_dict(TOY_VAE), TOY_VAE)
    use_onednn_conv3d(ours), use_onednn_conv3d(ref)  # as VideoVAE runs them (and faster on one thread)
    emb = Registry().get("toyarm")
    clip = make_episode(emb, episode_rng(0, "toyarm", 9), 64, 64, 9, ss=1).rgb
    x = VideoVAE.to_pixels(clip)
    sums = []
    norm_by_sums = layers.channel_norm_by_sums
    monkeypatch.setattr(layers, "channel_norm_by_sums", lambda t: sums.append(t.shape) or norm_by_sums(t))
    with torch.no_grad():
        z = ref.encode(x).latent_dist.mode()
        assert torch.equal(ours.encode(x).latent_dist.mode(), z)
        assert torch.equal(ours.decode(z).sample, ref.decode(z).sample)
    assert len(sums) > 10


def test_folders_written_by_either_library_load_in_the_other(tmp_path):
    ref, ours = _pair(CONFIGS["2.2-residual"])
    ours.save_pretrained(tmp_path / "ours")
    theirs = Reference.from_pretrained(tmp_path / "ours")
    ref.save_pretrained(tmp_path / "ref", safe_serialization=True)
    back = WanVAE.from_folder(tmp_path / "ref")
    for key, value in ours.state_dict().items():
        assert torch.equal(theirs.state_dict()[key], value) and torch.equal(back.state_dict()[key], value)
    assert json.dumps(dict(back.config)) == json.dumps(dict(ours.config))


@pytest.mark.parametrize(
    "field, value",
    [("patch_size", 2), ("attn_scales", [0.5]), ("temperal_downsample", [True, True, False])],
)
def test_settings_it_does_not_compute_are_refused_naming_the_file_and_field(tmp_path, field, value):
    ours = WanVAE(**CONFIGS["2.2-residual"])
    ours.save_pretrained(tmp_path / "vae")
    path = tmp_path / "vae" / "config.json"
    config = json.loads(path.read_text())
    config[field] = value
    path.write_text(json.dumps(config))
    with pytest.raises(CheckpointLayoutError, match=rf"config\.json: {field}: expected"):
        WanVAE.from_folder(tmp_path / "vae")
    with pytest.raises(CheckpointLayoutError, match=rf"config\.json: {field}: expected"):
        WanVAE.from_config(config)


def test_the_vae_path_imports_no_diffusers():
    """load_vae_folder + VideoVAE encode and decode in a fresh interpreter: no diffusers (nor transformers) module."""
    import subprocess
    import sys

    code = (
        "import sys, torch\n"
        "from oscar_core.model.vae import VideoVAE, load_vae_folder\n"
        f"vae = VideoVAE(load_vae_folder({str(TOY_VAE)!r}))\n"
        "vae.decode(vae.encode(torch.zeros(1, 3, 5, 64, 64)))\n"
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'diffusers', 'transformers', 'scipy'}))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


def test_a_toy_rollout_is_the_same_video_with_the_reference_vae(monkeypatch, tmp_path):
    """oscar-toy rolls out one chunk of a toy episode bit for bit as it did with diffusers' VAE in the model."""
    import numpy as np

    import oscar_zoo
    from oscar_core.model.cpu_conv import use_onednn_conv3d
    from oscar_core.model.sampler import SamplerConfig
    from oscar_core.plugin.registry import Registry
    from oscar_core.render.skeleton_video import render_skeleton_video
    from oscar_core.toyworld.episode import episode_rng, make_episode

    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "empty-cache"))
    monkeypatch.setenv("OSCAR_ZOO_REGISTRY", str(tmp_path / "zoo.json"))
    toy = oscar_zoo.load("oscar-toy")
    assert isinstance(toy.vae.vae, WanVAE)
    emb = Registry().get("franka")
    ep = make_episode(emb, episode_rng(0, "franka", 9), 64, 64, 17)
    skeleton = render_skeleton_video(emb, ep.trajectory, ep.camera)
    sampler = SamplerConfig(steps=2, guidance=3.0)
    ours = toy.rollout(ep.rgb[0], skeleton, sampler=sampler, progress=False).frames
    ref = build_strict(Reference, read_config(TOY_VAE, ("AutoencoderKLWan",)), load_state_dict(TOY_VAE), TOY_VAE)
    use_onednn_conv3d(ref)  # as VideoVAE sets up the VAE it wraps
    toy.vae.vae = ref
    np.testing.assert_array_equal(ours, toy.rollout(ep.rgb[0], skeleton, sampler=sampler, progress=False).frames)
