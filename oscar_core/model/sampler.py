"""Rectified-flow sampling of one chunk, conditioned on the first frame and a skeleton.

The settings (:class:`SamplerConfig`, :func:`apply_preset`) live in :mod:`oscar_core.model.sampler_config` and
the model card's recommended settings (:func:`resolve_sampler`, :func:`check_card_sampler`) in
:mod:`oscar_core.model.card_sampler`; this module re-exports both.

Flow convention (paper eq. 1): z_σ = (1 − σ) z_0 + σ ε, the model predicts the
velocity v = ε − z_0, and sampling integrates dz/dσ = v from σ = 1 (noise) to
σ = 0. The model receives σ itself as its timestep (Cosmos 2.5 feeds σ, not
1000 σ). Two solvers (``SamplerConfig.solver``):

* ``"unipc"`` (default; what Cosmos-Predict2.5 and diffusers' pipeline use):
  multistep UniPC (second order, predictor-corrector) on flow sigmas with
  ``flow_shift = shift``, or with the checkpoint's own scheduler config
  (``SamplerConfig.scheduler_config``, read from a diffusers ``scheduler/``
  folder). oscar's own solver (:mod:`oscar_core.model.unipc`, the numbers of
  diffusers' ``UniPCMultistepScheduler``) runs it; a checkpoint config asking
  for what that solver does not do (Karras sigmas, dynamic shifting, ...: its
  module docstring lists them) runs on diffusers' class, imported only then;
* ``"euler"``: first-order Euler on the shifted schedule
  σ' = s·σ / (1 + (s − 1)·σ), σ = linspace(1, 0, steps + 1).

First frame, as in diffusers' Cosmos 2.5 pipeline: at every step latent frame
0 is overwritten by the clean latent z_0 of the seed image, the condition
mask marks it, its timestep is a tiny constant (1e-4), and its predicted
velocity is replaced by the true one, ε − z_0 (so the Euler path of frame 0
is the exact straight line and ends at z_0).
A longer context (the card's ``context_frames``: 4k + 1 pixel frames, n = k + 1
latent frames) is handled the same way: ``first_latent`` then holds n clean
latent frames and all n are overwritten, masked and given the true velocity.

Guidance over the skeleton: the unconditional branch is the same call with
the unconditional skeleton latent: zeros (``"zero_latent"``) or the VAE
latent of an all-black skeleton video (``"black_video"``), whichever the
checkpoint was trained to drop to (``ModelCard.unconditional_skeleton``; the
rollout passes it as ``uncond_skeleton``).

* ``guidance_form="diffusers"`` (default): v = v_c + w (v_c − v_u), i.e.
  (1 + w) v_c − w v_u. This is Ho & Salimans' classifier-free guidance
  (their eq. 6, (1 + w) ε_c − w ε_u), which the paper cites for its w = 6;
  NVIDIA's Cosmos-Predict2.5 rectified-flow sampler (``velocity_fn``:
  ``cond_v + guidance * (cond_v - uncond_v)``, 35 steps, shift 5), which the
  paper's model was fine-tuned in; and diffusers' Cosmos pipelines. w = 0 is
  the conditional branch.
* ``guidance_form="standard"``: v = v_u + w (v_c − v_u); equals the form
  above with w − 1 (w = 1 is the conditional branch, w = 0 the
  unconditional one). See docs/world-model.md for the comparison.

Guidance interval (``SamplerConfig.guidance_interval = (lo, hi)``): guidance
only at the steps whose noise level σ lies in [lo, hi]; the other steps run the
conditional branch alone (one model call instead of two), as in Kynkäänniemi
et al. 2024, "Applying guidance in a limited interval improves sample and
distribution quality in diffusion models". ``None`` (default) guides every step.

Presets (:data:`SAMPLER_PRESETS`, ``--preset`` on the CLI): named budgets of
steps and guided steps; :func:`model_calls` counts the DiT evaluations (batch
items) a chunk costs under a config, the basis of the FLOPs each preset
reports. docs/world-model.md has their measured quality on the toy model.

When the guided velocity equals one branch (w = 1 or 0 in the standard form,
w = 0 in the diffusers form, or ``guidance=None``) only that branch runs.
``batched_cfg=True`` runs both branches as one forward of batch 2B;
``False`` runs two forwards of batch B (less peak memory, usually slower).

Latent-action models (``oscar_core.model.latent_action``): ``sample_chunk``
takes ``actions`` (B, window − 1, 14) instead of a skeleton latent. Guidance
is then over the actions, with weight ``action_guidance`` (``guidance`` is the
skeleton's and is ignored): the unconditional branch omits the action tokens
(the base pathway). Its default, None, runs the conditional branch alone —
the latent-action trainer never drops the actions, so that branch is a model
it never trained. The two branches always run as two forwards.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from .card_sampler import (  # CARD, DEFAULT, GIVEN: its module constants, importable from here as before
    CARD as CARD,
    CARD_SAMPLER_KEYS,
    DEFAULT as DEFAULT,
    GIVEN as GIVEN,
    SamplerChoice,
    check_card_sampler,
    resolve_sampler,
)
from .errors import ModelInputError
from .presets import SAMPLER_PRESETS
from .sampler_config import GUIDANCE_FORMS, SOLVERS, SamplerConfig, apply_preset

__all__ = [
    "SamplerConfig",
    "flow_sigmas",
    "guided_velocity",
    "sample_chunk",
    "integrate",
    "unipc_scheduler",
    "branches",
    "GUIDANCE_FORMS",
    "SOLVERS",
    "SAMPLER_PRESETS",
    "apply_preset",
    "model_calls",
    "CARD_SAMPLER_KEYS",
    "SamplerChoice",
    "check_card_sampler",
    "resolve_sampler",
    "step_sigmas",
]


def step_sigmas(config: SamplerConfig) -> list[float]:
    """The noise level σ of each model evaluation of one chunk, in order (what the guidance interval sees)."""
    if config.resolved_solver == "euler":
        return [float(x) for x in flow_sigmas(config.steps, config.shift)[:-1]]
    sched = unipc_scheduler(config)
    sched.set_timesteps(int(config.steps))
    return [float(x) for x in sched.sigmas[:-1]]


def guided_at(config: SamplerConfig, sigma: float) -> bool:
    """Whether the step at noise level ``sigma`` applies guidance (inside ``guidance_interval``)."""
    iv = config.guidance_interval
    return iv is None or iv[0] <= sigma <= iv[1]


def model_calls(config: SamplerConfig) -> int:
    """DiT evaluations (batch items) one chunk costs: per step, 2 where both branches run, else 1."""
    both = len(branches(config)) == 2
    return sum(2 if both and guided_at(config, s) else 1 for s in step_sigmas(config))


def flow_sigmas(steps: int, shift: float = 5.0) -> torch.Tensor:
    """(steps + 1,) float64 noise levels from 1 down to 0, shifted: σ' = sσ / (1 + (s − 1)σ)."""
    s = torch.linspace(1.0, 0.0, int(steps) + 1, dtype=torch.float64)
    return shift * s / (1.0 + (shift - 1.0) * s)


