"""The OSCAR DiT: zero-init equivalence with Cosmos, the summed skeleton tokens, loading base weights."""

import json
from pathlib import Path

import pytest
import torch
from diffusers import CosmosTransformer3DModel
from diffusers.models.transformers import transformer_cosmos

from oscar_core.model import CheckpointLayoutError, ModelInputError, OscarTransformer3DModel
from oscar_core.model._resize import _SHIM
from oscar_core.model.latent_action import LatentActionTransformer
from oscar_core.model.tiny import TINY_TRANSFORMER_CONFIG, build_tiny_transformer
from oscar_core.model.weights import meta_tensors

B, T, H, W = 2, 3, 4, 8
TOY_FOLDER = Path(__file__).resolve().parents[2] / "zoo" / "assets" / "oscar-toy" / "transformer"


@pytest.fixture
def no_torchvision_base(monkeypatch):
    """Let the unmodified diffusers forward run without torchvision, for this test only."""
    monkeypatch.setattr(transformer_cosmos, "transforms", _SHIM, raising=False)


def _base_like(model: OscarTransformer3DModel, **overrides) -> CosmosTransformer3DModel:
    base = CosmosTransformer3DModel(**{**TINY_TRANSFORMER_CONFIG, **overrides}).eval()
    base.load_state_dict({k: v for k, v in model.state_dict().items() if not k.startswith("skeleton_embed.")})
    return base


def _inputs(seed=1, per_frame_t=True, padding=True):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(B, 16, T, H, W, generator=g)
    cond = torch.zeros(B, 1, T, H, W)
    cond[:, :, 0] = 1
    t = torch.rand(B, 1, T, 1, 1, generator=g) if per_frame_t else torch.rand(B, generator=g)
    text = torch.randn(B, 5, TINY_TRANSFORMER_CONFIG["crossattn_proj_in_channels"], generator=g)
    pad = (torch.rand(1, 1, 8 * H, 8 * W, generator=g) > 0.7).float() if padding else torch.zeros(1, 1, 8 * H, 8 * W)
    skel = torch.randn(B, 16, T, H, W, generator=g)
    return dict(hidden_states=x, timestep=t, encoder_hidden_states=text, condition_mask=cond, padding_mask=pad), skel


@pytest.mark.parametrize("per_frame_t", [True, False])
def test_zero_pe_s_equals_base_model_exactly(no_torchvision_base, per_frame_t):
    model = build_tiny_transformer(seed=0)  # every weight random, PE_s zero
    base = _base_like(model)
    kwargs, skel = _inputs(per_frame_t=per_frame_t)
    with torch.no_grad():
        expected = base(**kwargs, return_dict=False)[0]
        with_skeleton = model(**kwargs, skeleton_latents=skel, return_dict=False)[0]
        without = model(**kwargs, return_dict=False)[0]
    assert with_skeleton.shape == (B, 16, T, H, W)
    assert torch.equal(with_skeleton, expected)
    assert torch.equal(without, expected)


def test_zero_pe_s_equals_base_without_padding_mask_channel():
    """Second oracle that needs no torchvision stand-in at all."""
    model = build_tiny_transformer(seed=3, concat_padding_mask=False)
    base = _base_like(model, concat_padding_mask=False)
    kwargs, skel = _inputs(seed=4)
    with torch.no_grad():
        assert torch.equal(model(**kwargs, skeleton_latents=skel).sample, base(**kwargs).sample)


