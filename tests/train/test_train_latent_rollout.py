"""An exported latent-action run is a model folder: it loads through the zoo and rolls out from actions."""

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from _models import tiny_clipset, tiny_train_config, tiny_world_model
from _paths import REPO

import oscar_zoo
from oscar_core.camera import load_camera
from oscar_core.errors import OscarError
from oscar_core.kinematics.trajectory import load_trajectory
from oscar_core.model.errors import ModelInputError
from oscar_core.model.latent_action import ACTION_DIM, LatentActionTransformer, hold_actions, latent_actions
from oscar_core.model.sampler import SamplerConfig
from oscar_core.model.world_model import MODEL_FILE, ModelCard
from oscar_core.plugin.registry import Registry
from oscar_core.train.loop import train

STEPS = SamplerConfig(steps=2)  # action_guidance None: the conditional branch alone
pytestmark = [
    pytest.mark.filterwarnings("ignore:no prompt embedding:UserWarning"),
    pytest.mark.usefixtures("one_thread"),
]  # tests/conftest.py


@pytest.fixture(scope="module")
def toyarm():
    emb = Registry().get("toyarm")
    return emb, load_trajectory(emb.example_trajectory), load_camera(emb.example_camera)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A 2-step tiny latent-action run (9-frame windows, 32x32), exported."""
    root = tmp_path_factory.mktemp("la")
    clips = tiny_clipset(root / "clips", clips=3)
    cfg = tiny_train_config(clips, root / "run", steps=2, export=True, condition="latent_action")
    return train(cfg, progress=False).export


@pytest.fixture()
def model(exported):
    return oscar_zoo.load(exported)


FIRST = np.full((32, 32, 3), 80, np.uint8)


def record_actions(model):
    """Wrap the DiT's forward: returns the list of ``actions`` it is called with (None for no actions)."""
    seen = []
    forward = model.transformer.forward

    def spy(*args, actions=None, **kwargs):
        seen.append(None if actions is None else actions.detach().clone())
        return forward(*args, actions=actions, **kwargs)

    model.transformer.forward = spy
    return seen


# ---------------------------------------------------------------------- the card and the folder
def test_export_loads_as_a_latent_action_world_model(exported, model):
    assert isinstance(model.transformer, LatentActionTransformer)
    assert model.card.condition == "latent_action"
    assert (model.card.chunk_frames, model.card.width, model.card.height) == (9, 32, 32)
    assert model.transformer.config.action_frames == 8
    card = json.loads((Path(exported) / MODEL_FILE).read_text())["card"]
    assert card["condition"] == "latent_action"
    # the trained action MLPs came through (they start at zero)
    assert model.transformer.action_embed_d[2].weight.abs().sum() > 0


def test_card_condition_defaults_to_skeleton_and_is_checked():
    old = {"name": "old", "chunk_frames": 81}  # a card written before the field existed
    assert ModelCard.from_dict(old).condition == "skeleton"
    assert ModelCard.from_dict(ModelCard(condition="none").to_dict()).condition == "none"
    assert ModelCard(condition="mesh").condition == "mesh"
    with pytest.raises(ModelInputError, match="model card condition: expected one of .* found 'depth'"):
        ModelCard(condition="depth")


# ---------------------------------------------------------------------- the rollout
def test_hold_actions_equal_the_features_of_a_padded_trajectory(toyarm):
    emb, full, _ = toyarm
    traj = full.time_slice(30, 42)  # the gripper closes in here: openness is not constant
    padded = traj.replace(
        q=np.concatenate([traj.q, np.repeat(traj.q[-1:], 5, 0)]),
        gripper=np.concatenate([traj.gripper, np.repeat(traj.gripper[-1:], 5, 0)]),
    )
    want = latent_actions(emb, padded)
    got = hold_actions(latent_actions(emb, traj), len(want))
    assert got.shape == (16, ACTION_DIM)
    np.testing.assert_allclose(got, want, atol=1e-9)
    assert np.abs(got[:, 6]).sum() > 0  # the openness column is really carried
    with pytest.raises(ModelInputError, match="at most 3 rows"):
        hold_actions(got, 3)


