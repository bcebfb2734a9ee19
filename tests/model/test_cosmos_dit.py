"""oscar's own Cosmos DiT against diffusers' ``CosmosTransformer3DModel``, the reference: same state dict, same
config keys, same output (float32, CPU) on random weights in several small configs, and the shipped toy
transformer folder giving what diffusers computes."""

import inspect
import json

import pytest
import torch
from _paths import REPO
from diffusers import CosmosTransformer3DModel
from diffusers.models.transformers import transformer_cosmos

from oscar_core.model import CheckpointLayoutError, ModelInputError
from oscar_core.model._resize import _SHIM
from oscar_core.model.cosmos_dit import CosmosDiT
from oscar_core.model.tiny import TINY_TRANSFORMER_CONFIG, randomise

pytestmark = pytest.mark.usefixtures("one_thread")

TOY_TRANSFORMER = REPO / "zoo" / "assets" / "oscar-toy" / "transformer"

#: small configs around the tiny one: text projection or not, learnt positions or not, padding mask or not,
#: other patch sizes, the 2B model's RoPE scale
CONFIGS = {
    "tiny": {},
    "plain-text": dict(use_crossattn_projection=False, text_embed_dim=48),
    "no-extra-pos": dict(extra_pos_embed_type=None, rope_scale=(1.0, 3.0, 3.0)),
    "no-padding-mask": dict(concat_padding_mask=False),
    "patch-1x1x1": dict(patch_size=(1, 1, 1), rope_scale=(2.0, 1.0, 1.0), attention_head_dim=12),
    "patch-2x2x2": dict(patch_size=(2, 2, 2), max_size=(16, 32, 32), num_attention_heads=3, attention_head_dim=16),
}
B, T, H, W = 2, 4, 4, 8


@pytest.fixture
def reference_runs_without_torchvision(monkeypatch):
    """diffusers' forward resizes the padding mask with torchvision; the torch-only stand-in does the same."""
    monkeypatch.setattr(transformer_cosmos, "transforms", _SHIM, raising=False)


def _pair(overrides: dict, seed: int = 0):
    """(reference, ours): diffusers' model with every weight random, and ours holding the same state dict."""
    config = {**TINY_TRANSFORMER_CONFIG, **overrides}
    reference = CosmosTransformer3DModel(**config).eval()
    randomise(reference, seed, 0.05)
    g = torch.Generator().manual_seed(seed + 100)
    with torch.no_grad():  # q/k norm gains near 2: sharp attention, so positions and masks show in the output
        for name, p in reference.named_parameters():
            if ".norm_q." in name or ".norm_k." in name:
                p.copy_(2 + 0.5 * torch.randn(p.shape, generator=g))
    ours = CosmosDiT(**config).eval()
    ours.load_state_dict(reference.state_dict(), strict=True)
    return reference, ours


def _inputs(model, per_frame_t: bool, seed: int = 1, fps=None):
    g = torch.Generator().manual_seed(seed)
    cfg = model.config
    x = torch.randn(B, cfg.out_channels, T, H, W, generator=g)
    cond = torch.zeros(B, 1, T, H, W)
    cond[:, :, :1] = 1
    t = torch.rand(B, 1, T, 1, 1, generator=g) if per_frame_t else torch.rand(B, generator=g)
    text_dim = cfg.crossattn_proj_in_channels if cfg.use_crossattn_projection else cfg.text_embed_dim
    kwargs = dict(
        hidden_states=x,
        timestep=t,
        encoder_hidden_states=torch.randn(B, 5, text_dim, generator=g),
        condition_mask=cond,
        fps=fps,
    )
    if cfg.concat_padding_mask:
        kwargs["padding_mask"] = (torch.rand(1, 1, 8 * H, 8 * W, generator=g) > 0.7).float()
    return kwargs


def _both(reference, ours, kwargs):
    with torch.no_grad():
        return reference(**kwargs).sample, ours(**kwargs).sample


