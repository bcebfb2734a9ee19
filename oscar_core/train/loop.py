"""The training loop, top to bottom: build → (resume) → step → log → save → export.

One optimiser step: the planner draws the global batch of step k from (seed,
k); this process takes its share, split into micro-batches (gradient
accumulation, the all-reduce only on the last); each micro-batch's loss is
the rectified-flow MSE (:mod:`.flow`) averaged over its clips and divided by
the number of micro-batches, so the summed (and, across processes,
averaged) gradient is that of the mean loss over the global batch. Then
gradient-norm clipping, AdamW at the warm-up learning rate, and the EMA.
With a ``distill`` section the micro-batch loss is the distillation loss of :mod:`.distill` (a frozen
teacher's guided multi-step target) instead; everything else is the same loop.
"""

from __future__ import annotations

import contextlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from .._util.atomic import atomic_write_bytes
from .._util.log import get_logger, progress_bar
from ..model.sampler import SamplerConfig
from ..render.conditions import is_video_condition, takes_actions
from .checkpoint import (
    checkpoint_step,
    latest_checkpoint,
    list_checkpoints,
    load_checkpoint,
    load_weights,
    save_checkpoint,
)
from .config import OVERRIDE_SOURCE, TrainConfig, TrainConfigError, check_resume_overrides, load_config, save_config
from .data import Batch, TrainData
from .distill import distill_loss, self_force
from .flow import flow_inputs, flow_loss
from .loader import iter_batches, micro_batches
from .models import build_transformer, build_vae, prepare_for_training
from .parallel import (
    DistInfo,
    all_reduce_mean,
    all_reduce_sum,
    any_rank_samples,
    close_distributed,
    init_distributed,
    no_sync,
    wrap_model,
)
from .sampling import PlanItem, StepPlanner, item_cond_sigma, item_context, item_noise
from .self_forcing import check_previous_windows, own_first_frames

__all__ = [
    "CONFIG_FILE",
    "METRICS_FILE",
    "TrainResult",
    "apply_update",
    "autocast_for",
    "build_optimizer",
    "lr_at",
    "step_loss",
    "train",
]

_log = get_logger(__name__)
METRICS_FILE = "metrics.jsonl"
CONFIG_FILE = "config.yaml"


@dataclass
class TrainResult:
    """run_dir; step: optimiser steps done; last_loss; export: the exported folder or None."""

    run_dir: Path
    step: int
    last_loss: float | None
    export: Path | None


def lr_at(step: int, lr: float, warmup: int) -> float:
    """Learning rate of optimiser step ``step`` (0-based): linear warm-up over ``warmup`` steps, then constant."""
    if warmup <= 0:
        return lr
    return lr * min(1.0, (step + 1) / warmup)


def step_loss(model, batch: Batch, items: list[PlanItem], config: TrainConfig, device, autocast=None) -> torch.Tensor:
    """Rectified-flow loss (scalar, mean over the micro-batch) of ``model`` on one loaded micro-batch."""
    z0 = batch.z0.to(device, torch.float32)
    noise = item_noise(items, tuple(z0.shape[1:])).to(device)
    sigma = torch.tensor([it.sigma for it in items], dtype=torch.float64)
    cond_sigma = None
    if config.flow.cond_noise_max:
        cond_sigma = item_cond_sigma(items, config.flow.cond_noise_max).to(device)
    context = item_context(items, context_latents(config), config.flow.context_dropout)
    inputs = flow_inputs(z0, noise, sigma.to(device), config.flow.cond_timestep, cond_sigma, context)
    h, w = z0.shape[-2:]
    kwargs = dict(
        hidden_states=inputs.x,
        timestep=inputs.timestep,
        encoder_hidden_states=batch.text.to(device),
        condition_mask=inputs.condition_mask,
        padding_mask=torch.zeros(1, 1, h, w, device=device),
        return_dict=False,
    )
    if is_video_condition(config.condition):
        kwargs["skeleton_latents"] = batch.skeleton.to(device)
    elif takes_actions(config.condition):
        kwargs["actions"] = batch.actions.to(device)
    with autocast or contextlib.nullcontext():
        pred = model(**kwargs)[0]
    weight = None
    if batch.focus is not None and config.flow.focus_weight:
        weight = 1.0 + config.flow.focus_weight * batch.focus.to(device, torch.float32)
    return flow_loss(pred, inputs, weight=weight)


