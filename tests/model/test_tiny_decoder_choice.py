"""Who chooses the tiny decoder: the model card's ``tiny_decoder`` (a file in the model folder), or the flags
``--tiny-decoder FILE`` / ``--full-decoder`` of the commands that roll out; bad values are refused before any
weights load, naming the file and the field. Weights here are random, written by the test."""

import argparse
import json
import sys

import cv2
import numpy as np
import pytest
import torch
from _models import tiny_world_model
from _paths import TOYARM_ASSETS
from safetensors.torch import save, save_file

import oscar_zoo
from oscar_core.errors import OscarError
from oscar_core.media.video import read_video
from oscar_core.model import ModelCard, ModelInputError, OscarWorldModel
from oscar_core.model.card import read_card
from oscar_core.model.cli import add_model_parsers
from oscar_core.model.decoder_options import decoder_identity
from oscar_core.model.errors import CheckpointLayoutError
from oscar_core.model.tiny_decoder import (
    ARCHITECTURE_KEY,
    TinyDecoderNet,
    TinyVideoDecoder,
    architecture_metadata,
    load_tiny_decoder,
)

TRAJ, CAM = TOYARM_ASSETS / "example_trajectory.npz", TOYARM_ASSETS / "example_camera.json"


def _write_net(path, net: TinyDecoderNet) -> TinyDecoderNet:
    """``net``'s tensors and its shape (metadata) in a safetensors file, as oscar's training writes it."""
    tensors = {k: v.contiguous() for k, v in net.state_dict().items()}
    path.write_bytes(save(tensors, metadata=architecture_metadata(net)))
    return net


def _small_net(seed: int = 0) -> TinyDecoderNet:
    torch.manual_seed(seed)
    return TinyDecoderNet(widths=(16, 8, 8, 8)).eval()  # x8 in space, x4 in time: the tiny test VAE's latents


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    model = tiny_world_model(skeleton_scale=0.05, name="tiny", chunk_frames=41, fps=15.0)
    return oscar_zoo.export(model, tmp_path_factory.mktemp("m") / "tiny")


@pytest.fixture(scope="module")
def first_frame(tmp_path_factory):
    path = tmp_path_factory.mktemp("img") / "first.png"
    cv2.imwrite(str(path), np.random.default_rng(0).integers(0, 256, (360, 640, 3), dtype=np.uint8))
    return path