@pytest.mark.parametrize("name", sorted(CONFIGS))
@pytest.mark.parametrize("per_frame_t", [True, False])
def test_forward_equals_diffusers(reference_runs_without_torchvision, name, per_frame_t):
    overrides = CONFIGS[name]
    if per_frame_t and overrides.get("patch_size", (1,))[0] != 1:
        pytest.skip("one timestep per latent frame needs temporal patch 1 (diffusers' assumption too)")
    reference, ours = _pair(overrides, seed=len(name))
    expected, got = _both(reference, ours, _inputs(ours, per_frame_t, fps=16 if per_frame_t else None))
    assert got.shape == expected.shape == (B, ours.config.out_channels, T, H, W)
    assert (got - expected).abs().max().item() <= 1e-5
    assert expected.abs().max() > 1e-2  # random weights everywhere: a real output, not zeros


def test_text_mask_and_controlnet_residuals_equal_diffusers(reference_runs_without_torchvision):
    reference, ours = _pair(dict(controlnet_block_every_n=1), seed=3)
    kwargs = _inputs(ours, per_frame_t=True)
    g = torch.Generator().manual_seed(4)
    mask = torch.ones(B, 5, dtype=torch.bool)
    mask[1, 3:] = False
    tokens = T * (H // 2) * (W // 2)
    residuals = [torch.randn(B, tokens, 64, generator=g) * 0.1 for _ in range(2)]
    kwargs.update(attention_mask=mask, block_controlnet_hidden_states=residuals)
    expected, got = _both(reference, ours, kwargs)
    assert (got - expected).abs().max().item() <= 1e-5
    without = _both(reference, ours, {**kwargs, "attention_mask": None, "block_controlnet_hidden_states": None})[1]
    assert (got - without).abs().max() > 1e-3  # both inputs do change the output


def test_same_parameters_in_the_same_order_and_the_same_seeded_init():
    """Parameter order and default init as diffusers': a seeded model (training's default init, the tiny preset's
    ``randomise``) draws the same numbers."""
    torch.manual_seed(5)
    reference = CosmosTransformer3DModel(**TINY_TRANSFORMER_CONFIG)
    torch.manual_seed(5)
    ours = CosmosDiT(**TINY_TRANSFORMER_CONFIG)
    ref_state, state = reference.state_dict(), ours.state_dict()
    assert list(state) == list(ref_state)
    assert all(torch.equal(state[k], v) for k, v in ref_state.items())
    assert [n for n, _ in ours.named_parameters()] == [n for n, _ in reference.named_parameters()]


def test_config_keys_and_folders_interchange_with_diffusers(tmp_path, reference_runs_without_torchvision):
    from safetensors.torch import load_file

    diffusers_keys = list(inspect.signature(CosmosTransformer3DModel.__init__).parameters)[1:]
    assert CosmosDiT.config_keys() == diffusers_keys
    reference, ours = _pair({}, seed=6)
    reference.save_pretrained(tmp_path / "theirs")
    ours.save_pretrained(tmp_path / "ours")
    assert json.loads((tmp_path / "ours" / "config.json").read_text())["_class_name"] == "CosmosTransformer3DModel"
    from_theirs = CosmosDiT.from_config(json.loads((tmp_path / "theirs" / "config.json").read_text()))
    from_theirs.load_state_dict(reference.state_dict(), strict=True)
    from_ours = CosmosTransformer3DModel.from_config(CosmosTransformer3DModel.load_config(tmp_path / "ours")).eval()
    from_ours.load_state_dict(load_file(str(tmp_path / "ours" / "diffusion_pytorch_model.safetensors")), strict=True)
    kwargs = _inputs(ours, per_frame_t=True)
    with torch.no_grad():
        assert torch.equal(from_theirs.eval()(**kwargs).sample, ours(**kwargs).sample)
        assert torch.equal(from_ours(**kwargs).sample, reference(**kwargs).sample)


@pytest.mark.parametrize(
    "field, value",
    [("img_context_dim_in", 1024), ("extra_pos_embed_type", "sincos"), ("attention_head_dim", 10)],
)
def test_unimplemented_settings_are_refused_naming_config_json_and_the_field(field, value):
    with pytest.raises(CheckpointLayoutError, match=f"config.json: {field}: expected .*, found {value!r}"):
        CosmosDiT.from_config({**TINY_TRANSFORMER_CONFIG, field: value})


def test_bad_inputs_are_refused_before_work():
    _, ours = _pair({}, seed=7)
    kwargs = _inputs(ours, per_frame_t=True)
    with pytest.raises(ModelInputError, match=r"timestep: expected .* found \(2, 1, 3, 1, 1\)"):
        ours(**{**kwargs, "timestep": torch.rand(B, 1, T - 1, 1, 1)})
    with pytest.raises(ModelInputError, match="latent grid: expected at most"):
        ours(
            **{**kwargs, "hidden_states": torch.randn(B, 16, T, 128, W), "condition_mask": torch.zeros(B, 1, T, 128, W)}
        )
    with pytest.raises(ModelInputError, match="controlnet_block_every_n = None"):
        ours(**kwargs, block_controlnet_hidden_states=[torch.zeros(1)])


def test_gradient_checkpointing_gives_the_same_gradients():
    _, ours = _pair({}, seed=8)
    kwargs = _inputs(ours, per_frame_t=True)
    grads = []
    for checkpointing in (False, True):
        ours.zero_grad()
        ours.enable_gradient_checkpointing() if checkpointing else ours.disable_gradient_checkpointing()
        ours(**kwargs).sample.square().mean().backward()
        grads.append({n: p.grad.clone() for n, p in ours.named_parameters() if p.grad is not None})
    assert grads[0].keys() == grads[1].keys() and len(grads[0]) == len(list(ours.parameters()))
    assert all(torch.allclose(grads[0][n], grads[1][n], rtol=0, atol=1e-7) for n in grads[0])


def test_bfloat16_keeps_the_learnt_positions_in_float32_and_runs():
    from oscar_core.model.weights import cast_model

    _, ours = _pair({}, seed=9)
    cast_model(ours, dtype=torch.bfloat16)
    assert ours.dtype == torch.bfloat16 and ours.learnable_pos_embed.pos_emb_t.dtype == torch.float32
    kwargs = _inputs(ours, per_frame_t=True)
    kwargs = {k: v.to(torch.bfloat16) if isinstance(v, torch.Tensor) else v for k, v in kwargs.items()}
    with torch.no_grad():
        out = ours(**kwargs).sample
    assert out.dtype == torch.bfloat16 and torch.isfinite(out.float()).all()


class _PatchesPlusSkeleton(torch.nn.Module):
    """PE_v(x) + PE_s(skeleton): the skeleton tokens summed right after the patch embedder, as oscar's DiT does."""

    def __init__(self, patch_embed, skeleton_embed, skeleton):
        super().__init__()
        self.patch_embed, self.skeleton_embed, self.skeleton = patch_embed, skeleton_embed, skeleton

    def forward(self, x):
        return self.patch_embed(x) + self.skeleton_embed(self.skeleton)


def test_shipped_toy_transformer_loads_strictly_and_equals_diffusers(reference_runs_without_torchvision):
    """The oscar-toy folder, loaded strictly, against diffusers' class holding the same weights with the skeleton
    tokens added after its patch embedder."""
    from oscar_core.model.transformer import OscarTransformer3DModel

    ours = OscarTransformer3DModel.load_strict(TOY_TRANSFORMER)
    config = json.loads((TOY_TRANSFORMER / "config.json").read_text())
    settings = {k: v for k, v in config.items() if not k.startswith("_") and k != "skeleton_channels"}
    reference = CosmosTransformer3DModel(**settings).eval()
    state = ours.state_dict()
    reference.load_state_dict({k: v for k, v in state.items() if not k.startswith("skeleton_embed.")}, strict=True)
    assert torch.count_nonzero(state["skeleton_embed.proj.weight"]) > 0  # a trained PE_s: the skeleton matters
    kwargs = _inputs(ours, per_frame_t=True, seed=10, fps=10)
    skeleton = torch.randn(B, 16, T, H, W, generator=torch.Generator().manual_seed(11))
    reference.patch_embed = _PatchesPlusSkeleton(reference.patch_embed, ours.skeleton_embed, skeleton)
    with torch.no_grad():
        expected = reference(**kwargs).sample
        got = ours(**kwargs, skeleton_latents=skeleton).sample
    assert (got - expected).abs().max().item() <= 1e-5