def context_latents(config: TrainConfig) -> int:
    """Latent frames of ``model.context_frames`` (4k + 1 pixel frames of the WAN VAE's 4x time: k + 1)."""
    return (int(config.model.context_frames) - 1) // 4 + 1


def build_optimizer(wrapped, config: TrainConfig) -> torch.optim.AdamW:
    """AdamW over ``wrapped``'s parameters with the config's ``optim`` section (the learning rate is set per step)."""
    o = config.optim
    return torch.optim.AdamW(
        wrapped.parameters(), lr=o.lr, betas=tuple(o.betas), eps=o.eps, weight_decay=o.weight_decay
    )


def autocast_for(config: TrainConfig, device):
    """The forward's autocast context (``model.dtype: bfloat16``) on ``device``, or None (float32)."""
    device = torch.device(device)
    return torch.autocast(device.type, dtype=torch.bfloat16) if config.model.dtype == "bfloat16" else None


def apply_update(wrapped, model, optimizer, ema: dict, config: TrainConfig) -> float:
    """The end of an optimiser step once the gradients are accumulated: clip their norm to ``optim.grad_clip``,
    step AdamW, move the fp32 EMA (``ema``: name → tensor) towards the weights; returns the norm before clipping."""
    o = config.optim
    grad_norm = _grad_norm(wrapped, o.grad_clip)
    optimizer.step()
    with torch.no_grad():
        for n, p in model.named_parameters():
            ema[n].lerp_(p.detach().float(), 1.0 - o.ema_decay)
    return grad_norm


def _grad_norm(model, max_norm: float) -> float:
    norm = torch.nn.utils.clip_grad_norm_(model.parameters(), max_norm)
    if hasattr(norm, "full_tensor"):
        norm = norm.full_tensor()
    return float(norm)


def _read_metrics(path: Path, upto: int) -> bytes:
    """The metrics lines of steps ≤ ``upto`` (what a resumed run keeps)."""
    if not path.is_file():
        return b""
    keep = []
    for line in path.read_text().splitlines():
        try:
            rec = json.loads(line)
        except ValueError:
            continue
        if rec.get("step", 0) <= upto:
            keep.append(line)
    return "".join(k + "\n" for k in keep).encode()


def train(
    config: TrainConfig | str | Path | None = None,
    *,
    resume=None,
    progress: bool = True,
    stop_after: int | None = None,
    registry=None,
    export: bool | None = None,
    source: str = "<config>",
    overrides: dict | None = None,
) -> TrainResult:
    """Train a run; with ``resume`` (a run folder) continue it from its latest checkpoint.

    config: a TrainConfig or a YAML path (ignored when resuming: the run's
    ``config.yaml`` is used). stop_after: stop after this many optimiser steps
    in total (a simulated interruption, after saving a checkpoint; tests).
    overrides: with ``resume``, new values of fields in
    :data:`~oscar_core.train.config.RESUME_OVERRIDES` (``{"steps": 30}`` trains
    the run further); they are written to the run's ``config.yaml``; any other
    field is refused. export: override ``config.export``. Every process of a torchrun launch calls this.
    """
    info = init_distributed()
    try:
        result, config = _train(config, resume, progress, stop_after, registry, source, info, overrides)
    finally:
        close_distributed(info)
    if info.main:
        _write_curves(result.run_dir)
    # export after the process group is gone: rank 0 alone, one process reading the (resharded) checkpoint
    if (config.export if export is None else export) and result.step == config.steps and info.main:
        from .export import export_run

        result.export = export_run(result.run_dir)
    return result


SOURCES_FILE = "sources.json"


