"""benchmarks/distill_speed.py: DiT evaluations per chunk are counted on the real transformer and equal what the
sampler declares (``model_calls``), and the 2B figures follow from the stated throughput by hand arithmetic."""

from __future__ import annotations

import importlib.util

import pytest
import torch
from _models import tiny_world_model
from _paths import REPO

from oscar_core.model.sampler import SamplerConfig, model_calls

pytestmark = pytest.mark.usefixtures("one_thread")


def bench():
    spec = importlib.util.spec_from_file_location("bench_distill_speed", REPO / "benchmarks" / "distill_speed.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    "sampler",
    [
        SamplerConfig(steps=3, guidance=3.0),  # guided every step, both branches in one forward of batch 2
        SamplerConfig(steps=3, guidance=3.0, batched_cfg=False),  # guided, two forwards of batch 1
        SamplerConfig(steps=6, guidance=3.0, guidance_interval=(0.0, 0.8)),  # guided at some steps only
        SamplerConfig(steps=4, guidance=None, solver="euler"),  # a student: one branch
    ],
    ids=["guided", "guided-two-pass", "interval", "unguided"],
)
def test_counted_evaluations_equal_model_calls(sampler):
    mod = bench()
    model = tiny_world_model(seed=0, skeleton_scale=0.1, empty_prompt=torch.zeros(1, 4, 48))
    inputs = mod.chunk_inputs(9, 32, 32)
    seen = mod.count_dit_evaluations(model, sampler, inputs)
    assert seen["items"] == model_calls(sampler)
    assert seen["forwards"] == (2 * sampler.steps if not sampler.batched_cfg else sampler.steps)


def test_interval_counts_fewer_than_every_step():
    mod = bench()
    model = tiny_world_model(seed=0, empty_prompt=torch.zeros(1, 4, 48))
    inputs = mod.chunk_inputs(9, 32, 32)
    every = mod.count_dit_evaluations(model, SamplerConfig(steps=6, guidance=3.0), inputs)["items"]
    part = mod.count_dit_evaluations(model, SamplerConfig(steps=6, guidance=3.0, guidance_interval=(0.0, 0.8)), inputs)
    assert every == 12 and 6 < part["items"] < 12


def test_computed_2b_by_hand():
    mod = bench()
    ref = {
        "tflop_per_evaluation": 100.0,
        "throughputs": {"card": {"tflops": 100.0, "vae_s": 1.0, "decode_share_of_vae": 0.5}},
    }
    whole = mod.computed_2b(4, ref)["card"]  # 4 evaluations of 1 s each + 1 s of VAE
    assert whole["seconds_per_chunk"] == pytest.approx(5.0)
    assert whole["frames_per_s"] == pytest.approx(80 / 5.0)
    assert whole["vae_share"] == pytest.approx(0.2)
    end = mod.computed_2b(4, ref, decode_ratio=0.1)["card"]  # decode 0.5 s -> 0.05 s
    assert end["seconds_per_chunk"] == pytest.approx(4.55)
