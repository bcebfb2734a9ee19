"""The toy world: determinism, the object rule, arm pixels on the skeleton's capsules, any plugin, the eval table."""

from __future__ import annotations

import json
import shutil
import textwrap

import numpy as np
import pytest

from oscar_core.cli import main
from oscar_core.plugin.registry import Registry, default_registry
from oscar_core.render.skeleton_video import project_skeleton
from oscar_core.toyworld.episode import episode_rng, link_radii, make_episode, render_world
from oscar_core.toyworld.evaluate import evaluate_clip, evaluate_conditions
from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
from oscar_core.toyworld.locate import EE_TARGET, OBJECT_TARGET, locate, position_errors
from oscar_core.toyworld.motion import ToyWorldError, carry_object, joint_limits, min_jerk, sample_motion
from oscar_core.train.clips import ClipSet

REG = default_registry()


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)  # FK of a few hundred poses: threads only add overhead here
    yield
    torch.set_num_threads(n)


def episode(name="franka", i=0, seed=0, size=(48, 40), frames=9, ss=2):
    return make_episode(REG.get(name), episode_rng(seed, name, i), size[0], size[1], frames, ss=ss)


# ------------------------------------------------------------------ determinism


def test_episode_is_a_function_of_seed_embodiment_and_index():
    a, b = episode(i=3), episode(i=3)
    np.testing.assert_array_equal(a.rgb, b.rgb)
    np.testing.assert_array_equal(a.trajectory.q, b.trajectory.q)
    np.testing.assert_array_equal(a.camera.extrinsic, b.camera.extrinsic)
    assert a.ground_truth() == b.ground_truth()
    c, d = episode(i=4), episode(i=3, seed=1)
    assert not np.array_equal(a.trajectory.q, c.trajectory.q)
    assert not np.array_equal(a.trajectory.q, d.trajectory.q)


def test_generate_is_deterministic_and_resumes_by_shard(tmp_path):
    cfg = GenerateConfig(("toyarm",), episodes=3, width=32, height=32, frames=5, seed=7, shard_size=2)
    generate_clipset(cfg, tmp_path / "a", REG)
    messages = []
    s = generate_clipset(cfg, tmp_path / "b", REG, progress=messages.append)
    assert s["episodes_written"] == 3
    assert messages == ["shard-toyarm-000000: 2 episodes written", "shard-toyarm-000001: 1 episode written"]

    def index(root):
        return sorted((p.relative_to(root).as_posix(), p.read_text()) for p in root.glob("shard-*/clips.jsonl"))

    assert index(tmp_path / "a") == index(tmp_path / "b")
    # kill one shard (and leave a stale temporary folder): a re-run rebuilds just that shard, identically
    shutil.rmtree(tmp_path / "b" / "shard-toyarm-000001")
    (tmp_path / "b" / ".shard-toyarm-000001.x.tmp").mkdir()
    messages = []
    s = generate_clipset(cfg, tmp_path / "b", REG, progress=messages.append)
    assert (s["episodes_written"], s["episodes_skipped"]) == (1, 2)
    # each shard's line counts its own episodes, not the run's so far
    assert messages == ["shard-toyarm-000000: 2 episodes already there", "shard-toyarm-000001: 1 episode written"]
    assert not list((tmp_path / "b").glob(".shard-*"))
    assert index(tmp_path / "a") == index(tmp_path / "b")
    A, B = ClipSet(tmp_path / "a"), ClipSet(tmp_path / "b")
    for r in A:
        ca, cb = A.load(r), B.load(r.id)
        np.testing.assert_array_equal(ca.rgb, cb.rgb)  # FFV1: lossless, so frames compare exactly
        np.testing.assert_array_equal(ca.skeleton, cb.skeleton)
        np.testing.assert_array_equal(ca.trajectory.q, cb.trajectory.q)
        assert r.source == "toyworld" and r.n_frames == 5 and (r.width, r.height) == (32, 32)
        gt = r.meta["toyworld"]
        assert len(gt["ee_px"]) == len(gt["object_px"]) == len(gt["attached"]) == 5
        assert r.meta["split"] in ("train", "heldout")


# ------------------------------------------------------------------ motions


def test_min_jerk_hits_keys_and_stays_between_them():
    keys = np.array([[0.0, 1.0], [1.0, -1.0], [1.0, -1.0], [2.0, 0.0]])
    q = min_jerk(keys, np.array([0, 4, 6, 10]), 11)
    np.testing.assert_allclose(q[[0, 4, 6, 10]], keys)
    np.testing.assert_allclose(q[5], keys[1])  # a hold stays put
    assert np.all(np.diff(q[:5, 0]) >= 0) and np.all(np.diff(q[:5, 1]) <= 0)  # monotone within a segment


