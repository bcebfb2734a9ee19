"""oscar's UniPC flow solver (oscar_core.model.unipc) against diffusers' ``UniPCMultistepScheduler``, the reference it
was written to reproduce (installed with oscar; imported here, never by the solver): the schedule, every state of a
trajectory on known velocity fields, which scheduler configs take which path, the toy model's chunk, and what the
solver does where diffusers' class fails (a NaN last step with bh1, a long schedule)."""

import subprocess
import sys

import pytest
import torch
from diffusers import UniPCMultistepScheduler

from oscar_core.model import ModelInputError, SamplerConfig, sample_chunk, sampler as sampler_mod
from oscar_core.model.unipc import FlowUniPC, flow_schedule, solver_for_config

STEPS = (1, 2, 3, 4, 10, 20, 35)
SHIFTS = (1.0, 3.0, 5.0)
FLOW = {"use_flow_sigmas": True, "prediction_type": "flow_prediction"}


def _linear(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """A linear velocity field: v = x A + σ b on the last axis (6 wide)."""
    g = torch.Generator().manual_seed(11)
    a = torch.randn(6, 6, generator=g, dtype=torch.float64) * 0.4
    b = torch.randn(6, generator=g, dtype=torch.float64)
    return x @ a.to(x.dtype) + sigma * b.to(x.dtype)


def _mlp(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """A random two-layer MLP of (x, σ) on the last axis (6 → 16 → 6)."""
    g = torch.Generator().manual_seed(12)
    w1, w2 = (torch.randn(*s, generator=g, dtype=torch.float64) / 2 for s in ((7, 16), (16, 6)))
    inputs = torch.cat([x, torch.full_like(x[..., :1], sigma)], dim=-1)
    return torch.tanh(inputs @ w1.to(x.dtype)) @ w2.to(x.dtype)


FIELDS = {"linear": _linear, "mlp": _mlp}


def _trajectory(solver, steps: int, field, dtype=torch.float32) -> list[torch.Tensor]:
    """Every state (after each step) of integrating ``field`` from seeded noise (2, 3, 6) with ``solver``
    (diffusers' class or ours), feeding the field the schedule's float32 level as oscar's sampler does."""
    solver.set_timesteps(steps)
    x = torch.randn(2, 3, 6, generator=torch.Generator().manual_seed(5), dtype=dtype)
    states = []
    for i, t in enumerate(solver.timesteps):
        v = field(x, float(solver.sigmas[i]))
        x = solver.step(v, x) if isinstance(solver, FlowUniPC) else solver.step(v, t, x, return_dict=False)[0]
        states.append(x)
    return states


def _relative_error(ours: torch.Tensor, reference: torch.Tensor) -> float:
    return float((ours - reference).abs().max() / reference.abs().max().clamp_min(1e-30))


@pytest.mark.parametrize("final", ["zero", "sigma_min"])
@pytest.mark.parametrize("shift", SHIFTS)
@pytest.mark.parametrize("steps", STEPS)
def test_the_schedule_is_diffusers_exactly(steps, shift, final):
    reference = UniPCMultistepScheduler(**FLOW, flow_shift=shift, final_sigmas_type=final)
    reference.set_timesteps(steps)
    sigmas, timesteps = flow_schedule(steps, shift, final_sigma=final)
    assert sigmas.dtype == torch.float32 and torch.equal(sigmas, reference.sigmas)
    assert torch.equal(timesteps, reference.timesteps)
    assert sigmas[0] < 1.0 and (sigmas[-1] == 0.0) == (final == "zero")


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("shift", SHIFTS)
@pytest.mark.parametrize("steps", STEPS)
@pytest.mark.parametrize("field", sorted(FIELDS))
def test_every_state_equals_diffusers_default_flow_unipc(field, steps, shift, dtype):
    reference = _trajectory(UniPCMultistepScheduler(**FLOW, flow_shift=shift), steps, FIELDS[field], dtype)
    ours = _trajectory(FlowUniPC(shift=shift), steps, FIELDS[field], dtype)
    assert len(ours) == len(reference) == steps
    for i, (a, b) in enumerate(zip(ours, reference)):
        assert a.dtype == b.dtype == dtype and bool(torch.isfinite(a).all())
        assert _relative_error(a, b) <= 1e-6, f"step {i}: {_relative_error(a, b):.3g}"
    # the same float32 coefficients in the same order: diffusers 0.42's states to the bit (measured here)
    assert all(torch.equal(a, b) for a, b in zip(ours, reference))


#: the Karras flow sigmas of NVIDIA's Cosmos checkpoints' diffusers conversions (sigma_min 0.01 or 0.147)
KARRAS = {"use_karras_sigmas": True, "sigma_max": 200.0, "sigma_min": 0.01}


@pytest.mark.parametrize("low", [0.01, 0.147])
@pytest.mark.parametrize("steps", [1, 2, 4, 10, 35])
def test_karras_flow_sigmas_equal_diffusers(steps, low):
    config = {**FLOW, **KARRAS, "sigma_min": low}
    ours, reference = solver_for_config(config), UniPCMultistepScheduler.from_config(config)
    assert isinstance(ours, FlowUniPC) and ours.karras == (low, 200.0)
    for field in FIELDS.values():
        for a, b in zip(_trajectory(ours, steps, field), _trajectory(reference, steps, field), strict=True):
            assert torch.equal(a, b)
    assert torch.equal(ours.sigmas, reference.sigmas) and torch.equal(ours.timesteps, reference.timesteps)
    assert ours.timesteps[0] == 995  # 1000 * 200 / 201


@pytest.mark.parametrize(
    "settings",
    [
        {"solver_order": 1},
        {"solver_order": 3},
        {"disable_corrector": [0, 3]},
        {"final_sigmas_type": "sigma_min"},
        {"num_train_timesteps": 500},
        {"solver_type": "bh1", "final_sigmas_type": "sigma_min"},
        {
            "solver_order": 3,
            "lower_order_final": True,
            "beta_schedule": "scaled_linear",
            "timestep_spacing": "trailing",
        },
    ],
    ids=lambda s: ",".join(f"{k}={v}" for k, v in s.items()),
)
def test_other_supported_settings_equal_diffusers(settings):
    config = {**FLOW, "flow_shift": 3.0, **settings}
    ours = solver_for_config(config)
    assert isinstance(ours, FlowUniPC)
    reference = UniPCMultistepScheduler.from_config(config)
    for field in FIELDS.values():
        for a, b in zip(_trajectory(ours, 10, field), _trajectory(reference, 10, field), strict=True):
            assert _relative_error(a, b) <= 1e-6


def test_bh1_lands_on_the_data_prediction_where_diffusers_returns_nan():
    # bh1's B(h) = -h is -inf on the last step to sigma = 0; diffusers multiplies it by its empty sum (NaN)
    reference = _trajectory(UniPCMultistepScheduler(**FLOW, flow_shift=3.0, solver_type="bh1"), 10, _mlp)
    ours_solver = FlowUniPC(shift=3.0, variant="bh1")
    ours = _trajectory(ours_solver, 10, _mlp)
    assert all(torch.equal(a, b) for a, b in zip(ours[:-1], reference[:-1]))
    assert bool(torch.isnan(reference[-1]).all())
    before_last = ours[-2]
    expected = before_last - ours_solver.sigmas[9] * _mlp(before_last, float(ours_solver.sigmas[9]))
    assert torch.equal(ours[-1], expected)


def test_a_long_schedule_runs_to_the_exact_end():
    # 300 steps at shift 5: the first two integer timesteps coincide (diffusers' class then starts at its second
    # entry); steps are counted here. A constant velocity c has the exact end noise - c.
    solver = FlowUniPC(shift=5.0)
    solver.set_timesteps(300)
    assert solver.timesteps[0] == solver.timesteps[1]
    c = torch.linspace(-1, 1, 12).reshape(2, 6)
    noise = torch.randn(2, 6, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    x = noise.clone()
    for _ in range(300):
        x = solver.step(c.to(x.dtype), x)
    # the coefficients are float32 (as diffusers'): 300 steps of rounding, measured 1.7e-6
    torch.testing.assert_close(x, noise - c.double(), rtol=0, atol=1e-5)
    with pytest.raises(RuntimeError, match="all 300 steps are taken"):
        solver.step(c, x)


def test_configs_take_the_path_their_settings_allow():
    saved = dict(UniPCMultistepScheduler(**FLOW, flow_shift=5.0).config)  # every setting, as a checkpoint saves it
    own = solver_for_config({"_class_name": "UniPCMultistepScheduler", **saved})
    assert isinstance(own, FlowUniPC) and (own.shift, own.order, own.variant) == (5.0, 2, "bh2")
    assert (own.lower_order_final, own.final_sigma, own.train_steps) == (True, "zero", 1000)
    assert solver_for_config({**saved, **KARRAS}).karras == (0.01, 200.0)
    for unsupported in (
        {"use_karras_sigmas": True},  # diffusers then takes the bounds from its betas
        {"use_karras_sigmas": True, "sigma_max": 200.0},
        {"use_exponential_sigmas": True},
        {"use_dynamic_shifting": True},
        {"shift_terminal": 0.1},
        {"thresholding": True},
        {"predict_x0": False},
        {"solver_type": "midpoint"},
        {"beta_schedule": "cubic"},
        {"a_setting_of_a_later_diffusers": 1},
        {"solver_order": "2"},
    ):
        assert solver_for_config({**saved, **unsupported}) is None, unsupported


def test_unipc_scheduler_is_ours_unless_the_checkpoint_asks_for_more():
    assert isinstance(sampler_mod.unipc_scheduler(SamplerConfig(shift=3.0)), FlowUniPC)
    assert sampler_mod.unipc_scheduler(SamplerConfig(shift=3.0)).shift == 3.0
    checkpoint = {"_class_name": "UniPCMultistepScheduler", **FLOW, "flow_shift": 2.0}
    assert sampler_mod.unipc_scheduler(SamplerConfig(scheduler_config=checkpoint)).shift == 2.0
    assert isinstance(sampler_mod.unipc_scheduler(SamplerConfig(scheduler_config={**checkpoint, **KARRAS})), FlowUniPC)
    betas = {**checkpoint, "use_karras_sigmas": True}  # Karras bounds from the betas: diffusers' class
    assert isinstance(sampler_mod.unipc_scheduler(SamplerConfig(scheduler_config=betas)), UniPCMultistepScheduler)
    velocity = lambda z, sigma: -0.5 * z + sigma  # noqa: E731
    out = sampler_mod.integrate(velocity, torch.ones(1, 2, 3), SamplerConfig(steps=6, scheduler_config=betas))
    assert out.dtype == torch.float32 and bool(torch.isfinite(out).all())
    with pytest.raises(ModelInputError, match="expected use_flow_sigmas=True"):
        sampler_mod.unipc_scheduler(SamplerConfig(scheduler_config={"prediction_type": "flow_prediction"}))


@pytest.mark.slow
def test_integrating_with_unipc_imports_no_diffusers():
    code = (
        "import sys, torch\n"
        "from oscar_core.model.sampler import SamplerConfig, integrate\n"
        "integrate(lambda z, s: 0.5 * z, torch.ones(1, 2, 3), SamplerConfig(steps=4, guidance=None))\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('diffusers', 'transformers')))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


#: the toy chunk below as diffusers' scheduler made it on main before oscar's solver (commit cdb675b, CPU):
#: latents[0, :3, 4, 2, :4]
TOY_SLICE = [
    [1.7411752939224243, 3.3883554935455322, 2.494039297103882, 0.144314244389534],
    [-7.176768779754639, -4.162210941314697, -5.576722145080566, 0.0716959685087204],
    [2.053054094314575, -1.2594256401062012, 3.9717843532562256, 2.186119318008423],
]


@pytest.mark.usefixtures("one_thread")
def test_the_toy_models_chunk_is_the_one_diffusers_scheduler_made(monkeypatch):
    import oscar_zoo
    from oscar_core.model.card_sampler import resolve_sampler

    model = oscar_zoo.load("oscar-toy")
    config = model.sampler_for(resolve_sampler(model.card.sampler).config)  # 20 UniPC steps, guidance 3, shift 5
    g = torch.Generator().manual_seed(7)
    first, skeleton = torch.randn(1, 16, 1, 8, 8, generator=g), torch.randn(1, 16, 5, 8, 8, generator=g)

    def chunk():
        noise = torch.Generator().manual_seed(3)
        return sample_chunk(model.transformer, first, skeleton, model.prompt_embeds(), config, generator=noise)

    ours = chunk()
    torch.testing.assert_close(ours[0, :3, 4, 2, :4], torch.tensor(TOY_SLICE), rtol=0, atol=1e-4)
    monkeypatch.setattr(
        sampler_mod,
        "unipc_scheduler",
        lambda c: UniPCMultistepScheduler(**FLOW, flow_shift=float(c.shift)),
    )
    assert torch.equal(ours, chunk())  # diffusers' scheduler in the same run: the same latents to the bit