def test_skeleton_tokens_are_summed_before_the_blocks(no_torchvision_base):
    """PE_v(x) + PE_s(s) == one patch embedder over the channel-concatenation [x | s] (linearity)."""
    model = build_tiny_transformer(seed=5, skeleton_scale=0.05)
    kwargs, skel = _inputs(seed=6)
    cfg = dict(TINY_TRANSFORMER_CONFIG, in_channels=17 + 16)  # base input order: [x(16), skel(16), cond, pad]
    base = CosmosTransformer3DModel(**cfg).eval()
    state = {k: v for k, v in model.state_dict().items() if not k.startswith("skeleton_embed.")}
    per_channel = 4  # p_t * p_h * p_w = 1 * 2 * 2, channel-major in the patch embedder's input
    wv, ws = state["patch_embed.proj.weight"], model.skeleton_embed.proj.weight.detach()
    state["patch_embed.proj.weight"] = torch.cat([wv[:, : 16 * per_channel], ws, wv[:, 16 * per_channel :]], dim=1)
    base.load_state_dict(state)
    with torch.no_grad():
        ours = model(**kwargs, skeleton_latents=skel).sample
        theirs = base(**{**kwargs, "hidden_states": torch.cat([kwargs["hidden_states"], skel], 1)}).sample
        plain = model(**kwargs).sample
    torch.testing.assert_close(ours, theirs, rtol=1e-4, atol=1e-5)
    assert (ours - plain).abs().max() > 1e-3  # the skeleton does change the output


def test_pe_s_is_zero_initialised_with_patch_size_of_pe_v():
    model = OscarTransformer3DModel(**TINY_TRANSFORMER_CONFIG)
    assert torch.count_nonzero(model.skeleton_embed.proj.weight) == 0
    assert model.skeleton_embed.patch_size == model.patch_embed.patch_size
    assert model.skeleton_embed.proj.bias is None
    assert model.skeleton_embed.proj.in_features == 16 * 4


def test_from_cosmos_base_folder_loads_strictly_with_zero_pe_s(tmp_path, no_torchvision_base):
    base = _base_like(build_tiny_transformer(seed=7))
    base.save_pretrained(tmp_path / "transformer")
    model = OscarTransformer3DModel.from_cosmos_base(tmp_path / "transformer")
    assert meta_tensors(model) == []
    assert torch.count_nonzero(model.skeleton_embed.proj.weight) == 0
    base_state, state = base.state_dict(), model.state_dict()
    assert set(state) - set(base_state) == {"skeleton_embed.proj.weight"}
    assert all(torch.equal(state[k], v) for k, v in base_state.items())
    kwargs, skel = _inputs(seed=8)
    with torch.no_grad():
        assert torch.equal(model(**kwargs, skeleton_latents=skel).sample, base(**kwargs).sample)


def test_from_cosmos_base_reads_sharded_weights(tmp_path):
    base = _base_like(build_tiny_transformer(seed=9))
    base.save_pretrained(tmp_path / "t", max_shard_size="200KB")
    assert (tmp_path / "t" / "diffusion_pytorch_model.safetensors.index.json").is_file()
    model = OscarTransformer3DModel.from_cosmos_base(tmp_path / "t")
    assert meta_tensors(model) == [] and all(
        torch.equal(model.state_dict()[k], v) for k, v in base.state_dict().items()
    )


def test_from_cosmos_base_in_memory_and_dtype():
    base = _base_like(build_tiny_transformer(seed=10))
    model = OscarTransformer3DModel.from_cosmos_base(base, dtype=torch.bfloat16)
    assert model.patch_embed.proj.weight.dtype == torch.bfloat16
    assert model.learnable_pos_embed.pos_emb_t.dtype == torch.float32  # kept in float32, like diffusers does


def test_from_cosmos_base_rejects_missing_or_extra_keys(tmp_path):
    from safetensors.torch import load_file, save_file

    base = _base_like(build_tiny_transformer(seed=11))
    base.save_pretrained(tmp_path / "t")
    weights = tmp_path / "t" / "diffusion_pytorch_model.safetensors"
    state = load_file(str(weights))
    state.pop("proj_out.weight")
    state["extra.weight"] = torch.zeros(2)
    save_file(state, str(weights))
    with pytest.raises(CheckpointLayoutError) as err:
        OscarTransformer3DModel.from_cosmos_base(tmp_path / "t")
    assert "proj_out.weight" in str(err.value) and "extra.weight" in str(err.value)


