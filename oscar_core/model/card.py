"""The model card of an OSCAR model folder: :class:`ModelCard` (what a checkpoint expects and where it came from:
chunk frames, resolution in pixels, fps, embodiments, text encoder, condition, recommended sampler settings) and
:func:`read_card`, which reads it from the folder's ``oscar_model.json`` (``{"format": FORMAT, "format_version": 1,
"card": {...}}``) without loading weights. Re-exported by :mod:`oscar_core.model.world_model`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from ..errors import OscarError
from ..render.conditions import (
    MODEL_CONDITIONS as CONDITIONS,
    ConditionName,
    condition_style,
    is_video_condition,
    takes_actions,
)
from ._files import MODEL_FILE
from .card_sampler import check_card_sampler
from .chunks import check_context_frames, check_frame_count
from .errors import CheckpointLayoutError, ModelInputError
from .manifest import MANIFEST_NAME

__all__ = ["FORMAT", "ModelCard", "read_card"]

FORMAT = "oscar-world-model"
UNCONDITIONAL_SKELETONS = ("zero_latent", "black_video")


@dataclass(frozen=True)
class ModelCard:
    """What a checkpoint expects and where it came from.

    chunk_frames: frames per generated chunk (4k+1; the paper trains on 81);
    width, height: resolution in pixels it was trained at (None: unknown);
    fps: frame rate of its training videos (None: unknown);
    embodiments: embodiment names (oscar plugins) it was trained on;
    text_encoder_id: names the encoder whose embeddings it takes (cache key);
    base: the checkpoint it was fine-tuned from; license: SPDX id or name;
    unconditional_skeleton: what the skeleton stream was replaced with when
    training dropped it (the paper's "replaced with zeros"), so that the
    sampler's unconditional branch sees the same thing: ``"zero_latent"`` (a
    zero skeleton latent) or ``"black_video"`` (the VAE latent of an all-black
    skeleton video).
    condition: what the model is conditioned on besides the first frame and
    the text: ``"skeleton"`` (the skeleton video; cards written before this
    field load as skeleton), ``"latent_action"`` (the paper's latent-action
    baseline: a ``LatentActionTransformer`` fed (chunk_frames − 1, 14)
    end-effector actions per chunk) or ``"none"`` (text and first frame
    only; its PE_s is zero, so a skeleton fed to it changes nothing).
    condition_style: how its condition video is drawn, a mapping of
    :class:`~oscar_core.render.raster.SkeletonStyle` fields (sizes in pixels at 288 px of height; e.g. a larger
    gripper indicator), as it was trained; every rollout draws the condition so. None: the default look.
    sampler: the sampler settings the model is meant to be rolled out with (a mapping of
    :data:`~oscar_core.model.card_sampler.CARD_SAMPLER_KEYS`: steps, guidance, guidance_form, preset); every
    entry point uses them where its caller gives none (:func:`~oscar_core.model.card_sampler.resolve_sampler`);
    None: the library's defaults.
    gripper_signal: the DiT also takes the gripper's openness per latent frame, appended to the condition latent
    (:mod:`~oscar_core.model.gripper_signal`); every rollout passes it (``rollout_inputs`` gives it as
    ``"gripper"``). False: the gripper is seen only as the indicator drawn in the condition video.
    tiny_decoder: a safetensors file of tiny-decoder weights inside the model folder (a relative path such as
    ``"tiny_decoder.safetensors"``, :mod:`~oscar_core.model.tiny_decoder`) that decodes instead of the full VAE
    decoder whenever the model is loaded (``from_pretrained(tiny_decoder=False)`` or ``--full-decoder`` turn it
    off). None: the full decoder.
    context_frames: pixel frames (4k + 1: 1, 5, ...; k + 1 latent frames, fewer than the chunk's) each chunk after
    the first is conditioned on: the previous chunk's last ``context_frames`` decoded frames, re-encoded and kept
    clean by the sampler (:mod:`~oscar_core.model.chunks` has the chunk plan). The first chunk of a rollout has the
    given first frame alone (a 1-frame context, which training serves with ``flow.context_dropout``). A card
    without it reads as 1 (one frame: every model before the field) and is written without it.
    """

    name: str | None = None
    chunk_frames: int = 81
    width: int | None = None
    height: int | None = None
    fps: float | None = None
    embodiments: tuple[str, ...] = ()
    text_encoder_id: str | None = None
    base: str | None = None
    license: str | None = None
    unconditional_skeleton: str = "zero_latent"
    condition: ConditionName = "skeleton"
    condition_style: dict | None = None
    sampler: dict | None = None
    gripper_signal: bool = False
    tiny_decoder: str | None = None
    context_frames: int = 1

    def __post_init__(self):
        check_frame_count(int(self.chunk_frames), what="model card chunk_frames")
        if self.unconditional_skeleton not in UNCONDITIONAL_SKELETONS:
            raise ModelInputError(
                f"model card unconditional_skeleton: expected one of {UNCONDITIONAL_SKELETONS}, "
                f"found {self.unconditional_skeleton!r}"
            )
        if self.condition not in CONDITIONS:
            raise ModelInputError(f"model card condition: expected one of {CONDITIONS}, found {self.condition!r}")
        try:
            condition_style(self.condition_style, "model card condition_style")
        except OscarError as e:
            raise ModelInputError(str(e)) from None
        object.__setattr__(self, "condition_style", dict(self.condition_style) if self.condition_style else None)
        if not isinstance(self.gripper_signal, bool):
            raise ModelInputError(f"model card gripper_signal: expected true or false, found {self.gripper_signal!r}")
        if self.gripper_signal and not is_video_condition(self.condition):
            raise ModelInputError(
                f"model card gripper_signal: expected a condition video beside it (skeleton, mesh, capsules), "
                f"found condition {self.condition!r}"
            )
        _check_tiny_decoder_name(self.tiny_decoder)
        check_context_frames(self.context_frames, int(self.chunk_frames), what="model card context_frames")
        if self.context_frames != 1 and takes_actions(self.condition):
            raise ModelInputError(
                f"model card context_frames: expected 1 for a latent-action model (condition {self.condition!r}), "
                f"found {self.context_frames}"
            )
        object.__setattr__(self, "embodiments", tuple(self.embodiments))
        object.__setattr__(self, "sampler", check_card_sampler(self.sampler, "model card sampler"))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["embodiments"] = list(self.embodiments)
        if d["tiny_decoder"] is None:
            del d["tiny_decoder"]  # a card without one is written as before it existed (same bytes, same hashes)
        if d["context_frames"] == 1:
            del d["context_frames"]  # likewise: a one-frame card keeps its bytes
        return d

    @classmethod
    def from_dict(cls, data: dict, source="<card>") -> ModelCard:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise CheckpointLayoutError(source, "card", f"keys among {sorted(known)}", f"unknown keys {unknown}")
        return cls(**data)


def _check_tiny_decoder_name(name) -> None:
    """The card's ``tiny_decoder``: None, or a relative path inside the model folder ending in ``.safetensors``."""
    if name is None:
        return
    ok = isinstance(name, str) and name.endswith(".safetensors")
    parts = Path(name).parts if ok else ()
    if not ok or not parts or Path(name).is_absolute() or ".." in parts:
        raise ModelInputError(
            f"model card tiny_decoder: expected a .safetensors file inside the model folder (a relative path), "
            f"found {name!r}"
        )


def read_card(folder: Path) -> ModelCard:
    """The :class:`ModelCard` of an OSCAR model folder (its ``oscar_model.json``), without loading weights. A card
    whose ``tiny_decoder`` names a file the folder lacks is refused here, before any weights are read."""
    path = folder / MODEL_FILE
    if not path.is_file():
        found = ", ".join(sorted(p.name for p in folder.iterdir())) if folder.is_dir() else "no such folder"
        raise CheckpointLayoutError(
            folder,
            MODEL_FILE,
            f"an OSCAR model folder ({MODEL_FILE}, transformer/, vae/, {MANIFEST_NAME})",
            found or "an empty folder",
        )
    try:
        data = json.loads(path.read_text())
    except ValueError as exc:
        raise CheckpointLayoutError(path, "JSON", "a JSON object", f"unreadable JSON ({exc})") from None
    if data.get("format") != FORMAT:
        raise CheckpointLayoutError(path, "format", repr(FORMAT), repr(data.get("format")))
    try:
        card = ModelCard.from_dict(data.get("card") or {}, path)
    except (TypeError, ModelInputError) as exc:
        raise CheckpointLayoutError(path, "card", "a valid model card", str(exc)) from None
    if card.tiny_decoder is not None and not (folder / card.tiny_decoder).is_file():
        raise CheckpointLayoutError(
            path, "card.tiny_decoder", f"a file of the model folder {folder}", f"no file {card.tiny_decoder}"
        )
    return card
