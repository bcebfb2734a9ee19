"""The loop on CPU with the tiny config: it learns, resumes bitwise, exports a loadable model, rejects bad input."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from _models import tiny_clipset, tiny_train_config, trained_weights
from _paths import REPO

from oscar_core.model.errors import CheckpointIntegrityError
from oscar_core.train.checkpoint import latest_checkpoint, list_checkpoints, load_weights, verify_checkpoint
from oscar_core.train.clips import ClipFormatError, ClipSet
from oscar_core.train.config import TrainConfigError, load_config
from oscar_core.train.data import TrainData
from oscar_core.train.loop import step_loss, train
from oscar_core.train.models import build_transformer, build_vae
from oscar_core.train.synthetic import write_toy_clipset

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def clipset(tmp_path_factory):
    root = tmp_path_factory.mktemp("clips") / "toy"
    return tiny_clipset(root, clips=3)


# ---------------------------------------------------------------------- learning
@pytest.mark.slow
def test_tiny_config_overfits_one_clip(tmp_path):
    clips = write_toy_clipset(
        tmp_path / "one", clips=1, frames=9, width=32, height=32, latents_vae="random", latents_window=9
    )
    cfg = tiny_train_config(
        clips,
        tmp_path / "run",
        steps=150,
        batch_size=1,
        save_every=150,
        log_every=50,
        **{"data.skeleton_dropout": 0.0, "optim.lr": 3e-3, "optim.warmup_steps": 5},
    )
    data = TrainData(cfg, None, 48)
    eval_items = data.planner().plan(10_000, 16)  # a fixed evaluation batch: 16 (sigma, noise) draws

    def eval_loss(model):
        with torch.no_grad():
            return float(step_loss(model.eval(), data.batch(eval_items, "skeleton"), eval_items, cfg, "cpu"))

    before = eval_loss(build_transformer(cfg))
    train(cfg, progress=False)
    after = eval_loss(load_weights(latest_checkpoint(cfg.run_dir), build_transformer(cfg), key="model"))
    assert after < before / 2.5, (before, after)  # measured here: 2.13 -> 0.41 (x5.2)
    rows = [json.loads(l) for l in (Path(cfg.run_dir) / "metrics.jsonl").read_text().splitlines()]
    assert rows[0]["event"] == "start" and rows[0]["latents"] == "cached"
    assert [r["step"] for r in rows[1:]] == [50, 100, 150]
    assert {"loss", "lr", "grad_norm", "steps_per_s"} <= set(rows[1])


@pytest.mark.slow
def test_exact_resume_is_bitwise(tmp_path, clipset):
    straight = tiny_train_config(clipset, tmp_path / "straight", steps=4)
    train(straight, progress=False)
    split = tiny_train_config(clipset, tmp_path / "split", steps=4)
    r = train(split, progress=False, stop_after=2)
    assert r.step == 2 and [p.name for p in list_checkpoints(split.run_dir)] == ["step-00000002"]
    train(resume=split.run_dir, progress=False)
    for key in ("model", "ema"):
        a, b = trained_weights(straight.run_dir, key), trained_weights(split.run_dir, key)
        assert all(torch.equal(a[k], b[k]) for k in a), key
    # the metrics of the resumed run continue the interrupted ones
    steps = [json.loads(l)["step"] for l in (Path(split.run_dir) / "metrics.jsonl").read_text().splitlines()]
    assert steps == [0, 1, 2, 3, 4]
    # so do the draws per source: the resumed part replays the plan of the steps it had done
    drawn = json.loads((Path(split.run_dir) / "sources.json").read_text())
    assert drawn == json.loads((Path(straight.run_dir) / "sources.json").read_text()) and drawn["draws"] == 8
    # and the test can fail: a different seed gives different weights
    other = tiny_train_config(clipset, tmp_path / "other", steps=4, seed=1)
    train(other, progress=False)
    assert not torch.equal(
        trained_weights(other.run_dir)["proj_out.weight"], trained_weights(straight.run_dir)["proj_out.weight"]
    )


def test_a_run_folder_is_not_silently_overwritten(tmp_path, clipset):
    cfg = tiny_train_config(clipset, tmp_path / "run", steps=2)
    train(cfg, progress=False)
    with pytest.raises(TrainConfigError, match="run_dir.*--resume"):
        train(cfg, progress=False)


def test_corrupted_checkpoint_is_refused_and_nothing_is_overwritten(tmp_path, clipset):
    cfg = tiny_train_config(clipset, tmp_path / "run", steps=2)
    train(cfg, progress=False)
    ckpt = latest_checkpoint(cfg.run_dir)
    shard = next(p for p in ckpt.iterdir() if p.suffix == ".distcp")
    raw = bytearray(shard.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    shard.write_bytes(bytes(raw))
    before = {p: p.read_bytes() for p in Path(cfg.run_dir).rglob("*") if p.is_file()}
    with pytest.raises(CheckpointIntegrityError, match=rf"{shard.name}.*sha256"):
        train(resume=cfg.run_dir, progress=False)
    after = {p: p.read_bytes() for p in Path(cfg.run_dir).rglob("*") if p.is_file()}
    assert before == after
    with pytest.raises(CheckpointIntegrityError):
        verify_checkpoint(ckpt)


# ---------------------------------------------------------------------- export
def test_export_is_a_zoo_loadable_model_with_ema_weights(tmp_path, clipset):
    import oscar_zoo

    cfg = tiny_train_config(
        clipset, tmp_path / "run", steps=2, export=True, **{"data.unconditional_skeleton": "black_video"}
    )
    result = train(cfg, progress=False)
    assert result.export == Path(cfg.run_dir) / "export"
    model = oscar_zoo.load(result.export)
    assert model.card.unconditional_skeleton == "black_video"
    assert (model.card.chunk_frames, model.card.width, model.card.height) == (9, 32, 32)
    assert model.card.embodiments == ("toyarm",)
    ema = trained_weights(cfg.run_dir, "ema")
    raw = trained_weights(cfg.run_dir, "model")
    got = model.transformer.state_dict()
    assert all(torch.equal(got[k], ema[k]) for k in ema)
    assert not all(torch.equal(got[k], raw[k]) for k in raw)  # EMA, not the raw weights
    # a rollout through the exported model runs (tiny sizes, 2 steps)
    from oscar_core.model.sampler import SamplerConfig

    out = model.rollout(
        np.zeros((32, 32, 3), np.uint8),
        np.zeros((9, 32, 32, 3), np.uint8),
        progress=False,
        sampler=SamplerConfig(steps=2, guidance=None),
    )
    assert out.frames.shape == (9, 32, 32, 3)
    assert model.empty_prompt is None  # the clips carried prompt embeddings: no empty prompt is invented


def test_export_of_a_run_without_prompts_stores_the_zero_prompt_it_trained_on(tmp_path):
    import warnings

    import oscar_zoo

    clips = write_toy_clipset(
        tmp_path / "noprompt", clips=1, frames=9, width=32, height=32, latents_vae="random", latents_window=9
    )
    cfg = tiny_train_config(clips, tmp_path / "run", steps=1, export=True)
    model = oscar_zoo.load(train(cfg, progress=False).export)
    assert model.empty_prompt.shape == (1, 1, 48) and not model.empty_prompt.any()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "ZERO text embedding" warning: it is what training used
        emb, source = model.resolve_prompt()
    assert "stored in the checkpoint" in source


def test_activation_checkpointing_gives_the_same_step_and_bf16_autocast_runs(tmp_path, clipset):
    plain = tiny_train_config(clipset, tmp_path / "plain", steps=1, save_every=1)
    train(plain, progress=False)
    a = trained_weights(plain.run_dir)
    full = tiny_train_config(clipset, tmp_path / "full", steps=1, save_every=1, activation_checkpointing="full")
    train(full, progress=False)
    assert all(torch.allclose(a[k], c, atol=1e-7) for k, c in trained_weights(full.run_dir).items())
    starts = [json.loads((Path(c.run_dir) / "metrics.jsonl").read_text().splitlines()[0]) for c in (plain, full)]
    assert [s["activation_checkpointing"] for s in starts] == ["none", "full"]  # auto is none on the CPU
    assert "auto: none on cpu" in starts[0]["checkpointing_reason"] and starts[0]["compile"] is False
    bf16 = tiny_train_config(clipset, tmp_path / "bf16", steps=1, save_every=1, **{"model.dtype": "bfloat16"})
    assert np.isfinite(train(bf16, progress=False).last_loss)


# ---------------------------------------------------------------------- conditions and stages
def test_dropped_skeleton_is_what_the_config_says(tmp_path, clipset):
    vae = build_vae(tiny_train_config(clipset, tmp_path))
    for mode in ("zero_latent", "black_video"):
        cfg = tiny_train_config(
            clipset, tmp_path / mode, **{"data.unconditional_skeleton": mode, "data.skeleton_dropout": 1.0}
        )
        data = TrainData(cfg, vae, 48)
        items = data.planner().plan(0, 2)
        assert all(it.drop for it in items)
        skel = data.batch(items, "skeleton").skeleton
        if mode == "zero_latent":
            assert skel.abs().sum() == 0
        else:
            black = vae.encode(vae.to_pixels(np.zeros((9, 32, 32, 3), np.uint8)))[0]
            assert torch.equal(skel[0], black) and skel.abs().sum() > 0


def test_text_only_and_latent_action_conditions_train(tmp_path, clipset):
    for cond in ("none", "latent_action"):
        cfg = tiny_train_config(clipset, tmp_path / cond, steps=2, condition=cond)
        r = train(cfg, progress=False)
        assert np.isfinite(r.last_loss)
    w = trained_weights(tmp_path / "latent_action")
    assert w["action_embed_d.2.weight"].abs().sum() > 0  # the action MLPs learned (they start at zero)
    assert trained_weights(tmp_path / "none")["skeleton_embed.proj.weight"].abs().sum() == 0  # PE_s unused


def test_stage_two_warm_starts_from_its_parent(tmp_path, clipset):
    stage1 = tiny_train_config(clipset, tmp_path / "stage1", steps=2)
    train(stage1, progress=False)
    # lr ~ 0: one stage-2 step leaves the parent's weights exactly in place
    stage2 = tiny_train_config(
        clipset,
        tmp_path / "stage2",
        steps=1,
        parent_run=str(stage1.run_dir),
        **{"optim.lr": 1e-30, "optim.warmup_steps": 0},
    )
    train(stage2, progress=False)
    a, b = trained_weights(stage1.run_dir), trained_weights(stage2.run_dir)
    assert all(torch.equal(a[k], b[k]) for k in a)
    fresh = build_transformer(stage2).state_dict()
    assert not torch.equal(fresh["proj_out.weight"], b["proj_out.weight"])


def test_on_the_fly_rendering_and_encoding(tmp_path):
    clips = write_toy_clipset(tmp_path / "raw", clips=1, frames=9, width=48, height=32)
    cfg = tiny_train_config(clips, tmp_path / "run", steps=1, batch_size=1, **{"data.skeleton_dropout": 0.0})
    vae = build_vae(cfg)
    data = TrainData(cfg, vae, 48)
    assert not data.cached
    item = data.planner().plan(0, 1)[0]
    got = data.load_item(item, "skeleton")
    # the skeleton latent is the VAE's encoding of the skeleton rendered at the training size (crop 48x32 -> 32x32)
    from oscar_core.render.skeleton_video import fit_image, render_skeleton_video

    clip = ClipSet(clips).load("toy-0", registry=data.registry)
    skel = render_skeleton_video(data.embodiment("toyarm"), clip.trajectory, clip.camera, (32, 32))
    assert torch.equal(got["skeleton"], vae.encode(vae.to_pixels(skel))[0])
    rgb = np.stack([fit_image(f, 32, 32) for f in clip.rgb])
    assert torch.equal(got["z0"], vae.encode(vae.to_pixels(rgb))[0])
    assert got["z0"].shape == (16, 3, 4, 4)
    train(cfg, progress=False)


# ---------------------------------------------------------------------- bad input
def _shard(clips):
    return next(p for p in Path(clips).glob("shard-*"))


def test_clip_shorter_than_the_window_is_named_or_skipped(tmp_path, clipset):
    with pytest.raises(ClipFormatError, match=r"shard-000000.*clip 'toy-0'.*n_frames.*at least the window's 17"):
        TrainData(tiny_train_config(clipset, tmp_path, **{"data.window": 17}), None, 48)
    short = write_toy_clipset(
        tmp_path / "mixed", clips=1, frames=9, width=32, height=32, latents_vae="random", latents_window=9
    )
    cfg = tiny_train_config(
        short,
        tmp_path / "run",
        **{
            "data.clips": [str(clipset), str(short)],
            "data.window": 13,
            "data.skip_bad_clips": True,
            "data.latents": "auto",
        },
    )
    data = TrainData(cfg, build_vae(cfg), 48)
    assert data.summary()["skipped_clips"] == 1 and data.skipped[0]["clip"] == "toy-0"
    assert data.summary()["clips"] == 3


def test_unknown_embodiment_and_missing_field(tmp_path, clipset):
    bad = tmp_path / "bad"
    shutil.copytree(clipset, bad)
    index = _shard(bad) / "clips.jsonl"
    lines = index.read_text().splitlines()
    rec = json.loads(lines[0])
    rec["embodiment"] = "robot9000"
    index.write_text("\n".join([json.dumps(rec)] + lines[1:]) + "\n")
    with pytest.raises(ClipFormatError, match=r"shard-000000.*clip 'toy-0'.*embodiment.*installed.*robot9000"):
        TrainData(tiny_train_config(bad, tmp_path), None, 48)
    data = TrainData(tiny_train_config(bad, tmp_path, **{"data.skip_bad_clips": True}), None, 48)
    assert data.summary()["skipped_clips"] == 1
    del rec["fps"]
    rec["embodiment"] = "toyarm"
    index.write_text("\n".join([json.dumps(rec)] + lines[1:]) + "\n")
    with pytest.raises(ClipFormatError, match=r"shard-000000.*clip 'toy-0'.*'fps'.*missing"):
        TrainData(tiny_train_config(bad, tmp_path), None, 48)


def test_video_and_trajectory_lengths_must_agree(tmp_path, clipset):
    from oscar_core.kinematics.trajectory import load_trajectory, save_trajectory

    bad = tmp_path / "bad"
    shutil.copytree(clipset, bad)
    traj_file = _shard(bad) / "toy-1" / "trajectory.npz"
    save_trajectory(load_trajectory(traj_file).time_slice(0, 10), traj_file)
    with pytest.raises(ClipFormatError, match=r"shard-000000.*clip 'toy-1'.*trajectory.*13 frames.*10 frames"):
        TrainData(tiny_train_config(bad, tmp_path), None, 48)
    bad2 = tmp_path / "bad2"
    shutil.copytree(clipset, bad2)
    from oscar_core.media.video import read_video, write_video

    video = _shard(bad2) / "toy-1" / "rgb.mkv"
    write_video(video, read_video(video)[:11], 15.0)
    with pytest.raises(ClipFormatError, match=r"clip 'toy-1'.*rgb.*13 frames.*11 frames"):
        TrainData(tiny_train_config(bad2, tmp_path), None, 48)
    assert (
        TrainData(tiny_train_config(bad2, tmp_path, **{"data.skip_bad_clips": True}), None, 48).summary()[
            "skipped_clips"
        ]
        == 1
    )


def test_config_errors_name_file_and_field(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("steps: 10\ndata: {clips: [x], window: 10}\n")
    with pytest.raises(TrainConfigError, match=r"c.yaml: field 'data.window': expected a frame count 4k\+1.*10"):
        load_config(p)
    p.write_text("stesp: 10\n")
    with pytest.raises(TrainConfigError, match=r"c.yaml: field 'stesp'.*unknown key"):
        load_config(p)
    p.write_text("data: {clips: [x]}\nbatch_size: 16\nmicro_batch: 3\n")
    with pytest.raises(TrainConfigError, match="micro_batch.*divisor of batch_size 16"):
        load_config(p)
    for name in ("tiny-cpu.yaml", "oscar-2b.yaml"):
        cfg = load_config(REPO / "configs" / "train" / name)
        assert cfg.data.skeleton_dropout == 0.2 and cfg.flow.shift == 5.0 and cfg.data.mixing_temperature == 3.0
    for name in ("toyworld.yaml", "toyworld-latent-action.yaml"):  # trained from scratch: condition layers drawn
        cfg = load_config(REPO / "configs" / "train" / name)
        assert cfg.model.init is None and cfg.model.condition_init == "default"
    big = load_config(REPO / "configs" / "train" / "oscar-2b.yaml")
    assert (big.optim.lr, big.batch_size, big.data.window) == (3e-5, 16, 81)


def test_condition_init_zero_or_default(tmp_path, clipset):
    """From scratch, model.condition_init picks a zero PE_s (the fine-tuning recipe) or nn.Linear's own init;
    the rest of the model is the same draw either way, and so are the latent-action MLPs' first layers."""
    zero = build_transformer(tiny_train_config(clipset, tmp_path))
    drawn = build_transformer(tiny_train_config(clipset, tmp_path, **{"model.condition_init": "default"}))
    assert torch.count_nonzero(zero.skeleton_embed.proj.weight) == 0
    w = drawn.skeleton_embed.proj.weight.detach()
    bound = 1 / w.shape[1] ** 0.5  # kaiming_uniform(a=sqrt(5)) of nn.Linear: U(-1/sqrt(fan_in), 1/sqrt(fan_in))
    assert torch.count_nonzero(w) == w.numel() and float(w.abs().max()) <= bound and float(w.std()) > bound / 3
    a, b = zero.state_dict(), drawn.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a if k != "skeleton_embed.proj.weight")
    la = {"condition": "latent_action", "model.condition_init": "default"}
    la_zero = build_transformer(tiny_train_config(clipset, tmp_path, condition="latent_action"))
    la_drawn = build_transformer(tiny_train_config(clipset, tmp_path, **la))
    for name in ("action_embed_d", "action_embed_3d"):
        assert torch.count_nonzero(getattr(la_zero, name)[2].weight) == 0
        assert torch.count_nonzero(getattr(la_drawn, name)[2].weight) > 0
        assert torch.equal(getattr(la_zero, name)[0].weight, getattr(la_drawn, name)[0].weight)
    assert torch.count_nonzero(la_drawn.skeleton_embed.proj.weight) == 0  # never sees a skeleton
    with pytest.raises(TrainConfigError, match=r"model.condition_init.*'zero' or 'default'.*'normal'"):
        tiny_train_config(clipset, tmp_path, **{"model.condition_init": "normal"})


