"""benchmarks/cosmos_dit.py: its in-process part runs both DiT classes on a toy step and finds them equal; bad
settings are refused before any work."""

import importlib.util

import pytest
from _paths import REPO

pytest.importorskip("diffusers")


def _bench():
    spec = importlib.util.spec_from_file_location("bench_cosmos_dit", REPO / "benchmarks" / "cosmos_dit.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_compute_rows_cover_both_classes_and_agree():
    import torch

    threads = torch.get_num_threads()
    try:
        rows = _bench().measure_compute(1)
    finally:
        torch.set_num_threads(threads)
    assert {r["dit"] for r in rows} == {
        "oscar OscarTransformer3DModel",
        "oscar OscarTransformer3DModel, RoPE tables made every call",
        "diffusers CosmosTransformer3DModel",
    }
    assert all(r["max_abs_diff"] == 0.0 and r["cpu_ms"] > 0 for r in rows)


def test_the_made_every_call_row_makes_new_tables_and_the_kept_row_does_not():
    import torch

    from oscar_core.model._cosmos_layers import RotaryPositions

    rope, cpu = RotaryPositions(32, (8, 8, 8), (1.0, 1.0, 1.0)), torch.device("cpu")
    kept = rope((5, 8, 8), cpu, 10.0)
    with _bench().rope_made_every_call():
        made = rope((5, 8, 8), cpu, 10.0)
    assert made[0] is not kept[0] and torch.equal(made[0], kept[0])
    assert rope((5, 8, 8), cpu, 10.0)[0] is kept[0]


def test_rope_rows_time_both_grids():
    rows = _bench().measure_rope(1)
    assert [r["grid"] for r in rows] == ["toy, 5 x 8 x 8 tokens", "2B, 21 x 18 x 32 tokens"]
    assert all(r["made_cpu_ms"] > 0 and r["kept_cpu_ms"] >= 0 for r in rows)


def test_zero_repeats_are_refused(tmp_path, capsys):
    assert _bench().main(["--repeats", "0", "--json", str(tmp_path / "out.json")]) == 2
    assert "--repeats: expected at least 1, found 0" in capsys.readouterr().err
    assert not (tmp_path / "out.json").exists()
