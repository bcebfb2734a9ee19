"""benchmarks/closed_loop.py: its CPU split per part and the rows it sums over interleaved rounds."""

from __future__ import annotations

import importlib.util
import sys
import threading
import time
import types

import pytest
from _paths import REPO


@pytest.fixture
def bench(monkeypatch):
    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))
    spec = importlib.util.spec_from_file_location("bench_closed_loop", REPO / "benchmarks" / "closed_loop.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _burn(seconds: float) -> None:
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass


def test_cpu_split_sums_each_part_in_every_thread_and_restores_the_functions(bench, monkeypatch):
    fake = types.ModuleType("fake_parts")

    class Worker:
        def work(self, seconds):
            _burn(seconds)
            return "done"

    fake.burn, fake.Worker = _burn, Worker
    monkeypatch.setitem(sys.modules, "fake_parts", fake)
    monkeypatch.setattr(bench, "CPU_PARTS", {"burn": ("fake_parts", "burn"), "work": ("fake_parts", "Worker.work")})
    totals = {}
    with bench.cpu_split(totals):
        fake.burn(0.05)
        thread = threading.Thread(target=fake.burn, args=(0.1,))
        thread.start()
        thread.join()
        assert Worker().work(0.08) == "done"
        time.sleep(0.05)  # waiting is no CPU time of any part
    assert fake.burn is _burn and "work" in vars(Worker) and Worker.work.__name__ == "work"
    assert totals["burn"] == pytest.approx(0.15, abs=0.03)
    assert totals["work"] == pytest.approx(0.08, abs=0.02)
    fake.burn(0.01)
    assert totals["burn"] == pytest.approx(0.15, abs=0.03)  # unwrapped: no longer counted


def test_rows_sum_the_rounds_and_the_rest_is_other(bench):
    def run(cells, cpu, parts):
        return {
            "batch_cells": 4,
            "cells": cells,
            "steps": 2 * cells,
            "failed": 0,
            "wall_s": 2 * cpu,
            "cpu_s": cpu,
            "wall_ms": {p: 10.0 * cells for p in bench.PARTS},
            "cpu_parts_s": parts,
            "world_calls": [(1.0, 0.5, 1), (3.0, 1.5, 4)],  # (wall s, CPU s, chunks) of each world step
        }

    row = bench._sum_rounds([run(8, 30.0, {"dit": 12.0, "vae_decode": 6.0}), run(8, 34.0, {"dit": 14.0})])
    assert (row["cells"], row["steps"], row["rounds"]) == (16, 32, 2)
    assert row["cells_per_cpu_minute"] == pytest.approx(16 / (64.0 / 60))
    assert row["cells_per_wall_minute"] == pytest.approx(16 / (128.0 / 60))
    per_step = row["cpu_ms_per_step"]
    assert per_step["dit"] == pytest.approx(26_000 / 32) and per_step["vae_decode"] == pytest.approx(6_000 / 32)
    assert per_step["total"] == pytest.approx(64_000 / 32)
    assert per_step["other"] == pytest.approx((64_000 - 32_000) / 32)
    assert row["model_wall_ms_per_step"] == pytest.approx(160 / 32)
    visible = row["policy_visible"]
    assert visible["world_calls"] == 4
    assert visible["wall_ms_per_call"] == pytest.approx(2000) and visible["cpu_ms_per_call"] == pytest.approx(1000)
    assert visible["cpu_ms_per_chunk"] == pytest.approx(4000 / 10)


def test_world_latency_times_each_world_step_and_counts_its_chunks(bench, monkeypatch):
    fake = types.ModuleType("fake_world")

    class World:
        def step(self, q, gripper):
            _burn(0.05)
            return "frames"

    def together(requests):
        _burn(0.02 * len(requests))
        return ["frames"] * len(requests)

    fake.World, fake.together = World, together
    monkeypatch.setitem(sys.modules, "fake_world", fake)
    monkeypatch.setattr(
        bench,
        "WORLD_STEPS",
        {("fake_world", "World.step"): lambda args: 1, ("fake_world", "together"): lambda args: len(args[0])},
    )
    calls = []
    with bench.world_latency(calls):
        assert World().step(None, None) == "frames"
        assert fake.together([1, 2, 3]) == ["frames"] * 3
    assert fake.together is together and World.step.__name__ == "step"
    assert [c[2] for c in calls] == [1, 3]
    assert calls[0][1] == pytest.approx(0.05, abs=0.02) and calls[1][1] == pytest.approx(0.06, abs=0.02)
    assert all(wall >= cpu * 0.9 for wall, cpu, _ in calls)


def test_every_timed_function_exists_where_the_benchmark_patches_it(bench):
    """A renamed or moved function would make the benchmark fail at its first run (as `_report` once did)."""
    targets = [*bench.CPU_PARTS.values(), *bench.WORLD_STEPS]
    for module, attr in targets:
        owner = importlib.import_module(module)
        for part in attr.split("."):
            assert hasattr(owner, part), f"{module}.{attr}: no {part!r}"
            owner = getattr(owner, part)
        assert callable(owner), f"{module}.{attr} is not callable"


def test_samplers_the_gpu_table_names(bench):
    """teacher (the card's, else the library's 35 guided steps), `fast` (its preset) and a 4-step sampler without
    guidance, as `make bench-gpu` asks for them."""
    model = bench.random_world_model("tiny", "cpu")
    teacher = bench._sampler(model, None, None)
    fast = bench._sampler(model, None, None, preset="fast")
    four = bench._sampler(model, 4, None, no_guidance=True)
    assert (teacher.steps, teacher.guidance) == (35, 6.0)
    assert (fast.steps, fast.guidance_interval) == (12, (0.0, 0.8))
    assert (four.steps, four.guidance) == (4, None)


@pytest.mark.slow
def test_a_random_weights_model_runs_closed_loop_with_a_random_tiny_decoder(bench, tmp_path, monkeypatch):
    """The path `make bench-gpu` takes for the 2B (--size, --device, --tiny-decoder random, --tiny-encoder random,
    --no-guidance), on the CPU with the tiny configuration: one chunk per cell, batch 1 and 2."""
    import json

    out = tmp_path / "closed_loop.json"
    argv = ["closed_loop.py", "--size", "tiny", "--device", "cpu", "--sessions", "1", "--horizon", "17"]
    argv += ["--batch", "2", "--steps", "2", "--no-guidance", "--tiny-decoder", "random", "--no-vae-probe"]
    argv += ["--tiny-encoder", "random"]
    monkeypatch.setattr(sys, "argv", [*argv, "--json", str(out)])
    assert bench.main() == 0
    result = json.loads(out.read_text())
    assert (result["model"], result["device"], result["dtype"]) == ("random tiny", "cpu", "float32")
    assert result["decoder"] == "tiny, random weights" and result["steps"] == 2
    assert result["condition_encoder"] == "tiny, random weights"
    assert result["guidance"].startswith("None")
    rows = {r["batch_cells"]: r for r in result["rows"]}
    assert set(rows) == {1, 2} and all(r["cells"] == 2 and r["failed"] == 0 for r in rows.values())
    assert rows[1]["policy_visible"]["world_calls"] == 2 and rows[2]["policy_visible"]["world_calls"] == 1
    assert "cells_per_gpu_hour" not in rows[1]  # only on CUDA
