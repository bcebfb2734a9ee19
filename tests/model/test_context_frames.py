"""The longer context (``context_frames``: 4k + 1 pixel frames, k + 1 latent frames): the chunk plan, the model
card field, training's condition mask, the sampler and the rollout's chunk loop (tiny random models, CPU)."""

import json

import pytest

from oscar_core.model import ModelCard, ModelInputError, chunk_plan, chunk_windows
from oscar_core.model.chunks import check_context_frames

# --------------------------------------------------------------------------- the chunk plan

# written out by hand: chunk 0 makes frames 1..16 from the first frame alone, every later chunk starts 12 frames on
# (17 − 5) from the previous chunk's last 5 frames and makes the 12 after them
BY_HAND_17_5 = {
    17: ([0], [(1, 16)]),
    18: ([0, 12], [(1, 16), (17, 17)]),
    29: ([0, 12], [(1, 16), (17, 28)]),
    30: ([0, 12, 24], [(1, 16), (17, 28), (29, 29)]),
    49: ([0, 12, 24, 36], [(1, 16), (17, 28), (29, 40), (41, 48)]),
    97: (
        [0, 12, 24, 36, 48, 60, 72, 84],
        [(1, 16), (17, 28), (29, 40), (41, 52), (53, 64), (65, 76), (77, 88), (89, 96)],
    ),
}


@pytest.mark.parametrize("frames", sorted(BY_HAND_17_5))
def test_the_plan_with_a_5_frame_context_is_the_one_written_by_hand(frames):
    starts, windows = BY_HAND_17_5[frames]
    assert chunk_plan(frames, 17, context_frames=5) == starts
    assert chunk_windows(frames, 17, context_frames=5) == windows
    # every frame after the first is made exactly once, and the last chunk reaches the last frame
    made = [f for a, b in windows for f in range(a, b + 1)]
    assert made == list(range(1, frames))
    assert starts[-1] + 17 >= frames > starts[-1] + 5  # the last chunk makes at least one frame


def test_a_9_frame_chunk_with_a_5_frame_context_advances_4_frames():
    assert chunk_plan(13, 9, context_frames=5) == [0, 4]
    assert chunk_windows(13, 9, context_frames=5) == [(1, 8), (9, 12)]
    assert chunk_windows(22, 9, context_frames=5) == [(1, 8), (9, 12), (13, 16), (17, 20), (21, 21)]


