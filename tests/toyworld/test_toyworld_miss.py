"""Missed picks in the toy world's training data (``pick_miss``): the ball lies out of reach and stays put,
the camera still sees it, and the default (0) generates exactly what the generator wrote before the option."""

from __future__ import annotations

import numpy as np
import pytest

from oscar_core.camera import project
from oscar_core.cli import main
from oscar_core.plugin.registry import default_registry
from oscar_core.toyworld.episode import episode_rng, make_episode, miss_rng
from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
from oscar_core.toyworld.motion import (
    GRAB_RADII,
    MISS_FAR_RADII,
    MISS_NEAR_RADII,
    ToyWorldError,
    miss_start,
    sample_motion,
)
from oscar_core.train.clips import ClipSet, clip_openness

REG = default_registry()
ARMS = ("toyarm", "franka", "kuka")


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def episode(name, i, pick_miss=0.0, seed=0, size=(32, 32), frames=9):
    return make_episode(
        REG.get(name),
        episode_rng(seed, name, i),
        size[0],
        size[1],
        frames,
        ss=1,
        pick_miss=pick_miss,
        miss_rng=miss_rng(seed, name, i),
    )


def grasp_frame(name, ep) -> int:
    """The frame the gripper closes on (its openness first drops below 0.5): where the carry rule may attach."""
    op = clip_openness(REG.get(name), ep.trajectory)[:, 0]
    return int(np.flatnonzero(op < 0.5)[0])


def test_every_pick_misses_at_one_and_the_ball_stays_in_view():
    n = 0
    for name in ARMS:
        for i in range(6):
            ep = episode(name, i, pick_miss=1.0)
            m, R = ep.motion, ep.motion.object_radius
            if m.kind != "pick_place":
                assert not m.missed
                continue
            n += 1
            assert m.missed and not m.attached.any(), (name, i)
            np.testing.assert_array_equal(m.object, np.repeat(m.object[:1], len(m.object), 0))  # never moves
            assert m.object[0, 2] == pytest.approx(R)  # resting on the floor
            t = grasp_frame(name, ep)
            assert np.linalg.norm(m.ee[t] - m.object[0]) > GRAB_RADII * R, (name, i)
            horizontal = np.linalg.norm(m.ee[t, :2] - m.object[0, :2]) / R
            assert MISS_NEAR_RADII[0] - 1e-6 <= horizontal <= MISS_FAR_RADII[1] + 1e-6, (name, i, horizontal)
            # the camera sees the whole ball (its top and bottom) in every frame
            W, H = ep.camera.intrinsics.width, ep.camera.intrinsics.height
            for dz in (-R, R):
                pr = project(m.object + [0, 0, dz], ep.camera)
                assert pr.in_front.all()
                assert ((pr.uv >= 0) & (pr.uv <= [W - 1, H - 1])).all(), (name, i)
            gt = ep.ground_truth(miss_fields=True)
            assert gt["kind"] == "pick_place" and gt["missed"] is True and gt["grabbed"] is False
            assert not any(gt["attached"])
    assert n >= 10  # enough pick-and-place episodes were checked


# Values written by the generator at the commit before pick_miss existed (fd2623d): kind, the ball's first and
# last pixel positions, the end-effector's last pixel position, frames attached. Rounded to 0.01 px.
GOLDEN = [
    ("toyarm", 0, "pick_place", [10.68, 22.17], [21.92, 19.53], [23.8, 14.52], 3),
    ("toyarm", 1, "reach", [25.44, 22.02], [25.44, 22.02], [16.42, 8.18], 0),
    ("toyarm", 2, "pick_place", [17.66, 20.58], [7.88, 27.18], [15.32, 10.0], 3),
    ("toyarm", 3, "pick_place", [16.91, 21.88], [11.96, 24.83], [16.03, 8.96], 3),
    ("kuka", 0, "pick_place", [16.46, 13.03], [4.5, 15.4], [19.74, 11.41], 3),
    ("kuka", 1, "pick_place", [15.97, 12.84], [24.36, 16.01], [3.96, 8.86], 3),
    ("kuka", 2, "pick_place", [13.42, 15.15], [12.92, 26.8], [23.83, 6.08], 3),
    ("kuka", 3, "reach", [21.42, 14.9], [21.42, 14.9], [12.98, 8.18], 0),
]


def test_default_generates_what_it_did_before_the_option():
    for name, i, kind, obj0, obj1, ee1, n_att in GOLDEN:
        gt = make_episode(REG.get(name), episode_rng(0, name, i), 32, 32, 9, ss=1).ground_truth()
        assert "missed" not in gt and "grabbed" not in gt  # default records keep their old keys
        assert gt["kind"] == kind and sum(gt["attached"]) == n_att, (name, i)
        for got, want in ((gt["object_px"][0], obj0), (gt["object_px"][-1], obj1), (gt["ee_px"][-1], ee1)):
            np.testing.assert_allclose(got, want, atol=0.011, err_msg=f"{name} {i}")


