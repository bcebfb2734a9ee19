"""Closed-loop cells in lock-step: N cells advance together, one batched world-model call per chunk.

:func:`run_lock_step` keeps up to ``batch_cells`` cells in flight. Each round, every cell that has no chunk
request yet is advanced (its :func:`~.closed_loop.cell_steps` generator: observe, call the policy, adapt its
actions) on a thread of its own, so slow (remote) policies wait in parallel; then the chunk requests of all
cells in flight are generated together: the world-model cells whose condition videos share one shape and
whose prompts share one shape in one :meth:`~oscar_core.model.OscarWorldModel.rollout_batch` call (each
video equal to its own ``rollout`` up to float rounding), a simulator's cells one by one. A cell that ends
(horizon, ``done``, or a policy fault) is written at once and leaves the batch, and the next waiting cell
joins it before the next chunk is generated, so the batch stays full until the waiting cells run out
(then it shrinks). Each cell keeps its own seed per chunk and its own policy object, so its frames equal
those of the one-at-a-time loop up to the batch's float rounding (tested: within one uint8 level).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..policy.protocol import PolicyFault
from .closed_loop_cell import ModelWorld, OpenCell, failed_to_load, generate_chunks

__all__ = ["generate_together", "run_lock_step"]


@dataclass
class _Slot:
    index: int
    cell: OpenCell
    steps: object  # the cell's generator
    started: bool = False
    frames: np.ndarray | None = None  # the chunk generated for its last request
    request: tuple | None = None  # (q (n, J), gripper (n, G)) of its next chunk
    run: object = None  # its CellRun once finished


def _advance(slot: _Slot) -> None:
    """Run a cell's generator to its next chunk request (or its end)."""
    try:
        slot.request = slot.steps.send(slot.frames) if slot.started else next(slot.steps)
        slot.started = True
    except StopIteration as stop:
        slot.run = stop.value
    slot.frames = None


def _batch_key(world: ModelWorld, inputs: dict) -> tuple:
    prompt = inputs["prompt"]
    return id(world.model), world.chunk_frames, inputs["video"].shape, None if prompt is None else tuple(prompt.shape)


def generate_together(requests: list[tuple]) -> list[np.ndarray]:
    """Generate the requested chunk of every ``(world, (q, gripper))`` pair: the world-model ones
    (:class:`ModelWorld`) in one batched call per key (model, chunk length, condition and prompt shapes), the others
    by their world's ``step``. Returns each pair's (n, H, W, 3) uint8 new frames, in order; each world has taken
    its chunk (``accept``). A batched call's seconds are shared among its worlds' ``timing``."""
    out: list = [None] * len(requests)
    groups: dict[tuple, list] = {}
    for k, (world, request) in enumerate(requests):
        if isinstance(world, ModelWorld):
            inputs = world.chunk_inputs(*request)
            groups.setdefault(_batch_key(world, inputs), []).append((k, inputs))
        else:
            out[k] = world.step(*request)
    for group in groups.values():
        world0 = requests[group[0][0]][0]
        t0 = time.perf_counter()
        videos = generate_chunks(
            world0.model, [i for _, i in group], chunk_frames=world0.chunk_frames, sampler=world0.sampler
        )
        share = (time.perf_counter() - t0) / len(group)
        for (k, inputs), video in zip(group, videos):
            world, request = requests[k]
            world.timing["model_s"] += share
            out[k] = world.accept(*request, inputs, video)
    return out


def run_lock_step(
    jobs: list,
    open_cell: Callable,
    finish: Callable,
    *,
    batch_cells: int,
    write: Callable,
    timeout,
) -> None:
    """Run ``jobs`` (each ``(index, ...)``; ``open_cell(job)`` gives its :class:`OpenCell`) with up to
    ``batch_cells`` in flight (module docstring); as each ends, ``finish(index, write(cell, run))`` is called
    (``write``: e.g. :func:`~.closed_loop._write_cell` of the run folder)."""
    waiting = list(jobs)
    active: list[_Slot] = []
    with ThreadPoolExecutor(max_workers=batch_cells, thread_name_prefix="closed-loop-cell") as threads:
        while waiting or active:
            while waiting and len(active) < batch_cells:
                job = waiting.pop(0)
                cell = open_cell(job)
                if isinstance(cell.policy, PolicyFault):
                    finish(job[0], write(cell, failed_to_load(cell)))
                    continue
                active.append(_Slot(job[0], cell, cell.steps(timeout)))
            need = [s for s in active if s.request is None]
            for _ in threads.map(_advance, need):  # policy calls of several cells at once; errors raise here
                pass
            ended = [s for s in active if s.run is not None]
            for slot in ended:
                finish(slot.index, write(slot.cell, slot.run))
                active.remove(slot)
            if ended and waiting:
                continue  # the next waiting cells join before the batch's next chunk
            if active:
                new = generate_together([(slot.cell.world, slot.request) for slot in active])
                for slot, frames in zip(active, new):
                    slot.frames, slot.request = frames, None
