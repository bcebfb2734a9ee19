"""Optional Weights & Biases logging (``log.wandb: true``): the metrics of ``metrics.jsonl``, as LeRobot and
diffusers' training scripts offer it beside TensorBoard.

Rank 0 opens one W&B run per training run: its id is kept in ``RUN_DIR/wandb_run_id`` so ``oscar train
--resume`` continues the same W&B run (``resume="allow"``), its files go under ``RUN_DIR/wandb/``, its name is
the run folder's, and its config is the effective training config. Each logged step records ``train/loss``,
``train/lr``, ``train/grad_norm``, ``train/steps_per_s``, ``train/sigma_mean`` and
``train/skeleton_dropped`` at that step (the same numbers as the JSONL line, the same names as TensorBoard's).
``log.wandb_mode``: ``offline`` (default: nothing leaves the machine; ``wandb sync RUN_DIR/wandb/...``
uploads later), ``online`` or ``disabled``. ``log.wandb_project`` names the project (default ``oscar``).
The ``wandb`` package is an optional extra: ``pip install "oscar-wm[wandb]"``.
"""

from __future__ import annotations

import secrets
from pathlib import Path

from .._util.atomic import atomic_write_bytes
from .tensorboard import SCALARS

__all__ = ["WANDB_MODES", "RUN_ID_FILE", "require_wandb", "WandbLog"]

WANDB_MODES = ("offline", "online", "disabled")
RUN_ID_FILE = "wandb_run_id"


def require_wandb():
    """The ``wandb`` module, or ImportError naming the extra when it is missing."""
    try:
        import wandb
    except ImportError:
        raise ImportError(
            'log.wandb: true needs the wandb package; install it with: pip install "oscar-wm[wandb]" '
            "(or set log.wandb: false)"
        ) from None
    return wandb


class WandbLog:
    """Logs one metrics record (a ``metrics.jsonl`` line as a dict) per call to a W&B run."""

    def __init__(self, run_dir, config: dict, project: str = "oscar", mode: str = "offline"):
        wandb = require_wandb()
        run_dir = Path(run_dir)
        id_file = run_dir / RUN_ID_FILE
        run_id = id_file.read_text().strip() if id_file.is_file() else None
        if not run_id:
            run_id = secrets.token_hex(8)
            atomic_write_bytes(id_file, (run_id + "\n").encode())
        self.run = wandb.init(
            project=project,
            dir=str(run_dir),
            id=run_id,
            resume="allow",
            mode=mode,
            name=run_dir.resolve().name,
            config=config,
        )

    def write(self, record: dict) -> None:
        values = {f"train/{name}": float(record[name]) for name in SCALARS if record.get(name) is not None}
        self.run.log(values, step=int(record["step"]))

    def close(self) -> None:
        self.run.finish()
