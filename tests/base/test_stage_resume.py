"""Runs a user can trust (issue 20): stage fingerprints, whole-stage faults, temporaries of dead processes, and
worker pools that neither hang nor outlive their parent."""

import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from _datasets import base_parts, write_episode
from _paths import REPO, TOYARM_ASSETS

from oscar_core._util import stage as _stage
from oscar_core._util.atomic import atomic_output, sweep_dead_temporaries
from oscar_core.cli import main
from oscar_core.data.engine import StageRecomputed, read_fingerprint, read_stage, run_sharded, stage_parts
from oscar_core.data.run import StaleStage
from oscar_core.train.clips import ClipSet

COMMON = ["--workers", "1", "--no-progress"]


def dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (exited, not yet reaped) is gone for our purpose
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


# ------------------------------------------------------------------ fingerprints


def test_fingerprint_is_canonical_and_changes_name_the_field():
    a = {"stage": "filter", "settings": {"min_length": 70, "size": (2, 3)}}
    b = {"settings": {"size": [2, 3], "min_length": 70}, "stage": "filter"}
    assert _stage.fingerprint(a) == _stage.fingerprint(b)
    c = {"stage": "filter", "settings": {"min_length": 40, "size": (2, 3)}}
    assert _stage.fingerprint(a) != _stage.fingerprint(c)
    assert _stage.changes(a, c) == ["settings.min_length: 70 -> 40"]
    assert _stage.changes(None, c) == ["no fingerprint recorded (made by an older oscar)"]


class Count:
    name = "count"

    def __init__(self, log):
        self.log = log

    def __call__(self, rows, shard=""):
        with open(self.log, "a") as f:
            f.write(shard + "\n")
        return [dict(r, y=r["x"] + 1) for r in rows]


def test_engine_recomputes_a_stage_whose_settings_changed(tmp_path):
    rows = [{"id": f"e{i}", "x": i} for i in range(4)]
    log, url = tmp_path / "log", str(tmp_path / "stage")
    parts = stage_parts("count", input={"stage": None}, settings={"k": 1})
    run_sharded(Count(log), rows, url, shard_size=2, workers=1, progress=False, parts=parts)
    again = run_sharded(Count(log), rows, url, shard_size=2, workers=1, progress=False, parts=parts)
    assert again.skipped == ["part-000000", "part-000001"] and not again.processed
    with pytest.warns(StageRecomputed, match=r"settings.k: 1 -> 2"):
        other = run_sharded(
            Count(log),
            rows,
            url,
            shard_size=2,
            workers=1,
            progress=False,
            parts=stage_parts("count", input={"stage": None}, settings={"k": 2}),
        )
    assert other.processed == ["part-000000", "part-000001"] and not other.skipped
    assert other.changed == ["settings.k: 1 -> 2"]
    assert log.read_text().split() == ["part-000000", "part-000001"] * 2
    assert read_fingerprint(url)["parts"]["settings"] == {"k": 2}
    # a new shard size is a new plan: recomputed, not refused
    with pytest.warns(StageRecomputed, match="shard_size: 2 -> 3"):
        run_sharded(
            Count(log),
            rows,
            url,
            shard_size=3,
            workers=1,
            progress=False,
            parts=stage_parts("count", input={"stage": None}, settings={"k": 2}),
        )


@pytest.fixture
def src(tmp_path):
    traj, _ = base_parts()
    write_episode(tmp_path / "src", "ep0", seed=0)
    write_episode(tmp_path / "src", "short", traj.time_slice(0, 40), seed=2)
    return tmp_path / "src"


def _verdicts(run):
    return {r["id"]: r.get("filter_status") for r in read_stage(str(run / "filter"))}


