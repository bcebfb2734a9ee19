"""data.workers: micro-batches loaded ahead in threads are exactly those loaded in the loop."""

import numpy as np
import pytest
import torch
from _models import tiny_train_config, trained_weights

from oscar_core.train.config import TrainConfigError
from oscar_core.train.data import TrainData
from oscar_core.train.loader import iter_batches, micro_batches
from oscar_core.train.loop import train
from oscar_core.train.models import build_vae
from oscar_core.train.sampling import StepPlanner
from oscar_core.train.synthetic import write_toy_clipset

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def onthefly(tmp_path_factory):
    """Clips without cached latents: every window is read, rendered (no stored skeleton) and encoded."""
    return write_toy_clipset(tmp_path_factory.mktemp("otf") / "toy", clips=3, frames=13, width=32, height=32)


def _schedule(data, cfg, steps, accum=1):
    planner = data.planner()
    return micro_batches(
        lambda s: StepPlanner.rank_slice(planner.plan(s, cfg.batch_size), 0, 1), 0, steps, accum, cfg.micro_batch
    )


def test_worker_threads_give_the_batches_of_the_main_process_in_order(tmp_path, onthefly):
    cfg = tiny_train_config(
        onthefly,
        tmp_path / "r",
        batch_size=4,
        micro_batch=2,
        **{"data.skeleton_dropout": 0.5, "data.unconditional_skeleton": "black_video"},
    )
    vae = build_vae(cfg)
    plain = list(iter_batches(TrainData(cfg, vae, 48), _schedule(TrainData(cfg, vae, 48), cfg, 4, 2), "skeleton"))
    data = TrainData(cfg, vae, 48)
    threaded = list(iter_batches(data, _schedule(data, cfg, 4, 2), "skeleton", workers=3, prefetch=2))
    assert [(s, k) for s, k, *_ in plain] == [(s, k) for s, k in np.ndindex(4, 2)]
    assert [(s, k, items) for s, k, items, _ in threaded] == [(s, k, items) for s, k, items, _ in plain]
    assert any(it.drop for _, _, items, _ in plain for it in items)  # the black-video latent is exercised
    for (*_, a), (*_, b) in zip(plain, threaded):
        assert torch.equal(a.z0, b.z0) and torch.equal(a.skeleton, b.skeleton) and torch.equal(a.text, b.text)


def test_a_run_with_workers_equals_a_run_without(tmp_path, onthefly):
    runs = {}
    for workers in (0, 2):
        cfg = tiny_train_config(onthefly, tmp_path / f"w{workers}", steps=2, save_every=2, **{"data.workers": workers})
        runs[workers] = train(cfg, progress=False).last_loss
    assert runs[0] == runs[2]
    a, b = trained_weights(tmp_path / "w0"), trained_weights(tmp_path / "w2")
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_a_load_error_surfaces_in_order_and_the_pool_stops(tmp_path, onthefly):
    cfg = tiny_train_config(onthefly, tmp_path / "r", batch_size=1, micro_batch=1)
    data = TrainData(cfg, build_vae(cfg), 48)
    calls = []
    real = data.batch

    def flaky(items, condition):
        calls.append(items)
        if len(calls) == 3:
            raise OSError("disk gone")
        return real(items, condition)

    data.batch = flaky
    it = iter_batches(data, _schedule(data, cfg, 10), "skeleton", workers=2, prefetch=1)
    got = [next(it)[0], next(it)[0]]
    assert got == [0, 1]
    with pytest.raises(OSError, match="disk gone"):
        next(it)
    assert len(calls) <= 5  # at most workers x prefetch loads ahead, then nothing more is started


def test_workers_and_prefetch_are_checked(tmp_path, onthefly):
    with pytest.raises(TrainConfigError, match="data.workers': expected an integer >= 0"):
        tiny_train_config(onthefly, tmp_path, **{"data.workers": -1})
    with pytest.raises(TrainConfigError, match="data.prefetch': expected a positive integer"):
        tiny_train_config(onthefly, tmp_path, **{"data.prefetch": 0})


def test_the_start_line_counts_clips_trained_without_text(tmp_path, onthefly):
    cfg = tiny_train_config(onthefly, tmp_path / "r")
    assert TrainData(cfg, None, 48).summary()["prompts"] == {
        "embedded": 0,
        "caption_only_zero_text": 3,
        "none_zero_text": 0,
    }
    embedded = write_toy_clipset(tmp_path / "emb", clips=2, frames=13, width=32, height=32, prompt_dim=48)
    assert TrainData(tiny_train_config(embedded, tmp_path / "r2"), None, 48).summary()["prompts"]["embedded"] == 2