def unipc_scheduler(config: SamplerConfig):
    """The UniPC solver for ``config``: flow sigmas with ``config.shift``, or its ``scheduler_config``.

    Returns oscar's :class:`~oscar_core.model.unipc.FlowUniPC` for the default and for every checkpoint config whose
    settings it supports (:func:`~oscar_core.model.unipc.solver_for_config`), else diffusers'
    ``UniPCMultistepScheduler`` built from that config (diffusers is imported only then). Both have
    ``set_timesteps(steps, device=)``, float32 ``sigmas`` and ``timesteps``; :func:`integrate` steps either.
    Raises ModelInputError for a config that is not a rectified-flow one.
    """
    from .unipc import FlowUniPC, solver_for_config

    if config.scheduler_config is None:
        return FlowUniPC(shift=float(config.shift))
    cfg = {k: v for k, v in dict(config.scheduler_config).items() if not k.startswith("_")}
    flow, prediction = cfg.get("use_flow_sigmas", False), cfg.get("prediction_type", "epsilon")
    if not flow or prediction != "flow_prediction":
        raise ModelInputError(
            "scheduler config: expected use_flow_sigmas=True and prediction_type="
            f"'flow_prediction' (a rectified-flow model), found use_flow_sigmas={flow}, prediction_type={prediction!r}"
        )
    own = solver_for_config(cfg)
    if own is not None:
        return own
    from diffusers import UniPCMultistepScheduler

    return UniPCMultistepScheduler.from_config(cfg)


