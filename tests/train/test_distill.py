"""Few-step students (oscar_core.train.distill): targets on analytic teachers, guidance and the first frame folded in
as computed by hand, a tiny distillation run that resumes bitwise, exports a card whose sampler makes 4 DiT calls
per chunk and no unconditional branch, and rolls out identically after a reload; 1 vs 2 processes under torchrun."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import yaml
from _models import tiny_clipset, tiny_train_config
from _paths import REPO
from _torchrun import train_under_torchrun

from oscar_core.model.card_sampler import sampler_of_card
from oscar_core.model.sampler import flow_sigmas, model_calls
from oscar_core.train.checkpoint import latest_checkpoint, list_checkpoints, load_weights
from oscar_core.train.config import TrainConfigError, config_from_dict, config_to_dict, load_config
from oscar_core.train.data import Batch
from oscar_core.train.distill import Teacher, distill_loss, distill_target, student_sampler, student_step_index
from oscar_core.train.loop import train
from oscar_core.train.models import build_transformer
from oscar_core.train.sampling import PlanItem, item_noise

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


# ---------------------------------------------------------------------- targets, by hand
def test_student_step_index_is_the_grid_interval_holding_sigma():
    grid = flow_sigmas(4, 5.0).tolist()  # 1, 0.9375, 0.8333, 0.625, 0
    sig = torch.tensor([1.0, 0.95, 0.9375, 0.9, 0.7, 0.3, 1e-4], dtype=torch.float64)
    assert grid[1] == pytest.approx(15 / 16) and grid[2] == pytest.approx(5 / 6) and grid[3] == pytest.approx(5 / 8)
    assert student_step_index(sig, 4, 5.0).tolist() == [0, 0, 1, 1, 2, 3, 3]


def test_two_teacher_steps_of_a_linear_field_give_the_hand_computed_one_step_target():
    # v(x, σ) = λ x with λ = 1/2; fine grid of 1 student step x 2: σ = 1, 5/6, 0 (shift 5: 5·½ / (1 + 4·½) = 5/6).
    # Euler: x' = x (1 + λ(5/6 − 1)) (1 + λ(0 − 5/6)) = x · 11/12 · 7/12 = x · 77/144; v* = (x − x') / 1 = x · 67/144
    z = torch.randn(2, 3, 2, 2, 2, generator=torch.Generator().manual_seed(0))
    got = distill_target(lambda x, s: 0.5 * x, z, torch.tensor([0, 0]), steps=1, substeps=2, shift=5.0)
    torch.testing.assert_close(got, z * 67 / 144, rtol=1e-6, atol=1e-6)
    # one sub-step is the teacher's velocity itself (guidance folding at the same step count)
    one = distill_target(lambda x, s: 0.5 * x, z, torch.tensor([0, 0]), steps=1, substeps=1, shift=5.0)
    torch.testing.assert_close(one, 0.5 * z)


def test_the_exact_field_of_a_single_clean_latent_is_distilled_to_itself():
    # data = one point μ: the exact rectified-flow velocity is (x − μ)/σ, whose paths are straight lines, so every
    # Euler step is exact and the target is the teacher's velocity at σ_i for any number of sub-steps
    mu = torch.randn(1, 2, 3, 2, 2, generator=torch.Generator().manual_seed(1))
    z = torch.randn(3, 2, 3, 2, 2, generator=torch.Generator().manual_seed(2))
    index = torch.tensor([0, 1, 2])
    sig = flow_sigmas(3, 5.0)[index].view(3, 1, 1, 1, 1).float()

    def v(x, s):
        return (x - mu) / s.float().view(-1, 1, 1, 1, 1)

    for k in (1, 2, 5):
        got = distill_target(v, z, index, steps=3, substeps=k, shift=5.0)
        torch.testing.assert_close(got, (z - mu) / sig, rtol=1e-5, atol=1e-5)


class _FieldDiT(torch.nn.Module):
    """A DiT stand-in with a velocity known in closed form:
    v = λ x + β S + γ (x · mask)[:, :, :1] + δ t, S the skeleton latent, mask the condition mask, t the timestep.
    As a student it returns ``reply`` (whatever the test wants it to predict)."""

    dtype = torch.float32

    def __init__(self, lam=0.3, beta=0.7, gamma=0.4, delta=0.2, reply=None):
        super().__init__()
        self.lam, self.beta, self.gamma, self.delta, self.reply = lam, beta, gamma, delta, reply
        self.calls = []

    def forward(self, hidden_states, timestep, encoder_hidden_states, condition_mask, padding_mask, **kw):
        self.calls.append(hidden_states.shape[0])
        if self.reply is not None:
            return (self.reply.clone().requires_grad_(True),)
        x, s = hidden_states, kw["skeleton_latents"]
        first = (x * condition_mask)[:, :, :1]
        return (self.lam * x + self.beta * s + self.gamma * first + self.delta * timestep,)


def _by_hand(z0, noise, skel, sigma_i, fine, w, f):
    """The guided 2-sub-step target of :class:`_FieldDiT` in numpy: frames ≥ 1 move, frame 0 stays z0's."""
    z0, noise, skel = z0.numpy().astype(np.float64), noise.numpy().astype(np.float64), skel.numpy().astype(np.float64)
    x = (1 - sigma_i) * z0 + sigma_i * noise
    x[:, :, 0] = z0[:, :, 0]
    start = x.copy()
    for s_now, s_next in zip(fine[:-1], fine[1:]):
        # v_c − v_u = β S (the unconditional skeleton is zero); diffusers form: v_c + w (v_c − v_u)
        v = f.lam * x + (1 + w) * f.beta * skel + f.gamma * z0[:, :, :1] + f.delta * s_now
        x[:, :, 1:] = x[:, :, 1:] + (s_next - s_now) * v[:, :, 1:]
    return (start - x) / (fine[0] - fine[-1])