def write_sources(run_dir: Path, planner: StepPlanner, drawn: dict[str, int], steps: int, config: TrainConfig) -> Path:
    """``RUN_DIR/sources.json`` (atomic): per source ``configured_weight`` (the config's ``data.source_weights``
    value as written, any positive scale; None under the temperature rule), ``normalised_weight`` (the probability
    a draw takes that source: the configured weights over their sum, or the temperature rule's), the items
    ``drawn`` by steps 1 .. ``steps`` and their ``drawn_fraction`` of all draws; ``mixing`` says which rule set
    the weights."""
    total = sum(drawn.values())
    explicit = config.data.source_weights is not None
    configured = dict(config.data.source_weights or {})
    doc = {
        "steps": steps,
        "draws": total,
        "mixing": "source_weights" if explicit else f"mixing_temperature {config.data.mixing_temperature:g}",
        "parent_run": config.parent_run,
        "sources": {
            s: {
                "configured_weight": configured.get(s) if explicit else None,
                "normalised_weight": w,
                "drawn": drawn[s],
                "drawn_fraction": drawn[s] / total if total else None,
            }
            for s, w in planner.weights.items()
        },
    }
    return atomic_write_bytes(run_dir / SOURCES_FILE, (json.dumps(doc, indent=1) + "\n").encode())


def _check_source_weights(config: TrainConfig, data, source: str) -> None:
    """Explicit ``data.source_weights`` must name exactly the sources of the clips (before anything is built)."""
    named = config.data.source_weights
    if named is None:
        return
    have = set(data.summary()["sources"])
    if set(named) != have:
        raise TrainConfigError(
            source,
            "data.source_weights",
            f"a weight for every source of the clips ({', '.join(sorted(have))}) and no other",
            f"{sorted(named)} (missing {sorted(have - set(named))}, unknown {sorted(set(named) - have)})",
        )


def _write_curves(run_dir: Path) -> None:
    """``RUN_DIR/curves.png`` (:mod:`oscar_core.train.curves`); skipped, with an INFO line, without matplotlib."""
    from .curves import plot_training_curves

    try:
        path = plot_training_curves(run_dir)
    except ImportError as exc:
        _log.info("no training-curve plot: %s", exc)
        return
    if path is not None:
        _log.info("training curves: %s", path)


def _checked_config(config, resume, overrides, source: str):
    """The run's config, checked before anything is built or written: ``(config, source, ckpt)`` with the
    config read from ``resume/config.yaml`` (with ``overrides``) or from a YAML path, the source that names it
    in errors, and the checkpoint to resume from (None for a new run)."""
    ckpt = None
    if resume is not None:
        run_dir = Path(resume)
        if not (run_dir / CONFIG_FILE).is_file():
            raise TrainConfigError(run_dir, CONFIG_FILE, "a run folder written by `oscar train`", "no config.yaml")
        check_resume_overrides(overrides or {})
        config = load_config(run_dir / CONFIG_FILE, overrides)
        ckpt = latest_checkpoint(run_dir)
        done = checkpoint_step(ckpt)
        if config.steps < done:
            raise TrainConfigError(
                OVERRIDE_SOURCE if "steps" in (overrides or {}) else run_dir / CONFIG_FILE,
                "steps",
                f"at least the latest checkpoint's step {done}",
                config.steps,
            )
    elif overrides:
        raise TrainConfigError(OVERRIDE_SOURCE, "overrides", "only with resume (pass them to load_config)", overrides)
    elif not isinstance(config, TrainConfig):
        source = str(config)
        config = load_config(config)
    config.validate(source)
    if config.distill.teacher is not None:
        from .distill import check_teacher

        check_teacher(config, source)  # before anything is built or written
    if config.log.tensorboard:
        from .tensorboard import require_tensorboard

        require_tensorboard()  # before anything is built or written
    if config.log.wandb:
        from .wandb_log import require_wandb

        require_wandb()
    return config, source, ckpt


def _checked_run_dir(config: TrainConfig, resume, source: str) -> Path:
    """The run folder: ``resume``, or ``config.run_dir`` when it holds no checkpoints yet."""
    run_dir = Path(config.run_dir) if resume is None else Path(resume)
    if resume is None and list_checkpoints(run_dir):
        raise TrainConfigError(
            source,
            "run_dir",
            "a new run folder (continue an existing run with --resume RUN_DIR)",
            f"{run_dir} (holds checkpoints)",
        )
    return run_dir


