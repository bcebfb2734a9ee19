"""The stage engine: shards written atomically with completion records, resume after a kill, fsspec URLs, and the
Ray engine giving the same manifest as the local one."""

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from _datasets import write_episode

from oscar_core.data import _fs
from oscar_core.data.engine import StageIncomplete, read_stage, run_sharded
from oscar_core.data.run import run_filter, run_ingest


class Double:
    """A toy stage: ``x`` doubled; counts calls through files so a test sees what was (re)done."""

    name = "double"

    def __init__(self, log=None):
        self.log = log

    def __call__(self, rows, shard=""):
        if self.log:
            with open(self.log, "a") as f:
                f.write(shard + "\n")
        return [dict(r, y=2 * r["x"]) for r in rows]


def _rows(rows: list[dict]) -> list[dict]:
    """Manifest rows with NaN (a value not measured, e.g. a filter that is off) as a marker equal to itself."""
    return [{k: "<nan>" if isinstance(v, float) and math.isnan(v) else v for k, v in r.items()} for r in rows]


def rows(n):
    return [{"id": f"e{i:03d}", "x": i} for i in range(n)]


def test_shards_completions_and_skip_on_rerun(tmp_path):
    log = tmp_path / "calls.txt"
    url = str(tmp_path / "stage")
    first = run_sharded(Double(log), rows(10), url, shard_size=4, workers=1, progress=False)
    assert first.processed == ["part-000000", "part-000001", "part-000002"] and not first.skipped
    assert [r["y"] for r in first.rows] == [2 * i for i in range(10)]
    again = run_sharded(Double(log), rows(10), url, shard_size=4, workers=1, progress=False)
    assert again.skipped == first.processed and not again.processed
    assert log.read_text().split() == first.processed  # nothing redone
    # a shard whose completion record is missing (killed between its two writes) is done again, once
    (tmp_path / "stage" / "completions" / "part-000001.json").unlink()
    (tmp_path / "stage" / "shards" / ".part-000002.parquet.0123.tmp").write_bytes(b"half")  # a killed write
    third = run_sharded(Double(log), rows(10), url, shard_size=4, workers=1, progress=False)
    assert third.processed == ["part-000001"] and [r["id"] for r in third.rows] == [r["id"] for r in rows(10)]


def test_another_input_is_refused_not_mixed(tmp_path):
    url = str(tmp_path / "stage")
    run_sharded(Double(), rows(6), url, shard_size=4, workers=1, progress=False)
    with pytest.raises(ValueError, match=r"plan.json: expected the plan of this input"):
        run_sharded(Double(), rows(7), url, shard_size=4, workers=1, progress=False)
    with pytest.raises(ValueError, match="unique episode ids"):
        run_sharded(Double(), rows(3) + rows(1), str(tmp_path / "other"), workers=1, progress=False)


def test_unfinished_stage_is_named(tmp_path):
    url = str(tmp_path / "stage")
    run_sharded(Double(), rows(6), url, shard_size=2, workers=1, progress=False)
    (tmp_path / "stage" / "manifest.parquet").unlink()
    (tmp_path / "stage" / "completions" / "part-000002.json").unlink()
    with pytest.raises(StageIncomplete, match=r"1 of 3 shards not done \(part-000002"):
        read_stage(url)


def test_memory_url(tmp_path):
    pytest.importorskip("pyarrow")
    url = "memory://oscar-test/run/stage"
    res = run_sharded(Double(), rows(5), url, shard_size=2, workers=1, progress=False)
    assert [r["y"] for r in read_stage(url)] == [r["y"] for r in res.rows] == [0, 2, 4, 6, 8]
    assert _fs.listdir(_fs.join(url, "completions")) == ["part-000000.json", "part-000001.json", "part-000002.json"]


def _source(root: Path, n: int) -> str:
    for i in range(n):
        write_episode(root / "src", f"ep{i:02d}", seed=i)
    return str(root / "src")


