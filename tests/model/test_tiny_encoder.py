"""The tiny encoder (TAEHV design): it loads the ``encoder.*`` tensors of a file laid out as the published ``taew2_1``
checkpoint by key name, its time handling (a time pool's channel order, a memory block's one-frame memory, WAN's
4k + 1 frames padded at the end to k + 1 latent frames, causality) checked by hand and against a second, frame-by-frame
implementation, and bad files and inputs are refused naming the file and the field. Weights here are random,
written by the test."""

import json

import pytest
import torch
from safetensors.torch import save, save_file

from oscar_core.model import ModelInputError
from oscar_core.model._taehv_blocks import MemoryBlock, run_with_memory
from oscar_core.model.errors import CheckpointIntegrityError, CheckpointLayoutError
from oscar_core.model.tiny_encoder import (
    ENCODER_ARCHITECTURE_KEY,
    TinyEncoderNet,
    TinyVideoEncoder,
    _TimePool,
    encoder_architecture_metadata,
    load_tiny_encoder,
    save_tiny_encoder,
)


def _taew2_1_encoder_shapes() -> dict:
    """The encoder.* keys and shapes of the published taew2_1 checkpoint, written out by hand (not from the net)."""
    shapes = {"encoder.0.weight": (64, 3, 3, 3), "encoder.0.bias": (64,)}
    for pool, stride in ((2, 2), (7, 2), (12, 1)):
        shapes[f"encoder.{pool}.conv.weight"] = (64, 64 * stride, 1, 1)
        shapes[f"encoder.{pool + 1}.weight"] = (64, 64, 3, 3)  # the strided convolution, no bias
        for i in range(pool + 2, pool + 5):
            shapes[f"encoder.{i}.conv.0.weight"] = (64, 128, 3, 3)
            for j in (2, 4):
                shapes[f"encoder.{i}.conv.{j}.weight"] = (64, 64, 3, 3)
            for j in (0, 2, 4):
                shapes[f"encoder.{i}.conv.{j}.bias"] = (64,)
    shapes["encoder.17.weight"] = (16, 64, 3, 3)
    shapes["encoder.17.bias"] = (16,)
    return shapes


