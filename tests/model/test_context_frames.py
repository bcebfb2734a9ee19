"""The longer context (``context_frames``: 4k + 1 pixel frames, k + 1 latent frames): the chunk plan, the model
card field, training's condition mask, the sampler and the rollout's chunk loop (tiny random models, CPU)."""

import json

import pytest

from oscar_core.model import ModelCard, ModelInputError, chunk_plan, chunk_windows
from oscar_core.model.chunks import check_context_frames

# --------------------------------------------------------------------------- the chunk plan

# written out by hand: chunk 0 makes frames 1..16 from the first frame alone, every later chunk starts 12 frames on
# (17 − 5) from the previous chunk's last 5 frames and makes the 12 after them
BY_HAND_17_5 = {
    17: ([0], [(1, 16)]),
    18: ([0, 12], [(1, 16), (17, 17)]),
    29: ([0, 12], [(1, 16), (17, 28)]),
    30: ([0, 12, 24], [(1, 16), (17, 28), (29, 29)]),
    49: ([0, 12, 24, 36], [(1, 16), (17, 28), (29, 40), (41, 48)]),
    97: (
        [0, 12, 24, 36, 48, 60, 72, 84],
        [(1, 16), (17, 28), (29, 40), (41, 52), (53, 64), (65, 76), (77, 88), (89, 96)],
    ),
}


@pytest.mark.parametrize("frames", sorted(BY_HAND_17_5))
def test_the_plan_with_a_5_frame_context_is_the_one_written_by_hand(frames):
    starts, windows = BY_HAND_17_5[frames]
    assert chunk_plan(frames, 17, context_frames=5) == starts
    assert chunk_windows(frames, 17, context_frames=5) == windows
    # every frame after the first is made exactly once, and the last chunk reaches the last frame
    made = [f for a, b in windows for f in range(a, b + 1)]
    assert made == list(range(1, frames))
    assert starts[-1] + 17 >= frames > starts[-1] + 5  # the last chunk makes at least one frame


def test_a_9_frame_chunk_with_a_5_frame_context_advances_4_frames():
    assert chunk_plan(13, 9, context_frames=5) == [0, 4]
    assert chunk_windows(13, 9, context_frames=5) == [(1, 8), (9, 12)]
    assert chunk_windows(22, 9, context_frames=5) == [(1, 8), (9, 12), (13, 16), (17, 20), (21, 21)]


@pytest.mark.parametrize("chunk", [5, 9, 17, 81])
def test_the_one_frame_context_plan_is_the_plan_before_the_option(chunk):
    for frames in range(chunk, 4 * chunk + 3):
        step = chunk - 1
        before = [k * step for k in range(-(-(frames - 1) // step))]  # the formula the plan had before
        assert chunk_plan(frames, chunk) == before == chunk_plan(frames, chunk, context_frames=1)
        assert chunk_windows(frames, chunk) == [(s + 1, min(s + step, frames - 1)) for s in before]


@pytest.mark.parametrize("bad", [0, 2, 3, 6, 17, 21, True, 5.0, "5"])
def test_a_context_not_4k_plus_1_or_not_shorter_than_the_chunk_is_refused(bad):
    with pytest.raises(ModelInputError, match=r"context_frames: expected .*4k\+1.*17-frame chunk's 5 .*at most 13"):
        chunk_plan(33, 17, context_frames=bad)


def test_the_longest_context_leaves_one_latent_frame():
    assert check_context_frames(13, 17) == 4
    assert check_context_frames(1, 5) == 1
    with pytest.raises(ModelInputError, match="found 5"):
        check_context_frames(5, 5)


# --------------------------------------------------------------------------- the model card


def test_a_card_without_the_field_reads_as_one_frame_and_is_written_without_it():
    card = ModelCard.from_dict({"chunk_frames": 17})
    assert card.context_frames == 1
    assert "context_frames" not in card.to_dict()
    five = ModelCard(chunk_frames=17, context_frames=5)
    assert five.to_dict()["context_frames"] == 5
    assert ModelCard.from_dict(five.to_dict()) == five


@pytest.mark.parametrize("bad", [3, 17, 0])
def test_a_card_with_a_bad_context_names_the_field(bad):
    with pytest.raises(ModelInputError, match=rf"model card context_frames: expected .* found {bad}"):
        ModelCard(chunk_frames=17, context_frames=bad)


def test_a_latent_action_card_keeps_the_one_frame_context():
    with pytest.raises(ModelInputError, match="model card context_frames: expected 1 for a latent-action model"):
        ModelCard(chunk_frames=17, condition="latent_action", context_frames=5)


def test_read_card_refuses_a_bad_context_before_loading_weights(tmp_path):
    from oscar_core.model.card import FORMAT, read_card
    from oscar_core.model.errors import CheckpointLayoutError

    (tmp_path / "oscar_model.json").write_text(
        json.dumps({"format": FORMAT, "format_version": 1, "card": {"chunk_frames": 17, "context_frames": 4}})
    )
    with pytest.raises(CheckpointLayoutError, match="context_frames"):
        read_card(tmp_path)
