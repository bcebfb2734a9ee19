"""Self forcing in distillation (oscar_core.train.distill.self_force): a chosen item's first latent frame is the
student's own, made as a long rollout makes it — the student samples the window that ends at the item's first
frame in its own Euler steps (checked against an Euler loop written here on a DiT whose velocity is known in
closed form), the VAE decodes it and re-encodes its last frame; items without such a window are left alone; the
choice is a function of the item's seed; a self-forced tiny run resumes bitwise, trains differently and gives
the same weights on 1 and 2 processes."""

from pathlib import Path

import numpy as np
import pytest
import torch
from _models import (
    ClosedFormDiT,
    assert_resumes_bitwise,
    long_clipset,
    metrics_rows,
    tiny_train_config,
    trained_one_and_two_ways,
)

from oscar_core.model.sampler import SamplerConfig, sample_chunk
from oscar_core.train.checkpoint import latest_checkpoint, load_weights
from oscar_core.train.config import TrainConfigError, load_config
from oscar_core.train.data import TrainData
from oscar_core.train.distill import _CONTEXT_SALT, self_force, self_forced
from oscar_core.train.loop import train
from oscar_core.train.models import build_transformer, build_vae
from oscar_core.train.sampling import PlanItem
from oscar_core.train.synthetic import write_toy_clipset

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def long_clips(tmp_path_factory):
    return long_clipset(tmp_path_factory.mktemp("sf") / "clips")


def _config(clips, run_dir, **over):
    return tiny_train_config(clips, run_dir, **{"distill.steps": 3, "distill.self_forcing": 1.0, **over})


