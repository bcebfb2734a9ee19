"""benchmarks/train.py --step-table: oscar's training step under activation checkpointing none/full and
model.compile false/true, exercised on the CPU at the tiny size.

What is asserted cannot flake on a shared machine:

* the variants' first-step losses and gradient norms agree (the same seed and batch; checkpointing changes
  memory, not arithmetic — eager none and full agree to the last bit here, single-threaded — and compile within
  the float32 tolerance);
* ``full`` saves fewer activation bytes than ``none``: a *count* of the storages autograd saves in one forward
  (``saved_tensors_hooks``), exact and the same on every run. The measured peak resident size is not asserted:
  at the tiny size (0.15 M parameters, a few hundred KiB of activations) it is below the resident size's noise
  (allocator arenas, pages touched by the sampling thread), so a comparison of the two would flake;
* the modelled activation bytes (``oscar_core.train.memory``, float32: twice the bf16 constant) are within a
  factor two of the count for ``none`` (a check of the library's constant at another width);
* a disagreement exits 1 naming the variants; ``--device cuda`` without CUDA and ``--step-size 2b`` on the CPU
  are refused with exit 2 before any work.
"""

from __future__ import annotations

import json

import pytest
import torch
from _paths import REPO

SCRIPT = REPO / "benchmarks" / "train.py"
VARIANTS = ["none", "full", "none+compile", "full+compile"]


def step_table(capsys, monkeypatch, *args) -> tuple[int, str]:
    """``benchmarks/train.py --step-table ARGS`` with its parent in this process (it only starts a fresh process per
    variant, which measures, and writes the table; its own process would only add an import of torch and oscar):
    the exit code (returned, or an argparse SystemExit) and stderr. One thread per variant, as the table is run."""
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    threads = torch.get_num_threads()  # main sets one thread for the process
    try:
        code = _bench_module().main(["--step-table", *args])
    except SystemExit as exc:
        code = exc.code
    finally:
        torch.set_num_threads(threads)
    return code, capsys.readouterr().err


def test_the_step_variants_are_the_four_with_the_eager_reference_first():
    bench = _bench_module()
    assert [bench.variant_name(c, k) for c, k in bench.STEP_VARIANTS] == VARIANTS


@pytest.mark.slow
def test_step_table_tiny_cpu(tmp_path, capsys, monkeypatch):
    # none+compile left out: compiled against eager without checkpointing is test_compiled_step_equals_eager's case
    # (tests/train/test_train_memory.py, per-parameter gradients), and each compile costs ~40 CPU s here
    out = tmp_path / "step.json"
    chosen = ["none", "full", "full+compile"]
    args = ["--step-size", "tiny", "--step-repeats", "2", "--step-variants", ",".join(chosen), "--json", str(out)]
    code, err = step_table(capsys, monkeypatch, *args)
    assert code == 0, err[-3000:]
    t = json.loads(out.read_text())["step_table"]
    assert [r["variant"] for r in t["variants"]] == chosen
    assert t["size"] == "tiny" and t["device"] == "cpu" and t["dtype"] == "float32" and t["disagreeing"] == []
    for r in t["variants"]:
        assert r["activation_checkpointing"] == r["variant"].split("+")[0]
        assert r["compile"] == r["variant"].endswith("+compile")
        assert len(r["step_s"]) == len(r["step_cpu_s"]) == 2
        assert 0 < r["best_step_s"] <= r["median_step_s"]
        assert r["peak_bytes"] >= 0 and r["steady_peak_bytes"] >= 0
        # the tiny config: 2 blocks of hidden 64, micro-batch 2 of 3 latent frames x 4 x 4 latents -> 12 tokens
        assert r["layers"] == 2 and r["hidden"] == 64 and r["latent_shape"] == [2, 16, 3, 4, 4]
        assert r["tokens_per_clip"] == 12
        m = r["modelled"]
        assert m["total"] == pytest.approx(m["state"] + m["optimizer_temporaries"] + m["activations"])
        assert m["state"] == 20 * r["params"]
        if r["compile"]:
            assert r["compile_s"] > 0 and r["saved_activation_bytes"] is None
        else:
            assert r["compile_s"] is None and r["saved_activation_bytes"] > 0
    # correctness: the same first step in every variant
    assert t["max_diff"] <= t["tolerance"] == 1e-4
    agree = {c["variant"]: c for c in t["agreement"]}
    assert agree["full"]["max_diff"] <= 1e-6  # checkpointing recomputes the same operations in the same order
    losses = {r["variant"]: r["first_step_loss"] for r in t["variants"]}
    assert all(v == pytest.approx(losses["none"], rel=1e-4) for v in losses.values())
    # memory, by count: full keeps only what lies outside the checkpointed blocks
    saved = {r["variant"]: r["saved_activation_bytes"] for r in t["variants"]}
    assert saved["full"] < 0.5 * saved["none"]
    none = next(r for r in t["variants"] if r["variant"] == "none")
    assert 0.5 < none["modelled"]["activations_none"] / saved["none"] < 2.0


