"""The torch-only padding-mask resize reproduces torchvision's tensor resize (NEAREST).

Oracle: torchvision's tensor path (transforms/functional.py → _functional_tensor.py)
returns the input when the size matches, else casts non-float32/64 inputs to
float32, calls interpolate(mode="nearest"), and casts back (rounding integer
dtypes). PyTorch's legacy "nearest" reads source index min(floor(i·s), in−1)
with s = in/out in float32 (i when sizes match, i>>1 for an exact 2x
upscale). The expected values below are built from that formula in numpy,
independently of torch.nn.functional.
"""

import numpy as np
import pytest
import torch

from oscar_core.model import resize_padding_mask
from oscar_core.model._resize import install_torchvision_free_resize


def _nearest_indices(n_in: int, n_out: int) -> np.ndarray:
    if n_in == n_out:
        return np.arange(n_out)
    if n_out == 2 * n_in:
        return np.arange(n_out) >> 1
    scale = np.float32(n_in) / np.float32(n_out)
    return np.minimum(np.floor(np.arange(n_out, dtype=np.float32) * scale).astype(np.int64), n_in - 1)


def _oracle(mask: np.ndarray, size) -> np.ndarray:
    rows, cols = _nearest_indices(mask.shape[-2], size[0]), _nearest_indices(mask.shape[-1], size[1])
    return mask[..., rows, :][..., :, cols]


# pixel size -> latent size (÷8) for the resolutions oscar uses, plus odd and upscaling cases
SIZES = [
    ((704, 1280), (88, 160)),
    ((288, 512), (36, 64)),
    ((480, 640), (60, 80)),
    ((32, 64), (4, 8)),
    ((37, 23), (8, 5)),
    ((5, 7), (10, 14)),
    ((6, 4), (9, 11)),
]


@pytest.mark.parametrize("src,dst", SIZES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16, torch.uint8])
def test_nearest_matches_torchvision_semantics(src, dst, dtype):
    g = torch.Generator().manual_seed(src[0] * 7 + dst[1])
    mask = (torch.rand(1, 1, *src, generator=g) > 0.5).to(dtype)
    out = resize_padding_mask(mask, dst)
    assert out.shape == (1, 1, *dst) and out.dtype == dtype
    expected = _oracle(mask.float().numpy(), dst)
    np.testing.assert_array_equal(out.float().numpy(), expected)


def test_three_dim_input_and_identity():
    mask = (torch.rand(1, 16, 24) > 0.5).float()
    assert resize_padding_mask(mask, (16, 24)) is mask  # torchvision returns the input itself
    out = resize_padding_mask(mask, (4, 6))
    assert out.shape == (1, 4, 6)
    np.testing.assert_array_equal(out.numpy(), _oracle(mask.numpy(), (4, 6)))


def test_only_nearest_is_accepted():
    with pytest.raises(ValueError, match="nearest"):
        resize_padding_mask(torch.zeros(1, 1, 8, 8), (4, 4), interpolation="bilinear")


def test_install_shim_only_where_torchvision_is_missing(monkeypatch):
    from diffusers.models.controlnets import controlnet_cosmos
    from diffusers.models.transformers import transformer_cosmos

    for module in (transformer_cosmos, controlnet_cosmos):  # start without the name; undo leaves it absent again
        monkeypatch.setattr(module, "transforms", None, raising=False)
        monkeypatch.delattr(module, "transforms")
    patched = install_torchvision_free_resize()
    assert "diffusers.models.transformers.transformer_cosmos" in patched
    tv = transformer_cosmos.transforms
    mask = torch.ones(1, 1, 16, 16)
    out = tv.functional.resize(mask, [2, 2], interpolation=tv.InterpolationMode.NEAREST)
    assert out.shape == (1, 1, 2, 2)
    assert install_torchvision_free_resize() == []  # present now: nothing to do