@pytest.mark.parametrize("name", ["toyarm", "franka", "kuka", "hsr", "agibot_g1"])
def test_motions_stay_inside_urdf_limits_and_in_view(name):
    emb = REG.get(name)
    lo, hi = joint_limits(emb, shrink=0.0)
    for i in range(2):
        ep = make_episode(emb, episode_rng(0, name, i), 40, 32, 9, ss=1)
        q = ep.trajectory.q
        assert np.all(q >= lo - 1e-9) and np.all(q <= hi + 1e-9)
        emb.check_trajectory(ep.trajectory)  # raw gripper signals inside the documented range
        proj = project_skeleton(emb, ep.trajectory, ep.camera)
        u, v = proj.uv[..., 0], proj.uv[..., 1]
        assert proj.usable.all() and (u >= 0).all() and (u <= 39).all() and (v >= 0).all() and (v <= 31).all()
        assert ep.camera.is_static


def test_carry_rule_attaches_only_on_a_close_within_reach_and_drops_on_open():
    R, reach = 0.05, 0.11
    T = 8
    ee = np.array(
        [
            [0.5, 0.0, 0.5],
            [0.3, 0.0, 0.3],
            [0.1, 0.0, 0.1],
            [0.0, 0.0, 0.1],
            [0.0, 0.0, 0.1],
            [0.1, 0.2, 0.4],
            [0.2, 0.3, 0.5],
            [0.3, 0.3, 0.5],
        ]
    )
    start = np.array([0.0, 0.0, R])
    # closes at frame 3, 5 cm above the ball's centre: attached until it opens at frame 6
    op = np.array([1, 1, 1, 0, 0, 0, 1, 1], dtype=float)
    pos, att = carry_object(ee, op, start, R, reach)
    assert att.tolist() == [False, False, False, True, True, True, False, False]
    np.testing.assert_allclose(pos[:4], np.repeat(start[None], 4, 0))
    np.testing.assert_allclose(pos[5], ee[5] + (start - ee[3]))  # keeps its offset from the end-effector
    np.testing.assert_allclose(pos[6], [ee[5, 0], ee[5, 1] + 0.0, R])  # released: falls straight down
    np.testing.assert_allclose(pos[7], pos[6])
    # closing out of reach (frame 1) and then moving over the ball while closed: never attached
    op2 = np.array([1, 0, 0, 0, 0, 0, 0, 0], dtype=float)
    pos2, att2 = carry_object(ee, op2, start, R, reach)
    assert not att2.any()
    np.testing.assert_allclose(pos2, np.repeat(start[None], T, 0))
    # closing at the same place but with a shorter reach: not attached
    _, att3 = carry_object(ee, op, start, R, 0.04)
    assert not att3.any()


def test_pick_and_place_episodes_carry_the_ball():
    kinds = []
    for i in range(6):
        ep = episode("toyarm", i, frames=17)
        m = ep.motion
        kinds.append(m.kind)
        if m.kind == "pick_place":
            att = np.flatnonzero(m.attached)
            assert len(att) >= 3
            offset = m.object[att] - m.ee[att]
            np.testing.assert_allclose(offset, np.repeat(offset[:1], len(att), 0), atol=1e-9)
            assert np.linalg.norm(m.object[-1, :2] - m.object[0, :2]) > 0.1 * m.scale  # it moved somewhere else
            assert m.object[-1, 2] == pytest.approx(m.object_radius)  # and was put down on the floor
    assert "pick_place" in kinds


def test_hands_are_rejected_by_name():
    with pytest.raises(ToyWorldError, match=r"'mano'.*keypoints.*kinematic-tree"):
        sample_motion(REG.get("mano"), np.random.default_rng(0), 9)


# ------------------------------------------------------------------ rendering


def _segment_distance(px, a, b):
    d = b - a
    dd = float(d @ d)
    t = np.clip(((px - a) @ d) / dd, 0, 1) if dd > 0 else np.zeros(len(px))
    return np.linalg.norm(px - (a + t[:, None] * d), axis=1)


