"""Optional TensorBoard logging (``log.tensorboard: true``): the metrics of ``metrics.jsonl`` as scalars.

Events go to ``RUN_DIR/tensorboard/`` (``tensorboard --logdir RUN_DIR``),
written by rank 0 only, through ``torch.utils.tensorboard.SummaryWriter``.
Each logged step writes ``train/loss``, ``train/lr``, ``train/grad_norm``,
``train/steps_per_s``, ``train/sigma_mean`` and ``train/skeleton_dropped``
at that step (the optimiser steps done), the same numbers as the JSONL line.
The ``tensorboard`` package is an optional extra: ``pip install "oscar-wm[tensorboard]"``.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["TENSORBOARD_DIR", "SCALARS", "require_tensorboard", "TensorBoardLog"]

TENSORBOARD_DIR = "tensorboard"
SCALARS = ("loss", "lr", "grad_norm", "steps_per_s", "sigma_mean", "skeleton_dropped")


def require_tensorboard():
    """``torch.utils.tensorboard.SummaryWriter``, or ImportError naming the extra when ``tensorboard`` is missing."""
    try:
        import tensorboard  # noqa: F401 - torch.utils.tensorboard needs it
    except ImportError:
        raise ImportError(
            "log.tensorboard: true needs the tensorboard package; install it with: "
            'pip install "oscar-wm[tensorboard]" (or set log.tensorboard: false)'
        ) from None
    from torch.utils.tensorboard import SummaryWriter

    return SummaryWriter


class TensorBoardLog:
    """Writes one metrics record (a ``metrics.jsonl`` line as a dict) per call as scalars under ``train/``."""

    def __init__(self, run_dir, purge_step: int | None = None):
        writer_cls = require_tensorboard()
        # purge_step: a resumed run hides the events a crashed run wrote after its last checkpoint
        self.writer = writer_cls(log_dir=str(Path(run_dir) / TENSORBOARD_DIR), purge_step=purge_step)

    def write(self, record: dict) -> None:
        step = int(record["step"])
        for name in SCALARS:
            if record.get(name) is not None:
                self.writer.add_scalar(f"train/{name}", float(record[name]), step)
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()
