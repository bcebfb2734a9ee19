"""The Gymnasium environment over the closed loop: registered ids, check_env, bad actions, and the same cells as
``oscar eval closed-loop`` (the toy simulator; ``oscar-toy`` for a short horizon, single and vectorised)."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium", reason='gymnasium is not installed (pip install "oscar-wm[gym]")')

from gymnasium.utils.env_checker import check_env  # noqa: E402

from oscar_core.envs import ActionSpaceError, ClosedLoopEnv, ClosedLoopVectorEnv, make_toy_env, run_policy  # noqa: E402
from oscar_core.evaluation.cli import load_judge  # noqa: E402
from oscar_core.evaluation.closed_loop import run_closed_loop  # noqa: E402
from oscar_core.kinematics.workspace import joint_limits  # noqa: E402
from oscar_core.media.video import read_video  # noqa: E402
from oscar_core.policy.protocol import absurd_bounds  # noqa: E402
from oscar_core.toyworld.closed_loop import toy_simulator, write_closed_loop_sessions  # noqa: E402
from oscar_core.toyworld.image_policies import ExactPolicy, NeverClosesPolicy  # noqa: E402

JUDGE = "oscar_core.toyworld.judge:ball_moved"
POLICIES = {"exact": ExactPolicy, "never_closes": NeverClosesPolicy}


@pytest.fixture(scope="module")
def toy(tmp_path_factory) -> Path:
    """Two toyarm sessions (49 frames), the exact and the never-closing toy policies."""
    root = tmp_path_factory.mktemp("gym_env")
    return write_closed_loop_sessions(root / "s", ["toyarm"], 2, seed=3, horizon=49, policies=list(POLICIES))


def _short(manifest: Path, horizon: int) -> Path:
    """The sessions of ``manifest`` at ``horizon`` frames, the exact policy only."""
    data = json.loads(manifest.read_text())
    data["defaults"]["horizon"] = horizon
    data["policies"] = [p for p in data["policies"] if p["name"] == "exact"]
    out = manifest.parent / f"h{horizon}.json"
    out.write_text(json.dumps(data))
    return out


def _cells_equal(out: Path, res, env_kwargs: dict, manifest: Path, *, level: int = 0) -> int:
    """Run every cell of ``res`` again in the environment; assert frames, joint path and verdict equal. Returns
    the number of cells compared."""
    n = 0
    for rec in res.records:
        assert rec["status"] == "ok", rec["reason"]
        env = ClosedLoopEnv(manifest, policy=rec["policy"], judge=JUDGE, **env_kwargs)
        got = run_policy(env, POLICIES[rec["policy"]](), options={"session": rec["session"]})
        video = read_video(out / rec["video"])
        assert got["frames"].shape == video.shape
        assert np.abs(got["frames"].astype(int) - video.astype(int)).max() <= level, rec["dir"]
        np.testing.assert_array_equal(got["q"], np.load(out / rec["trajectory"])["q"])
        np.testing.assert_array_equal(got["gripper"], np.load(out / rec["trajectory"])["gripper"])
        assert got["calls"] == rec["calls"]
        assert got["info"]["verdict"]["binary"] == rec["verdict"]["binary"]
        assert got["reward"] == float(rec["verdict"]["binary"] == 1)
        if rec["outcome"]:
            assert got["info"]["outcome"] == rec["outcome"]
        n += 1
    return n


def test_the_environment_gives_the_cells_of_eval_closed_loop_on_the_simulator(toy, tmp_path):
    sim = dict(simulator=toy_simulator, fps=10.0, chunk_frames=17)
    res = run_closed_loop(toy, tmp_path / "cl", judge=load_judge(JUDGE), log=lambda m: None, **sim)
    assert _cells_equal(tmp_path / "cl", res, sim, toy) == 4
    outcomes = {r["policy"]: r["outcome"]["success"] for r in res.records}
    assert outcomes == {"exact": 1, "never_closes": 0}  # the two policies differ: the comparison is not vacuous


def test_oscar_toy_short_horizon_single_and_vectorised(toy, tmp_path, monkeypatch):
    """17 frames = 2 chunks of 9 on oscar-toy (2 sampler steps): the environment's cells equal the command's;
    two episodes in a vector environment share one batched world-model call per chunk."""
    import oscar_zoo
    from oscar_core.model import SamplerConfig

    model = oscar_zoo.load("oscar-toy")
    manifest = _short(toy, 17)
    wm = dict(model=model, sampler=SamplerConfig(steps=2), chunk_frames=9)
    res = run_closed_loop(manifest, tmp_path / "wm", judge=load_judge(JUDGE), log=lambda m: None, **wm)
    exact = res.records
    assert [r["policy"] for r in exact] == ["exact", "exact"]
    assert _cells_equal(tmp_path / "wm", res, wm, manifest) == 2

    batches, singles = [], []
    real_batch, real_single = model.rollout_batch, model.rollout
    monkeypatch.setattr(model, "rollout_batch", lambda f, *a, **k: batches.append(len(f)) or real_batch(f, *a, **k))
    monkeypatch.setattr(model, "rollout", lambda *a, **k: singles.append(1) or real_single(*a, **k))
    venv = ClosedLoopVectorEnv(2, manifest, policy="exact", judge=JUDGE, **wm)
    names = [r["session"] for r in exact]
    policies = [ExactPolicy(), ExactPolicy()]
    obs, _ = venv.reset(seed=0)
    obs = [venv.envs[i].reset(options={"session": names[i]})[0] for i in range(2)]  # one session each
    done, step = np.zeros(2, bool), 0
    while not done.all():
        if step % 8 == 0:
            chunks = [p.infer(o)["actions"] for p, o in zip(policies, obs)]
        batch, rewards, term, _, info = venv.step(np.stack([c[step % 8] for c in chunks]))
        obs = [{k: v[i] for k, v in batch.items()} for i in range(2)]
        done |= term
        step += 1
    assert batches == [2, 2] and singles == [] and venv.world_model_calls == 2
    for i, rec in enumerate(exact):
        video = read_video(tmp_path / "wm" / rec["video"])
        frames = venv.envs[i].frames()
        assert np.abs(frames.astype(int) - video.astype(int)).max() <= 1  # the batch's float rounding
        np.testing.assert_array_equal(venv.envs[i].joint_path()[0], np.load(tmp_path / "wm" / rec["trajectory"])["q"])
        assert rewards[i] == float(rec["verdict"]["binary"] == 1)
    venv.close()


def test_check_env_spaces_and_bad_actions(toy):
    env = ClosedLoopEnv(
        toy, policy="exact", simulator=toy_simulator, fps=10.0, chunk_frames=17, judge=JUDGE, render_mode="rgb_array"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # check_env's advice on unbounded extras and unnormalised boxes
        check_env(env)
    lo, hi = absurd_bounds("ee_position", *joint_limits(env.emb, shrink=0.0), 10.0)
    np.testing.assert_array_equal(env.action_space.low, lo)
    np.testing.assert_array_equal(env.action_space.high, hi)
    with pytest.raises(gymnasium.error.ResetNeeded):
        ClosedLoopEnv(toy, simulator=toy_simulator, fps=10.0, chunk_frames=17).step(np.zeros(4))
    obs, info = env.reset(seed=5)
    assert env.observation_space.contains(obs) and info["frame"] == 0
    assert np.array_equal(env.render(), obs["observation/exterior_image_1_left"])  # 64 x 64: the frame itself
    with pytest.raises(ActionSpaceError, match=r"^action: expected shape \(4,\) \(ee_position: x y z gripper\), "):
        env.step(np.zeros(3))
    with pytest.raises(ActionSpaceError, match=r"^action\[2\] \(z\): expected a value in \[-10, 10\] .* found 11$"):
        env.step(np.array([0.1, 0.0, 11.0, 0.0]))
    with pytest.raises(ActionSpaceError, match=r"^action\[3\] \(gripper\): .* found nan$"):
        env.step(np.array([0.1, 0.0, 0.2, np.nan]))
    # inside the box but past the joint limits: executed clipped and counted, as the command does
    _, reward, term, trunc, info = env.step(np.array([3.0, 0.0, 0.1, 1.5]))
    assert info["clipped"] == 1 and info["clipped_total"] == 1 and info["ik_position_error_m"] > 0.1
    assert (reward, term, trunc, info["frame"]) == (0.0, False, False, 0)
    env.close()


def test_registered_ids_after_import_oscar_core_either_order(tmp_path):
    """``import oscar_core`` imports neither gymnasium nor torch; the ids exist whichever is imported first."""
    code = """
