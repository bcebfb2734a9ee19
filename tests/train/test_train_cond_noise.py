"""``flow.cond_noise_max``: the conditioning frame fed noised at a per-sample level in training (against drift)."""

import pytest
import torch

from oscar_core.train.config import TrainConfigError, config_from_dict
from oscar_core.train.flow import flow_inputs
from oscar_core.train.sampling import PlanItem, item_cond_sigma


def test_a_noised_conditioning_frame_and_its_timestep():
    g = torch.Generator().manual_seed(0)
    z0, eps = torch.randn(3, 4, 5, 2, 2, generator=g), torch.randn(3, 4, 5, 2, 2, generator=g)
    sigma = torch.tensor([0.1, 0.5, 0.9], dtype=torch.float64)
    clean = flow_inputs(z0, eps, sigma, cond_timestep=1e-4)
    cs = torch.tensor([0.0, 0.25, 0.6], dtype=torch.float64)
    fi = flow_inputs(z0, eps, sigma, cond_timestep=1e-4, cond_sigma=cs)
    c = cs.float().view(3, 1, 1, 1)
    torch.testing.assert_close(fi.x[:, :, 0], (1 - c) * z0[:, :, 0] + c * eps[:, :, 0])
    assert torch.equal(fi.x[0, :, 0], z0[0, :, 0])  # sigma_c = 0: clean, as without the option
    torch.testing.assert_close(fi.timestep[:, 0, 0, 0, 0], torch.tensor([1e-4, 0.25, 0.6]))
    # the frames the model predicts, the target, the masks: as without the option
    for name in ("target", "condition_mask", "loss_mask"):
        assert torch.equal(getattr(fi, name), getattr(clean, name)), name
    assert torch.equal(fi.x[:, :, 1:], clean.x[:, :, 1:]) and torch.equal(
        fi.timestep[:, :, 1:], clean.timestep[:, :, 1:]
    )
    with pytest.raises(ValueError, match=r"cond_sigma: expected shape \(3,\)"):
        flow_inputs(z0, eps, sigma, cond_sigma=cs[:2])


def test_item_cond_sigma_is_uniform_per_item_and_reproducible():
    items = [PlanItem(clip=0, start=0, drop=False, sigma=0.5, noise_seed=s) for s in range(4000)]
    a = item_cond_sigma(items, 0.3)
    assert torch.equal(a, item_cond_sigma(items, 0.3))  # the same draws on any process
    assert torch.equal(item_cond_sigma(items[7:9], 0.3), a[7:9])  # an item's level is its own, not its batch's
    assert 0.0 <= float(a.min()) and float(a.max()) <= 0.3
    assert float(a.mean()) == pytest.approx(0.15, abs=0.01) and float(a.std()) == pytest.approx(0.3 / 12**0.5, abs=0.01)
    # apart from the item's noise: the level is not a function of the noise's first draw
    first = torch.stack([torch.randn((), generator=torch.Generator().manual_seed(s)) for s in range(4000)])
    assert abs(float(torch.corrcoef(torch.stack([a, first.double()]))[0, 1])) < 0.05


@pytest.mark.parametrize("bad", [-0.1, 1.5, True, "0.2"])
def test_cond_noise_max_is_checked(bad, tmp_path):
    d = {
        "run_dir": str(tmp_path),
        "model": {"transformer": "tiny", "vae": "tiny"},
        "data": {"clips": [str(tmp_path)], "window": 9, "width": 32, "height": 32},
        "flow": {"cond_noise_max": bad},
    }
    with pytest.raises(TrainConfigError, match="flow.cond_noise_max"):
        config_from_dict(d)


def test_the_training_step_feeds_the_noised_frame_only_when_asked(tmp_path, monkeypatch):
    import oscar_core.train.loop as loop
    from oscar_core.train.data import Batch

    seen = []
    real = loop.flow_inputs
    monkeypatch.setattr(loop, "flow_inputs", lambda *a: seen.append(a[4] if len(a) > 4 else None) or real(*a))

    def cfg(level):
        d = {
            "run_dir": str(tmp_path),
            "model": {"transformer": "tiny", "vae": "tiny"},
            "data": {"clips": [str(tmp_path)], "window": 9, "width": 32, "height": 32},
            "flow": {"cond_noise_max": level},
        }
        return config_from_dict(d)

    torch.manual_seed(0)
    model = loop.build_transformer(cfg(0.0))
    items = [PlanItem(clip=0, start=0, drop=False, sigma=0.5, noise_seed=s) for s in (3, 4)]
    g = torch.Generator().manual_seed(1)
    skel_c = model.skeleton_in_channels if hasattr(model, "skeleton_in_channels") else 16
    batch = Batch(
        torch.randn(2, 16, 3, 4, 4, generator=g),
        torch.randn(2, skel_c, 3, 4, 4, generator=g),
        torch.zeros(2, 1, 48),
        None,
    )
    with torch.no_grad():
        plain = loop.step_loss(model, batch, items, cfg(0.0), "cpu")
        noised = loop.step_loss(model, batch, items, cfg(0.5), "cpu")
    assert seen[0] is None and torch.equal(seen[1], item_cond_sigma(items, 0.5))
    assert plain != noised