def test_cli_trains_resumes_and_exports(tmp_path, clipset, capsys):
    from oscar_core.cli import main

    run = tmp_path / "run"
    args = [
        "train",
        str(REPO / "configs" / "train" / "tiny-cpu.yaml"),
        "--set",
        f"run_dir={run}",
        "--set",
        "steps=2",
        "--set",
        f"data.clips=[{clipset}]",
        "--set",
        "batch_size=2",
        "--set",
        "export=false",
        "--no-progress",
        "--json",
    ]
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["step"] == 2
    # the run folder keeps a plain log and the training curves (loss, grad norm, lr)
    logs = list((run / "logs").glob("train-*.log"))
    assert len(logs) == 1 and "training curves:" in logs[0].read_text()
    from oscar_core.train.curves import read_curves

    curves = read_curves(run / "metrics.jsonl")
    assert curves["step"] == [2.0] and all(v > 0 for v in curves["loss"] + curves["grad_norm"])
    pytest.importorskip("matplotlib")
    assert (run / "curves.png").read_bytes()[:4] == b"\x89PNG"
    assert main(["train", "--export", str(run), "--out", str(tmp_path / "model"), "--json"]) == 0
    assert (tmp_path / "model" / "oscar_model.json").is_file()
    assert main(["train", "--resume", str(run), "--no-progress"]) == 0  # already finished: nothing to do
    assert main(["train"]) == 2
    assert "exactly one" in capsys.readouterr().err


