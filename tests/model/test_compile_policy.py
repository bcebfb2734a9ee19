"""The DiT compile policy: when to compile, once per process, the fallback, the persistent cache, timings."""

import argparse
import logging
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from oscar_core.model import ModelCard, ModelInputError, OscarWorldModel, SamplerConfig, compile_policy as cp
from oscar_core.model.tiny import build_tiny_transformer, build_tiny_vae

H, W = 32, 64
SAMPLER = SamplerConfig(steps=2)


def _model(**card):
    return OscarWorldModel.from_modules(
        build_tiny_transformer(seed=0, skeleton_scale=0.05),
        build_tiny_vae(seed=0),
        ModelCard(name="tiny", chunk_frames=9, **card),
        empty_prompt=torch.randn(1, 4, 48, generator=torch.Generator().manual_seed(0)),
    )


@pytest.fixture(scope="module")
def clip():
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, (H, W, 3), dtype=np.uint8), rng.integers(0, 256, (17, H, W, 3), dtype=np.uint8)


class CountingCompile:
    """Stands in for torch.compile: counts calls; the 'compiled' function is the eager one (or one that fails)."""

    def __init__(self, fail_at_call: bool = False, fail_at_wrap: bool = False):
        self.calls, self.kwargs, self.fail_at_call, self.fail_at_wrap = 0, [], fail_at_call, fail_at_wrap

    def __call__(self, fn, **kwargs):
        self.calls += 1
        self.kwargs.append(kwargs)
        if self.fail_at_wrap:
            raise RuntimeError("Dynamo is not supported on this Python")
        if self.fail_at_call:

            def broken(*args, **kw):
                raise RuntimeError("InductorError: CppCompileError: no C++ compiler\nlong log ...")

            return broken
        return fn


# --------------------------------------------------------------------------- the decision rule
def test_break_even_follows_the_issue_numbers():
    # 63 s of compiling against 5.8 s saved per 35-step chunk: 11 chunks; at 12 steps each saves 1.99 s: 32 chunks
    assert cp.COMPILE_COST_S == pytest.approx(62.8)
    assert cp.break_even_chunks(35) == 11
    assert cp.break_even_chunks(12) == 32
    assert 10 * 5.8 < cp.COMPILE_COST_S < 11 * 5.8


def test_break_even_scales_with_the_dit_evaluations_of_a_preset():
    from oscar_core.model.sampler import SamplerConfig, apply_preset, model_calls

    fast = apply_preset(SamplerConfig(), "fast")
    calls = model_calls(fast)  # 12 steps, guidance on part of the range: 17 evaluations, not 24
    assert calls == 17
    saving = 5.8 * calls / 70  # seconds saved per chunk: the measured 5.8 s per 70 evaluations
    need = cp.break_even_chunks(fast.steps, calls)
    assert (need - 1) * saving < cp.COMPILE_COST_S < need * saving and need == 45
    assert cp.compile_decision("auto", "cuda", need - 1, fast.steps, calls)[0] is False
    ok, why = cp.compile_decision("auto", "cuda", need, fast.steps, calls)
    assert ok and "17 DiT evaluations" in why
    assert cp.break_even_chunks(35, model_calls(apply_preset(SamplerConfig(), "paper"))) == cp.break_even_chunks(35)


def test_the_model_weighs_its_preset_when_deciding(monkeypatch):
    """The rollout asks the rule with the sampler's own evaluation count and the chunks × cells it will sample."""
    from oscar_core.model.sampler import SamplerConfig, apply_preset

    asked = []
    monkeypatch.setattr(cp, "compile_decision", lambda *a: asked.append(a) or (False, "no"))
    model = _model().set_compile("auto", cells=3)
    model._prepare_compile(17, 9, apply_preset(SamplerConfig(), "fast"))  # 17 frames in 9-frame chunks: 2 chunks
    assert asked == [("auto", model.device, 2 * 3, 12, 17)]