import sys, warnings
import {first}, {second}
assert "torch" not in sys.modules, "torch imported"
import gymnasium
env = gymnasium.make("oscar/ToySim-v0", sessions=1, horizon=17, render_mode="rgb_array")
obs, info = env.reset(seed=0)
obs, r, term, trunc, info = env.step(env.action_space.sample())
print(info["frame"], env.render().shape, gymnasium.spec("oscar/ToyWorldModel-v0").kwargs)
vec = gymnasium.make_vec("oscar/ToySim-v0", num_envs=2, sessions=1, horizon=17)
print(type(vec).__name__, vec.reset(seed=0)[0]["observation/joint_position"].shape)
env.close(); vec.close()
"""
    bare = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys, oscar_core; print(sorted(m for m in ('gymnasium', 'torch', 'numpy') if m in sys.modules))",
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    assert bare.stdout.strip() == "[]"
    for first, second in (("oscar_core", "gymnasium"), ("gymnasium", "oscar_core")):
        proc = subprocess.run(
            [sys.executable, "-c", code.format(first=first, second=second)], capture_output=True, text=True
        )
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert proc.stdout.splitlines() == [
            "0 (64, 64, 3) {'world': 'model'}",
            "ClosedLoopVectorEnv (2, 4)",
        ]


def test_a_missing_extra_is_one_line_naming_the_package():
    code = "import sys; sys.modules['gymnasium'] = None\nimport oscar_core.envs.closed_loop_env"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines()[-1].startswith("ImportError: gymnasium is needed here and is not installed")
    assert 'pip install "oscar-wm[gym]"' in proc.stderr


def test_toy_env_removes_its_session_folder_on_close():
    env = make_toy_env(sessions=1, horizon=17)
    folder = env.manifest.path.parent
    assert (folder / "toyarm-0000" / "first.png").is_file()
    env.close()
    assert not folder.exists()


def test_the_vector_env_resets_an_ended_episode_on_the_next_step():
    """Gymnasium's next-step autoreset: the step after ``terminated`` resets that episode and ignores its action."""
    vec = gymnasium.make_vec("oscar/ToySim-v0", num_envs=2, sessions=1, horizon=17)
    obs, info = vec.reset(seed=0)
    assert obs["observation/joint_position"].shape == (2, 4) and list(info["frame"]) == [0, 0]
    action = np.tile([0.3, 0.0, 0.2, 0.0], (2, 1))
    for step in range(16):  # 16 actions at 10 Hz cover the one chunk of 16 new frames
        obs, reward, term, trunc, info = vec.step(action)
        assert list(term) == [step == 15] * 2 and not trunc.any()
    assert list(info["frame"]) == [16, 16] and "verdict" in info and list(info["_verdict"]) == [True, True]
    obs, reward, term, trunc, info = vec.step(action)
    assert list(info["frame"]) == [0, 0] and list(reward) == [0.0, 0.0] and not term.any()
    assert vec.unwrapped.world_model_calls == 1  # the simulator's one chunk, both episodes in one round
    vec.close()
