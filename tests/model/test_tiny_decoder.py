"""The tiny decoder (TAEHV design): it loads a file laid out as the published ``taew2_1`` checkpoint by key name,
its all-frames-at-once pass equals a frame-by-frame pass with explicit memory, and it can stand in for the full
WAN decoder behind VideoVAE.decode (off by default). Weights here are random, written by the test."""

import pytest
import torch
from safetensors.torch import save_file

from oscar_core.model import ModelInputError, VideoVAE
from oscar_core.model.errors import CheckpointIntegrityError, CheckpointLayoutError
from oscar_core.model.tiny import build_tiny_vae
from oscar_core.model.tiny_decoder import TinyDecoderNet, TinyVideoDecoder, load_tiny_decoder


def _taew2_1_decoder_shapes(grow0_rows: int = 256) -> dict:
    """The decoder.* keys and shapes of the published taew2_1 checkpoint, written out by hand (not from the net)."""
    shapes = {"decoder.1.weight": (256, 16, 3, 3), "decoder.1.bias": (256,)}
    for first, width in ((3, 256), (9, 128), (15, 64)):
        for i in range(first, first + 3):
            shapes[f"decoder.{i}.conv.0.weight"] = (width, 2 * width, 3, 3)
            for j in (2, 4):
                shapes[f"decoder.{i}.conv.{j}.weight"] = (width, width, 3, 3)
            for j in (0, 2, 4):
                shapes[f"decoder.{i}.conv.{j}.bias"] = (width,)
    shapes["decoder.7.conv.weight"] = (grow0_rows, 256, 1, 1)
    shapes["decoder.8.weight"] = (128, 256, 3, 3)
    shapes["decoder.13.conv.weight"] = (256, 128, 1, 1)
    shapes["decoder.14.weight"] = (64, 128, 3, 3)
    shapes["decoder.19.conv.weight"] = (128, 64, 1, 1)
    shapes["decoder.20.weight"] = (64, 64, 3, 3)
    shapes["decoder.22.weight"] = (3, 64, 3, 3)
    shapes["decoder.22.bias"] = (3,)
    return shapes


