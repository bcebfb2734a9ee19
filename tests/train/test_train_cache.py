"""Cached latents (``oscar train --cache-latents``): the right tensors, the split filter, resume, and the trainer's use."""

import json
import os

import numpy as np
import pytest
import torch

from oscar_core.cli import main
from oscar_core.model.tiny import build_tiny_vae
from oscar_core.model.vae import VideoVAE
from oscar_core.plugin.registry import Registry
from oscar_core.render.skeleton_video import render_skeleton_video
from oscar_core.train.cache import cache_latents, window_starts
from oscar_core.train.clips import ClipSet
from oscar_core.train.config import config_from_dict
from oscar_core.train.data import TrainData
from oscar_core.train.synthetic import write_toy_clipset

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    return write_toy_clipset(tmp_path_factory.mktemp("src") / "toy", clips=3, frames=13, width=32, height=32)


def vae4x():
    """The toy world's layout (4x space, 4x time) at a tiny width: latents of 32x32 frames are 8x8."""
    return VideoVAE(build_tiny_vae(0, dim_mult=[1, 2, 2], temperal_downsample=[True, True]))


def test_window_starts():
    assert window_starts(13, 9, 9).tolist() == [0]
    assert window_starts(13, 9, 2).tolist() == [0, 2, 4]
    assert window_starts(17, 17, 17).tolist() == [0]
    assert window_starts(8, 9, 1).tolist() == []
    with pytest.raises(ValueError, match="stride"):
        window_starts(13, 9, 0)


def test_cached_latents_are_the_vae_encodings_of_the_windows(tmp_path, source):
    vae = vae4x()
    s = cache_latents(source, tmp_path / "out", vae, window=9, stride=2, log=lambda m: None)
    assert (s.clips_cached, s.clips_too_short, s.shards_written, s.shards_kept) == (3, 0, 2, 0)
    src, out = ClipSet(source), ClipSet(tmp_path / "out")
    assert [r.id for r in out] == [r.id for r in src]
    emb = Registry().get("toyarm")
    for rec in src:
        clip, cached = src.load(rec), out.load(rec.id)
        np.testing.assert_array_equal(cached.rgb, clip.rgb)  # the copy keeps the clip (lossless video)
        lat = cached.latents
        assert lat["starts"].tolist() == [0, 2, 4] and lat["window"] == "9"
        assert tuple(lat["video"].shape) == (3, 16, 3, 8, 8) == tuple(lat["skeleton"].shape)
        # window 2 (start 4): video and the skeleton rendered from trajectory + camera, encoded again here
        skel = render_skeleton_video(emb, clip.trajectory, clip.camera, (32, 32))
        with torch.no_grad():
            want_v = vae.encode(vae.to_pixels(clip.rgb[4:13]))[0]
            want_s = vae.encode(vae.to_pixels(skel[4:13]))[0]
        torch.testing.assert_close(lat["video"][2], want_v)
        torch.testing.assert_close(lat["skeleton"][2], want_s)
        assert not torch.allclose(lat["video"][2], lat["video"][0])  # windows differ


def test_stored_skeleton_is_used_and_short_clips_get_no_latents(tmp_path):
    src = write_toy_clipset(tmp_path / "src", clips=2, frames=9, width=32, height=32, stored_skeleton=True)
    vae = vae4x()
    s = cache_latents(src, tmp_path / "out", vae, window=9, log=lambda m: None)
    clip = ClipSet(src).load("toy-1")
    with torch.no_grad():
        want = vae.encode(vae.to_pixels(clip.skeleton))[0]
    torch.testing.assert_close(ClipSet(tmp_path / "out").load("toy-1").latents["skeleton"][0], want)
    assert s.clips_cached == 2
    s = cache_latents(src, tmp_path / "out13", vae, window=13, log=lambda m: None)
    assert (s.clips_cached, s.clips_too_short) == (0, 2)
    assert "latents" not in ClipSet(tmp_path / "out13").record("toy-0").files


def test_split_filter_and_resume(tmp_path):
    from oscar_core.toyworld.generate import GenerateConfig, generate_clipset

    src = tmp_path / "toy"
    generate_clipset(
        GenerateConfig(
            embodiments=("toyarm",), episodes=10, width=32, height=32, frames=9, seed=0, shard_size=5, supersample=1
        ),
        src,
        Registry(),
    )
    vae = vae4x()
    s = cache_latents(src, tmp_path / "train", vae, window=9, split="train", log=lambda m: None)
    ids = [r.id for r in ClipSet(tmp_path / "train")]
    assert len(ids) == 9 and all(ClipSet(src).record(i).meta["split"] == "train" for i in ids)
    assert s.shards_written == 2
    # a re-run keeps the finished shards (nothing rewritten); a lost shard is redone
    shard = next(p for p in (tmp_path / "train").glob("shard-*"))
    before = os.stat(shard / "clips.jsonl").st_mtime_ns
    s = cache_latents(src, tmp_path / "train", vae, window=9, split="train", log=lambda m: None)
    assert (s.shards_written, s.shards_kept) == (0, 2)
    assert os.stat(shard / "clips.jsonl").st_mtime_ns == before
    import shutil

    shutil.rmtree(shard)
    s = cache_latents(src, tmp_path / "train", vae, window=9, split="train", log=lambda m: None)
    assert (s.shards_written, s.shards_kept) == (1, 1) and len(ClipSet(tmp_path / "train")) == 9
    with pytest.raises(ValueError, match="other than the source"):
        cache_latents(src, src, vae, window=9, log=lambda m: None)


def test_trainer_uses_latents_cached_at_the_vaes_compression(tmp_path, source):
    """A 4x-space VAE's 8x8 latents of 32x32 clips are recognised as cached (not only WAN's 8x)."""
    vae = vae4x()
    cache_latents(source, tmp_path / "out", vae, window=9, log=lambda m: None)
    cfg = config_from_dict(
        {
            "run_dir": str(tmp_path / "run"),
            "model": {"transformer": "tiny", "vae": "tiny"},
            "data": {"clips": [str(tmp_path / "out")], "window": 9, "width": 32, "height": 32, "latents": "cached"},
        }
    )
    data = TrainData(cfg, vae, 48)
    assert data.cached
    item = data.planner().plan(0, 1)[0]
    got = data.load_item(item, "skeleton")
    assert tuple(got["z0"].shape) == (16, 3, 8, 8)


def test_cli(tmp_path, source, capsys):
    vae_dir = tmp_path / "vae"
    vae4x().vae.save_pretrained(vae_dir, safe_serialization=True)
    rc = main(
        [
            "train",
            "--cache-latents",
            str(source),
            "--vae",
            str(vae_dir),
            "--window",
            "9",
            "--out",
            str(tmp_path / "out"),
            "--threads",
            "1",
            "--json",
        ]
    )
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["clips_cached"] == 3
    assert main(["train", "--cache-latents", str(source), "--vae", str(vae_dir), "--out", str(tmp_path / "o2")]) != 0
    assert "field '--window': expected given with --cache-latents, found missing" in capsys.readouterr().err