def _accumulation_steps(config: TrainConfig, info: DistInfo, source: str) -> int:
    """Micro-batches per optimiser step on each process: batch_size / (processes × micro_batch), a whole number ≥ 1."""
    per_rank, rem = divmod(config.batch_size, info.world * config.micro_batch)
    if rem or per_rank < 1:
        raise TrainConfigError(
            source,
            "batch_size",
            f"a multiple of processes x micro_batch = {info.world} x {config.micro_batch}",
            config.batch_size,
        )
    return per_rank


@dataclass
class _Run:
    """What the loop trains, built once: the bare ``model`` and its parallel ``wrapped`` form, AdamW, the fp32
    ``ema`` (parameter name → tensor), the clips and their step planner, the frozen distillation ``teacher``
    (or None), the optimiser steps already done (``start``), micro-batches per step, the activation
    checkpointing chosen and why, and the forward's autocast context (or None)."""

    run_dir: Path
    model: torch.nn.Module
    wrapped: torch.nn.Module
    optimizer: torch.optim.AdamW
    ema: dict
    data: TrainData
    planner: StepPlanner
    teacher: object
    start: int
    accum: int
    checkpointing: object
    checkpointing_reason: str
    autocast: object


def _build_run(config: TrainConfig, ckpt, registry, source: str, info: DistInfo, run_dir: Path, accum: int) -> _Run:
    """Seeds torch, builds the VAE, transformer, data, teacher and optimiser on ``info.device`` and loads the
    parent run's weights or the checkpoint ``ckpt`` being resumed."""
    torch.manual_seed(config.seed)
    vae = build_vae(config, device=info.device, source=source)
    model = build_transformer(config, source)
    data = TrainData(config, vae, model.text_dim, registry)
    _check_source_weights(config, data, source)
    planner: StepPlanner = data.planner()
    teacher = None
    if config.distill.teacher is not None:
        from .distill import load_teacher

        teacher = load_teacher(config, data, info.device, source)
    check_previous_windows(config.flow.self_forcing, "flow.self_forcing", data, config.data.window, source)
    if config.parent_run and ckpt is None:
        load_weights(latest_checkpoint(config.parent_run), model, key="model")
    shards = info.world if config.parallel == "fsdp" else 1
    compression = (int(getattr(vae, "temporal", 4)) if vae is not None else 4, data.spatial)
    checkpointing, why = prepare_for_training(model, config, info.device, shards, compression)
    _log.info("%s%s", why, "; model.compile: every DiT block compiled" if config.model.compile else "")
    model.to(info.device)
    wrapped = wrap_model(model, config.parallel, info)
    optimizer = build_optimizer(wrapped, config)
    ema = {n: p.detach().clone().float() for n, p in model.named_parameters()}
    start = 0
    if ckpt is not None:
        start = load_checkpoint(ckpt, wrapped, optimizer, ema, info)
    return _Run(run_dir, model, wrapped, optimizer, ema, data, planner, teacher, start, accum, checkpointing, why, None)


def _train(config, resume, progress, stop_after, registry, source, info: DistInfo, overrides=None):
    """build → (resume) → the loop of :func:`_train_steps`; returns ``(TrainResult, config)``."""
    config, source, ckpt = _checked_config(config, resume, overrides, source)
    run_dir = _checked_run_dir(config, resume, source)
    accum = _accumulation_steps(config, info, source)
    run = _build_run(config, ckpt, registry, source, info, run_dir, accum)
    metrics_path = run_dir / METRICS_FILE
    if info.main:
        run_dir.mkdir(parents=True, exist_ok=True)
        if resume is None or overrides:
            save_config(config, run_dir / CONFIG_FILE)
        atomic_write_bytes(metrics_path, _read_metrics(metrics_path, run.start))
    run.autocast = autocast_for(config, info.device)
    end = config.steps if stop_after is None else min(config.steps, stop_after)
    last_loss = _train_steps(config, run, info, end, progress)
    return TrainResult(run_dir, end, last_loss, None), config


