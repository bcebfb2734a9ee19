"""Samplers against answers known in advance: an exact ODE solution, pinned timesteps, step direction,
the first-frame velocity replacement, one-branch guidance, the unconditional skeleton, chunk alignment."""

import numpy as np
import pytest
import torch
from _models import tiny_world_model

from oscar_core.model import (
    ModelCard,
    OscarWorldModel,
    SamplerConfig,
    flow_sigmas,
    sample_chunk,
    sampler as sampler_mod,
)
from oscar_core.model.rollout import iter_rollout, rollout
from oscar_core.model.sampler import branches, integrate, unipc_scheduler

# --------------------------------------------------------------------------- an exact solution
#
# Data z_0 ~ N(mu, s^2) per element, noise eps ~ N(0, 1), z_sigma = (1 - sigma) z_0 + sigma eps. The
# marginal of z_sigma is N((1 - sigma) mu, a(sigma)) with a = (1 - sigma)^2 s^2 + sigma^2, and the flow
# that transports it is the monotone map z_sigma = (1 - sigma) mu + sqrt(a(sigma)) eps. Its velocity,
# written as a function of z, is linear in z:
#     v(z, sigma) = -mu + (sigma - (1 - sigma) s^2) / a(sigma) * (z - (1 - sigma) mu),
# and integrating from sigma = 1 (z = eps) to 0 must give exactly z_0 = mu + s eps.


def _gaussian_problem(seed=0):
    g = torch.Generator().manual_seed(seed)
    mu = torch.randn(2, 2048, generator=g) * 2
    s = torch.rand(2, 2048, generator=g) + 0.5
    eps = torch.randn(2, 2048, generator=g)

    def velocity(z, sigma):
        a = (1 - sigma) ** 2 * s**2 + sigma**2
        return -mu + (sigma - (1 - sigma) * s**2) / a * (z - (1 - sigma) * mu)

    return velocity, eps, mu + s * eps


def _error(solver, steps):
    velocity, eps, exact = _gaussian_problem()
    out = integrate(velocity, eps.clone(), SamplerConfig(steps=steps, solver=solver, guidance=None))
    return float((out - exact).abs().max())


def test_unipc_recovers_the_exact_solution_to_second_order():
    e35, e70 = _error("unipc", 35), _error("unipc", 70)
    assert e35 < 0.05 and e70 < 0.01  # measured here: 0.036 and 0.0077 (max over 4096 elements)
    assert e35 / e70 > 3.5  # halving the step divides the error by ~4: second order


def test_euler_recovers_the_exact_solution_to_first_order():
    e35, e70 = _error("euler", 35), _error("euler", 70)
    assert e35 < 0.35 and e70 < 0.18  # measured here: 0.281 and 0.143
    assert 1.7 < e35 / e70 < 2.3  # first order
    assert _error("unipc", 35) < e35 / 5  # and UniPC is far closer for the same number of model calls


def test_default_unipc_is_oscars_flow_solver_with_shift():
    from oscar_core.model.unipc import FlowUniPC

    sched = unipc_scheduler(SamplerConfig(shift=5.0))
    assert isinstance(sched, FlowUniPC) and sched.shift == 5.0 and sched.order == 2 and sched.variant == "bh2"
    sched.set_timesteps(4)
    s = np.linspace(1, 1 / 1000, 5)[:-1]
    expected = 5 * s / (1 + 4 * s)
    expected[0] -= 1e-6
    np.testing.assert_allclose(sched.sigmas.numpy(), np.r_[expected, 0.0], rtol=1e-6)


# --------------------------------------------------------------------------- spies


class _Spy(torch.nn.Module):
    """Stands in for the DiT: returns ``fn(hidden_states, skeleton_latents)``; records every call."""

    def __init__(self, fn=None):
        super().__init__()
        self.anchor = torch.nn.Parameter(torch.zeros(1))
        self.fn = fn or (lambda x, s: torch.zeros_like(x))
        self.calls = []
        self.config = type("Cfg", (), {"patch_size": (1, 2, 2)})()

    @property
    def dtype(self):
        return torch.float32

    def project_text(self, text):
        return text

    def forward(
        self,
        hidden_states,
        timestep,
        encoder_hidden_states,
        condition_mask,
        padding_mask,
        fps,
        skeleton_latents,
        return_dict,
        text_projected=False,
    ):
        self.calls.append(dict(x=hidden_states.clone(), t=timestep.clone(), s=skeleton_latents.clone()))
        return (self.fn(hidden_states, skeleton_latents),)


