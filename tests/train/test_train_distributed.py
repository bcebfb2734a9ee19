"""1 process == 2 processes (gloo, CPU) with the same global batch, under DDP and FSDP2 (torchrun launches)."""

import os
import socket
import subprocess
import sys

import pytest
import torch
import yaml
from _models import tiny_clipset

from oscar_core.train.checkpoint import latest_checkpoint, load_weights
from oscar_core.train.config import load_config
from oscar_core.train.loop import train
from oscar_core.train.models import build_transformer

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def clipset(tmp_path_factory):
    return tiny_clipset(tmp_path_factory.mktemp("clips") / "toy", clips=3)


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(tmp_path, clipset, name, nproc, parallel="auto"):
    cfg = {
        "run_dir": str(tmp_path / name),
        "steps": 3,
        "batch_size": 4,
        "micro_batch": 1,
        "save_every": 3,
        "parallel": parallel,
        "export": False,
        "model": {"transformer": "tiny", "vae": "tiny"},
        "data": {"clips": [str(clipset)], "window": 9, "width": 32, "height": 32, "skeleton_dropout": 0.5},
        "optim": {"lr": 1e-3, "warmup_steps": 0, "grad_clip": 1.0, "ema_decay": 0.5},
    }
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(cfg))
    if nproc == 1:  # in this process: the plain loop, no process group
        n = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            train(path, progress=False)
        finally:
            torch.set_num_threads(n)
        return _weights(tmp_path / name)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--nproc-per-node",
        str(nproc),
        "--master-addr",
        "127.0.0.1",
        "--master-port",
        str(_port()),
        "-m",
        "oscar_core.train",
        str(path),
        "--no-progress",
    ]
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    return _weights(tmp_path / name)


def _weights(run_dir):
    model = build_transformer(load_config(run_dir / "config.yaml"))
    out = {}
    for key in ("model", "ema"):
        out[key] = {
            k: v.clone() for k, v in load_weights(latest_checkpoint(run_dir), model, key=key).state_dict().items()
        }
    return out


def close(a, b, atol=2e-6):
    return all(torch.allclose(a[k], b[k], atol=atol, rtol=1e-5) for k in a)


@pytest.fixture(scope="module")
def one_process(tmp_path_factory, clipset):
    tmp = tmp_path_factory.mktemp("one")
    one = run(tmp, clipset, "one", 1)
    start = build_transformer(load_config(tmp / "one" / "config.yaml")).state_dict()
    assert not close(one["model"], start)  # training moved the weights
    return one


@pytest.mark.parametrize("parallel", ["ddp", "fsdp"])
def test_two_processes_match_one_process(tmp_path, clipset, one_process, parallel):
    """DDP, and FSDP2 with fully_shard per block (sharded state, resharded by DCP on load), on 2 gloo processes."""
    two = run(tmp_path, clipset, parallel, 2, parallel=parallel)
    for key in ("model", "ema"):
        assert close(one_process[key], two[key]), key
