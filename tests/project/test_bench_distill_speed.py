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


def _fake_reference() -> dict:
    """Two cards: a: 0.225 s per evaluation, 1 s for 1 TFLOP of VAE; b: 0.15 s per evaluation, 0.5 s of VAE."""
    return {
        "tflop_per_evaluation": 22.5,
        "tflop_vae_per_chunk": 1.0,
        "throughputs": {
            "a": {"tflops": 100.0, "vae_s": 1.0, "decode_share_of_vae": 0.6},
            "b": {"tflops": 150.0, "vae_s": 0.5, "decode_share_of_vae": 0.6},
        },
    }


FAKE_FLOPS = {
    "encode_seed": 0.1e12,
    "encode_condition": 0.3e12,
    "decode": 0.6e12,
    "tiny_decode": 0.05e12,
    "tiny_encode_condition": 0.02e12,
}


def test_closed_loop_2b_by_hand():
    cl = bench().closed_loop_2b(_fake_reference(), FAKE_FLOPS)
    full, tiny, both, bound = cl["rows"]
    assert [r["step"] for r in cl["rows"]] == [
        "full VAE",
        "tiny decoder",
        "tiny decoder + tiny condition encoder",
        "tiny decoder, no condition encode (bound)",
    ]
    assert [r["condition_encoder"] for r in cl["rows"]][1:] == [
        "WAN 2.1 encoder",
        "tiny encoder (taew2_1 width)",
        "none",
    ]
    # card a: DiT 4 x 0.225 = 0.9 s; the VAE at 1 TFLOP/s
    assert full["a_seconds_per_chunk"] == pytest.approx(1.9)
    assert full["a_vae_share"] == pytest.approx(1.0 / 1.9)
    assert tiny["a_vae_seconds"] == pytest.approx(0.1 + 0.3 + 0.05)
    assert tiny["a_frames_per_s"] == pytest.approx(80 / 1.35)  # 59.3: short of 60
    assert tiny["a_meets_targets"] is False
    assert bound["a_vae_seconds"] == pytest.approx(0.15) and bound["a_meets_targets"] is True
    # both tiny: the seed's full encode 0.1 + the tiny condition encode 0.02 + the tiny decode 0.05 at 1 TFLOP/s
    assert both["a_vae_seconds"] == pytest.approx(0.17) and both["a_frames_per_s"] == pytest.approx(80 / 1.07)
    assert both["a_vae_share"] == pytest.approx(0.17 / 1.07) and both["a_meets_targets"] is True
    # card b: DiT 0.6 s; the VAE at 2 TFLOP/s
    assert full["b_vae_share"] == pytest.approx(0.5 / 1.1) and full["b_meets_targets"] is False  # 45 % of the step
    assert tiny["b_seconds_per_chunk"] == pytest.approx(0.825) and tiny["b_meets_targets"] is True
    # the largest condition encode meeting both: a's frame rate binds (0.4333 s of VAE), b's share (0.4 s)
    a, b = cl["condition_encode_budget"]["a"], cl["condition_encode_budget"]["b"]
    assert a["condition_encode_s_max"] == pytest.approx(80 / 60 - 0.9 - 0.15)
    assert a["fraction_of_now"] == pytest.approx((80 / 60 - 1.05) / 0.3)
    assert a["tiny_encode_condition_s"] == pytest.approx(0.02)  # 0.02 TFLOP at card a's 1 TFLOP/s of VAE
    assert a["tiny_encoder_min_tflops"] == pytest.approx(0.02 / (80 / 60 - 1.05))
    assert b["condition_encode_s_max"] == pytest.approx(0.6 * 0.4 / 0.6 - 0.075)
    split = cl["vae_split"]
    assert split["tiny_encode_vs_encode_condition"] == pytest.approx(0.02 / 0.3)
    assert split["decode_share_by_flops"] == pytest.approx(0.6) and split["tiny_decode_vs_decode"] == pytest.approx(
        1 / 12
    )


def _tiny_decoder_flops_by_hand(t: int, h: int, w: int) -> int:
    """The taew2_1-width tiny decoder's convolution FLOPs (2 per multiply-add) for (t, 16, h, w) latents, from its
    published layout: a 3x3 conv 16 -> 256, then per stage three memory blocks (3x3 convs 2c -> c, c -> c, c -> c),
    x2 nearest upsampling, a 1x1 time-grow c -> c x stride, a 3x3 conv to the next width; a 3x3 conv 64 -> 3 last."""
    widths, time_up = (256, 128, 64, 64), (1, 2, 2)
    frames, pixels = t, h * w
    total = 2 * 9 * 16 * 256 * frames * pixels
    for stage in range(3):
        c = widths[stage]
        total += 3 * 2 * 9 * (2 * c * c + c * c + c * c) * frames * pixels
        pixels *= 4
        total += 2 * c * c * time_up[stage] * frames * pixels
        frames *= time_up[stage]
        total += 2 * 9 * c * widths[stage + 1] * frames * pixels
    return total + 2 * 9 * 64 * 3 * frames * pixels