def integrate(
    velocity: Callable[[torch.Tensor, float], torch.Tensor], x: torch.Tensor, config: SamplerConfig, progress=None
) -> torch.Tensor:
    """Integrate dz/dσ = velocity(z, σ) from σ ≈ 1 (``x``, the noise) down to σ = 0 with ``config``'s solver.

    velocity: (z float32 of x's shape, σ float) → velocity of the same shape;
    returns z at σ = 0 (float32). One velocity call per step.
    """
    from .unipc import FlowUniPC

    x = x.float()
    if config.resolved_solver == "euler":
        sigmas = flow_sigmas(config.steps, config.shift).tolist()
        for i in range(config.steps):
            x = x + (sigmas[i + 1] - sigmas[i]) * velocity(x, sigmas[i])
            if progress is not None:
                progress.update(1)
        return x
    solver = unipc_scheduler(config)
    solver.set_timesteps(int(config.steps), device=x.device)
    own = isinstance(solver, FlowUniPC)
    for i, t in enumerate(solver.timesteps):
        sigma = float(solver.sigmas[i])  # the schedule's float32 level: what the model is fed
        v = velocity(x, sigma).float()
        x = (solver.step(v, x) if own else solver.step(v, t, x, return_dict=False)[0]).float()
        if progress is not None:
            progress.update(1)
    return x


def branches(config: SamplerConfig) -> tuple[str, ...]:
    """Which model branches the guided velocity needs: ("cond",), ("uncond",) or ("cond", "uncond")."""
    if config.guidance is None:
        return ("cond",)
    w = float(config.guidance)
    if config.guidance_form == "standard":
        return ("cond",) if w == 1.0 else ("uncond",) if w == 0.0 else ("cond", "uncond")
    return ("cond",) if w == 0.0 else ("cond", "uncond")


def guided_velocity(
    transformer,
    latents,
    timestep,
    text,
    skeleton,
    condition_mask,
    padding_mask,
    config: SamplerConfig,
    text_projected: bool = False,
    uncond_skeleton: torch.Tensor | None = None,
    actions: torch.Tensor | None = None,
) -> torch.Tensor:
    """The guided velocity (B, C, T, H, W) of one denoising step (float32).

    latents: (B, C, T, H, W) model input; timestep: (B, 1, T, 1, 1);
    text: (B, L, D) prompt embedding, or its projection with ``text_projected``;
    skeleton: (B, C_s, T, H, W); condition_mask: (B, 1, T, H, W);
    uncond_skeleton: (1 or B, C_s, T, H, W) skeleton latent of the
    unconditional branch (None: zeros).
    actions: (B, window − 1, 14) latent actions of a ``LatentActionTransformer``
    (then ``skeleton`` is None and the guidance is ``config.action_guidance``
    over the actions; see :func:`_action_guided_velocity`).
    """
    if actions is not None:
        return _action_guided_velocity(
            transformer, latents, timestep, text, actions, condition_mask, padding_mask, config, text_projected
        )
    dtype = transformer.dtype  # the timestep stays float32: bf16 would round sigma to 3 digits

    def call(x, t, txt, skel, mask):
        out = transformer(
            hidden_states=x.to(dtype),
            timestep=t,
            encoder_hidden_states=txt.to(dtype),
            condition_mask=mask.to(dtype),
            padding_mask=padding_mask,
            fps=config.fps,
            skeleton_latents=skel.to(dtype),
            return_dict=False,
            text_projected=text_projected,
        )[0]
        return out.float()

    need = branches(config)
    if "uncond" in need:
        if uncond_skeleton is None:
            uncond_skeleton = torch.zeros_like(skeleton)
        elif uncond_skeleton.shape[1:] != skeleton.shape[1:] or uncond_skeleton.shape[0] not in (1, skeleton.shape[0]):
            raise ModelInputError(
                f"uncond_skeleton: expected shape (1 or {skeleton.shape[0]}, "
                f"{tuple(skeleton.shape[1:])}), found {tuple(uncond_skeleton.shape)}"
            )
        uncond_skeleton = uncond_skeleton.to(skeleton.device, skeleton.dtype).expand_as(skeleton)
    if need == ("cond",):
        return call(latents, timestep, text, skeleton, condition_mask)
    if need == ("uncond",):
        return call(latents, timestep, text, uncond_skeleton, condition_mask)
    if config.batched_cfg:
        both = call(
            torch.cat([latents, latents]),
            torch.cat([timestep, timestep]),
            torch.cat([text, text]),
            torch.cat([skeleton, uncond_skeleton]),
            torch.cat([condition_mask, condition_mask]),
        )
        v_cond, v_uncond = both.chunk(2)
    else:
        v_cond = call(latents, timestep, text, skeleton, condition_mask)
        v_uncond = call(latents, timestep, text, uncond_skeleton, condition_mask)
    w = float(config.guidance)
    if config.guidance_form == "standard":
        return v_uncond + w * (v_cond - v_uncond)
    return v_cond + w * (v_cond - v_uncond)


