"""The tiny condition encoder as an option: VideoVAE.encode_condition takes it only when asked (the seed frame's
encode never), a rollout encodes every chunk's condition with it, ``from_pretrained(tiny_encoder=FILE)`` and
``oscar rollout --tiny-encoder FILE`` choose it (the summary and a closed-loop run's fingerprint record it), and bad
choices are refused before any weights load, naming the file and the field. Weights here are random, written by the
test."""

import argparse
import hashlib
import json
import sys

import cv2
import numpy as np
import pytest
import torch
from _models import tiny_world_model
from _paths import TOYARM_ASSETS

import oscar_zoo
from oscar_core.errors import OscarError
from oscar_core.model import ModelInputError, OscarWorldModel, VideoVAE
from oscar_core.model.cli import add_model_parsers
from oscar_core.model.encoder_options import encoder_identity
from oscar_core.model.errors import CheckpointLayoutError
from oscar_core.model.sampler import SamplerConfig
from oscar_core.model.tiny import build_tiny_vae
from oscar_core.model.tiny_encoder import TinyEncoderNet, TinyVideoEncoder, save_tiny_encoder

TRAJ, CAM = TOYARM_ASSETS / "example_trajectory.npz", TOYARM_ASSETS / "example_camera.json"


def _small_net(seed: int = 0, **shape) -> TinyEncoderNet:
    torch.manual_seed(seed)
    return TinyEncoderNet(width=8, **shape).eval()  # /8 in space, /4 in time: the tiny test VAE's latents


