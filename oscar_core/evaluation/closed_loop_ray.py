"""Closed-loop cells on Ray actors (``oscar eval closed-loop --engine ray``): one world per actor.

:func:`run_on_ray` starts ``workers`` actors (:func:`~.rollout_engines.start_ray_actors`: one GPU each on CUDA,
else one CPU each), each loading the world model once from its spec (or building the simulator's worlds) and
keeping its own policy objects. Groups of ``batch_cells`` cells are queued to whichever actor is free; an actor
runs its group as this process would (one at a time, or in lock-step for ``batch_cells`` > 1,
:mod:`.closed_loop_batch`) and sends back, per cell, what it did (frames, joint path, calls, fault), its
condition video and the world's outcome. This process writes every file and record, so the run folder, the
resume rule and the report are the local engine's, and the workers need no access to the output folder (they
read the session inputs by path, like ``eval run``'s workers). A policy fault fails its cell on the worker and
the others go on; a fault of a worker (its model cannot load, an exception in the world) stops the run.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .closed_loop_cell import OpenCell, open_cell, run_open_cell
from .rollout_engines import ray_result, start_ray_actors

__all__ = ["run_on_ray"]


@dataclass
class _RecordedWorld:
    """What the driver needs of a worker's world to write a cell: its name, frame rate, condition frames and
    outcome."""

    name: str
    fps: float
    condition: list = field(default_factory=list)
    result: dict = field(default_factory=dict)
    timing: dict = field(default_factory=dict)

    def outcome(self) -> dict:
        return self.result


class _ClosedLoopWorker:
    """A Ray actor's state: one world model (loaded once) or the simulator's factory, and its policy objects."""

    def __init__(
        self, model_spec, revision, device: str, dtype_name, plugin_paths: tuple, simulator, tiny_decoder, tiny_encoder
    ):
        import torch

        from .closed_loop_cell import PolicyPool

        self.model = None
        if simulator is None:
            import oscar_zoo

            dtype = getattr(torch, dtype_name) if dtype_name else None
            self.model = oscar_zoo.load(
                model_spec, revision, device=device, dtype=dtype, tiny_decoder=tiny_decoder, tiny_encoder=tiny_encoder
            )
        self.simulator, self.plugin_paths, self.pool = simulator, plugin_paths, PolicyPool()

    def run(self, jobs: list, world_options: dict, batch_cells: int, timeout) -> list:
        """[(index, {"run", "world", "seconds"})] of ``jobs`` ((index, session, spec, parts, key, K))."""
        from ..plugin.registry import get_embodiment
        from .closed_loop_batch import run_lock_step

        embs: dict = {}
        results: list = []

        def open_job(job) -> OpenCell:
            _, s, spec, parts, key, K = job
            if s.embodiment not in embs:
                embs[s.embodiment] = get_embodiment(s.embodiment, self.plugin_paths)
            return open_cell(
                s,
                spec,
                embs[s.embodiment],
                parts,
                key,
                pool=self.pool,
                K=K,
                get_model=lambda: self.model,
                simulator=self.simulator,
                **world_options,
            )

        def write(cell: OpenCell, run) -> dict:
            if run.fault is None:
                self.pool.give(cell.spec, cell.policy)
            w = cell.world
            world = _RecordedWorld(
                w.name,
                float(w.fps),
                list(getattr(w, "condition", None) or []),
                w.outcome() or {},
                dict(getattr(w, "timing", None) or {}),
            )
            return {"run": run, "world": world, "seconds": time.perf_counter() - cell.started}

        def finish(index: int, payload: dict) -> None:
            results.append((index, payload))

        if batch_cells > 1:
            run_lock_step(jobs, open_job, finish, batch_cells=batch_cells, write=write, timeout=timeout)
        else:
            for job in jobs:
                cell = open_job(job)
                finish(job[0], write(cell, run_open_cell(cell, timeout)))
        return results


def run_on_ray(
    pending: list,
    finish: Callable,
    write: Callable,
    *,
    model_spec,
    revision,
    simulator,
    device,
    dtype,
    tiny_decoder,
    tiny_encoder,
    workers: int,
    batch_cells: int,
    timeout,
    plugin_paths,
    world_options: dict,
    log: Callable[[str], None],
) -> None:
    """Run the ``pending`` cells ((index, session, spec, parts, key, K), manifest order) on Ray actors (module
    docstring); for each as it comes back, ``finish(index, write(cell, run))`` in this process."""
    from ..plugin.registry import get_embodiment

    ray, actors, n, gpu = start_ray_actors(
        _ClosedLoopWorker,
        -(-len(pending) // batch_cells),
        workers=workers,
        model_spec=model_spec,
        revision=revision,
        device=device,
        dtype=dtype,
        plugin_paths=plugin_paths,
        log=log,
        extra=lambda share: (simulator, tiny_decoder, tiny_encoder),
    )
    log(f"running {len(pending)} closed-loop cells on {n} Ray worker(s) ({'one GPU' if gpu else 'one CPU'} each)")
    queue = [pending[i : i + batch_cells] for i in range(0, len(pending), batch_cells)]
    by_index = {job[0]: job for job in pending}
    embs: dict = {}
    in_flight: dict = {}

    def submit(actor) -> None:
        if queue:
            in_flight[actor.run.remote(queue.pop(0), world_options, batch_cells, timeout)] = actor

    try:
        for actor in actors:
            submit(actor)
        while in_flight:
            (ref,), _ = ray.wait(list(in_flight), num_returns=1)
            actor = in_flight.pop(ref)
            results = ray_result(ray, ref, model_spec or "the simulator")
            submit(actor)
            for index, payload in results:
                _, s, spec, parts, key, K = by_index[index]
                if s.embodiment not in embs:
                    embs[s.embodiment] = get_embodiment(s.embodiment, plugin_paths)
                run = payload["run"]
                cell = OpenCell(
                    s,
                    spec,
                    embs[s.embodiment],
                    parts,
                    key,
                    payload["world"],
                    None,
                    np.asarray(run.q[0]),
                    np.asarray(run.gripper[0]),
                    K,
                    time.perf_counter() - payload["seconds"],
                )
                finish(index, write(cell, run))
    finally:
        for actor in actors:
            ray.kill(actor)
