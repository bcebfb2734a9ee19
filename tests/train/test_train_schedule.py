"""The learning-rate warm-up and the EMA, checked against their definitions on a tiny run: the first step trains at
lr / warmup (not 0), and the EMA after each step is decay * EMA + (1 - decay) * weights, from the initial weights."""

import pytest
import torch
from _models import tiny_clipset

from oscar_core.train.checkpoint import list_checkpoints, load_weights
from oscar_core.train.config import config_from_dict, load_config
from oscar_core.train.loop import lr_at, train
from oscar_core.train.models import build_transformer

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def test_warmup_is_linear_from_the_first_step():
    assert lr_at(0, 1e-3, 4) == pytest.approx(0.25e-3)  # step 0 already trains
    assert [lr_at(s, 1.0, 4) for s in range(6)] == pytest.approx([0.25, 0.5, 0.75, 1.0, 1.0, 1.0])
    assert lr_at(0, 1e-3, 1) == 1e-3 and lr_at(0, 1e-3, 0) == 1e-3 and lr_at(7, 2e-5, 0) == 2e-5


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("schedule")
    clips = tiny_clipset(root / "clips", clips=2)
    cfg = config_from_dict(
        {
            "run_dir": str(root / "run"),
            "steps": 3,
            "batch_size": 1,
            "micro_batch": 1,
            "save_every": 1,
            "keep_last": 3,
            "log_every": 1,
            "export": False,
            "model": {"transformer": "tiny", "vae": "tiny"},
            "data": {"clips": [str(clips)], "window": 9, "width": 32, "height": 32},
            "optim": {"lr": 1e-3, "warmup_steps": 4, "grad_clip": 1.0, "ema_decay": 0.75},
        }
    )
    train(cfg, progress=False)
    return root / "run"


def test_the_logged_lr_follows_the_warmup_and_the_first_step_moves_the_weights(run):
    import json

    steps = [json.loads(x) for x in (run / "metrics.jsonl").read_text().splitlines()]
    lrs = [r["lr"] for r in steps if "loss" in r]
    assert lrs == pytest.approx([0.25e-3, 0.5e-3, 0.75e-3])
    cfg = load_config(run / "config.yaml")
    start = build_transformer(cfg).state_dict()
    first = load_weights(list_checkpoints(run)[0], build_transformer(cfg), key="model").state_dict()
    assert any(not torch.equal(start[k], first[k]) for k in start)  # lr 0 at step 1 would leave them


def test_the_ema_is_its_recursion_over_the_saved_weights(run):
    cfg = load_config(run / "config.yaml")
    decay = cfg.optim.ema_decay
    ckpts = list_checkpoints(run)
    assert [int(p.name.split("-")[1]) for p in ckpts] == [1, 2, 3]
    ema = {n: p.detach().clone() for n, p in build_transformer(cfg).named_parameters()}  # the initial weights
    for ckpt in ckpts:
        model = dict(load_weights(ckpt, build_transformer(cfg), key="model").named_parameters())
        saved = dict(load_weights(ckpt, build_transformer(cfg), key="ema").named_parameters())
        ema = {n: decay * ema[n] + (1.0 - decay) * model[n].detach() for n in ema}
        for n in ema:
            torch.testing.assert_close(saved[n].detach(), ema[n], rtol=1e-5, atol=1e-7, msg=f"{ckpt.name} {n}")
    moved = [n for n in ema if not torch.equal(model[n], ema[n])]
    assert moved  # the EMA lags the weights: the check above is not weights == EMA
