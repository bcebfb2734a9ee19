"""Training on a GPU: activation checkpointing (full / none / auto by the computed memory model) and model.compile."""

import copy

import pytest
import torch

from oscar_core.train import memory
from oscar_core.train.config import TrainConfigError, config_from_dict
from oscar_core.train.models import build_transformer, prepare_for_training

BASE = {
    "run_dir": "runs/x",
    "model": {"transformer": "tiny", "vae": "tiny"},
    "data": {"clips": ["clips"], "window": 9, "width": 32, "height": 32},
}


def _config(**top):
    model = top.pop("model", {})
    return config_from_dict({**BASE, **top, "model": {**BASE["model"], **model}})


def _inputs(seed=0, frames=3, h=4, w=4):
    g = torch.Generator().manual_seed(seed)
    return dict(
        hidden_states=torch.randn(2, 16, frames, h, w, generator=g),
        timestep=torch.rand(2, 1, frames, 1, 1, generator=g),
        encoder_hidden_states=torch.randn(2, 5, 48, generator=g),
        condition_mask=torch.zeros(2, 1, frames, h, w),
        padding_mask=torch.zeros(1, 1, h, w),
        skeleton_latents=torch.randn(2, 16, frames, h, w, generator=g),
        return_dict=False,
    )


def _loss_and_grads(model, inputs):
    model.zero_grad(set_to_none=True)
    loss = model(**inputs)[0].square().mean()
    loss.backward()
    return loss.detach(), {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}


def test_checkpointed_step_equals_the_plain_one():
    full = _config(activation_checkpointing="full")
    plain = build_transformer(full)
    ckpt = copy.deepcopy(plain)
    assert prepare_for_training(ckpt, full, "cpu")[0] == "full" and ckpt.gradient_checkpointing
    assert prepare_for_training(plain, _config(activation_checkpointing="none"), "cpu")[0] == "none"
    assert not plain.gradient_checkpointing
    inputs = _inputs()
    loss_a, grads_a = _loss_and_grads(plain, inputs)
    loss_b, grads_b = _loss_and_grads(ckpt, inputs)
    torch.testing.assert_close(loss_b, loss_a, rtol=1e-6, atol=1e-7)
    assert grads_a.keys() == grads_b.keys() and len(grads_a) > 10
    for name in grads_a:
        torch.testing.assert_close(grads_b[name], grads_a[name], rtol=1e-5, atol=1e-7, msg=name)


def test_checkpointing_saves_fewer_tensors_for_backward():
    """The switch really changes what autograd keeps (a test that fails if checkpointing were a no-op)."""
    from torch.autograd.graph import saved_tensors_hooks

    def saved_bytes(policy):
        config = _config(activation_checkpointing=policy)
        model = build_transformer(config)
        prepare_for_training(model, config, "cpu")
        total = []
        with saved_tensors_hooks(lambda t: total.append(t.numel() * t.element_size()) or t, lambda t: t):
            model(**_inputs(frames=5, h=8, w=8))[0].sum()
        return sum(total)

    assert saved_bytes("full") < 0.5 * saved_bytes("none")


def test_auto_chooses_by_free_memory(monkeypatch):
    config = _config(activation_checkpointing="auto")
    model = build_transformer(config)
    est = memory.model_estimate(model, config)
    assert est.total("full") < est.total("none")
    assert prepare_for_training(model, config, "cpu")[0] == "none"  # not a GPU
    monkeypatch.setattr(memory, "free_device_memory", lambda device: int(est.total("none") / 0.9) + 1)
    policy, why = memory.choose_checkpointing(config, model, "cuda")
    assert policy == "none" and "auto: none" in why
    monkeypatch.setattr(memory, "free_device_memory", lambda device: int(est.total("none")))  # over 90 % of it
    policy, why = memory.choose_checkpointing(config, model, "cuda")
    assert policy == "full" and "auto: full" in why
    assert prepare_for_training(model, config, "cuda:0")[0] == "full" and model.gradient_checkpointing


def test_memory_model_adds_up():
    p, block, layers, hidden, tokens = 1000, 100, 4, 64, 50
    est = memory.estimate_memory(p, block, layers, hidden, tokens, micro_batch=2, shards=2)
    per_token = memory.ACT_BYTES_PER_TOKEN_PER_WIDTH * hidden
    assert est.state == 20 * p / 2 and est.autocast_weights == 2 * p and est.optimizer_temporaries == 4 * p / 2
    assert est.gathered == 8 * block
    assert est.activations_none == pytest.approx(per_token * tokens * 2 * layers)
    assert est.activations_full == pytest.approx(4 * hidden * tokens * 2 * layers + per_token * tokens * 2)
    fp32 = memory.estimate_memory(p, block, layers, hidden, tokens, bf16_autocast=False, fused_adamw=True)
    assert fp32.autocast_weights == 0 and fp32.optimizer_temporaries == 0 and fp32.gathered == 0
    assert fp32.activations_none == pytest.approx(2 * per_token * tokens * layers)
    assert memory.tokens_per_clip(81, 512, 288) == 21 * 18 * 32  # the 2B recipe's 12,096 tokens


@pytest.mark.parametrize(
    "override, field, found",
    [
        ({"activation_checkpointing": "some"}, "activation_checkpointing", "'some'"),
        ({"model": {"compile": "yes"}}, "model.compile", "str 'yes'"),
    ],
)
def test_bad_settings_are_clear_errors(override, field, found):
    with pytest.raises(TrainConfigError) as info:
        _config(**copy.deepcopy(override))
    assert info.value.field == field and info.value.found == found


@pytest.mark.slow
def test_compiled_step_equals_eager():
    """torch.compile (inductor, CPU) of every block: the same loss and gradients as eager, the same weight names."""
    try:
        import torch._inductor
    except ImportError as exc:  # pragma: no cover - a torch without inductor
        pytest.skip(f"inductor unavailable: {exc}")
    config = _config(model={"compile": True}, activation_checkpointing="none")
    eager = build_transformer(config)
    compiled = copy.deepcopy(eager)
    prepare_for_training(compiled, config, "cpu")
    assert compiled.state_dict().keys() == eager.state_dict().keys()
    assert all(b._compiled_call_impl is not None for b in compiled.transformer_blocks)
    inputs = _inputs()
    loss_a, grads_a = _loss_and_grads(eager, inputs)
    try:
        loss_b, grads_b = _loss_and_grads(compiled, inputs)
    except Exception as exc:
        if "CppCompileError" in type(exc).__name__ + str(exc) or "InvalidCxxCompiler" in str(exc):
            pytest.skip(f"inductor cannot build C++ here: {type(exc).__name__}")
        raise
    torch.testing.assert_close(loss_b, loss_a, rtol=1e-4, atol=1e-6)
    for name in grads_a:
        torch.testing.assert_close(grads_b[name], grads_a[name], rtol=1e-3, atol=1e-5, msg=name)


def test_the_estimate_counts_tokens_at_the_vaes_compression():
    config = _config()
    model = build_transformer(config)
    wan, toy = memory.model_estimate(model, config), memory.model_estimate(model, config, compression=(4, 4))
    d = config.data
    assert memory.tokens_per_clip(d.window, d.width, d.height, (1, 2, 2), 4, 4) == 4 * memory.tokens_per_clip(
        d.window, d.width, d.height, (1, 2, 2), 4, 8
    )
    assert toy.activations_none == pytest.approx(4 * wan.activations_none)
