"""``model.gripper_signal``: a DiT trained with the gripper's openness per latent frame beside its condition video.
The trainer appends the window's features (zeros for a dropped condition), the exported card says so and its
rollouts pass the signal, and a fine-tune from a model without it starts exactly at that model."""

import numpy as np
import pytest
import torch

import oscar_zoo
from oscar_core.camera import load_camera
from oscar_core.kinematics.trajectory import load_trajectory
from oscar_core.model.gripper_signal import gripper_channels, gripper_features
from oscar_core.model.tiny import build_tiny_vae
from oscar_core.model.vae import VideoVAE
from oscar_core.plugin.registry import Registry
from oscar_core.train.cache import cache_latents
from oscar_core.train.config import TrainConfigError, config_from_dict
from oscar_core.train.data import TrainData
from oscar_core.train.loop import train
from oscar_core.train.models import build_transformer
from oscar_core.train.sampling import PlanItem
from oscar_core.train.synthetic import write_toy_clipset

pytestmark = [
    pytest.mark.filterwarnings("ignore:no prompt embedding:UserWarning"),
    pytest.mark.usefixtures("one_thread"),
]  # tests/conftest.py


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    root = tmp_path_factory.mktemp("grip")
    clips = write_toy_clipset(root / "toy", clips=6, frames=25, width=32, height=32)
    cache_latents(clips, root / "latents", VideoVAE(build_tiny_vae(0)), window=9, stride=8, log=lambda m: None)
    return root / "latents"


def _config(clips, run_dir, **over):
    d = {
        "run_dir": str(run_dir),
        "steps": 2,
        "batch_size": 1,
        "micro_batch": 1,
        "save_every": 2,
        "export": True,
        "model": {"transformer": "tiny", "vae": "tiny", "gripper_signal": True},
        "data": {"clips": [str(clips)], "window": 9, "width": 32, "height": 32, "skeleton_dropout": 0.0},
    }
    for k, v in over.items():
        node = d
        *parents, last = k.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[last] = v
    return config_from_dict(d)


def test_the_condition_latent_carries_the_windows_gripper_features(tmp_path, source):
    cfg = _config(source, tmp_path / "run")
    data = TrainData(cfg, VideoVAE(build_tiny_vae(0)), 48)
    assert build_transformer(cfg).skeleton_in_channels == 16 + gripper_channels(4)
    for u_index, u in enumerate(data.clips):
        for start in u.starts:
            item = PlanItem(clip=u_index, start=int(start), drop=False, sigma=0.5, noise_seed=0)
            cond = data.load_item(item, "skeleton")["skeleton"]
            assert cond.shape[0] == 24
            want = gripper_features(u.record.openness_array[start : start + 9], 4)
            torch.testing.assert_close(cond[16:, :, 0, 0], torch.from_numpy(want))
            plain = u.clipset.load(u.record, start=int(start), frames=9, video=False).latents
            row = int(np.nonzero(plain["starts"].numpy() == start)[0][0])
            torch.testing.assert_close(cond[:16], plain["skeleton"][row].float())
            dropped = data.load_item(PlanItem(u_index, int(start), True, 0.5, 0), "skeleton")["skeleton"]
            assert dropped.shape[0] == 24 and not dropped.any()
    # the windows differ in their gripper features somewhere (else the test would not see a shifted window)
    feats = {gripper_features(u.record.openness_array[s : s + 9], 4).tobytes() for u in data.clips for s in u.starts}
    assert len(feats) > 1 and sum(len(u.starts) for u in data.clips) == 18


def test_the_export_takes_the_signal_and_rollouts_pass_it(tmp_path, source):
    result = train(_config(source, tmp_path / "run"), progress=False)
    model = oscar_zoo.load(result.export)
    assert model.card.gripper_signal is True
    emb = Registry().get("toyarm")
    traj = load_trajectory(emb.example_trajectory).time_slice(0, 9)
    cam = load_camera(emb.example_camera)
    inputs = model.rollout_inputs(traj, cam, emb)
    np.testing.assert_allclose(inputs["gripper"], emb.gripper_openness(traj.gripper, traj.source))
    first = np.zeros((32, 32, 3), np.uint8)
    frames = model.rollout_trajectory(first, traj, cam, emb, progress=False, keep_chunks=False).frames
    assert frames.shape == (9, 32, 32, 3)


def test_a_fine_tune_with_the_signal_starts_at_its_base(tmp_path, source):
    base = train(_config(source, tmp_path / "base", **{"model.gripper_signal": False}), progress=False)
    cfg = _config(source, tmp_path / "tuned", **{"model.init": str(base.export)})
    tuned = build_transformer(cfg).eval()
    plain = oscar_zoo.load(base.export).transformer.eval()
    g = torch.Generator().manual_seed(0)
    x = torch.randn(1, 16, 3, 4, 4, generator=g)
    skel = torch.randn(1, 16, 3, 4, 4, generator=g)
    grip = torch.randn(1, 8, 3, 1, 1, generator=g).expand(-1, -1, -1, 4, 4)
    args = dict(timestep=torch.tensor([0.5]), encoder_hidden_states=torch.zeros(1, 1, 48), return_dict=False)
    mask = torch.zeros(1, 1, 3, 4, 4)
    with torch.no_grad():
        want = plain(x, condition_mask=mask, skeleton_latents=skel, **args)[0]
        got = tuned(x, condition_mask=mask, skeleton_latents=torch.cat([skel, grip], 1), **args)[0]
    torch.testing.assert_close(got, want)


def test_a_gripper_signal_needs_a_condition_video():
    with pytest.raises(TrainConfigError, match="model.gripper_signal"):
        config_from_dict(
            {"run_dir": "r", "data": {"clips": ["c"]}, "condition": "latent_action", "model": {"gripper_signal": True}}
        )
    with pytest.raises(TrainConfigError, match="model.gripper_signal"):
        config_from_dict({"run_dir": "r", "data": {"clips": ["c"]}, "model": {"gripper_signal": 1}})
