"""Source mixing as drawn: per-source weights (temperature rule or explicit), the fraction of each source drawn,
logged per run, within a binomial tolerance of the weights; stage 2 on toy robot + hand clip sets warm-starts from
stage 1 and logs its draws."""

import json
import math

import numpy as np
import pytest
import torch

from oscar_core.train.config import TrainConfigError, config_from_dict
from oscar_core.train.sampling import StepPlanner, mixing_weights

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py

#: z of the binomial tolerance: |drawn - N p| <= Z sqrt(N p (1 - p)); two-sided 4 sigma (p ~ 6e-5 per source)
Z = 4.0


def assert_binomial(drawn: dict[str, int], weights: dict[str, float]):
    n = sum(drawn.values())
    for s, p in weights.items():
        tol = Z * math.sqrt(n * p * (1 - p))
        assert abs(drawn[s] - n * p) <= tol, (s, drawn[s], n * p, tol)


CLIPS = (
    [("a", 50, np.ones((50, 1)), None)] * 3
    + [("b", 400, np.ones((400, 1)), None)]
    + [("c", 20, np.ones((20, 1)), None)] * 2
)


def test_temperature_weights_are_drawn_in_their_proportions():
    planner = StepPlanner(CLIPS, 9, seed=1, temperature=3.0)
    # w ∝ n_frames^(1/3): a 150, b 400, c 40 frames
    raw = {"a": 150 ** (1 / 3), "b": 400 ** (1 / 3), "c": 40 ** (1 / 3)}
    want = {k: v / sum(raw.values()) for k, v in raw.items()}
    assert planner.weights == pytest.approx(want, abs=1e-12)
    assert_binomial(planner.drawn(300, 8), want)


def test_explicit_weights_replace_the_temperature_rule():
    planner = StepPlanner(CLIPS, 9, seed=2, weights={"a": 7.0, "b": 2.0, "c": 1.0})
    assert planner.weights == pytest.approx({"a": 0.7, "b": 0.2, "c": 0.1})
    drawn = planner.drawn(300, 8)
    assert sum(drawn.values()) == 2400
    assert_binomial(drawn, planner.weights)
    # the tolerance is tight enough to tell these weights from the temperature rule's
    with pytest.raises(AssertionError):
        assert_binomial(drawn, mixing_weights({"a": 150, "b": 400, "c": 40}))


def test_explicit_weights_must_name_every_source_and_be_positive():
    with pytest.raises(ValueError, match=r"missing \['c'\], unknown \['z'\]"):
        mixing_weights({"a": 1, "c": 1}, explicit={"a": 1.0, "z": 1.0})
    base = {"data": {"clips": ["x"]}, "model": {"transformer": "tiny", "vae": "tiny"}}
    with pytest.raises(TrainConfigError, match=r"data.source_weights.hand': expected a positive weight, found 0"):
        config_from_dict({**base, "data": {"clips": ["x"], "source_weights": {"robot": 1, "hand": 0}}})
    with pytest.raises(TrainConfigError, match=r"data.source_weights': expected a mapping, found list"):
        config_from_dict({**base, "data": {"clips": ["x"], "source_weights": [1, 2]}})


# ---------------------------------------------------------------------- stages on toy clip sets
@pytest.fixture(scope="module")
def toy_hand_robot(tmp_path_factory):
    from oscar_core.plugin.registry import Registry
    from oscar_core.toyworld.generate import GenerateConfig, generate_clipset

    out = tmp_path_factory.mktemp("mix") / "toy"
    cfg = GenerateConfig(("toyarm", "mano"), episodes=3, width=32, height=32, frames=9, shard_size=3, seed=5)
    generate_clipset(cfg, out, Registry())
    return out


def _config(clips, run_dir, **over):
    d = {
        "run_dir": str(run_dir),
        "steps": 2,
        "batch_size": 2,
        "save_every": 100,
        "log_every": 5,
        "export": False,
        "model": {"transformer": "tiny", "vae": "tiny"},
        "data": {"clips": [str(clips)], "window": 9, "width": 32, "height": 32, "check_files": False},
        "optim": {"lr": 1e-3, "warmup_steps": 0, "grad_clip": 1.0, "ema_decay": 0.9},
    }
    for k, v in over.items():
        section, _, key = k.rpartition(".")
        (d[section] if section else d)[key] = v
    return config_from_dict(d)


def test_stage_two_on_toy_robot_and_hand_clips_warm_starts_and_logs_its_draws(tmp_path, toy_hand_robot):
    from oscar_core.train.checkpoint import latest_checkpoint, load_weights
    from oscar_core.train.loop import train
    from oscar_core.train.models import build_transformer

    stage1 = _config(toy_hand_robot, tmp_path / "s1", **{"data.sources": ["toyworld"]})
    train(stage1, progress=False)
    s1 = json.loads((tmp_path / "s1" / "sources.json").read_text())
    one = {"configured_weight": None, "normalised_weight": 1.0, "drawn": 4, "drawn_fraction": 1.0}
    assert s1["sources"] == {"toyworld": one}  # the temperature rule: nothing configured

    weights = {"toyworld": 1.0, "toyworld_hand": 3.0}
    # lr ~ 0: the stage-2 weights stay the parent's, so the warm start is visible in them
    stage2 = _config(
        toy_hand_robot,
        tmp_path / "s2",
        steps=10,
        batch_size=4,
        parent_run=str(tmp_path / "s1"),
        **{"data.source_weights": weights, "optim.lr": 1e-30},
    )
    train(stage2, progress=False)
    doc = json.loads((tmp_path / "s2" / "sources.json").read_text())
    assert doc["draws"] == 40 and doc["mixing"] == "source_weights" and doc["parent_run"] == str(tmp_path / "s1")
    drawn = {s: v["drawn"] for s, v in doc["sources"].items()}
    assert_binomial(drawn, {"toyworld": 0.25, "toyworld_hand": 0.75})
    for name, v in doc["sources"].items():
        assert v["drawn_fraction"] == v["drawn"] / 40
        assert v["configured_weight"] == weights[name]  # as written in the config (1 : 3) ...
        assert v["normalised_weight"] == weights[name] / 4.0  # ... and as drawn (0.25 : 0.75)
    lines = [json.loads(x) for x in (tmp_path / "s2" / "metrics.jsonl").read_text().splitlines()]
    assert lines[-1]["sources_drawn"] == drawn and lines[0]["mixing_weights"] == {
        "toyworld": 0.25,
        "toyworld_hand": 0.75,
    }

    def state(run, cfg):
        return load_weights(latest_checkpoint(run), build_transformer(cfg), key="model").state_dict()

    a, b = state(tmp_path / "s1", stage1), state(tmp_path / "s2", stage2)
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_source_weights_naming_a_source_the_clips_lack_are_refused_before_training(tmp_path, toy_hand_robot):
    from oscar_core.train.loop import train

    cfg = _config(toy_hand_robot, tmp_path / "r", **{"data.source_weights": {"toyworld": 1.0, "egodex": 1.0}})
    with pytest.raises(
        TrainConfigError, match=r"data.source_weights.*missing \['toyworld_hand'\], unknown \['egodex'\]"
    ):
        train(cfg, progress=False)
    assert not (tmp_path / "r" / "metrics.jsonl").exists()