@pytest.mark.parametrize(
    "mode, device, chunks, steps, expected",
    [
        ("auto", "cpu", 1000, 35, False),  # never on the CPU by default
        ("auto", "cuda", 1, 35, False),  # a one-chunk rollout stays eager
        ("auto", "cuda", 10, 35, False),
        ("auto", "cuda:0", 11, 35, True),
        ("auto", "cuda", 20, 12, False),  # the fast preset saves less per chunk
        ("auto", "cuda", 32, 12, True),
        ("always", "cpu", 1, 35, True),
        ("never", "cuda", 1000, 35, False),
    ],
)
def test_compile_decision(mode, device, chunks, steps, expected):
    ok, why = cp.compile_decision(mode, device, chunks, steps)
    assert ok is expected and mode in why


def test_bad_mode_is_a_clear_error():
    with pytest.raises(ModelInputError, match=r"compile: expected one of \('auto', 'always', 'never'\), found 'yes'"):
        cp.compile_decision("yes", "cuda", 1)
    with pytest.raises(ModelInputError, match="compile cells: expected an integer >= 1, found 0"):
        _model().set_compile("auto", cells=0)


# --------------------------------------------------------------------------- once per process, fallback
def test_two_rollouts_compile_once_and_match_eager(monkeypatch, clip):
    first, skel = clip
    eager = _model().rollout(first, skel, sampler=SAMPLER, progress=False).frames
    fake = CountingCompile()
    monkeypatch.setattr(torch, "compile", fake)
    model = _model().set_compile("always")
    a = model.rollout(first, skel, sampler=SAMPLER, progress=False)
    b = model.rollout(first, skel, sampler=SAMPLER, progress=False, seed=1)
    model.rollout_batch([first, first], [skel, skel], sampler=SAMPLER)
    assert fake.calls == 1 and fake.kwargs[0]["dynamic"] is False
    assert cp.is_compiled(model.transformer) and "reused" in model.compile_reason
    np.testing.assert_array_equal(a.frames, eager)
    assert len(a.starts) == 2 and b.frames.shape == a.frames.shape


def test_compile_transformer_is_once_per_module(monkeypatch):
    fake = CountingCompile()
    monkeypatch.setattr(torch, "compile", fake)
    a, b = _model(), _model()
    assert cp.compile_transformer(a.transformer) and cp.compile_transformer(a.transformer)
    assert fake.calls == 1
    assert cp.compile_transformer(b.transformer) and fake.calls == 2  # another model compiles its own


def test_auto_on_the_cpu_and_never_do_not_compile(monkeypatch, clip):
    first, skel = clip
    fake = CountingCompile()
    monkeypatch.setattr(torch, "compile", fake)
    for mode in ("auto", "never"):
        model = _model().set_compile(mode, cells=1000)
        model.rollout(first, skel, sampler=SAMPLER, progress=False)
    assert fake.calls == 0 and not cp.is_compiled(model.transformer)


def test_auto_weighs_the_whole_job_on_cuda(monkeypatch, clip):
    """Decided before sampling from chunks x cells (a device faked as CUDA; the model itself stays on the CPU)."""
    first, skel = clip  # 17 frames, chunks of 9: 2 chunks per rollout
    fake = CountingCompile()
    monkeypatch.setattr(torch, "compile", fake)
    monkeypatch.setattr(OscarWorldModel, "device", property(lambda self: torch.device("cuda")))
    paper = SamplerConfig(steps=35)  # the rule's unit: 35-step chunks
    model = _model().set_compile("auto", cells=5)  # 10 chunks < 11: eager
    model.rollout(first, skel, sampler=paper, progress=False)
    assert fake.calls == 0 and "10 chunk(s)" in model.compile_reason
    model.set_compile("auto", cells=6)  # 12 chunks: compile
    model.rollout(first, skel, sampler=paper, progress=False)
    assert fake.calls == 1 and "12 chunk(s)" in model.compile_reason


