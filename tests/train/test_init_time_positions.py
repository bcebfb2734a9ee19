"""Fine-tuning on longer windows than a base's learnt time positions cover (``model.init`` with a larger
``max_size[0]``): the new rows of ``pos_emb_t`` repeat the base's last row, every other weight is the base's, and on
windows the base could take the fine-tune starts as the base."""

import pytest
import torch
from _models import tiny_clipset, tiny_train_config

import oscar_zoo
from oscar_core.model.tiny import TINY_TRANSFORMER_CONFIG
from oscar_core.train.loop import train
from oscar_core.train.models import build_transformer

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py

KEY = "learnable_pos_embed.pos_emb_t"


def _transformer(frames: int) -> dict:
    return {**TINY_TRANSFORMER_CONFIG, "max_size": [frames, 64, 64]}


def test_a_longer_fine_tune_repeats_the_last_learnt_time_position_and_starts_as_its_base(tmp_path):
    clips = tiny_clipset(tmp_path / "clips", clips=2)
    base_cfg = tiny_train_config(
        clips, tmp_path / "base", steps=1, export=True, **{"model.transformer": _transformer(3)}
    )
    base = oscar_zoo.load(train(base_cfg, progress=False).export).transformer.eval()
    over = {"model.transformer": _transformer(5), "model.init": str(tmp_path / "base" / "export")}
    tuned = build_transformer(tiny_train_config(clips, tmp_path / "tuned", **over)).eval()
    learnt, widened = base.state_dict()[KEY], tuned.state_dict()[KEY]
    assert learnt.shape[0] == 3 and widened.shape[0] == 5
    torch.testing.assert_close(widened[:3], learnt)
    torch.testing.assert_close(widened[3:], learnt[-1:].expand(2, -1))
    for name, value in base.state_dict().items():
        if name != KEY:
            torch.testing.assert_close(tuned.state_dict()[name], value, msg=name)
    g = torch.Generator().manual_seed(0)
    x, skel = torch.randn(1, 16, 3, 4, 4, generator=g), torch.randn(1, 16, 3, 4, 4, generator=g)
    args = dict(timestep=torch.tensor([0.5]), encoder_hidden_states=torch.zeros(1, 1, 48), return_dict=False)
    mask = torch.zeros(1, 1, 3, 4, 4)
    with torch.no_grad():
        want = base(x, condition_mask=mask, skeleton_latents=skel, **args)[0]
        got = tuned(x, condition_mask=mask, skeleton_latents=skel, **args)[0]
    torch.testing.assert_close(got, want)
