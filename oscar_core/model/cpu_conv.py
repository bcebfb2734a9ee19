"""3-D convolutions of a single clip on the CPU through oneDNN, as a batch of several already runs.

PyTorch picks the CPU backend of a float32 ``Conv3d`` per call: oneDNN (``mkldnn``) when the batch holds more than
one clip, the input is large or the kernel is wider than 3 pixels; otherwise its im2col path (``slow_conv3d``).
The WAN VAE's 3x3x3 convolutions of one 64x64 clip fall on the im2col path, which on one thread is 2 to 7 times
slower than oneDNN on the same input (docs/closed-loop.md has the figures) — so a batch of one paid that much
more per clip than a batch of four in every VAE encode and decode.

:func:`use_onednn_conv3d` makes the ``Conv3d`` layers of a module call oneDNN (``aten.mkldnn_convolution``)
themselves for float32 CPU inputs with a kernel larger than 1x1 in space, whatever the batch; anything else (a GPU,
another dtype, a 1x1 kernel, a padding mode other than zeros, a call that needs gradients) takes the layer's own
path. Both backends compute the same convolution; the outputs differ by float rounding (about 1e-4 on unit-scale
activations).
"""

from __future__ import annotations

import types

import torch
from torch import nn

__all__ = ["use_onednn_conv3d", "onednn_available"]


def onednn_available() -> bool:
    """Whether this PyTorch has oneDNN on the CPU and its convolution op."""
    return bool(torch.backends.mkldnn.is_available()) and hasattr(torch.ops.aten, "mkldnn_convolution")


def _fast(conv: nn.Conv3d, x: torch.Tensor, weight: torch.Tensor, bias) -> bool:
    if torch.compiler.is_compiling():
        return False  # inductor has no fake-tensor rule for aten.mkldnn_convolution; it picks its own kernel
    if x.device.type != "cpu" or x.dtype != torch.float32 or weight.dtype != torch.float32:
        return False
    if not torch.backends.mkldnn.enabled or conv.padding_mode != "zeros" or isinstance(conv.padding, str):
        return False
    if weight.shape[-1] == 1 and weight.shape[-2] == 1:
        return False  # a 1x1 kernel: PyTorch's own path is as fast on one thread
    grads = x.requires_grad or weight.requires_grad or (bias is not None and bias.requires_grad)
    return not (grads and torch.is_grad_enabled())


def _conv_forward(self: nn.Conv3d, x: torch.Tensor, weight: torch.Tensor, bias) -> torch.Tensor:
    if _fast(self, x, weight, bias):
        return torch.ops.aten.mkldnn_convolution(
            x, weight, bias, list(self.padding), list(self.stride), list(self.dilation), self.groups
        )
    return nn.Conv3d._conv_forward(self, x, weight, bias)


def use_onednn_conv3d(module: nn.Module) -> int:
    """Route the ``Conv3d`` layers of ``module`` through oneDNN on the CPU (module docstring); returns how many
    layers now do (0 when this PyTorch has no oneDNN). Idempotent; the weights and the state dict are unchanged."""
    if not onednn_available():
        return 0
    count = 0
    for layer in module.modules():
        if isinstance(layer, nn.Conv3d):
            if "_conv_forward" not in vars(layer):
                layer._conv_forward = types.MethodType(_conv_forward, layer)
            count += 1
    return count