def test_filter_rerun_with_lower_min_length_recomputes_and_export_follows(tmp_path, src):
    run = tmp_path / "run"
    assert main(["data", "ingest", str(src), "--reader", "npz", "--out", str(run), *COMMON]) == 0
    assert main(["data", "filter", str(run), *COMMON]) == 0
    assert _verdicts(run) == {"src/ep0": "ok", "src/short": "rejected"}
    with pytest.warns(StageRecomputed, match="settings.min_length: 70 -> 30"):
        assert main(["data", "filter", str(run), "--set", "min_length=30", *COMMON]) == 0
    assert _verdicts(run) == {"src/ep0": "ok", "src/short": "ok"}
    assert json.loads((run / "filter" / "config.json").read_text())["min_length"] == 30
    # export to one clip set, then to a new --out at another size: a new output, written
    assert main(["data", "export", str(run), "--out", str(tmp_path / "a"), *COMMON]) == 0
    with pytest.warns(StageRecomputed, match="settings.out"):
        assert main(["data", "export", str(run), "--out", str(tmp_path / "b"), "--size", "32x32", *COMMON]) == 0
    clips = list(ClipSet(tmp_path / "b"))
    assert len(clips) == 2 and {(c.width, c.height) for c in clips} == {(32, 32)}
    assert len(list(ClipSet(tmp_path / "a"))) == 2


def test_a_later_stage_made_from_a_recomputed_input_is_refused(tmp_path, src, capsys):
    run = tmp_path / "run"
    assert main(["data", "ingest", str(src), "--reader", "npz", "--out", str(run), *COMMON]) == 0
    assert main(["data", "filter", str(run), *COMMON]) == 0
    write_episode(src, "ep1", seed=1)  # the dataset grew: ingest is computed again
    with pytest.warns(StageRecomputed, match="input.listing"):
        assert main(["data", "ingest", str(src), "--reader", "npz", "--out", str(run), *COMMON]) == 0
    from oscar_core.data.run import input_rows

    with pytest.raises(StaleStage, match=r"filter was made from a 'ingest' output .* run `oscar data filter"):
        input_rows(str(run), "export")
    capsys.readouterr()
    assert main(["data", "export", str(run), "--out", str(tmp_path / "clips"), *COMMON]) != 0
    assert "found a stale one" in capsys.readouterr().err and not (tmp_path / "clips").exists()
    with pytest.warns(StageRecomputed):
        assert main(["data", "filter", str(run), *COMMON]) == 0
    assert main(["data", "export", str(run), "--out", str(tmp_path / "clips"), *COMMON]) == 0
    assert len(list(ClipSet(tmp_path / "clips"))) == 2


# ------------------------------------------------------------ whole-stage faults


class SilentHub(str):
    """The hub's address; ``held``: the connections it accepted so far."""

    def __new__(cls, url: str, held: list):
        self = super().__new__(cls, url)
        self.held = held
        return self


