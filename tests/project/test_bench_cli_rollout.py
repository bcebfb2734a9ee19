"""benchmarks/cli_rollout.py: one tiny one-chunk `oscar rollout` process measured, and a failing one refused."""

import importlib.util
import json

import pytest
from _paths import REPO


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_cli_rollout", REPO / "benchmarks" / "cli_rollout.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow  # end to end: a model exported and measured in an `oscar rollout` process (12 CPU s)
def test_tiny_never_one_repeat_on_cpu(bench, tmp_path, capsys):
    out = tmp_path / "result.json"
    code = bench.main(
        ["--size", "tiny", "--repeats", "1", "--device", "cpu", "--work", str(tmp_path / "work"), "--json", str(out)]
    )
    table = capsys.readouterr().out
    assert code == 0
    result = json.loads(out.read_text())
    assert result["device"] == "cpu" and result["machine"]["cpus"] >= 1 and "gpu" not in result["machine"]
    assert (result["frames"], result["width"], result["height"]) == (17, 64, 64)
    [row] = result["rows"]
    assert row["mode"] == "never" and row["repeats"] == 1 and "never" in row["compile_reason"]
    [run] = row["runs"]
    assert run["frames"] == 17 and run["chunks"] == 1 and run["device"] == "cpu" and run["size"] == [64, 64]
    parts, model = run["parts"], run["model"]
    assert set(parts) == set(bench.PARTS) and set(model) == {"encode", "sample", "decode"}
    assert all(v >= 0 for v in [*parts.values(), *model.values()])
    assert model["sample"] > 0 and parts["import"] > 0
    # the parts are measured inside the process and the wall outside it: they cannot add up to more
    assert sum(parts.values()) + sum(model.values()) <= run["wall_s"] + 0.05
    assert run["cli_wall_s"] <= run["wall_s"] + 0.05 and run["cpu_s"] > 0
    assert run["fixed_s"] == pytest.approx(run["wall_s"] - sum(model.values()))
    assert row["new_frames"] == 16 and row["frames_per_s_wall"] == pytest.approx(16 / row["wall_s"])
    assert row["frames_per_s_sample"] == pytest.approx(16 / row["sample_s"])
    assert row["vae_s"] == pytest.approx(model["encode"] + model["decode"])
    assert "never" in table and "fixed" in table and f"{row['wall_s']:.2f}" in table


@pytest.mark.slow  # end to end: an `oscar rollout` process that imports the model stack, then refuses (8 CPU s)
def test_a_failing_rollout_process_fails_the_benchmark(bench, tmp_path, capsys):
    out = tmp_path / "result.json"
    code = bench.main(
        [
            "--size",
            "tiny",
            "--repeats",
            "1",
            "--json",
            str(out),
            "--work",
            str(tmp_path / "work"),
            "--rollout-arg=--size=60x60",
        ]
    )  # not a multiple of 16: the CLI refuses it, exit 2
    err = capsys.readouterr().err
    assert code == 1 and not out.exists()
    assert "never (repeat 1): the rollout process exited with 2" in err and "60x60" in err


def test_the_plan_alternates_a_baseline_with_never_and_runs_cold_before_warm(bench):
    groups = bench.plan(True, {"OSCAR_FULL_EXIT": "1"})
    assert [[label for label, *_ in g] for g in groups] == [
        ["never, OSCAR_FULL_EXIT=1", "never"],
        ["always, cold cache"],
        ["always, warm cache"],
        ["auto"],
    ]
    assert groups[0][0][3] == {"OSCAR_FULL_EXIT": "1"} and groups[0][1][3] == {}
    assert groups[1][0][2] == "fresh" and groups[2][0][2] == "warm"  # warm: the cache the cold runs filled
    assert [g[0][1] for g in bench.plan(False)] == ["never"]
