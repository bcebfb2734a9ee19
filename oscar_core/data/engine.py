"""Map a stage over sharded episodes with a local process pool or Ray Data; resumable by completions.

A stage folder (``RUN/<stage>/``) holds::

    plan.json                 shard name → episode ids (fixed on the first run)
    shards/<name>.parquet     the stage's output rows of one shard (written atomically)
    completions/<name>.json   written after its shard: the shard is done
    manifest.parquet          every shard's rows, id order (written when all are done)

The unit of work is a shard of ``shard_size`` episodes. A stage function is a
plain picklable callable ``fn(rows, shard=name) -> rows`` with no global state
(one row per input row, same ids). Both engines run the very same task
(:func:`run_shard`): compute, write the shard, then its completion record.
A killed run leaves finished shards with their completions and at worst a
shard without one (or a temporary file); the next run skips every completed
shard and redoes only the rest, so nothing is redone and nothing duplicated.
A stage function may declare ``shard_complete(rows) -> bool``: a shard it
calls incomplete (captions deferred by the request budget) is written but
not recorded, and is done again on the next run.

``fingerprint.json`` (written before any shard, atomically) records what the
stage's output depends on: the stage, its input (the previous stage's
fingerprint and a hash of the episode ids), its effective settings, its model
and a format version (:mod:`oscar_core._util.stage`). A re-run with other parts
recomputes the stage — its plan, shards, completions and manifest are
deleted first, and a warning names what changed — so a completion record
always belongs to the settings in the fingerprint beside it. A stage folder
with completions but no fingerprint (an older oscar) is recomputed too.
Worker processes come from a fork server (never a plain fork after threads
exist) and exit when the process that made the pool dies.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, get_args

from .._util import stage as _stage
from .._util.log import get_logger
from .._util.stage import EngineName
from . import _fs
from .manifest import rows_from_parquet, rows_to_parquet, table_from_parquet, table_to_parquet

__all__ = [
    "ENGINES",
    "EngineName",
    "FINGERPRINT",
    "StageIncomplete",
    "StageRecomputed",
    "StageRun",
    "ids_hash",
    "read_fingerprint",
    "read_stage",
    "run_shard",
    "run_sharded",
    "stage_done",
    "stage_parts",
    "use_fingerprint",
    "write_stage_manifest",
]

_log = get_logger(__name__)

ENGINES: tuple[str, ...] = get_args(EngineName)
MANIFEST = "manifest.parquet"
FINGERPRINT = "fingerprint.json"


class StageRecomputed(UserWarning):
    """A stage's recorded fingerprint differs from this run's: its old output is deleted and it is computed again."""


class StageIncomplete(ValueError):
    """A stage's output is asked for before every shard of it is done."""


@dataclass
class StageRun:
    """What one call of :func:`run_sharded` did: shard names processed now, skipped as done, left incomplete."""

    stage_url: str
    processed: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    incomplete: list[str] = field(default_factory=list)
    changed: list[str] = field(default_factory=list)  # what differed from the recorded fingerprint (recomputed)
    table: Any = None  # the stage manifest (pyarrow Table) when every shard is done
    _rows: list[dict[str, Any]] | None = None

    @property
    def rows(self) -> list[dict[str, Any]]:
        """The manifest's rows (id order); empty while shards are unfinished."""
        if self._rows is None:
            self._rows = [] if self.table is None else self.table.to_pylist()
        return self._rows

    @rows.setter
    def rows(self, value: list[dict[str, Any]]) -> None:
        self._rows = value


def _shard_url(stage_url: str, name: str) -> str:
    return _fs.join(stage_url, "shards", f"{name}.parquet")


def _completion_url(stage_url: str, name: str) -> str:
    return _fs.join(stage_url, "completions", f"{name}.json")


def run_shard(fn: Callable, rows: list[dict], stage_url: str, name: str) -> tuple[str, int, bool]:
    """Run ``fn`` on one shard, write its rows, then (when complete) its completion record.

    returns (shard name, rows written, completed).
    """
    out = fn(rows, shard=name)
    want = [r["id"] for r in rows]
    got = [r["id"] for r in out]
    if got != want:
        raise RuntimeError(
            f"stage {getattr(fn, 'name', fn)!r}, shard {name}: expected rows for ids {want[:3]}…, "
            f"found {got[:3]}… ({len(got)} rows for {len(want)})"
        )
    _fs.write_bytes_atomic(_shard_url(stage_url, name), rows_to_parquet(out))
    check = getattr(fn, "shard_complete", None)
    done = bool(check(out)) if check is not None else True
    if done:
        _fs.write_bytes_atomic(_completion_url(stage_url, name), json.dumps({"shard": name, "rows": len(out)}).encode())
    return name, len(out), done


