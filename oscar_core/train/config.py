"""The training configuration, one schema: every field's comment says where its default comes from.

A tree of dataclasses read from YAML. Loading the YAML (each value typed as its field says) follows the
dataclasses it fills; what each field may hold, alone and beside the others, is checked in :mod:`.config_checks`.

Every field has a default and a comment saying where its value comes from.
Defaults are the paper's recipe (Appendix "Training implementation
details") where it gives a number, else Cosmos-Predict2.5's public trainer
defaults (``shared/design/architecture.md`` §7), else our own choice (said so).
``configs/train/oscar-2b.yaml`` restates them with the same comments;
``configs/train/tiny-cpu.yaml`` is the CPU smoke-test config.

A YAML file holds the same tree (unknown keys are errors naming the file and
the key)::

    run_dir: runs/tiny
    model: {transformer: tiny, vae: tiny}
    data: {clips: [clipsets/toy], window: 9, width: 32, height: 32}
    optim: {lr: 3.0e-5}
    steps: 100
"""

from __future__ import annotations

import dataclasses
import math
import re
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .._util.inputs import read_text_file
from ..errors import OscarError
from ..render.conditions import MODEL_CONDITIONS as CONDITIONS
from .config_checks import PARALLEL_MODES, check_config

__all__ = [
    "TrainConfigError",
    "ModelSection",
    "DataSection",
    "FlowSection",
    "OptimSection",
    "LogSection",
    "DistillSection",
    "TrainConfig",
    "load_config",
    "save_config",
    "config_from_dict",
    "config_to_dict",
    "CONDITIONS",
    "PARALLEL_MODES",
    "RESUME_OVERRIDES",
    "parse_overrides",
    "check_resume_overrides",
]


class TrainConfigError(OscarError, ValueError):
    """A training config is invalid; names the file, the field, what was expected and what was found."""

    def __init__(self, source, field_name, expected, found):
        self.source, self.field, self.expected, self.found = str(source), field_name, expected, found
        super().__init__(f"{source}: field '{field_name}': expected {expected}, found {found}")

    def __reduce__(self):
        return (type(self), (self.source, self.field, self.expected, self.found))


@dataclass
class ModelSection:
    """Which networks to train and where their weights start."""

    # "tiny" (oscar_core.model.tiny, seeded random), "cosmos-2b" (the 2B architecture, random init), a path to a
    # transformer config.json (or a folder holding one), or an inline dict of OscarTransformer3DModel arguments
    transformer: Any = "tiny"
    # where the transformer's weights start: null (random: seeded for "tiny", diffusers' init otherwise, PE_s
    # zero), "cosmos_base:FOLDER" (Cosmos-Predict2.5 diffusers transformer folder + zero PE_s, the paper's start),
    # or an OSCAR model folder (oscar_zoo.load layout) or an OSCAR transformer folder
    init: str | None = None
    # the VAE: "tiny" (seeded random), an AutoencoderKLWan folder (config.json + safetensors), or an OSCAR model
    # folder (its vae/); needed for on-the-fly encoding, the black-video unconditional latent and export
    vae: str = "tiny"
    # seed of the "tiny" presets' random weights (ours)
    seed: int = 0
    # how the layers that bring the condition in start when init is null (training from scratch): "zero" (the
    # paper's fine-tuning recipe: PE_s, or the latent-action MLPs' last layers, output zero, so the model starts as
    # its base) or "default" (the constructor's own init, as the video patch embedder's; ours: from scratch there
    # is no base to preserve, and a zero PE_s grew ~9x slower than the video embedder in the toy world). With a
    # base (init set), the new layers are always zero.
    condition_init: str = "zero"
    # torch.compile every DiT block (ours: faster steps on a GPU after a compile of about a minute; the weights,
    # checkpoints and their keys are the same); docs/training.md
    compile: bool = False
    # the DiT also takes the gripper's openness per latent frame, appended to the condition latent and embedded by
    # PE_s (ours: the skeleton's gripper indicator covers 1-2 latent cells at 64 px and a model trained on it moved
    # the ball whether or not the gripper closed; oscar_core/model/gripper_signal.py). The export's card records it.
    gripper_signal: bool = False
    # pixel frames each chunk is conditioned on, 4k+1 (k + 1 latent frames kept clean, fewer than the window's): 1
    # (the paper: the first frame) or 5 (ours, against drift: two latent frames, so the model sees the motion at a
    # chunk's seam, as Cosmos-Predict2's Video2World takes 1 or 5 frames). The export's card records it
    context_frames: int = 1
    # compute dtype of the forward: "float32" on CPU (issue), "bfloat16" autocast on GPU (Cosmos trains in bf16)
    dtype: str = "float32"


