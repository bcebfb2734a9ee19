"""Several training runs under one ``torchrun`` launch: :func:`train_under_torchrun` starts 2 gloo processes (one
thread each) that run ``oscar_core.train``'s command on each config in turn, as ``torchrun -m oscar_core.train
CONFIG`` would one at a time. A launch costs an import of torch and the training stack in every process; the tests
that compare DDP and FSDP2 runs with one process share one launch instead of paying it per parallel mode.

Run as a script (by torchrun): ``_torchrun.py CONFIG.yaml [CONFIG.yaml ...]``; stops at the first run that fails
and exits with its code, naming the config on stderr. The runs share one gloo process group, started here and
closed after the last run (``train`` uses a group that exists and, here only, leaves it open: a second group
started against torchrun's store after the first was closed waits forever)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

_REPO = Path(__file__).resolve().parent.parent


def train_under_torchrun(configs, nproc: int = 2, timeout: float = 300) -> subprocess.CompletedProcess:
    """Train each config (paths to YAML files) in turn on ``nproc`` gloo processes of one ``torchrun`` launch;
    returns the finished launcher (its ``returncode``: 0 when every run finished)."""
    # --standalone: torchrun's own store listens on a port the OS picks and the workers meet there; a port picked
    # here and closed before torchrun binds it could be taken meanwhile by a launch of another test worker
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", str(nproc)]
    cmd += [__file__, *map(str, configs)]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout, check=False)


def _main(paths: list[str]) -> int:
    # the checkout's oscar_core (as `-m oscar_core.train` run from the repository root would import it)
    sys.path.insert(0, str(_REPO))
    import torch.distributed as dist

    import oscar_core.train.loop as loop
    from oscar_core.train.__main__ import main

    dist.init_process_group("gloo")
    loop.close_distributed = lambda info: None
    try:
        for path in paths:
            code = main([path, "--no-progress"])
            if code:
                print(f"_torchrun: training {path} exited {code}", file=sys.stderr)
                return code
    finally:
        dist.destroy_process_group()
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
