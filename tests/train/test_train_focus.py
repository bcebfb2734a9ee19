"""Focus weights (``data.focus_mask``, ``flow.focus_weight``): the latent cells a pixel mask touches, the weighted
flow loss, the config's checks, and a training batch that carries the cells of the window it loaded."""

import numpy as np
import pytest
import torch

from oscar_core.model.tiny import build_tiny_vae
from oscar_core.model.vae import VideoVAE
from oscar_core.train.cache import cache_latents
from oscar_core.train.config import TrainConfigError, config_from_dict
from oscar_core.train.data import TrainData
from oscar_core.train.flow import flow_inputs, flow_loss
from oscar_core.train.focus import latent_focus
from oscar_core.train.sampling import PlanItem
from oscar_core.train.synthetic import write_toy_clipset

pytestmark = [
    pytest.mark.filterwarnings("ignore:no prompt embedding:UserWarning"),
    pytest.mark.usefixtures("one_thread"),
]  # tests/conftest.py

#: a mask function a user would write: the pixels (y 9-10, x 17) of pixel frames 5 and 6 of any window
MASK_CODE = """
import numpy as np

def mask(frames):
    m = np.zeros(frames.shape[:3], bool)
    m[5:7, 9:11, 17] = True
    return m
"""


def test_latent_focus_follows_the_causal_vae_layout():
    m = np.zeros((9, 32, 32), bool)
    m[0, 0, 31] = True  # frame 0 -> latent frame 0, cell (0, 3) at 8 px per cell
    m[5, 9, 17] = True  # frames 5-8 -> latent frame 2, cell (1, 2)
    m[4, 31, 0] = True  # frames 1-4 -> latent frame 1, cell (3, 0)
    got = latent_focus(m, (3, 4, 4), temporal=4)
    want = torch.zeros(1, 3, 4, 4)
    want[0, 0, 0, 3] = want[0, 2, 1, 2] = want[0, 1, 3, 0] = 1.0
    assert torch.equal(got, want)
    with pytest.raises(ValueError, match="expected .* T = 9 frames"):
        latent_focus(m[:8], (3, 4, 4))
    with pytest.raises(ValueError, match="multiples of 5 x 4"):
        latent_focus(m, (3, 5, 4))


def test_weighted_flow_loss_is_the_plain_one_at_weight_1_and_weighs_the_focus_cells():
    g = torch.Generator().manual_seed(0)
    z0, noise, pred = (torch.randn(2, 3, 3, 4, 4, generator=g) for _ in range(3))
    inputs = flow_inputs(z0, noise, torch.tensor([0.3, 0.8]))
    plain = flow_loss(pred, inputs, reduction="none")
    assert torch.equal(flow_loss(pred, inputs, reduction="none", weight=torch.ones(2, 1, 3, 4, 4)), plain)
    weight = torch.ones(2, 1, 3, 4, 4)
    weight[1, 0, 2, 1, 2] = 11.0  # one focus cell of sample 1, weight 1 + 10
    err = (pred - inputs.target) ** 2
    want1 = (err[1, :, 1:].sum() + 10 * err[1, :, 2, 1, 2].sum()) / (3 * 2 * 4 * 4)
    got = flow_loss(pred, inputs, reduction="none", weight=weight)
    assert got[0] == plain[0] and got[1] == pytest.approx(float(want1), rel=1e-6)
    weight[0, 0, 0] = 100.0  # the conditioning frame stays out of the loss whatever its weight
    assert flow_loss(pred, inputs, reduction="none", weight=weight)[0] == plain[0]


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    root = tmp_path_factory.mktemp("focus")
    clips = write_toy_clipset(root / "toy", clips=2, frames=17, width=32, height=32)
    cache_latents(clips, root / "latents", VideoVAE(build_tiny_vae(0)), window=9, stride=8, log=lambda m: None)
    (root / "user_mask.py").write_text(MASK_CODE)
    return root


def _config(root, **over):
    d = {
        "run_dir": str(root / "run"),
        "steps": 1,
        "batch_size": 1,
        "micro_batch": 1,
        "model": {"transformer": "tiny", "vae": "tiny"},
        "data": {"clips": [str(root / "latents")], "window": 9, "width": 32, "height": 32},
        "flow": {},
    }
    for k, v in over.items():
        section, key = k.split(".")
        d[section][key] = v
    return config_from_dict(d)


