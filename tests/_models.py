"""Tiny world models and training configs the tests share: seeded random weights, small enough for one CPU thread.

Every builder is deterministic: the same arguments give bitwise the same weights, so a module-scoped fixture and a
test that builds its own model agree.
"""

from pathlib import Path

import torch

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


def long_clipset(folder: Path) -> Path:
    """Two 21-frame clips at 32x32 with seeded latents of every 9-frame window (starts 0..12): windows 8 frames
    apart, what a self-forced item needs (:mod:`oscar_core.train.self_forcing`); returns its folder."""
    return write_toy_clipset(folder, clips=2, frames=21, width=32, height=32, latents_vae="random", latents_window=9)


class ClosedFormDiT(torch.nn.Module):
    """A DiT with a velocity known in closed form, v = λ x + β S + γ x[:, :, :1] + δ t (S the condition latent, t the
    timestep): a sampler's result can be written by hand. Its text projection is the identity."""

    dtype = torch.float32

    def __init__(self, lam=0.3, beta=0.7, gamma=0.4, delta=0.2):
        super().__init__()
        self.anchor = torch.nn.Parameter(torch.zeros(()))  # where the sampler looks for the device
        self.lam, self.beta, self.gamma, self.delta = lam, beta, gamma, delta

    def project_text(self, text):
        return text

    def forward(self, hidden_states, timestep, encoder_hidden_states, condition_mask, padding_mask, **kw):
        x, s = hidden_states, kw["skeleton_latents"]
        return (self.lam * x + self.beta * s + self.gamma * x[:, :, :1] + self.delta * timestep,)

    def euler_by_hand(self, first, skel, noise, steps, *, uncond=None, w=0.0, shift=5.0):
        """The chunk (B, C, T, h, w) the Euler sampler makes from ``first`` (B, C, 1, h, w) with this field, written
        out: the grid flow_sigmas(steps, shift), frame 0 clean at timestep 1e-4, the velocity guided in the diffusers
        form v_c + w (v_c − v_u), v_u the field on ``uncond`` (w = 0: the conditional branch alone)."""
        from oscar_core.model.sampler import flow_sigmas

        x = noise.double().clone()
        x[:, :, :1] = first.double()
        sig = flow_sigmas(steps, shift).tolist()
        for s_now, s_next in zip(sig[:-1], sig[1:]):
            t = torch.full_like(x[:, :1], s_now)
            t[:, :, :1] = 1e-4
            base = self.lam * x + self.gamma * x[:, :, :1] + self.delta * t
            v = base + self.beta * skel.double()
            if w:
                v = v + w * (v - (base + self.beta * uncond.double()))
            x[:, :, 1:] += (s_next - s_now) * v[:, :, 1:]
        return x.float()


def metrics_rows(run_dir) -> list[dict]:
    """The records of a run's ``metrics.jsonl``."""
    import json

    return [json.loads(line) for line in (Path(run_dir) / "metrics.jsonl").read_text().splitlines()]


def assert_resumes_bitwise(make_config, tmp_path: Path) -> Path:
    """Trains ``make_config(run_dir)`` (a :class:`TrainConfig` of at least 3 steps) whole in ``tmp_path/straight`` and
    again in ``tmp_path/split``, stopped after step 2 and resumed; asserts that their model and EMA weights are equal
    bit for bit. Returns the straight run's folder."""
    from oscar_core.train.config import config_to_dict
    from oscar_core.train.loop import train

    straight = make_config(tmp_path / "straight")
    train(straight, progress=False)
    split = config_from_dict(config_to_dict(make_config(tmp_path / "split")))
    assert train(split, progress=False, stop_after=2).step == 2
    train(resume=split.run_dir, progress=False)
    for key in ("model", "ema"):
        a, b = trained_weights(straight.run_dir, key), trained_weights(split.run_dir, key)
        assert all(torch.equal(a[k], b[k]) for k in a), key
    return Path(straight.run_dir)


def trained_one_and_two_ways(make_config, tmp_path: Path) -> Path:
    """Trains ``make_config(run_dir, parallel)`` (a self-forced :class:`TrainConfig`, batch 4) in this process in
    ``tmp_path/one`` and on 2 gloo processes under DDP and FSDP2 in ``tmp_path/ddp`` and ``tmp_path/fsdp``, the two
    in one torchrun launch (tests/_torchrun.py). First asserts that the plan holds the case that needs care under
    FSDP2: a micro-step in which one process has items to self-force and the other none. Returns ``tmp_path``."""
    import yaml
    from _torchrun import train_under_torchrun

    from oscar_core.train.config import config_to_dict
    from oscar_core.train.data import TrainData
    from oscar_core.train.loop import train
    from oscar_core.train.models import build_vae
    from oscar_core.train.sampling import StepPlanner

    one = make_config(tmp_path / "one", "none")
    data = TrainData(one, build_vae(one), text_dim=48)
    back = one.data.window - 1
    has = [
        [data.has_window(it.clip, it.start - back) for it in StepPlanner.rank_slice(data.planner().plan(s, 4), r, 2)]
        for s in range(one.steps)
        for r in range(2)
    ]
    assert any(any(a) != any(b) for a, b in zip(has[0::2], has[1::2])), has
    train(one, progress=False)
    paths = []
    for mode in ("ddp", "fsdp"):
        paths.append(tmp_path / f"{mode}.yaml")
        paths[-1].write_text(yaml.safe_dump(config_to_dict(make_config(tmp_path / mode, mode))))
    out = train_under_torchrun(paths)
    assert out.returncode == 0, out.stderr[-3000:]
    return tmp_path
