"""Load the micro-batches of a run in order, in the main process or ahead of time in worker threads.

``data.workers: 0`` (default) loads each micro-batch when the loop asks for
it. ``data.workers: N`` loads them in N threads, up to ``N × data.prefetch``
micro-batches ahead of the one being trained on, and hands them back in plan
order. The content of a micro-batch is a function of its plan items alone
(window start, dropout, noise seed are drawn by the planner from (seed,
step)), so N workers give exactly the batches of 0 workers (tested).

Threads, not processes: the VAE runs where the model does (a GPU cannot be
shared by forked workers), nothing is pickled, and video decoding, file
reads and the renderer's tensor work release the GIL. The VAE's encodes are
serialised by a lock in :class:`~oscar_core.train.data.TrainData` (diffusers'
VAE kept its causal-convolution cache on the module; oscar's ``WanVAE`` keeps
it per call, so the lock now only keeps one encode on the cores at a time);
what overlaps is reading, decoding, rendering and the training step.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor

from .data import Batch, TrainData
from .sampling import PlanItem

__all__ = ["iter_batches", "micro_batches"]


def micro_batches(
    plan: Callable[[int], list[PlanItem]], start: int, end: int, accum: int, micro_batch: int
) -> Iterator[tuple[int, int, list[PlanItem]]]:
    """(step, k, items) of every micro-batch k < ``accum`` of steps [start, end); ``plan(step)`` is this process's share."""
    for step in range(start, end):
        mine = plan(step)
        for k in range(accum):
            yield step, k, mine[k * micro_batch : (k + 1) * micro_batch]


def iter_batches(
    data: TrainData,
    schedule: Iterator[tuple[int, int, list[PlanItem]]],
    condition: str,
    workers: int = 0,
    prefetch: int = 2,
) -> Iterator[tuple[int, int, list[PlanItem], Batch]]:
    """(step, k, items, batch) in ``schedule`` order; ``workers`` threads keep ``workers × prefetch`` batches in flight.

    An error while loading a batch is raised when that batch's turn comes (the
    batches before it are still handed out). Closing the iterator (or leaving
    the loop) cancels what was not started and waits for the running loads.
    """
    if workers <= 0:
        for step, k, items in schedule:
            yield step, k, items, data.batch(items, condition)
        return
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="oscar-train-data")
    pending: deque[tuple[int, int, list[PlanItem], Future]] = deque()
    ahead = workers * max(1, int(prefetch))
    try:
        source = iter(schedule)
        exhausted = False
        while True:
            while not exhausted and len(pending) < ahead:
                try:
                    step, k, items = next(source)
                except StopIteration:
                    exhausted = True
                    break
                pending.append((step, k, items, pool.submit(data.batch, items, condition)))
            if not pending:
                return
            step, k, items, future = pending.popleft()
            yield step, k, items, future.result()
    finally:
        for *_, future in pending:
            future.cancel()
        pool.shutdown(wait=True, cancel_futures=True)