def _loss_setup(sigma=0.9, w=2.0):
    b, c, t, h, wd = 2, 4, 3, 2, 2
    g = torch.Generator().manual_seed(3)
    z0 = torch.randn(b, c, t, h, wd, generator=g)
    skel = torch.randn(b, c, t, h, wd, generator=g)
    items = [PlanItem(0, 0, False, sigma, 11), PlanItem(0, 0, False, sigma, 12)]
    noise = item_noise(items, (c, t, h, wd))
    config = SimpleNamespace(
        distill=SimpleNamespace(steps=2, substeps=2), flow=SimpleNamespace(shift=5.0, cond_timestep=1e-4)
    )
    batch = Batch(z0, skel, torch.zeros(b, 1, 8), None)
    return z0, skel, items, noise, config, batch


@pytest.mark.parametrize("sigma", [0.9, 0.5])
def test_distill_loss_is_zero_exactly_at_the_guided_teacher_target_with_the_clean_first_frame(sigma):
    z0, skel, items, noise, config, batch = _loss_setup(sigma)
    w, f = 2.0, _FieldDiT()
    i = int(student_step_index(torch.tensor([sigma], dtype=torch.float64), 2, 5.0))
    fine = flow_sigmas(4, 5.0).tolist()[2 * i : 2 * i + 3]
    expected = torch.from_numpy(_by_hand(z0, noise, skel, fine[0], fine, w, f)).float()
    teacher = Teacher(f, w, "diffusers")
    hit = distill_loss(_FieldDiT(reply=expected), teacher, batch, items, config, "cpu")
    assert float(hit.detach()) < 1e-10
    assert f.calls == [4, 4]  # two guided sub-steps, each one batched forward of cond + uncond (2 x B = 4)
    # the test can fail: the conditional (w = 0) or the unconditional teacher is a different target
    cond_only = torch.from_numpy(_by_hand(z0, noise, skel, fine[0], fine, 0.0, f)).float()
    assert float(distill_loss(_FieldDiT(reply=cond_only), teacher, batch, items, config, "cpu").detach()) > 1e-3
    uncond = torch.from_numpy(_by_hand(z0, noise, skel, fine[0], fine, -1.0, f)).float()
    assert float(distill_loss(_FieldDiT(reply=uncond), teacher, batch, items, config, "cpu").detach()) > 1e-3