def _action_guided_velocity(
    transformer,
    latents,
    timestep,
    text,
    actions,
    condition_mask,
    padding_mask,
    config: SamplerConfig,
    text_projected: bool,
) -> torch.Tensor:
    """Guided velocity of a latent-action model: w = ``config.action_guidance``, unconditional = no action tokens."""
    from dataclasses import replace

    dtype = transformer.dtype

    def call(act):
        out = transformer(
            hidden_states=latents.to(dtype),
            timestep=timestep,
            encoder_hidden_states=text.to(dtype),
            condition_mask=condition_mask.to(dtype),
            padding_mask=padding_mask,
            fps=config.fps,
            actions=act,
            return_dict=False,
            text_projected=text_projected,
        )[0]
        return out.float()

    need = branches(replace(config, guidance=config.action_guidance))
    if need == ("cond",):
        return call(actions)
    if need == ("uncond",):
        return call(None)
    v_cond, v_uncond = call(actions), call(None)
    w = float(config.action_guidance)
    if config.guidance_form == "standard":
        return v_uncond + w * (v_cond - v_uncond)
    return v_cond + w * (v_cond - v_uncond)


def _checked_chunk_inputs(first_latent, skeleton_latent, text, actions, latent_frames, device):
    """Checks the shapes :func:`sample_chunk` takes and returns ``(skeleton_latent, actions)``: with ``actions``
    ((B, window − 1, 14), moved to ``device`` as float32) an empty (B, 0, T, H, W) skeleton latent that only
    carries the shape (T = ``latent_frames``); without, the given (B, C_s, T, H, W) skeleton latent."""
    if actions is not None:
        if skeleton_latent is not None or latent_frames is None:
            raise ModelInputError(
                "sample_chunk: with actions, expected skeleton_latent=None and latent_frames set, "
                f"found skeleton_latent={'a tensor' if skeleton_latent is not None else None}, "
                f"latent_frames={latent_frames}"
            )
        b, _, _, h, w = first_latent.shape
        t = int(latent_frames)
        if actions.ndim != 3 or actions.shape[0] != b:
            raise ModelInputError(f"actions: expected (B={b}, window - 1, 14), found {tuple(actions.shape)}")
        actions = actions.to(device, torch.float32)
        skeleton_latent = first_latent.new_empty((b, 0, t, h, w))  # shape only; never fed to the model
    elif skeleton_latent is None:
        raise ModelInputError("sample_chunk: expected a skeleton latent (or actions), found neither")
    b, _, t, h, w = skeleton_latent.shape
    c = first_latent.shape[1]
    n = first_latent.shape[2] if first_latent.ndim == 5 else 0
    if first_latent.shape != (b, c, n, h, w) or not 1 <= n < t:
        raise ModelInputError(
            f"first_latent: expected shape {(b, c, 'n', h, w)} with 1 <= n < {t} (the context's latent frames, "
            f"fewer than the chunk's, at the skeleton latent's size), found {tuple(first_latent.shape)}"
        )
    if text.shape[0] not in (1, b):
        raise ModelInputError(f"text: expected batch 1 or {b}, found shape {tuple(text.shape)}")
    return skeleton_latent, actions


def _initial_noise(shape: tuple[int, ...], generator, generators, device) -> torch.Tensor:
    """Standard normal noise of ``shape`` (B, C, T, H, W) float32 on ``device``, drawn on the CPU from ``generator``,
    or item by item from ``generators`` (one per batch item)."""
    if generators is not None:
        if len(generators) != shape[0]:
            raise ModelInputError(f"generators: expected one per batch item ({shape[0]}), found {len(generators)}")
        noise = torch.cat([torch.randn((1, *shape[1:]), generator=g, dtype=torch.float32) for g in generators])
        return noise.to(device)
    return torch.randn(shape, generator=generator, dtype=torch.float32).to(device)


