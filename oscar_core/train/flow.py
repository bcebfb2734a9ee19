"""Rectified-flow training as Cosmos-Predict2.5 does it, matching ``oscar_core.model.sampler``.

* Timesteps: u ~ sigmoid(N(m, s)), σ = shift·u / (1 + (shift − 1)·u) (logit-normal, shifted);
  :func:`sigma_cdf` is the analytic CDF of σ (for the KS test).
* Noising: z_σ = (1 − σ) z_0 + σ ε, target v = ε − z_0 (the sampler's eq. 1).
* The first latent frame is the clean conditioning frame: it is fed clean, the
  condition mask marks it, its timestep is ``cond_timestep`` (1e-4), and it is
  excluded from the loss (MSE over latent frames 1..T'−1, uniform weight).
* Ours, against drift (``flow.cond_noise_max``): the conditioning frame may be fed noised,
  (1 − σ_c) z_0 + σ_c ε with σ_c per sample, its timestep then σ_c (at least ``cond_timestep``), so the model
  learns to continue from a first frame that is not exactly the truth — as its own generated last frame is when
  a rollout chains chunks (noise augmentation of the context, as GameNGen trains it). The sampler feeds it
  clean (σ_c = 0, inside the trained range).
* Ours, against drift (``model.context_frames``): the first n latent frames of an item are its clean context
  instead of frame 0 alone (n = 2 for 5 pixel frames: the model sees the motion at the seam), handled exactly as
  frame 0 is (clean or noised by ``cond_noise_max``, the condition mask on, out of the loss); n is per item, so a
  batch mixes items trained at the full context and at the first frame alone (``flow.context_dropout``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

__all__ = ["shift_sigma", "sample_sigmas", "sigma_cdf", "FlowInputs", "flow_inputs", "flow_loss"]


def shift_sigma(u, shift: float):
    """σ = s·u / (1 + (s − 1)·u): the schedule shift the sampler uses (``flow_sigmas``)."""
    return shift * u / (1.0 + (shift - 1.0) * u)


def sample_sigmas(
    n: int, generator: torch.Generator, shift: float = 5.0, mean: float = 0.0, std: float = 1.0
) -> torch.Tensor:
    """(n,) float64 flow times σ in (0, 1): u = sigmoid(N(mean, std)), then shifted."""
    u = torch.sigmoid(torch.randn(n, generator=generator, dtype=torch.float64) * std + mean)
    return shift_sigma(u, shift)


def sigma_cdf(s, shift: float = 5.0, mean: float = 0.0, std: float = 1.0):
    """P(σ ≤ s) of :func:`sample_sigmas`: invert the shift, u = s / (shift − (shift − 1) s), then Φ((logit u − mean)/std)."""
    s = float(s)
    if s <= 0.0:
        return 0.0
    if s >= 1.0:
        return 1.0
    u = s / (shift - (shift - 1.0) * s)
    z = (math.log(u / (1.0 - u)) - mean) / std
    return 0.5 * (1.0 + math.erf(z / math.sqrt(2.0)))


@dataclass
class FlowInputs:
    """What the DiT sees for one batch, and what it must predict.

    x: (B, C, T, H, W) model input (frame 0 clean, the rest noised; the first n_b frames with a longer context);
    timestep: (B, 1, T, 1, 1) float32 (frame 0: cond_timestep, others σ_b);
    condition_mask: (B, 1, T, H, W) 1 on frame 0 (on the context frames); target: (B, C, T, H, W) ε − z_0;
    loss_mask: (B, 1, T, 1, 1) 0 on frame 0 (on the context frames), 1 elsewhere.
    """

    x: torch.Tensor
    timestep: torch.Tensor
    condition_mask: torch.Tensor
    target: torch.Tensor
    loss_mask: torch.Tensor


def flow_inputs(
    z0: torch.Tensor,
    noise: torch.Tensor,
    sigma: torch.Tensor,
    cond_timestep: float = 1e-4,
    cond_sigma: torch.Tensor | None = None,
    context=1,
) -> FlowInputs:
    """Noise clean latents ``z0`` (B, C, T, H, W) with ``noise`` (same shape) at per-sample ``sigma`` (B,).

    Exactly the sampler's conventions: z_σ = (1 − σ) z_0 + σ ε on frames ≥ 1,
    frame 0 replaced by its clean latent under the condition mask.
    cond_sigma: (B,) noise levels of the conditioning frame (module docstring): frame 0 is then
    (1 − σ_c) z_0 + σ_c ε (ε: ``noise``'s frame 0) at timestep max(σ_c, cond_timestep); None = clean.
    context: latent frames of clean context per item, an int for all or a sequence of B ints, each in [1, T − 1]
    (1: frame 0 alone, as the paper); every context frame is handled as frame 0 (module docstring).
    """
    if z0.ndim != 5 or noise.shape != z0.shape:
        raise ValueError(
            f"z0, noise: expected equal (B, C, T, H, W) shapes, found {tuple(z0.shape)} and {tuple(noise.shape)}"
        )
    b, _, t, h, w = z0.shape
    if sigma.shape != (b,):
        raise ValueError(f"sigma: expected shape ({b},), found {tuple(sigma.shape)}")
    s = sigma.to(z0.dtype).view(b, 1, 1, 1, 1)
    noisy = (1.0 - s) * z0 + s * noise
    counts = [int(context)] * b if isinstance(context, int) else [int(n) for n in context]
    if len(counts) != b or not all(1 <= n < t for n in counts):
        raise ValueError(f"context: expected {b} latent frame counts in [1, {t - 1}], found {context!r}")
    indicator = torch.zeros(b, 1, t, 1, 1, dtype=z0.dtype, device=z0.device)
    for i, n in enumerate(counts):
        indicator[i, :, :n] = 1.0
    first, first_t = z0, torch.full((b, 1, 1, 1, 1), cond_timestep, dtype=z0.dtype, device=z0.device)
    if cond_sigma is not None:
        if cond_sigma.shape != (b,):
            raise ValueError(f"cond_sigma: expected shape ({b},), found {tuple(cond_sigma.shape)}")
        sc = cond_sigma.to(z0.dtype).view(b, 1, 1, 1, 1)
        first = (1.0 - sc) * z0 + sc * noise
        first_t = torch.clamp(sc, min=cond_timestep)
    x = indicator * first + (1.0 - indicator) * noisy
    timestep = (indicator * first_t + (1.0 - indicator) * s).float()
    return FlowInputs(
        x=x,
        timestep=timestep,
        condition_mask=indicator.expand(b, 1, t, h, w),
        target=noise - z0,
        loss_mask=1.0 - indicator,
    )


def flow_loss(
    pred: torch.Tensor, inputs: FlowInputs, reduction: str = "mean", weight: torch.Tensor | None = None
) -> torch.Tensor:
    """MSE between the predicted velocity (B, C, T, H, W) and ε − z_0 on latent frames ≥ 1 (≥ n_b with a context).

    Per sample: the mean over the C·(T−1)·H·W (C·(T−n_b)·H·W) loss elements; ``reduction``
    "mean" averages the samples, "none" returns (B,). The conditioning frame
    contributes exactly zero (its error is multiplied by 0, gradient included).
    weight: (B, 1, T, H, W) per-cell weights (the focus weights, :mod:`oscar_core.train.focus`) multiplying each
    element's squared error before the same mean; None = 1 everywhere.
    """
    err = (pred.float() - inputs.target.float()).square() * inputs.loss_mask
    if weight is not None:
        err = err * weight.to(err.dtype)
    b, c, t, h, w = err.shape
    frames = [int(n) for n in inputs.loss_mask.flatten(1).sum(1).tolist()]  # latent frames in the loss, per item
    if len(set(frames)) == 1:
        per_sample = err.sum(dim=(1, 2, 3, 4)) / (c * frames[0] * h * w)
    else:
        per_sample = err.sum(dim=(1, 2, 3, 4)) / torch.tensor([c * n * h * w for n in frames], device=err.device)
    return per_sample.mean() if reduction == "mean" else per_sample