def test_distill_loss_gradient_reaches_the_student_only():
    _, _, items, _, config, batch = _loss_setup()
    teacher, student = _FieldDiT(), _FieldDiT()
    teacher.lam, student.lam = torch.nn.Parameter(torch.tensor(0.3)), torch.nn.Parameter(torch.tensor(0.1))
    distill_loss(student, Teacher(teacher, 1.0), batch, items, config, "cpu").backward()
    assert student.lam.grad is not None and float(student.lam.grad) != 0.0
    assert teacher.lam.grad is None


# ---------------------------------------------------------------------- a tiny distillation run
@pytest.fixture(scope="module")
def clipset(tmp_path_factory):
    root = tmp_path_factory.mktemp("clips") / "toy"
    return tiny_clipset(root, clips=3)


@pytest.fixture(scope="module")
def teacher(tmp_path_factory, clipset):
    tmp = tmp_path_factory.mktemp("teacher")
    return train(tiny_train_config(clipset, tmp / "run", steps=2, export=True), progress=False).export


def _student(clips, teacher, run_dir, **over) -> dict:
    """A tiny distillation config (as a mapping) of 4 optimiser steps from ``teacher`` to a 4-step student."""
    over = {"model.init": str(teacher), "distill.teacher": str(teacher), "distill.steps": 4, **over}
    return config_to_dict(tiny_train_config(clips, run_dir, **over))


def _weights(run_dir, key):
    model = build_transformer(load_config(Path(run_dir) / "config.yaml"))
    return {k: v.clone() for k, v in load_weights(latest_checkpoint(run_dir), model, key=key).state_dict().items()}


def test_a_distill_config_names_its_teacher_and_its_start(tmp_path, clipset, teacher):
    with pytest.raises(TrainConfigError, match="model.init"):
        tiny_train_config(clipset, tmp_path / "r", **{"distill.teacher": str(teacher)})
    with pytest.raises(TrainConfigError, match="distill.steps"):
        config_from_dict(_student(clipset, teacher, tmp_path / "r", **{"distill.steps": 0}))
    with pytest.raises(TrainConfigError, match="distill.teacher"):
        train(config_from_dict(_student(clipset, tmp_path, tmp_path / "r2")), progress=False)
    with pytest.raises(TrainConfigError, match="condition.*the teacher's condition 'skeleton'.*capsules"):
        train(config_from_dict(_student(clipset, teacher, tmp_path / "r3", condition="capsules")), progress=False)
    assert not (tmp_path / "r2").exists() and not (tmp_path / "r3").exists()  # refused before anything is written