@pytest.mark.parametrize("where", ["call", "wrap"])
def test_a_failing_compiler_warns_once_and_runs_eager(monkeypatch, clip, caplog, where):
    first, skel = clip
    eager = _model().rollout(first, skel, sampler=SAMPLER, progress=False).frames
    fake = CountingCompile(fail_at_call=where == "call", fail_at_wrap=where == "wrap")
    monkeypatch.setattr(torch, "compile", fake)
    model = _model().set_compile("always")
    with caplog.at_level(logging.WARNING, logger="oscar"):
        got = model.rollout(first, skel, sampler=SAMPLER, progress=False).frames
        again = model.rollout(first, skel, sampler=SAMPLER, progress=False).frames
    warnings = [r for r in caplog.records if "torch.compile of the DiT failed" in r.getMessage()]
    assert (
        len(warnings) == 1 and ("CppCompileError" if where == "call" else "not supported") in warnings[0].getMessage()
    )
    assert fake.calls == 1 and not cp.is_compiled(model.transformer)
    assert "forward" not in model.transformer.__dict__  # the plain module again
    np.testing.assert_array_equal(got, eager)
    np.testing.assert_array_equal(again, eager)


def test_an_input_error_is_not_swallowed_by_the_fallback(monkeypatch):
    monkeypatch.setattr(torch, "compile", CountingCompile(fail_at_call=True))
    model = _model()
    cp.compile_transformer(model.transformer)
    with pytest.raises(Exception) as info:  # the eager forward's own error about the bad input
        model.transformer(
            hidden_states=torch.zeros(1, 3, 1, 4, 8),
            timestep=torch.zeros(1),
            encoder_hidden_states=torch.zeros(1, 2, 48),
        )
    assert "CppCompileError" not in str(info.value)


# --------------------------------------------------------------------------- persistent cache
def test_compile_cache_goes_to_oscar_cache_unless_set(monkeypatch, tmp_path):
    monkeypatch.delenv("TORCHINDUCTOR_CACHE_DIR", raising=False)
    monkeypatch.setenv("OSCAR_CACHE", str(tmp_path / "oc"))
    assert cp.configure_compile_cache() == str(tmp_path / "oc" / "compile")
    import os

    assert os.environ["TORCHINDUCTOR_CACHE_DIR"] == str(tmp_path / "oc" / "compile")
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path / "mine"))
    assert cp.configure_compile_cache() == str(tmp_path / "mine")
    assert os.environ["TORCHINDUCTOR_CACHE_DIR"] == str(tmp_path / "mine")
    monkeypatch.delenv("OSCAR_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cp.default_compile_cache_dir() == tmp_path / "xdg" / "oscar" / "compile"


def test_compile_cache_is_ours_after_torch_set_its_default(tmp_path):
    """Importing diffusers makes torch set TORCHINDUCTOR_CACHE_DIR to its /tmp default: that is not a choice."""
    import os
    import subprocess
    import sys

    code = (
        "import oscar_core.model.world_model, os\n"  # diffusers' import asks torch for its cache folder
        "from torch._inductor.runtime.cache_dir_utils import cache_dir, default_cache_dir\n"
        "before = os.environ.get('TORCHINDUCTOR_CACHE_DIR')\n"
        "from oscar_core.model.compile_policy import configure_compile_cache\n"
        "print(before == os.path.abspath(default_cache_dir()), configure_compile_cache(), cache_dir())"
    )
    env = {k: v for k, v in os.environ.items() if k != "TORCHINDUCTOR_CACHE_DIR"}
    env["OSCAR_CACHE"] = str(tmp_path / "oc")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=False)
    assert proc.returncode == 0, proc.stderr
    ours = str(tmp_path / "oc" / "compile")
    assert proc.stdout.split() == ["True", ours, ours]


# --------------------------------------------------------------------------- CLI options
@pytest.mark.parametrize(
    "argv, expected",
    [
        ([], "auto"),
        (["--compile"], "always"),
        (["--compile", "never"], "never"),
        (["--no-compile"], "never"),
        (["--compile", "auto"], "auto"),
    ],
)
def test_compile_options(argv, expected):
    parser = argparse.ArgumentParser()
    cp.add_compile_options(parser)
    assert parser.parse_args(argv).compile == expected


def test_compile_options_refuse_a_bad_mode_and_a_contradiction(capsys):
    parser = argparse.ArgumentParser()
    cp.add_compile_options(parser)
    for argv in (["--compile", "yes"], ["--compile", "always", "--no-compile"]):
        with pytest.raises(SystemExit):
            parser.parse_args(argv)
    assert "invalid choice: 'yes'" in capsys.readouterr().err