@torch.no_grad()
def sample_chunk(
    transformer,
    first_latent: torch.Tensor,
    skeleton_latent: torch.Tensor | None,
    text: torch.Tensor,
    config: SamplerConfig = SamplerConfig(),
    generator: torch.Generator | None = None,
    progress=None,
    uncond_skeleton: torch.Tensor | None = None,
    *,
    actions: torch.Tensor | None = None,
    latent_frames: int | None = None,
    generators=None,
    project_once: bool = True,
) -> torch.Tensor:
    """Denoise one chunk; returns its clean latent (B, C, T, H, W) float32 with frame 0 = ``first_latent``.

    first_latent: (B, C, n, H, W) normalised clean latent of the seed frame (n = 1), or of the chunk's context
        (n ≥ 2 latent frames, fewer than T; module docstring): frames 0..n − 1 of the result, bit for bit.
    skeleton_latent: (B, C_s, T, H, W) normalised skeleton latent of the chunk;
        latent frame k conditions latent frame k of the video.
    text: (B or 1, L, D) prompt embedding.
    generator: CPU generator for the initial noise (drawn on the CPU, so a seed
        gives the same noise on every device); progress: optional tqdm-like
        object, ``update(1)`` per step. generators: instead of ``generator``,
        one CPU generator per batch item, each drawing its item's noise (B
        independent rollouts in one batch draw what each would draw alone).
    uncond_skeleton: the unconditional branch's skeleton latent (None: zeros).
    actions: (B, window − 1, 14) latent actions of the chunk, for a
        ``LatentActionTransformer``: then ``skeleton_latent`` is None and
        ``latent_frames`` (T, the chunk's latent frames) gives the length.
    project_once: project the prompt once per chunk (``transformer.project_text``); False hands it to every
        forward unprojected, for a model whose forward must run whole (FSDP2 gathers the projection's weights
        there).
    """
    device = next(transformer.parameters()).device
    skeleton_latent, actions = _checked_chunk_inputs(
        first_latent, skeleton_latent, text, actions, latent_frames, device
    )
    b, _, t, h, w = skeleton_latent.shape
    c = first_latent.shape[1]
    # the prompt is the same at every step: project it once (where the projection lives), not per step
    text = (transformer.project_text(text) if project_once else text).to(device).expand(b, -1, -1)
    skeleton_latent = skeleton_latent.to(device)
    if uncond_skeleton is not None:
        uncond_skeleton = uncond_skeleton.to(device)

    noise = _initial_noise((b, c, t, h, w), generator, generators, device)
    n = first_latent.shape[2]  # latent frames of the context: kept clean at every step
    clean = torch.zeros_like(noise)
    clean[:, :, :n] = first_latent.to(device, torch.float32)
    seed_frame, cond_t = clean, config.cond_timestep  # what the model is fed at frame 0, and its timestep
    if config.cond_noise:  # the noised conditioning frame (SamplerConfig.cond_noise); frame 0 of `noise` is unused else
        seed_frame = (1.0 - config.cond_noise) * clean + config.cond_noise * noise
        cond_t = max(config.cond_noise, config.cond_timestep)
    indicator = torch.zeros(b, 1, t, 1, 1, device=device)
    indicator[:, :, :n] = 1.0
    mask = indicator.expand(b, 1, t, h, w)
    true_velocity = (noise - clean) * mask  # ε − z_0 on the conditioning frames, 0 elsewhere
    padding = torch.zeros(1, 1, h, w, device=device)  # no padded pixels (latent size; resize is a no-op)

    from dataclasses import replace

    unguided = replace(config, guidance=None, action_guidance=None)  # the conditional branch alone

    def velocity(x: torch.Tensor, sigma: float) -> torch.Tensor:
        model_in = mask * seed_frame + (1.0 - mask) * x
        timestep = indicator * cond_t + (1.0 - indicator) * sigma
        step_config = config if guided_at(config, float(sigma)) else unguided
        v = guided_velocity(
            transformer,
            model_in,
            timestep,
            text,
            None if actions is not None else skeleton_latent,
            mask,
            padding,
            step_config,
            text_projected=project_once,
            uncond_skeleton=uncond_skeleton,
            actions=actions,
        )
        return true_velocity + v * (1.0 - mask)

    x = integrate(velocity, noise, config, progress)
    x[:, :, :n] = clean[:, :, :n]
    return x