def _start_record(config: TrainConfig, run: _Run, info: DistInfo) -> dict:
    """The metrics line of step 0 (``event: start``): processes, accumulation, parallelism, the data's summary."""
    return {
        "step": 0,
        "event": "start",
        "world_size": info.world,
        "accumulation": run.accum,
        "parallel": config.parallel,
        "activation_checkpointing": run.checkpointing,
        "checkpointing_reason": run.checkpointing_reason,
        "compile": config.model.compile,
        **run.data.summary(),
        "skipped": run.data.skipped,
        "mixing_weights": run.planner.weights,
    }


def _accumulate_gradients(config: TrainConfig, run: _Run, info: DistInfo, step: int, batches) -> tuple[float, int]:
    """Zeroes the gradients and backpropagates the ``run.accum`` micro-batches of optimiser step ``step`` (the
    all-reduce only on the last). Returns ``(loss, forced)``: this process's mean loss over them and the items
    it trained from the student's own first frame (self forcing; 0 without it)."""
    run.optimizer.zero_grad(set_to_none=True)
    loss_sum, forced = 0.0, 0
    for k in range(run.accum):
        got_step, got_k, micro, batch = next(batches)
        assert (got_step, got_k) == (step, k), "the loader hands out micro-batches in plan order"
        with no_sync(run.wrapped, k == run.accum - 1):
            if run.teacher is None:
                if config.flow.self_forcing > 0:
                    batch, n_forced = _flow_self_force(run, batch, micro, config, info.device)
                    forced += n_forced
                loss = step_loss(run.wrapped, batch, micro, config, info.device, run.autocast)
            else:
                if config.distill.self_forcing > 0:
                    # FSDP2's student gathers its shards in its forward; DDP's wrapper would sync buffers
                    student = run.wrapped if config.parallel == "fsdp" else run.model
                    batch, n_forced = self_force(student, run.data, batch, micro, config, info.device, run.autocast)
                    forced += n_forced
                loss = distill_loss(run.wrapped, run.teacher, batch, micro, config, info.device, run.autocast)
            (loss / run.accum).backward()
        loss_sum += float(loss.detach()) / run.accum
    return loss_sum, forced


def _flow_self_force(run: _Run, batch: Batch, micro: list[PlanItem], config: TrainConfig, device) -> tuple[Batch, int]:
    """``flow.self_forcing``: the micro-batch with its chosen items' first latent frames made by the model being
    trained (:func:`~.self_forcing.own_first_frames`), sampled in ``flow.self_forcing_steps`` Euler steps with
    guidance ``flow.self_forcing_guidance`` (diffusers form) on the training schedule's shift."""
    f = config.flow
    sampler = SamplerConfig(
        steps=f.self_forcing_steps,
        shift=f.shift,
        guidance=f.self_forcing_guidance,
        guidance_form="diffusers",
        cond_timestep=f.cond_timestep,
        solver="euler",
    )
    model = run.wrapped if config.parallel == "fsdp" else run.model  # DDP's wrapper would sync buffers
    return own_first_frames(
        model,
        run.data,
        batch,
        micro,
        f.self_forcing,
        sampler,
        device,
        condition=config.condition,
        window=config.data.window,
        autocast=run.autocast,
        any_rank=lambda mine: any_rank_samples(mine, config),
    )


def _batch_figures(config: TrainConfig, whole: list[PlanItem]) -> dict:
    """A step's metrics figures of its whole global batch ``whole``: the mean sigma, the items whose skeleton was
    dropped and, with a context of more than one frame, the items trained on the first frame alone."""
    figures = {"sigma_mean": sum(i.sigma for i in whole) / len(whole), "skeleton_dropped": sum(i.drop for i in whole)}
    if context_latents(config) > 1:
        drawn_context = item_context(whole, context_latents(config), config.flow.context_dropout)
        figures["context_one_frame"] = drawn_context.count(1)
    return figures