def test_from_cosmos_base_rejects_pickle_only_folder(tmp_path):
    folder = tmp_path / "t"
    folder.mkdir()
    (folder / "config.json").write_text(json.dumps({"_class_name": "CosmosTransformer3DModel"}))
    (folder / "diffusion_pytorch_model.bin").write_bytes(b"not loaded")
    with pytest.raises(CheckpointLayoutError, match="pickle"):
        OscarTransformer3DModel.from_cosmos_base(folder)


def test_save_pretrained_and_from_pretrained_roundtrip(tmp_path):
    model = build_tiny_transformer(seed=12, skeleton_scale=0.1)
    model.save_pretrained(tmp_path / "m")
    assert (tmp_path / "m" / "diffusion_pytorch_model.safetensors").is_file()
    for loaded in (
        OscarTransformer3DModel.from_pretrained(tmp_path / "m"),
        OscarTransformer3DModel.load_strict(tmp_path / "m"),
    ):
        assert all(torch.equal(loaded.state_dict()[k], v) for k, v in model.state_dict().items())
        assert loaded.config.skeleton_channels is None and loaded.skeleton_in_channels == 16


def test_bad_skeleton_shape_is_a_clear_error():
    model = build_tiny_transformer(seed=13)
    kwargs, skel = _inputs()
    with pytest.raises(ModelInputError, match="skeleton_latents: expected shape"):
        model(**kwargs, skeleton_latents=skel[:, :, :2])


# The Cosmos settings and defaults as the constructors spelled them out before the subclasses took **kwargs
# (diffusers' CosmosTransformer3DModel's, in its order).
COSMOS_DEFAULTS = {
    "in_channels": 16,
    "out_channels": 16,
    "num_attention_heads": 32,
    "attention_head_dim": 128,
    "num_layers": 28,
    "mlp_ratio": 4.0,
    "text_embed_dim": 1024,
    "adaln_lora_dim": 256,
    "max_size": (128, 240, 240),
    "patch_size": (1, 2, 2),
    "rope_scale": (2.0, 1.0, 1.0),
    "concat_padding_mask": True,
    "extra_pos_embed_type": "learnable",
    "use_crossattn_projection": False,
    "crossattn_proj_in_channels": 1024,
    "encoder_hidden_states_channels": 1024,
    "controlnet_block_every_n": None,
    "img_context_dim_in": None,
    "img_context_num_tokens": 256,
    "img_context_dim_out": 2048,
}
OSCAR_DEFAULTS = {**COSMOS_DEFAULTS, "skeleton_channels": None}
LATENT_ACTION_DEFAULTS = {**OSCAR_DEFAULTS, "action_frames": 80, "action_dim": 14}


@pytest.mark.parametrize(
    ("cls", "defaults"),
    [(OscarTransformer3DModel, OSCAR_DEFAULTS), (LatentActionTransformer, LATENT_ACTION_DEFAULTS)],
)
def test_subclass_configs_are_the_cosmos_settings_plus_their_own(tmp_path, cls, defaults):
    with torch.device("meta"):  # the full-size defaults: 2B parameters, so no storage
        assert list(cls().config.items()) == list(defaults.items())
    assert cls.config_keys() == list(defaults)
    shipped = json.loads((TOY_FOLDER / "config.json").read_text())
    settings = {k: v for k, v in shipped.items() if not k.startswith("_")}
    model = cls.from_config(settings)
    assert list(model.config) == list(defaults) and dict(model.config) == {**defaults, **settings}
    model.save_pretrained(tmp_path / "m")
    written = json.loads((tmp_path / "m" / "config.json").read_text())
    assert {k: v for k, v in written.items() if k != "_diffusers_version"} == {
        **{k: list(v) if isinstance(v, tuple) else v for k, v in defaults.items()},
        **settings,
        "_class_name": cls.config_class_name,
    }
    with pytest.raises(CheckpointLayoutError, match="colour") as err:
        cls.from_config({**settings, "colour": "red"}, source="some/config.json")
    assert f"only settings {cls.__name__} takes ({', '.join(defaults)})" in str(err.value)
    with pytest.raises(TypeError, match="colour"):
        cls(colour="red")
