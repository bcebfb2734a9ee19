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
    assert {r["dit"] for r in rows} == {"oscar OscarTransformer3DModel", "diffusers CosmosTransformer3DModel"}
    assert all(r["max_abs_diff"] == 0.0 and r["cpu_ms"] > 0 for r in rows)


def test_zero_repeats_are_refused(tmp_path, capsys):
    assert _bench().main(["--repeats", "0", "--json", str(tmp_path / "out.json")]) == 2
    assert "--repeats: expected at least 1, found 0" in capsys.readouterr().err
    assert not (tmp_path / "out.json").exists()