@pytest.mark.parametrize("chunk", [5, 9, 17, 81])
def test_the_one_frame_context_plan_is_the_plan_before_the_option(chunk):
    for frames in range(chunk, 4 * chunk + 3):
        step = chunk - 1
        before = [k * step for k in range(-(-(frames - 1) // step))]  # the formula the plan had before
        assert chunk_plan(frames, chunk) == before == chunk_plan(frames, chunk, context_frames=1)
        assert chunk_windows(frames, chunk) == [(s + 1, min(s + step, frames - 1)) for s in before]


@pytest.mark.parametrize("bad", [0, 2, 3, 6, 17, 21, True, 5.0, "5"])
def test_a_context_not_4k_plus_1_or_not_shorter_than_the_chunk_is_refused(bad):
    with pytest.raises(ModelInputError, match=r"context_frames: expected .*4k\+1.*17-frame chunk's 5 .*at most 13"):
        chunk_plan(33, 17, context_frames=bad)


def test_the_longest_context_leaves_one_latent_frame():
    assert check_context_frames(13, 17) == 4
    assert check_context_frames(1, 5) == 1
    with pytest.raises(ModelInputError, match="found 5"):
        check_context_frames(5, 5)


# --------------------------------------------------------------------------- the model card


def test_a_card_without_the_field_reads_as_one_frame_and_is_written_without_it():
    card = ModelCard.from_dict({"chunk_frames": 17})
    assert card.context_frames == 1
    assert "context_frames" not in card.to_dict()
    five = ModelCard(chunk_frames=17, context_frames=5)
    assert five.to_dict()["context_frames"] == 5
    assert ModelCard.from_dict(five.to_dict()) == five


@pytest.mark.parametrize("bad", [3, 17, 0])
def test_a_card_with_a_bad_context_names_the_field(bad):
    with pytest.raises(ModelInputError, match=rf"model card context_frames: expected .* found {bad}"):
        ModelCard(chunk_frames=17, context_frames=bad)


def test_a_latent_action_card_keeps_the_one_frame_context():
    with pytest.raises(ModelInputError, match="model card context_frames: expected 1 for a latent-action model"):
        ModelCard(chunk_frames=17, condition="latent_action", context_frames=5)


def test_read_card_refuses_a_bad_context_before_loading_weights(tmp_path):
    from oscar_core.model.card import FORMAT, read_card
    from oscar_core.model.errors import CheckpointLayoutError

    (tmp_path / "oscar_model.json").write_text(
        json.dumps({"format": FORMAT, "format_version": 1, "card": {"chunk_frames": 17, "context_frames": 4}})
    )
    with pytest.raises(CheckpointLayoutError, match="context_frames"):
        read_card(tmp_path)


# --------------------------------------------------------------------------- training


def _z(b=3, t=5, seed=0):
    import torch

    g = torch.Generator().manual_seed(seed)
    return torch.randn(b, 4, t, 2, 3, generator=g), torch.randn(b, 4, t, 2, 3, generator=g)


def test_the_training_condition_mask_covers_exactly_the_context_latent_frames():
    import torch

    from oscar_core.train.flow import flow_inputs

    z0, noise = _z()
    sigma = torch.tensor([0.3, 0.6, 0.9], dtype=torch.float64)
    inp = flow_inputs(z0, noise, sigma, 1e-4, context=[1, 2, 4])
    for i, n in enumerate([1, 2, 4]):
        on = inp.condition_mask[i, 0, :, 0, 0]
        assert on.tolist() == [1.0] * n + [0.0] * (5 - n)
        assert (inp.condition_mask[i] == on.view(1, 5, 1, 1)).all()  # the whole frame, no more
        assert inp.loss_mask[i].flatten().tolist() == [0.0] * n + [1.0] * (5 - n)
        assert torch.equal(inp.x[i, :, :n], z0[i, :, :n])  # clean context
        assert torch.allclose(inp.x[i, :, n:], ((1 - sigma[i]) * z0[i, :, n:] + sigma[i] * noise[i, :, n:]).float())
        assert torch.allclose(inp.timestep[i, 0, :n].flatten(), torch.tensor(1e-4))
        assert torch.allclose(inp.timestep[i, 0, n:].flatten(), torch.tensor(float(sigma[i])))


def test_conditioning_noise_reaches_every_context_frame():
    import torch

    from oscar_core.train.flow import flow_inputs

    z0, noise = _z()
    sc = torch.tensor([0.2, 0.2, 0.2], dtype=torch.float64)
    inp = flow_inputs(z0, noise, torch.full((3,), 0.5, dtype=torch.float64), 1e-4, sc, context=2)
    assert torch.allclose(inp.x[:, :, :2], 0.8 * z0[:, :, :2] + 0.2 * noise[:, :, :2])
    assert torch.allclose(inp.timestep[:, 0, :2].flatten(), torch.tensor(0.2))


def test_the_loss_averages_over_the_generated_frames_only():
    import torch

    from oscar_core.train.flow import flow_inputs, flow_loss

    z0, noise = _z()
    sigma = torch.full((3,), 0.5, dtype=torch.float64)
    inp = flow_inputs(z0, noise, sigma, context=[1, 2, 3])
    pred = inp.target.clone()
    pred[:, :, :3] += 100.0  # errors on context frames of some items only...
    pred[2, :, 3:] += 1.0  # ...and an error of 1 on every generated element of item 2
    per = flow_loss(pred, inp, reduction="none")
    assert per[1].item() > 1000  # item 1 (context 2) pays for frame 2
    assert per[2].item() == pytest.approx(1.0)  # mean over its 2 generated frames, not 4
    one = flow_inputs(z0, noise, sigma)  # the default: frame 0 alone, as before the option
    assert torch.equal(one.condition_mask, flow_inputs(z0, noise, sigma, context=[1, 1, 1]).condition_mask)
    assert flow_loss(one.target + 1.0, one).item() == pytest.approx(1.0)


def test_context_dropout_draws_per_item_and_one_latent_frame_needs_no_draw():
    from oscar_core.train.sampling import PlanItem, item_context

    items = [PlanItem(0, 0, False, 0.5, seed) for seed in range(400)]
    drawn = item_context(items, 2, 0.25)
    assert set(drawn) == {1, 2} and drawn == item_context(items, 2, 0.25)  # seeded per item
    assert 0.18 < drawn.count(1) / len(drawn) < 0.32
    assert item_context(items, 1, 0.25) == [1] * 400
    assert item_context(items, 2, 0.0) == [2] * 400


def test_training_feeds_the_model_the_context_mask(tmp_path):
    """One step of the loop's loss with model.context_frames 5 on 9-frame windows: the DiT's condition mask covers
    latent frames 0 and 1 of the items not dropped to one frame."""
    import torch
    from _models import tiny_train_config

    from oscar_core.train.data import Batch
    from oscar_core.train.loop import step_loss
    from oscar_core.train.sampling import PlanItem, item_context

    config = tiny_train_config(tmp_path, tmp_path / "run", **{"model.context_frames": 5, "flow.context_dropout": 0.5})
    seen = {}

    def model(**kw):
        seen.update(kw)
        return (torch.zeros_like(kw["hidden_states"]),)

    items = [PlanItem(0, 0, False, 0.5, seed) for seed in range(8)]
    batch = Batch(torch.randn(8, 16, 3, 4, 4), torch.randn(8, 16, 3, 4, 4), torch.zeros(8, 1, 48), None)
    step_loss(model, batch, items, config, "cpu")
    expect = item_context(items, 2, 0.5)
    assert set(expect) == {1, 2}
    assert seen["condition_mask"][:, 0, :, 0, 0].sum(1).tolist() == [float(n) for n in expect]


def test_the_config_refuses_a_bad_context_naming_the_field(tmp_path):
    from _models import tiny_train_config

    from oscar_core.train.config import TrainConfigError

    for value, what in ((3, "4k\\+1"), (9, "data.window 9's 3"), (13, "data.window 9's 3")):
        with pytest.raises(TrainConfigError, match=rf"field 'model.context_frames': expected .*{what}.* found {value}"):
            tiny_train_config(tmp_path, tmp_path / "run", **{"model.context_frames": value})
    with pytest.raises(TrainConfigError, match="field 'flow.context_dropout'"):
        tiny_train_config(tmp_path, tmp_path / "run", **{"model.context_frames": 5, "flow.context_dropout": 0.0})


# --------------------------------------------------------------------------- the sampler


def test_the_sampler_keeps_the_context_latents_bit_identical_at_every_step():
    import torch
    from _models import tiny_world_model

    from oscar_core.model import SamplerConfig, sample_chunk

    model = tiny_world_model(skeleton_scale=0.05, chunk_frames=9, empty_prompt=torch.zeros(1, 1, 48))
    g = torch.Generator().manual_seed(1)
    context = torch.randn(1, 16, 2, 4, 8, generator=g)
    skel = torch.randn(1, 16, 3, 4, 8, generator=g)
    inputs = []
    forward = model.transformer.forward

    def spy(*a, **kw):
        inputs.append((kw["hidden_states"].clone(), kw["condition_mask"].clone(), kw["timestep"].clone()))
        return forward(*a, **kw)

    model.transformer.forward = spy
    try:
        for solver in ("euler", "unipc"):
            inputs.clear()
            config = SamplerConfig(steps=3, guidance=2.0, solver=solver)
            out = sample_chunk(model.transformer, context, skel, model.prompt_embeds(), config, generator=g)
            assert torch.equal(out[:, :, :2], context)
            assert not torch.equal(out[:, :, 2], torch.zeros_like(out[:, :, 2]))
            assert len(inputs) == 3  # batched guidance: one forward of batch 2 per step
            for x, mask, t in inputs:
                assert torch.equal(x[:, :, :2], context.expand(2, -1, -1, -1, -1))  # fed clean, bit for bit
                assert mask[:, 0, :, 0, 0].tolist() == [[1.0, 1.0, 0.0]] * 2
                assert torch.all(t[:, 0, :2] == 1e-4) and torch.all(t[:, 0, 2] > 1e-4)
    finally:
        model.transformer.forward = forward


def test_the_sampler_refuses_a_context_as_long_as_the_chunk():
    import torch
    from _models import tiny_world_model

    from oscar_core.model import sample_chunk

    model = tiny_world_model(chunk_frames=9, empty_prompt=torch.zeros(1, 1, 48))
    with pytest.raises(ModelInputError, match=r"first_latent: expected shape .*1 <= n < 3"):
        sample_chunk(model.transformer, torch.zeros(1, 16, 3, 4, 8), torch.zeros(1, 16, 3, 4, 8), model.prompt_embeds())


# --------------------------------------------------------------------------- the rollout

H, W = 32, 64


def _clip(frames, seed=0):
    import numpy as np

    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (H, W, 3), dtype=np.uint8), rng.integers(0, 256, (frames, H, W, 3), dtype=np.uint8)


def _tiny(**card):
    import torch
    from _models import tiny_world_model

    return tiny_world_model(skeleton_scale=0.05, chunk_frames=9, empty_prompt=torch.zeros(1, 1, 48), **card)


def test_the_rollout_seeds_each_later_chunk_with_the_previous_chunks_last_5_decoded_frames():
    import numpy as np
    import torch

    from oscar_core.model import SamplerConfig
    from oscar_core.model.vae import VideoVAE

    model = _tiny(context_frames=5)
    first, skel = _clip(22)
    encoded = []
    encode = model.vae.encode

    def spy(pixels, *a, **kw):
        encoded.append(pixels.clone())
        return encode(pixels, *a, **kw)

    model.vae.encode = spy
    res = model.rollout(first, skel, sampler=SamplerConfig(steps=2, guidance=None), progress=False)
    assert res.starts == [0, 4, 8, 12, 16] and len(res.frames) == 22
    seeds = [e for e in encoded if e.shape[2] != 9]  # the chunks' condition videos are 9 frames long
    assert [tuple(e.shape[2:]) for e in seeds] == [(1, H, W)] + [(5, H, W)] * 4
    assert torch.equal(seeds[0], VideoVAE.to_pixels(first[None]))  # chunk 0: the first frame alone
    for c in range(1, 5):
        assert torch.equal(seeds[c], res.chunks[c - 1][:, :, -5:])  # the last 5 decoded (clamped) frames
        assert torch.equal(res.seeds[c], seeds[c])
    # what is emitted: chunk 0 whole, then each chunk's frames after its 5-frame context, cut at 22
    pieces = [VideoVAE.to_uint8(res.chunks[0])[0]] + [VideoVAE.to_uint8(ch[:, :, 5:])[0] for ch in res.chunks[1:]]
    assert np.array_equal(res.frames, np.concatenate(pieces)[:22])


@pytest.mark.parametrize("frames", [9, 10, 13, 14, 21])
def test_a_context_rollout_emits_the_frames_asked_for(frames):
    from oscar_core.model import SamplerConfig

    model = _tiny(context_frames=5)
    first, skel = _clip(frames)
    out = model.rollout(first, skel, sampler=SamplerConfig(steps=1, guidance=None), progress=False, keep_chunks=False)
    assert out.frames.shape == (frames, H, W, 3)
    assert out.starts == chunk_plan(frames, 9, context_frames=5)
    batch = model.rollout_batch([first, first], [skel, skel], sampler=SamplerConfig(steps=1, guidance=None))
    assert [b.shape for b in batch] == [(frames, H, W, 3)] * 2


def _one_frame_rollout_by_hand(model, first, skel, sampler, seed=0):
    """The rollout before the context option, written out plainly: chunks every 8 frames, each seeded by the last
    decoded frame of the one before, the first kept whole and the others without their seed frame."""
    import numpy as np
    import torch

    from oscar_core.model import sample_chunk
    from oscar_core.model.vae import VideoVAE

    L, total = 9, len(skel)
    starts = list(range(0, total - 1, L - 1))
    padded = np.concatenate([skel, np.repeat(skel[-1:], starts[-1] + L - total, axis=0)])
    g = torch.Generator().manual_seed(seed)
    seed_px, pieces = VideoVAE.to_pixels(first[None]), []
    for i, s in enumerate(starts):
        latent = sample_chunk(
            model.transformer,
            model.vae.encode(seed_px),
            model.vae.encode(VideoVAE.to_pixels(padded[s : s + L])),
            model.prompt_embeds(),
            sampler,
            generator=g,
        )
        video = model.vae.decode(latent).clamp(-1, 1)
        pieces.append(VideoVAE.to_uint8(video if i == 0 else video[:, :, 1:])[0])
        seed_px = video[:, :, -1:]
    return np.concatenate(pieces)[:total]


def test_a_card_without_the_field_rolls_out_bit_identical_to_the_one_frame_rollout_by_hand():
    import numpy as np

    from oscar_core.model import SamplerConfig

    model = _tiny()
    assert model.card.context_frames == 1
    sampler = SamplerConfig(steps=2, guidance=None, solver="euler")
    for frames in (9, 20):
        first, skel = _clip(frames, seed=frames)
        out = model.rollout(first, skel, sampler=sampler, progress=False).frames
        assert np.array_equal(out, _one_frame_rollout_by_hand(model, first, skel, sampler))


# --------------------------------------------------------------------------- the benchmarks and the closed loop

CARD64 = dict(name="tiny-ctx5", chunk_frames=17, width=64, height=64, context_frames=5)


@pytest.mark.filterwarnings("ignore:no prompt embedding")
def test_the_action_following_benchmark_rolls_out_and_reconstructs_with_the_cards_context(tmp_path, monkeypatch):
    """A context-5 model goes through the benchmark: its variants are rolled out with the context (33 frames asked,
    33 scored) and the ceiling is asked for the context's chunk plan."""
    from _models import tiny_world_model

    import oscar_core.evaluation.action_following_ceiling as ceiling_module
    from oscar_core.evaluation.action_following import ActionFollowingSettings, run_action_following
    from oscar_core.metrics.programmatic import ProgrammaticJudge
    from oscar_core.model import SamplerConfig
    from oscar_core.toyworld.counterfactual import write_counterfactual_sets
    from oscar_core.toyworld.judge import ball_moved

    sets = write_counterfactual_sets(tmp_path / "sets", ["toyarm"], 1, seed=0, frames=33)
    model = tiny_world_model(**CARD64)
    judge = ProgrammaticJudge(ball_moved)
    calls = []
    rollout_batch = model.rollout_batch

    def spy(*a, **kw):
        out = rollout_batch(*a, **kw)
        calls.append([v.shape for v in out])
        return out

    model.rollout_batch = spy
    fast = SamplerConfig(steps=1, guidance=None)
    settings = ActionFollowingSettings(sampler=fast, resamples=50, progress=False)
    rep = run_action_following(sets, tmp_path / "af", judge=judge, model=model, settings=settings).report
    assert calls and all(shape == (33, 64, 64, 3) for shape in calls[0])
    assert [len(v["chunks"]) for v in rep["records"][0]["variants"]] == [2] * len(rep["records"][0]["variants"])
    asked = []

    def reconstruct(vae, truths, chunk_frames, context_frames=1):
        asked.append((chunk_frames, context_frames))
        return truths

    monkeypatch.setattr(ceiling_module, "reconstruct_variants", reconstruct)
    ceiling = ActionFollowingSettings(ceiling=True, resamples=50, progress=False)
    run_action_following(sets, tmp_path / "ceiling", judge=judge, model=model, settings=ceiling)
    assert asked == [(17, 5)]


def test_the_ceiling_reconstructs_in_the_contexts_chunk_plan():
    import numpy as np

    from oscar_core.model.rollout import reconstruct_rollout
    from oscar_core.model.vae import VideoVAE

    model = _tiny(context_frames=5)
    _, video = _clip(13)
    got = reconstruct_rollout(model.vae, video, chunk_frames=9, context_frames=5)
    by_hand = []  # chunks at 0 and 4: the first whole, the second after its 5 context frames
    for i, s in enumerate((0, 4)):
        rec = VideoVAE.to_uint8(model.vae.decode(model.vae.encode(VideoVAE.to_pixels(video[s : s + 9]))).clamp(-1, 1))[
            0
        ]
        by_hand.append(rec if i == 0 else rec[5:])
    assert np.array_equal(got, np.concatenate(by_hand)[:13])
    assert not np.array_equal(got, reconstruct_rollout(model.vae, video, chunk_frames=9))


def test_the_closed_loop_refuses_a_context_model_before_any_cell(tmp_path, capsys):
    from _models import export_tiny_world_model

    from oscar_core.cli import main
    from oscar_core.toyworld.closed_loop import write_closed_loop_sessions

    manifest = write_closed_loop_sessions(tmp_path / "sessions", ["toyarm"], 1, seed=3, horizon=17, policies=["exact"])
    folder = export_tiny_world_model(tmp_path / "model", **CARD64)
    out = tmp_path / "out"
    code = main(
        ["eval", "closed-loop", str(manifest), "--model", str(folder), "--out", str(out), "--no-progress", "-v"]
    )
    err = capsys.readouterr().err
    assert code == 2, err
    errors = [x for x in err.splitlines() if x.startswith("error:")]
    assert len(errors) == 1 and "context_frames" in errors[0] and "expected 1" in errors[0] and "found 5" in errors[0]
    assert "loading world model" not in err and not (out / "cells").exists()  # refused from the card alone


def test_the_gymnasium_env_and_the_model_world_refuse_a_context_model(tmp_path):
    from _models import tiny_world_model

    from oscar_core.envs.closed_loop_env import ClosedLoopEnv
    from oscar_core.evaluation.closed_loop_cell import ModelWorld
    from oscar_core.metrics.common import MetricInputError
    from oscar_core.toyworld.closed_loop import write_closed_loop_sessions

    manifest = write_closed_loop_sessions(tmp_path / "sessions", ["toyarm"], 1, seed=3, horizon=17, policies=["exact"])
    model = tiny_world_model(**CARD64)
    with pytest.raises(MetricInputError, match="model card: field 'context_frames': expected 1 .* found 5"):
        ClosedLoopEnv(manifest, model=model)
    with pytest.raises(MetricInputError, match="context_frames"):
        ModelWorld(model, first=None, camera=None, camera_source="", emb=None, q0=[0.0], g0=[0.0], fps=10.0,
                   chunk_frames=17, size=(64, 64), prompt=None, sampler=None, seed=0)  # fmt: skip


@pytest.mark.filterwarnings("ignore:no prompt embedding")
def test_a_tiny_context_training_exports_its_card_and_the_export_rolls_out_in_two_chunks(tmp_path):
    import json as _json

    import numpy as np
    from _models import tiny_clipset, tiny_train_config

    import oscar_zoo
    from oscar_core.model import SamplerConfig
    from oscar_core.train.loop import train

    clips = tiny_clipset(tmp_path / "clips", clips=2)
    config = tiny_train_config(clips, tmp_path / "run", **{"model.context_frames": 5, "steps": 2, "export": True})
    result = train(config, progress=False)
    lines = [_json.loads(x) for x in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert all("context_one_frame" in x for x in lines if "loss" in x)
    model = oscar_zoo.load(result.export)
    assert model.card.context_frames == 5
    first, skel = np.zeros((32, 32, 3), np.uint8), np.zeros((13, 32, 32, 3), np.uint8)
    out = model.rollout(first, skel, sampler=SamplerConfig(steps=1, guidance=None), progress=False)
    assert out.starts == [0, 4] and out.frames.shape == (13, 32, 32, 3)