def _write(path, shapes: dict, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    tensors = {
        k: torch.randn(s, generator=g) * (0.5 / max(1, (s[1] * 9) ** 0.5 if len(s) > 1 else 1))
        for k, s in shapes.items()
    }
    tensors["encoder.0.weight"] = torch.zeros(64, 3, 3, 3)  # the checkpoint's encoder: present, ignored
    save_file(tensors, str(path))
    return tensors


def test_loads_the_taew2_1_layout_by_key_name(tmp_path):
    path = tmp_path / "taew2_1.safetensors"
    tensors = _write(path, _taew2_1_decoder_shapes())
    net = load_tiny_decoder(path)
    assert set(net.state_dict()) == set(_taew2_1_decoder_shapes())
    assert torch.equal(net.state_dict()["decoder.14.weight"], tensors["decoder.14.weight"])
    z = torch.randn(1, 5, 16, 4, 6)
    out = net(z)
    assert out.shape == (1, 17, 3, 32, 48)  # 4(T' - 1) + 1 frames, x8 in space
    assert out.min() >= 0 and out.max() <= 1


def test_a_time_grow_stored_at_a_larger_stride_keeps_its_last_output_channels(tmp_path):
    path = tmp_path / "old.safetensors"
    tensors = _write(path, _taew2_1_decoder_shapes(grow0_rows=512))
    net = load_tiny_decoder(path)
    assert torch.equal(net.state_dict()["decoder.7.conv.weight"], tensors["decoder.7.conv.weight"][256:])


def test_missing_and_misshapen_tensors_are_named(tmp_path):
    shapes = _taew2_1_decoder_shapes()
    del shapes["decoder.20.weight"]
    _write(tmp_path / "a.safetensors", shapes)
    with pytest.raises(CheckpointLayoutError, match=r"a\.safetensors.*missing \['decoder\.20\.weight'\]"):
        load_tiny_decoder(tmp_path / "a.safetensors")
    shapes = _taew2_1_decoder_shapes()
    shapes["decoder.8.weight"] = (128, 128, 3, 3)
    _write(tmp_path / "b.safetensors", shapes)
    with pytest.raises(CheckpointLayoutError, match=r"decoder\.8\.weight: expected shape \(128, 256, 3, 3\), found"):
        load_tiny_decoder(tmp_path / "b.safetensors")
    with pytest.raises(CheckpointLayoutError, match=r"expected a \.safetensors file"):
        load_tiny_decoder(tmp_path / "taew2_1.pth")


def _frame_by_frame(net: TinyDecoderNet, z: torch.Tensor) -> torch.Tensor:
    """A second implementation: one frame at a time through the layers, each memory block holding the input it
    saw one frame earlier (zeros at first), a time-grow splitting a frame into its output frames in channel order."""
    from oscar_core.model._taehv_blocks import MemoryBlock
    from oscar_core.model.tiny_decoder import _TimeGrow

    memory: dict[int, torch.Tensor] = {}

    def run(x: torch.Tensor, start: int) -> list[torch.Tensor]:
        for i in range(start, len(net.decoder)):
            layer = net.decoder[i]
            if isinstance(layer, MemoryBlock):
                previous = memory.get(i, torch.zeros_like(x))
                memory[i] = x
                x = layer(x, previous)
            elif isinstance(layer, _TimeGrow):
                c = x.shape[1]
                grown = layer.conv(x)
                return [f for j in range(layer.stride) for f in run(grown[:, j * c : (j + 1) * c], i + 1)]
            else:
                x = layer(x)
        return [x]

    frames = [f for t in range(z.shape[1]) for f in run(z[:, t], 0)]
    return torch.stack(frames, 1).clamp(0, 1)[:, net.frames_to_trim :]


def test_all_frames_at_once_equals_frame_by_frame():
    torch.manual_seed(0)
    net = TinyDecoderNet(widths=(16, 8, 8, 8)).eval()
    with torch.no_grad():
        for p in net.parameters():
            p.normal_(0, 0.3)
        z = torch.randn(2, 4, 16, 3, 3)
        fast, slow = net(z), _frame_by_frame(net, z)
    assert fast.shape == slow.shape == (2, 13, 3, 24, 24)
    torch.testing.assert_close(fast, slow, rtol=0, atol=1e-5)
    assert fast.std() > 0.01  # not a saturated or constant output


def test_video_vae_decodes_with_the_tiny_decoder_only_when_asked():
    vae = VideoVAE(build_tiny_vae(seed=0))
    z = torch.randn(1, 16, 2, 4, 8)
    full = vae.decode(z)
    torch.manual_seed(1)
    net = TinyDecoderNet(widths=(16, 8, 8, 8))
    vae.use_tiny_decoder(net)
    tiny = vae.decode(z)
    assert tiny.shape == full.shape == (1, 3, 5, 32, 64)
    assert tiny.min() >= -1 and tiny.max() <= 1 and not torch.equal(tiny, full)
    expected = net((z * vae.std + vae.mean).permute(0, 2, 1, 3, 4)).permute(0, 2, 1, 3, 4) * 2 - 1
    torch.testing.assert_close(tiny, expected, rtol=0, atol=1e-6)
    vae.use_tiny_decoder(None)
    assert torch.equal(vae.decode(z), full)
    with pytest.raises(ModelInputError, match=r"expected x4 in time and x8 in space .* found x4 and x4"):
        vae.use_tiny_decoder(TinyDecoderNet(space_upscale=(True, True, False), widths=(16, 8, 8, 8)))


def test_a_batch_is_decoded_clip_by_clip_on_the_cpu_with_each_clips_own_decode():
    torch.manual_seed(2)
    net = TinyDecoderNet(widths=(16, 8, 8, 8)).eval()
    decoder = TinyVideoDecoder(net, torch.zeros(1, 16, 1, 1, 1), torch.ones(1, 16, 1, 1, 1))
    z = torch.randn(3, 16, 2, 4, 4)
    batches = []
    forward = net.forward
    net.forward = lambda x: batches.append(x.shape[0]) or forward(x)
    together = decoder.decode(z)
    assert batches == [1, 1, 1]
    alone = [decoder.decode(z[i : i + 1]) for i in range(3)]
    assert together.shape == (3, 3, 5, 32, 32)
    assert all(torch.equal(together[i : i + 1], a) for i, a in enumerate(alone))


def test_from_pretrained_takes_a_tiny_decoder_file_and_defaults_to_the_full_decoder(tmp_path):
    from _models import tiny_world_model

    from oscar_core.model import OscarWorldModel

    tiny_world_model(seed=0, chunk_frames=5).save_pretrained(tmp_path / "model")
    torch.manual_seed(2)
    net = TinyDecoderNet(widths=(16, 8, 8, 8))
    save_file({k: v.contiguous() for k, v in net.state_dict().items()}, str(tmp_path / "tiny.safetensors"))
    default = OscarWorldModel.from_pretrained(tmp_path / "model")
    assert default.vae.tiny is None
    with pytest.raises(CheckpointLayoutError, match=r"decoder\.1\.weight: expected shape \(256, 16, 3, 3\)"):
        OscarWorldModel.from_pretrained(tmp_path / "model", tiny_decoder=tmp_path / "tiny.safetensors")
    (tmp_path / "cut.safetensors").write_bytes((tmp_path / "tiny.safetensors").read_bytes()[:-10])
    with pytest.raises(CheckpointIntegrityError):
        load_tiny_decoder(tmp_path / "cut.safetensors", TinyDecoderNet(widths=(16, 8, 8, 8)))
    full = TinyDecoderNet()
    save_file({k: v.contiguous() for k, v in full.state_dict().items()}, str(tmp_path / "taew2_1.safetensors"))
    fast = OscarWorldModel.from_pretrained(tmp_path / "model", tiny_decoder=tmp_path / "taew2_1.safetensors")
    z = torch.randn(1, 16, 2, 4, 8)
    torch.testing.assert_close(fast.vae.decode(z), TinyVideoDecoder(full, fast.vae.mean, fast.vae.std).decode(z))
