"""The DiT's rotary tables are kept per (grid, device, fps): the same values as computed afresh, the same tensors on a
repeat, a bounded number kept, none carried across a move, and tables first made in inference mode usable in a
training step. The DiT's output against diffusers' stays in test_cosmos_dit.py."""

import pytest
import torch

from oscar_core.model._cosmos_layers import ROPE_TABLES_KEPT, RotaryPositions
from oscar_core.model.cosmos_dit import CosmosDiT
from oscar_core.model.tiny import TINY_TRANSFORMER_CONFIG, randomise

CPU = torch.device("cpu")


def _rope() -> RotaryPositions:
    return RotaryPositions(32, (8, 16, 16), (2.0, 1.0, 1.0))


@pytest.mark.parametrize("fps", [None, 10.0, 16])
def test_kept_tables_are_the_fresh_ones_bit_for_bit_and_the_same_tensors_on_a_repeat(fps):
    rope = _rope()
    first = rope((5, 8, 8), CPU, fps)
    again = rope((5, 8, 8), "cpu", fps)
    fresh = rope.tables((5, 8, 8), CPU, fps)
    assert again[0] is first[0] and again[1] is first[1]
    assert torch.equal(first[0], fresh[0]) and torch.equal(first[1], fresh[1])
    assert first[0].shape == (5 * 8 * 8, 32) and first[0].dtype == torch.float32


def test_grid_and_fps_each_get_their_own_tables_and_only_the_last_few_are_kept():
    rope = _rope()
    base = rope((5, 8, 8), CPU, 10.0)
    other_fps = rope((5, 8, 8), CPU, 24.0)
    other_grid = rope((3, 8, 8), CPU, 10.0)
    assert not torch.equal(base[0], other_fps[0])  # time angles scale with 1 / fps
    assert other_grid[0].shape[0] == 3 * 8 * 8
    assert torch.equal(base[0], rope.tables((5, 8, 8), CPU, 10.0)[0])
    for t in range(1, ROPE_TABLES_KEPT + 2):
        rope((t, 4, 4), CPU, None)
    assert len(rope._tables) == ROPE_TABLES_KEPT
    assert rope((5, 8, 8), CPU, 10.0)[0] is not base[0]  # the oldest went first: made again


def test_moving_the_module_drops_its_tables():
    rope = _rope()
    first = rope((5, 8, 8), CPU, None)
    rope.to(torch.float64)
    assert rope((5, 8, 8), CPU, None)[0] is not first[0]


def test_the_grid_check_still_comes_first():
    from oscar_core.model import ModelInputError

    with pytest.raises(ModelInputError, match=r"expected at most 16 tokens along each axis"):
        _rope()((5, 17, 8), CPU, None)


def test_tables_made_in_inference_mode_serve_a_training_step_after_it():
    """A rollout (inference mode) then a training step in one process: the kept tables must be ordinary tensors,
    or autograd refuses to save them for the backward pass."""
    torch.manual_seed(0)
    model = CosmosDiT(**TINY_TRANSFORMER_CONFIG)
    randomise(model, 0, 0.05)
    cfg = model.config
    g = torch.Generator().manual_seed(1)
    kwargs = dict(
        hidden_states=torch.randn(1, cfg.out_channels, 2, 4, 4, generator=g),
        timestep=torch.rand(1, generator=g),
        encoder_hidden_states=torch.randn(1, 3, cfg.crossattn_proj_in_channels, generator=g),
        condition_mask=torch.zeros(1, 1, 2, 4, 4),
        padding_mask=torch.zeros(1, 1, 32, 32),
        fps=10.0,
    )
    with torch.inference_mode():
        sampled = model(**kwargs).sample
    assert len(model.rope._tables) == 1
    out = model(**kwargs).sample
    out.square().mean().backward()
    assert torch.equal(out.detach(), sampled)
    assert all(p.grad is not None for p in model.transformer_blocks[0].attn1.parameters())
