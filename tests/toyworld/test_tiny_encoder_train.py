"""``oscar toyworld train-tiny-encoder``: distils the toy VAE's full encoder on the clips' skeleton videos, seeded
(the same command writes the same bytes), learns (held-out relative RMS against the full encoder's latents below
the same seed's untrained net's, recomputed here), writes a file that loads at the toy shape from its metadata alone,
and refuses bad input with exit 2."""

import json

import numpy as np
import pytest
import torch

from oscar_core.model.tiny_encoder import TinyEncoderNet, TinyVideoEncoder, load_tiny_encoder
from oscar_core.model.vae import VideoVAE, load_vae_folder
from oscar_core.plugin.registry import Registry
from oscar_core.toyworld.tiny_encoder_train import (
    TOY_TINY_ENCODER,
    TinyEncoderTrainConfig,
    condition_windows,
    relative_rms,
    train_tiny_encoder,
)

TOY_VAE = __import__("_paths").REPO / "zoo" / "assets" / "oscar-toy" / "vae"


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """Ten toyarm episodes of 9 frames at 32x32, each with its skeleton video."""
    from oscar_core.toyworld.generate import GenerateConfig, generate_clipset

    root = tmp_path_factory.mktemp("tiny_enc") / "clips"
    generate_clipset(GenerateConfig(("toyarm",), 10, width=32, height=32, frames=9, seed=1), root, Registry())
    return root


CFG = dict(steps=10, batch=2, window=5, train_windows=6, eval_windows=3, heldout_every=3, heldout_residue=0)


def test_relative_rms_by_hand():
    assert relative_rms(np.array([3.0, 4.0]), np.array([3.0, 4.0])) == 0.0
    assert relative_rms(np.zeros(2), np.array([3.0, 4.0])) == 1.0
    assert relative_rms(np.array([3.0, 0.0]), np.array([3.0, 4.0])) == pytest.approx(4 / 5)


def test_training_is_seeded_learns_and_writes_a_file_that_loads_at_its_shape(clips, tmp_path, one_thread):
    cfg = TinyEncoderTrainConfig(**CFG, eval_every=0)
    card = train_tiny_encoder([clips], TOY_VAE, tmp_path / "a", cfg, log=lambda m: None)
    train_tiny_encoder([clips], TOY_VAE, tmp_path / "b", cfg, log=lambda m: None)
    a, b = (tmp_path / d / "tiny_encoder.safetensors" for d in "ab")
    assert a.read_bytes() == b.read_bytes()  # seeded: the same command, the same bytes
    net = load_tiny_encoder(a)  # no shape given: the file's metadata says it
    assert (net.width, net.space_factor, net.time_factor) == (TOY_TINY_ENCODER["width"], 4, 4)
    saved = json.loads((tmp_path / "a" / "tiny_encoder_card.json").read_text())
    assert saved["heldout_relative_rms"] == card["heldout_relative_rms"] and saved["heldout_windows"] == 3
    # the held-out error against the full encoder, recomputed here, and the same seed's untrained net's
    vae = VideoVAE(load_vae_folder(TOY_VAE))
    _, held = condition_windows([clips], 5, 3, 0, np.random.default_rng(0))
    frames = np.stack([w for _, w in held][:3])
    target = vae.encode(vae.to_pixels(frames)).numpy()

    def error_of(n: TinyEncoderNet) -> float:
        return relative_rms(TinyVideoEncoder(n, vae.mean, vae.std).encode(vae.to_pixels(frames)).numpy(), target)

    assert error_of(net) == pytest.approx(card["heldout_relative_rms"], rel=1e-5)
    torch.manual_seed(0)
    untrained = TinyEncoderNet(**TOY_TINY_ENCODER).eval()
    assert error_of(net) < 0.8 * error_of(untrained)
    vae.use_tiny_encoder(a)  # fits the toy VAE's scale (/4 in space and time)
    assert vae.encode_condition(vae.to_pixels(frames[:1])).shape == (1, 16, 2, 8, 8)


def test_bad_input_exits_2_naming_it(clips, tmp_path, capsys):
    from oscar_core.cli import main

    base = ["toyworld", "train-tiny-encoder", str(clips), "--vae", str(TOY_VAE), "--out", str(tmp_path / "o")]
    assert main([*base, "--window", "6"]) == 2
    assert "--window: expected a frame count of the form 4k+1" in capsys.readouterr().err
    code = main(["toyworld", "train-tiny-encoder", str(tmp_path), "--vae", str(TOY_VAE), "--out", str(tmp_path / "o")])
    assert code == 2 and "not a clip set" in capsys.readouterr().err
    assert main([*base, "--window", "13"]) == 2
    assert "expected at least 13 frames, found 9" in capsys.readouterr().err
    assert not (tmp_path / "o" / "tiny_encoder.safetensors").exists()