def test_config_names_a_vae_folder_and_a_transformer_config(tmp_path):
    """What the toy world needs: its own small DiT config, its own VAE folder, 17-frame windows at 64x64."""
    from oscar_core.model.tiny import TINY_TRANSFORMER_CONFIG, build_tiny_vae

    build_tiny_vae(seed=7).save_pretrained(tmp_path / "vae", safe_serialization=True)
    (tmp_path / "dit.json").write_text(
        json.dumps({**TINY_TRANSFORMER_CONFIG, "num_layers": 1, "num_attention_heads": 1})
    )
    clips = write_toy_clipset(
        tmp_path / "clips", clips=1, frames=17, width=64, height=64, latents_vae="random", latents_window=17
    )
    cfg = tiny_train_config(
        clips,
        tmp_path / "run",
        steps=1,
        batch_size=1,
        export=True,
        **{
            "model.vae": str(tmp_path / "vae"),
            "model.transformer": str(tmp_path / "dit.json"),
            "data.window": 17,
            "data.width": 64,
            "data.height": 64,
        },
    )
    result = train(cfg, progress=False)
    import oscar_zoo

    model = oscar_zoo.load(result.export)
    assert model.transformer.config.num_layers == 1 and model.card.chunk_frames == 17
    vae = build_tiny_vae(seed=7)
    assert all(torch.equal(v, model.vae.vae.state_dict()[k]) for k, v in vae.state_dict().items())
    with pytest.raises(TrainConfigError, match="model.transformer"):
        train(
            tiny_train_config(clips, tmp_path / "bad", **{"model.transformer": str(tmp_path / "nope.json")}),
            progress=False,
        )


