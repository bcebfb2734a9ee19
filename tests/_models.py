"""Tiny world models and training configs the tests share: seeded random weights, small enough for one CPU thread.

Every builder is deterministic: the same arguments give bitwise the same weights, so a module-scoped fixture and a
test that builds its own model agree.
"""

from pathlib import Path

from oscar_core.model import ModelCard, OscarWorldModel
from oscar_core.train.checkpoint import latest_checkpoint, load_weights
from oscar_core.train.config import TrainConfig, config_from_dict, load_config
from oscar_core.train.models import build_transformer
from oscar_core.train.synthetic import write_toy_clipset


def tiny_world_model(
    *, seed: int = 0, skeleton_scale: float | None = None, empty_prompt=None, **card
) -> OscarWorldModel:
    """A world model of the tiny transformer and VAE (``oscar_core.model.tiny``), both seeded with ``seed``;
    ``skeleton_scale``: the skeleton embedder's weight scale (None: zero, the video ignores the skeleton); ``card``:
    the ``ModelCard`` fields; ``empty_prompt``: the cached empty-prompt embedding ``(1, L, 48)``, or None."""
    from oscar_core.model.tiny import build_tiny_transformer, build_tiny_vae

    extra = {} if empty_prompt is None else {"empty_prompt": empty_prompt}
    return OscarWorldModel.from_modules(
        build_tiny_transformer(seed=seed, skeleton_scale=skeleton_scale),
        build_tiny_vae(seed=seed),
        ModelCard(**card),
        **extra,
    )


def export_tiny_world_model(folder: Path, **kwargs) -> Path:
    """``tiny_world_model(**kwargs)`` exported in the oscar layout to ``folder``; returns the folder."""
    import oscar_zoo

    return oscar_zoo.export(tiny_world_model(**kwargs), folder)


def tiny_clipset(folder: Path, clips: int = 3) -> Path:
    """A toy clip set that fits :func:`tiny_train_config`: ``clips`` clips of 13 frames at 32x32 with cached latents
    (a seeded random VAE, 9-frame windows) and 48-dim prompt embeddings; returns its folder."""
    return write_toy_clipset(
        folder, clips=clips, frames=13, width=32, height=32, latents_vae="random", latents_window=9, prompt_dim=48
    )


def tiny_train_config(clips, run_dir, **over) -> TrainConfig:
    """The tiny training config (CPU, 32x32, 9-frame windows, 4 steps) on ``clips`` writing to ``run_dir``; ``over``
    sets dotted keys (``"optim.lr": 1e-2``)."""
    d = {
        "run_dir": str(run_dir),
        "steps": 4,
        "batch_size": 2,
        "micro_batch": 1,
        "save_every": 2,
        "log_every": 1,
        "export": False,
        "model": {"transformer": "tiny", "vae": "tiny"},
        "data": {"clips": [str(clips)], "window": 9, "width": 32, "height": 32},
        "optim": {"lr": 1e-3, "warmup_steps": 2, "grad_clip": 1.0, "ema_decay": 0.9},
    }
    for k, v in over.items():
        node = d
        *parents, last = k.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[last] = v
    return config_from_dict(d)


def trained_weights(run_dir, key="model") -> dict:
    """The state dict of the latest checkpoint of ``run_dir`` (``key``: "model" or "ema")."""
    model = build_transformer(load_config(Path(run_dir) / "config.yaml"))
    return load_weights(latest_checkpoint(run_dir), model, key=key).state_dict()