@dataclass
class DataSection:
    """Where clips come from and how windows are drawn."""

    # clip-set folders (oscar_core.train.clips); all their finished shards are used
    clips: list[str] = field(default_factory=list)
    # keep only clips of these sources (stage 1: the robot sources), null = all
    sources: list[str] | None = None
    # frames per training window, 4k+1 (the paper: 81)
    window: int = 81
    # training resolution in pixels; clips of another size are centre-cropped and scaled, the camera with them
    # (the paper's 512x288, architecture.md §8)
    width: int = 512
    height: int = 288
    # "cached": use the clips' cached VAE latents; "on_the_fly": encode videos in the loop; "auto": cached when
    # every clip has latents for this window and size, else on the fly
    latents: str = "auto"
    # source-mixing temperature T: w_i ∝ n_frames_i^(1/T) (the paper: T = 3)
    mixing_temperature: float = 3.0
    # explicit per-source weights {source: weight}, normalised, replacing the temperature rule; they must name every
    # source of the clips (ours: the hand/robot ratio of docs/toyworld.md); null = the temperature rule
    source_weights: dict[str, float] | None = None
    # trapezoid window prior: ramp width as a fraction of the window (ours; the paper gives none, docs/training.md)
    prior_ramp: float = 0.25
    # mixture weight of a uniform prior added to the trapezoid one (ours; 0 = the paper's pure trapezoid)
    prior_uniform: float = 0.0
    # skeleton dropout probability per sample, for classifier-free guidance (the paper: 0.2)
    skeleton_dropout: float = 0.2
    # what a dropped skeleton becomes: "zero_latent" or "black_video" (the paper: "replaced with zeros")
    unconditional_skeleton: str = "zero_latent"
    # false: a bad clip (too short, unknown embodiment, unreadable files) is an error naming shard and clip;
    # true: it is skipped and counted (metrics.jsonl "skipped_clips")
    skip_bad_clips: bool = False
    # open every clip's files before training (trajectory length, video frame count and size); catches broken
    # clips up front at the cost of one pass over the files
    check_files: bool = True
    # threads that load micro-batches ahead of the training step (ours; 0 = load in the loop, the default);
    # the batches are the same for any number (oscar_core.train.loader)
    workers: int = 0
    # micro-batches each worker keeps loaded ahead (ours; as torch DataLoader's prefetch_factor)
    prefetch: int = 2
    # ours: a function (frames (T, H, W, 3) uint8) -> (T, H, W) bool, as module:attr or path/to/file.py:attr, that
    # marks the pixels whose latent cells flow.focus_weight weighs more (oscar_core.train.focus; the toy world's
    # ball: oscar_core.toyworld.locate:ball_mask); null = none
    focus_mask: str | None = None


@dataclass
class FlowSection:
    """Rectified flow as Cosmos-Predict2.5 trains it."""

    # schedule shift s: sigma = s u / (1 + (s - 1) u) (the paper and Cosmos: 5)
    shift: float = 5.0
    # u = sigmoid(N(mean, std)) (Cosmos: logit-normal with mean 0, std 1)
    logit_mean: float = 0.0
    logit_std: float = 1.0
    # timestep fed for the clean conditioning frame (the sampler's and diffusers' 1e-4)
    cond_timestep: float = 1e-4
    # ours, against drift: the conditioning frame is fed noised at sigma_c ~ U(0, cond_noise_max) per sample, its
    # timestep then sigma_c (oscar_core.train.flow); 0 = always clean (the paper's and Cosmos' recipe)
    cond_noise_max: float = 0.0
    # ours: extra loss weight w on the latent cells data.focus_mask touches (their elements weigh 1 + w, the rest
    # 1; oscar_core.train.focus); 0 = the plain loss
    focus_weight: float = 0.0
    # with model.context_frames > 1: the fraction of items trained with the first latent frame alone as context, the
    # context a rollout's first chunk has (ours; Cosmos-Predict2.5's Video2World trainers likewise draw 1 or 2
    # conditioning latent frames per sample)
    context_dropout: float = 0.25
    # ours, against drift (self forcing, oscar_core.train.self_forcing): the fraction of items whose first frame is
    # the model's own, as chunk 2 of a rollout sees it: the model being trained samples the window that ends at the
    # item's first frame (data.window - 1 frames earlier, from its clean first frame; no gradient), the VAE decodes
    # it and re-encodes its last frame. Only items with such a window in their clip qualify. 0: off
    self_forcing: float = 0.0
    # how that window is sampled, as the model's rollouts will sample it (ours: the toy benchmark's 10 steps,
    # guidance 3 in the diffusers form; null guidance: the conditional branch alone, half the cost)
    self_forcing_steps: int = 10
    self_forcing_guidance: float | None = 3.0