def test_the_memory_policy_counts_tokens_with_the_vaes_own_compression(tmp_path, monkeypatch):
    """The toy VAE compresses 4x in space: activation_checkpointing auto must count 4x the tokens WAN's 8x gives."""
    from oscar_core.train import loop

    asked = []

    def prepare(model, config, device, shards=1, compression=(4, 8)):
        asked.append(compression)
        raise KeyboardInterrupt  # stop before the first step: only the policy's inputs are under test

    monkeypatch.setattr(loop, "prepare_for_training", prepare)
    clips = write_toy_clipset(tmp_path / "clips", clips=1, frames=17, width=64, height=64)
    cfg = tiny_train_config(
        clips,
        tmp_path / "run",
        **{
            "model.vae": str(REPO / "zoo" / "assets" / "oscar-toy" / "vae"),
            "data.window": 17,
            "data.width": 64,
            "data.height": 64,
        },
    )
    with pytest.raises(KeyboardInterrupt):
        train(cfg, progress=False)
    assert asked == [(4, 4)]
    with pytest.raises(KeyboardInterrupt):
        train(
            tiny_train_config(clips, tmp_path / "run2", **{"data.window": 17, "data.width": 64, "data.height": 64}),
            progress=False,
        )
    assert asked[-1] == (4, 8)  # the tiny test VAE: WAN's factors