def _train_steps(config: TrainConfig, run: _Run, info: DistInfo, end: int, progress: bool) -> float | None:
    """Optimiser steps ``run.start`` .. ``end`` − 1: step, log (metrics.jsonl, TensorBoard, W&B, the progress
    bar), save a checkpoint every ``save_every`` steps and at ``end``. Returns the last step's loss (None when no
    step was taken)."""
    run_dir, planner, start, o = run.run_dir, run.planner, run.start, config.optim
    tb = None
    if info.main and config.log.tensorboard:
        from .tensorboard import TensorBoardLog

        tb = TensorBoardLog(run_dir, purge_step=start + 1 if start else None)
    wb = None
    if info.main and config.log.wandb:
        from dataclasses import asdict

        from .wandb_log import WandbLog

        wb = WandbLog(run_dir, asdict(config), project=config.log.wandb_project, mode=config.log.wandb_mode)
    log = open(run_dir / METRICS_FILE, "a") if info.main else None
    if log and start == 0:
        log.write(json.dumps(_start_record(config, run, info)) + "\n")
        log.flush()
    # items drawn per source so far (a resumed run replays the plan of the steps it has done)
    drawn = planner.drawn(start, config.batch_size) if info.main else {}
    bar = progress_bar(total=config.steps, initial=start, enabled=progress and info.main, unit="step", desc="train")
    last_loss, t0, done_at_t0 = None, time.perf_counter(), start
    forced = 0  # items of this rank trained from the model's own first frame (self forcing), since the last log
    self_forcing = config.distill.self_forcing > 0 or config.flow.self_forcing > 0
    forced_all = 0  # the whole global batch's count, summed over ranks when a record is written

    def plan(step: int) -> list[PlanItem]:
        return StepPlanner.rank_slice(planner.plan(step, config.batch_size), info.rank, info.world)

    batches = iter_batches(
        run.data,
        micro_batches(plan, start, end, run.accum, config.micro_batch),
        config.condition,
        config.data.workers,
        config.data.prefetch,
    )
    try:
        for step in range(start, end):
            lr = lr_at(step, o.lr, o.warmup_steps)
            for g in run.optimizer.param_groups:
                g["lr"] = lr
            mine = plan(step)
            loss_sum, n_forced = _accumulate_gradients(config, run, info, step, batches)
            forced += n_forced
            grad_norm = apply_update(run.wrapped, run.model, run.optimizer, run.ema, config)
            loss_mean = all_reduce_mean(loss_sum, info)
            last_loss = loss_mean
            done = step + 1
            if not math.isfinite(loss_mean):
                raise FloatingPointError(f"{run_dir}: loss: expected a finite number, found {loss_mean} at step {done}")
            rate = (done - done_at_t0) / max(time.perf_counter() - t0, 1e-9)
            bar.set_postfix(loss=f"{loss_mean:.4f}", lr=f"{lr:.2e}", refresh=False)
            bar.update(1)
            if log:
                # figures of the whole global batch, not this rank's share: the plan is a function of (seed, step),
                # so rank 0 recomputes it rather than gathering the other ranks' shares
                whole = planner.plan(step, config.batch_size) if info.world > 1 else mine
                for src, n in planner.source_counts(whole).items():
                    drawn[src] += n
            logs_now = done % config.log_every == 0 or done == end
            if logs_now and self_forcing:  # every rank: the count of the whole global batch, since the last record
                forced_all, forced = int(all_reduce_sum(forced, info)), 0
            if log and logs_now:
                record = {
                    "step": done,
                    "loss": loss_mean,
                    "lr": lr,
                    "grad_norm": grad_norm,
                    "steps_per_s": rate,
                    "elapsed_s": time.perf_counter() - t0,
                    **_batch_figures(config, whole),
                    "sources_drawn": dict(drawn),
                }
                if self_forcing:
                    record["self_forced"] = forced_all
                log.write(json.dumps(record) + "\n")
                log.flush()
                if tb is not None:
                    tb.write(record)
                if wb is not None:
                    wb.write(record)
            if done % config.save_every == 0 or done == end:
                save_checkpoint(run_dir, done, run.wrapped, run.optimizer, run.ema, info, config.keep_last)
                if info.main:
                    write_sources(run_dir, planner, drawn, done, config)
    finally:
        batches.close()
        bar.close()
        if log:
            log.close()
        if tb is not None:
            tb.close()
        if wb is not None:
            wb.close()
    return last_loss
