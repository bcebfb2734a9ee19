"""benchmarks/rollout.py --measure: the per-preset table a GPU user gets, exercised on the CPU at the tiny size.

The FLOPs it reports are counted by running each chunk under ``torch.utils.flop_counter``; they must equal
what the sampler's own evaluation count implies (``model_calls`` DiT evaluations of batch 1, the text
projection once, the VAE's encodes and decode), and the derived columns must follow from the timed parts.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import torch
from _paths import REPO

from oscar_core.model.presets import SAMPLER_PRESETS
from oscar_core.model.sampler import SamplerConfig, apply_preset, model_calls

SCRIPT = REPO / "benchmarks" / "rollout.py"


def run(tmp_path, *args, timeout=600):
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OSCAR_CACHE": str(tmp_path / "cache")}
    return subprocess.run(
        [sys.executable, str(SCRIPT), "--skip-tiny", "--skip-computed", *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
    )


@pytest.mark.slow
def test_measure_reports_every_preset_eager_and_compiled(tmp_path):
    out = tmp_path / "rollout.json"
    peak = 0.5  # TFLOP/s, given: the CPU has no known peak
    proc = run(
        tmp_path,
        "--measure",
        "cpu",
        "--measure-size",
        "tiny",
        "--repeats",
        "1",
        "--compile",
        "--peak-tflops",
        str(peak),
        "--json",
        str(out),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    m = json.loads(out.read_text())["measured"]
    assert m["compiled"] is True and m["compile_first_call_s"] > 0
    flops = m["flops"]
    per_eval = flops["step_conditional"]
    assert per_eval > 0 and flops["step_guided"] == 2 * per_eval  # batched guidance: one forward of batch 2
    rows = {(r["preset"], r["variant"]): r for r in m["presets"]}
    assert set(rows) == {(p, v) for p in SAMPLER_PRESETS for v in ("eager", "compiled")}
    frames = m["frames"]
    for (preset, _variant), r in rows.items():
        config = apply_preset(SamplerConfig(guidance=6.0, solver="unipc"), preset)
        assert r["steps"] == config.steps and r["dit_evaluations"] == model_calls(config)
        # counted by running the chunk == implied by the sampler's evaluation count
        assert flops[f"chunk_{preset}"] == (
            flops["vae_per_chunk"] + flops["text_projection"] + model_calls(config) * per_eval
        )
        parts = r["seconds_parts"]
        assert set(parts) == {"encode", "sample", "decode"} and min(parts.values()) > 0
        assert sum(parts.values()) <= r["seconds_per_chunk"] + 1e-6  # one timed run: its parts fit in its wall
        assert r["seconds_per_step"] * r["steps"] == pytest.approx(parts["sample"])
        assert r["frames_per_s"] * r["seconds_per_chunk"] == pytest.approx(frames - 1)
        assert r["vae_share"] == pytest.approx((parts["encode"] + parts["decode"]) / sum(parts.values()))
        dit = flops[f"chunk_{preset}"] - flops["vae_per_chunk"]
        assert r["mfu_sampling"] == pytest.approx(dit / (parts["sample"] * peak * 1e12))
        assert r["mfu_chunk"] == pytest.approx(flops[f"chunk_{preset}"] / (r["seconds_per_chunk"] * peak * 1e12))
    assert rows[("fast", "eager")]["tflop_per_chunk"] < rows[("paper", "eager")]["tflop_per_chunk"]
    assert "MFU sampling" in proc.stdout and "compiled" in proc.stdout


@pytest.mark.parametrize(
    "args, message",
    [
        (["--measure", "cuda"], "needs a CUDA device"),
        (["--measure", "tpu"], "--measure: expected"),
        (["--measure", "cpu", "--presets", "paper,turbo"], "--presets: expected"),
        (["--measure", "cpu", "--peak-tflops", "0"], "--peak-tflops: expected a positive number"),
    ],
)
def test_measure_refuses_bad_settings_before_work(tmp_path, args, message):
    """The script's main in this process (a refusal is its SystemExit; a fresh process would only add an import)."""
    if args[:2] == ["--measure", "cuda"] and torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    out = tmp_path / "rollout.json"
    with pytest.raises(SystemExit) as refused:
        _bench_module().main(["--skip-tiny", "--skip-computed", *args, "--json", str(out)])
    assert refused.value.code not in (0, None) and message in str(refused.value.code)
    assert not out.exists()


def _bench_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_rollout", SCRIPT)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def test_vae_variants_are_timed_compared_and_undone(monkeypatch):
    """--vae-variants: each variant's output against eager, a failing one is a row with its reason, and the VAE is
    left as it was (contiguous weights, no tiling). torch.compile is left out here (a minute of inductor)."""
    import numpy as np

    from oscar_core.model.tiny import build_tiny_vae
    from oscar_core.model.vae import VideoVAE

    bench = _bench_module()
    monkeypatch.setattr(bench, "VAE_VARIANTS", ("eager", "channels_last", "tiling"))
    vae = VideoVAE(build_tiny_vae(seed=0))
    rng = np.random.default_rng(0)
    first = vae.to_pixels(rng.integers(0, 256, (1, 64, 64, 3), dtype=np.uint8))
    condition = vae.to_pixels(rng.integers(0, 256, (5, 64, 64, 3), dtype=np.uint8))
    rows = {r["variant"]: r for r in bench.measure_vae_variants(vae, first, condition, 1, torch.device("cpu"))}
    assert rows["eager"]["max_abs_diff"] == 0 and rows["eager"]["vs_eager"] == 1.0
    assert rows["channels_last"]["max_abs_diff"] < 1e-4 and rows["channels_last"]["seconds"] > 0
    assert all(p.is_contiguous() for p in vae.vae.parameters()) and not vae.vae.use_tiling

    def broken(*a, **k):
        raise RuntimeError("tiling is not supported here")

    monkeypatch.setattr(vae.vae, "enable_tiling", broken)
    rows = {r["variant"]: r for r in bench.measure_vae_variants(vae, first, condition, 1, torch.device("cpu"))}
    assert rows["tiling"] == {
        "variant": "tiling",
        "failed": "RuntimeError: tiling is not supported here",
        "vs_eager": None,
    }
    assert "seconds" in rows["channels_last"]


def test_the_random_2b_is_built_in_its_dtype_on_its_device():
    """build_random_2b (the 2B rows of benchmarks/rollout.py and cli_rollout.py): on the meta device, no memory."""
    from oscar_core.model.tiny import build_random_2b

    before = torch.get_default_dtype()
    transformer, vae = build_random_2b("meta", torch.bfloat16)
    assert torch.get_default_dtype() == before  # restored
    params = list(transformer.parameters()) + list(vae.parameters())
    assert {p.device.type for p in params} == {"meta"} and {p.dtype for p in params} == {torch.bfloat16}
    assert sum(p.numel() for p in transformer.parameters()) == 2_059_305_984  # benchmarks/rollout.py's count
    assert not transformer.training and not vae.training