def _plan(rows: list[dict], shard_size: int) -> dict[str, list[str]]:
    ids = [r["id"] for r in rows]
    if len(set(ids)) != len(ids):
        dup = sorted({i for i in ids if ids.count(i) > 1})[:3]
        raise ValueError(f"manifest: field 'id': expected unique episode ids, found duplicates {dup}")
    return {f"part-{k // shard_size:06d}": ids[k : k + shard_size] for k in range(0, len(ids), shard_size)}


def _worker_init() -> None:
    from .._util.interrupt import worker_ignores_interrupt

    worker_ignores_interrupt()  # Ctrl-C: the parent stops the pool
    # one thread per worker process: the pool already uses every core
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover
        pass
    try:
        import cv2

        cv2.setNumThreads(1)
    except ImportError:  # pragma: no cover
        pass


# modules a worker needs: imported once by the fork server, inherited by every worker it forks
_PRELOAD = [
    "numpy",
    "cv2",
    "torch",
    "av",
    "pyarrow",
    "oscar_core.plugin.registry",
    "oscar_core.render.skeleton_video",
    "oscar_core.data.ingest",
    "oscar_core.data.filters",
    "oscar_core.data.dedup",
    "oscar_core.data.export",
    "oscar_core.data.caption",
]


def _pool_context():
    """Process start method: a fork server with the heavy imports preloaded where available, else spawn.

    Spawned workers each import torch, OpenCV and the plugins (seconds each);
    forked from a preloaded server they start in milliseconds. Neither
    inherits the parent's threads (plain fork after torch has run is unsafe).
    """
    return _stage.pool_context(_PRELOAD)


def ids_hash(rows: list[dict]) -> str:
    """sha256 (16 hex digits) of the rows' episode ids in order: the identity of a stage's input episodes."""
    h = hashlib.sha256()
    for r in rows:
        h.update(str(r["id"]).encode() + b"\0")
    return h.hexdigest()[:16]