def _write(path, shapes: dict, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    tensors = {
        k: torch.randn(s, generator=g) * (0.5 / max(1, (s[1] * 9) ** 0.5 if len(s) > 1 else 1))
        for k, s in shapes.items()
    }
    tensors["decoder.1.weight"] = torch.zeros(256, 16, 3, 3)  # the checkpoint's decoder: present, ignored
    save_file(tensors, str(path))
    return tensors


def test_loads_the_taew2_1_encoder_by_key_name(tmp_path):
    path = tmp_path / "taew2_1.safetensors"
    tensors = _write(path, _taew2_1_encoder_shapes())
    net = load_tiny_encoder(path)
    assert set(net.state_dict()) == set(_taew2_1_encoder_shapes())
    assert torch.equal(net.state_dict()["encoder.7.conv.weight"], tensors["encoder.7.conv.weight"])
    out = net(torch.rand(1, 9, 3, 32, 48))
    assert out.shape == (1, 3, 16, 4, 6)  # 4k + 1 = 9 frames -> k + 1 = 3 latent frames, /8 in space


def test_missing_unexpected_and_misshapen_tensors_are_named(tmp_path):
    shapes = _taew2_1_encoder_shapes()
    del shapes["encoder.13.weight"]
    _write(tmp_path / "a.safetensors", shapes)
    with pytest.raises(CheckpointLayoutError, match=r"a\.safetensors: encoder\.\* tensors: .*missing \['encoder\.13"):
        load_tiny_encoder(tmp_path / "a.safetensors")
    shapes = {**_taew2_1_encoder_shapes(), "encoder.18.weight": (16, 16, 1, 1)}
    _write(tmp_path / "b.safetensors", shapes)
    with pytest.raises(CheckpointLayoutError, match=r"unexpected \['encoder\.18\.weight'\]"):
        load_tiny_encoder(tmp_path / "b.safetensors")
    shapes = _taew2_1_encoder_shapes()
    shapes["encoder.12.conv.weight"] = (64, 128, 1, 1)  # a time pool at stride 2 where taew2_1 has stride 1
    _write(tmp_path / "c.safetensors", shapes)
    with pytest.raises(
        CheckpointLayoutError, match=r"c\.safetensors: encoder\.12\.conv\.weight: expected shape \(64, 64, 1, 1\)"
    ):
        load_tiny_encoder(tmp_path / "c.safetensors")
    with pytest.raises(CheckpointLayoutError, match=r"taew2_1\.pth: tiny encoder: expected a \.safetensors file"):
        load_tiny_encoder(tmp_path / "taew2_1.pth")
    with pytest.raises(CheckpointLayoutError, match=r"none\.safetensors: tiny encoder: .*no such file"):
        load_tiny_encoder(tmp_path / "none.safetensors")
    (tmp_path / "cut.safetensors").write_bytes((tmp_path / "c.safetensors").read_bytes()[:-10])
    with pytest.raises(CheckpointIntegrityError, match=r"cut\.safetensors"):
        load_tiny_encoder(tmp_path / "cut.safetensors")


def test_a_file_written_by_oscar_reloads_at_its_own_shape_and_bad_metadata_is_named(tmp_path):
    torch.manual_seed(0)
    net = TinyEncoderNet(space_downscale=(True, True, False), width=8)
    save_tiny_encoder(net, tmp_path / "sub" / "enc.safetensors")
    back = load_tiny_encoder(tmp_path / "sub" / "enc.safetensors")
    assert (back.width, back.space_factor, back.time_factor) == (8, 4, 4)
    assert all(torch.equal(back.state_dict()[k], v) for k, v in net.state_dict().items())
    tensors = {k: v.contiguous() for k, v in net.state_dict().items()}
    (tmp_path / "bad.safetensors").write_bytes(save(tensors, metadata={ENCODER_ARCHITECTURE_KEY: '{"width": 8}'}))
    with pytest.raises(CheckpointLayoutError, match=r"bad\.safetensors: metadata oscar_tiny_encoder: expected"):
        load_tiny_encoder(tmp_path / "bad.safetensors")
    assert json.loads(encoder_architecture_metadata(net)[ENCODER_ARCHITECTURE_KEY])["width"] == 8


def test_a_time_pool_stacks_consecutive_frames_earliest_first():
    """By hand: a pool whose weight is [0 | I] keeps the second frame of each pair, [I | 0] the first."""
    pool = _TimePool(2, 2)
    frames = torch.arange(6 * 2 * 1 * 1, dtype=torch.float32).reshape(6, 2, 1, 1)  # 6 frames of 2 channels
    with torch.no_grad():
        pool.conv.weight.copy_(torch.cat([torch.zeros(2, 2), torch.eye(2)], 1)[..., None, None])
        assert torch.equal(pool(frames), frames[1::2])
        pool.conv.weight.copy_(torch.cat([torch.eye(2), torch.zeros(2, 2)], 1)[..., None, None])
        assert torch.equal(pool(frames), frames[0::2])


def test_a_memory_block_sees_its_clips_previous_frame_and_zeros_before_the_first():
    """By hand: a block whose convolutions pass the memory half through unchanged gives x_t + x_{t-1} (inputs
    >= 0), per clip, with nothing carried from one clip into the next."""
    block = MemoryBlock(1, 1)
    with torch.no_grad():
        for conv in block.conv[::2]:
            conv.weight.zero_(), conv.bias.zero_()
        block.conv[0].weight[0, 1, 1, 1] = 1.0  # the centre tap of the memory channel
        block.conv[2].weight[0, 0, 1, 1] = 1.0
        block.conv[4].weight[0, 0, 1, 1] = 1.0
        clips = torch.tensor([[1.0, 2.0, 4.0], [8.0, 16.0, 32.0]])  # 2 clips of 3 one-pixel frames
        out = run_with_memory(torch.nn.Sequential(block), clips.reshape(6, 1, 1, 1), clips=2).reshape(2, 3)
    assert out.tolist() == [[1.0, 3.0, 6.0], [8.0, 24.0, 48.0]]


def _small_net(seed: int = 0) -> TinyEncoderNet:
    torch.manual_seed(seed)
    net = TinyEncoderNet(width=8).eval()
    with torch.no_grad():
        for p in net.parameters():
            p.normal_(0, 0.3)
    return net


def _frame_by_frame(net: TinyEncoderNet, frames: torch.Tensor) -> torch.Tensor:
    """A second implementation: the frames one at a time (padded at the end with the last one to a multiple of 4),
    each memory block holding the input it saw one frame earlier (zeros at first), each time pool collecting
    ``stride`` frames and passing one on once it has them."""
    memory: dict[int, torch.Tensor] = {}
    waiting: dict[int, list[torch.Tensor]] = {}
    out = []

    def run(x: torch.Tensor, start: int) -> None:
        for i in range(start, len(net.encoder)):
            layer = net.encoder[i]
            if isinstance(layer, MemoryBlock):
                previous = memory.get(i, torch.zeros_like(x))
                memory[i] = x
                x = layer(x, previous)
            elif isinstance(layer, _TimePool):
                waiting.setdefault(i, []).append(x)
                if len(waiting[i]) < layer.stride:
                    return
                x = layer.conv(torch.cat(waiting.pop(i), dim=1))
            else:
                x = layer(x)
        out.append(x)

    t = frames.shape[1]
    padded = list(frames.unbind(1)) + [frames[:, -1]] * (-t % net.time_factor)
    for frame in padded:
        run(frame, 0)
    return torch.stack(out, 1)


@pytest.mark.parametrize("frames", [1, 5, 9, 8])
def test_all_frames_at_once_equals_frame_by_frame(frames):
    net = _small_net()
    x = torch.rand(2, frames, 3, 16, 24)
    with torch.no_grad():
        fast, slow = net(x), _frame_by_frame(net, x)
    assert fast.shape == slow.shape == (2, -(-frames // 4), 16, 2, 3)
    torch.testing.assert_close(fast, slow, rtol=0, atol=1e-5)
    assert fast.std() > 0.01


def test_latent_frame_j_covers_frames_4j_to_4j_plus_3_and_sees_no_later_frame():
    net = _small_net(1)
    x = torch.rand(1, 9, 3, 16, 16)
    with torch.no_grad():
        base = net(x)
        for t in (0, 3, 4, 7, 8):
            y = x.clone()
            y[:, t] = torch.rand(3, 16, 16)
            changed = (net(y) - base).abs().amax(dim=(0, 2, 3, 4)) > 0
            assert changed.tolist() == [j >= t // 4 for j in range(3)], t
        # WAN's 4k + 1 frames: the last latent frame is frame 4k repeated 4 times
        held = torch.cat([x, x[:, -1:].expand(1, 3, 3, 16, 16)], 1)
        torch.testing.assert_close(net(x), net(held), rtol=0, atol=0)


def test_the_video_encoder_takes_vae_pixels_gives_normalised_latents_and_refuses_a_wrong_frame_count():
    net = _small_net(2)
    mean, std = torch.randn(1, 16, 1, 1, 1), torch.rand(1, 16, 1, 1, 1) + 0.5
    encoder = TinyVideoEncoder(net, mean, std)
    pixels = torch.rand(2, 3, 5, 16, 16) * 2 - 1
    z = encoder.encode(pixels)
    assert z.shape == (2, 16, 2, 2, 2)
    expected = (net(((pixels + 1) / 2).permute(0, 2, 1, 3, 4)).permute(0, 2, 1, 3, 4) - mean) / std
    torch.testing.assert_close(z, expected, rtol=0, atol=1e-6)
    with pytest.raises(ModelInputError, match=r"tiny encoder input: expected a frame count of the form 4k\+1.*found 6"):
        encoder.encode(torch.zeros(1, 3, 6, 16, 16))
    with pytest.raises(ModelInputError, match=r"pixels: expected \(B, 3, T, H, W\), found shape \(1, 5, 16, 16\)"):
        encoder.encode(torch.zeros(1, 5, 16, 16))
    with pytest.raises(ModelInputError, match=r"tiny encoder input: .*divisible by 8, found \(1, 5, 3, 12, 16\)"):
        net(torch.zeros(1, 5, 3, 12, 16))
