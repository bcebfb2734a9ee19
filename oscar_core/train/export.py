"""Export a run (any saved checkpoint) as a folder ``oscar_zoo.load`` and ``oscar rollout --model`` accept.

The transformer gets the checkpoint's EMA weights (or its raw weights with
``weights="model"``), the VAE is the config's, and the model card records
the window (``chunk_frames``), the training size, the clips' embodiments and
frame rate, the starting weights (``base``) and ``unconditional_skeleton``
(what skeleton dropout fed, so the sampler's unconditional branch matches)
and the run's ``condition``: a ``latent_action`` run's folder holds a
``LatentActionTransformer`` and loads (``oscar_zoo.load``) as an
``OscarWorldModel`` whose rollout is fed latent actions instead of a skeleton.
A distillation run's export (``distill.teacher`` set) records the student's sampler in its card (its steps, no
guidance: it is folded in) and an Euler scheduler, so every entry point samples it as it was trained.
"""

from __future__ import annotations

import shutil
import tempfile
from collections import Counter
from pathlib import Path

import torch

from .checkpoint import checkpoint_dir, latest_checkpoint, load_weights
from .clips import ClipSet
from .config import load_config
from .models import build_transformer, build_vae

__all__ = ["export_run"]


def export_run(
    run_dir,
    out=None,
    *,
    step: int | None = None,
    weights: str = "ema",
    name: str | None = None,
    sampler: dict | None = None,
) -> Path:
    """Write ``run_dir``'s checkpoint (latest, or ``step``) to ``out`` (default RUN_DIR/export); returns ``out``.

    ``sampler``: the settings the card recommends (a card's ``sampler`` mapping: steps, guidance, guidance_form,
    preset), checked before anything is written; None: the run config's ``export_sampler`` (none when that is
    null: rollouts use the library's), the student's own for a distillation run, which refuses any other.

    The folder is assembled beside ``out`` and renamed into place, replacing an older export.
    When no training clip had a prompt embedding (every step saw the zero text
    embedding), the export stores that zero embedding as the model's empty
    prompt.
    """
    from ..model.card_sampler import check_card_sampler
    from ..model.errors import ModelInputError
    from ..model.world_model import ModelCard, OscarWorldModel

    run_dir = Path(run_dir)
    config = load_config(run_dir / "config.yaml")
    recommended = check_card_sampler(config.export_sampler if sampler is None else sampler, "export sampler")
    if recommended is not None and config.distill.teacher is not None:
        raise ModelInputError(
            f"{run_dir}: export sampler: expected none for a distilled student (its card names the steps it was "
            f"trained for), found {recommended!r}"
        )
    ckpt = latest_checkpoint(run_dir) if step is None else checkpoint_dir(run_dir, step)
    out = Path(out) if out is not None else run_dir / "export"
    base = config.model.init or (config.model.transformer if isinstance(config.model.transformer, str) else None)
    config.model.init = None  # the weights come from the checkpoint
    transformer = build_transformer(config)
    load_weights(ckpt, transformer, key=weights)
    transformer.eval()
    vae = build_vae(config)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        records = [
            r
            for root in config.data.clips
            for r in ClipSet(root)
            if config.data.sources is None or r.source in config.data.sources
        ]
        fps = Counter(r.fps for r in records).most_common(1)[0][0] if records else None
        sampler, scheduler = recommended, None
        if config.distill.teacher is not None:
            from ..model.world_model import read_card
            from .distill import student_sampler

            teacher_card = read_card(Path(config.distill.teacher))
            form = (teacher_card.sampler or {}).get("guidance_form", "diffusers")
            sampler, scheduler = student_sampler(config, form)
        card = ModelCard(
            name=name or run_dir.name,
            chunk_frames=config.data.window,
            width=config.data.width,
            height=config.data.height,
            fps=fps,
            embodiments=tuple(sorted({r.embodiment for r in records})),
            base=base,
            unconditional_skeleton=config.data.unconditional_skeleton,
            condition=config.condition,
            condition_style=config.condition_style,
            sampler=sampler,
            gripper_signal=config.model.gripper_signal,
            context_frames=config.model.context_frames,
        )
        model = OscarWorldModel(transformer, vae, card, scheduler_config=scheduler)
        if records and not any("prompt_embeds" in r.files for r in records):
            # every clip trained on the zero text embedding (1, D): that is this model's empty prompt, stored so
            # that a rollout without a prompt uses what training used (and does not warn about zeros)
            model.empty_prompt = torch.zeros(1, 1, transformer.text_dim)
        model.save_pretrained(tmp)
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
