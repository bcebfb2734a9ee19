"""The ``capsules`` condition (oscar_core/render/capsules.py): capsules along the skeleton's edges and fingers.

Checked against answers known in advance: every vertex lies on its capsule's surface (distance r from the
segment), the finger gap follows the openness formula, the silhouette equals the toy world's own analytic
capsule raster (a second implementation of the same bodies), frames are independent of the chunking, and the
CLI, the trainer's cache and the rollout pick the condition up by name.
"""

import numpy as np
import pytest
import torch

from oscar_core.errors import PluginError
from oscar_core.plugin.embodiment import SkeletonFrames
from oscar_core.plugin.registry import Registry
from oscar_core.render.capsules import (
    RADIUS_BASE,
    RADIUS_TIP,
    CapsuleStyle,
    body_reach,
    body_vertices,
    finger_axes,
    link_radii,
    render_capsule_video,
)
from oscar_core.render.conditions import CONDITIONS, condition_video, video_condition_of
from oscar_core.toyworld.episode import episode_rng, make_episode, render_world


def _segment_distance(p, a, b):
    d = b - a
    t = np.clip(((p - a) @ d) / max(d @ d, 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * d), axis=1)


def test_radii_taper_from_base_to_tip_of_the_reach():
    r = link_radii(5, 2.0)
    assert r[0] == pytest.approx(RADIUS_BASE * 2.0) and r[-1] == pytest.approx(RADIUS_TIP * 2.0)
    assert np.all(np.diff(r) < 0)
    assert link_radii(1, 1.0).tolist() == [RADIUS_BASE] and len(link_radii(0, 1.0)) == 0