def test_a_miss_changes_the_ball_only_and_only_in_the_episodes_that_miss():
    missed = {}
    for name in ARMS:
        for i in range(6):
            base = episode(name, i)
            half = episode(name, i, pick_miss=0.5)
            high = episode(name, i, pick_miss=0.9)
            assert not base.motion.missed
            np.testing.assert_array_equal(half.trajectory.q, base.trajectory.q)  # the robot moves the same
            np.testing.assert_array_equal(half.trajectory.gripper, base.trajectory.gripper)
            if half.motion.missed:
                assert high.motion.missed  # coupled draws: a miss at 0.5 is a miss at 0.9, at the same place
                np.testing.assert_array_equal(half.motion.object, high.motion.object)
                assert not np.allclose(half.motion.object[0], base.motion.object[0])
            else:  # everything, pixels and camera included, as with pick_miss = 0
                np.testing.assert_array_equal(half.rgb, base.rgb)
                np.testing.assert_array_equal(half.camera.extrinsic, base.camera.extrinsic)
                gt = half.ground_truth(miss_fields=True)
                assert gt.pop("missed") is False and gt.pop("grabbed") == bool(base.motion.attached.any())
                assert gt == base.ground_truth()
            missed[name, i] = half.motion.missed
    assert 0 < sum(missed.values()) < sum(episode(n, i).motion.kind == "pick_place" for n, i in missed)


def test_miss_start_bands_and_base_distance():
    rng = np.random.default_rng(0)
    R, scale = 0.09, 1.0
    grasp, base = np.array([0.5, 0.0]), np.zeros(2)
    d = np.array([np.linalg.norm(miss_start(rng, grasp, base, R, scale) - grasp) / R for _ in range(400)])
    assert d.min() >= MISS_NEAR_RADII[0] and d.max() <= MISS_FAR_RADII[1]
    near = d < MISS_NEAR_RADII[1]
    assert 0.4 < near.mean() < 0.6  # half of the misses just outside the grab distance
    far = [miss_start(rng, grasp, base, R, scale) for _ in range(200)]
    assert min(np.linalg.norm(p - base) for p in far) >= 0.25 * scale  # never on the robot's base


def test_bad_fraction_is_refused(tmp_path, capsys):
    for bad in ("-0.1", "1.5", "x", "nan"):
        with pytest.raises(SystemExit) as e:
            main(
                [
                    "toyworld",
                    "generate",
                    "--embodiments",
                    "toyarm",
                    "--episodes",
                    "1",
                    "--pick-miss",
                    bad,
                    "--out",
                    str(tmp_path / "c"),
                ]
            )
        assert e.value.code == 2
        err = capsys.readouterr().err
        assert "--pick-miss" in err and bad in err, err
    assert not (tmp_path / "c").exists()
    with pytest.raises(ToyWorldError, match="--pick-miss"):
        generate_clipset(GenerateConfig(("toyarm",), 1, 16, 16, 5, pick_miss=1.5), tmp_path / "d", REG)
    assert not (tmp_path / "d").exists()
    with pytest.raises(ToyWorldError, match="--pick-miss"):
        sample_motion(REG.get("toyarm"), np.random.default_rng(0), 9, pick_miss=-0.1)


def test_generated_records_say_which_picks_missed(tmp_path):
    generate_clipset(
        GenerateConfig(("toyarm",), 4, 16, 16, 9, seed=0, skeleton=False, pick_miss=1.0), tmp_path / "m", REG
    )
    generate_clipset(GenerateConfig(("toyarm",), 4, 16, 16, 9, seed=0, skeleton=False), tmp_path / "z", REG)
    kinds = []
    for r in ClipSet(tmp_path / "m"):
        gt = r.meta["toyworld"]
        kinds.append(gt["kind"])
        assert gt["missed"] is (gt["kind"] == "pick_place") and gt["grabbed"] is False
    assert "pick_place" in kinds
    assert all("missed" not in r.meta["toyworld"] for r in ClipSet(tmp_path / "z"))


def test_without_a_miss_generator_the_episode_stream_is_left_alone():
    emb = REG.get("kuka")
    for seed in range(4):  # seed 3 is a pick_place that misses
        r0, r1 = np.random.default_rng(seed), np.random.default_rng(seed)
        a, b = sample_motion(emb, r0, 9), sample_motion(emb, r1, 9, pick_miss=1.0)
        np.testing.assert_array_equal(a.trajectory.q, b.trajectory.q)
        assert b.missed == (b.kind == "pick_place") and r0.uniform() == r1.uniform()
    assert b.missed


def test_a_rerun_with_another_miss_fraction_is_refused_and_more_episodes_are_added(tmp_path):
    """toyworld generate fingerprints what every episode depends on: a changed --pick-miss into the same folder
    is refused (naming it) instead of mixing two kinds of episodes; more episodes only add shards."""
    from oscar_core._util.stage import StageChanged
    from oscar_core.plugin.registry import Registry
    from oscar_core.toyworld.generate import GenerateConfig, generate_clipset

    reg, out = Registry(), tmp_path / "set"
    cfg = GenerateConfig(("toyarm",), 2, width=32, height=32, frames=9, shard_size=2, pick_miss=0.5)
    assert generate_clipset(cfg, out, reg)["episodes_written"] == 2
    with pytest.raises(StageChanged, match="pick_miss"):
        generate_clipset(GenerateConfig(("toyarm",), 2, width=32, height=32, frames=9, shard_size=2), out, reg)
    more = generate_clipset(
        GenerateConfig(("toyarm",), 4, width=32, height=32, frames=9, shard_size=2, pick_miss=0.5), out, reg
    )
    assert (more["episodes_written"], more["episodes_skipped"]) == (2, 2)
