"""Build the networks a config names: the DiT (skeleton / latent-action / text-only) and the VAE."""

from __future__ import annotations

import json
from pathlib import Path

import torch

from ..render.conditions import is_video_condition, takes_actions
from .config import TrainConfig, TrainConfigError

__all__ = ["build_transformer", "build_vae", "transformer_config", "prepare_for_training", "VAE_TEMPORAL"]

#: The temporal compression of every VAE the trainer builds (WAN 2.1 and the toy VAE: 4 frames per latent frame
#: after the first); the gripper signal's channel count depends on it, and the data loader checks it.
VAE_TEMPORAL = 4


def transformer_config(spec, source: str = "<config>") -> dict:
    """OscarTransformer3DModel arguments from ``model.transformer`` ("tiny", "cosmos-2b", a path or a dict)."""
    from ..model.tiny import COSMOS_2B_TRANSFORMER_CONFIG, TINY_TRANSFORMER_CONFIG

    if isinstance(spec, dict):
        return dict(spec)
    if spec == "tiny":
        return dict(TINY_TRANSFORMER_CONFIG)
    if spec == "cosmos-2b":
        return dict(COSMOS_2B_TRANSFORMER_CONFIG)
    path = Path(str(spec))
    if path.is_dir():
        path = path / "config.json"
    if not path.is_file():
        raise TrainConfigError(
            source, "model.transformer", "'tiny', 'cosmos-2b', a config.json (or its folder) or a mapping", repr(spec)
        )
    data = json.loads(path.read_text())
    return {k: v for k, v in data.items() if not k.startswith("_") and k not in ("action_frames", "action_dim")}


def build_transformer(config: TrainConfig, source: str = "<config>"):
    """The DiT to train, its weights initialised as ``model.init`` says (float32, train mode)."""
    from ..model.latent_action import LatentActionTransformer
    from ..model.tiny import randomise
    from ..model.transformer import OscarTransformer3DModel

    m = config.model
    args = transformer_config(m.transformer, source)
    cls = OscarTransformer3DModel
    if takes_actions(config.condition):
        cls = LatentActionTransformer
        args.update(action_frames=config.data.window - 1, action_dim=14)
    if m.gripper_signal:
        from ..model.gripper_signal import gripper_channels

        latent = int(args.get("out_channels", 16))
        args["skeleton_channels"] = latent + gripper_channels(VAE_TEMPORAL)
    init = m.init
    if init is None:
        torch.manual_seed(m.seed)  # diffusers' default init draws from the global generator
        model = cls(**args)
        if m.transformer == "tiny":
            # the tiny preset's weights, as oscar_core.model.tiny draws them (diffusers zero-inits some layers)
            randomise(model, m.seed, 0.05)
        if m.condition_init == "zero":
            with torch.no_grad():
                model.skeleton_embed.proj.weight.zero_()
                if cls is LatentActionTransformer:
                    for mlp in (model.action_embed_d, model.action_embed_3d):
                        mlp[2].weight.zero_()
                        mlp[2].bias.zero_()
        else:  # "default": the condition layers draw nn.Linear's own init, seeded after the rest of the model
            torch.manual_seed(m.seed + 1)
            if is_video_condition(config.condition):
                model.skeleton_embed.proj.reset_parameters()
            else:  # PE_s stays zero (and frozen, below) in a model that never sees a skeleton
                with torch.no_grad():
                    model.skeleton_embed.proj.weight.zero_()
            if cls is LatentActionTransformer:
                for mlp in (model.action_embed_d, model.action_embed_3d):
                    mlp[2].reset_parameters()
    else:
        base = _base_weights(init, source)
        torch.manual_seed(m.seed)
        model = cls(**args)
        base = _widen_time_positions(_widen_condition_embedder(base, model), model)
        missing, unexpected = model.load_state_dict(base, strict=False)
        allowed = {"skeleton_embed.proj.weight"} | {k for k in model.state_dict() if k.startswith("action_embed")}
        bad_missing = [k for k in missing if k not in allowed]
        if bad_missing or unexpected:
            raise TrainConfigError(
                source,
                "model.init",
                f"weights matching the transformer config ({init})",
                f"missing {bad_missing[:5]}, unexpected {list(unexpected)[:5]}",
            )
        # the keys the base lacks (PE_s, the action MLPs) keep their constructor init: zero outputs
    if not is_video_condition(config.condition):
        # PE_s is unused without a skeleton: frozen, it stays zero and DDP does not wait for its gradient
        model.skeleton_embed.requires_grad_(False)
    model.train()
    return model