def test_file_url_run(tmp_path):
    src = _source(tmp_path, 2)
    run = f"file://{tmp_path}/run"
    run_ingest(f"file://{src}", "npz", run, workers=1, progress=False)
    rows_ = read_stage(_fs.join(run, "ingest"))
    assert [r["ingest_status"] for r in rows_] == ["ok", "ok"]
    assert rows_[0]["paths"].count("file://") == 4


@pytest.mark.slow
def test_killed_stage_resumes_without_redoing_or_duplicating(tmp_path):
    src = _source(tmp_path, 10)
    run = str(tmp_path / "run")
    run_ingest(src, "npz", run, workers=1, shard_size=5, progress=False)
    ref_run = str(tmp_path / "ref")
    run_ingest(src, "npz", ref_run, workers=1, shard_size=5, progress=False)
    run_filter(ref_run, workers=1, shard_size=1, progress=False)
    cmd = [
        sys.executable,
        "-m",
        "oscar_core.cli",
        "data",
        "filter",
        run,
        "--workers",
        "1",
        "--shard-size",
        "1",
        "--no-progress",
    ]
    done = tmp_path / "run" / "filter" / "completions"
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None and len(list(done.glob("*.json"))) < 3:
        time.sleep(0.02)
    assert proc.poll() is None, "the stage finished before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    finished = sorted(p.name for p in done.glob("*.json"))
    assert 3 <= len(finished) < 10
    stamps = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "run" / "filter" / "shards").glob("*.parquet")}
    with pytest.raises(StageIncomplete):
        read_stage(str(tmp_path / "run" / "filter"))
    res = run_filter(run, workers=1, shard_size=1, progress=False)
    assert res.skipped == [n[:-5] for n in finished]  # finished shards are not redone ...
    assert set(res.processed) == {f"part-{i:06d}" for i in range(10)} - set(res.skipped)
    for name in finished:  # ... nor rewritten
        assert (
            tmp_path / "run" / "filter" / "shards" / name.replace(".json", ".parquet")
        ).stat().st_mtime_ns == stamps[name.replace(".json", ".parquet")]
    got = read_stage(str(tmp_path / "run" / "filter"))
    assert [r["id"] for r in got] == sorted({r["id"] for r in got})  # each episode exactly once
    assert _rows(got) == _rows(read_stage(str(tmp_path / "ref" / "filter")))


@pytest.mark.slow
def test_process_pool_and_ray_give_the_in_process_manifest(tmp_path):
    src = _source(tmp_path, 2)
    manifests = {}
    for name, kw in {"inline": dict(workers=1), "pool": dict(workers=2), "ray": dict(engine="ray", workers=1)}.items():
        if name == "ray" and not _has_ray():
            continue
        run = str(tmp_path / name)
        run_ingest(src, "npz", run, shard_size=1, progress=False, **kw)
        run_filter(run, shard_size=1, progress=False, **kw)
        manifests[name] = read_stage(str(tmp_path / name / "filter"))
    assert _rows(manifests["pool"]) == _rows(manifests["inline"])
    if "ray" in manifests:
        assert _rows(manifests["ray"]) == _rows(manifests["inline"])
    else:
        pytest.skip('ray is not installed (pip install "oscar-wm[ray]"): pool checked, ray skipped')


def _has_ray():
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def test_atomic_write_leaves_no_temporary_and_local_path_refuses_object_stores(tmp_path):
    url = f"file://{tmp_path}/a/b.bin"
    _fs.write_bytes_atomic(url, b"one")
    _fs.write_bytes_atomic(url, b"two")
    assert _fs.read_bytes(url) == b"two" and os.listdir(tmp_path / "a") == ["b.bin"]
    assert _fs.local_path(url) == str(tmp_path / "a" / "b.bin") and _fs.local_path("rel/x").endswith("rel/x")
    with pytest.raises(ValueError, match=r"memory://x/clips: expected a local folder or a file:// URL"):
        _fs.local_path("memory://x/clips")


