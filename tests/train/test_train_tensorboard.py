"""log.tensorboard: the metrics.jsonl numbers as TensorBoard scalars, or an ImportError naming the extra."""

import json
import sys

import pytest
import torch
from _models import tiny_clipset, tiny_train_config

from oscar_core.train.config import TrainConfigError
from oscar_core.train.loop import train


@pytest.fixture(scope="module")
def clipset(tmp_path_factory):
    return tiny_clipset(tmp_path_factory.mktemp("tb") / "toy", clips=2)


def test_scalars_equal_the_metrics_file(tmp_path, clipset):
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        cfg = tiny_train_config(clipset, tmp_path / "run", steps=3, save_every=3, **{"log.tensorboard": True})
        train(cfg, progress=False)
    finally:
        torch.set_num_threads(n)
    rows = [json.loads(l) for l in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    rows = [r for r in rows if "loss" in r]
    acc = EventAccumulator(str(tmp_path / "run" / "tensorboard")).Reload()
    assert {"train/loss", "train/lr", "train/grad_norm", "train/steps_per_s"} <= set(acc.Tags()["scalars"])
    for tag in ("loss", "lr", "grad_norm"):
        events = acc.Scalars(f"train/{tag}")
        assert [e.step for e in events] == [r["step"] for r in rows] == [1, 2, 3]
        assert [e.value for e in events] == pytest.approx([r[tag] for r in rows], rel=1e-6)


def test_missing_tensorboard_names_the_extra_before_anything_is_written(tmp_path, clipset, monkeypatch):
    monkeypatch.setitem(sys.modules, "tensorboard", None)  # `import tensorboard` raises ImportError
    cfg = tiny_train_config(clipset, tmp_path / "run", steps=1, **{"log.tensorboard": True})
    with pytest.raises(ImportError, match=r'pip install "oscar-wm\[tensorboard\]"'):
        train(cfg, progress=False)
    assert not (tmp_path / "run").exists()


def test_the_switch_is_a_boolean(tmp_path, clipset):
    with pytest.raises(TrainConfigError, match="'log.tensorboard': expected true or false, found str 'yes'"):
        tiny_train_config(clipset, tmp_path, **{"log.tensorboard": "yes"})