def prepare_for_training(
    model, config: TrainConfig, device, shards: int = 1, compression: tuple[int, int] = (4, 8)
) -> tuple[str, str]:
    """Apply the config's activation checkpointing (:func:`.memory.choose_checkpointing`) and ``model.compile``
    (``torch.compile`` of every transformer block, in place: parameter names and checkpoints stay the same) to a
    built transformer, before it moves to ``device``; returns (checkpointing chosen, why). compression: the VAE's
    (temporal, spatial) compression, which sets the tokens per clip the memory model counts."""
    from .memory import choose_checkpointing

    policy, why = choose_checkpointing(config, model, device, shards, compression)
    if policy == "full":
        model.enable_gradient_checkpointing()
    elif model.gradient_checkpointing:
        model.disable_gradient_checkpointing()
    if config.model.compile:
        for block in model.transformer_blocks:
            block.compile(dynamic=False)
    return policy, why


def _widen_condition_embedder(base: dict, model) -> dict:
    """A base without the gripper signal's channels, fine-tuned with them: PE_s's weight gets zero columns for the
    new input channels (channel-major: CosmosPatchEmbed flattens (C, p_t, p_h, p_w)), so at step 0 the model is
    the base model whatever the gripper does. Other shapes are left to the strict check."""
    key = "skeleton_embed.proj.weight"
    old, new = base.get(key), model.state_dict().get(key)
    if old is None or new is None or old.shape == new.shape:
        return base
    if old.shape[0] != new.shape[0] or old.shape[1] > new.shape[1]:
        return base
    pad = old.new_zeros(old.shape[0], new.shape[1] - old.shape[1])
    return {**base, key: torch.cat([old, pad], dim=1)}


def _widen_time_positions(base: dict, model) -> dict:
    """A base with fewer learnt time positions than the model's (``max_size[0]`` raised to fine-tune on longer
    windows): the new rows of ``pos_emb_t`` repeat the base's last row, so a latent frame past the base's last
    starts where that frame's position was. Other shapes are left to the strict check."""
    key = "learnable_pos_embed.pos_emb_t"
    old, new = base.get(key), model.state_dict().get(key)
    if old is None or new is None or old.shape == new.shape:
        return base
    if old.ndim != 2 or old.shape[1] != new.shape[1] or old.shape[0] > new.shape[0]:
        return base
    return {**base, key: torch.cat([old, old[-1:].expand(new.shape[0] - old.shape[0], -1)], dim=0)}


def _base_weights(init: str, source: str) -> dict:
    """State dict named by ``model.init``: ``cosmos_base:FOLDER``, an OSCAR model folder or a transformer folder."""
    from ..model.weights import load_state_dict

    if init.startswith("cosmos_base:"):
        folder = Path(init.split(":", 1)[1])
    else:
        folder = Path(init)
        if (folder / "transformer").is_dir():
            folder = folder / "transformer"
    if not folder.is_dir():
        raise TrainConfigError(
            source, "model.init", "a folder of transformer weights (safetensors)", f"{folder} (missing)"
        )
    return load_state_dict(folder)


def build_vae(config: TrainConfig, device="cpu", source: str = "<config>"):
    """The ``VideoVAE`` a config names ("tiny", an AutoencoderKLWan folder, or an OSCAR model folder's vae/)."""
    from ..model.tiny import build_tiny_vae
    from ..model.vae import VideoVAE

    spec = config.model.vae
    if spec == "tiny":
        return VideoVAE(build_tiny_vae(config.model.seed), device=device)
    from ..model.vae import load_vae_folder

    folder = Path(spec)
    if (folder / "vae").is_dir():
        folder = folder / "vae"
    if not (folder / "config.json").is_file():
        raise TrainConfigError(
            source,
            "model.vae",
            "'tiny', an AutoencoderKLWan folder or an OSCAR model folder",
            f"{spec} (no config.json)",
        )
    return VideoVAE(load_vae_folder(folder), device=device)