@pytest.mark.slow
def test_memory_run_ingest_filter_resume_and_export(tmp_path):
    # a whole run on fsspec's in-memory filesystem: manifests written and read back, a resumed stage skips what is
    # done, and the exported clip set (copied back to disk) equals the one exported to a local folder
    import fsspec

    from oscar_core.data.run import run_export
    from oscar_core.train.clips import ClipSet

    src = _source(tmp_path, 3)
    run = "memory://oscar-test-run/r1"
    run_ingest(src, "npz", run, workers=1, shard_size=1, progress=False)
    run_filter(run, workers=1, shard_size=1, progress=False)
    ingest = read_stage(_fs.join(run, "ingest"))
    assert [r["ingest_status"] for r in ingest] == ["ok"] * 3
    local = str(tmp_path / "local")
    run_ingest(src, "npz", local, workers=1, shard_size=1, progress=False)
    run_filter(local, workers=1, shard_size=1, progress=False)
    assert _rows(read_stage(_fs.join(run, "filter"))) == _rows(read_stage(_fs.join(local, "filter")))
    # resume: forget one shard's completion and the manifest; the re-run redoes that shard only
    fs = fsspec.filesystem("memory")
    fs.rm("/oscar-test-run/r1/filter/completions/part-000001.json")
    fs.rm("/oscar-test-run/r1/filter/manifest.parquet")
    with pytest.raises(StageIncomplete, match="part-000001"):
        read_stage(_fs.join(run, "filter"))
    again = run_filter(run, workers=1, shard_size=1, progress=False)
    assert again.skipped == ["part-000000", "part-000002"] and again.processed == ["part-000001"]
    assert _rows(read_stage(_fs.join(run, "filter"))) == _rows(read_stage(_fs.join(local, "filter")))
    # export to memory:// and to disk
    clips = "memory://oscar-test-run/clips"
    with pytest.raises(ValueError, match=r"memory://oscar-test-run/clips: a memory:// folder lives in this process"):
        run_export(run, clips, workers=2, progress=False)
    run_export(run, clips, workers=1, shard_size=2, progress=False)
    run_export(local, str(tmp_path / "clips"), workers=1, shard_size=2, progress=False)
    names = sorted(p.rsplit("/", 1)[-1] for p in fs.find("/oscar-test-run/clips"))
    assert names.count("clips.jsonl") == 2 and "oscar_clips.json" in names
    fs.get("/oscar-test-run/clips", str(tmp_path / "copied"), recursive=True)
    got, ref = ClipSet(tmp_path / "copied"), ClipSet(tmp_path / "clips")
    assert sorted(r.id for r in got) == sorted(r.id for r in ref) and len(ref) == 3
    for rec in ref:
        a, b = got.load(rec.id), ref.load(rec)
        np.testing.assert_array_equal(a.rgb, b.rgb)
        np.testing.assert_array_equal(a.trajectory.q, b.trajectory.q)
    assert _rows(read_stage(_fs.join(run, "export"))) == _rows(read_stage(_fs.join(local, "export")))
    fs.rm("/oscar-test-run", recursive=True)


def test_unknown_protocol_and_missing_filesystem_package_are_named():
    with pytest.raises(
        ValueError,
        match=r"nosuchfs://bucket/run: expected a local path or an fsspec URL, found the "
        r"unknown protocol 'nosuchfs'",
    ):
        _fs.exists("nosuchfs://bucket/run")
    from fsspec.registry import known_implementations

    missing = next(p for p in ("gcs", "s3", "az", "oci", "webhdfs") if _missing(known_implementations[p]["class"]))
    package = known_implementations[missing]["class"].split(".")[0]
    with pytest.raises(
        ImportError,
        match=rf"{missing}://b/run/plan.json: the {missing}:// filesystem needs the Python package "
        rf"'{package}' \(pip install {package}\)",
    ):
        run_sharded(Double(), rows(2), f"{missing}://b/run", workers=1, progress=False)


def _missing(cls_path: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(cls_path.split(".")[0]) is None