def test_a_self_forced_item_starts_from_the_last_frame_of_the_students_own_previous_chunk(tmp_path, long_clips):
    config = _config(long_clips, tmp_path / "run", **{"model.transformer": "tiny"})
    vae = build_vae(config)
    data = TrainData(config, vae, text_dim=48)
    assert data.cached and data.has_window(0, 12) and data.has_window(0, 0) and not data.has_window(0, 13)
    items = [PlanItem(0, 8, False, 0.7, 101), PlanItem(1, 3, False, 0.4, 102), PlanItem(1, 8, False, 0.2, 103)]
    batch = data.batch(items, "skeleton")
    student = ClosedFormDiT()
    forced, n = self_force(student, data, batch, items, config, "cpu")
    assert n == 2  # the item at frame 3 has no window 8 frames before it

    # by hand: item k's previous window (start − 8) sampled in 3 Euler steps from its own clean first frame
    prev = data.batch([PlanItem(0, 0, False, 0.7, 101), PlanItem(1, 0, False, 0.2, 103)], "skeleton")
    noise = torch.cat(
        [
            torch.randn((1, *prev.z0.shape[1:]), generator=torch.Generator().manual_seed(seed ^ _CONTEXT_SALT))
            for seed in (101, 103)
        ]
    )
    chunk = student.euler_by_hand(prev.z0[:, :, :1], prev.skeleton, noise, steps=3)
    pixels = vae.decode(chunk).clamp(-1, 1)  # (2, 3, 9, 32, 32)
    expected = vae.encode(pixels[:, :, -1:])
    torch.testing.assert_close(forced.z0[0, :, :1], expected[0], rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(forced.z0[2, :, :1], expected[1], rtol=1e-4, atol=1e-4)
    # everything else is the data's: the later latent frames, the unchosen item, the condition and the text
    assert torch.equal(forced.z0[:, :, 1:], batch.z0[:, :, 1:]) and torch.equal(forced.z0[1], batch.z0[1])
    assert torch.equal(forced.skeleton, batch.skeleton) and torch.equal(forced.text, batch.text)
    # the test can fail: the data's own first frame, or the first frame of the chunk (not its last), differ
    assert not torch.allclose(forced.z0[0, :, :1], batch.z0[0, :, :1], atol=1e-2)
    assert not torch.allclose(expected, vae.encode(pixels[:, :, :1]), atol=1e-2)
    # off: the batch comes back untouched
    again, none = self_force(
        student, data, batch, items, _config(long_clips, tmp_path / "r", **{"distill.self_forcing": 0.0}), "cpu"
    )
    assert none == 0 and again is batch


def test_the_prompt_projected_in_each_forward_samples_as_projected_once(tmp_path, long_clips):
    """On the real (tiny) DiT: ``sample_chunk(..., project_once=False)`` (how a self-forced context chunk is made, so
    that a sharded student runs whole) equals the rollout's sampler, which projects the prompt once."""
    config = _config(long_clips, tmp_path / "run")
    data = TrainData(config, build_vae(config), text_dim=48)
    student = build_transformer(config).eval()
    prev = data.batch([PlanItem(0, 0, False, 0.5, 7), PlanItem(1, 4, False, 0.5, 8)], "skeleton")
    sampler = SamplerConfig(steps=3, shift=config.flow.shift, guidance=None, solver="euler")
    runs = []
    for once in (True, False):
        gens = [torch.Generator().manual_seed(seed) for seed in (7, 8)]
        with torch.no_grad():
            first, skel = prev.z0[:, :, :1], prev.skeleton
            runs.append(sample_chunk(student, first, skel, prev.text, sampler, generators=gens, project_once=once))
    torch.testing.assert_close(runs[0], runs[1], rtol=1e-4, atol=1e-4)
    assert not torch.allclose(runs[0][:, :, 1:], prev.z0[:, :, 1:], atol=1e-2)  # a sample, not the data


def test_which_items_are_self_forced_depends_on_their_seed_alone():
    items = [PlanItem(0, 0, False, 0.5, seed) for seed in range(2000)]
    half = [self_forced(it, 0.5) for it in items]
    assert half == [self_forced(it, 0.5) for it in items]
    assert 0.45 < np.mean(half) < 0.55
    assert 0.2 < np.mean([self_forced(it, 0.25) for it in items]) < 0.3
    assert not any(self_forced(it, 0.0) for it in items) and all(self_forced(it, 1.0) for it in items)


@pytest.mark.parametrize(
    "bad, expected",
    [(-0.1, r"a fraction in \[0, 1\]"), (1.5, r"a fraction in \[0, 1\]"), (True, "a number"), ("half", "a number")],
)
def test_self_forcing_is_a_fraction(tmp_path, long_clips, bad, expected):
    with pytest.raises(TrainConfigError, match=rf"distill\.self_forcing.*{expected}"):
        _config(long_clips, tmp_path / "r", **{"distill.self_forcing": bad, "distill.teacher": str(tmp_path)})


def test_clips_too_short_for_a_previous_window_are_refused_before_anything_is_written(tmp_path):
    short = write_toy_clipset(
        tmp_path / "short", clips=2, frames=13, width=32, height=32, latents_vae="random", latents_window=9
    )
    teacher = train(tiny_train_config(short, tmp_path / "teacher", steps=1, export=True), progress=False).export
    config = _config(short, tmp_path / "student", **{"model.init": str(teacher), "distill.teacher": str(teacher)})
    with pytest.raises(TrainConfigError, match=r"distill\.self_forcing.*at least 17 frames.*none among 2 clips"):
        train(config, progress=False)
    assert not (tmp_path / "student").exists()


def _weights(run_dir, key="model"):
    model = build_transformer(load_config(Path(run_dir) / "config.yaml"))
    return load_weights(latest_checkpoint(run_dir), model, key=key).state_dict()


@pytest.mark.slow
def test_a_self_forced_distillation_resumes_bitwise_and_trains_otherwise_than_without(tmp_path, long_clips):
    teacher = train(tiny_train_config(long_clips, tmp_path / "teacher", steps=2, export=True), progress=False).export
    common = {"model.init": str(teacher), "distill.teacher": str(teacher), "batch_size": 4, "micro_batch": 2}
    straight = assert_resumes_bitwise(lambda run_dir: _config(long_clips, run_dir, **common), tmp_path)
    rows = metrics_rows(straight)
    forced = [r["self_forced"] for r in rows if "self_forced" in r]
    assert len(forced) == 4 and sum(forced) > 0  # log_every 1: items trained from their own frame, per step
    plain = _config(long_clips, tmp_path / "plain", **common, **{"distill.self_forcing": 0.0})
    train(plain, progress=False)
    a, b = _weights(straight), _weights(plain.run_dir)
    assert not all(torch.equal(a[k], b[k]) for k in a)  # the student's own first frames change what it learns


@pytest.fixture(scope="module")
def self_forced_two_ways(tmp_path_factory, long_clips):
    """Run folders of the same 2-step self-forced distillation in this process ("one") and on 2 gloo processes under
    DDP and FSDP2 ("ddp", "fsdp"), the two trained by one torchrun launch (tests/_torchrun.py)."""
    tmp = tmp_path_factory.mktemp("self_forced_two_ways")
    teacher = train(tiny_train_config(long_clips, tmp / "teacher", steps=2, export=True), progress=False).export
    common = {"model.init": str(teacher), "distill.teacher": str(teacher), "steps": 2, "batch_size": 4}
    return trained_one_and_two_ways(
        lambda run_dir, parallel: _config(long_clips, run_dir, parallel=parallel, **common), tmp
    )


@pytest.mark.slow
@pytest.mark.parametrize("parallel", ["ddp", "fsdp"])
def test_two_processes_self_force_as_one(self_forced_two_ways, parallel):
    for key in ("model", "ema"):
        a, b = _weights(self_forced_two_ways / "one", key), _weights(self_forced_two_ways / parallel, key)
        assert all(torch.allclose(a[k], b[k], atol=2e-6, rtol=1e-5) for k in a), key