@pytest.mark.parametrize("name", ["toyarm", "kuka"])
def test_every_arm_pixel_lies_on_a_capsule_of_the_rendered_skeleton(name):
    emb = REG.get(name)
    ep = make_episode(emb, episode_rng(1, name, 0), 64, 48, 9, ss=1)
    # the skeleton renderer's own projection (oscar_core.render.skeleton_video), not the toy renderer's
    proj = project_skeleton(emb, ep.trajectory, ep.camera)
    edges = emb.edge_index()
    radii = link_radii(len(edges), ep.motion.scale)
    M = ep.camera.world_to_cv()
    depth = ep.motion.points @ M[2, :3] + M[2, 3]  # along the optical axis, metres
    bare = render_world(emb, ep.motion, ep.scene, ep.camera, ss=1, draw_robot=False)
    label = ep.render.label
    E = len(edges)
    for t in range(len(ep.rgb)):
        changed = np.any(ep.rgb[t] != bare.rgb[t], axis=-1)
        arm = (label[t] >= 0) & (label[t] < E)
        marker = label[t] == E + 1
        # the robot changes exactly the pixels it covers (capsules and the end-effector marker)
        np.testing.assert_array_equal(changed, arm | marker)
        assert arm.sum() > 0
        ys, xs = np.nonzero(arm)
        px = np.stack([xs, ys], 1).astype(float)
        for e, (a, b) in enumerate(edges):
            sel = label[t][ys, xs] == e
            if not sel.any():
                continue
            dist = _segment_distance(px[sel], proj.uv[t, a], proj.uv[t, b])
            r_px = radii[e] * ep.camera.intrinsics.fx / min(depth[t, a], depth[t, b]) * 1.05
            assert dist.max() <= r_px + 1e-6, (t, e, dist.max(), r_px)


def test_supersampled_frames_change_only_near_the_robot():
    ep = episode("franka", 2, size=(48, 40), frames=5, ss=2)
    bare = render_world(REG.get("franka"), ep.motion, ep.scene, ep.camera, ss=2, draw_robot=False)
    import cv2

    E = len(REG.get("franka").edges)
    for t in range(len(ep.rgb)):
        robot = ((ep.render.label[t] >= 0) & (ep.render.label[t] != E)).astype(np.uint8)
        covered = robot.reshape(40, 2, 48, 2).max(axis=(1, 3))  # output pixels the robot touches at all
        near = cv2.dilate(covered, np.ones((3, 3), np.uint8)) > 0
        changed = np.any(ep.rgb[t] != bare.rgb[t], axis=-1)
        assert changed.any() and not (changed & ~near).any()


# ------------------------------------------------------------------ locating and the table


def test_locate_finds_a_blob_centroid_and_ignores_everything_else():
    f = np.full((2, 20, 30, 3), 128, np.uint8)
    f[0, 4:7, 10:14] = (255, 0, 255)  # magenta: the end-effector marker
    f[0, 12:15, 2:4] = (255, 209, 0)  # yellow: the object
    f[0, 0:3, 0:3] = (0, 90, 255)  # a blue link
    pos, n = locate(f, EE_TARGET)
    np.testing.assert_allclose(pos[0], [11.5, 5.0])
    assert n[0] == 12 and np.isnan(pos[1]).all()
    pos, _ = locate(f, OBJECT_TARGET)
    np.testing.assert_allclose(pos[0], [2.5, 13.0])


def test_rendered_targets_are_found_where_they_were_projected():
    errs = {"ee": [], "object": []}
    for i in range(4):
        ep = episode("kuka", i, size=(64, 64), frames=9)
        gt = ep.ground_truth()
        for key, target in (("ee", EE_TARGET), ("object", OBJECT_TARGET)):
            pos, _ = locate(ep.rgb, target)
            ok = np.isfinite(pos[:, 0]) & (np.array(gt[f"{key}_area"]) >= 3)
            errs[key] += list(np.linalg.norm(pos[ok] - np.array(gt[f"{key}_px"])[ok], axis=1))
    for key, e in errs.items():
        assert len(e) > 10 and np.median(e) < 1.0 and np.max(e) < 3.0, (key, np.median(e), np.max(e))


@pytest.fixture(scope="module")
def small_set(tmp_path_factory):
    root = tmp_path_factory.mktemp("toy") / "clips"
    generate_clipset(GenerateConfig(("kuka", "franka"), episodes=2, width=48, height=48, frames=5, seed=3), root, REG)
    return ClipSet(root)


