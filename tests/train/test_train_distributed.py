"""1 process == 2 processes (gloo, CPU) with the same global batch, under DDP and FSDP2 (one torchrun launch
trains both, tests/_torchrun.py): the same weights, and metrics.jsonl reports the whole global batch
(``sigma_mean`` and ``skeleton_dropped`` of the 2 processes equal those of 1 process and those of the step's plan)."""

import json

import pytest
import torch
import yaml
from _models import tiny_clipset
from _torchrun import train_under_torchrun

from oscar_core.train.checkpoint import latest_checkpoint, load_weights
from oscar_core.train.config import load_config
from oscar_core.train.data import TrainData
from oscar_core.train.loop import train
from oscar_core.train.models import build_transformer, build_vae
from oscar_core.train.sampling import StepPlanner

pytestmark = pytest.mark.slow

STEPS, BATCH = 3, 4


@pytest.fixture(scope="module")
def clipset(tmp_path_factory):
    return tiny_clipset(tmp_path_factory.mktemp("clips") / "toy", clips=3)


def _config(tmp_path, clipset, name, parallel="auto"):
    """The YAML file of a tiny run of STEPS steps (global batch BATCH, micro-batch 1, metrics logged every step) in
    ``tmp_path/name``."""
    cfg = {
        "run_dir": str(tmp_path / name),
        "steps": STEPS,
        "batch_size": BATCH,
        "micro_batch": 1,
        "save_every": STEPS,
        "log_every": 1,
        "parallel": parallel,
        "export": False,
        "model": {"transformer": "tiny", "vae": "tiny"},
        "data": {"clips": [str(clipset)], "window": 9, "width": 32, "height": 32, "skeleton_dropout": 0.5},
        "optim": {"lr": 1e-3, "warmup_steps": 0, "grad_clip": 1.0, "ema_decay": 0.5},
    }
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


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
    n = torch.get_num_threads()
    torch.set_num_threads(1)  # in this process: the plain loop, no process group
    try:
        train(_config(tmp, clipset, "one"), progress=False)
    finally:
        torch.set_num_threads(n)
    start = build_transformer(load_config(tmp / "one" / "config.yaml")).state_dict()
    assert not close(_weights(tmp / "one")["model"], start)  # training moved the weights
    return tmp / "one"


@pytest.fixture(scope="module")
def two_processes(tmp_path_factory, clipset):
    """The run folders of the DDP and the FSDP2 run, both trained by one launch of 2 gloo processes."""
    tmp = tmp_path_factory.mktemp("two")
    modes = ("ddp", "fsdp")
    out = train_under_torchrun([_config(tmp, clipset, mode, parallel=mode) for mode in modes])
    assert out.returncode == 0, out.stderr[-3000:]
    return {mode: tmp / mode for mode in modes}


@pytest.mark.parametrize("parallel", ["ddp", "fsdp"])
def test_two_processes_match_one_process(one_process, two_processes, parallel):
    """DDP, and FSDP2 with fully_shard per block (sharded state, resharded by DCP on load), on 2 gloo processes."""
    one, two = _weights(one_process), _weights(two_processes[parallel])
    for key in ("model", "ema"):
        assert close(one[key], two[key]), key


def _steps(run_dir):
    lines = [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines()]
    return [r for r in lines if "loss" in r]


@pytest.mark.parametrize("parallel", ["ddp", "fsdp"])
def test_two_processes_log_the_global_batch(one_process, two_processes, parallel):
    one, two = _steps(one_process), _steps(two_processes[parallel])
    assert [r["step"] for r in one] == [r["step"] for r in two] == list(range(1, STEPS + 1))

    # the reference: the step's global batch as the planner draws it from (seed, step)
    cfg = load_config(one_process / "config.yaml")
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
