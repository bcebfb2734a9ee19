"""Pure-torch resize of the Cosmos padding mask (no torchvision).

diffusers' ``CosmosTransformer3DModel.forward`` resizes its padding mask with
``torchvision.transforms.functional.resize(mask, [h, w],
interpolation=InterpolationMode.NEAREST)``. torchvision wheels break beside
the torch build oscar runs on, so :func:`resize_padding_mask` reproduces that
call with torch alone. What torchvision does for a tensor (read from its
``transforms/functional.py`` and ``_functional_tensor.py``):

1. if the size already matches, return the input unchanged (same object);
2. add a batch dimension to a 2-D/3-D tensor (``(C, H, W)`` → ``(1, C, H, W)``);
3. cast to float32 unless the tensor is float32/float64;
4. ``torch.nn.functional.interpolate(x, size, mode="nearest")`` (legacy
   "nearest": source index ``min(floor(i * in / out), in - 1)``, not
   "nearest-exact"; no antialias for nearest);
5. undo 2 and 3 (integer dtypes are rounded before the cast back).

diffusers' Cosmos code only uses NEAREST for this mask; bilinear is not
needed and is refused rather than half-supported.

:func:`install_torchvision_free_resize` lets the *unmodified* diffusers
classes run without torchvision too (e.g. the plain base model used as a
test oracle): it puts a tiny stand-in for the ``transforms`` name into the
diffusers Cosmos modules' namespace, only when torchvision is absent, and
never touches files in site-packages. oscar's own transformer does not need
it: its forward calls :func:`resize_padding_mask` directly.
"""

from __future__ import annotations

import importlib
import types

import torch
import torch.nn.functional as F

__all__ = ["resize_padding_mask", "install_torchvision_free_resize"]

_FLOAT_OK = (torch.float32, torch.float64)
_INTEGER = (torch.uint8, torch.int8, torch.int16, torch.int32, torch.int64)


def resize_padding_mask(mask: torch.Tensor, size, interpolation: str = "nearest") -> torch.Tensor:
    """Resize ``mask`` to ``size`` exactly as torchvision's tensor ``resize`` with NEAREST does.

    mask: (..., H, W) tensor with 2 to 4 dimensions, e.g. the Cosmos padding
        mask (1, 1, H_px, W_px) with 1 = padded pixel, 0 = image.
    size: (h, w) output size in pixels (latent pixels for Cosmos).
    returns: (..., h, w) tensor of ``mask``'s dtype; ``mask`` itself when the
        size already matches (as torchvision does).
    """
    if interpolation != "nearest":
        raise ValueError(
            f"resize_padding_mask: interpolation: expected 'nearest' (the only mode diffusers' Cosmos "
            f"code uses for the padding mask), found {interpolation!r}"
        )
    if not isinstance(mask, torch.Tensor) or not 2 <= mask.ndim <= 4:
        found = f"{type(mask).__name__} with {getattr(mask, 'ndim', '?')} dims"
        raise ValueError(f"resize_padding_mask: mask: expected a tensor of 2 to 4 dims (..., H, W), found {found}")
    h, w = (int(v) for v in size)
    if (mask.shape[-2], mask.shape[-1]) == (h, w):
        return mask
    x = mask
    squeeze = 0
    while x.ndim < 4:
        x = x.unsqueeze(0)
        squeeze += 1
    out_dtype = x.dtype
    cast = out_dtype not in _FLOAT_OK
    if cast:
        x = x.to(torch.float32)
    x = F.interpolate(x, size=[h, w], mode="nearest")
    for _ in range(squeeze):
        x = x.squeeze(0)
    if cast:
        if out_dtype in _INTEGER:
            x = torch.round(x)
        x = x.to(out_dtype)
    return x


class _InterpolationMode:
    NEAREST = "nearest"


def _shim_resize(img, size, interpolation="nearest", max_size=None, antialias=None):
    if max_size is not None or len(size) != 2:
        raise ValueError("oscar's torchvision-free resize supports only an explicit [h, w] size")
    return resize_padding_mask(img, size, interpolation=str(getattr(interpolation, "value", interpolation)))


_SHIM = types.SimpleNamespace(
    functional=types.SimpleNamespace(resize=_shim_resize), InterpolationMode=_InterpolationMode
)
_MODULES = ("diffusers.models.transformers.transformer_cosmos", "diffusers.models.controlnets.controlnet_cosmos")


def install_torchvision_free_resize() -> list[str]:
    """Give diffusers' Cosmos modules a ``transforms`` stand-in when torchvision is missing.

    Only sets the module-level name ``transforms`` where it is undefined (i.e.
    where diffusers skipped ``from torchvision import transforms``); a real
    torchvision, if present, is left alone. Returns the patched module names.
    """
    patched = []
    for name in _MODULES:
        try:
            module = importlib.import_module(name)
        except ImportError:
            continue
        if not hasattr(module, "transforms"):
            module.transforms = _SHIM
            patched.append(name)
    return patched
