"""The Wan VAE's RMS norm: the sum-of-squares norm (``channel_norm_by_sums``) is torch's own L2 norm bit for bit,
and :class:`RMSNorm` gives ``F.normalize``'s values (diffusers' ``WanRMS_norm``) on every path it takes.

The bit-identity rests on how the installed torch's CPU kernels add (the norm one channel after another per position,
the sum likewise over its first 16 rows); a torch whose kernels add in another order fails here first. The VAE as a
whole is compared with diffusers' class in test_wan_vae.py (the toy folder and the toy rollout take the fast path).
"""

import pytest
import torch
import torch.nn.functional as F

from oscar_core.model import _wan_vae_layers as layers
from oscar_core.model._wan_vae_layers import SUM_NORM_MIN_ELEMENTS, RMSNorm, channel_norm_by_sums


def _activations(shape, seed: int, layout: str = "contiguous") -> torch.Tensor:
    """Values over many magnitudes (a spread of scales per channel, some all-zero pixels) in the given memory layout:
    ``contiguous``; ``time_outer`` (B, T, C, H, W) in memory, as some of the VAE's convolution outputs are."""
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(shape, generator=g) * torch.logspace(-3, 3, shape[1]).reshape(1, -1, *[1] * (len(shape) - 2))
    x.view(shape[0], shape[1], -1)[:, :, ::97] = 0.0
    if layout == "time_outer":
        x = x.transpose(1, 2).contiguous().transpose(1, 2)
    return x


CHANNELS = [1, 3, 15, 16, 17, 31, 32, 33, 48, 96]
SHAPES = [(1, 4, 64, 64), (2, 1, 32, 32), (4, 2, 32, 32), (1, 1, 16, 72), (3, 1, 1, 2048)]


@pytest.mark.parametrize("channels", CHANNELS)
@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("layout", ["contiguous", "time_outer"])
def test_the_sum_of_squares_norm_is_torchs_norm_bit_for_bit(channels, shape, layout):
    b, *rest = shape
    x = _activations((b, channels, *rest), seed=channels, layout=layout)
    assert x.stride(1) != 1
    assert torch.equal(channel_norm_by_sums(x), torch.linalg.vector_norm(x, 2, dim=1, keepdim=True))


def _reference(norm: RMSNorm, x: torch.Tensor) -> torch.Tensor:
    """diffusers' ``WanRMS_norm.forward`` for float32 (no bias)."""
    return F.normalize(x, dim=1) * norm.scale * norm.gamma


def _perturbed(channels: int, images: bool) -> RMSNorm:
    norm = RMSNorm(channels, images=images)
    with torch.no_grad():
        norm.gamma.add_(torch.randn(norm.gamma.shape, generator=torch.Generator().manual_seed(5)))
    return norm


@pytest.mark.parametrize(
    "shape, images, layout, fast",
    [
        ((1, 16, 4, 64, 64), False, "contiguous", True),
        ((2, 32, 2, 32, 32), False, "time_outer", True),
        ((1, 48, 64, 64), True, "contiguous", True),
        ((1, 32, 1, 16, 16), False, "contiguous", False),  # 256 per channel: F.normalize is faster there
    ],
)
def test_rms_norm_without_autograd_is_the_references_and_takes_the_fast_path_where_it_pays(
    monkeypatch, shape, images, layout, fast
):
    calls = []
    monkeypatch.setattr(layers, "channel_norm_by_sums", lambda x: calls.append(1) or channel_norm_by_sums(x))
    norm = _perturbed(shape[1], images)
    x = _activations(shape, seed=1, layout=layout)
    with torch.no_grad():
        want = _reference(norm, x)
        assert torch.equal(norm(x), want)
    assert len(calls) == (1 if fast else 0)
    assert (x[0, 0].numel() >= SUM_NORM_MIN_ELEMENTS) == fast


def test_channels_last_inputs_keep_f_normalize():
    """oneDNN convolutions hand back channels-last tensors: torch reduces their contiguous channels with vector
    instructions in another order, so they keep the reference's operation."""
    norm = _perturbed(32, images=False)
    x = _activations((1, 32, 4, 64, 64), seed=2).to(memory_format=torch.channels_last_3d)
    with torch.no_grad():
        assert not layers._sum_norm_applies(x)
        assert torch.equal(norm(x), _reference(norm, x))


def test_a_zero_pixel_gives_zeros_as_the_references_eps_does():
    """eps bounds the norm (1e-12), not the mean square: an all-zero channel vector stays zero, never NaN."""
    norm = _perturbed(16, images=False)
    x = torch.zeros(1, 16, 1, 32, 32)
    x[0, :, 0, 0, 0] = 1e-20  # a norm below eps: divided by eps, as F.normalize does
    with torch.no_grad():
        assert layers._sum_norm_applies(x)
        out = norm(x)
    assert torch.equal(out, _reference(norm, x))
    assert out.isfinite().all() and out[0, :, 0, 0, 1].eq(0).all()


def test_with_autograd_the_operations_and_gradients_are_the_references():
    norm = _perturbed(16, images=False)
    x = _activations((1, 16, 2, 32, 32), seed=3).requires_grad_()
    assert not layers._sum_norm_applies(x)
    out = norm(x)
    (out * out.detach().sin()).sum().backward()
    grads = x.grad.clone(), norm.gamma.grad.clone()
    x.grad, norm.gamma.grad = None, None
    ref = _reference(norm, x)
    (ref * ref.detach().sin()).sum().backward()
    assert torch.equal(out, ref)
    assert torch.equal(grads[0], x.grad) and torch.equal(grads[1], norm.gamma.grad)


def test_bfloat16_keeps_the_float32_normalisation_of_the_reference():
    norm = _perturbed(16, images=False).to(torch.bfloat16)
    x = _activations((1, 16, 2, 32, 32), seed=4).to(torch.bfloat16)
    with torch.no_grad():
        want = F.normalize(x.float(), dim=1).to(torch.bfloat16) * norm.scale * norm.gamma
        assert torch.equal(norm(x), want)
