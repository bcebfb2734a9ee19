"""``oscar toyworld train-tiny-decoder``: distils the toy VAE's full decoder from cached latents, seeded (the same
command writes the same bytes), learns (held-out PSNR against the full decode above the same seed's untrained
net's), writes a file that loads at the toy shape from its metadata alone, and refuses bad input with exit 2."""

import json

import numpy as np
import pytest
import torch

from oscar_core.model.tiny_decoder import TinyDecoderNet, TinyVideoDecoder, load_tiny_decoder
from oscar_core.model.vae import VideoVAE, load_vae_folder
from oscar_core.plugin.registry import Registry
from oscar_core.toyworld.tiny_decoder_train import (
    TOY_TINY_DECODER,
    TinyDecoderTrainConfig,
    full_decode,
    latent_windows,
    train_tiny_decoder,
)

TOY_VAE = __import__("_paths").REPO / "zoo" / "assets" / "oscar-toy" / "vae"


@pytest.fixture(scope="module")
def latents(tmp_path_factory):
    """Nine train-split toyarm episodes of 9 frames at 32x32, cached by oscar-toy's VAE in 5-frame windows."""
    from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
    from oscar_core.train.cache import cache_latents

    root = tmp_path_factory.mktemp("tiny_dec")
    generate_clipset(GenerateConfig(("toyarm",), 10, width=32, height=32, frames=9, seed=1), root / "clips", Registry())
    vae = VideoVAE(load_vae_folder(TOY_VAE))
    cache_latents(root / "clips", root / "latents", vae, 5, split="train", log=lambda m: None)
    return root / "latents"


CFG = dict(steps=12, batch=2, train_windows=6, eval_windows=3, heldout_every=3, heldout_residue=0, eval_every=0)


def test_training_is_seeded_learns_and_writes_a_file_that_loads_at_its_shape(latents, tmp_path, one_thread):
    cfg = TinyDecoderTrainConfig(**CFG)
    card = train_tiny_decoder([latents], TOY_VAE, tmp_path / "a", cfg, log=lambda m: None)
    train_tiny_decoder([latents], TOY_VAE, tmp_path / "b", cfg, log=lambda m: None)
    a, b = (tmp_path / d / "tiny_decoder.safetensors" for d in "ab")
    assert a.read_bytes() == b.read_bytes()  # seeded: the same command, the same bytes
    net = load_tiny_decoder(a)  # no shape given: the file's metadata says it
    assert (net.widths, net.space_factor, net.time_factor) == (TOY_TINY_DECODER["widths"], 4, 4)
    saved = json.loads((tmp_path / "a" / "tiny_decoder_card.json").read_text())
    assert saved["heldout_psnr_db"] == card["heldout_psnr_db"] and saved["heldout_windows"] == 3
    assert all(c.split("-")[1].lstrip("0") in ("", "3", "6") for c in saved["heldout_clips"])  # episodes 0, 3, 6
    # the held-out PSNR against the full decode, recomputed here, and the same seed's untrained net's
    vae = VideoVAE(load_vae_folder(TOY_VAE))
    _, held = latent_windows([latents], 3, 0)
    z = np.stack([w[0] for _, w in held][:3])
    target = full_decode(vae, z).astype(np.float64)

    def psnr_of(n: TinyDecoderNet) -> float:
        out = TinyVideoDecoder(n, vae.mean, vae.std).decode(torch.from_numpy(z))
        pred = ((out.clamp(-1, 1) + 1) * 127.5).round().numpy()
        return float(10 * np.log10(255.0**2 / np.mean((pred - target) ** 2)))

    torch.manual_seed(0)
    untrained = TinyDecoderNet(**TOY_TINY_DECODER).eval()
    assert psnr_of(net) > psnr_of(untrained) + 3.0
    vae.use_tiny_decoder(a)  # fits the toy VAE's scale (x4 in space and time)
    assert vae.decode(torch.from_numpy(z[:1])).shape == (1, 3, 5, 32, 32)


def test_bad_input_exits_2_naming_it(latents, tmp_path, capsys):
    from oscar_core.cli import main

    code = main(
        ["toyworld", "train-tiny-decoder", str(latents), "--vae", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]
    )
    assert code == 2 and "--vae" in capsys.readouterr().err and not (tmp_path / "o").exists()
    code = main(["toyworld", "train-tiny-decoder", str(tmp_path), "--vae", str(TOY_VAE), "--out", str(tmp_path / "o")])
    assert code == 2 and "not a clip set" in capsys.readouterr().err
    code = main(
        [
            "toyworld",
            "train-tiny-decoder",
            str(latents),
            "--vae",
            str(TOY_VAE),
            "--heldout-every",
            "50",
            "--heldout-residue",
            "49",
            "--out",
            str(tmp_path / "o"),
        ]
    )
    assert code == 2 and "expected clips in both splits" in capsys.readouterr().err