def test_eval_scores_ground_truth_against_itself_perfectly_and_a_shift_by_its_size(tmp_path, small_set):
    same, shifted = tmp_path / "same", tmp_path / "shift"
    same.mkdir(), shifted.mkdir()
    expected = {}
    for r in small_set:
        rgb = small_set.load(r, skeleton=False).rgb
        np.save(same / f"{r.id}.npy", rgb)
        np.save(shifted / f"{r.id}.npy", np.roll(rgb, 3, axis=2))  # 3 px to the right (wrapping around)
        m = evaluate_clip(np.roll(rgb, 3, axis=2), rgb)
        gp, _ = locate(rgb, EE_TARGET)
        pp, _ = locate(np.roll(rgb, 3, axis=2), EE_TARGET)
        intact = np.isfinite(gp[:, 0]) & (gp[:, 0] < 48 - 6)  # blobs that did not wrap
        np.testing.assert_allclose(np.linalg.norm(pp - gp, axis=1)[intact], 3.0, atol=1e-9)
        expected[r.id] = m
    table = evaluate_conditions(small_set, {"same": str(same), "shifted": str(shifted)})
    row = table["rows"]["same"]
    assert row["clips"] == len(small_set)
    assert row["psnr_db"] == 100.0 and row["ssim"] == pytest.approx(1.0)
    assert row["ee_error_px"] == 0.0 and row["object_error_px"] == 0.0
    assert row["moved_object_error_px"] == 0.0 if row["moved_object_clips"] else np.isnan(row["moved_object_error_px"])
    sh = table["rows"]["shifted"]
    assert sh["psnr_db"] < 40 and sh["ssim"] < 0.99
    assert 2.5 < sh["object_error_px"] < 3.5 and 2.5 < sh["ee_error_px"] < 3.5
    np.testing.assert_equal(table["clips"]["shifted"], expected)  # NaN == NaN: a ball that never moves


def test_moved_object_error_counts_only_frames_where_the_true_ball_moved():
    from oscar_core.toyworld.evaluate import moved_object_error

    gt = np.full((5, 20, 20, 3), 100, np.uint8)
    xs = [4, 4, 8, 12, 16]  # the ball lies still for a frame, then is carried 4 px per frame
    for t, x in enumerate(xs):
        gt[t, 8:10, x : x + 2] = (255, 212, 0)
    still = np.repeat(gt[:1], 5, axis=0)  # a prediction that leaves the ball where it lay
    r = moved_object_error(still, gt)
    assert r["frames"] == 3 and r["error_px"] == pytest.approx(np.mean([4.0, 8.0, 12.0]))
    assert moved_object_error(gt, gt) == {"error_px": 0.0, "frames": 3}
    lost = gt.copy()
    lost[4] = 100
    assert moved_object_error(lost, gt)["error_px"] == pytest.approx(np.hypot(20, 20) / 3)
    r = moved_object_error(gt, still)  # a truth whose ball never moves: not counted
    assert r["frames"] == 0 and np.isnan(r["error_px"])
    r = moved_object_error(gt, gt, min_shift=4.0)  # "more than": a 4 px shift is not a move at 4 px
    assert r["frames"] == 2


def test_position_errors_count_a_lost_target_as_the_diagonal():
    gt = np.full((3, 10, 10, 3), 100, np.uint8)
    gt[:, 2:4, 2:4] = (255, 0, 255)
    pred = gt.copy()
    pred[1] = 100  # the prediction lost the marker in frame 1
    r = position_errors(pred, gt, EE_TARGET)
    assert r["per_frame"].tolist() == [0.0, pytest.approx(np.hypot(10, 10)), 0.0]
    assert r["found"] == pytest.approx(2 / 3)


