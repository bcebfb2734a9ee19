"""Rectified-flow sampling of one chunk, conditioned on the first frame and a skeleton.

Flow convention (paper eq. 1): z_σ = (1 − σ) z_0 + σ ε, the model predicts the
velocity v = ε − z_0, and sampling integrates dz/dσ = v from σ = 1 (noise) to
σ = 0 with Euler steps on a shifted schedule σ' = s·σ / (1 + (s − 1)·σ).

First frame, as in diffusers' Cosmos 2.5 pipeline: at every step latent frame
0 is overwritten by the clean latent z_0 of the seed image, the condition
mask marks it, its timestep is a tiny constant (1e-4), and its predicted
velocity is replaced by the true one, ε − z_0 (so the Euler path of frame 0
is the exact straight line and ends at z_0).

Guidance over the skeleton: the unconditional branch is the same call with the
skeleton latent zeroed (PE_s has no bias, so that is the base model's view).

* ``guidance_form="standard"`` (default, the paper's): v = v_u + w (v_c − v_u);
  w = 1 is the conditional branch, w = 0 the unconditional one.
* ``guidance_form="diffusers"`` (diffusers' Cosmos pipelines): v = v_c + w (v_c − v_u);
  it equals the standard form with w + 1, so w = 0 is the conditional branch.

``batched_cfg=True`` runs both branches as one forward of batch 2B;
``False`` runs two forwards of batch B (less peak memory, usually slower).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .errors import ModelInputError

__all__ = ["SamplerConfig", "flow_sigmas", "guided_velocity", "sample_chunk", "GUIDANCE_FORMS"]

GUIDANCE_FORMS = ("standard", "diffusers")


@dataclass(frozen=True)
class SamplerConfig:
    """Sampler settings.

    steps: Euler steps per chunk; shift: schedule shift s (the paper trains with 5);
    guidance: w, or None for the conditional branch alone (no second branch);
    guidance_form: "standard" or "diffusers" (module docstring);
    batched_cfg: one forward of batch 2B for both branches;
    cond_timestep: timestep fed for the clean first latent frame (diffusers' 1e-4);
    fps: passed to the DiT's RoPE (None, as the Cosmos 2.5 pipeline does).
    """

    steps: int = 35
    shift: float = 5.0
    guidance: float | None = 6.0
    guidance_form: str = "standard"
    batched_cfg: bool = True
    cond_timestep: float = 1e-4
    fps: float | None = None

    def __post_init__(self):
        if int(self.steps) < 1:
            raise ModelInputError(f"sampler steps: expected an integer >= 1, found {self.steps!r}")
        if not self.shift > 0:
            raise ModelInputError(f"sampler shift: expected a positive number, found {self.shift!r}")
        if self.guidance_form not in GUIDANCE_FORMS:
            raise ModelInputError(f"guidance_form: expected one of {GUIDANCE_FORMS}, found {self.guidance_form!r}")


def flow_sigmas(steps: int, shift: float = 5.0) -> torch.Tensor:
    """(steps + 1,) float64 noise levels from 1 down to 0, shifted: σ' = sσ / (1 + (s − 1)σ)."""
    s = torch.linspace(1.0, 0.0, int(steps) + 1, dtype=torch.float64)
    return shift * s / (1.0 + (shift - 1.0) * s)


def guided_velocity(transformer, latents, timestep, text, skeleton, condition_mask, padding_mask,
                    config: SamplerConfig, text_projected: bool = False) -> torch.Tensor:
    """The guided velocity (B, C, T, H, W) of one denoising step (float32).

    latents: (B, C, T, H, W) model input; timestep: (B, 1, T, 1, 1);
    text: (B, L, D) prompt embedding, or its projection with ``text_projected``;
    skeleton: (B, C_s, T, H, W); condition_mask: (B, 1, T, H, W).
    """
    dtype = transformer.dtype  # the timestep stays float32: bf16 would round sigma to 3 digits

    def call(x, t, txt, skel, mask):
        out = transformer(hidden_states=x.to(dtype), timestep=t, encoder_hidden_states=txt.to(dtype),
                          condition_mask=mask.to(dtype), padding_mask=padding_mask, fps=config.fps,
                          skeleton_latents=skel.to(dtype), return_dict=False, text_projected=text_projected)[0]
        return out.float()

    if config.guidance is None:
        return call(latents, timestep, text, skeleton, condition_mask)
    uncond_skeleton = torch.zeros_like(skeleton)
    if config.batched_cfg:
        both = call(torch.cat([latents, latents]), torch.cat([timestep, timestep]), torch.cat([text, text]),
                    torch.cat([skeleton, uncond_skeleton]), torch.cat([condition_mask, condition_mask]))
        v_cond, v_uncond = both.chunk(2)
    else:
        v_cond = call(latents, timestep, text, skeleton, condition_mask)
        v_uncond = call(latents, timestep, text, uncond_skeleton, condition_mask)
    w = float(config.guidance)
    if config.guidance_form == "standard":
        return v_uncond + w * (v_cond - v_uncond)
    return v_cond + w * (v_cond - v_uncond)


@torch.no_grad()
def sample_chunk(transformer, first_latent: torch.Tensor, skeleton_latent: torch.Tensor, text: torch.Tensor,
                 config: SamplerConfig = SamplerConfig(), generator: torch.Generator | None = None,
                 progress=None) -> torch.Tensor:
    """Denoise one chunk; returns its clean latent (B, C, T, H, W) float32 with frame 0 = ``first_latent``.

    first_latent: (B, C, 1, H, W) normalised clean latent of the seed frame.
    skeleton_latent: (B, C_s, T, H, W) normalised skeleton latent of the chunk.
    text: (B or 1, L, D) prompt embedding.
    generator: CPU generator for the initial noise (drawn on the CPU, so a seed
        gives the same noise on every device); progress: optional tqdm-like
        object, ``update(1)`` per step.
    """
    device = next(transformer.parameters()).device
    b, _, t, h, w = skeleton_latent.shape
    c = first_latent.shape[1]
    if first_latent.shape != (b, c, 1, h, w):
        raise ModelInputError(f"first_latent: expected shape {(b, c, 1, h, w)} (one frame of the skeleton "
                              f"latent's size), found {tuple(first_latent.shape)}")
    if text.shape[0] not in (1, b):
        raise ModelInputError(f"text: expected batch 1 or {b}, found shape {tuple(text.shape)}")
    # the prompt is the same at every step: project it once (where the projection lives), not per step
    text = transformer.project_text(text).to(device).expand(b, -1, -1)
    skeleton_latent = skeleton_latent.to(device)

    noise = torch.randn((b, c, t, h, w), generator=generator, dtype=torch.float32).to(device)
    clean = torch.zeros_like(noise)
    clean[:, :, :1] = first_latent.to(device, torch.float32)
    indicator = torch.zeros(b, 1, t, 1, 1, device=device)
    indicator[:, :, 0] = 1.0
    mask = indicator.expand(b, 1, t, h, w)
    true_velocity = (noise - clean) * mask  # ε − z_0 on the conditioning frame, 0 elsewhere
    padding = torch.zeros(1, 1, h, w, device=device)  # no padded pixels (latent size; resize is a no-op)

    sigmas = flow_sigmas(config.steps, config.shift).tolist()
    x = noise
    for i in range(config.steps):
        sigma, sigma_next = sigmas[i], sigmas[i + 1]
        model_in = mask * clean + (1.0 - mask) * x
        timestep = indicator * config.cond_timestep + (1.0 - indicator) * sigma
        v = guided_velocity(transformer, model_in, timestep, text, skeleton_latent, mask, padding, config,
                            text_projected=True)
        v = true_velocity + v * (1.0 - mask)
        x = x + (sigma_next - sigma) * v
        if progress is not None:
            progress.update(1)
    x[:, :, :1] = clean[:, :, :1]
    return x