def _chunk(spy, config, seed=0, t=3):
    g = torch.Generator().manual_seed(100)
    first = torch.randn(1, 4, 1, 2, 2, generator=g)
    skel = torch.randn(1, 4, t, 2, 2, generator=g)
    out = sample_chunk(spy, first, skel, torch.zeros(1, 1, 8), config, generator=torch.Generator().manual_seed(seed))
    noise = torch.randn((1, 4, t, 2, 2), generator=torch.Generator().manual_seed(seed))
    return out, first, skel, noise


@pytest.mark.parametrize("solver", ["euler", "unipc"])
def test_the_model_receives_sigma_itself_and_a_tiny_timestep_on_the_seed_frame(solver):
    spy = _Spy()
    config = SamplerConfig(steps=5, solver=solver, guidance=None)
    _chunk(spy, config)
    if solver == "euler":
        expected = flow_sigmas(5, 5.0)[:-1].tolist()
    else:
        sched = unipc_scheduler(config)
        sched.set_timesteps(5)
        expected = sched.sigmas[:-1].tolist()
    assert len(spy.calls) == 5
    for call, sigma in zip(spy.calls, expected):
        t = call["t"]
        assert t.shape == (1, 1, 3, 1, 1)
        torch.testing.assert_close(t[:, :, 1:], torch.full_like(t[:, :, 1:], sigma))  # sigma, not 1000 sigma
        assert torch.all(t[:, :, 0] == 1e-4)
    assert 0.99 < expected[0] <= 1.0 and all(a > b for a, b in zip(expected, expected[1:]))