@pytest.fixture(autouse=True)
def isolated(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hf-cache"))
    monkeypatch.setenv("OSCAR_ZOO_REGISTRY", str(tmp_path / "zoo.json"))


# ------------------------------------------------------------------------------------------------ the card


@pytest.mark.parametrize(
    "value", ["/abs/tiny.safetensors", "../tiny.safetensors", "tiny.pth", "", 3, ["tiny.safetensors"]]
)
def test_the_card_field_must_be_a_safetensors_file_inside_the_folder(value):
    with pytest.raises(ModelInputError, match=r"model card tiny_decoder: expected a \.safetensors file inside"):
        ModelCard(chunk_frames=5, tiny_decoder=value)


def test_a_card_without_a_tiny_decoder_is_written_as_before():
    assert "tiny_decoder" not in ModelCard(chunk_frames=5).to_dict()
    assert ModelCard(chunk_frames=5, tiny_decoder="dec/tiny.safetensors").to_dict()["tiny_decoder"] == (
        "dec/tiny.safetensors"
    )


def test_a_card_naming_a_missing_file_is_refused_before_weights_load(model_dir, tmp_path):
    import shutil

    folder = tmp_path / "model"
    shutil.copytree(model_dir, folder)
    data = json.loads((folder / "oscar_model.json").read_text())
    data["card"]["tiny_decoder"] = "tiny_decoder.safetensors"
    (folder / "oscar_model.json").write_text(json.dumps(data))
    with pytest.raises(CheckpointLayoutError) as err:
        read_card(folder)
    msg = str(err.value)
    assert "oscar_model.json" in msg and "card.tiny_decoder" in msg and "no file tiny_decoder.safetensors" in msg
    with pytest.raises(CheckpointLayoutError, match="card.tiny_decoder"):
        OscarWorldModel.from_pretrained(folder, verify=False)


def test_the_card_chooses_the_tiny_decoder_and_false_turns_it_off(tmp_path):
    model = tiny_world_model(seed=0, chunk_frames=5)
    net = _small_net()
    with pytest.raises(ModelInputError, match="names tiny.safetensors, but this model decodes with the full decoder"):
        model.save_pretrained(tmp_path / "nothing", ModelCard(chunk_frames=5, tiny_decoder="tiny.safetensors"))
    model.vae.use_tiny_decoder(net)
    folder = model.save_pretrained(tmp_path / "model", ModelCard(chunk_frames=5, tiny_decoder="tiny.safetensors"))
    manifest = json.loads((folder / "oscar_manifest.json").read_text())["files"]
    assert "tiny.safetensors" in manifest  # checked on every load like the other weights
    loaded = OscarWorldModel.from_pretrained(folder)
    assert loaded.vae.tiny is not None and loaded.card.tiny_decoder == "tiny.safetensors"
    z = torch.randn(1, 16, 2, 4, 8)
    expected = TinyVideoDecoder(net, loaded.vae.mean, loaded.vae.std).decode(z)
    torch.testing.assert_close(loaded.vae.decode(z), expected, rtol=0, atol=0)
    full = OscarWorldModel.from_pretrained(folder, tiny_decoder=False)
    assert full.vae.tiny is None
    plain = tiny_world_model(seed=0, chunk_frames=5)
    torch.testing.assert_close(full.vae.decode(z), plain.vae.decode(z), rtol=0, atol=0)
    assert not torch.allclose(full.vae.decode(z), expected)


# ------------------------------------------------------------------------------------------------ the file


def test_a_file_records_its_shape_and_a_bad_record_is_named(tmp_path):
    torch.manual_seed(1)
    toy = TinyDecoderNet(space_upscale=(True, True, False), widths=(8, 8, 4, 4))
    _write_net(tmp_path / "toy.safetensors", toy)
    net = load_tiny_decoder(tmp_path / "toy.safetensors")  # no net given: the metadata's shape, not taew2_1's
    assert net.widths == (8, 8, 4, 4) and net.space_factor == 4 and net.time_factor == 4
    z = torch.randn(1, 3, 16, 4, 4)
    torch.testing.assert_close(net(z), toy.eval()(z), rtol=0, atol=0)
    tensors = {k: v.contiguous() for k, v in toy.state_dict().items()}
    for bad in (
        '{"widths": [8, 8, 4]}',
        "not json",
        json.dumps({**json.loads(architecture_metadata(toy)[ARCHITECTURE_KEY]), "widths": [8, 8, 4, 0]}),
    ):
        save_file(tensors, str(tmp_path / "bad.safetensors"), metadata={ARCHITECTURE_KEY: bad})
        with pytest.raises(CheckpointLayoutError, match=rf"bad\.safetensors: metadata {ARCHITECTURE_KEY}: expected"):
            load_tiny_decoder(tmp_path / "bad.safetensors")


# ------------------------------------------------------------------------------------------------ the flags


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


def test_rollout_decodes_with_the_flag_s_tiny_decoder_and_full_decoder_overrides_the_card(
    capsys, tmp_path, model_dir, first_frame
):
    _write_net(tmp_path / "tiny.safetensors", _small_net())
    code, out, err = run(capsys, *_rollout(model_dir, first_frame, tmp_path / "full.mkv"))
    assert code == 0, err
    assert json.loads(out)["decoder"] == "full" and json.loads(out)["condition_encoder"] == "full"
    code, out, err = run(
        capsys,
        *_rollout(model_dir, first_frame, tmp_path / "tiny.mkv", "--tiny-decoder", tmp_path / "tiny.safetensors"),
    )
    assert code == 0, err
    assert json.loads(out)["decoder"] == "tiny"
    full, tiny = read_video(tmp_path / "full.mkv"), read_video(tmp_path / "tiny.mkv")
    assert full.shape == tiny.shape and not np.array_equal(full, tiny)
    # a copy of the model whose card names the same file: the card chooses it; --full-decoder turns it off
    import shutil

    carded = tmp_path / "carded"
    model = OscarWorldModel.from_pretrained(model_dir)
    model.vae.use_tiny_decoder(tmp_path / "tiny.safetensors")
    data = json.loads((model_dir / "oscar_model.json").read_text())["card"]
    shutil.rmtree(carded, ignore_errors=True)
    model.save_pretrained(carded, ModelCard.from_dict({**data, "tiny_decoder": "tiny.safetensors"}))
    code, out, err = run(capsys, *_rollout(carded, first_frame, tmp_path / "card.mkv"))
    assert code == 0, err
    np.testing.assert_array_equal(read_video(tmp_path / "card.mkv"), tiny)
    code, out, err = run(capsys, *_rollout(carded, first_frame, tmp_path / "off.mkv", "--full-decoder"))
    assert code == 0, err
    np.testing.assert_array_equal(read_video(tmp_path / "off.mkv"), full)


def test_a_bad_tiny_decoder_flag_exits_2_before_anything_loads(capsys, tmp_path, model_dir, first_frame):
    out = tmp_path / "v.mkv"
    code, _, err = run(capsys, *_rollout(model_dir, first_frame, out, "--tiny-decoder", tmp_path / "no.safetensors"))
    assert code == 2 and "--tiny-decoder: expected a tiny-decoder file, found no file" in err and not out.exists()
    (tmp_path / "w.pth").write_bytes(b"x")
    code, _, err = run(capsys, *_rollout(model_dir, first_frame, out, "--tiny-decoder", tmp_path / "w.pth"))
    assert code == 2 and "--tiny-decoder: expected a .safetensors file" in err
    _write_net(tmp_path / "toy.safetensors", TinyDecoderNet(space_upscale=(True, True, False), widths=(8, 8, 8, 8)))
    code, _, err = run(capsys, *_rollout(model_dir, first_frame, out, "--tiny-decoder", tmp_path / "toy.safetensors"))
    assert code == 2 and "expected x4 in time and x8 in space (the VAE's), found x4 and x4" in err
    with pytest.raises(SystemExit) as exit_:
        run(
            capsys,
            *_rollout(model_dir, first_frame, out, "--tiny-decoder", tmp_path / "toy.safetensors", "--full-decoder"),
        )
    assert exit_.value.code == 2 and "not allowed with argument" in capsys.readouterr().err


def test_a_run_s_fingerprint_records_a_chosen_decoder_only(tmp_path):
    from oscar_core.evaluation.action_following import _decoder_part
    from oscar_core.evaluation.closed_loop import _decoder_identity

    path = tmp_path / "tiny.safetensors"
    _write_net(path, _small_net())
    import hashlib

    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    assert decoder_identity(None) is None and decoder_identity(False) == "full"
    assert decoder_identity(path) == f"tiny-sha256:{digest}"
    assert _decoder_part(None) == {} and _decoder_part(path) == {"decoder": f"tiny-sha256:{digest}"}
    assert _decoder_identity(None, None) == {} and _decoder_identity(None, False) == {"decoder": "full"}
    assert _decoder_identity(object(), path) == {}  # a simulator has no decoder


def test_the_bundled_toy_tiny_decoder_fits_oscar_toy_and_is_off_by_default():
    from oscar_core.model.vae import VideoVAE, load_vae_folder

    folder = oscar_zoo.pull("oscar-toy")  # bundled: every file's sha256 pinned in the table, the tiny decoder's too
    assert read_card(folder).tiny_decoder is None  # the card does not choose it
    net = load_tiny_decoder(folder / "tiny_decoder.safetensors")  # its shape from the file's metadata
    assert net.widths == (32, 32, 16, 16) and (net.space_factor, net.time_factor) == (4, 4)
    vae = VideoVAE(load_vae_folder(folder / "vae"))
    vae.use_tiny_decoder(net)
    out = vae.decode(torch.zeros(1, 16, 5, 16, 16))
    assert out.shape == (1, 3, 17, 64, 64) and out.min() >= -1 and out.max() <= 1