@dataclass
class OptimSection:
    """AdamW, warm-up, clipping, EMA."""

    # learning rate (the paper: 3e-5)
    lr: float = 3e-5
    # AdamW weight decay (Cosmos-Predict2.5 trainer: 1e-3)
    weight_decay: float = 1e-3
    # AdamW betas and eps (PyTorch defaults; the paper gives none)
    betas: tuple = (0.9, 0.999)
    eps: float = 1e-8
    # gradient-norm clipping (Cosmos-Predict2.5 trainer: 0.1)
    grad_clip: float = 0.1
    # linear warm-up steps (Cosmos-Predict2.5 trainer: 100)
    warmup_steps: int = 100
    # EMA decay per step (ours; the paper gives none)
    ema_decay: float = 0.9999


@dataclass
class LogSection:
    """Where metrics go besides RUN_DIR/metrics.jsonl."""

    # also write the metrics as TensorBoard scalars to RUN_DIR/tensorboard (ours; needs oscar-wm[tensorboard])
    tensorboard: bool = False
    # also log the metrics to a Weights & Biases run, as LeRobot and diffusers offer (ours; needs oscar-wm[wandb])
    wandb: bool = False
    # the W&B project (ours)
    wandb_project: str = "oscar"
    # offline (default: nothing leaves the machine; `wandb sync` later), online or disabled (ours)
    wandb_mode: str = "offline"


@dataclass
class DistillSection:
    """A few-step student distilled from a teacher (oscar_core.train.distill, docs/distillation.md); off when
    ``teacher`` is null."""

    # the teacher: an OSCAR model folder (oscar_model.json); null: plain training. The student starts from
    # model.init (set it to the teacher: Meng et al. 2023 initialise the student as the teacher)
    teacher: str | None = None
    # Euler steps the student samples a chunk in, on the flow.shift schedule (ours: 4, the budget)
    steps: int = 4
    # teacher Euler steps per student step: 2 is one halving round of progressive distillation (Meng et al. 2023,
    # Salimans & Ho 2022); 1 folds the guidance in at the same step count
    substeps: int = 2
    # the teacher's guidance weight w; null: the teacher card's recommendation (else the library's 6)
    guidance: float | None = None
    # self forcing (ours; Huang et al. 2025's train-test fix): the fraction of items whose first frame is the
    # student's own, as in a long rollout: the student samples the chunk that ends at the item's first frame (the
    # window data.window - 1 frames earlier, in distill.steps Euler steps from its clean first frame), the VAE
    # decodes it and re-encodes its last frame. Only items with such a window in their clip qualify. 0: off
    self_forcing: float = 0.0


