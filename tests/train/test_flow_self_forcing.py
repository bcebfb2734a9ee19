"""Self forcing in plain rectified-flow training (``flow.self_forcing``): a chosen item's first latent frame is made
by the model being trained, sampled as its rollouts sample it — guided Euler steps whose unconditional branch sees
the item's dropped condition (checked against a guided Euler loop written here on a DiT whose velocity is known in
closed form), decoded and re-encoded; the run logs how many items it forced, trains otherwise than without, resumes
bitwise, and gives the same weights on 1 and 2 processes (DDP and FSDP2); bad settings are refused by field before
anything is written."""

import pytest
import torch
from _models import (
    ClosedFormDiT,
    assert_resumes_bitwise,
    long_clipset,
    metrics_rows,
    tiny_train_config,
    trained_one_and_two_ways,
    trained_weights,
)

from oscar_core.model.sampler import SamplerConfig
from oscar_core.train.config import TrainConfigError
from oscar_core.train.data import TrainData
from oscar_core.train.loop import train
from oscar_core.train.models import build_vae
from oscar_core.train.sampling import PlanItem
from oscar_core.train.self_forcing import CONTEXT_SALT, own_first_frames
from oscar_core.train.synthetic import write_toy_clipset

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def long_clips(tmp_path_factory):
    return long_clipset(tmp_path_factory.mktemp("flow_sf") / "clips")