@pytest.mark.slow
def test_step_table_disagreement_exits_nonzero_naming_variants(tmp_path, capsys, monkeypatch):
    # a negative tolerance: every variant "disagrees" (eager only, so no compile: quick)
    out = tmp_path / "step.json"
    code, err = step_table(
        capsys,
        monkeypatch,
        "--step-size",
        "tiny",
        "--step-variants",
        "none,full",
        "--step-repeats",
        "1",
        "--step-tolerance",
        "-1",
        "--json",
        str(out),
    )
    assert code == 1
    assert "FAILED" in err and "none (" in err and "full (" in err
    t = json.loads(out.read_text())["step_table"]  # the measurements are written all the same
    assert t["disagreeing"] == ["none", "full"]


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the refusal on a machine without CUDA")
def test_cuda_refused_without_cuda(tmp_path, capsys, monkeypatch):
    code, err = step_table(
        capsys, monkeypatch, "--step-size", "2b", "--device", "cuda", "--json", str(tmp_path / "x.json")
    )
    assert code == 2
    assert "CUDA is not available" in err and not (tmp_path / "x.json").exists()


def test_2b_refused_on_cpu(tmp_path, capsys, monkeypatch):
    code, err = step_table(capsys, monkeypatch, "--step-size", "2b", "--json", str(tmp_path / "x.json"))
    assert code == 2
    assert "--device cuda" in err and not (tmp_path / "x.json").exists()


def test_unknown_variant_refused(tmp_path, capsys, monkeypatch):
    code, err = step_table(capsys, monkeypatch, "--step-size", "tiny", "--step-variants", "none,half")
    assert code == 2 and "--step-variants" in err and "half" in err


def _bench_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("bench_train", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_compare_leaves_out_of_memory_rows_and_measures_relative_differences():
    bench = _bench_module()

    def row(name, loss, grad, per):
        return {
            "variant": name,
            "first_step_loss": loss,
            "first_step_grad_norm": grad,
            "first_step_param_grad_norms": per,
        }

    rows = [
        {"variant": "none", "out_of_memory": True, "error": "CUDA out of memory"},
        row("full", 2.0, 10.0, [6.0, 8.0]),
        row("full+compile", 2.002, 10.0, [6.0, 8.5]),
    ]
    got = {c["variant"]: c for c in bench._compare(rows)}
    assert set(got) == {"full", "full+compile"}  # the reference is the first measured row
    assert got["full"]["max_diff"] == 0.0
    c = got["full+compile"]
    assert c["loss_rel_diff"] == pytest.approx(1e-3) and c["grad_norm_rel_diff"] == 0.0
    assert c["param_grad_norm_max_diff"] == pytest.approx(0.05) and c["max_diff"] == pytest.approx(0.05)
    # a parameter list of another length (a different model) can never agree
    assert bench._compare([row("a", 1.0, 1.0, [1.0]), row("b", 1.0, 1.0, [1.0, 0.0])])[1]["max_diff"] == float("inf")