def test_a_batch_carries_the_focus_cells_of_its_windows(source):
    cfg = _config(source, **{"data.focus_mask": f"{source / 'user_mask.py'}:mask", "flow.focus_weight": 10.0})
    data = TrainData(cfg, VideoVAE(build_tiny_vae(0)), 48)
    items = [PlanItem(clip=0, start=0, drop=False, sigma=0.5, noise_seed=0), PlanItem(1, 8, False, 0.5, 0)]
    batch = data.batch(items, "skeleton")
    want = torch.zeros(2, 1, 3, 4, 4)
    want[:, 0, 2, 1, 2] = 1.0  # pixel frames 5-6 -> latent frame 2; (y 9-10, x 17) -> cell (1, 2)
    assert torch.equal(batch.focus, want)
    # without a focus weight the mask is not even imported, and batches carry none
    plain = TrainData(_config(source, **{"data.focus_mask": "no_such_module:mask"}), VideoVAE(build_tiny_vae(0)), 48)
    assert plain.batch(items, "skeleton").focus is None


def test_focus_settings_are_checked_before_any_clip_is_read(source):
    with pytest.raises(TrainConfigError, match="data.focus_mask"):
        _config(source, **{"flow.focus_weight": 5.0})
    with pytest.raises(TrainConfigError, match="flow.focus_weight"):
        _config(source, **{"data.focus_mask": "m:f", "flow.focus_weight": -1.0})
    with pytest.raises(TrainConfigError, match="data.focus_mask"):
        _config(source, **{"data.focus_mask": "no-colon", "flow.focus_weight": 1.0})
    cfg = _config(source, **{"data.focus_mask": "no_such_module_xyz:mask", "flow.focus_weight": 1.0})
    with pytest.raises(ValueError, match="data.focus_mask: expected an importable module:attr"):
        TrainData(cfg, VideoVAE(build_tiny_vae(0)), 48)


def test_the_toy_ball_mask_is_its_reserved_colour():
    from oscar_core.toyworld.locate import OBJECT_TARGET, ball_mask, color_mask
    from oscar_core.toyworld.scene import OBJECT_RGB

    frames = np.full((2, 8, 8, 3), 90, np.uint8)
    frames[1, 3:5, 2:4] = (np.array(OBJECT_RGB) * 255).astype(np.uint8)
    m = ball_mask(frames)
    assert m.shape == (2, 8, 8) and m.sum() == 4 and m[1, 3:5, 2:4].all()
    assert np.array_equal(m, color_mask(frames, OBJECT_TARGET))


def test_the_training_step_weighs_the_focus_cells(source):
    from dataclasses import replace

    from oscar_core.train.loop import step_loss
    from oscar_core.train.models import build_transformer

    cfg = _config(source, **{"data.focus_mask": f"{source / 'user_mask.py'}:mask", "flow.focus_weight": 10.0})
    torch.manual_seed(0)
    model = build_transformer(cfg)
    items = [PlanItem(clip=0, start=0, drop=False, sigma=0.5, noise_seed=0)]
    batch = TrainData(cfg, VideoVAE(build_tiny_vae(0)), 48).batch(items, "skeleton")
    with torch.no_grad():
        focused = step_loss(model, batch, items, cfg, "cpu")
        plain = step_loss(model, replace(batch, focus=None), items, cfg, "cpu")
        unfocused = step_loss(model, replace(batch, focus=torch.zeros_like(batch.focus)), items, cfg, "cpu")
    assert unfocused == plain and focused > plain


def test_a_window_drawn_again_reuses_its_focus_cells_without_reading_its_video(source, monkeypatch):
    from oscar_core.train.clips import ClipSet

    cfg = _config(source, **{"data.focus_mask": f"{source / 'user_mask.py'}:mask", "flow.focus_weight": 10.0})
    data = TrainData(cfg, VideoVAE(build_tiny_vae(0)), 48)
    items = [PlanItem(clip=0, start=0, drop=False, sigma=0.5, noise_seed=0), PlanItem(1, 8, False, 0.5, 0)]
    first = data.batch(items, "skeleton").focus
    loads, calls = [], []
    real_load, real_mask = ClipSet.load, data.focus_mask
    monkeypatch.setattr(
        ClipSet, "load", lambda self, rec, **kw: loads.append(kw["video"]) or real_load(self, rec, **kw)
    )
    data.focus_mask = lambda frames: calls.append(1) or real_mask(frames)
    again = data.batch(items, "skeleton").focus
    assert torch.equal(first, again) and not calls and loads == [False, False]  # the memo: no video, no mask call
    monkeypatch.setattr("oscar_core.train.data.FOCUS_MEMO_BYTES", 0)
    fresh = TrainData(cfg, VideoVAE(build_tiny_vae(0)), 48)
    fresh.focus_mask = data.focus_mask
    loads.clear()
    assert torch.equal(fresh.batch(items, "skeleton").focus, first) and calls and loads == [True, True]
    assert torch.equal(fresh.batch(items, "skeleton").focus, first) and loads == [True] * 4  # no room: every draw
