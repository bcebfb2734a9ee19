"""Few-step students: guided progressive distillation of a rectified-flow world model.

The method is Meng et al., CVPR 2023, "On Distillation of Guided Diffusion Models" (arXiv 2210.03142), its two
stages written for the rectified flow of :mod:`.flow` and the Euler sampler of ``oscar_core.model.sampler``:

* **Guidance folded in** (their stage 1): the teacher's velocity is the guided one, v = v_c + w (v_c − v_u) in the
  diffusers form (or v_u + w (v_c − v_u), standard form), with the teacher's unconditional skeleton; the student
  is one conditional branch trained to match it, so it samples with no unconditional branch (``guidance: null`` in
  its card). The student here has w baked in (one w per student); their w-conditioned student needs a w embedding
  the DiT does not have.
* **Fewer steps** (their stage 2, progressive distillation; Salimans & Ho, ICLR 2022): the student runs ``steps``
  Euler steps on the shifted grid σ_0 = 1 > σ_1 > … > σ_N = 0 (``flow_sigmas(steps, shift)``, exactly the
  sampler's Euler grid). For student step i, z at σ_i is drawn from the forward process, z_σ = (1 − σ) z_0 + σ ε
  (frame 0 clean, as in training), and the teacher takes ``substeps`` = K guided Euler steps on the finer grid
  ``flow_sigmas(steps·K, shift)`` (which holds the student's grid at every K-th point) from σ_i down to σ_{i+1},
  reaching z'. The student's target velocity is the one whose single Euler step lands there:
  v* = (z − z') / (σ_i − σ_{i+1}). K = 2 is their halving round; with a student as the next teacher the rounds
  repeat (8 → 4 → 2 → 1). K = 1 is pure guidance distillation at the student's step count.

**Self forcing** (``distill.self_forcing``; the train-test gap of Huang, Li, He, Zhou, Shechtman, "Self Forcing",
arXiv 2506.08009, 2025): a student distilled as above only ever starts from a clean first frame of the data, while
chunk k ≥ 2 of a long rollout starts from a frame it made itself. For a chosen item (a function of its noise seed)
the student first samples, without gradients and in its own ``steps`` Euler steps, the chunk that ends at the
item's first frame (the clip's window ``data.window − 1`` frames earlier, from that window's clean first frame and
condition); the VAE decodes it and re-encodes its last frame, exactly as a rollout chains chunks, and that latent
replaces the item's first frame for the student and the teacher alike. The loss stays the regression to the guided
teacher above (theirs is distribution matching over the whole rollout): what carries over is the context the
student is trained from.

Which student step a training item serves follows its flow time σ from the plan (the interval
σ_i ≥ σ > σ_{i+1} that holds it), so the steps are weighted as training weights noise levels, and every target is
a function of (seed, step) alone: resume and any process count see the same targets.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, replace

import torch

from ..model.card_sampler import sampler_of_card
from ..model.sampler import SamplerConfig, flow_sigmas, guided_velocity
from .config import TrainConfigError
from .data import Batch
from .flow import flow_inputs, flow_loss
from .parallel import any_rank_samples
from .sampling import PlanItem, item_noise
from .self_forcing import CHOICE_SALT, CONTEXT_SALT, check_previous_windows, own_first_frames, self_forced

__all__ = [
    "Teacher",
    "student_step_index",
    "distill_target",
    "distill_loss",
    "self_forced",
    "self_force",
    "check_self_forcing",
    "check_teacher",
    "load_teacher",
    "student_sampler",
]


@dataclass
class Teacher:
    """The frozen teacher of a distillation run.

    transformer: the teacher DiT (eval, no gradients); guidance: w of the teacher's guided velocity (None or the
    form's no-op value: the conditional branch alone); guidance_form: "diffusers" or "standard";
    uncond_skeleton: (1, C_s, T, h, w) skeleton latent of the unconditional branch, or None (zeros);
    cond_timestep: the timestep fed for the clean first frame.
    """

    transformer: torch.nn.Module
    guidance: float | None
    guidance_form: str = "diffusers"
    uncond_skeleton: torch.Tensor | None = None
    cond_timestep: float = 1e-4

    def sampler(self) -> SamplerConfig:
        """The guidance settings as a :class:`SamplerConfig` (what ``guided_velocity`` reads)."""
        return SamplerConfig(guidance=self.guidance, guidance_form=self.guidance_form, batched_cfg=True)


def student_step_index(sigma: torch.Tensor, steps: int, shift: float) -> torch.Tensor:
    """(B,) int64 student step i with σ_i ≥ σ > σ_{i+1} on ``flow_sigmas(steps, shift)``; σ: (B,) in (0, 1]."""
    grid = flow_sigmas(steps, shift)  # descending, (steps + 1,)
    # count of grid points (excluding σ_0 = 1) that are ≥ σ: the interval index
    return (grid[1:].unsqueeze(0) >= sigma.double().unsqueeze(1)).sum(dim=1).clamp(max=steps - 1)


def distill_target(
    velocity, z: torch.Tensor, index: torch.Tensor, steps: int, substeps: int, shift: float
) -> torch.Tensor:
    """The student's target velocity v* = (z − z') / (σ_i − σ_{i+1}) (B, C, T, H, W) float32.

    velocity: (z (B, C, T, H, W), σ (B,) float64) → the teacher's velocity, same shape as z;
    z: (B, C, T, H, W) the student's input at σ_i; index: (B,) student step i per item; z' is z after ``substeps``
    Euler steps of ``velocity`` on ``flow_sigmas(steps·substeps, shift)`` from σ_i to σ_{i+1}.
    """
    fine = flow_sigmas(steps * substeps, shift)
    b = z.shape[0]
    view = (b,) + (1,) * (z.ndim - 1)
    start = index.long() * substeps
    x = z.float()
    for j in range(substeps):
        s_now, s_next = fine[start + j], fine[start + j + 1]
        x = x + (s_next - s_now).to(x.dtype).view(view) * velocity(x, s_now)
    span = (fine[start] - fine[start + substeps]).to(x.dtype).view(view)
    return (z.float() - x) / span


def distill_loss(
    student, teacher: Teacher, batch: Batch, items: list[PlanItem], config, device, autocast=None
) -> torch.Tensor:
    """Distillation loss (scalar, mean over the micro-batch): MSE between the student's velocity at σ_i and the
    target :func:`distill_target` of the guided teacher, on latent frames ≥ 1 (frame 0 is the clean condition)."""
    d = config.distill
    z0 = batch.z0.to(device, torch.float32)
    noise = item_noise(items, tuple(z0.shape[1:])).to(device)
    index = student_step_index(
        torch.tensor([it.sigma for it in items], dtype=torch.float64), d.steps, config.flow.shift
    )
    sigma_i = flow_sigmas(d.steps, config.flow.shift)[index]
    inputs = flow_inputs(z0, noise, sigma_i.to(device), config.flow.cond_timestep)
    h, w = z0.shape[-2:]
    text = batch.text.to(device)
    skeleton = batch.skeleton.to(device)
    padding = torch.zeros(1, 1, h, w, device=device)
    indicator = 1.0 - inputs.loss_mask  # (B, 1, T, 1, 1): 1 on the clean first frame
    clean = indicator * z0
    guide = teacher.sampler()
    uncond = None if teacher.uncond_skeleton is None else teacher.uncond_skeleton.to(device)

    def teacher_velocity(x: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        s = sigma.to(device, torch.float32).view(-1, 1, 1, 1, 1)
        model_in = clean + (1.0 - indicator) * x  # the first frame stays the clean condition at every sub-step
        timestep = indicator * teacher.cond_timestep + (1.0 - indicator) * s
        v = guided_velocity(
            teacher.transformer,
            model_in,
            timestep,
            text,
            skeleton,
            inputs.condition_mask,
            padding,
            guide,
            uncond_skeleton=uncond,
        )
        return v * (1.0 - indicator)

    with torch.no_grad(), autocast or contextlib.nullcontext():
        target = distill_target(teacher_velocity, inputs.x, index, d.steps, d.substeps, config.flow.shift)
    kwargs = dict(
        hidden_states=inputs.x,
        timestep=inputs.timestep,
        encoder_hidden_states=text,
        condition_mask=inputs.condition_mask,
        padding_mask=padding,
        skeleton_latents=skeleton,
        return_dict=False,
    )
    with autocast or contextlib.nullcontext():
        pred = student(**kwargs)[0]
    return flow_loss(pred, replace(inputs, target=target))


_CHOICE_SALT, _CONTEXT_SALT = CHOICE_SALT, CONTEXT_SALT  # the names this module's callers import


def self_force(student, data, batch: Batch, items: list[PlanItem], config, device, autocast=None) -> tuple[Batch, int]:
    """(``batch`` with the first latent frame of its self-forced items replaced, how many were replaced):
    :func:`~.self_forcing.own_first_frames` with the student's own sampler, read from the description its export
    writes (:func:`student_sampler`: ``distill.steps`` Euler steps, no guidance), as a rollout of the exported
    student reads it, for the ``distill.self_forcing`` share of items."""
    sampler = sampler_of_card(*student_sampler(config), cond_timestep=config.flow.cond_timestep)
    return own_first_frames(
        student,
        data,
        batch,
        items,
        config.distill.self_forcing,
        sampler,
        device,
        condition=config.condition,
        window=config.data.window,
        autocast=autocast,
        any_rank=lambda mine: any_rank_samples(mine, config),
    )


def check_self_forcing(config, data, source: str = "<config>") -> int:
    """How many of ``data``'s clips hold a window with the window ``data.window − 1`` frames before it (what a
    self-forced item needs); a :class:`TrainConfigError` when ``distill.self_forcing`` is on and none does."""
    return check_previous_windows(config.distill.self_forcing, "distill.self_forcing", data, config.data.window, source)


def check_teacher(config, source: str = "<config>"):
    """The teacher's folder (``distill.teacher``), checked before anything is built: an OSCAR model folder whose
    card's condition is the run's."""
    from pathlib import Path

    from ..model.world_model import MODEL_FILE, read_card

    folder = Path(config.distill.teacher)
    if not (folder / MODEL_FILE).is_file():
        raise TrainConfigError(
            source, "distill.teacher", f"an OSCAR model folder ({MODEL_FILE})", f"{folder} (no {MODEL_FILE})"
        )
    card = read_card(folder)
    if card.condition != config.condition:
        raise TrainConfigError(
            source, "condition", f"the teacher's condition {card.condition!r}", repr(config.condition)
        )
    if (card.condition_style or None) != (config.condition_style or None):
        raise TrainConfigError(
            source,
            "condition_style",
            f"the teacher's condition_style {card.condition_style!r}",
            repr(config.condition_style),
        )
    return folder


def load_teacher(config, data, device, source: str = "<config>") -> Teacher:
    """The frozen teacher ``config.distill.teacher`` names (an OSCAR model folder), on ``device`` in float32; its
    guidance is ``distill.guidance``, else its card's recommendation, else the library's 6; its unconditional
    skeleton is its card's (a black-video latent comes from ``data``, a :class:`~.data.TrainData`)."""
    from ..model.world_model import OscarWorldModel

    folder = check_teacher(config, source)
    check_self_forcing(config, data, source)
    model = OscarWorldModel.from_pretrained(folder, device=device, dtype=torch.float32)
    card = model.card
    rec = dict(card.sampler or {})
    guidance = config.distill.guidance
    if guidance is None:
        guidance = rec.get("guidance", 6.0)
    uncond = None
    if guidance is not None and card.unconditional_skeleton == "black_video":
        uncond = data.black_latent().unsqueeze(0)
    transformer = model.transformer.eval().requires_grad_(False)
    return Teacher(
        transformer,
        guidance,
        rec.get("guidance_form", "diffusers"),
        uncond,
        config.flow.cond_timestep,
    )


def student_sampler(config, teacher_form: str = "diffusers") -> tuple[dict, dict]:
    """(card sampler, scheduler config) of a distilled student: ``distill.steps`` Euler steps on the schedule of
    shift ``flow.shift``, no guidance (it is folded in); what its export writes so every entry point samples it
    as it was trained."""
    card = {"steps": int(config.distill.steps), "guidance": None, "guidance_form": teacher_form, "preset": None}
    scheduler = {
        "_class_name": "FlowMatchEulerDiscreteScheduler",
        "num_train_timesteps": 1000,
        "shift": float(config.flow.shift),
    }
    return card, scheduler
