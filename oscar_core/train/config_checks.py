"""The training configuration's checks: every field of a :class:`~.config.TrainConfig` against what it may hold and
against the fields it depends on, the first bad one handed to the caller's ``fail`` (which raises)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from ..errors import OscarError
from ..render.conditions import MODEL_CONDITIONS as CONDITIONS, is_video_condition, takes_actions

if TYPE_CHECKING:
    from .config import DataSection, TrainConfig

__all__ = ["check_config", "PARALLEL_MODES", "CHECKPOINTING", "LATENT_MODES", "UNCONDITIONAL"]

PARALLEL_MODES = ("auto", "none", "ddp", "fsdp")
CHECKPOINTING = ("none", "full", "auto")
LATENT_MODES = ("auto", "cached", "on_the_fly")
UNCONDITIONAL = ("zero_latent", "black_video")


def _number(v) -> bool:
    """Whether ``v`` is an int or a float (a YAML boolean is neither)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _fraction(v) -> bool:
    """Whether ``v`` is a number in [0, 1]."""
    return _number(v) and 0.0 <= v <= 1.0


def check_config(config: TrainConfig, fail) -> None:
    """Call ``fail(name, expected, found)`` for the first bad field of ``config`` (``found``: its text); ``fail``
    raises (:meth:`.config.TrainConfig.validate` passes one that raises its ``TrainConfigError``)."""

    def bad(name, expected, found):
        fail(name, expected, repr(found))

    if config.condition not in CONDITIONS:
        bad("condition", f"one of {CONDITIONS}", config.condition)
    if config.condition_style is not None:
        from ..render.conditions import condition_style

        try:
            condition_style(config.condition_style)
        except OscarError as e:
            fail("condition_style", "a mapping of SkeletonStyle fields", str(e))
    if config.export_sampler is not None:
        from ..model.card_sampler import check_card_sampler

        try:
            check_card_sampler(config.export_sampler, "export_sampler")
        except OscarError as e:
            fail("export_sampler", "a card's sampler mapping (steps, guidance, guidance_form, preset)", str(e))
        if config.distill.teacher is not None:
            bad(
                "export_sampler",
                "null for a distillation run (its card names the student's steps)",
                config.export_sampler,
            )
    if config.parallel not in PARALLEL_MODES:
        bad("parallel", f"one of {PARALLEL_MODES}", config.parallel)
    if config.activation_checkpointing not in CHECKPOINTING:
        bad("activation_checkpointing", f"one of {CHECKPOINTING}", config.activation_checkpointing)
    for name in ("steps", "batch_size", "micro_batch", "log_every", "save_every", "keep_last"):
        v = getattr(config, name)
        if not isinstance(v, int) or isinstance(v, bool) or v < 1:
            bad(name, "a positive integer", v)
    if config.batch_size % config.micro_batch:
        bad("micro_batch", f"a divisor of batch_size {config.batch_size}", config.micro_batch)
    _check_data_section(config.data, bad)
    f = config.flow
    if not f.shift > 0:
        bad("flow.shift", "a positive number", f.shift)
    if not f.logit_std > 0:
        bad("flow.logit_std", "a positive number", f.logit_std)
    if not (_number(f.focus_weight) and f.focus_weight >= 0):
        bad("flow.focus_weight", "a number >= 0", f.focus_weight)
    if f.focus_weight > 0 and config.data.focus_mask is None:
        bad("data.focus_mask", "a mask function (module:attr) when flow.focus_weight > 0", None)
    cn = config.flow.cond_noise_max
    if not _fraction(cn):
        bad("flow.cond_noise_max", "a noise level in [0, 1]", cn)
    _check_flow_self_forcing(config, bad)
    o = config.optim
    if not o.lr > 0:
        bad("optim.lr", "a positive number", o.lr)
    if not 0.0 <= o.ema_decay < 1.0:
        bad("optim.ema_decay", "a number in [0, 1)", o.ema_decay)
    if not o.grad_clip > 0:
        bad("optim.grad_clip", "a positive number (the max gradient norm)", o.grad_clip)
    if o.warmup_steps < 0:
        bad("optim.warmup_steps", "an integer >= 0", o.warmup_steps)
    _check_log_and_model_sections(config, bad)
    _check_distill_section(config, bad)


