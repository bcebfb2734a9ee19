"""Sets written before their stage kept a fingerprint: the first re-run checks what their shards recorded.

Each test writes a set with today's code, deletes its ``fingerprint.json``
(what a set of an older oscar looks like) and re-runs into it.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import pytest

from oscar_core._util.stage import StageChanged
from oscar_core.cli import main
from oscar_core.plugin.registry import Registry
from oscar_core.toyworld.episode import miss_rng
from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
from oscar_core.train.clips import ClipSet

BASE = GenerateConfig(("toyarm",), 4, width=32, height=32, frames=9, shard_size=2, pick_miss=0.5)


@pytest.fixture(scope="module")
def reg():
    return Registry()


@pytest.fixture
def old_set(tmp_path, reg):
    out = tmp_path / "set"
    assert generate_clipset(BASE, out, reg)["episodes_written"] == 4
    (out / "fingerprint.json").unlink()
    return out


@pytest.mark.parametrize(("change", "field", "sentence"), [
    ({"seed": 1}, "seed", "seed: 0 -> 1"),
    ({"width": 48}, "width", "width: 32 -> 48"),
    ({"frames": 13}, "frames", "frames: 9 -> 13"),
    ({"fps": 5.0}, "fps", "fps: 10.0 -> 5.0"),
    ({"skeleton": False}, "skeleton", "skeleton: true -> false"),
    ({"shard_size": 3}, "shard_size", "shard_size: shard-toyarm-000001 holding episode 2 -> 3"),
    ({"pick_miss": 0.0}, "pick_miss", "pick_miss: above 0 (miss fields recorded) -> 0.0"),
])
def test_a_changed_setting_is_refused_naming_it(old_set, reg, change, field, sentence):
    with pytest.raises(StageChanged, match="before fingerprints") as err:
        generate_clipset(replace(BASE, **change), old_set, reg)
    assert sentence in str(err.value) and "2 shard(s)" in str(err.value)
    assert not (old_set / "fingerprint.json").exists()  # nothing recorded for a refused run


def test_another_miss_fraction_is_told_by_which_episodes_missed(old_set, reg):
    """A pick-and-place episode missed exactly when its miss generator's first draw is below --pick-miss."""
    draws = []
    for rec in ClipSet(old_set):
        world = rec.meta["toyworld"]
        if world["kind"] == "pick_place":
            u = miss_rng(0, "toyarm", rec.meta["episode"]).uniform()
            assert world["missed"] == (u < 0.5)  # the rule the check relies on, on today's set
            draws.append(u)
    assert draws, "the set needs a pick-and-place episode"
    flip = min(draws, key=lambda u: abs(u - 0.5))  # a fraction on the other side of one episode's draw
    other = flip + 1e-6 if flip >= 0.5 else flip - 1e-6
    keep = [f for f in (0.5 + 1e-9, 0.5 - 1e-9) if all((u < f) == (u < 0.5) for u in draws)]
    with pytest.raises(StageChanged, match=r"pick_miss: a value in \(") as err:
        generate_clipset(replace(BASE, pick_miss=max(other, 1e-6)), old_set, reg)
    assert "pick_miss" in str(err.value)
    assert generate_clipset(replace(BASE, pick_miss=keep[0]), old_set, reg)["episodes_skipped"] == 4


def test_the_same_settings_are_taken_with_one_warning_and_recorded(old_set, reg, caplog):
    with caplog.at_level(logging.WARNING, logger="oscar"):
        again = generate_clipset(replace(BASE, episodes=6), old_set, reg)
    assert (again["episodes_written"], again["episodes_skipped"]) == (2, 4)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "2 shard(s) made before fingerprints" in warnings[0]
    assert "supersample" in warnings[0] and "pick_miss" in warnings[0]
    assert (old_set / "fingerprint.json").is_file()  # from now on the fingerprint decides
    with pytest.raises(StageChanged, match="supersample"):
        generate_clipset(replace(BASE, supersample=3), old_set, reg)


def test_the_command_exits_2_naming_the_field(old_set, capsys):
    args = ["toyworld", "generate", "--embodiments", "toyarm", "--episodes", "4", "--size", "32x32", "--frames", "9",
            "--shard-size", "2", "--out", str(old_set), "--no-progress"]
    assert main([*args, "--pick-miss", "0.5", "--seed", "3"]) == 2
    err = capsys.readouterr().err
    assert "seed: 0 -> 3" in err and "before fingerprints" in err


