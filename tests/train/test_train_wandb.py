"""log.wandb: the metrics.jsonl numbers logged to one W&B run per training run (kept across --resume), or an
ImportError naming the extra. A stand-in ``wandb`` module records the calls (the real package is an optional
extra and never talks to a server in tests)."""

import importlib.machinery
import json
import sys
import types

import pytest
import torch
from _models import tiny_clipset, tiny_train_config

from oscar_core.train.config import TrainConfigError
from oscar_core.train.loop import train


@pytest.fixture(scope="module")
def clipset(tmp_path_factory):
    return tiny_clipset(tmp_path_factory.mktemp("wb") / "toy", clips=2)


class _FakeWandb(types.ModuleType):
    def __init__(self):
        super().__init__("wandb")
        self.__spec__ = importlib.machinery.ModuleSpec("wandb", None)  # libraries probe find_spec("wandb")
        self.inits, self.logs, self.finished = [], [], 0

    def init(self, **kwargs):
        self.inits.append(kwargs)
        fake = self

        class Run:
            def log(self, values, step):
                fake.logs.append((step, dict(values)))

            def finish(self):
                fake.finished += 1

        return Run()


def _one_thread(fn):
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return fn()
    finally:
        torch.set_num_threads(n)


def test_metrics_go_to_one_wandb_run_that_resume_continues(tmp_path, clipset, monkeypatch):
    fake = _FakeWandb()
    monkeypatch.setitem(sys.modules, "wandb", fake)
    run = tmp_path / "run"
    cfg = tiny_train_config(clipset, run, steps=4, save_every=2, **{"log.wandb": True, "log.wandb_project": "p"})
    _one_thread(lambda: train(cfg, progress=False, stop_after=2))
    _one_thread(lambda: train(None, resume=run, progress=False))
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    rows = [r for r in rows if "loss" in r]
    assert [step for step, _ in fake.logs] == [r["step"] for r in rows] == [1, 2, 3, 4]
    for (_step, values), r in zip(fake.logs, rows):
        assert values["train/loss"] == pytest.approx(r["loss"]) and values["train/lr"] == pytest.approx(r["lr"])
        assert values["train/grad_norm"] == pytest.approx(r["grad_norm"])
    first, second = fake.inits
    assert first["id"] == second["id"] == (run / "wandb_run_id").read_text().strip()  # the same W&B run
    assert first["resume"] == "allow" and first["project"] == "p" and first["mode"] == "offline"
    assert first["dir"] == str(run) and first["config"]["steps"] == 4 and fake.finished == 2


def test_missing_wandb_names_the_extra_before_anything_is_written(tmp_path, clipset, monkeypatch):
    monkeypatch.setitem(sys.modules, "wandb", None)  # `import wandb` raises ImportError
    cfg = tiny_train_config(clipset, tmp_path / "run", steps=1, **{"log.wandb": True})
    with pytest.raises(ImportError, match=r'pip install "oscar-wm\[wandb\]"'):
        train(cfg, progress=False)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "field, value, expected",
    [("log.wandb", "yes", "true or false"), ("log.wandb_mode", "cloud", "offline, online or disabled")],
)
def test_the_settings_are_checked(tmp_path, clipset, field, value, expected):
    with pytest.raises(TrainConfigError, match=f"'{field}': expected {expected}"):
        tiny_train_config(clipset, tmp_path, **{field: value})