def _check_data_section(d: DataSection, bad) -> None:
    """The ``data`` section's checks; ``bad(name, expected, found)`` raises for the first bad field."""
    if not isinstance(d.window, int) or d.window < 5 or (d.window - 1) % 4:
        bad("data.window", "a frame count 4k+1 >= 5 (e.g. 9, 17, 81)", d.window)
    for name in ("width", "height"):
        v = getattr(d, name)
        if not isinstance(v, int) or v < 16 or v % 16:
            bad(f"data.{name}", "a positive multiple of 16 pixels (VAE x8, patch x2)", v)
    if d.latents not in LATENT_MODES:
        bad("data.latents", f"one of {LATENT_MODES}", d.latents)
    if not 0.0 <= d.skeleton_dropout <= 1.0:
        bad("data.skeleton_dropout", "a probability in [0, 1]", d.skeleton_dropout)
    if d.unconditional_skeleton not in UNCONDITIONAL:
        bad("data.unconditional_skeleton", f"one of {UNCONDITIONAL}", d.unconditional_skeleton)
    if not d.mixing_temperature > 0:
        bad("data.mixing_temperature", "a positive number", d.mixing_temperature)
    for k, v in (d.source_weights or {}).items():
        if not v > 0:
            bad(f"data.source_weights.{k}", "a positive weight", v)
    if d.source_weights is not None and not d.source_weights:
        bad("data.source_weights", "a mapping {source: weight} with at least one source, or null", {})
    if not 0.0 < d.prior_ramp <= 0.5:
        bad("data.prior_ramp", "a fraction in (0, 0.5]", d.prior_ramp)
    if not 0.0 <= d.prior_uniform <= 1.0:
        bad("data.prior_uniform", "a fraction in [0, 1]", d.prior_uniform)
    if not isinstance(d.workers, int) or isinstance(d.workers, bool) or d.workers < 0:
        bad("data.workers", "an integer >= 0 (0: load in the training loop)", d.workers)
    if not isinstance(d.prefetch, int) or isinstance(d.prefetch, bool) or d.prefetch < 1:
        bad("data.prefetch", "a positive integer (micro-batches loaded ahead per worker)", d.prefetch)
    if not isinstance(d.clips, list) or not d.clips:
        bad("data.clips", "a non-empty list of clip-set folders", d.clips)
    if d.focus_mask is not None and (not isinstance(d.focus_mask, str) or ":" not in d.focus_mask):
        bad("data.focus_mask", "module:attr or path/to/file.py:attr of a mask function, or null", d.focus_mask)


def _check_log_and_model_sections(config: TrainConfig, bad) -> None:
    """The ``log`` and ``model`` sections' checks; ``bad(name, expected, found)`` raises for the first bad field."""
    if not isinstance(config.log.tensorboard, bool):
        bad("log.tensorboard", "true or false", config.log.tensorboard)
    if not isinstance(config.log.wandb, bool):
        bad("log.wandb", "true or false", config.log.wandb)
    if config.log.wandb_mode not in ("offline", "online", "disabled"):
        bad("log.wandb_mode", "offline, online or disabled", config.log.wandb_mode)
    if not isinstance(config.log.wandb_project, str) or not config.log.wandb_project:
        bad("log.wandb_project", "a project name", config.log.wandb_project)
    if config.model.condition_init not in ("zero", "default"):
        bad("model.condition_init", "'zero' or 'default'", config.model.condition_init)
    if not isinstance(config.model.gripper_signal, bool):
        bad("model.gripper_signal", "true or false", config.model.gripper_signal)
    if config.model.gripper_signal and not is_video_condition(config.condition):
        bad(
            "model.gripper_signal",
            "a condition video beside it (condition: skeleton, mesh or capsules)",
            f"condition {config.condition!r}",
        )
    _check_context(config, bad)
    if config.model.dtype not in ("float32", "bfloat16"):
        bad("model.dtype", "'float32' or 'bfloat16'", config.model.dtype)