# ---------------------------------------------------------------------- latent cache
@pytest.fixture(scope="module")
def cache_env(tmp_path_factory, reg):
    """A toy-world source (10 episodes in 2 shards, episode 9 held out) and the tiny training VAE."""
    from test_train_loop import tiny

    from oscar_core.train.models import build_vae

    root = tmp_path_factory.mktemp("cache")
    src = root / "src"
    generate_clipset(GenerateConfig(("toyarm",), 10, width=32, height=32, frames=9, shard_size=5), src, reg)
    return src, build_vae(tiny(src, root / "r", steps=1)), root


def _cache(env, reg, out, **kw):
    from oscar_core.train.cache import cache_latents

    src, vae, _ = env
    kw = {"window": 5, "stride": 4, **kw}
    return cache_latents(kw.pop("src", src), out, kw.pop("vae", vae), registry=reg, log=lambda m: None, **kw)


@pytest.fixture
def old_cache(cache_env, reg, tmp_path):
    out = tmp_path / "cache"
    assert _cache(cache_env, reg, out).shards_written == 2
    (out / "fingerprint.json").unlink()
    return out


@pytest.mark.parametrize(("change", "sentence"), [
    ({"window": 9}, "window: 5 -> 9"),
    ({"stride": 2}, "stride: 4 -> 2"),
    ({"condition": "capsules"}, "condition: skeleton -> capsules"),
    ({"split": "train"}, "split: null -> train"),
    ({"vae_name": "my-vae"}, "vae: config-sha256:"),
])
def test_a_cache_with_a_changed_setting_is_refused_naming_it(cache_env, reg, old_cache, change, sentence):
    with pytest.raises(StageChanged, match="before fingerprints") as err:
        _cache(cache_env, reg, old_cache, **change)
    assert sentence in str(err.value) and "2 shard(s)" in str(err.value)
    assert not (old_cache / "fingerprint.json").exists()


def test_other_vae_weights_or_source_frames_are_found_by_encoding_one_window(cache_env, reg, old_cache):
    import copy

    import torch

    _, vae, root = cache_env
    other = copy.deepcopy(vae)
    with torch.no_grad():
        next(other.vae.parameters()).add_(1.0)  # same config (same default name), other weights
    with pytest.raises(StageChanged, match="vae_weights: other weights or source frames"):
        _cache(cache_env, reg, old_cache, vae=other)
    regen = root / "src-seed1"  # the same clip ids and shards, other frames
    if not regen.exists():
        generate_clipset(GenerateConfig(("toyarm",), 10, width=32, height=32, frames=9, shard_size=5, seed=1),
                         regen, reg)
    with pytest.raises(StageChanged, match="vae_weights: other weights or source frames"):
        _cache(cache_env, reg, old_cache, src=regen)


def test_a_cache_made_with_the_same_settings_is_kept_and_fingerprinted(cache_env, reg, old_cache, caplog):
    with caplog.at_level(logging.INFO, logger="oscar"):
        again = _cache(cache_env, reg, old_cache)
    assert (again.shards_written, again.shards_kept) == (0, 2)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert any("2 shard(s) made before fingerprints existed agree with this run" in r.getMessage()
               for r in caplog.records)
    assert (old_cache / "fingerprint.json").is_file()


def test_train_cache_latents_exits_2_on_an_old_cache_of_other_settings(cache_env, tmp_path, capsys):
    from pathlib import Path

    import oscar_zoo

    src = cache_env[0]
    vae = str(oscar_zoo.pull("oscar-toy", local_files_only=True))
    args = ["train", "--cache-latents", str(src), "--vae", vae, "--window", "5", "--out", str(tmp_path / "lat"),
            "--no-progress"]
    assert main(args) == 0
    (Path(tmp_path / "lat") / "fingerprint.json").unlink()
    capsys.readouterr()
    assert main([*args, "--stride", "2"]) == 2
    err = capsys.readouterr().err
    assert "made before fingerprints existed" in err and "stride: more than 4 -> 2" in err
    assert main(args) == 0 and (tmp_path / "lat" / "fingerprint.json").is_file()
