"""``condition_style``: a model may be trained on a condition video drawn in another look (e.g. a gripper indicator
large enough to show at a 64-px toy's latent resolution). The style is checked, drawn, recorded with cached
latents (a trainer never takes latents of another look), written into the exported card, and every rollout of
that model draws its condition as training did."""

import json

import numpy as np
import pytest
import torch

import oscar_zoo
from oscar_core.camera import load_camera
from oscar_core.cli import main
from oscar_core.errors import OscarError
from oscar_core.kinematics.trajectory import load_trajectory
from oscar_core.model.tiny import build_tiny_vae
from oscar_core.model.vae import VideoVAE
from oscar_core.model.world_model import ModelCard
from oscar_core.plugin.registry import Registry
from oscar_core.render.conditions import condition_key, condition_style, condition_video
from oscar_core.render.raster import SkeletonStyle
from oscar_core.render.skeleton_video import render_skeleton_video
from oscar_core.train.cache import cache_latents
from oscar_core.train.clips import ClipSet
from oscar_core.train.config import TrainConfigError, config_from_dict
from oscar_core.train.data import TrainData
from oscar_core.train.loop import train
from oscar_core.train.synthetic import write_toy_clipset

pytestmark = [
    pytest.mark.filterwarnings("ignore:no prompt embedding:UserWarning"),
    pytest.mark.usefixtures("one_thread"),
]  # tests/conftest.py

BOLD = {"gripper_radius_open": 27, "gripper_radius_closed": 14}


def test_a_style_is_a_mapping_of_style_fields():
    assert condition_style(None) is None
    assert condition_style(BOLD) == SkeletonStyle(gripper_radius_open=27, gripper_radius_closed=14)
    assert condition_style({"gripper_color_open": [0, 0, 255]}).gripper_color_open == (0, 0, 255)
    assert condition_key("skeleton") == condition_key("skeleton", {}) == "skeleton"
    assert condition_key("skeleton", BOLD) == condition_key("skeleton", dict(reversed(BOLD.items())))
    assert condition_key("skeleton", BOLD) != condition_key("skeleton", {"gripper_radius_open": 28})


@pytest.mark.parametrize(
    "bad, message",
    [
        ({"gripper_size": 3}, r"condition_style: expected keys among .*found unknown keys \['gripper_size'\]"),
        ({"gripper_radius_open": 0}, r"condition_style.gripper_radius_open: expected a finite number > 0, found 0"),
        ({"line_width": -1}, r"condition_style.line_width: expected a finite number >= 0, found -1"),
        ({"point_radius": float("nan")}, r"condition_style.point_radius: expected a finite number >= 0"),
        ({"gripper_radius_closed": True}, r"gripper_radius_closed: expected a finite number > 0, found True"),
        ({"gripper_color_closed": [255, 0]}, r"gripper_color_closed: expected three integers in \[0, 255\]"),
        ({"antialias": "yes"}, r"condition_style.antialias: expected true or false, found 'yes'"),
        ([1, 2], r"condition_style: expected a mapping of SkeletonStyle fields"),
    ],
)
def test_a_bad_style_is_refused_with_its_key(bad, message):
    with pytest.raises(OscarError, match=message):
        condition_style(bad)
    with pytest.raises((TrainConfigError, OscarError), match="condition_style"):
        config_from_dict({"run_dir": "r", "data": {"clips": ["c"]}, "condition_style": bad})
    with pytest.raises(OscarError, match="condition_style"):
        ModelCard(condition_style=bad)


def test_the_condition_video_is_drawn_in_the_style():
    emb = Registry().get("toyarm")
    traj = load_trajectory(emb.example_trajectory).time_slice(0, 9)
    cam = load_camera(emb.example_camera)
    bold = condition_video("skeleton", emb, traj, cam, (64, 64), style=BOLD)
    want = render_skeleton_video(emb, traj, cam, (64, 64), style=SkeletonStyle(**BOLD))
    np.testing.assert_array_equal(bold, want)
    plain = condition_video("skeleton", emb, traj, cam, (64, 64))
    np.testing.assert_array_equal(plain, render_skeleton_video(emb, traj, cam, (64, 64)))
    # the indicator's disc at 64 px: radius 27·64/288 = 6 px instead of 2 px: about π(6² − 2²) ≈ 100 more pixels
    changed = (bold != plain).any(-1).sum((1, 2))
    assert (changed > 60).all(), changed


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    return write_toy_clipset(tmp_path_factory.mktemp("style") / "toy", clips=2, frames=9, width=32, height=32)


def _vae():
    return VideoVAE(build_tiny_vae(0))


def _config(clips, run_dir, **over):
    d = {
        "run_dir": str(run_dir),
        "steps": 2,
        "batch_size": 1,
        "micro_batch": 1,
        "save_every": 2,
        "export": True,
        "model": {"transformer": "tiny", "vae": "tiny"},
        "data": {"clips": [str(clips)], "window": 9, "width": 32, "height": 32, "skeleton_dropout": 0.0},
        **over,
    }
    return config_from_dict(d)