def _check_context(config: TrainConfig, bad) -> None:
    """``model.context_frames`` against the window, and ``flow.context_dropout``."""
    from ..model.chunks import check_context_frames
    from ..model.errors import ModelInputError

    cf, window = config.model.context_frames, config.data.window
    try:
        check_context_frames(cf, window, what="model.context_frames")
    except ModelInputError:
        bad(
            "model.context_frames",
            f"pixel frames of the form 4k+1 (1, 5, ...) covering fewer latent frames than data.window {window}'s "
            f"{(window - 1) // 4 + 1}",
            cf,
        )
    cd = config.flow.context_dropout
    if not _fraction(cd):
        bad("flow.context_dropout", "a fraction in [0, 1]", cd)
    if cf != 1 and not cd > 0:
        bad(
            "flow.context_dropout",
            "a fraction > 0 with model.context_frames > 1 (a rollout's first chunk has the first frame alone)",
            cd,
        )
    if cf != 1 and takes_actions(config.condition):
        bad("model.context_frames", "1 for a latent-action model", cf)
    if cf != 1 and config.distill.teacher is not None:
        bad("model.context_frames", "1 when distilling (the distillation's chunks start from one frame)", cf)


def _check_flow_self_forcing(config: TrainConfig, bad) -> None:
    """``flow.self_forcing`` and its sampler; ``bad(name, expected, found)`` raises for the first bad field."""
    f = config.flow
    sf = f.self_forcing
    if not _fraction(sf):
        bad("flow.self_forcing", "a fraction in [0, 1]", sf)
    steps = f.self_forcing_steps
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        bad("flow.self_forcing_steps", "a positive integer", steps)
    g = f.self_forcing_guidance
    if g is not None and not (_number(g) and math.isfinite(g) and g >= 0):
        bad("flow.self_forcing_guidance", "a number >= 0 (or null: no guidance)", g)
    if sf > 0:
        if config.distill.teacher is not None:
            bad("flow.self_forcing", "0 when distilling (distill.self_forcing says how a student self-forces)", sf)
        if config.condition not in ("skeleton", "mesh", "capsules"):
            bad("condition", "a condition video (skeleton, mesh, capsules) with flow.self_forcing", config.condition)
        if config.model.context_frames != 1:
            bad(
                "model.context_frames", "1 with flow.self_forcing (one frame carried over)", config.model.context_frames
            )


def _check_distill_section(config: TrainConfig, bad) -> None:
    """The ``distill`` section's checks (only with a teacher); ``bad(name, expected, found)`` raises for the first
    bad field."""
    ds, f = config.distill, config.flow
    if ds.teacher is not None:
        for name in ("steps", "substeps"):
            v = getattr(ds, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                bad(f"distill.{name}", "a positive integer", v)
        if ds.guidance is not None and ds.guidance < 0:
            bad("distill.guidance", "a number >= 0 (or null: the teacher card's)", ds.guidance)
        sf = ds.self_forcing
        if not _fraction(sf):
            bad("distill.self_forcing", "a fraction in [0, 1]", sf)
        if config.condition not in ("skeleton", "mesh", "capsules"):
            bad("condition", "a condition video (skeleton, mesh, capsules) when distilling", config.condition)
        if not config.model.init:
            bad("model.init", "the student's starting weights (the teacher's folder) when distilling", None)
        if f.shift != 5.0:  # the sampler's Euler grid uses SamplerConfig.shift, 5 unless a rollout says otherwise
            bad("flow.shift", "5.0 when distilling (the shift every sampler uses by default)", f.shift)
