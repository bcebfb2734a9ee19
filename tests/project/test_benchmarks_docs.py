"""docs/benchmarks.md is generated from benchmarks/measured/*.json by benchmarks/make_docs.py (``make docs``) and kept
up to date: a headline table, then one section per benchmark with its CPU and GPU runs side by side."""

from __future__ import annotations

import importlib.util
import json

import pytest
from _paths import REPO


def make_docs():
    spec = importlib.util.spec_from_file_location("make_docs", REPO / "benchmarks" / "make_docs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_page_is_what_the_committed_json_gives():
    assert (REPO / "docs" / "benchmarks.md").read_text() == make_docs().render_page(REPO / "benchmarks" / "measured"), (
        "docs/benchmarks.md is out of date: run make docs"
    )


def test_every_committed_measurement_carries_date_commit_and_machine():
    files = sorted((REPO / "benchmarks" / "measured").glob("*.json"))
    assert files
    for f in files:
        prov = json.loads(f.read_text())["provenance"]
        assert prov["date"] and prov["commit"] and prov["machine"]["cpus"] >= 1 and prov["command"], f.name


PROV_CPU = {
    "date": "2026-01-02T03:04:05+00:00",
    "commit": "0123456789ab",
    "command": "python benchmarks/rollout.py",
    "machine": {"processor": "x86_64", "cpus": 2, "load_average": 3.5},
}
PROV_GPU = {
    "date": "2026-01-03T00:00:00+00:00",
    "commit": "ba9876543210",
    "command": "python benchmarks/rollout.py --gpu",
    "machine": {"cpus": 16, "load_average": 1.0, "gpu": "NVIDIA H100 80GB HBM3"},
    "note": "cut short",
}


def write_fixtures(folder):
    """A rollout benchmark measured on the CPU and on a GPU, and a render benchmark without provenance."""
    (folder / "rollout.json").write_text(
        json.dumps(
            {
                "provenance": PROV_CPU,
                "settings": {"repeats": 3, "steps": 4},
                "computed": {"fps_at_utilisation": {"0.2": 2.5, "0.5": 6.25}},
                "presets": [
                    {"preset": "fast", "variant": "eager", "steps": 12, "seconds_per_chunk": 40.0, "batched": True},
                    {"preset": "paper", "variant": "eager", "steps": 35, "seconds_per_chunk": 120.0},
                ],
            }
        )
    )
    (folder / "rollout_gpu.json").write_text(
        json.dumps(
            {
                "provenance": PROV_GPU,
                "settings": {"repeats": 2, "steps": 4},
                "computed": {"fps_at_utilisation": {"0.2": 2.5, "0.5": 6.25}},
                "grad_norms": [float(i) for i in range(20)],
                "presets": [
                    {"preset": "fast", "variant": "eager", "steps": 12, "seconds_per_chunk": 5.5, "batched": True},
                    {"preset": "fast", "variant": "compiled", "steps": 12, "seconds_per_chunk": 4.0},
                ],
            }
        )
    )
    (folder / "render.json").write_text(json.dumps({"rows": [{"embodiment": "toyarm", "fps": 1000.0}]}))


def fixture_headlines(module):
    H = module.Headline
    return (
        H("fast, compiled", "rollout_gpu.json", "presets[preset=fast,variant=compiled].seconds_per_chunk", "s"),
        H("fast on the CPU", "rollout.json", "presets[preset=fast,variant=eager].seconds_per_chunk", "ms", scale=1e3),
        H(
            "at half",
            "rollout.json",
            "computed.fps_at_utilisation.0.5",
            "frames/s",
            kind="computed",
            machine="one H100",
        ),
        H("not measured here", "train.json", "speed[run=x].steps_per_s", "steps/s"),
    )


def test_the_headline_table_reads_each_figure_from_its_file(tmp_path, monkeypatch):
    write_fixtures(tmp_path)
    module = make_docs()
    monkeypatch.setattr(module, "HEADLINES", fixture_headlines(module))
    page = module.render_page(tmp_path)
    head = page[: page.index("\n## ")]
    assert "| figure | value | unit | kind | machine | date | section · record |" in head
    rollout = "[World-model rollout](#world-model-rollout)"
    assert (
        f"| fast, compiled | 4 | s | measured | NVIDIA H100 80GB HBM3 | 2026-01-03 | {rollout} · "
        "[`rollout_gpu.json`](../benchmarks/measured/rollout_gpu.json) |" in head
    )
    assert f"| fast on the CPU | 40000 | ms | measured | 2 CPUs, load 3.5 | 2026-01-02 | {rollout} · " in head
    assert f"| at half | 6.25 | frames/s | computed | one H100 | 2026-01-02 | {rollout} · " in head
    assert "not measured here" not in page  # its file is absent: the row is left out
    assert head.count("\n|") == 2 + 3  # header, rule, three figures
    # each section's link is the anchor GitHub gives its heading
    assert module.slug("Teacher, `fast` and the few-step student") == "teacher-fast-and-the-few-step-student"
    assert "## World-model rollout\n" in page and "## Skeleton rendering\n" in page


def test_a_headline_from_a_section_with_its_own_provenance_gives_that_section_s_date(tmp_path, monkeypatch):
    write_fixtures(tmp_path)
    data = json.loads((tmp_path / "rollout.json").read_text())
    data["added"] = {"provenance": {**PROV_CPU, "date": "2026-02-09T00:00:00+00:00"}, "fps": 61.5}
    (tmp_path / "rollout.json").write_text(json.dumps(data))
    module = make_docs()
    H = module.Headline
    monkeypatch.setattr(
        module,
        "HEADLINES",
        (
            H("added later", "rollout.json", "added.fps", "frames/s", kind="computed", provenance="added.provenance"),
            H("the file's own", "rollout.json", "added.fps", "frames/s", kind="computed"),
        ),
    )
    head = module.render_page(tmp_path).split("\n## ")[0]
    assert "| added later | 61.5 | frames/s | computed | 2 CPUs, load 3.5 | 2026-02-09 |" in head
    assert "| the file's own | 61.5 | frames/s | computed | 2 CPUs, load 3.5 | 2026-01-02 |" in head
    monkeypatch.setattr(module, "HEADLINES", (H("x", "rollout.json", "added.fps", "s", provenance="added.nowhere"),))
    with pytest.raises(
        module.HeadlineError,
        match=r"rollout\.json: headline 'x' reads its provenance at added\.nowhere: no field 'nowhere'",
    ):
        module.render_page(tmp_path)


def test_a_headline_the_file_does_not_hold_is_an_error_naming_file_and_path(tmp_path, monkeypatch, capsys):
    write_fixtures(tmp_path)
    module = make_docs()
    wrong = module.Headline("fast, compiled", "rollout_gpu.json", "presets[preset=fast,variant=fused].x", "s")
    monkeypatch.setattr(module, "HEADLINES", (wrong,))
    with pytest.raises(module.HeadlineError, match=r"rollout_gpu\.json: headline 'fast, compiled' reads .*0 records"):
        module.render_page(tmp_path)
    monkeypatch.setattr(module, "MEASURED", tmp_path)
    monkeypatch.setattr(module, "PAGE", tmp_path / "benchmarks.md")
    assert module.main([]) == 2
    assert "rollout_gpu.json" in capsys.readouterr().err and not (tmp_path / "benchmarks.md").exists()


def test_cpu_and_gpu_runs_of_a_benchmark_stand_side_by_side_in_one_section(tmp_path, monkeypatch):
    write_fixtures(tmp_path)
    module = make_docs()
    monkeypatch.setattr(module, "HEADLINES", ())
    page = module.render_page(tmp_path)
    assert page.count("## World-model rollout") == 1 and "## World-model rollout (GPU)" not in page
    rollout = page[page.index("## World-model rollout") : page.index("## Skeleton rendering")]
    # the runs, with where and when
    assert (
        "| CPU | [`rollout.json`](../benchmarks/measured/rollout.json) | 2026-01-02T03:04:05+00:00 | `0123456789ab` |"
        in rollout
    )
    assert (
        "| GPU | [`rollout_gpu.json`](../benchmarks/measured/rollout_gpu.json) | 2026-01-03T00:00:00+00:00 |" in rollout
    )
    assert "- GPU: cut short" in rollout
    # single figures: those that differ with a column per run, then those every run shares
    assert (
        "| figure | CPU | GPU |\n|---|---|---|\n| settings.repeats | 3 | 2 |\n| grad_norms | – | 20 values, 0 to 19 |"
        in rollout
    )
    assert (
        "| figure | every run |\n|---|---|\n| settings.steps | 4 |\n| computed.fps_at_utilisation | 0.2: 2.5, 0.5: 6.25 |"
        in rollout
    )
    # records matched by their text fields; a field that differs gets one column per run, one that agrees one column
    assert (
        "| preset | variant | steps | seconds_per_chunk (CPU) | seconds_per_chunk (GPU) | batched |\n"
        "|---|---|---|---|---|---|\n"
        "| fast | eager | 12 | 40 | 5.5 | yes |\n"
        "| paper | eager | 35 | 120 | – | – |\n"
        "| fast | compiled | 12 | – | 4 | – |"
    ) in rollout
    # a benchmark with one run and no provenance
    render = page[page.index("## Skeleton rendering") :]
    assert "| CPU | [`render.json`](../benchmarks/measured/render.json) | – | – | not recorded | – |" in render
    assert "| embodiment | fps |\n|---|---|\n| toyarm | 1000 |" in render
    # a changed measurement changes the page: the up-to-date test above cannot pass on stale JSON
    (tmp_path / "rollout_gpu.json").write_text((tmp_path / "rollout_gpu.json").read_text().replace("5.5", "5.25"))
    assert module.render_page(tmp_path) != page