def test_cached_latents_record_their_style_and_a_trainer_takes_only_its_own(tmp_path, source):
    vae = _vae()
    cache_latents(source, tmp_path / "bold", vae, window=9, log=lambda m: None, condition_style=BOLD)
    cache_latents(source, tmp_path / "plain", vae, window=9, log=lambda m: None)
    bold_print = json.loads((tmp_path / "bold" / "fingerprint.json").read_text())
    plain_print = json.loads((tmp_path / "plain" / "fingerprint.json").read_text())
    assert bold_print["parts"]["condition_style"] == BOLD and "condition_style" not in plain_print["parts"]
    emb = Registry().get("toyarm")
    rec = next(iter(ClipSet(source)))
    clip = ClipSet(source).load(rec, registry=Registry())
    want = {}
    for name, style in (("bold", SkeletonStyle(**BOLD)), ("plain", None)):
        video = render_skeleton_video(emb, clip.trajectory, clip.camera, (32, 32), style=style)
        want[name] = vae.encode(vae.to_pixels(video))[0]
        cached = ClipSet(tmp_path / name).load(rec.id).latents
        assert cached["condition"] == condition_key("skeleton", BOLD if name == "bold" else None)
        torch.testing.assert_close(cached["skeleton"][0], want[name])
    assert not torch.allclose(want["bold"], want["plain"], atol=1e-3)
    # each run gets its own look's latents: from the cache when it matches, else drawn and encoded
    for cache in ("bold", "plain"):
        for name, style in (("bold", BOLD), ("plain", None)):
            cfg = _config(tmp_path / cache, tmp_path / f"run-{cache}-{name}", condition_style=style)
            data = TrainData(cfg, vae, 48)
            item = data.planner().plan(0, 1)[0]
            torch.testing.assert_close(data.load_item(item, "skeleton")["skeleton"], want[name])


def test_the_exported_card_keeps_the_style_and_rollouts_draw_it(tmp_path, source):
    cache_latents(source, tmp_path / "bold", _vae(), window=9, log=lambda m: None, condition_style=BOLD)
    result = train(_config(tmp_path / "bold", tmp_path / "run", condition_style=BOLD), progress=False)
    model = oscar_zoo.load(result.export)
    assert model.card.condition_style == BOLD
    emb = Registry().get("toyarm")
    traj = load_trajectory(emb.example_trajectory).time_slice(0, 9)
    cam = load_camera(emb.example_camera)
    video = model.rollout_inputs(traj, cam, emb)["skeleton"]
    np.testing.assert_array_equal(video, render_skeleton_video(emb, traj, cam, (32, 32), style=SkeletonStyle(**BOLD)))
    assert not np.array_equal(video, render_skeleton_video(emb, traj, cam, (32, 32)))
    model.save_pretrained(tmp_path / "again")
    assert oscar_zoo.load(tmp_path / "again").card.condition_style == BOLD
    # a student is distilled in its teacher's look
    student = {"model": {"transformer": "tiny", "vae": "tiny", "init": str(result.export)}}
    student["distill"] = {"teacher": str(result.export)}
    with pytest.raises(
        TrainConfigError, match=r"'condition_style': expected the teacher's condition_style \{.*found None"
    ):
        train(_config(tmp_path / "bold", tmp_path / "student", **student), progress=False)
    assert not (tmp_path / "student").exists()


def test_the_cache_command_takes_a_json_style_and_refuses_a_bad_one(tmp_path, source, capsys):
    vae_dir = tmp_path / "vae"
    _vae().vae.save_pretrained(vae_dir, safe_serialization=True)
    base = ["train", "--cache-latents", str(source), "--vae", str(vae_dir), "--window", "9", "--threads", "1"]
    assert main([*base, "--out", str(tmp_path / "ok"), "--condition-style", json.dumps(BOLD), "--json"]) == 0
    assert ClipSet(tmp_path / "ok").load("toy-0").latents["condition"] == condition_key("skeleton", BOLD)
    for bad in ('{"gripper_radius_open": -2}', "{not json", '{"size": 1}'):
        assert main([*base, "--out", str(tmp_path / "bad"), "--condition-style", bad]) == 2
        assert "--condition-style" in capsys.readouterr().err
        assert not (tmp_path / "bad").exists()


def test_a_style_with_another_condition_is_refused_before_the_cache_writes(tmp_path, source):
    # a style draws the skeleton; mesh and capsules have their own looks (the renderer would get the wrong style)
    with pytest.raises(OscarError, match="expected the skeleton condition .*found condition 'capsules'"):
        cache_latents(source, tmp_path / "c", _vae(), window=9, log=lambda m: None, condition="capsules",
                      condition_style=BOLD)  # fmt: skip
    assert not (tmp_path / "c").exists()
