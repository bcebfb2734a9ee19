"""The OSCAR world model as one object.

DiT + VAE + text fallback + model card. One class, one job: its loaders, saver and the four rollout entry points
share the loaded modules and the card; the chunk loop itself lives in :mod:`.rollout`, what a trajectory conditions it on in
:mod:`.rollout_conditions`, the card in :mod:`.card`.

The model card (:class:`ModelCard`, :func:`read_card`, ``FORMAT``) lives in :mod:`oscar_core.model.card` and is
re-exported here.

A saved model is a folder (the layout the zoo expects on the Hub)::

    oscar_model.json                         format tag + ModelCard
    transformer/config.json                  OscarTransformer3DModel
    transformer/diffusion_pytorch_model.safetensors   (or an index + shards)
    vae/config.json                          AutoencoderKLWan (oscar's WanVAE reads and writes it)
    vae/diffusion_pytorch_model.safetensors
    text/empty_prompt_embeds.safetensors     optional: the encoder's embedding of ""
    scheduler/scheduler_config.json          optional: the UniPC (or Euler) scheduler the sampler uses
    oscar_manifest.json                      size + sha256 of every other file

Loading reads safetensors only, builds on the meta device and assigns the
weights strictly (no key may be missing or left over), and checks the
manifest's hashes unless told not to.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from .._util.log import get_logger
from ..render.conditions import takes_actions
from ._files import EMPTY_PROMPT_FILE, MODEL_FILE, SCHEDULER_FILE
from .card import (
    CONDITIONS as CONDITIONS,
    FORMAT,
    UNCONDITIONAL_SKELETONS as UNCONDITIONAL_SKELETONS,
    ModelCard,
    read_card,
)
from .card_sampler import resolve_sampler, sampler_with_scheduler
from .errors import CheckpointLayoutError, ModelInputError
from .gripper_signal import check_gripper_given
from .manifest import read_manifest, verify_files, write_manifest
from .rollout_conditions import action_plan, condition_inputs
from .sampler import SamplerConfig
from .text import check_prompt_embeds, empty_prompt_embeds
from .transformer import OscarTransformer3DModel
from .vae import VideoVAE, load_vae_folder
from .weights import cast_model, check_safetensors

__all__ = ["FORMAT", "MODEL_FILE", "ModelCard", "OscarWorldModel", "read_card"]

_log = get_logger(__name__)


@dataclass(eq=False)
class OscarWorldModel:
    """DiT + VAE (+ stored empty-prompt embedding) + card.

    transformer: OscarTransformer3DModel (already on its device/dtype);
    vae: VideoVAE; card: ModelCard; empty_prompt: (1, L, D) or None.
    compile_mode: ``auto`` (default), ``always`` or ``never``: whether rollouts compile the DiT
    (:mod:`oscar_core.model.compile_policy`; ``auto`` compiles on CUDA for jobs long enough to pay for it);
    compile_cells: how many rollouts of this size the job will run (``oscar eval run`` sets it), so that
    ``auto`` weighs the whole job, not one rollout. :meth:`set_compile` sets both.
    """

    transformer: OscarTransformer3DModel
    vae: VideoVAE
    card: ModelCard = field(default_factory=ModelCard)
    empty_prompt: torch.Tensor | None = None
    scheduler_config: dict | None = None
    compile_mode: str = "auto"
    compile_cells: int = 1
    compile_reason: str | None = None  # the last rollout's compile decision, in words

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_modules(
        cls,
        transformer,
        vae,
        card: ModelCard | None = None,
        empty_prompt=None,
        *,
        device="cpu",
        dtype: torch.dtype | None = None,
        vae_dtype: torch.dtype | None = None,
        offload_vae: bool = False,
        offload_text: bool = False,
    ) -> OscarWorldModel:
        """Assemble from an OscarTransformer3DModel and a WanVAE (moved to device/dtype).

        dtype None: bfloat16 on CUDA (the fast default), else the modules' own dtype.
        Memory options (GPU): ``dtype=torch.bfloat16``; ``offload_vae`` keeps the
        VAE on the CPU between encode/decode calls; ``offload_text`` keeps the
        DiT's text projection (100352 → 1024, ~103 M parameters in the 2B) on
        the CPU — samplers project the prompt once per chunk there, so calls
        to the transformer must then pass ``text_projected=True``.
        """
        if dtype is None and torch.device(device).type == "cuda":
            dtype = torch.bfloat16
        cast_model(transformer, device, dtype)
        if offload_text and transformer.config.use_crossattn_projection:
            transformer.crossattn_proj.to("cpu")
        transformer.eval()
        vae_dtype = vae_dtype or dtype or torch.float32
        model = cls(
            transformer, VideoVAE(vae, device=device, dtype=vae_dtype, offload=offload_vae), card or ModelCard(), None
        )
        if empty_prompt is not None:
            model.empty_prompt = check_prompt_embeds(empty_prompt, transformer.text_dim, "empty prompt embedding")
        return model

    @classmethod
    def from_pretrained(
        cls,
        folder,
        *,
        device="cpu",
        dtype: torch.dtype | None = None,
        vae_dtype: torch.dtype | None = None,
        offload_vae: bool = False,
        offload_text: bool = False,
        verify: bool = True,
        tiny_decoder=None,
        tiny_encoder=None,
    ) -> OscarWorldModel:
        """Load a folder written by :meth:`save_pretrained` (safetensors only, keys matched strictly).

        verify: check every file against ``oscar_manifest.json`` (sha256) and
        the structure of every safetensors file before loading.
        tiny_decoder: a safetensors file of tiny-decoder weights (``taew2_1``'s
        key names, :mod:`.tiny_decoder`) that then decodes instead of the full
        VAE decoder; None (the default): the card's ``tiny_decoder`` (a file
        in the folder) if it names one, else the full decoder; False: the
        full decoder whatever the card says. Checked before the model's
        weights are read.
        tiny_encoder: a safetensors file of tiny-encoder weights (``taew2_1``'s
        ``encoder.*`` key names, :mod:`.tiny_encoder`) that then encodes the
        condition videos instead of the full VAE encoder (the seed frame stays
        with the full encoder); None or False (the default): the full encoder.
        Checked before the model's weights are read.
        """
        from .._util.devices import check_device

        check_device(device, ModelInputError)  # before reading anything: safetensors would fail with a traceback
        folder = Path(folder)
        card = read_card(folder)
        tiny = None
        if tiny_decoder is None and card.tiny_decoder is not None:
            tiny_decoder = folder / card.tiny_decoder
        if tiny_decoder is not None and tiny_decoder is not False:
            from .tiny_decoder import load_tiny_decoder

            tiny = load_tiny_decoder(tiny_decoder)
        condition_encoder = None
        if tiny_encoder is not None and tiny_encoder is not False:
            from .tiny_encoder import load_tiny_encoder

            condition_encoder = load_tiny_encoder(tiny_encoder)
        if verify:
            manifest = read_manifest(folder)
            if manifest is not None:
                verify_files(folder, {p: m.get("sha256") for p, m in manifest.items()}, source=folder)
        transformer_cls = OscarTransformer3DModel
        if takes_actions(card.condition):
            from .latent_action import LatentActionTransformer

            transformer_cls = LatentActionTransformer
        # on a GPU the weights are read straight onto it (no host copy); the VAE too unless it is offloaded
        gpu = torch.device(device).type == "cuda"
        transformer = transformer_cls.load_strict(folder / "transformer", device=device if gpu else None)
        vae = load_vae_folder(folder / "vae", device=device if gpu and not offload_vae else "cpu")
        empty = None
        if (folder / EMPTY_PROMPT_FILE).is_file():
            check_safetensors(folder / EMPTY_PROMPT_FILE)
            tensors = load_file(str(folder / EMPTY_PROMPT_FILE))
            if "prompt_embeds" not in tensors:
                raise CheckpointLayoutError(folder / EMPTY_PROMPT_FILE, "tensors", "'prompt_embeds'", sorted(tensors))
            empty = tensors["prompt_embeds"]
        model = cls.from_modules(
            transformer,
            vae,
            card,
            empty,
            device=device,
            dtype=dtype,
            vae_dtype=vae_dtype,
            offload_vae=offload_vae,
            offload_text=offload_text,
        )
        if tiny is not None:
            model.vae.use_tiny_decoder(tiny)
        if condition_encoder is not None:
            model.vae.use_tiny_encoder(condition_encoder)
        if (folder / SCHEDULER_FILE).is_file():
            try:
                model.scheduler_config = json.loads((folder / SCHEDULER_FILE).read_text())
            except ValueError as exc:
                raise CheckpointLayoutError(
                    folder / SCHEDULER_FILE, "JSON", "a JSON object", f"unreadable JSON ({exc})"
                ) from None
        return model

    @classmethod
    def from_cosmos_base(
        cls,
        folder,
        card: ModelCard | None = None,
        *,
        skeleton_channels: int | None = None,
        device="cpu",
        dtype: torch.dtype | None = None,
        vae_dtype: torch.dtype | None = None,
        offload_vae: bool = False,
        offload_text: bool = False,
    ) -> OscarWorldModel:
        """Start from a Cosmos-Predict2.5 diffusers folder (``transformer/`` + ``vae/``): base + zero PE_s."""
        folder = Path(folder)
        transformer = OscarTransformer3DModel.from_cosmos_base(folder / "transformer", skeleton_channels)
        vae = load_vae_folder(folder / "vae")
        return cls.from_modules(
            transformer,
            vae,
            card,
            None,
            device=device,
            dtype=dtype,
            vae_dtype=vae_dtype,
            offload_vae=offload_vae,
            offload_text=offload_text,
        )

    # ------------------------------------------------------------------ export
    def save_pretrained(self, folder, card: ModelCard | None = None, max_shard_size: str | int = "10GB") -> Path:
        """Write the folder layout of the module docstring (safetensors) and its sha256 manifest."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        card = card or self.card
        self.transformer.save_pretrained(folder / "transformer", safe_serialization=True, max_shard_size=max_shard_size)
        self.vae.vae.save_pretrained(folder / "vae", safe_serialization=True, max_shard_size=max_shard_size)
        if self.scheduler_config is not None:
            (folder / "scheduler").mkdir(exist_ok=True)
            (folder / SCHEDULER_FILE).write_text(json.dumps(self.scheduler_config, indent=2) + "\n")
        if self.empty_prompt is not None:
            (folder / "text").mkdir(exist_ok=True)
            save_file({"prompt_embeds": self.empty_prompt.detach().cpu().contiguous()}, str(folder / EMPTY_PROMPT_FILE))
        if card.tiny_decoder is not None:
            if self.vae.tiny is None:
                raise ModelInputError(
                    f"model card tiny_decoder: names {card.tiny_decoder}, but this model decodes with the full "
                    "decoder (load one with vae.use_tiny_decoder, or save with a card without tiny_decoder)"
                )
            from .tiny_decoder import save_tiny_decoder

            save_tiny_decoder(self.vae.tiny.net, folder / card.tiny_decoder)
        (folder / MODEL_FILE).write_text(
            json.dumps({"format": FORMAT, "format_version": 1, "card": card.to_dict()}, indent=2) + "\n"
        )
        write_manifest(folder)
        if not (folder / "README.md").exists():
            # a model card with the Hub's metadata block (model/hub_card.py); documentation, outside the manifest
            # like oscar-toy's README
            from .hub_card import default_model_card

            (folder / "README.md").write_text(default_model_card(card.to_dict()))
        return folder

    # ------------------------------------------------------------------ use
    @property
    def device(self) -> torch.device:
        return next(self.transformer.parameters()).device

    def prompt_embeds(self, prompt_embeds: torch.Tensor | None = None) -> torch.Tensor:
        """(1, L, D) embedding to condition on (see :meth:`resolve_prompt`, which also says where it came from)."""
        return self.resolve_prompt(prompt_embeds)[0]

    def resolve_prompt(self, prompt_embeds: torch.Tensor | None = None, cache_dir=None) -> tuple[torch.Tensor, str]:
        """(embedding (1, L, D), where it came from).

        The given one; else the encoder's embedding of the empty prompt: the
        one the checkpoint ships (``text/empty_prompt_embeds.safetensors``),
        else the one in the prompt cache under the card's ``text_encoder_id``
        (``oscar encode-prompt ""`` puts it there). Only when neither exists
        does it fall back to zeros, and it warns: the model never saw a zero
        embedding.
        """
        dim = self.transformer.text_dim
        if prompt_embeds is not None:
            return check_prompt_embeds(prompt_embeds, dim), "given prompt embedding"
        if self.empty_prompt is not None:
            return self.empty_prompt, "empty-prompt embedding stored in the checkpoint"
        if self.card.text_encoder_id:
            from .text import PromptEmbeddingCache

            cache = PromptEmbeddingCache(cache_dir, encoder_id=self.card.text_encoder_id)
            found = cache.get("")
            if found is not None:
                return check_prompt_embeds(
                    found.float(), dim, str(cache.path(""))
                ), f"empty-prompt embedding from the prompt cache ({cache.path('')})"
        import warnings

        warnings.warn(
            "no prompt embedding and no empty-prompt embedding (none in the checkpoint, none cached for "
            f"encoder {self.card.text_encoder_id!r}): using a ZERO text embedding, which the model never "
            'saw in training; run `oscar encode-prompt "" --model NAME` once',
            stacklevel=3,
        )
        return empty_prompt_embeds(dim), "ZERO text embedding (no empty-prompt embedding available)"

    def recommended_sampler(self, **given) -> SamplerConfig:
        """The sampler of a rollout given no ``sampler``: :func:`~oscar_core.model.card_sampler.resolve_sampler` of the
        card's recommended settings (``card.sampler``) under ``given`` options, logged at INFO with where each
        setting came from."""
        choice = resolve_sampler(self.card.sampler, **given)
        _log.info("sampler of %s: %s", self.card.name or "the model", choice.describe("argument"))
        return choice.config

    def sampler_for(self, sampler: SamplerConfig) -> SamplerConfig:
        """``sampler`` with the checkpoint's choices filled in: solver (and UniPC config) from its scheduler
        (:func:`~oscar_core.model.card_sampler.sampler_with_scheduler`)."""
        return sampler_with_scheduler(sampler, self.scheduler_config)

    def set_compile(self, mode: str = "auto", *, cells: int = 1) -> OscarWorldModel:
        """Set :attr:`compile_mode` and :attr:`compile_cells` (rollouts of this size the job runs); returns self."""
        from .compile_policy import check_compile_mode

        check_compile_mode(mode)
        if isinstance(cells, bool) or not isinstance(cells, int) or cells < 1:
            raise ModelInputError(f"compile cells: expected an integer >= 1, found {cells!r}")
        self.compile_mode, self.compile_cells = mode, cells
        return self

    def _prepare_compile(self, frames: int, chunk: int, sampler: SamplerConfig) -> None:
        """Compile the DiT before a rollout of ``frames`` frames when the compile policy says so (once per process)."""
        from .compile_policy import compile_decision, compile_transformer, is_compiled
        from .rollout import chunk_plan
        from .sampler import model_calls

        if self.compile_mode == "never":
            self.compile_reason = "compile=never"
            return
        if is_compiled(self.transformer):
            self.compile_reason = "compiled earlier in this process (reused)"
            return
        if self.vae is None:  # no VAE, no rollout to weigh (the rollout itself reports it)
            return
        try:
            chunks = len(chunk_plan(int(frames), chunk, self.vae.temporal, self.card.context_frames))
        except (ModelInputError, TypeError, ValueError):
            return  # the rollout itself reports the bad input
        ok, why = compile_decision(
            self.compile_mode, self.device, chunks * self.compile_cells, sampler.steps, model_calls(sampler)
        )
        if why != self.compile_reason:  # said once per job: every cell of `oscar eval run` weighs the same
            _log.info("%s", why)
        self.compile_reason = why
        if ok and not compile_transformer(self.transformer):
            self.compile_reason = f"{why}; compiling failed, eager"

    def enable_vae_tiling(self, **kwargs) -> None:
        self.vae.enable_tiling(**kwargs)

    def enable_vae_slicing(self) -> None:
        self.vae.enable_slicing()

    def rollout(
        self,
        first_frame,
        skeleton,
        prompt_embeds: torch.Tensor | None = None,
        *,
        chunk_frames: int | None = None,
        sampler: SamplerConfig | None = None,
        seed: int = 0,
        progress: bool = True,
        keep_chunks: bool = True,
        actions=None,
        gripper=None,
    ):
        """Autoregressive rollout (see :func:`oscar_core.model.rollout.rollout`); chunk length from the card by default.

        A latent-action model takes ``actions`` (T − 1, 14) (``latent_actions``
        of the trajectory) and ``skeleton=None``; :meth:`rollout_trajectory`
        builds either input from a trajectory. A model whose card has ``gripper_signal`` also takes ``gripper``
        (T, G) openness per condition frame (``rollout_inputs`` gives it).
        """
        from .rollout import rollout

        sampler = self.recommended_sampler() if sampler is None else sampler
        chunk = int(chunk_frames or self.card.chunk_frames)
        actions, num_frames = self._rollout_actions(skeleton, actions, chunk)
        check_gripper_given(self.card, gripper is not None)
        self._prepare_compile(num_frames if skeleton is None else len(skeleton), chunk, sampler)
        if self.card.width and self.card.height:
            h, w = first_frame.shape[:2]
            if (w, h) != (self.card.width, self.card.height):
                import warnings

                warnings.warn(
                    f"model {self.card.name or ''} was trained at {self.card.width}x{self.card.height}; "
                    f"rolling out at {w}x{h}",
                    stacklevel=2,
                )
        return rollout(
            self.transformer,
            self.vae,
            first_frame,
            skeleton,
            self.prompt_embeds(prompt_embeds),
            chunk_frames=chunk,
            sampler=self.sampler_for(sampler),
            seed=seed,
            progress=progress,
            keep_chunks=keep_chunks,
            uncond_skeleton=self.card.unconditional_skeleton,
            actions=actions,
            num_frames=num_frames,
            gripper=gripper,
            context_frames=self.card.context_frames,
        )

    def rollout_batch(
        self,
        first_frames,
        skeletons,
        prompt_embeds=None,
        *,
        chunk_frames: int | None = None,
        sampler: SamplerConfig | None = None,
        seeds=None,
        progress: bool = False,
        grippers=None,
    ) -> list:
        """B rollouts in one batch (see :func:`oscar_core.model.rollout.rollout_batch`): B (T, H, W, 3) uint8 videos,
        each equal to :meth:`rollout` of its own inputs and seed up to float rounding.

        prompt_embeds: None (the card's empty prompt for all), one (1, L, D) tensor, or a list of B (1, L, D) /
        None; condition videos of one length and size; grippers: B (T, G) openness arrays for a model with a
        gripper signal, else None. Skeleton- and mesh-conditioned models only.
        """
        from .rollout import rollout_batch

        sampler = self.recommended_sampler() if sampler is None else sampler
        if takes_actions(self.card.condition):
            raise ModelInputError("rollout_batch: latent-action models roll out one at a time (rollout)")
        check_gripper_given(self.card, grippers is not None)
        if isinstance(prompt_embeds, (list, tuple)):
            embeds = [self.prompt_embeds(e) for e in prompt_embeds]
            if len({tuple(e.shape) for e in embeds}) != 1:
                raise ModelInputError(
                    f"prompt_embeds: expected one shape for the batch, found {sorted({tuple(e.shape) for e in embeds})}"
                )
            prompt = torch.cat(embeds)
        else:
            prompt = self.prompt_embeds(prompt_embeds)
        chunk = int(chunk_frames or self.card.chunk_frames)
        if len(skeletons):
            self._prepare_compile(len(skeletons[0]), chunk, sampler)
        return rollout_batch(
            self.transformer,
            self.vae,
            first_frames,
            skeletons,
            prompt,
            chunk_frames=int(chunk_frames or self.card.chunk_frames),
            sampler=self.sampler_for(sampler),
            seeds=seeds,
            progress=progress,
            uncond_skeleton=self.card.unconditional_skeleton,
            grippers=grippers,
            context_frames=self.card.context_frames,
        )

    def iter_rollout(
        self,
        first_frame,
        skeleton,
        prompt_embeds: torch.Tensor | None = None,
        *,
        chunk_frames: int | None = None,
        sampler: SamplerConfig | None = None,
        seed: int = 0,
        progress: bool = True,
        result=None,
        actions=None,
        gripper=None,
    ):
        """Stream a rollout: yields each chunk's new uint8 frames (see :func:`oscar_core.model.rollout.iter_rollout`)."""
        from .rollout import iter_rollout

        sampler = self.recommended_sampler() if sampler is None else sampler
        chunk = int(chunk_frames or self.card.chunk_frames)
        actions, num_frames = self._rollout_actions(skeleton, actions, chunk)
        check_gripper_given(self.card, gripper is not None)
        self._prepare_compile(num_frames if skeleton is None else len(skeleton), chunk, sampler)
        return iter_rollout(
            self.transformer,
            self.vae,
            first_frame,
            skeleton,
            self.prompt_embeds(prompt_embeds),
            chunk_frames=chunk,
            sampler=self.sampler_for(sampler),
            seed=seed,
            progress=progress,
            uncond_skeleton=self.card.unconditional_skeleton,
            result=result,
            actions=actions,
            num_frames=num_frames,
            gripper=gripper,
            context_frames=self.card.context_frames,
        )

    def _rollout_actions(self, skeleton, actions, chunk: int):
        """(actions padded to the chunk plan or None, frame count or None); checks the input fits the card."""
        return action_plan(self.card, self.transformer, self.vae, skeleton, actions, chunk)

    def rollout_inputs(
        self,
        trajectory,
        camera,
        embodiment,
        size: tuple[int, int] | None = None,
        *,
        resize_mode: str = "crop",
        camera_source: str = "<camera>",
    ) -> dict:
        """What this model's rollout is conditioned on, from a trajectory (:func:`.rollout_conditions.condition_inputs`
        for this model's card): ``{"skeleton": ...}`` or ``{"actions": ...}``, plus ``gripper`` for a card with a
        gripper signal — every key is a keyword of :meth:`rollout` but ``skeleton``, its second argument."""
        return condition_inputs(
            self.card, trajectory, camera, embodiment, size, resize_mode=resize_mode, camera_source=camera_source
        )

    def rollout_trajectory(
        self,
        first_frame,
        trajectory,
        camera,
        embodiment,
        prompt_embeds: torch.Tensor | None = None,
        *,
        size: tuple[int, int] | None = None,
        resize_mode: str = "crop",
        **options,
    ):
        """Roll out along a trajectory, whatever the card's condition: skeleton rendered, or latent actions.

        first_frame: (H, W, 3) uint8 already at the rollout size; trajectory,
        camera, embodiment: as :func:`oscar_core.render.skeleton_video.render_skeleton_video`
        takes them; size: (width, height) of the skeleton video (default: the
        first frame's). ``options``: :meth:`rollout`'s. Returns a RolloutResult.
        """
        h, w = np.asarray(first_frame).shape[:2]
        inputs = self.rollout_inputs(trajectory, camera, embodiment, size or (w, h), resize_mode=resize_mode)
        extra = {k: v for k, v in inputs.items() if k != "skeleton" and v is not None}
        return self.rollout(first_frame, inputs["skeleton"], prompt_embeds, **extra, **options)