def test_tiny_decoder_flops_on_the_meta_device_equal_the_random_weights_module_and_the_layer_arithmetic():
    from torch.utils.flop_counter import FlopCounterMode

    from oscar_core.model.tiny_decoder import TinyDecoderNet

    mod = bench()
    counted = mod.closed_loop_flops_2b(frames=9, width=64, height=32)  # latents (3, 16, 4, 8)
    net = TinyDecoderNet().eval()  # random weights on the CPU
    with FlopCounterMode(display=False) as fc, torch.no_grad():
        out = net(torch.randn(1, 3, 16, 4, 8))
    assert out.shape == (1, 9, 3, 32, 64)
    assert counted["tiny_decode"] == fc.get_total_flops() == _tiny_decoder_flops_by_hand(3, 4, 8)
    assert 0 < counted["encode_seed"] < counted["encode_condition"] and counted["decode"] > counted["tiny_decode"]


def _tiny_encoder_flops_by_hand(t: int, h: int, w: int) -> int:
    """The taew2_1-width tiny encoder's convolution FLOPs (2 per multiply-add) for t frames of h x w, from its
    published layout: the frames padded at the end to a multiple of 4; a 3x3 conv 3 -> 64; per stage a 1x1 time pool
    (stride 2, 2, 1: 64 x stride -> 64 on 1 / stride of the frames), a 3x3 conv 64 -> 64 at stride 2 in space, three
    memory blocks (3x3 convs 128 -> 64, 64 -> 64, 64 -> 64); a 3x3 conv 64 -> 16 last."""
    frames, pixels = -(-t // 4) * 4, h * w
    total = 2 * 9 * 3 * 64 * frames * pixels
    for stride in (2, 2, 1):
        frames //= stride
        total += 2 * 64 * stride * 64 * frames * pixels
        pixels //= 4
        total += 2 * 9 * 64 * 64 * frames * pixels
        total += 3 * 2 * 9 * (128 * 64 + 64 * 64 + 64 * 64) * frames * pixels
    return total + 2 * 9 * 64 * 16 * frames * pixels


def test_tiny_encoder_flops_on_the_meta_device_equal_the_random_weights_module_and_the_layer_arithmetic():
    from torch.utils.flop_counter import FlopCounterMode

    from oscar_core.model.tiny_encoder import TinyEncoderNet

    counted = bench().closed_loop_flops_2b(frames=9, width=64, height=32)  # 9 frames padded to 12
    net = TinyEncoderNet().eval()  # random weights on the CPU
    with FlopCounterMode(display=False) as fc, torch.no_grad():
        out = net(torch.rand(1, 9, 3, 32, 64))
    assert out.shape == (1, 3, 16, 4, 8)
    assert counted["tiny_encode_condition"] == fc.get_total_flops() == _tiny_encoder_flops_by_hand(9, 32, 64)
    assert counted["tiny_encode_condition"] < counted["encode_condition"]


def test_closed_loop_2b_only_adds_its_section_and_keeps_every_other_field(tmp_path, monkeypatch, capsys):
    import json

    mod = bench()
    monkeypatch.setattr(mod, "closed_loop_flops_2b", lambda: dict(FAKE_FLOPS))
    before = {"provenance": {"date": "then"}, "reference_2b": _fake_reference(), "rows": [{"row": "x", "ms": 1.5}]}
    path = tmp_path / "distill_speed.json"
    path.write_text(json.dumps(before))
    assert mod.main(["--closed-loop-2b-only", "--json", str(path)]) == 0
    after = json.loads(path.read_text())
    assert {k: after[k] for k in before} == before
    assert after["closed_loop_2b"]["rows"][1]["a_frames_per_s"] == pytest.approx(80 / 1.35)  # from the file's reference
    assert "date" in after["closed_loop_2b"]["provenance"]
    with pytest.raises(SystemExit) as e:
        mod.main(["--closed-loop-2b-only", "--json", str(tmp_path / "none.json")])
    assert e.value.code == 2 and "none.json: expected a JSON file written by this benchmark" in capsys.readouterr().err


def test_the_paper_preset_is_read_from_the_run_that_measured_it(tmp_path, monkeypatch):
    import json

    mod = bench()
    gpu = tmp_path / "rollout_gpu.json"
    gpu.write_text(json.dumps({"measured": {"presets": [{"preset": "fast", "variant": "eager"}]}}))
    monkeypatch.setattr(mod, "GPU_JSON", gpu)
    with pytest.raises(ValueError, match="rollout_gpu.json and rollout_paper_gpu.json"):
        mod.paper_eager_row()
    paper = {"preset": "paper", "variant": "eager", "seconds_parts": {"encode": 0.5, "decode": 0.8}}
    compiled = {**paper, "variant": "compiled"}
    (tmp_path / "rollout_paper_gpu.json").write_text(json.dumps({"measured": {"presets": [compiled, paper]}}))
    assert mod.paper_eager_row() == (paper, tmp_path / "rollout_paper_gpu.json")
