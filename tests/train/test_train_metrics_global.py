"""Under torchrun, metrics.jsonl reports the whole global batch: ``sigma_mean`` and ``skeleton_dropped`` of 2 gloo
processes equal those of 1 process with the same global batch, and those of the step's plan."""

import json
import os
import socket
import subprocess
import sys

import pytest
import torch
import yaml
from _models import tiny_clipset

from oscar_core.train.config import load_config
from oscar_core.train.loop import train
from oscar_core.train.sampling import StepPlanner

pytestmark = pytest.mark.slow

STEPS, BATCH = 3, 4


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _config(tmp_path, clips, name):
    cfg = {
        "run_dir": str(tmp_path / name),
        "steps": STEPS,
        "batch_size": BATCH,
        "micro_batch": 1,
        "save_every": STEPS,
        "log_every": 1,
        "parallel": "auto",
        "export": False,
        "model": {"transformer": "tiny", "vae": "tiny"},
        "data": {"clips": [str(clips)], "window": 9, "width": 32, "height": 32, "skeleton_dropout": 0.5},
        "optim": {"lr": 1e-3, "warmup_steps": 0, "grad_clip": 1.0, "ema_decay": 0.5},
    }
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def _steps(run_dir):
    lines = [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()]
    return [r for r in lines if "loss" in r]


def test_two_processes_log_the_global_batch(tmp_path):
    clips = tiny_clipset(tmp_path / "clips", clips=3)
    one_cfg = _config(tmp_path, clips, "one")
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        train(one_cfg, progress=False)
    finally:
        torch.set_num_threads(n)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--nproc-per-node",
        "2",
        "--master-addr",
        "127.0.0.1",
        "--master-port",
        str(_port()),
        "-m",
        "oscar_core.train",
        str(_config(tmp_path, clips, "two")),
        "--no-progress",
    ]
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    one, two = _steps(tmp_path / "one"), _steps(tmp_path / "two")
    assert [r["step"] for r in one] == [r["step"] for r in two] == list(range(1, STEPS + 1))

    # the reference: the step's global batch as the planner draws it from (seed, step)
    from oscar_core.train.data import TrainData
    from oscar_core.train.models import build_transformer, build_vae

    cfg = load_config(one_cfg)
    planner = TrainData(cfg, build_vae(cfg), build_transformer(cfg).text_dim).planner()
    dropped_any = False
    for r1, r2 in zip(one, two):
        items = planner.plan(r1["step"] - 1, BATCH)
        want_sigma = sum(i.sigma for i in items) / BATCH
        want_dropped = sum(i.drop for i in items)
        dropped_any |= 0 < want_dropped < BATCH
        assert r1["sigma_mean"] == pytest.approx(want_sigma, abs=1e-12)
        assert r2["sigma_mean"] == pytest.approx(want_sigma, abs=1e-12)
        assert r1["skeleton_dropped"] == r2["skeleton_dropped"] == want_dropped
        assert r2["loss"] == pytest.approx(r1["loss"], rel=1e-4, abs=1e-6)  # already all-reduced before this fix
    # a rank's half and the whole differ on at least one step (else the test could not tell them apart)
    halves = [sum(i.drop for i in StepPlanner.rank_slice(planner.plan(s, BATCH), 0, 2)) for s in range(STEPS)]
    assert dropped_any and halves != [r["skeleton_dropped"] for r in one]