@pytest.mark.parametrize("solver", ["euler", "unipc"])
def test_steps_go_from_noise_towards_data_along_the_velocity(solver):
    # a constant velocity c: z_sigma = z_0 + sigma c, so from z_1 = noise the end is noise - c, exactly
    c = torch.full((1, 4, 3, 2, 2), 0.75)
    spy = _Spy(lambda x, s: c.expand_as(x))
    out, first, _, noise = _chunk(spy, SamplerConfig(steps=6, solver=solver, guidance=None))
    torch.testing.assert_close(out[:, :, 1:], (noise - c)[:, :, 1:], rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(out[:, :, :1], first)


@pytest.mark.parametrize("solver", ["euler", "unipc"])
def test_the_seed_frame_follows_the_true_velocity_whatever_the_model_says(solver, monkeypatch):
    seen = {}
    real = sampler_mod.integrate

    def keep(velocity, x, config, progress=None):
        out = real(velocity, x, config, progress)
        seen["end"] = out.clone()  # before sample_chunk overwrites frame 0
        return out

    monkeypatch.setattr(sampler_mod, "integrate", keep)
    spy = _Spy(lambda x, s: torch.full_like(x, 1000.0))  # nonsense on every frame, frame 0 included
    _, first, _, _ = _chunk(spy, SamplerConfig(steps=6, solver=solver, guidance=None))
    # with v = eps - z_0 on frame 0 the path is the straight line from eps to z_0
    torch.testing.assert_close(seen["end"][:, :, :1], first, rtol=2e-3, atol=2e-3)


def test_guidance_runs_one_branch_when_the_formula_reduces_to_one():
    assert SamplerConfig().guidance_form == "diffusers"  # the default (docs/world-model.md says why)
    assert branches(SamplerConfig(guidance=1.0, guidance_form="standard")) == ("cond",)
    assert branches(SamplerConfig(guidance=0.0, guidance_form="standard")) == ("uncond",)
    assert branches(SamplerConfig(guidance=0.0, guidance_form="diffusers")) == ("cond",)
    assert branches(SamplerConfig(guidance=1.0, guidance_form="diffusers")) == ("cond", "uncond")
    assert branches(SamplerConfig(guidance=None)) == ("cond",)
    for config, uses_skeleton in (
        (SamplerConfig(steps=2, guidance=1.0, guidance_form="standard"), True),
        (SamplerConfig(steps=2, guidance=0.0, guidance_form="standard"), False),
        (SamplerConfig(steps=2, guidance=0.0, guidance_form="diffusers"), True),
    ):
        spy = _Spy()
        _, _, skel, _ = _chunk(spy, config)
        assert len(spy.calls) == 2 and all(c["x"].shape[0] == 1 for c in spy.calls)
        assert all(torch.equal(c["s"], skel) == uses_skeleton for c in spy.calls)


def test_unconditional_branch_uses_the_given_skeleton_latent():
    spy = _Spy()
    g = torch.Generator().manual_seed(1)
    first, skel = torch.randn(1, 4, 1, 2, 2, generator=g), torch.randn(1, 4, 3, 2, 2, generator=g)
    uncond = torch.full((1, 4, 3, 2, 2), -3.0)
    sample_chunk(spy, first, skel, torch.zeros(1, 1, 8), SamplerConfig(steps=2, guidance=6.0), uncond_skeleton=uncond)
    both = spy.calls[0]["s"]
    assert both.shape[0] == 2 and torch.equal(both[:1], skel) and torch.equal(both[1:], uncond)


# --------------------------------------------------------------------------- rollouts with a transparent VAE


class _IndexVAE:
    """A 'VAE' whose latent frame k is pixel frame 4k (so a latent says which frame it came from).

    encode: (B, 3, T, H, W) in [-1, 1] → (B, 4, (T-1)/4+1, H/8, W/8), every value = the pixel frame's
    channel-0 mean; decode repeats each latent frame four times (frame 0 once).
    """

    temporal, spatial, z_dim = 4, 8, 4

    def __init__(self):
        self.encoded = []

    def encode(self, pixels):
        b, _, t, h, w = pixels.shape
        frames = pixels[:, 0, ::4].mean(dim=(-1, -2))  # (B, T')
        self.encoded.append(t)
        return frames[:, None, :, None, None].expand(b, 4, frames.shape[1], h // 8, w // 8).clone()

    def encode_condition(self, pixels):
        """The condition's path: a VideoVAE without a tiny encoder encodes conditions with ``encode``."""
        return self.encode(pixels)

    def decode(self, latents):
        b, _, t, h, w = latents.shape
        v = latents[:, :1]
        frames = torch.cat([v[:, :, :1]] + [v[:, :, k : k + 1].expand(b, 1, 4, h, w) for k in range(1, t)], dim=2)
        return frames.expand(b, 3, frames.shape[2], h, w).repeat_interleave(8, -1).repeat_interleave(8, -2).clone()


def _index_video(n, h=16, w=16):
    """(n, h, w, 3) uint8 skeleton video whose frame i has every pixel = 2i (encodes its index)."""
    return np.repeat((2 * np.arange(n, dtype=np.uint8))[:, None, None, None], h * w * 3, axis=1).reshape(n, h, w, 3)


def _decode_index(latent_value):
    return int(round((float(latent_value) + 1.0) * 127.5 / 2))


def test_each_chunk_is_conditioned_on_its_own_skeleton_frames():
    spy = _Spy(lambda x, s: torch.zeros_like(x))
    vae = _IndexVAE()
    total, chunk = 23, 9  # chunks start at 0, 8, 16; the last runs past the end and is padded
    skel = _index_video(total)
    result = rollout(
        spy,
        vae,
        skel[0],
        skel,
        torch.zeros(1, 1, 8),
        chunk_frames=chunk,
        sampler=SamplerConfig(steps=1, solver="euler", guidance=None),
        progress=False,
    )
    assert result.starts == [0, 8, 16] and len(result.frames) == total
    seen = [c["s"] for c in spy.calls]  # one call per chunk (1 step, one branch)
    for start, s in zip(result.starts, seen):
        indices = [_decode_index(s[0, 0, k, 0, 0]) for k in range(s.shape[2])]
        assert indices == [min(start + 4 * k, total - 1) for k in range(s.shape[2])], (start, indices)


@pytest.mark.parametrize("kind", ["zero_latent", "black_video"])
def test_unconditional_skeleton_kinds_and_black_video_cached_per_chunk_size(kind):
    spy = _Spy()
    vae = _IndexVAE()
    skel = _index_video(23)
    list(
        iter_rollout(
            spy,
            vae,
            skel[0],
            skel,
            torch.zeros(1, 1, 8),
            chunk_frames=9,
            progress=False,
            sampler=SamplerConfig(steps=1, solver="euler", guidance=6.0),
            uncond_skeleton=kind,
        )
    )
    uncond = [c["s"][1:] for c in spy.calls]
    expected = 0.0 if kind == "zero_latent" else -1.0  # black pixels are -1 and this VAE keeps values
    assert all(torch.all(u == expected) for u in uncond)
    black_encodes = sum(1 for t in vae.encoded if t == 9) - 3  # 3 chunks encode their skeleton (9 frames) each
    assert black_encodes == (0 if kind == "zero_latent" else 1)


def test_model_rollout_reads_the_unconditional_skeleton_from_the_card(monkeypatch):
    from oscar_core.model import rollout as rollout_mod

    seen = {}
    monkeypatch.setattr(rollout_mod, "rollout", lambda *a, **kw: seen.update(kw) or "ok")
    model = OscarWorldModel.__new__(OscarWorldModel)
    model.card = ModelCard(chunk_frames=9, unconditional_skeleton="black_video")
    model.scheduler_config = {"_class_name": "FlowMatchEulerDiscreteScheduler"}
    model.transformer, model.vae, model.empty_prompt = type("T", (), {"text_dim": 8})(), None, torch.zeros(1, 1, 8)
    model.rollout(np.zeros((16, 16, 3), np.uint8), _index_video(9), progress=False)
    assert seen["uncond_skeleton"] == "black_video" and seen["sampler"].solver == "euler"
    model.scheduler_config = {
        "_class_name": "UniPCMultistepScheduler",
        "use_flow_sigmas": True,
        "flow_shift": 3.0,
        "prediction_type": "flow_prediction",
    }
    model.rollout(np.zeros((16, 16, 3), np.uint8), _index_video(9), progress=False)
    assert seen["sampler"].solver == "unipc" and seen["sampler"].scheduler_config["flow_shift"] == 3.0
    model.rollout(
        np.zeros((16, 16, 3), np.uint8), _index_video(9), progress=False, sampler=SamplerConfig(solver="euler")
    )
    assert seen["sampler"].solver == "euler"  # the option beats the checkpoint


def test_streamed_frames_are_uint8_and_equal_the_collected_rollout():
    spy = _Spy(lambda x, s: 0.1 * x)
    skel = _index_video(23)
    args = (spy, _IndexVAE(), skel[0], skel, torch.zeros(1, 1, 8))
    kw = dict(chunk_frames=9, sampler=SamplerConfig(steps=2, guidance=None), progress=False, seed=4)
    pieces = list(iter_rollout(*args, **kw))
    assert [len(p) for p in pieces] == [9, 8, 6] and all(p.dtype == np.uint8 for p in pieces)
    np.testing.assert_array_equal(np.concatenate(pieces), rollout(*args, **kw).frames)


def test_the_next_seed_is_clamped_before_it_is_re_encoded():
    class LoudVAE(_IndexVAE):
        def __init__(self):
            super().__init__()
            self.seeds = []

        def encode(self, pixels):
            if pixels.shape[2] == 1:
                self.seeds.append(float(pixels.max()))
            return super().encode(pixels)

        def decode(self, latents):
            return super().decode(latents) + 5.0  # far outside [-1, 1]

    vae = LoudVAE()
    skel = _index_video(17)
    frames = rollout(
        _Spy(),
        vae,
        skel[0],
        skel,
        torch.zeros(1, 1, 8),
        chunk_frames=9,
        progress=False,
        sampler=SamplerConfig(steps=1, guidance=None),
    ).frames
    assert len(vae.seeds) == 2 and vae.seeds[1] <= 1.0  # chunk 1's seed: the clamped last frame of chunk 0
    assert frames.dtype == np.uint8 and frames[1:].min() == 255


# --------------------------------------------------------------------------- #
# guidance interval and presets
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("solver", ["euler", "unipc"])
def test_guidance_interval_guides_exactly_the_steps_inside_it(solver):
    from oscar_core.model.sampler import model_calls, step_sigmas

    lo, hi = 0.3, 0.9
    config = SamplerConfig(steps=8, solver=solver, guidance=3.0, guidance_interval=(lo, hi))
    spy = _Spy(lambda x, s: 0.1 * x + s)  # depends on the skeleton, so the branches differ
    _, _, skel, _ = _chunk(spy, config)
    sigmas = step_sigmas(config)
    # batched guidance is one call of batch 2 (cond then uncond); an unguided step one call of batch 1 (cond)
    batch = [c["x"].shape[0] for c in spy.calls]
    assert len(batch) == 8 and batch == [2 if lo <= s <= hi else 1 for s in sigmas]
    assert 0 < batch.count(2) < 8  # the interval cuts this schedule
    for call, sigma in zip(spy.calls, sigmas):
        torch.testing.assert_close(call["t"][:, :, 1:], torch.full_like(call["t"][:, :, 1:], sigma))
        assert torch.equal(call["s"][:1], skel)  # the first item is always the conditional branch
    assert model_calls(config) == sum(batch)
    assert model_calls(SamplerConfig(steps=8, solver=solver, guidance=3.0)) == 16
    assert model_calls(SamplerConfig(steps=8, solver=solver, guidance=None)) == 8


def test_guidance_interval_covering_all_or_no_steps_equals_full_or_no_guidance():
    fn = lambda x, s: 0.1 * x + s  # noqa: E731
    full, _, _, _ = _chunk(_Spy(fn), SamplerConfig(steps=5, guidance=3.0))
    every, _, _, _ = _chunk(_Spy(fn), SamplerConfig(steps=5, guidance=3.0, guidance_interval=(0.0, 1.0)))
    cond, _, _, _ = _chunk(_Spy(fn), SamplerConfig(steps=5, guidance=None))
    never, _, _, _ = _chunk(_Spy(fn), SamplerConfig(steps=5, guidance=3.0, guidance_interval=(0.0, 0.0)))
    assert torch.equal(full, every) and torch.equal(cond, never) and not torch.equal(full, cond)


@pytest.mark.parametrize(
    "bad", [(0.5, 0.2), (-0.1, 0.5), (0.2, 1.5), (0.1,), "0.1,0.9", (float("nan"), 1.0), (True, 1.0)]
)
def test_guidance_interval_refuses_what_is_not_an_interval_of_noise_levels(bad):
    from oscar_core.model import ModelInputError

    with pytest.raises(ModelInputError, match="guidance_interval: expected"):
        SamplerConfig(guidance_interval=bad)


def test_presets_set_steps_and_interval_and_keep_the_rest():
    from oscar_core.model import ModelInputError
    from oscar_core.model.sampler import SAMPLER_PRESETS, apply_preset

    base = SamplerConfig(guidance=3.0, shift=4.0)
    assert apply_preset(base, None) is base
    paper = apply_preset(base, "paper")
    assert (paper.steps, paper.guidance_interval, paper.guidance, paper.shift) == (35, None, 3.0, 4.0)
    fast = apply_preset(base, "fast")
    assert (fast.steps, fast.guidance_interval) == (
        SAMPLER_PRESETS["fast"]["steps"],
        SAMPLER_PRESETS["fast"]["guidance_interval"],
    )
    with pytest.raises(ModelInputError, match="sampler preset: expected one of"):
        apply_preset(base, "turbo")


# --------------------------------------------------------------------------- #
# batched rollouts
# --------------------------------------------------------------------------- #
def test_per_item_generators_draw_what_each_item_draws_alone():
    fn = lambda x, s: 0.1 * x + s  # noqa: E731
    g = torch.Generator().manual_seed(100)
    first = torch.randn(3, 4, 1, 2, 2, generator=g)
    skel = torch.randn(3, 4, 3, 2, 2, generator=g)
    config = SamplerConfig(steps=4, guidance=3.0)
    batch = sample_chunk(
        _Spy(fn),
        first,
        skel,
        torch.zeros(1, 1, 8),
        config,
        generators=[torch.Generator().manual_seed(s) for s in (7, 8, 9)],
    )
    for i, s in enumerate((7, 8, 9)):
        alone = sample_chunk(
            _Spy(fn),
            first[i : i + 1],
            skel[i : i + 1],
            torch.zeros(1, 1, 8),
            config,
            generator=torch.Generator().manual_seed(s),
        )
        torch.testing.assert_close(batch[i : i + 1], alone, rtol=1e-5, atol=1e-5)
    with pytest.raises(Exception, match="generators: expected one per batch item"):
        sample_chunk(_Spy(fn), first, skel, torch.zeros(1, 1, 8), config, generators=[torch.Generator()])


def test_rollout_batch_equals_one_at_a_time():

    model = tiny_world_model(skeleton_scale=0.05, name="t", chunk_frames=5, fps=15.0)
    rng = np.random.default_rng(0)
    firsts = [rng.integers(0, 255, (16, 32, 3), dtype=np.uint8) for _ in range(3)]
    skels = [rng.integers(0, 255, (11, 16, 32, 3), dtype=np.uint8) for _ in range(3)]  # 3 chunks, the last padded
    prompt = torch.randn(1, 4, model.transformer.text_dim, generator=torch.Generator().manual_seed(1))
    config = SamplerConfig(steps=3, guidance=2.0)
    alone = [
        model.rollout(f, s, prompt, sampler=config, seed=10 + k, progress=False).frames
        for k, (f, s) in enumerate(zip(firsts, skels))
    ]
    batch = model.rollout_batch(firsts, skels, [prompt] * 3, sampler=config, seeds=[10, 11, 12])
    for a, b in zip(alone, batch):
        assert a.shape == b.shape == (11, 16, 32, 3)
        diff = np.abs(a.astype(int) - b.astype(int))
        assert diff.max() <= 1 and (diff == 0).mean() > 0.99  # float rounding of batched matmuls, nothing more
    assert not np.array_equal(batch[0], batch[1])  # each item its own inputs and noise
    with pytest.raises(Exception, match="one length and size"):
        model.rollout_batch(firsts[:2], [skels[0], skels[1][:9]], sampler=config)


@pytest.mark.parametrize("solver", ["euler", "unipc"])
def test_a_noised_conditioning_frame_is_fed_at_its_level_and_returned_clean(solver):
    """SamplerConfig.cond_noise: every call sees frame 0 as (1 - s) first + s noise[0] at timestep s; the frames
    after it start from the same noise as without it; the returned frame 0 is the clean seed latent."""
    spy, plain_spy = _Spy(), _Spy()
    out, first, _, noise = _chunk(spy, SamplerConfig(steps=4, solver=solver, guidance=None, cond_noise=0.3))
    plain, *_ = _chunk(plain_spy, SamplerConfig(steps=4, solver=solver, guidance=None))
    want = 0.7 * first + 0.3 * noise[:, :, :1]
    for call, base in zip(spy.calls, plain_spy.calls):
        torch.testing.assert_close(call["x"][:, :, :1], want)
        assert torch.all(call["t"][:, :, 0] == 0.3)
        assert torch.equal(call["x"][:, :, 1:], base["x"][:, :, 1:]) and torch.equal(
            call["t"][:, :, 1:], base["t"][:, :, 1:]
        )
    assert torch.equal(out[:, :, :1], first) and torch.equal(out, plain)  # a zero-velocity model ignores frame 0
    for bad in (1.0, -0.1, float("nan")):
        with pytest.raises(ValueError, match="cond_noise"):
            SamplerConfig(cond_noise=bad)