def test_each_chunk_is_fed_its_window_of_the_trajectory_actions(model, toyarm):
    emb, full, cam = toyarm
    traj = full.time_slice(20, 40)  # 20 frames: chunks of 9 start at 0, 8, 16; the last one is padded
    seen = record_actions(model)
    out = model.rollout_trajectory(FIRST, traj, cam, emb, progress=False, sampler=STEPS)
    assert out.frames.shape == (20, 32, 32, 3) and out.starts == [0, 8, 16]
    padded = traj.replace(
        q=np.concatenate([traj.q, np.repeat(traj.q[-1:], 5, 0)]),
        gripper=np.concatenate([traj.gripper, np.repeat(traj.gripper[-1:], 5, 0)]),
    )
    feats = torch.from_numpy(latent_actions(emb, padded)).float()  # (24, 14)
    assert len(seen) == 3 * STEPS.steps
    for i, a in enumerate(seen):
        start = out.starts[i // STEPS.steps]
        assert a is not None and a.shape == (1, 8, ACTION_DIM)
        torch.testing.assert_close(a[0], feats[start : start + 8], rtol=0, atol=1e-6)


def test_actions_change_the_video(model, toyarm):
    emb, full, cam = toyarm
    up, down = full.time_slice(0, 9), full.time_slice(45, 54)
    a = model.rollout_trajectory(FIRST, up, cam, emb, progress=False, sampler=STEPS)
    b = model.rollout_trajectory(FIRST, down, cam, emb, progress=False, sampler=STEPS)
    again = model.rollout_trajectory(FIRST, up, cam, emb, progress=False, sampler=STEPS)
    assert a.frames.shape == (9, 32, 32, 3)
    np.testing.assert_array_equal(a.frames, again.frames)  # same seed, same video
    assert not np.array_equal(a.frames, b.frames)
    assert (a.chunks[0] - b.chunks[0]).abs().max() > 1e-4
    # control: with the action MLPs' outputs zeroed the two trajectories give the same video
    with torch.no_grad():
        for mlp in (model.transformer.action_embed_d, model.transformer.action_embed_3d):
            mlp[2].weight.zero_()
            mlp[2].bias.zero_()
    a0 = model.rollout_trajectory(FIRST, up, cam, emb, progress=False, sampler=STEPS)
    b0 = model.rollout_trajectory(FIRST, down, cam, emb, progress=False, sampler=STEPS)
    torch.testing.assert_close(a0.chunks[0], b0.chunks[0], rtol=0, atol=0)


def test_action_guidance_runs_an_unconditional_branch_without_actions(model, toyarm):
    emb, full, cam = toyarm
    seen = record_actions(model)
    model.rollout_trajectory(
        FIRST, full.time_slice(0, 9), cam, emb, progress=False, sampler=SamplerConfig(steps=2, action_guidance=3.0)
    )
    assert [a is None for a in seen] == [False, True, False, True]  # cond, uncond per step
    seen.clear()
    model.rollout_trajectory(FIRST, full.time_slice(0, 9), cam, emb, progress=False, sampler=STEPS)
    assert len(seen) == 2 and all(a is not None for a in seen)  # default: the conditional branch alone


def test_guided_velocity_over_actions_is_the_cfg_formula(model):
    from oscar_core.model.sampler import guided_velocity

    tr = model.transformer
    g = torch.Generator().manual_seed(0)
    x = torch.randn(1, 16, 3, 4, 4, generator=g)
    t = torch.full((1, 1, 3, 1, 1), 0.5)
    text = tr.project_text(torch.randn(1, 2, tr.text_dim, generator=g))
    mask = torch.zeros(1, 1, 3, 4, 4)
    pad = torch.zeros(1, 1, 4, 4)
    acts = torch.randn(1, 8, ACTION_DIM, generator=g)
    kw = dict(text_projected=True)
    v_c = guided_velocity(tr, x, t, text, None, mask, pad, SamplerConfig(), actions=acts, **kw)
    v_u = tr(
        hidden_states=x,
        timestep=t,
        encoder_hidden_states=text,
        condition_mask=mask,
        padding_mask=pad,
        return_dict=False,
        text_projected=True,
    )[0]
    w = 2.5
    v = guided_velocity(tr, x, t, text, None, mask, pad, SamplerConfig(action_guidance=w), actions=acts, **kw)
    torch.testing.assert_close(v, v_c + w * (v_c - v_u), rtol=1e-5, atol=1e-6)
    v = guided_velocity(
        tr, x, t, text, None, mask, pad, SamplerConfig(action_guidance=w, guidance_form="standard"), actions=acts, **kw
    )
    torch.testing.assert_close(v, v_u + w * (v_c - v_u), rtol=1e-5, atol=1e-6)
    assert (v_c - v_u).abs().max() > 0


def test_wrong_inputs_are_named(model, toyarm):
    emb, full, cam = toyarm
    acts = latent_actions(emb, full.time_slice(0, 9))
    with pytest.raises(ModelInputError, match="latent-action model: expected actions"):
        model.rollout(FIRST, np.zeros((9, 32, 32, 3), np.uint8), progress=False, sampler=STEPS)
    with pytest.raises(
        ModelInputError,
        match=r"chunk_frames: a latent-action model takes the window it was trained "
        r"on \(9 frames.*found 13",
    ):
        model.rollout(FIRST, None, actions=acts, chunk_frames=13, progress=False, sampler=STEPS)


def test_a_skeleton_model_refuses_actions(tmp_path):

    m = tiny_world_model(chunk_frames=9)
    with pytest.raises(ModelInputError, match="conditioned on 'skeleton': expected a skeleton video, found actions"):
        m.rollout(FIRST, None, actions=np.zeros((8, ACTION_DIM)), progress=False, sampler=STEPS)


def test_oscar_rollout_cli_rolls_a_latent_action_model_out(tmp_path, capsys, exported):
    import cv2

    from oscar_core.media.video import read_video
    from oscar_core.model.cli import add_model_parsers

    assets = REPO / "examples" / "oscar-toyarm" / "oscar_toyarm" / "assets"
    first = tmp_path / "first.png"
    cv2.imwrite(str(first), np.random.default_rng(0).integers(0, 256, (360, 640, 3), dtype=np.uint8))
    parser = argparse.ArgumentParser(prog="oscar")
    add_model_parsers(parser.add_subparsers(dest="command", required=True))
    out = tmp_path / "v.mkv"
    args = parser.parse_args(
        [
            str(a)
            for a in (
                "rollout",
                "--model",
                exported,
                "--embodiment",
                "toyarm",
                "--first-frame",
                first,
                "--trajectory",
                assets / "example_trajectory.npz",
                "--camera",
                assets / "example_camera.json",
                "--out",
                out,
                "--steps",
                "1",
                "--no-progress",
                "--no-side-by-side",
                "--json",
            )
        ]
    )
    try:
        code = args.func(args)
    except OscarError as exc:  # pragma: no cover - shows the message on failure
        pytest.fail(str(exc))
    summary = json.loads(capsys.readouterr().out)
    assert code == 0 and summary["condition"] == "latent_action" and summary["guidance"]["action_w"] is None
    assert summary["frames"] == 81 and summary["chunks"] == 10 and summary["size"] == [32, 32]
    assert read_video(out).shape == (81, 32, 32, 3)


def test_eval_run_rolls_a_latent_action_model_out_from_each_cells_actions(model, tmp_path):
    """``oscar eval run`` gives a latent-action model the actions of each cell's trajectory (not a skeleton video)."""
    from _studies import make_study

    from oscar_core.evaluation.loop import run_evaluation

    seen = record_actions(model)
    manifest = make_study(tmp_path / "study", frames=9)
    res = run_evaluation(manifest, tmp_path / "out", model=model, sampler=STEPS, log=lambda m: None)
    assert res.report["counts"]["rollouts_done"] == 6
    assert seen and all(a is not None for a in seen)
    from oscar_core.evaluation.manifest import load_manifest

    cell = load_manifest(manifest).cells[0]
    want = latent_actions(Registry().get(cell.embodiment), load_trajectory(cell.trajectory))
    assert any(np.allclose(a[0, : len(want)].numpy(), want, atol=1e-5) for a in seen)