@dataclass
class TrainConfig:
    """A whole training run."""

    # the run folder (checkpoints, metrics.jsonl, config.yaml, export/)
    run_dir: str = "runs/oscar"
    # what conditions the DiT: "skeleton" (OSCAR), "mesh" (the robot's URDF visual geometry rendered through the
    # same camera, through the VAE and PE_s like the skeleton: the paper's ablation), "capsules" (capsules along the
    # skeleton's edges with fingers: the toy world's robot body, a mesh for robots without meshes), "latent_action" (the paper's
    # ablation), "none" (text only)
    condition: str = "skeleton"
    # how the condition video is drawn, a mapping of SkeletonStyle fields (oscar_core.render.raster; sizes in pixels
    # at 288 px of height), e.g. {gripper_radius_open: 27, gripper_radius_closed: 14} for a gripper indicator that
    # shows at a 64-px toy's latent resolution; null: the default look. Written into the export's card, so every
    # rollout draws the condition as training did; cached condition latents record it and must match
    condition_style: dict | None = None
    # warm start from another run's latest checkpoint (stage 2 names the stage-1 run), or null
    parent_run: str | None = None
    # seed of every random draw (windows, timesteps, noise, dropout)
    seed: int = 0
    # optimiser steps (the paper: stage 1 = 15k iterations)
    steps: int = 15000
    # global batch in clips per optimiser step (the paper: 16)
    batch_size: int = 16
    # clips per forward on one process; batch_size = processes x micro_batch x accumulation (ours: 1 fits a GPU)
    micro_batch: int = 1
    # "auto" (DDP when launched on several processes), "none", "ddp" or "fsdp" (fully_shard per block)
    parallel: str = "auto"
    # activation checkpointing of every DiT block: "full", "none", or "auto" (ours: full when the step would not
    # fit the GPU's free memory without it, by oscar_core.train.memory's computed model; none on the CPU)
    activation_checkpointing: str = "auto"
    # write metrics every n steps, a checkpoint every n steps (and at the end), keep the last n checkpoints
    log_every: int = 10
    save_every: int = 1000
    keep_last: int = 3
    # write a zoo-loadable folder (EMA weights) to RUN_DIR/export at the end
    export: bool = True
    # the sampler the export's card recommends, as a card's sampler mapping (steps, guidance, guidance_form,
    # preset), so rollouts of the export sample as the run was measured to; `oscar train --export --sampler` wins
    # over it. null: none (rollouts take the library's 35 steps at guidance 6). A distillation run's export names
    # the student's own
    export_sampler: dict | None = None
    model: ModelSection = field(default_factory=ModelSection)
    data: DataSection = field(default_factory=DataSection)
    flow: FlowSection = field(default_factory=FlowSection)
    optim: OptimSection = field(default_factory=OptimSection)
    log: LogSection = field(default_factory=LogSection)
    distill: DistillSection = field(default_factory=DistillSection)

    def validate(self, source: str = "<config>") -> TrainConfig:
        """Raise :class:`TrainConfigError` naming the first bad field (:func:`.config_checks.check_config`)."""

        def fail(name, expected, found):
            raise TrainConfigError(source, name, expected, found) from None

        check_config(self, fail)
        return self


_SECTIONS = {
    "model": ModelSection,
    "data": DataSection,
    "flow": FlowSection,
    "optim": OptimSection,
    "log": LogSection,
    "distill": DistillSection,
}


#: keys this loader no longer reads, by section prefix: what to write instead (the error's "expected")
_RENAMED = {
    "model.": {
        "gradient_checkpointing": "the top-level key activation_checkpointing instead (full for true, "
        "auto or none for false)"
    }
}


def _build(cls, data: Any, source: str, prefix: str):
    if not isinstance(data, dict):
        raise TrainConfigError(source, prefix or "<root>", "a mapping", type(data).__name__)
    names = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    for key in sorted(set(data) & set(_RENAMED.get(prefix, {}))):
        raise TrainConfigError(source, f"{prefix}{key}", _RENAMED[prefix][key], f"{prefix}{key}: {data[key]!r}")
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise TrainConfigError(source, f"{prefix}{unknown[0]}", f"one of {sorted(names)}", "an unknown key")
    kwargs = {}
    for key, value in data.items():
        if cls is TrainConfig and key in _SECTIONS:
            kwargs[key] = _build(_SECTIONS[key], value or {}, source, f"{key}.")
        elif key == "betas":
            if not isinstance(value, (list, tuple)) or len(value) != 2:
                raise TrainConfigError(source, f"{prefix}{key}", "two numbers", repr(value))
            kwargs[key] = tuple(_typed(float, v, source, f"{prefix}{key}[{i}]") for i, v in enumerate(value))
        else:
            kwargs[key] = _typed(hints[key], value, source, f"{prefix}{key}")
    return cls(**kwargs)


_EXPONENT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")
_KINDS = {
    bool: "true or false",
    int: "an integer",
    float: "a number",
    str: "a string",
    list: "a list",
    dict: "a mapping",
}


