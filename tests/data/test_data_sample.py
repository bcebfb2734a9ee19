"""The offline data quick start: `oscar data sample-dataset`, then every stage, with no download."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("pyarrow")

from oscar_core.cli import main
from oscar_core.data.dedup import trajectory_embedding
from oscar_core.data.engine import read_stage
from oscar_core.data.stats import column_of
from oscar_core.train.clips import ClipSet


@pytest.mark.slow
def test_the_quick_start_runs_offline_and_every_episode_meets_its_fate(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")  # nothing may be fetched
    data, run = tmp_path / "data" / "sample", tmp_path / "runs" / "sample"
    assert main(["data", "sample-dataset", str(data), "--json"]) == 0
    expected = json.loads(capsys.readouterr().out)["expected"]
    assert (data / "videos" / "observation.images.exterior_1_left" / "chunk-000" / "file-000.mp4").is_file()
    assert len(list(data.rglob("*.mp4"))) == 1  # one MP4 shared by all 7 episodes
    common = ["--workers", "1", "--no-progress"]
    assert main(["data", "ingest", str(data), "--reader", "lerobot", "--out", str(run), *common]) == 0
    assert main(["data", "filter", str(run), *common]) == 0
    assert main(["data", "dedup", str(run), "--embedder", "trajectory", *common]) == 0
    assert main(["data", "export", str(run), "--out", str(tmp_path / "clips"), *common]) == 0
    assert main(["data", "stats", str(run), "--no-html"]) == 0
    fates = {r["id"]: column_of(r) or "kept" for r in read_stage(str(run / "dedup"))}
    assert fates == expected
    assert len(list(ClipSet(tmp_path / "clips"))) == list(expected.values()).count("kept")
    assert main(["data", "sample-dataset", str(data)]) == 2  # never written over
    for stage in ("ingest", "filter", "dedup", "export"):  # each stage keeps a timestamped log in the run folder
        (log,) = (run / "logs").glob(f"data-{stage}-*.log")
        assert "shards done" in log.read_text(), stage


def test_dedup_without_an_embedder_choice_needs_a_model(tmp_path, capsys):
    assert main(["data", "dedup", str(tmp_path), "--workers", "1"]) == 2
    assert "--embedder trajectory" in capsys.readouterr().err


def test_trajectory_embedding_is_the_shape_of_the_motion():
    rng = np.random.default_rng(0)
    pts = rng.standard_normal((64, 5, 3)).cumsum(axis=0)
    e = trajectory_embedding(pts)
    assert e.shape == (64 * 3,) and np.isclose(np.linalg.norm(e), 1.0)
    assert np.allclose(trajectory_embedding(pts + [1.0, -2.0, 0.5]), e)  # where it happens does not matter
    assert np.allclose(trajectory_embedding(pts * 3.0), e)  # nor how large (the RMS check judges that)
    assert trajectory_embedding(pts[::-1]) @ e < 0.99  # its direction in time does