@pytest.fixture(autouse=True)
def isolated(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hf-cache"))
    monkeypatch.setenv("OSCAR_ZOO_REGISTRY", str(tmp_path / "zoo.json"))


def test_video_vae_encodes_conditions_with_the_tiny_encoder_only_when_asked_and_the_seed_never():
    vae = VideoVAE(build_tiny_vae(seed=0))
    pixels = torch.rand(1, 3, 5, 32, 64) * 2 - 1
    full = vae.encode(pixels)
    assert torch.equal(vae.encode_condition(pixels), full)  # off by default
    net = _small_net()
    vae.use_tiny_encoder(net)
    tiny = vae.encode_condition(pixels)
    assert tiny.shape == full.shape == (1, 16, 2, 4, 8) and not torch.equal(tiny, full)
    torch.testing.assert_close(tiny, TinyVideoEncoder(net, vae.mean, vae.std).encode(pixels), rtol=0, atol=0)
    assert torch.equal(vae.encode(pixels), full)  # the seed frame's (and every other) encode is unchanged
    with pytest.raises(ModelInputError, match=r"video: expected a frame count of the form 4k\+1.*found 6"):
        vae.encode_condition(torch.zeros(1, 3, 6, 32, 64))
    vae.use_tiny_encoder(None)
    assert torch.equal(vae.encode_condition(pixels), full)
    with pytest.raises(ModelInputError, match=r"tiny encoder: expected /4 in time and /8 in space .* found /4 and /4"):
        vae.use_tiny_encoder(_small_net(space_downscale=(True, True, False)))
    with pytest.raises(ModelInputError, match=r"tiny encoder: expected 16 latent channels .* found 4"):
        vae.use_tiny_encoder(TinyEncoderNet(latent_channels=4, width=8))


def test_a_rollout_encodes_every_chunk_s_condition_with_it_and_its_seed_frames_with_the_full_encoder():
    model = tiny_world_model(seed=0, chunk_frames=5, skeleton_scale=0.5)  # a DiT that reads its condition
    rng = np.random.default_rng(0)
    first = rng.integers(0, 256, (32, 64, 3), dtype=np.uint8)
    skeleton = rng.integers(0, 256, (9, 32, 64, 3), dtype=np.uint8)
    full = model.rollout(first, skeleton, sampler=SamplerConfig(steps=1), progress=False).frames
    model.vae.use_tiny_encoder(_small_net())
    seen = []
    tiny_encode = model.vae.tiny_encoder.encode
    model.vae.tiny_encoder.encode = lambda x: seen.append(x.shape[2]) or tiny_encode(x)
    tiny = model.rollout(first, skeleton, sampler=SamplerConfig(steps=1), progress=False).frames
    assert seen == [5, 5]  # two chunks of 5 frames: the conditions; the 1-frame seeds went to the full encoder
    assert tiny.shape == full.shape and not np.array_equal(tiny, full)


def test_from_pretrained_takes_a_tiny_encoder_file_and_defaults_to_the_full_encoder(tmp_path):
    tiny_world_model(seed=0, chunk_frames=5).save_pretrained(tmp_path / "model")
    net = _small_net(1)
    save_tiny_encoder(net, tmp_path / "enc.safetensors")
    assert OscarWorldModel.from_pretrained(tmp_path / "model").vae.tiny_encoder is None
    assert OscarWorldModel.from_pretrained(tmp_path / "model", tiny_encoder=False).vae.tiny_encoder is None
    fast = OscarWorldModel.from_pretrained(tmp_path / "model", tiny_encoder=tmp_path / "enc.safetensors")
    pixels = torch.rand(1, 3, 5, 32, 64) * 2 - 1
    expected = TinyVideoEncoder(net, fast.vae.mean, fast.vae.std).encode(pixels)
    torch.testing.assert_close(fast.vae.encode_condition(pixels), expected, rtol=0, atol=0)
    (tmp_path / "taew2_1.pth").write_bytes(b"x")
    with pytest.raises(CheckpointLayoutError, match=r"taew2_1\.pth: tiny encoder: expected a \.safetensors file"):
        OscarWorldModel.from_pretrained(tmp_path / "model", tiny_encoder=tmp_path / "taew2_1.pth")
    loaded = oscar_zoo.load(tmp_path / "model", tiny_encoder=tmp_path / "enc.safetensors")
    torch.testing.assert_close(loaded.vae.encode_condition(pixels), expected, rtol=0, atol=0)


# ------------------------------------------------------------------------------------------------ the flag


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    model = tiny_world_model(skeleton_scale=0.05, name="tiny", chunk_frames=41, fps=15.0)
    return oscar_zoo.export(model, tmp_path_factory.mktemp("m") / "tiny")


@pytest.fixture(scope="module")
def first_frame(tmp_path_factory):
    path = tmp_path_factory.mktemp("img") / "first.png"
    cv2.imwrite(str(path), np.random.default_rng(0).integers(0, 256, (360, 640, 3), dtype=np.uint8))
    return path


def run(capsys, *argv):
    """What ``oscar`` does with ``oscar rollout``: exit code, stdout, stderr."""
    parser = argparse.ArgumentParser(prog="oscar")
    add_model_parsers(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args([str(a) for a in argv])
    try:
        code = args.func(args)
    except (OscarError, ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        code = 2
    out, err = capsys.readouterr()
    return code, out, err


def _rollout(model, first_frame, out, *extra):
    return (
        "rollout",
        "--model",
        model,
        "--embodiment",
        "toyarm",
        "--first-frame",
        first_frame,
        "--trajectory",
        TRAJ,
        "--camera",
        CAM,
        "--out",
        out,
        "--size",
        "64x32",
        "--steps",
        "1",
        "--no-progress",
        "--no-side-by-side",
        "--json",
        *extra,
    )


def test_rollout_records_the_condition_encoder_and_a_bad_flag_exits_2_before_anything_loads(
    capsys, tmp_path, model_dir, first_frame
):
    save_tiny_encoder(_small_net(), tmp_path / "enc.safetensors")
    code, out, err = run(
        capsys,
        *_rollout(model_dir, first_frame, tmp_path / "tiny.mkv", "--tiny-encoder", tmp_path / "enc.safetensors"),
    )
    assert code == 0, err
    assert json.loads(out)["condition_encoder"] == "tiny" and json.loads(out)["decoder"] == "full"
    bad = tmp_path / "bad.mkv"
    code, _, err = run(capsys, *_rollout(model_dir, first_frame, bad, "--tiny-encoder", tmp_path / "no.safetensors"))
    assert code == 2 and "--tiny-encoder: expected a tiny-encoder file, found no file" in err and not bad.exists()
    (tmp_path / "w.pth").write_bytes(b"x")
    code, _, err = run(capsys, *_rollout(model_dir, first_frame, bad, "--tiny-encoder", tmp_path / "w.pth"))
    assert code == 2 and "--tiny-encoder: expected a .safetensors file" in err
    save_tiny_encoder(_small_net(space_downscale=(True, True, False)), tmp_path / "toy.safetensors")
    code, _, err = run(capsys, *_rollout(model_dir, first_frame, bad, "--tiny-encoder", tmp_path / "toy.safetensors"))
    assert code == 2 and "expected /4 in time and /8 in space (the VAE's), found /4 and /4" in err


def test_a_closed_loop_run_s_fingerprint_records_a_tiny_condition_encoder_only(tmp_path):
    from oscar_core.evaluation.closed_loop import _encoder_identity

    path = tmp_path / "enc.safetensors"
    save_tiny_encoder(_small_net(), path)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    assert encoder_identity(None) == "full" and encoder_identity(path) == f"tiny-sha256:{digest}"
    assert _encoder_identity(None, None) == {}  # the full encoder: the fingerprint of every earlier run
    assert _encoder_identity(None, path) == {"condition_encoder": f"tiny-sha256:{digest}"}
    assert _encoder_identity(object(), path) == {}  # a simulator has no encoder


def test_the_bundled_toy_tiny_encoder_fits_oscar_toy_and_is_off_by_default():
    from oscar_core.model.tiny_encoder import load_tiny_encoder
    from oscar_core.model.vae import load_vae_folder

    folder = oscar_zoo.pull("oscar-toy")  # bundled: every file's sha256 pinned in the table, the tiny encoder's too
    assert OscarWorldModel.from_pretrained(folder).vae.tiny_encoder is None  # nothing chooses it by default
    net = load_tiny_encoder(folder / "tiny_encoder.safetensors")  # its shape from the file's metadata
    assert net.width == 16 and (net.space_factor, net.time_factor) == (4, 4)
    vae = VideoVAE(load_vae_folder(folder / "vae"))
    skeleton = np.zeros((1, 3, 17, 64, 64), np.float32) - 1.0  # a black condition video
    skeleton[..., 20:44, 30:34] = 1.0  # one white limb
    full = vae.encode_condition(torch.from_numpy(skeleton))
    vae.use_tiny_encoder(net)
    tiny = vae.encode_condition(torch.from_numpy(skeleton))
    assert tiny.shape == full.shape == (1, 16, 5, 16, 16)
    assert float((tiny - full).pow(2).sum().sqrt() / full.pow(2).sum().sqrt()) < 0.2  # trained: near the full one