def stage_parts(
    stage: str, *, input: Mapping[str, Any], settings: Mapping[str, Any], model: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """The fingerprint parts of a data stage (see the module docstring)."""
    return {
        "stage": stage,
        "format": _stage.FORMAT_VERSION,
        "input": dict(input),
        "settings": dict(settings),
        "model": dict(model) if model else None,
    }


def read_fingerprint(stage_url: str) -> dict | None:
    """A stage folder's recorded ``{"fingerprint": hex, "parts": {...}}``, or None when it has none."""
    url = _fs.join(stage_url, FINGERPRINT)
    if not _fs.exists(url):
        return None
    try:
        got = json.loads(_fs.read_bytes(url))
    except ValueError:
        return None
    return got if isinstance(got, dict) and "fingerprint" in got else None


def _clear_stage(stage_url: str, extra: tuple[str, ...] = ()) -> None:
    fs, root = _fs.url_to_fs(stage_url)
    for name in ("plan.json", MANIFEST, FINGERPRINT, *extra):
        path = f"{root.rstrip('/')}/{name}"
        if fs.exists(path):
            fs.rm(path)
    for name in ("shards", "completions"):
        path = f"{root.rstrip('/')}/{name}"
        if fs.exists(path):
            fs.rm(path, recursive=True)


def use_fingerprint(stage_url: str, parts: Mapping[str, Any], *, clear: tuple[str, ...] = ()) -> list[str]:
    """Make ``stage_url`` belong to ``parts``: when its recorded fingerprint differs (or is absent while the folder
    has work in it), delete its plan, shards, completions, manifest and the files named in ``clear``, warn with
    :class:`StageRecomputed` naming what changed, and record the new fingerprint. Returns what changed ([] when
    nothing did)."""
    new = _stage.fingerprint(parts)
    old = read_fingerprint(stage_url)
    if old is not None and old["fingerprint"] == new:
        return []
    has_work = _fs.exists(_fs.join(stage_url, "plan.json")) or _fs.exists(_fs.join(stage_url, MANIFEST))
    what = _stage.changes(old.get("parts") if old else None, parts) if (old or has_work) else []
    if what:
        _clear_stage(stage_url, clear)
        warnings.warn(
            f"{stage_url}: made under other inputs or settings ({'; '.join(what)}); its old output is "
            "deleted and the stage is computed again",
            StageRecomputed,
            stacklevel=3,
        )
    _fs.write_bytes_atomic(
        _fs.join(stage_url, FINGERPRINT), json.dumps({"fingerprint": new, "parts": _stage._canonical(parts)}).encode()
    )
    return what


class _RayShardTask:
    """The Ray Data ``map`` function: one item is one shard (rows as JSON, for a stable Arrow schema)."""

    def __init__(self, fn, stage_url):
        self.fn, self.stage_url = fn, stage_url

    def __call__(self, item: dict) -> dict:
        _worker_init()
        name, n, done = run_shard(self.fn, json.loads(item["rows"]), self.stage_url, item["name"])
        return {"name": name, "n": n, "done": done}


def check_workers_see(url: str, engine: EngineName, workers: int | None) -> None:
    """ValueError when worker processes (``--workers`` > 1 or Ray) would write ``url`` on a filesystem only this
    process sees (``memory://``): their output would be lost."""
    if (engine == "ray" or (workers or os.cpu_count() or 1) > 1) and _fs.process_local(url):
        raise ValueError(
            f"{url}: a memory:// folder lives in this process only; expected --workers 1 and "
            f"--engine local with it, found --engine {engine} --workers {workers or os.cpu_count()}"
        )


def _check_plan(stage_url: str, plan: dict[str, list], shard_size: int) -> None:
    """Records ``plan`` (shard name → row ids) in ``stage_url/plan.json`` on the first run; on a later run
    ValueError when the recorded plan is another one."""
    plan_url = _fs.join(stage_url, "plan.json")
    if _fs.exists(plan_url):
        old = json.loads(_fs.read_bytes(plan_url))
        if old.get("shards") != plan:
            raise ValueError(
                f"{plan_url}: expected the plan of this input (same episodes, same --shard-size), found "
                f"another run's plan; use a new output folder or delete this stage's folder"
            )
    else:
        _fs.write_bytes_atomic(plan_url, json.dumps({"shards": plan, "shard_size": shard_size}).encode())


def _run_pool(fn, tasks, stage_url: str, n_workers: int, bar) -> list[tuple[str, int, bool]]:
    """:func:`run_shard` of every ``(name, rows)`` task in a pool of ``n_workers`` processes, in completion order;
    Ctrl-C stops the pool at once."""
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from .._util.interrupt import stop_pool
    from .._util.main_guard import check_main_guard

    check_main_guard(f"run_sharded(workers={n_workers})")  # a script's unguarded top level would run again
    results = []
    with ProcessPoolExecutor(
        n_workers,
        mp_context=_pool_context(),
        initializer=_stage.worker_initializer,
        initargs=(os.getpid(), _worker_init),
    ) as pool:
        try:
            futures = [pool.submit(run_shard, fn, shard_rows, stage_url, name) for name, shard_rows in tasks]
            for fut in as_completed(futures):
                results.append(fut.result())
                bar.update(1)
        except KeyboardInterrupt:  # stop now rather than run the rest of the queue first
            stop_pool(pool)
            raise
    return results


def _run_tasks(
    fn,
    tasks,
    stage_url: str,
    engine: EngineName,
    workers: int | None,
    progress: bool,
    label: str,
    n_plan: int,
    n_skipped: int,
) -> list[tuple[str, int, bool]]:
    """Runs the ``(name, rows)`` shard tasks on ``engine`` with a progress bar; returns ``(name, rows written,
    finished)`` per shard. ``n_plan`` and ``n_skipped`` (shards in the plan, done earlier) are for the log line."""
    from .._util.log import progress_bar
    from .._util.threads import check_threads, default_threads

    bar = progress_bar(total=len(tasks), desc=label, unit="shard", enabled=progress)
    if workers:
        check_threads(workers, "--workers")
    n_workers = min(workers or default_threads(), len(tasks))  # default: the cores idle now, one thread each
    _log.info(
        "%s: %d shards of %d to do (%d done earlier), engine %s, %d worker(s)",
        label,
        len(tasks),
        n_plan,
        n_skipped,
        engine,
        n_workers,
    )
    results: list[tuple[str, int, bool]] = []
    if engine == "ray":
        results = _run_ray(fn, tasks, stage_url, n_workers)
        bar.update(len(results))
    elif n_workers <= 1:
        for name, shard_rows in tasks:
            results.append(run_shard(fn, shard_rows, stage_url, name))
            bar.update(1)
    else:
        results = _run_pool(fn, tasks, stage_url, n_workers, bar)
    bar.close()
    return results


def run_sharded(
    fn: Callable,
    rows: list[dict],
    stage_url: str,
    *,
    shard_size: int = 32,
    engine: EngineName = "local",
    workers: int | None = None,
    progress: bool = True,
    desc: str = "",
    parts: Mapping[str, Any] | None = None,
) -> StageRun:
    """Map ``fn`` over ``rows`` in shards into ``stage_url``; skip shards already completed.

    rows: input rows in a fixed order (the plan is made from it on the first
    run and checked on later ones); engine: ``local`` (process pool;
    ``workers`` ≤ 1 runs in this process) or ``ray`` (Ray Data; uses a running
    Ray or starts a local one with ``workers`` CPUs). Writes ``manifest.parquet``
    when every shard is done. parts: the stage's fingerprint parts
    (:func:`stage_parts`; the shard size and the input ids are added here):
    a stage recorded under other parts is computed again
    (:func:`use_fingerprint`). Returns a :class:`StageRun`. Worker processes
    import the calling script again: a script calls this under
    ``if __name__ == "__main__":`` (else ``MainGuardError`` before the pool
    starts; ``oscar_core._util.main_guard``).
    """
    if engine not in ENGINES:
        raise ValueError(f"--engine: expected one of {list(ENGINES)}, found {engine!r}")
    if shard_size < 1:
        raise ValueError(f"--shard-size: expected a positive integer, found {shard_size}")
    check_workers_see(stage_url, engine, workers)
    plan = _plan(rows, shard_size)
    if parts is not None:
        parts = dict(parts, input=dict(parts.get("input") or {}, ids=ids_hash(rows), shard_size=shard_size))
        run_changes = use_fingerprint(stage_url, parts)
    else:
        run_changes = []
    _check_plan(stage_url, plan, shard_size)
    by_id = {r["id"]: r for r in rows}
    done = {n[:-5] for n in _fs.listdir(_fs.join(stage_url, "completions")) if n.endswith(".json")}
    run = StageRun(stage_url)
    run.changed = run_changes
    todo = [n for n in plan if n not in done]
    run.skipped = [n for n in plan if n in done]
    tasks = [(n, [by_id[i] for i in plan[n]]) for n in todo]
    label = desc or stage_url
    results = (
        _run_tasks(fn, tasks, stage_url, engine, workers, progress, label, len(plan), len(run.skipped)) if tasks else []
    )
    for name, _, ok in results:
        (run.processed if ok else run.incomplete).append(name)
    run.processed.sort()
    run.incomplete.sort()
    if run.incomplete:
        _log.warning(
            "%s: %d shard(s) unfinished (%s); run the stage again",
            label,
            len(run.incomplete),
            ", ".join(run.incomplete[:5]),
        )
    elif tasks:
        _log.info("%s: %d shards done -> %s", label, len(run.processed), stage_url)
    if not run.incomplete:
        run.table = write_stage_manifest(stage_url, list(plan))
    return run


def _run_ray(fn, tasks, stage_url, n_workers) -> list[tuple[str, int, bool]]:
    from .._util.optional import require

    ray = require("ray", "ray")
    if not ray.is_initialized():
        ray.init(
            num_cpus=max(1, n_workers),
            include_dashboard=False,
            log_to_driver=False,
            configure_logging=False,
            ignore_reinit_error=True,
        )
    import ray.data

    ctx = ray.data.DataContext.get_current()
    ctx.enable_progress_bars = False
    items = [{"name": name, "rows": json.dumps(rows)} for name, rows in tasks]
    ds = ray.data.from_items(items, override_num_blocks=len(items)).map(_RayShardTask(fn, stage_url))
    return [(r["name"], int(r["n"]), bool(r["done"])) for r in ds.take_all()]


def write_stage_manifest(stage_url: str, names: list[str]):
    """Merge the shards into ``manifest.parquet`` (rows in id order) and return it as a pyarrow Table.

    Columns stay columnar (no Python objects per value), so embedding columns
    of millions of rows merge in Arrow's memory, not as lists of floats.
    """
    import pyarrow as pa

    tables = []
    for name in names:
        url = _shard_url(stage_url, name)
        tables.append(table_from_parquet(_fs.read_bytes(url), url))
    tables = [t for t in tables if t.num_columns]
    table = (
        pa.concat_tables(tables, promote_options="permissive")
        if tables
        else pa.table({"id": pa.array([], pa.string())})
    )
    table = table.sort_by("id")
    _fs.write_bytes_atomic(_fs.join(stage_url, MANIFEST), table_to_parquet(table))
    return table


def stage_done(stage_url: str) -> bool:
    return _fs.exists(_fs.join(stage_url, MANIFEST))


def read_stage(stage_url: str) -> list[dict]:
    """Rows of a finished stage (id order); :class:`StageIncomplete` naming what is missing otherwise."""
    url = _fs.join(stage_url, MANIFEST)
    if not _fs.exists(url):
        plan_url = _fs.join(stage_url, "plan.json")
        if _fs.exists(plan_url):
            plan = json.loads(_fs.read_bytes(plan_url))["shards"]
            done = {n[:-5] for n in _fs.listdir(_fs.join(stage_url, "completions"))}
            missing = [n for n in plan if n not in done]
            raise StageIncomplete(
                f"{stage_url}: expected a finished stage, found {len(missing)} of {len(plan)} shards "
                f"not done ({', '.join(missing[:3])}…); run the stage again to finish it"
            )
        raise StageIncomplete(f"{url}: expected a stage manifest, found no such file (has the stage run?)")
    return rows_from_parquet(_fs.read_bytes(url), url)