# --------------------------------------------------------------------------- dtype and timings
def test_dtype_none_is_bfloat16_on_cuda_only(monkeypatch):
    seen = {}
    from oscar_core.model import world_model

    monkeypatch.setattr(world_model, "cast_model", lambda m, device, dtype: seen.setdefault("dtype", dtype))
    monkeypatch.setattr(world_model, "VideoVAE", lambda vae, device, dtype, offload: seen.setdefault("vae", dtype))
    OscarWorldModel.from_modules(build_tiny_transformer(), build_tiny_vae(), device="cuda")
    assert seen == {"dtype": torch.bfloat16, "vae": torch.bfloat16}
    seen.clear()
    OscarWorldModel.from_modules(build_tiny_transformer(), build_tiny_vae(), device="cpu")
    assert seen == {"dtype": None, "vae": torch.float32}


def test_rollout_timings_cover_encode_sample_decode(clip):
    import time

    first, skel = clip
    t0 = time.perf_counter()
    result = _model().rollout(first, skel, sampler=SAMPLER, progress=False)
    wall = time.perf_counter() - t0
    assert set(result.timings) == {"encode", "sample", "decode"}
    assert all(v > 0 for v in result.timings.values()) and sum(result.timings.values()) <= wall


def test_weights_are_read_straight_onto_the_gpu(monkeypatch, tmp_path):
    """from_pretrained(device="cuda") asks safetensors for CUDA tensors (no host copy); the CPU path stays on the
    CPU, and an offloaded VAE is read to the CPU. The reads themselves are redirected to the CPU (no GPU here)."""
    import safetensors.torch

    from oscar_core.model import cosmos_dit, world_model

    folder = _model().save_pretrained(tmp_path / "m")
    original, asked = safetensors.torch.load_file, []

    def load_file(path, device="cpu"):
        asked.append((Path(path).parent.name, device))
        return original(path, device="cpu")

    monkeypatch.setattr(safetensors.torch, "load_file", load_file)
    monkeypatch.setattr(cosmos_dit, "cast_model", lambda model, device=None, dtype=None: model)
    monkeypatch.setattr(world_model, "cast_model", lambda model, device=None, dtype=None: model)
    monkeypatch.setattr(world_model, "VideoVAE", lambda vae, device, dtype, offload: vae)
    monkeypatch.setattr("oscar_core._util.devices.device_problem", lambda device: None)  # as if this machine had CUDA
    OscarWorldModel.from_pretrained(folder, device="cuda")
    assert asked == [("transformer", "cuda"), ("vae", "cuda")]
    asked.clear()
    OscarWorldModel.from_pretrained(folder, device="cuda", offload_vae=True)
    assert asked == [("transformer", "cuda"), ("vae", "cpu")]
    asked.clear()
    OscarWorldModel.from_pretrained(folder, device="cpu")
    assert asked == [("transformer", "cpu"), ("vae", "cpu")]


def test_the_decision_is_said_once_per_job_not_once_per_cell(caplog):
    """`oscar eval run` rolls many cells out with one model: the compile=auto line is logged once."""
    from oscar_core.model.sampler import SamplerConfig

    model = _model().set_compile("auto", cells=4)
    with caplog.at_level("INFO", logger="oscar"):
        for _ in range(4):
            model._prepare_compile(17, 9, SamplerConfig(steps=2))
    said = [r.getMessage() for r in caplog.records if r.getMessage().startswith("compile=auto")]
    assert len(said) == 1 and "eager on cpu" in said[0], said


def test_a_rollout_draws_bars_only_on_a_terminal(clip, monkeypatch, capsys):
    """`oscar rollout 2> log` must not fill the log with tqdm lines: progress=True is only a wish."""
    from oscar_core.model.sampler import SamplerConfig

    first, skel = clip
    model = _model()
    monkeypatch.setattr(sys.stderr, "isatty", lambda: False, raising=False)
    model.rollout(first, skel[:9], sampler=SamplerConfig(steps=2), progress=True)
    assert "%|" not in capsys.readouterr().err
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    model.rollout(first, skel[:9], sampler=SamplerConfig(steps=2), progress=True)
    assert "%|" in capsys.readouterr().err  # the same call on a terminal does draw
