"""benchmarks/tiny_encoder.py: the per-chunk PSNR by hand, and a rollout pair that compares the two condition
encoders on the same seed and leaves the model with its full encoder."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
import torch
from _models import tiny_world_model
from _paths import REPO

from oscar_core.model.sampler import SamplerConfig
from oscar_core.model.tiny_encoder import TinyEncoderNet

pytestmark = pytest.mark.usefixtures("one_thread")


def bench():
    spec = importlib.util.spec_from_file_location("bench_tiny_encoder", REPO / "benchmarks" / "tiny_encoder.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_chunk_psnrs_skip_each_chunk_s_seed_frame_by_hand():
    a = np.zeros((9, 4, 4, 3), np.uint8)
    b = a.copy()
    b[1:5] = 10  # chunk 0's generated frames (1-4) differ by 10 levels
    b[5] = 200  # chunk 1's seed frame: not counted
    psnrs = bench().chunk_psnrs(a, b, starts=[0, 4], chunk=5)
    assert psnrs[0] == pytest.approx(10 * math.log10(255.0**2 / 100.0))
    assert psnrs[1] > psnrs[0]  # frames 5-8 of chunk 1 hold frame 5 (200 levels off) once, and three equal frames


def test_a_rollout_pair_uses_the_same_seed_and_puts_the_full_encoder_back():
    model = tiny_world_model(seed=0, chunk_frames=5, skeleton_scale=0.5)
    rng = np.random.default_rng(0)
    first = rng.integers(0, 256, (32, 64, 3), dtype=np.uint8)
    condition = rng.integers(0, 256, (9, 32, 64, 3), dtype=np.uint8)
    torch.manual_seed(0)
    net = TinyEncoderNet(width=8)
    sampler = SamplerConfig(steps=1)
    videos = bench().rollout_pair(model, net, first, condition, sampler, seed=3)
    assert model.vae.tiny_encoder is None
    again = model.rollout(first, condition, sampler=sampler, seed=3, progress=False).frames
    np.testing.assert_array_equal(videos["full"], again)  # the same seed: the same full-encoder rollout
    assert not np.array_equal(videos["tiny"], videos["full"])
    assert not np.array_equal(videos["full_other_seed"], videos["full"])