@pytest.mark.slow
def test_resume_with_more_steps_extends_the_run_bitwise(tmp_path, clipset):
    """`oscar train --resume RUN --set steps=4` on a finished 2-step run gives the weights of a straight 4-step run."""
    from oscar_core.cli import main

    straight = tiny_train_config(clipset, tmp_path / "straight", steps=4)
    train(straight, progress=False)
    short = tiny_train_config(clipset, tmp_path / "short", steps=2)
    assert train(short, progress=False).step == 2
    assert (
        main(["train", "--resume", str(short.run_dir), "--set", "steps=4", "--set", "save_every=1", "--no-progress"])
        == 0
    )
    for key in ("model", "ema"):
        a, b = trained_weights(straight.run_dir, key), trained_weights(short.run_dir, key)
        assert all(torch.equal(a[k], b[k]) for k in a), key
    saved = load_config(Path(short.run_dir) / "config.yaml")
    assert (saved.steps, saved.save_every) == (4, 1)  # the next --resume continues from the extended config
    assert [p.name for p in list_checkpoints(short.run_dir)][-2:] == ["step-00000003", "step-00000004"]
    steps = [json.loads(l)["step"] for l in (Path(short.run_dir) / "metrics.jsonl").read_text().splitlines()]
    assert steps == [0, 1, 2, 3, 4]