@pytest.fixture
def silent_hub():
    """A port that accepts connections and never answers."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(16)
    held, stop = [], threading.Event()

    def accept():
        srv.settimeout(0.2)
        while not stop.is_set():
            try:
                held.append(srv.accept()[0])
            except OSError:
                pass

    t = threading.Thread(target=accept, daemon=True)
    t.start()
    yield SilentHub(f"http://127.0.0.1:{srv.getsockname()[1]}", held)
    stop.set()
    t.join()
    for c in held:
        c.close()
    srv.close()


def test_dedup_with_an_unreachable_hub_fails_within_the_timeout_and_records_nothing(
    tmp_path, src, silent_hub, monkeypatch, capsys
):
    run = tmp_path / "run"
    assert main(["data", "ingest", str(src), "--reader", "npz", "--out", str(run), *COMMON]) == 0
    monkeypatch.setenv("HF_ENDPOINT", silent_hub)
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "empty-cache"))
    monkeypatch.setenv("OSCAR_HUB_TIMEOUT", "2")
    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    capsys.readouterr()
    t0 = time.monotonic()
    assert main(["data", "dedup", str(run), "--siglip", "someone/siglip-test", *COMMON]) != 0
    assert time.monotonic() - t0 < 8.0  # the 2 s timeout, not the Hub client's default of 10 s
    err = capsys.readouterr().err
    assert "cannot reach the Hub" in err and "no answer within 2 s" in err and "HF_HUB_OFFLINE=1" in err, err
    assert not (run / "dedup" / "embed" / "completions").exists() and not (run / "dedup" / "manifest.parquet").exists()
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    asked = len(silent_hub.held)
    assert main(["data", "dedup", str(run), "--siglip", "someone/siglip-test", *COMMON]) != 0
    time.sleep(0.5)  # the hub's accept loop polls every 0.2 s
    assert len(silent_hub.held) == asked, "offline, the hub was still asked"
    err = capsys.readouterr().err
    assert "someone/siglip-test: not in the Hub cache" in err and "HF_HUB_OFFLINE" in err, err


class BrokenModel:
    """An embedder whose model cannot load: a fault of the whole stage, not of each episode."""

    def identity(self):
        return {"model": "broken"}

    def model(self):
        raise OSError("weights truncated")

    def __call__(self, frames):
        return self.model()


def test_a_model_failing_in_the_stage_fails_it_instead_of_rejecting_every_episode(tmp_path, src):
    from oscar_core.data.run import run_dedup

    run = tmp_path / "run"
    assert main(["data", "ingest", str(src), "--reader", "npz", "--out", str(run), *COMMON]) == 0
    with pytest.raises(OSError, match="weights truncated"):
        run_dedup(str(run), BrokenModel(), workers=1, progress=False)
    assert not (run / "dedup" / "embed" / "completions").exists()


# ---------------------------------------------------------- nothing left behind


def _killed_writer(code: str, folder: Path, wait_for) -> None:
    """Run ``code`` in a child (it must print READY once its temporary exists), kill -9 it, wait for it."""
    p = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(code)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=REPO,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
    )
    try:
        assert p.stdout.readline().strip() == "READY"
        assert wait_for(), list(folder.iterdir())
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait()
        p.stdout.close()


def test_a_killed_writers_temporary_is_swept_by_the_next_write_and_a_live_ones_kept(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    _killed_writer(
        f"""
        import time
        from oscar_core._util.atomic import atomic_output
        with atomic_output({str(folder / "x.json")!r}) as tmp:
            tmp.write_text("half")
            print("READY", flush=True)
            time.sleep(60)
        """,
        folder,
        lambda: any(p.name.startswith(".x.json.") for p in folder.iterdir()),
    )
    left = [p.name for p in folder.iterdir()]
    assert len(left) == 1 and ".tmp" in left[0]
    with atomic_output(folder / "y.json") as tmp:  # mine, alive: never swept by another writer
        tmp.write_text("{}")
        assert sweep_dead_temporaries(folder) == [] and tmp.exists()
    assert sorted(p.name for p in folder.iterdir()) == ["y.json"]


def test_a_killed_render_and_a_killed_export_shard_are_swept_by_the_next_run(tmp_path, src):
    vids = tmp_path / "vids"
    vids.mkdir()
    _killed_writer(
        f"""
        import time
        from oscar_core.media.video import VideoWriter
        import numpy as np
        w = VideoWriter({str(vids / "a.mkv")!r}, 15, size=(32, 32))
        w.__enter__()
        w.write(np.zeros((2, 32, 32, 3), np.uint8))
        print("READY", flush=True)
        time.sleep(60)
        """,
        vids,
        lambda: any(".tmp" in p.name for p in vids.iterdir()),
    )
    from oscar_core.media.video import VideoWriter

    with VideoWriter(vids / "b.mkv", 15, size=(32, 32)) as w:  # another target in the same folder
        w.write(np.zeros((2, 32, 32, 3), np.uint8))
    assert sorted(p.name for p in vids.iterdir()) == ["b.mkv"]

    run, clips = tmp_path / "run", tmp_path / "clips"
    assert main(["data", "ingest", str(src), "--reader", "npz", "--out", str(run), *COMMON]) == 0
    clips.mkdir()
    _killed_writer(
        f"""
        import time
        from oscar_core.train.clips import ClipSetWriter
        ClipSetWriter({str(clips)!r}).shard("shard-part-000000")
        print("READY", flush=True)
        time.sleep(60)
        """,
        clips,
        lambda: any(p.name.startswith(".shard-part-000000.") for p in clips.iterdir()),
    )
    assert main(["data", "export", str(run), "--out", str(clips), *COMMON]) == 0
    assert not [p.name for p in clips.iterdir() if p.name.startswith(".")]


# ------------------------------------------------------------ no hangs, no orphans


def test_pools_never_fork_this_process():
    from oscar_core.data.engine import _pool_context as data_context
    from oscar_core.render.batch import RenderOptions, _pool_context

    assert _pool_context([], RenderOptions()).get_start_method() in ("forkserver", "spawn")
    assert data_context().get_start_method() in ("forkserver", "spawn")


def test_two_render_pools_in_one_process_after_threads_exist(tmp_path):
    """render_many(workers=1) then twice workers=2 in one process, with threads running: no hang (a child)."""
    code = f"""
        import threading, time
        from pathlib import Path
        from oscar_core import load_trajectory, save_trajectory
        from oscar_core.render.batch import EpisodeSpec, render_many
        root, assets = Path({str(tmp_path)!r}), Path({str(TOYARM_ASSETS)!r})
        cam = assets / "example_camera.json"
        stop = threading.Event()
        threading.Thread(target=lambda: [time.sleep(0.001) for _ in iter(stop.is_set, True)], daemon=True).start()
        for i in range(4):
            save_trajectory(load_trajectory(assets / "example_trajectory.npz").time_slice(4 * i, 4 * i + 4),
                            root / f"t{{i}}.npz")
        for n, workers in enumerate((1, 2, 2)):
            specs = [EpisodeSpec("toyarm", str(root / f"t{{i}}.npz"), str(cam), str(root / f"r{{n}}" / f"t{{i}}.mkv"),
                                 size=(32, 32)) for i in range(4)]
            res = render_many(specs, workers=workers, progress=True)
            assert all(r.ok for r in res), [r.error for r in res]
        stop.set()
        print("DONE", flush=True)
        """
    p = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=240,
        cwd=REPO,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
    )
    assert p.returncode == 0 and "DONE" in p.stdout, p.stderr[-2000:]


def _descendants(pid: int) -> set[int]:
    kids: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            kids.setdefault(ppid, []).append(int(d.name))
    out, todo = set(), [pid]
    while todo:
        for k in kids.get(todo.pop(), []):
            if k not in out:
                out.add(k)
                todo.append(k)
    return out


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc to find the workers")
def test_workers_die_with_a_killed_parent(tmp_path):
    (tmp_path / "slowstage.py").write_text(
        textwrap.dedent("""
        import os, time
        class Slow:
            name = "slow"
            def __call__(self, rows, shard=""):
                open(os.path.join(os.environ["MARKS"], str(os.getpid())), "w").close()
                time.sleep(120)
                return rows
        """)
    )
    marks = tmp_path / "marks"
    marks.mkdir()
    code = f"""
        from oscar_core.data.engine import run_sharded
        from slowstage import Slow
        rows = [{{"id": f"e{{i}}"}} for i in range(2)]
        run_sharded(Slow(), rows, {str(tmp_path / "stage")!r}, shard_size=1, workers=2, progress=False)
        """
    env = dict(os.environ, PYTHONPATH=f"{REPO}{os.pathsep}{tmp_path}", MARKS=str(marks))
    p = subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], env=env, cwd=tmp_path)
    try:
        deadline = time.monotonic() + 120
        while len(list(marks.iterdir())) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        workers = {int(m.name) for m in marks.iterdir()}
        assert len(workers) == 2
        family = _descendants(p.pid)  # the fork server and the workers
        assert workers <= family
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait()
    deadline = time.monotonic() + 10
    while any(alive(x) for x in family) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [x for x in family if alive(x)]


def test_render_many_resume_skips_unchanged_episodes_and_redoes_changed_ones(tmp_path):
    from oscar_core import load_trajectory, save_trajectory
    from oscar_core.render.batch import EpisodeSpec, RenderOptions, record_path, render_many

    trajs = []
    for i in range(2):
        trajs.append(tmp_path / f"t{i}.npz")
        save_trajectory(
            load_trajectory(TOYARM_ASSETS / "example_trajectory.npz").time_slice(3 * i, 3 * i + 3), trajs[-1]
        )
    specs = [
        EpisodeSpec(
            "toyarm",
            str(t),
            str(TOYARM_ASSETS / "example_camera.json"),
            str(tmp_path / "v" / f"{t.stem}.mkv"),
            size=(32, 32),
        )
        for t in trajs
    ]
    first = render_many(specs, resume=True)
    assert [r.skipped for r in first] == [False, False] and all(record_path(s).is_file() for s in specs)
    assert [r.skipped for r in render_many(specs, resume=True)] == [True, True]
    save_trajectory(load_trajectory(TOYARM_ASSETS / "example_trajectory.npz").time_slice(10, 13), trajs[1])  # new input
    assert [r.skipped for r in render_many(specs, resume=True)] == [True, False]
    again = render_many(specs, RenderOptions(crf=30), resume=True)  # another encoder setting: every episode
    assert [r.skipped for r in again] == [False, False] and all(r.ok for r in again)
    (tmp_path / "v" / "t0.mkv").unlink()  # an output gone: rendered again even though its record is there
    assert [r.skipped for r in render_many(specs, RenderOptions(crf=30), resume=True)] == [False, True]


def test_zoo_pull_against_a_silent_hub_fails_within_the_timeout_counted_from_the_start(tmp_path, silent_hub):
    """The whole command, interpreter start-up and imports included: no agent-registry request before ours,
    no diffusers import before the request, and the request's timeout counted from the process's start."""
    env = dict(
        os.environ,
        PYTHONPATH=str(REPO),
        HF_ENDPOINT=silent_hub,
        HF_HUB_CACHE=str(tmp_path / "cache"),
        HF_HOME=str(tmp_path / "home"),
        OSCAR_HUB_TIMEOUT="6",
    )
    env.pop("HF_HUB_OFFLINE", None)
    t0 = time.monotonic()
    p = subprocess.run(
        [sys.executable, "-m", "oscar_core.cli", "zoo", "pull", "oscar-2b"],
        capture_output=True,
        text=True,
        env=env,
        cwd=REPO,
        timeout=120,
    )
    wall = time.monotonic() - t0
    assert p.returncode != 0 and "cannot reach the Hub" in p.stderr and "HF_HUB_OFFLINE=1" in p.stderr, p.stderr
    assert wall < 6 + 2.5, f"{wall:.1f} s for a 6 s timeout"


def test_a_down_caption_endpoint_fails_the_stage_at_once(tmp_path, src, silent_hub):
    from oscar_core.data.caption import CaptionConfig, EndpointUnreachable
    from oscar_core.data.run import run_caption

    run = tmp_path / "run"
    assert main(["data", "ingest", str(src), "--reader", "npz", "--out", str(run), *COMMON]) == 0
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    refused = f"http://127.0.0.1:{srv.getsockname()[1]}/v1"
    srv.close()  # nothing listens: connections are refused
    t0 = time.monotonic()
    with pytest.raises(EndpointUnreachable, match=r"--endpoint http://127.0.0.1:\d+/v1: cannot reach"):
        run_caption(str(run), CaptionConfig(base_url=refused, model="m", max_retries=4), workers=1, progress=False)
    assert time.monotonic() - t0 < 3.0
    with pytest.raises(EndpointUnreachable, match=r"no answer within 1 s"):
        run_caption(
            str(run), CaptionConfig(base_url=silent_hub + "/v1", model="m", timeout=1.0), workers=1, progress=False
        )
    assert not (run / "caption" / "completions").exists() and not (run / "caption" / "shards").exists()


def test_a_full_disk_during_export_fails_the_stage_instead_of_rejecting_episodes(tmp_path, src, monkeypatch):
    import errno

    from oscar_core.train import clips

    run = tmp_path / "run"
    assert main(["data", "ingest", str(src), "--reader", "npz", "--out", str(run), *COMMON]) == 0

    def full(self, clip):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(clips.ShardWriter, "add", full)
    from oscar_core.data.run import run_export

    with pytest.raises(OSError, match="No space left"):
        run_export(str(run), str(tmp_path / "clips"), workers=1, progress=False)
    assert not (run / "export" / "completions").exists()


def test_a_killed_checkpoint_saves_temporary_is_removed_by_the_next_save(tmp_path):
    import torch

    from oscar_core.train.checkpoint import list_checkpoints, save_checkpoint
    from oscar_core.train.parallel import DistInfo

    model = torch.nn.Linear(2, 2)
    opt = torch.optim.SGD(model.parameters(), lr=0.1)
    killed = tmp_path / "checkpoints" / ".step-00000005.tmp"  # a save of step 5 killed mid-write
    killed.mkdir(parents=True)
    (killed / "__0_0.distcp").write_bytes(b"half")
    save_checkpoint(tmp_path, 10, model, opt, {}, DistInfo())
    assert [p.name for p in list_checkpoints(tmp_path)] == ["step-00000010"]
    assert sorted(p.name for p in (tmp_path / "checkpoints").iterdir()) == ["step-00000010"]