def test_every_vertex_lies_on_its_capsule_surface():
    rng = np.random.default_rng(3)
    T = 4
    pts = rng.normal(size=(T, 3, 3))
    pts[1, 2] = pts[1, 1] + [0, 0, 1.0]  # an edge along world z (the helper-axis switch)
    pts[2, 2] = pts[2, 1]  # a zero-length edge: a sphere
    fr = SkeletonFrames(pts, np.zeros((T, 0, 3)), np.zeros((T, 0)))
    edges = np.array([[0, 1], [1, 2]])
    world, faces, part = body_vertices(fr, edges, 1.0, CapsuleStyle(segments=8))
    radii = link_radii(2, 1.0)
    n = world.shape[1] // 2
    assert (part[: len(faces) // 2] == 0).all() and (part[len(faces) // 2 :] == 1).all()
    for t in range(T):
        for e, (i, j) in enumerate(edges):
            v = world[t, e * n : (e + 1) * n]
            np.testing.assert_allclose(_segment_distance(v, pts[t, i], pts[t, j]), radii[e], rtol=0, atol=1e-9)
    # closed and wound outward: the signed volume of each capsule is positive
    v = world[0, :n]
    f = faces[: len(faces) // 2]
    vol = np.einsum("fi,fi->f", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6
    L = np.linalg.norm(pts[0, 1] - pts[0, 0])
    exact = np.pi * radii[0] ** 2 * L + 4 / 3 * np.pi * radii[0] ** 3
    assert 0.7 * exact < vol < exact  # a polygonal capsule inside the round one


def test_the_finger_gap_follows_the_openness():
    T = 3
    pts = np.array([[[0, 0, 0], [0, 0, 1.0], [1.0, 0, 1.0]]] * T)
    grip = pts[:, 2] + [0.1, 0, 0]
    openness = np.array([[0.0], [0.5], [1.0]])
    fr = SkeletonFrames(pts, grip[:, None], openness)
    world, faces, part = body_vertices(fr, np.array([[0, 1], [1, 2]]), 1.0, CapsuleStyle(segments=8))
    r_tip = link_radii(2, 1.0)[-1]
    axis = finger_axes(pts, grip, 2 * r_tip)
    np.testing.assert_allclose(axis, [[1.0, 0, 0]] * T)  # from the last skeleton point to the indicator
    n = world.shape[1] // 4  # two edges, two fingers, same capsule each
    for t in range(T):
        a, b = world[t, 2 * n : 3 * n].mean(0), world[t, 3 * n :].mean(0)  # finger centres
        gap = np.linalg.norm(a - b)
        assert gap == pytest.approx(2 * r_tip * (0.5 + 1.5 * openness[t, 0]), abs=1e-9)
    assert set(part.tolist()) == {0, 1, 2}  # both fingers are the gripper's part


@pytest.fixture(scope="module")
def registry():
    return Registry()


@pytest.mark.parametrize("name", ["toyarm", "kuka"])
def test_the_silhouette_is_the_toy_worlds_own_capsules(registry, name):
    """The toy world draws the same capsules with its own analytic raster: the silhouettes agree."""
    emb = registry.get(name)
    ep = make_episode(emb, episode_rng(0, name, 9), 128, 128, 9)
    world = render_world(emb, ep.motion, ep.scene, ep.camera, ss=1)
    E = len(emb.edges)
    truth = (world.label >= 0) & (world.label < E)  # the links
    judged = world.label < E  # pixels where the ball or the marker is in front say nothing about the links

    def iou(reach):
        ours = render_capsule_video(
            emb, ep.trajectory, ep.camera, style=CapsuleStyle(reach=reach, fingers=False, segments=16)
        ).any(-1)
        return (truth & ours & judged).sum() / ((truth | ours) & judged).sum()

    same = iou(ep.motion.scale)
    assert same > 0.9, same
    # a body of the wrong size does not match as well: the check can fail
    assert iou(1.6 * ep.motion.scale) < same - 0.1


def test_body_reach_is_the_toy_worlds_reach(registry):
    for name in ("toyarm", "franka"):
        emb = registry.get(name)
        scales = [make_episode(emb, episode_rng(0, name, i), 32, 32, 9).motion.scale for i in range(3)]
        assert body_reach(emb) == pytest.approx(np.mean(scales), rel=0.05)


def test_a_frame_alone_equals_the_same_frame_in_a_video(registry):
    emb = registry.get("franka")
    ep = make_episode(emb, episode_rng(0, "franka", 1), 48, 40, 9)
    video = render_capsule_video(emb, ep.trajectory, ep.camera, chunk_frames=4)
    for t in (0, 5, 8):
        alone = render_capsule_video(emb, ep.trajectory.time_slice(t, t + 1), ep.camera.time_slice(t, t + 1))
        np.testing.assert_array_equal(alone[0], video[t])
    assert video.any(axis=(1, 2, 3)).all()


def test_the_condition_is_known_by_name_everywhere(registry):
    assert "capsules" in CONDITIONS and video_condition_of("capsules") == "capsules"
    assert video_condition_of("latent_action") == "skeleton"
    emb = registry.get("kuka")  # no visual geometry: no mesh, but capsules
    ep = make_episode(emb, episode_rng(0, "kuka", 2), 32, 32, 5)
    with pytest.raises(PluginError, match="no visual geometry"):
        condition_video("mesh", emb, ep.trajectory, ep.camera, (32, 32))
    v = condition_video("capsules", emb, ep.trajectory, ep.camera, (32, 32))
    assert v.shape == (5, 32, 32, 3) and v.any()


def test_render_cli_draws_capsules_for_a_robot_without_meshes(tmp_path, registry):
    from oscar_core.camera import save_camera
    from oscar_core.kinematics.trajectory import save_trajectory

    emb = registry.get("kuka")
    ep = make_episode(emb, episode_rng(0, "kuka", 3), 48, 48, 5)
    save_trajectory(ep.trajectory, tmp_path / "t.npz")
    save_camera(ep.camera, tmp_path / "c.json")
    out = tmp_path / "caps.mkv"
    from oscar_core.cli import main

    code = main(
        [
            "render",
            "--embodiment",
            "kuka",
            "--trajectory",
            str(tmp_path / "t.npz"),
            "--camera",
            str(tmp_path / "c.json"),
            "--out",
            str(out),
            "--condition",
            "capsules",
        ]
    )
    assert code == 0
    from oscar_core.media.video import read_video

    got = read_video(out)
    np.testing.assert_array_equal(got, render_capsule_video(emb, ep.trajectory, ep.camera))


def test_a_capsule_cache_holds_capsule_latents_and_a_capsule_run_uses_them(tmp_path):
    from _models import tiny_train_config

    from oscar_core.train.cache import cache_latents
    from oscar_core.train.clips import ClipSet
    from oscar_core.train.data import TrainData
    from oscar_core.train.models import build_vae
    from oscar_core.train.synthetic import write_toy_clipset

    src = write_toy_clipset(tmp_path / "src", clips=2, frames=9, width=32, height=32, prompt_dim=48)
    cfg0 = tiny_train_config(src, tmp_path / "run0", steps=1, batch_size=1)
    vae = build_vae(cfg0)
    reg = Registry()
    cache_latents(src, tmp_path / "caps", vae, 9, registry=reg, condition="capsules", log=lambda m: None)
    cache_latents(src, tmp_path / "skel", vae, 9, registry=reg, log=lambda m: None)
    cs = ClipSet(tmp_path / "caps")
    rec = next(iter(cs))
    clip = cs.load(rec, registry=reg)
    assert clip.latents["condition"] == "capsules"
    caps = render_capsule_video(reg.get(rec.embodiment), clip.trajectory, clip.camera, (32, 32))
    assert torch.allclose(clip.latents["skeleton"][0], vae.encode(vae.to_pixels(caps))[0], atol=1e-5)
    assert ClipSet(tmp_path / "skel").load(rec.id, registry=reg).latents["condition"] == "skeleton"
    # a capsule run reads the capsule latents from the cache; on the skeleton cache it renders and encodes them
    for cached in ("caps", "skel"):
        cfg = tiny_train_config(
            tmp_path / cached,
            tmp_path / f"run-{cached}",
            steps=1,
            batch_size=1,
            condition="capsules",
            **{"data.skeleton_dropout": 0.0},
        )
        data = TrainData(cfg, vae, 48)
        item = data.planner().plan(0, 1)[0]
        got = data.load_item(item, "capsules")["skeleton"]
        r = data.clips[item.clip].record
        c = ClipSet(tmp_path / cached).load(r.id, start=item.start, frames=9, registry=reg)
        want = vae.encode(vae.to_pixels(render_capsule_video(reg.get(r.embodiment), c.trajectory, c.camera, (32, 32))))[
            0
        ]
        assert torch.allclose(got, want, atol=1e-5), cached


def test_a_capsules_model_exports_its_condition_and_rolls_out_through_the_clis(tmp_path, capsys):
    """A capsules run exports ``condition: capsules``; ``oscar toyworld rollout`` and ``oscar eval benchmark run``
    hand it the capsule video of each clip."""
    import json

    from _models import tiny_train_config

    import oscar_zoo
    from oscar_core.cli import main
    from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
    from oscar_core.train.cache import cache_latents
    from oscar_core.train.clips import ClipSet
    from oscar_core.train.loop import train
    from oscar_core.train.models import build_vae

    reg = Registry()
    clips = tmp_path / "clips"
    generate_clipset(GenerateConfig(("toyarm",), 10, width=32, height=32, frames=9, seed=0), clips, reg)
    cfg = tiny_train_config(
        clips, tmp_path / "run", steps=2, export=True, condition="capsules", **{"data.latents": "on_the_fly"}
    )
    cache = tmp_path / "cached"
    cache_latents(clips, cache, build_vae(cfg), 9, registry=reg, condition="capsules", log=lambda m: None)
    cfg = tiny_train_config(cache, tmp_path / "run", steps=2, export=True, condition="capsules")
    result = train(cfg, progress=False)
    model = oscar_zoo.load(result.export)
    assert model.card.condition == "capsules"
    cs = ClipSet(clips)
    rec = next(r for r in cs if r.meta["split"] == "heldout")
    clip = cs.load(rec, registry=reg)
    want = render_capsule_video(reg.get("toyarm"), clip.trajectory, clip.camera, (32, 32))
    got = model.rollout_inputs(clip.trajectory, clip.camera, reg.get("toyarm"), (32, 32))["skeleton"]
    np.testing.assert_array_equal(got, want)
    out = tmp_path / "preds"
    assert (
        main(["toyworld", "rollout", str(clips), "--model", str(result.export), "--steps", "1", "--out", str(out)]) == 0
    )
    video = np.load(out / f"{rec.id}.npy")
    assert video.shape == (9, 32, 32, 3)
    fp = json.loads((out / "fingerprint.json").read_text())
    assert "capsules" in json.dumps(fp)
    assert (
        main(
            [
                "eval",
                "benchmark",
                "build",
                str(clips),
                "--out",
                str(tmp_path / "b.json"),
                "--total",
                "1",
                "--frames",
                "9",
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "eval",
                "benchmark",
                "run",
                str(tmp_path / "b.json"),
                "--model",
                str(result.export),
                "--steps",
                "1",
                "--out",
                str(tmp_path / "bp"),
            ]
        )
        == 0
    )
    assert len(list((tmp_path / "bp").glob("*.npy"))) == 1


def test_a_latent_cache_rerun_with_another_condition_or_vae_is_refused(tmp_path):
    """cache_latents fingerprints its output: a changed condition or other VAE weights into the same folder are
    refused, naming what changed, instead of keeping the finished shards of the other kind."""
    from _models import tiny_train_config

    from oscar_core._util.stage import StageChanged
    from oscar_core.train.cache import cache_latents
    from oscar_core.train.models import build_vae
    from oscar_core.train.synthetic import write_toy_clipset

    src = write_toy_clipset(tmp_path / "src", clips=2, frames=9, width=32, height=32, prompt_dim=48)
    vae = build_vae(tiny_train_config(src, tmp_path / "r", steps=1))
    reg = Registry()
    first = cache_latents(src, tmp_path / "c", vae, 9, registry=reg, log=lambda m: None)
    again = cache_latents(src, tmp_path / "c", vae, 9, registry=reg, log=lambda m: None)
    assert first.shards_written > 0 and again.shards_written == 0 and again.shards_kept == first.shards_written
    with pytest.raises(StageChanged, match="condition"):
        cache_latents(src, tmp_path / "c", vae, 9, registry=reg, condition="capsules", log=lambda m: None)
    with torch.no_grad():
        next(vae.vae.parameters()).add_(1.0)  # same config, other weights
    with pytest.raises(StageChanged, match="vae_weights"):
        cache_latents(src, tmp_path / "c", vae, 9, registry=reg, log=lambda m: None)
