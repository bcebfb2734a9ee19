"""3-D convolutions of one clip on the CPU through oneDNN (oscar_core/model/cpu_conv.py)."""

from __future__ import annotations

import copy

import pytest
import torch
from torch import nn

from oscar_core.model.cpu_conv import onednn_available, use_onednn_conv3d

pytestmark = pytest.mark.skipif(not onednn_available(), reason="this PyTorch has no oneDNN on the CPU")


def _aten_ops(fn) -> set[str]:
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
        fn()
    return {e.name for e in prof.events()}


def _conv(kernel=3, stride=1, padding=1) -> nn.Conv3d:
    torch.manual_seed(0)
    return nn.Conv3d(8, 6, kernel, stride=stride, padding=padding)


@pytest.mark.parametrize(("kernel", "stride", "padding"), [(3, 1, 1), (3, 2, 0), ((1, 3, 3), 1, (0, 1, 1))])
def test_one_clip_runs_on_onednn_and_equals_the_reference_convolution(kernel, stride, padding):
    conv = _conv(kernel, stride, padding)
    x = torch.randn(1, 8, 5, 12, 12)
    with torch.no_grad():
        want = nn.functional.conv3d(x, conv.weight, conv.bias, stride, padding)
        assert "aten::slow_conv3d_forward" in _aten_ops(lambda: conv(x))  # PyTorch's own choice at batch 1
        assert use_onednn_conv3d(conv) == 1
        got = conv(x)
        ops = _aten_ops(lambda: conv(x))
    assert "aten::mkldnn_convolution" in ops and "aten::slow_conv3d_forward" not in ops
    assert got.shape == want.shape
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)


def test_what_keeps_the_layer_own_path():
    conv = _conv()
    use_onednn_conv3d(conv)
    x = torch.randn(1, 8, 5, 12, 12)
    # a call that needs gradients: PyTorch's own (differentiable) path, and the gradient flows
    out = conv(x.requires_grad_())
    assert "aten::mkldnn_convolution" not in _aten_ops(lambda: conv(x))
    out.sum().backward()
    assert x.grad is not None and conv.weight.grad is not None
    # another dtype and a 1x1 kernel
    with torch.no_grad():
        assert "aten::mkldnn_convolution" not in _aten_ops(lambda: conv.double()(x.detach().double()))
        one = nn.Conv3d(8, 4, 1)
        use_onednn_conv3d(one)
        assert "aten::mkldnn_convolution" not in _aten_ops(lambda: one(x.detach()))


def test_state_dict_copies_and_repeat_calls_are_unchanged():
    net = nn.Sequential(_conv(), nn.SiLU(), nn.Conv3d(6, 3, 3, padding=1))
    before = {k: v.clone() for k, v in net.state_dict().items()}
    assert use_onednn_conv3d(net) == 2 and use_onednn_conv3d(net) == 2
    assert net.state_dict().keys() == before.keys()
    twin = copy.deepcopy(net)
    x = torch.randn(1, 8, 5, 12, 12)
    with torch.no_grad():
        twin[0].weight.mul_(2.0)  # the copy's layers use the copy's weights, not the original's
        assert not torch.allclose(twin(x), net(x))
        assert "aten::mkldnn_convolution" in _aten_ops(lambda: twin(x))


def test_the_vae_decodes_one_clip_on_onednn_and_as_in_a_batch():
    from tests._models import tiny_world_model

    vae = tiny_world_model(seed=0).vae
    torch.manual_seed(1)
    lat = torch.randn(3, vae.z_dim, 2, 4, 4)
    with torch.no_grad():
        ops = _aten_ops(lambda: vae.decode(lat[:1]))
        alone = torch.cat([vae.decode(lat[i : i + 1]) for i in range(3)])
        batch = vae.decode(lat)
    assert "aten::mkldnn_convolution" in ops  # (its 1x1 layers keep PyTorch's path)
    torch.testing.assert_close(alone, batch, rtol=0, atol=1e-5)


def test_a_compiled_module_falls_back_to_the_plain_convolution_and_matches():
    """torch.compile traces the layer with fake tensors, for which aten.mkldnn_convolution has no rule: while
    compiling, the layer takes PyTorch's own path (the compiled VAE of ``benchmarks/rollout.py --vae-variants``); inductor, as they compile it."""
    conv = _conv()
    x = torch.randn(1, 8, 5, 12, 12)
    use_onednn_conv3d(conv)
    with torch.no_grad():
        want = nn.functional.conv3d(x, conv.weight, conv.bias, 1, 1)
        got = torch.compile(
            conv,
            dynamic=False,
        )(x)
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)