def test_resume_overrides_other_than_extending_ones_are_refused_naming_the_field(tmp_path, clipset, capsys):
    from oscar_core.cli import main

    cfg = tiny_train_config(clipset, tmp_path / "run", steps=2)
    train(cfg, progress=False, stop_after=2)
    before = (Path(cfg.run_dir) / "config.yaml").read_text()
    assert main(["train", "--resume", str(cfg.run_dir), "--set", "optim.lr=0.5"]) == 2
    err = capsys.readouterr().err
    assert (
        err.startswith(
            "error: --set: field 'optim.lr': expected with --resume only steps, save_every, log_every, keep_last"
        )
        and err.count("\n") == 1
    )
    assert main(["train", "--resume", str(cfg.run_dir), "--set", "steps=1"]) == 2  # fewer than done: refused
    assert "field 'steps': expected at least the latest checkpoint's step 2, found 1" in capsys.readouterr().err
    assert (Path(cfg.run_dir) / "config.yaml").read_text() == before  # nothing changed by a refused resume


def test_a_bad_set_value_blames_set_not_the_yaml_file(tmp_path, capsys):
    from oscar_core.cli import main

    config = str(REPO / "configs" / "train" / "tiny-cpu.yaml")
    for value, found in [
        ("steps=abc", "expected an integer, found str 'abc'"),
        ("optim.lr=nope", "expected a number, found str 'nope'"),
        ("steps=0", "expected a positive integer, found 0"),
    ]:
        assert main(["train", config, "--set", value, "--set", f"run_dir={tmp_path / 'r'}"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"error: --set: field '{value.split('=')[0]}'") and found in err, err
        assert "tiny-cpu.yaml" not in err
    assert main(["train", config, "--set", "nosuch=1"]) == 2
    assert capsys.readouterr().err.startswith("error: --set: field 'nosuch'")