@pytest.mark.slow
def test_distillation_resumes_bitwise_and_exports_a_four_call_student_that_reloads_identically(
    tmp_path, clipset, teacher
):
    import oscar_zoo

    straight = config_from_dict(_student(clipset, teacher, tmp_path / "straight", export=True))
    result = train(straight, progress=False)
    split = config_from_dict(_student(clipset, teacher, tmp_path / "split"))
    assert train(split, progress=False, stop_after=2).step == 2
    assert [p.name for p in list_checkpoints(split.run_dir)] == ["step-00000002"]
    train(resume=split.run_dir, progress=False)
    start = build_transformer(straight).state_dict()
    for key in ("model", "ema"):
        a, b = _weights(straight.run_dir, key), _weights(split.run_dir, key)
        assert all(torch.equal(a[k], b[k]) for k in a), key
        assert not all(torch.equal(a[k], start[k]) for k in a)  # distillation moved the weights
    rows = [json.loads(line) for line in (Path(split.run_dir) / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == [0, 1, 2, 3, 4] and all(np.isfinite(r["loss"]) for r in rows[1:])

    # the export: a world model whose card samples it in 2 Euler steps with no unconditional branch
    student = oscar_zoo.load(result.export)
    assert student.card.sampler == {"steps": 4, "guidance": None, "guidance_form": "diffusers", "preset": None}
    assert student.card.base == str(teacher)
    sampler = student.sampler_for(student.recommended_sampler())
    assert (sampler.resolved_solver, sampler.steps, sampler.guidance) == ("euler", 4, None)
    assert model_calls(sampler) == 4
    # the same sampler self forcing gives the student in training: both read the one description (student_sampler)
    assert sampler == sampler_of_card(*student_sampler(straight))
    calls = []
    forward = student.transformer.forward

    def counted(*a, **kw):
        calls.append(int(kw["hidden_states"].shape[0]))
        return forward(*a, **kw)

    student.transformer.forward = counted
    first, skeleton = np.full((32, 32, 3), 90, np.uint8), np.zeros((9, 32, 32, 3), np.uint8)
    skeleton[:, 10:20, 12:16] = 255
    prompt = torch.zeros(1, 1, 48)
    out = student.rollout(first, skeleton, prompt, progress=False, seed=3)
    assert calls == [1, 1, 1, 1]  # one chunk: 4 DiT evaluations of batch 1 (no unconditional branch)
    student.transformer.forward = forward

    # saved and reloaded, it rolls out identically
    student.save_pretrained(tmp_path / "again")
    again = oscar_zoo.load(tmp_path / "again")
    assert again.card == student.card and again.scheduler_config == student.scheduler_config
    assert np.array_equal(again.rollout(first, skeleton, prompt, progress=False, seed=3).frames, out.frames)


@pytest.fixture(scope="module")
def distilled_two_ways(tmp_path_factory, clipset, teacher):
    """Run folders of the same 2-step distillation in this process ("one") and on 2 gloo processes under DDP and
    FSDP2 ("ddp", "fsdp"), the two trained by one torchrun launch (tests/_torchrun.py)."""
    tmp = tmp_path_factory.mktemp("distil_two_ways")
    common = {"steps": 2, "batch_size": 4, "save_every": 2, "data.skeleton_dropout": 0.5}
    train(config_from_dict(_student(clipset, teacher, tmp / "one", **common)), progress=False)
    paths = []
    for mode in ("ddp", "fsdp"):
        paths.append(tmp / f"{mode}.yaml")
        paths[-1].write_text(yaml.safe_dump(_student(clipset, teacher, tmp / mode, parallel=mode, **common)))
    out = train_under_torchrun(paths)
    assert out.returncode == 0, out.stderr[-3000:]
    return tmp


@pytest.mark.slow
@pytest.mark.parametrize("parallel", ["ddp", "fsdp"])
def test_two_processes_distil_as_one(distilled_two_ways, parallel):
    for key in ("model", "ema"):
        a, b = _weights(distilled_two_ways / "one", key), _weights(distilled_two_ways / parallel, key)
        assert all(torch.allclose(a[k], b[k], atol=2e-6, rtol=1e-5) for k in a), key


def test_the_toy_distillation_config_loads_and_names_the_bundled_teacher():
    repo = REPO
    cfg = load_config(repo / "configs" / "train" / "toyworld-distill.yaml", {"data.clips": ["x"]})
    assert (cfg.distill.steps, cfg.distill.substeps, cfg.distill.guidance) == (4, 2, None)
    assert cfg.model.init == cfg.distill.teacher == "zoo/assets/oscar-toy"
    assert (repo / cfg.distill.teacher / "oscar_model.json").is_file()