def _typed(hint, value: Any, source: str, name: str) -> Any:
    """``value`` checked against a field's type hint (``int`` as a float is a float); TrainConfigError if it is not.

    YAML gives ``nope`` as a string, ``2.5`` as a float and ``droid`` as a
    string: a boolean takes only true/false, a count only an integer, a list
    only a list (of strings where the field says so).
    """
    args = typing.get_args(hint)
    if type(None) in args:  # X | None
        if value is None:
            return None
        hint = next(a for a in args if a is not type(None))
        args = typing.get_args(hint)
    origin = typing.get_origin(hint) or hint
    if origin is Any:
        return value
    ok = {
        bool: lambda v: isinstance(v, bool),
        int: lambda v: isinstance(v, int) and not isinstance(v, bool),
        float: lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
        str: lambda v: isinstance(v, str),
        list: lambda v: isinstance(v, list),
        dict: lambda v: isinstance(v, dict),
    }[origin]
    if origin is float and isinstance(value, str) and _EXPONENT.fullmatch(value.strip()):
        value = float(value)  # YAML 1.2's 1e-4, which PyYAML (YAML 1.1) reads as a string
    if not ok(value):
        found = "null" if value is None else f"{type(value).__name__} {value!r}"
        raise TrainConfigError(source, name, _KINDS[origin], found)
    if origin is list and args:
        for i, item in enumerate(value):
            _typed(args[0], item, source, f"{name}[{i}]")
    if origin is dict and args:
        return {
            _typed(args[0], k, source, f"{name} key"): _typed(args[1], v, source, f"{name}.{k}")
            for k, v in value.items()
        }
    if origin is float and not math.isfinite(value):
        raise TrainConfigError(source, name, "a finite number", repr(value))
    return float(value) if origin is float else value


def config_from_dict(data: dict, source: str = "<config>") -> TrainConfig:
    """Build and validate a :class:`TrainConfig` from a nested mapping."""
    return _build(TrainConfig, data, source, "").validate(source)


def config_to_dict(config: TrainConfig) -> dict:
    """Plain nested dict (tuples as lists), the inverse of :func:`config_from_dict`."""

    def plain(v):
        if isinstance(v, tuple):
            return [plain(x) for x in v]
        if isinstance(v, list):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v

    return plain(dataclasses.asdict(config))


def load_config(path, overrides: dict | None = None) -> TrainConfig:
    """Read a YAML config; ``overrides`` ({"optim.lr": 1e-4, ...}) replace single fields."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(read_text_file(path, "a training config (YAML, utf-8 text)", error=TrainConfigError))
    except yaml.YAMLError as exc:
        raise TrainConfigError(path, "<file>", "valid YAML", str(exc).splitlines()[0]) from None
    data = data or {}
    overrides = dict(overrides or {})
    for dotted, value in overrides.items():
        node = data
        *parents, last = dotted.split(".")
        for p in parents:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise TrainConfigError(
                    OVERRIDE_SOURCE, dotted, f"a field inside the section {p!r}", f"{p} is not a section"
                )
        node[last] = value
    try:
        return config_from_dict(data, str(path))
    except TrainConfigError as exc:  # a bad value that came from --set is blamed on --set, not on the file
        key = exc.field.split("[", 1)[0]
        if key in overrides or any(key.startswith(k + ".") for k in overrides):
            raise TrainConfigError(OVERRIDE_SOURCE, exc.field, exc.expected, exc.found) from None
        raise


OVERRIDE_SOURCE = "--set"
# the fields `oscar train --resume RUN --set ...` may change: they extend a run or change how often it logs and saves,
# never what a step computes (lr_at, the data plan and the noise do not depend on them)
RESUME_OVERRIDES = ("steps", "save_every", "log_every", "keep_last", "export_sampler")


def parse_overrides(items) -> dict:
    """``["optim.lr=1e-4", "steps=30"]`` → ``{"optim.lr": 1e-4, "steps": 30}`` (values read as YAML)."""
    import yaml

    out = {}
    for item in items:
        if "=" not in item:
            raise TrainConfigError("<command line>", OVERRIDE_SOURCE, "KEY=VALUE", repr(item))
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = yaml.safe_load(v)
        except yaml.YAMLError as exc:
            raise TrainConfigError(OVERRIDE_SOURCE, k.strip(), "a YAML value", str(exc).splitlines()[0]) from None
    return out


def check_resume_overrides(overrides: dict) -> None:
    """Refuse a ``--set`` with ``--resume`` that would change the run rather than extend it, naming the field."""
    for key in overrides:
        if key not in RESUME_OVERRIDES:
            raise TrainConfigError(
                OVERRIDE_SOURCE,
                key,
                f"with --resume only {', '.join(RESUME_OVERRIDES)} (they "
                "extend the run; any other field would change what its checkpoints were trained "
                "with)",
                "a change of the run's config",
            )


def save_config(config: TrainConfig, path) -> Path:
    """Write the resolved config as YAML (atomically)."""
    import yaml

    from .._util.atomic import atomic_write_bytes

    return atomic_write_bytes(path, yaml.safe_dump(config_to_dict(config), sort_keys=False).encode())