@pytest.mark.parametrize("uncond_kind", ["zero_latent", "black_video"])
def test_the_models_own_first_frame_is_sampled_guided_against_the_dropped_condition(tmp_path, long_clips, uncond_kind):
    config = tiny_train_config(
        long_clips, tmp_path / "run", **{"flow.self_forcing": 1.0, "data.unconditional_skeleton": uncond_kind}
    )
    vae = build_vae(config)
    data = TrainData(config, vae, text_dim=48)
    items = [PlanItem(0, 8, False, 0.7, 11), PlanItem(1, 3, True, 0.4, 12), PlanItem(1, 12, True, 0.2, 13)]
    batch = data.batch(items, "skeleton")
    field = ClosedFormDiT()
    sampler = SamplerConfig(steps=3, shift=5.0, guidance=2.5, guidance_form="diffusers", solver="euler")
    forced, n = own_first_frames(
        field, data, batch, items, 1.0, sampler, "cpu", condition="skeleton", window=9, autocast=None
    )
    assert n == 2  # the item at frame 3 has no window 8 frames before it

    # by hand: the previous windows (start − 8) with their condition, never dropped, and the dropped condition
    prev = data.batch([PlanItem(0, 0, False, 0.7, 11), PlanItem(1, 4, False, 0.2, 13)], "skeleton")
    uncond = data.batch([PlanItem(0, 0, True, 0.7, 11), PlanItem(1, 4, True, 0.2, 13)], "skeleton").skeleton
    assert not torch.equal(prev.skeleton, uncond)
    if uncond_kind == "zero_latent":
        assert not uncond.any()
    else:
        assert uncond.abs().sum() > 0  # the black video's latent, not zeros
    noise = torch.cat(
        [
            torch.randn((1, *prev.z0.shape[1:]), generator=torch.Generator().manual_seed(seed ^ CONTEXT_SALT))
            for seed in (11, 13)
        ]
    )
    chunk = field.euler_by_hand(prev.z0[:, :, :1], prev.skeleton, noise, steps=3, uncond=uncond, w=2.5)
    expected = vae.encode(vae.decode(chunk).clamp(-1, 1)[:, :, -1:])
    torch.testing.assert_close(forced.z0[0, :, :1], expected[0], rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(forced.z0[2, :, :1], expected[1], rtol=1e-4, atol=1e-4)
    assert torch.equal(forced.z0[:, :, 1:], batch.z0[:, :, 1:]) and torch.equal(forced.z0[1], batch.z0[1])
    assert torch.equal(forced.skeleton, batch.skeleton)
    # the test can fail: the same loop unguided, or guided against zeros where the black video was dropped to
    unguided = field.euler_by_hand(prev.z0[:, :, :1], prev.skeleton, noise, steps=3, uncond=uncond, w=0.0)
    assert not torch.allclose(vae.encode(vae.decode(unguided).clamp(-1, 1)[:, :, -1:]), expected, atol=1e-3)
    if uncond_kind == "black_video":
        zeros = field.euler_by_hand(prev.z0[:, :, :1], prev.skeleton, noise, steps=3, uncond=0 * uncond, w=2.5)
        assert not torch.allclose(vae.encode(vae.decode(zeros).clamp(-1, 1)[:, :, -1:]), expected, atol=1e-3)


def test_without_guidance_the_conditional_branch_alone_samples(tmp_path, long_clips):
    config = tiny_train_config(long_clips, tmp_path / "run", **{"flow.self_forcing": 1.0})
    vae = build_vae(config)
    data = TrainData(config, vae, text_dim=48)
    items = [PlanItem(0, 12, False, 0.5, 21)]
    batch = data.batch(items, "skeleton")
    sampler = SamplerConfig(steps=2, shift=5.0, guidance=None, solver="euler")
    forced, n = own_first_frames(
        ClosedFormDiT(), data, batch, items, 1.0, sampler, "cpu", condition="skeleton", window=9
    )
    prev = data.batch([PlanItem(0, 4, False, 0.5, 21)], "skeleton")
    noise = torch.randn((1, *prev.z0.shape[1:]), generator=torch.Generator().manual_seed(21 ^ CONTEXT_SALT))
    chunk = ClosedFormDiT().euler_by_hand(prev.z0[:, :, :1], prev.skeleton, noise, steps=2, uncond=prev.skeleton, w=0.0)
    assert n == 1
    torch.testing.assert_close(
        forced.z0[0, :, :1], vae.encode(vae.decode(chunk).clamp(-1, 1)[:, :, -1:])[0], atol=1e-4, rtol=1e-4
    )


@pytest.mark.slow
def test_a_self_forced_run_logs_its_items_resumes_bitwise_and_trains_otherwise_than_without(tmp_path, long_clips):
    common = {"flow.self_forcing": 1.0, "flow.self_forcing_steps": 2, "batch_size": 4, "micro_batch": 2}
    straight = assert_resumes_bitwise(lambda run_dir: tiny_train_config(long_clips, run_dir, **common), tmp_path)
    forced = [r["self_forced"] for r in metrics_rows(straight) if "self_forced" in r]
    assert len(forced) == 4 and sum(forced) > 0  # log_every 1: items trained from their own frame, per step
    plain = tiny_train_config(long_clips, tmp_path / "plain", **{**common, "flow.self_forcing": 0.0})
    train(plain, progress=False)
    assert not any("self_forced" in r for r in metrics_rows(plain.run_dir))
    a, b = trained_weights(straight), trained_weights(plain.run_dir)
    assert not all(torch.equal(a[k], b[k]) for k in a)  # the model's own first frames change what it learns


@pytest.mark.parametrize(
    "over, field, expected",
    [
        ({"flow.self_forcing": -0.1}, "flow.self_forcing", r"a fraction in \[0, 1\]"),
        ({"flow.self_forcing": 1.5}, "flow.self_forcing", r"a fraction in \[0, 1\]"),
        ({"flow.self_forcing": True}, "flow.self_forcing", "a number"),
        ({"flow.self_forcing_steps": 0}, "flow.self_forcing_steps", "a positive integer"),
        ({"flow.self_forcing_steps": 2.5}, "flow.self_forcing_steps", "an integer"),
        ({"flow.self_forcing_guidance": -1.0}, "flow.self_forcing_guidance", "a number >= 0"),
        ({"flow.self_forcing_guidance": float("nan")}, "flow.self_forcing_guidance", "a finite number"),
        ({"flow.self_forcing": 0.5, "model.context_frames": 5}, "model.context_frames", "1 with flow.self_forcing"),
        ({"flow.self_forcing": 0.5, "condition": "latent_action"}, "condition", "a condition video"),
    ],
)
def test_bad_self_forcing_settings_are_refused_by_field(tmp_path, long_clips, over, field, expected):
    with pytest.raises(TrainConfigError, match=rf"field '{field}'.*expected {expected}"):
        tiny_train_config(long_clips, tmp_path / "r", **over)


def test_self_forcing_is_refused_when_distilling(tmp_path, long_clips):
    with pytest.raises(TrainConfigError, match=r"field 'flow\.self_forcing'.*0 when distilling"):
        tiny_train_config(
            long_clips,
            tmp_path / "r",
            **{"flow.self_forcing": 0.5, "distill.teacher": str(tmp_path), "model.init": str(tmp_path)},
        )


def test_clips_too_short_for_a_previous_window_are_refused_before_anything_is_written(tmp_path):
    short = write_toy_clipset(
        tmp_path / "short", clips=2, frames=13, width=32, height=32, latents_vae="random", latents_window=9
    )
    config = tiny_train_config(short, tmp_path / "run", **{"flow.self_forcing": 0.5})
    with pytest.raises(TrainConfigError, match=r"flow\.self_forcing.*at least 17 frames.*none among 2 clips"):
        train(config, progress=False)
    assert not (tmp_path / "run").exists()


def test_items_with_no_previous_window_are_left_alone(tmp_path, long_clips):
    config = tiny_train_config(long_clips, tmp_path / "run", **{"flow.self_forcing": 1.0})
    data = TrainData(config, build_vae(config), text_dim=48)
    items = [PlanItem(0, 0, False, 0.5, 1), PlanItem(1, 7, False, 0.5, 2)]
    batch = data.batch(items, "skeleton")
    sampler = SamplerConfig(steps=2, guidance=None, solver="euler")
    same, n = own_first_frames(ClosedFormDiT(), data, batch, items, 1.0, sampler, "cpu", condition="skeleton", window=9)
    assert n == 0 and same is batch


@pytest.fixture(scope="module")
def flow_self_forced_two_ways(tmp_path_factory, long_clips):
    """Run folders of the same 2-step self-forced training in this process ("one") and on 2 gloo processes under DDP
    and FSDP2 ("ddp", "fsdp"), the two trained by one torchrun launch (tests/_torchrun.py)."""
    common = {"flow.self_forcing": 1.0, "flow.self_forcing_steps": 2, "steps": 2, "batch_size": 4}
    return trained_one_and_two_ways(
        lambda run_dir, parallel: tiny_train_config(long_clips, run_dir, parallel=parallel, **common),
        tmp_path_factory.mktemp("flow_self_forced_two_ways"),
    )


@pytest.mark.slow
@pytest.mark.parametrize("parallel", ["ddp", "fsdp"])
def test_two_processes_self_force_as_one(flow_self_forced_two_ways, parallel):
    forced = [r["self_forced"] for r in metrics_rows(flow_self_forced_two_ways / parallel) if "self_forced" in r]
    assert forced == [r["self_forced"] for r in metrics_rows(flow_self_forced_two_ways / "one") if "self_forced" in r]
    for key in ("model", "ema"):
        a = trained_weights(flow_self_forced_two_ways / "one", key)
        b = trained_weights(flow_self_forced_two_ways / parallel, key)
        assert all(torch.allclose(a[k], b[k], atol=2e-6, rtol=1e-5) for k in a), key