def test_cli_eval_writes_json_and_plot(tmp_path, small_set, capsys):
    pred = tmp_path / "pred"
    pred.mkdir()
    for r in small_set:
        np.save(pred / f"{r.id}.npy", small_set.load(r, skeleton=False).rgb)
    rc = main(
        [
            "toyworld",
            "eval",
            "--gt",
            str(small_set.root),
            "--pred",
            f"true={pred}",
            "--out",
            str(tmp_path / "t.json"),
            "--plot",
            str(tmp_path / "t.png"),
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "| true |" in out and "100.00" in out
    t = json.loads((tmp_path / "t.json").read_text())
    assert t["rows"]["true"]["ee_error_px"] == 0.0
    assert (tmp_path / "t.png").read_bytes()[:4] == b"\x89PNG"
    rc = main(["toyworld", "eval", "--gt", str(small_set.root), "--pred", f"x={tmp_path}"])
    assert rc == 2 and "found none" in capsys.readouterr().err
    # the model-free reference row: the first frame held still
    assert main(["toyworld", "baseline", str(small_set.root), "--split", "all", "--out", str(tmp_path / "ff")]) == 0
    first = np.load(tmp_path / "ff" / f"{small_set.records[0].id}.npy")
    truth = small_set.load(small_set.records[0], skeleton=False).rgb
    assert first.shape == truth.shape and (first == truth[0]).all()
    capsys.readouterr()
    assert main(["toyworld", "eval", "--gt", str(small_set.root), "--pred", f"ff={tmp_path / 'ff'}", "--json"]) == 0
    row = json.loads(capsys.readouterr().out)["rows"]["ff"]
    assert row["clips"] == len(small_set) and row["psnr_db"] < 100 and row["ee_error_px"] > 0
    # --split all means every clip, as it does to rollout and baseline (not a split named "all")
    args = ["toyworld", "eval", "--gt", str(small_set.root), "--pred", f"ff={tmp_path / 'ff'}", "--json"]
    assert main([*args, "--split", "all"]) == 0
    assert json.loads(capsys.readouterr().out)["rows"]["ff"]["clips"] == len(small_set)


# ------------------------------------------------------------------ any plugin, through the CLI

URDF = """<?xml version="1.0"?>
<robot name="stick">
  <link name="root"/><link name="a"/><link name="b"/><link name="hand"/><link name="finger"/>
  <joint name="yaw" type="revolute"><parent link="root"/><child link="a"/><origin xyz="0 0 0.2"/>
    <axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="pitch" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 1 0"/><limit lower="0.2" upper="1.8" effort="1" velocity="1"/></joint>
  <joint name="elbow" type="revolute"><parent link="b"/><child link="hand"/><origin xyz="0.35 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-0.5" upper="2.0" effort="1" velocity="1"/></joint>
  <joint name="slide" type="prismatic"><parent link="hand"/><child link="finger"/><origin xyz="0.25 0 0"/>
    <axis xyz="0 1 0"/><limit lower="0" upper="0.03" effort="1" velocity="1"/></joint>
</robot>
"""

PLUGIN = """
from oscar_core import Embodiment, Gripper, Skeleton, hookimpl

class Stick(Embodiment):
    name = "stick"
    urdf = r"{urdf}"
    skeleton = Skeleton(links=("root", "a", "b", "hand", "finger"))
    grippers = (Gripper("claw", link="hand", point=(0.25, 0.0, 0.0), signal_range=(0.0, 1.0), closed_at="high",
                        joint="slide", joint_range=(0.0, 0.03)),)

@hookimpl
def oscar_register_embodiments():
    return [Stick]
"""


def test_an_out_of_tree_one_file_plugin_generates_clips(tmp_path, capsys):
    (tmp_path / "stick.urdf").write_text(URDF)
    plugin = tmp_path / "stick_plugin.py"
    plugin.write_text(textwrap.dedent(PLUGIN.format(urdf=tmp_path / "stick.urdf")))
    out = tmp_path / "clips"
    rc = main(
        [
            "--plugin",
            str(plugin),
            "toyworld",
            "generate",
            "--embodiments",
            "stick",
            "--episodes",
            "3",
            "--size",
            "32x32",
            "--frames",
            "9",
            "--seed",
            "1",
            "--out",
            str(out),
            "--json",
        ]
    )
    assert rc == 0, capsys.readouterr().err
    summary = json.loads(capsys.readouterr().out)
    assert summary["episodes_written"] == 3
    cs = ClipSet(out)
    assert [r.embodiment for r in cs] == ["stick"] * 3
    reg = Registry(plugin_paths=[plugin])
    clip = cs.load(cs.records[0], registry=reg)
    assert clip.rgb.shape == (9, 32, 32, 3) and clip.skeleton.shape == (9, 32, 32, 3)
    assert reg.get("stick").check_trajectory(clip.trajectory) is not None


def test_cli_rejects_too_short_hand_episodes_before_writing(tmp_path, capsys):
    argv = ["toyworld", "generate", "--embodiments", "toyarm,mano", "--episodes", "1", "--frames", "7"]
    rc = main(argv + ["--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert rc == 2 and "--frames: expected at least 9 frames for a hand episode (mano), found 7" in err
    assert not (tmp_path / "x").exists()  # rejected before anything is written


# ------------------------------------------------------------------ the VAE


@pytest.mark.slow
def test_train_vae_saves_a_loadable_autoencoder_whose_numbers_agree(tmp_path):
    import torch

    from oscar_core.model import ModelCard, OscarWorldModel
    from oscar_core.model.tiny import build_tiny_transformer
    from oscar_core.model.vae import VideoVAE
    from oscar_core.toyworld.vae_train import VAETrainConfig, load_toy_vae, train_vae, write_reconstructions

    clips = tmp_path / "clips"
    generate_clipset(
        GenerateConfig(("toyarm",), episodes=10, width=16, height=16, frames=5, seed=0, shard_size=10, skeleton=False),
        clips,
        REG,
    )
    n = torch.get_num_threads()
    card = train_vae(
        clips,
        tmp_path / "vae",
        VAETrainConfig(steps=2, batch=1, base_dim=4, eval_every=0, eval_clips=1),
        log=lambda m: None,
    )
    torch.set_num_threads(n)
    assert card["steps_done"] == 2 and card["heldout_clips"] == ["toyarm-000009"]
    assert (tmp_path / "vae" / "vae" / "diffusion_pytorch_model.safetensors").is_file()
    vae = load_toy_vae(tmp_path / "vae")
    # latents_mean/std are the training latents' statistics: normalised latents are zero-mean, unit-std
    train = np.stack([ClipSet(clips).load(f"toyarm-{i:06d}", skeleton=False).rgb for i in range(9)])
    z = VideoVAE(vae).encode(VideoVAE.to_pixels(train)).transpose(0, 1).reshape(16, -1)
    np.testing.assert_allclose(z.mean(1).numpy(), 0.0, atol=1e-4)
    np.testing.assert_allclose(z.std(1).numpy(), 1.0, atol=1e-3)
    # the reconstructions scored by `oscar toyworld eval` give the PSNR the trainer reported
    ids = write_reconstructions(clips, tmp_path / "vae", tmp_path / "recon")
    table = evaluate_conditions(clips, {"vae": str(tmp_path / "recon")})
    assert ids == ["toyarm-000009"] and table["rows"]["vae"]["clips"] == 1
    # equal up to float rounding: the saved VAE normalises its latents ((z - mean) / std, then back), the
    # trainer's evaluation ran before the statistics were set
    assert table["rows"]["vae"]["psnr_db"] == pytest.approx(card["heldout_psnr_db"], abs=1e-3)
    # fine-tuning starts from the saved weights (same architecture, whatever --base-dim says)
    tuned = train_vae(
        clips,
        tmp_path / "tuned",
        VAETrainConfig(steps=1, batch=1, base_dim=99, eval_every=0, eval_clips=1, init=str(tmp_path / "vae")),
        log=lambda m: None,
    )
    torch.set_num_threads(n)
    assert tuned["config"] == card["config"]
    assert tuned["evals"][0]["psnr_db"] == pytest.approx(card["heldout_psnr_db"], abs=1e-3)  # normalisation rounding
    # --residual: the Wan 2.2 variant of the same class, recorded in config.json and the card
    res = train_vae(
        clips,
        tmp_path / "res",
        VAETrainConfig(
            steps=5,
            stop_at=1,
            batch=1,
            base_dim=4,
            eval_every=0,
            eval_clips=1,
            config={"is_residual": True},
            foreground=10.0,
        ),
        log=lambda m: None,
    )
    torch.set_num_threads(n)
    assert res["config"]["is_residual"] and load_toy_vae(tmp_path / "res").config.is_residual
    assert (res["steps_done"], res["stopped_by"]) == (1, "stop_at (1)")
    assert not card["config"]["is_residual"]
    assert 0.0 <= res["heldout_chroma_ratio"] == res["evals"][-1]["chroma_ratio"]
    # and the folder is the vae/ of a world model
    model = OscarWorldModel.from_modules(build_tiny_transformer(), vae, ModelCard(name="toy", chunk_frames=5))
    model.save_pretrained(tmp_path / "model")
    again = OscarWorldModel.from_pretrained(tmp_path / "model")
    for (k, a), (_, b) in zip(vae.state_dict().items(), again.vae.vae.state_dict().items()):
        assert torch.equal(a, b), k


@pytest.mark.slow
def test_foreground_weight_changes_the_update_and_only_through_moving_pixels(tmp_path, monkeypatch):
    """--foreground adds foreground x MSE on moving pixels: with the mask forced empty the run is the plain one."""
    import torch
    from safetensors.torch import load_file

    import oscar_core.toyworld.vae_train as vt

    clips = tmp_path / "clips"
    generate_clipset(
        GenerateConfig(("toyarm",), episodes=10, width=16, height=16, frames=5, seed=0, shard_size=10, skeleton=False),
        clips,
        REG,
    )
    n = torch.get_num_threads()

    def weights(name, **kw):
        vt.train_vae(
            clips,
            tmp_path / name,
            vt.VAETrainConfig(steps=2, batch=1, base_dim=4, eval_every=0, eval_clips=1, **kw),
            log=lambda m: None,
        )
        torch.set_num_threads(n)
        return load_file(tmp_path / name / "vae" / "diffusion_pytorch_model.safetensors")

    plain, weighted = weights("plain"), weights("fg", foreground=10.0)
    assert any(not torch.equal(plain[k], weighted[k]) for k in plain)
    monkeypatch.setattr(vt, "moving_pixels", lambda x: torch.zeros_like(x[:, :1]))
    masked = weights("masked", foreground=10.0)
    assert all(torch.equal(plain[k], masked[k]) for k in plain)
    # --ball: the same rule through the ball's pixels
    ball = weights("ball", ball=50.0)
    assert any(not torch.equal(plain[k], ball[k]) for k in plain)
    monkeypatch.setattr(vt, "ball_pixels", lambda x: torch.zeros_like(x[:, :1]))
    assert all(torch.equal(plain[k], v) for k, v in weights("ball-masked", ball=50.0).items())


def _yellow_disc_frames(centres, size=16, r=2.0):
    """(T, size, size, 3) uint8: grey floor with a ball of the toy's object hue at each (x, y) centre (None: none)."""
    import colorsys

    from oscar_core.toyworld.scene import OBJECT_HUE

    rgb = np.array(colorsys.hsv_to_rgb(OBJECT_HUE / 360.0, 0.9, 0.9)) * 255
    frames = np.full((len(centres), size, size, 3), 90, np.uint8)
    ys, xs = np.mgrid[0:size, 0:size]
    for f, c in zip(frames, centres):
        if c is not None:
            f[(xs - c[0]) ** 2 + (ys - c[1]) ** 2 <= r * r] = rgb.astype(np.uint8)
    return frames


def test_ball_pixels_marks_the_ball_and_its_rim_only():
    import torch

    from oscar_core.toyworld.vae_train import ball_pixels

    frames = _yellow_disc_frames([(8, 8), None])
    x = torch.from_numpy(frames).permute(3, 0, 1, 2).unsqueeze(0).float().div(127.5).sub(1.0)
    m = ball_pixels(x)
    assert m.shape == (1, 1, 2, 16, 16)
    ys, xs = np.mgrid[0:16, 0:16]
    disc = (xs - 8) ** 2 + (ys - 8) ** 2 <= 4
    ring = np.zeros_like(disc)  # the disc grown by one pixel in each of the 8 directions (a 3 x 3 dilation)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            ring |= np.roll(np.roll(disc, dy, 0), dx, 1)
    got = m[0, 0, 0].numpy() > 0
    assert np.array_equal(got, ring)
    assert m[0, 0, 1].sum() == 0  # no ball, no weight


def test_ball_kept_counts_frames_whose_ball_is_found_near_the_truth():
    from oscar_core.toyworld.vae_train import ball_kept

    truth = _yellow_disc_frames([(5, 5), (8, 8), (10, 10), None])
    pred = _yellow_disc_frames([(5, 5), (9, 8), None, (3, 3)])  # kept, 1 px off (kept), lost; no truth ball
    assert ball_kept(pred, truth) == pytest.approx(2 / 3)
    assert ball_kept(pred, truth, tol_px=0.5) == pytest.approx(1 / 3)
    assert ball_kept(truth[3:], truth[3:]) is None


def test_false_ball_pixels_counts_the_balls_colour_outside_the_truths_ball():
    from oscar_core.toyworld.vae_train import false_ball_pixels

    truth = _yellow_disc_frames([(8, 8), (8, 8), None])
    assert false_ball_pixels(truth, truth) == 0.0
    # frame 0 exact; frame 1's ball moved 1 px (inside the truth's 1-px rim: not false); frame 2 paints a disc
    # of 13 pixels (r = 2) where the truth shows no ball
    pred = _yellow_disc_frames([(8, 8), (9, 8), (4, 4)])
    disc = int(((np.mgrid[0:16, 0:16] - np.array([4, 4])[:, None, None]) ** 2).sum(0).__le__(4).sum())
    assert disc == 13
    assert false_ball_pixels(pred, truth) == pytest.approx(disc / 3)
    # a disc two pixels off reaches past the rim by its tip alone: (12, 8) is 2 px beyond the truth's edge at
    # (10, 8), whose rim covers x = 11 for rows 7-9
    assert false_ball_pixels(_yellow_disc_frames([(10, 8)]), truth[:1]) == pytest.approx(1.0)


def test_ball_region_union_weights_the_reconstructions_own_ball_coloured_pixels(monkeypatch):
    import torch

    from oscar_core.toyworld import vae_train as vt

    truth = _yellow_disc_frames([(5, 5), (5, 5)])
    smear = _yellow_disc_frames([(5, 5), (11, 11)])  # frame 1 keeps nothing of the ball and paints one elsewhere

    def to_x(f):
        return torch.from_numpy(f).permute(3, 0, 1, 2).unsqueeze(0).float().div(127.5).sub(1.0)

    x, y = to_x(truth), to_x(smear)

    class _Fake:  # encode -> posterior (mean 0, var 1: KL 0); decode -> the fixed reconstruction y
        def encode(self, x):
            z = torch.zeros(1, 1, 1, 1, 1)
            post = type("P", (), {"mean": z, "var": z + 1, "logvar": z, "mode": lambda s: z, "sample": lambda s: z})
            return type("E", (), {"latent_dist": post()})()

        def decode(self, z):
            return type("D", (), {"sample": y})()

    err = (y - x) ** 2
    plain = torch.mean(err)

    def loss(region):
        cfg = vt.VAETrainConfig(ball=10.0, ball_region=region, kl=0.0)
        return vt._vae_loss(_Fake(), x, cfg)[0]

    truth_only = plain + 10.0 * torch.mean(vt.ball_pixels(x) * err)
    union = plain + 10.0 * torch.mean(torch.maximum(vt.ball_pixels(x), vt.ball_pixels(y)) * err)
    assert torch.allclose(loss("truth"), truth_only)
    assert torch.allclose(loss("union"), union)
    assert loss("union") > loss("truth")  # the smear at (11, 11) costs the ball weight only in the union
    with pytest.raises(ValueError, match="--ball-region: expected one of truth, union, found 'both'"):
        vt.train_vae("unused", "unused", vt.VAETrainConfig(ball_region="both"), log=lambda m: None)


def test_chroma_ratio_on_known_colours():
    from oscar_core.toyworld.vae_train import chroma_ratio

    truth = np.zeros((2, 4, 4, 3), np.uint8)
    truth[..., 0] = 200  # red: chroma (+133.3, -66.7, -66.7)
    grey = np.full_like(truth, 67)
    half = truth.copy()
    half[..., 0] = 100  # chroma (+66.7, -33.3, -33.3): half the truth's
    assert chroma_ratio(grey, truth) == 0.0
    assert chroma_ratio(truth, truth) == pytest.approx(1.0)
    assert chroma_ratio(half, truth) == pytest.approx(0.5)


def test_moving_pixels_marks_a_moving_square_and_its_rim():
    import torch

    from oscar_core.toyworld.vae_train import moving_pixels

    x = torch.full((1, 3, 5, 12, 12), -0.5)
    for t in range(5):  # a 2 x 2 square moving one pixel right per frame on row 5-6; a still 2 x 2 square at 0-1
        x[0, :, t, 5:7, 2 + t : 4 + t] = 0.8
    x[0, :, :, 0:2, 0:2] = 0.9
    x[0, 1, :, 10, 10] += torch.linspace(0, 0.05, 5)  # changes by less than the threshold: still
    m = moving_pixels(x)
    assert m.shape == (1, 1, 5, 12, 12)
    assert m[0, 0, :, 0:2, 0:2].sum() == 0 and m[0, 0, :, 10, 10].sum() == 0
    # frame 0: the square covers x 2-3; the median over time of those pixels is background, so they move
    core = torch.zeros(12, 12)
    core[5:7, 2:4] = 1
    rim = torch.nn.functional.max_pool2d(core[None, None], 3, 1, 1)[0, 0]
    assert torch.equal(m[0, 0, 0] * rim, rim)  # the square and a one-pixel rim around it
    assert m[0, 0, 0, 0:4].sum() == 0 and m[0, 0, 0, 8:].sum() == 0  # nothing beyond the rim rows


def test_motion_iou_on_known_masks():
    from oscar_core.toyworld.evaluate import motion_iou, motion_mask

    gt = np.full((3, 8, 8, 3), 50, np.uint8)
    gt[1:, 0:2, 0:4] = 200  # 8 pixels change in frames 1 and 2
    pred = np.full((3, 8, 8, 3), 50, np.uint8)
    pred[1:, 0:2, 2:6] = 200  # 8 pixels change, 4 of them where the truth changed
    assert motion_mask(gt).sum() == 16
    assert motion_iou(pred, gt) == pytest.approx(8 / 24)  # per frame 4 shared of 12 in the union
    assert motion_iou(gt, gt) == 1.0
    grey = gt.mean(-1, keepdims=True).astype(np.uint8).repeat(3, -1)
    assert motion_iou(grey, gt) == 1.0  # colour-free: a grey rendering of the same motion scores 1
    still = np.full((3, 8, 8, 3), 50, np.uint8)
    assert motion_iou(still, gt) == 0.0 and np.isnan(motion_iou(still, still))
