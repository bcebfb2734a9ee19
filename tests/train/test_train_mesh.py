"""``condition: mesh`` in ``oscar train``: the mesh video goes through the VAE and PE_s like the skeleton,
the exported card says so, and rollouts render the mesh for such a model."""

import numpy as np
import pytest
import torch
from _models import tiny_clipset, tiny_train_config

import oscar_zoo
from oscar_core.camera import load_camera
from oscar_core.kinematics.trajectory import load_trajectory
from oscar_core.plugin.registry import Registry
from oscar_core.render.mesh import render_mesh_video
from oscar_core.render.skeleton_video import render_skeleton_video
from oscar_core.train.clips import ClipSet
from oscar_core.train.data import TrainData
from oscar_core.train.loop import train
from oscar_core.train.models import build_vae

pytestmark = [
    pytest.mark.filterwarnings("ignore:no prompt embedding:UserWarning"),
    pytest.mark.usefixtures("one_thread"),
]  # tests/conftest.py


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """Toy-arm clips with cached latents (of the video and of the *skeleton*)."""
    return tiny_clipset(tmp_path_factory.mktemp("mesh") / "clips", clips=2)


def test_the_mesh_latent_is_the_vae_encoding_of_the_mesh_video(tmp_path, clips):
    cfg = tiny_train_config(
        clips, tmp_path / "run", steps=1, batch_size=1, condition="mesh", **{"data.skeleton_dropout": 0.0}
    )
    vae = build_vae(cfg)
    data = TrainData(cfg, vae, 48)
    assert data.cached  # the video latents come from the cache; the cached skeleton latents are not a mesh
    item = data.planner().plan(0, 1)[0]
    got = data.load_item(item, "mesh")
    rec = data.clips[item.clip].record
    clip = ClipSet(clips).load(rec.id, start=item.start, frames=9, registry=data.registry)
    emb = data.embodiment(rec.embodiment)
    mesh = render_mesh_video(emb, clip.trajectory, clip.camera, (32, 32))
    assert torch.equal(got["skeleton"], vae.encode(vae.to_pixels(mesh))[0])
    skel = data.load_item(item, "skeleton")["skeleton"]
    assert not torch.equal(got["skeleton"], skel)
    assert torch.equal(got["z0"], data.load_item(item, "skeleton")["z0"])
    assert mesh.any()


def test_a_mesh_run_trains_pe_s_exports_its_condition_and_rolls_out_the_mesh(tmp_path, clips):
    cfg = tiny_train_config(clips, tmp_path / "run", steps=2, export=True, condition="mesh")
    result = train(cfg, progress=False)
    assert np.isfinite(result.last_loss)
    model = oscar_zoo.load(result.export)
    assert model.card.condition == "mesh"
    assert model.transformer.skeleton_embed.proj.weight.abs().sum() > 0  # PE_s learned from the mesh latents
    emb = Registry().get("toyarm")
    traj = load_trajectory(emb.example_trajectory).time_slice(0, 9)
    cam = load_camera(emb.example_camera)
    video = model.rollout_inputs(traj, cam, emb)["skeleton"]
    np.testing.assert_array_equal(video, render_mesh_video(emb, traj, cam, (32, 32)))
    assert not np.array_equal(video, render_skeleton_video(emb, traj, cam, (32, 32)))
