"""docs/benchmarks.md is generated from benchmarks/measured/*.json by benchmarks/make_docs.py and kept up to date."""

from __future__ import annotations

import importlib.util
import json

from _paths import REPO


def make_docs():
    spec = importlib.util.spec_from_file_location("make_docs", REPO / "benchmarks" / "make_docs.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_page_is_what_the_committed_json_gives():
    assert (REPO / "docs" / "benchmarks.md").read_text() == make_docs().render_page(), (
        "docs/benchmarks.md is out of date: run python benchmarks/make_docs.py"
    )


def test_every_committed_measurement_carries_date_commit_and_machine():
    files = sorted((REPO / "benchmarks" / "measured").glob("*.json"))
    assert files
    for f in files:
        prov = json.loads(f.read_text())["provenance"]
        assert prov["date"] and prov["commit"] and prov["machine"]["cpus"] >= 1 and prov["command"], f.name


def test_the_generator_renders_records_nested_values_gpu_files_and_missing_provenance(tmp_path):
    prov = {
        "date": "2026-01-02T03:04:05+00:00",
        "commit": "0123456789ab",
        "command": "python benchmarks/rollout.py",
        "machine": {"processor": "x86_64", "cpus": 2, "load_average": 3.5},
    }
    (tmp_path / "rollout.json").write_text(
        json.dumps(
            {
                "provenance": prov,
                "settings": {"repeats": 3, "steps": 4},
                "tiny": [
                    {"size": "128x64", "step_ms": 6.123456, "batched": True},
                    {"size": "256x128", "step_ms": 33.0},
                ],
            }
        )
    )
    (tmp_path / "rollout_gpu.json").write_text(
        json.dumps({"measured": {"device": "NVIDIA H100", "rows": [{"preset": "fast", "seconds_per_chunk": 1.25}]}})
    )
    page = make_docs().render_page(tmp_path)
    assert page.index("## World-model rollout\n") < page.index("## World-model rollout (GPU)\n")
    assert "- **date** 2026-01-02T03:04:05+00:00 · **commit** `0123456789ab`" in page
    assert "- **machine** processor x86_64, cpus 2, load_average 3.5" in page
    assert "| size | step_ms | batched |\n|---|---|---|\n| 128x64 | 6.123 | yes |\n| 256x128 | 33 | – |" in page
    assert "| repeats | 3 |" in page and "| preset | seconds_per_chunk |\n|---|---|\n| fast | 1.25 |" in page
    assert "*Provenance: not recorded in this file.*" in page  # the GPU file has none
    assert "| `rollout_gpu.json` | – | `–` |" in page
    # a changed measurement changes the page: the up-to-date test above cannot pass on stale JSON
    (tmp_path / "rollout.json").write_text((tmp_path / "rollout.json").read_text().replace("33.0", "34.0"))
    assert make_docs().render_page(tmp_path) != page
