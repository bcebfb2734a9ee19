"""Closed-loop promises that no other test holds: each test here fails when the promise is broken in the code.

- chunk k of a cell is sampled with its own noise seed (``chunk_seed(seed, k)``), and that seed changes the chunk;
- a policy that answers ``"done": true`` mid-chunk has its last command (joints and gripper) held to the chunk's end;
- ``report.json``: a failed cell is a failure in ``success_rate`` and in the ranking;
- the cell fingerprint holds the policy's source: changing only a source redoes that policy's cells, no others.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from oscar_core.evaluation.closed_loop import chunk_seed, run_closed_loop
from oscar_core.evaluation.closed_loop_step import closure_to_signal
from oscar_core.kinematics.trajectory import load_trajectory
from oscar_core.plugin.registry import get_embodiment
from oscar_core.toyworld.closed_loop import toy_simulator, write_closed_loop_sessions

POLICIES = '''
import os
import numpy as np
from oscar_core.toyworld.image_policies import ExactPolicy, NeverClosesPolicy


class DoneMidChunk:
    """Eight joint velocities, the gripper closing on the last one only, and "done" on the first answer."""
    def infer(self, obs):
        a = np.tile([0.2, -0.1, 0.15, 0.05, 0.0], (8, 1))
        a[-1, -1] = 1.0
        return {"actions": a, "done": True}


class Flaky(ExactPolicy):
    """The exact policy, except that it raises on the task named by FLAKY_TASK (one session's)."""
    def infer(self, obs):
        if obs["prompt"] == os.environ.get("FLAKY_TASK"):
            raise RuntimeError("dropped the connection")
        return super().infer(obs)


class SameAsNeverCloses(NeverClosesPolicy):
    """The never-closing policy under another source."""
'''


@pytest.fixture(scope="module")
def toy(tmp_path_factory) -> Path:
    """Two toyarm sessions (seed 3, as tests/evaluation/test_closed_loop.py), the exact and never-closing policies,
    and a module of test policies beside them (policies.py)."""
    root = tmp_path_factory.mktemp("cl_contracts")
    path = write_closed_loop_sessions(
        root / "sessions", ["toyarm"], 2, seed=3, horizon=49, policies=["exact", "never_closes"]
    )
    (root / "policies.py").write_text(POLICIES)
    return path


def _variant(manifest: Path, name: str, *, horizon: int | None = None, policies: list | None = None) -> Path:
    data = json.loads(manifest.read_text())
    if horizon is not None:
        data["defaults"]["horizon"] = horizon
    if policies is not None:
        data["policies"] = policies
    out = manifest.parent / f"{name}.json"
    out.write_text(json.dumps(data))
    return out


def _policy(toy: Path, name: str, attr: str, **over) -> dict:
    spec = {
        "name": name,
        "policy": f"{toy.parent.parent / 'policies.py'}:{attr}",
        "action_space": "joint_velocity",
        "control_hz": 10.0,
        "image_size": [64, 64],
        "actions_per_call": 8,
        "gripper": "position",
    }
    return {**spec, **over}


def test_each_chunk_of_a_cell_is_sampled_with_its_own_seed(toy, tmp_path, monkeypatch):
    """A cell of 2 chunks in the world model: the seeds that reach the model are chunk_seed(session seed, k) for
    k = 0, 1, different; and chunk 1 sampled again from its own inputs with chunk 0's seed differs from
    the chunk generated, while with its own seed it is that chunk."""
    import oscar_zoo
    from oscar_core.model import SamplerConfig

    model = oscar_zoo.load("oscar-toy")
    m = _variant(toy, "seeds", horizon=17)
    data = json.loads(m.read_text())
    data["sessions"], data["policies"] = data["sessions"][:1], data["policies"][:1]
    m.write_text(json.dumps(data))
    calls = []
    real = model.rollout

    def recording(first, video, prompt, **kw):
        got = real(first, video, prompt, **kw)
        calls.append({"first": first, "video": video, "prompt": prompt, "kw": kw, "frames": got.frames})
        return got

    monkeypatch.setattr(model, "rollout", recording)
    sampler = SamplerConfig(steps=2)
    res = run_closed_loop(m, tmp_path / "wm", model=model, sampler=sampler, chunk_frames=9, log=lambda s: None)
    assert res.counts["done"] == 1 and res.records[0]["frames"] == 17
    seed = res.records[0]["parts"]["session"]["seed"]
    seeds = [c["kw"]["seed"] for c in calls]
    assert seeds == [chunk_seed(seed, k) for k in range(2)] and len(set(seeds)) == 2
    c1 = calls[1]
    kw = {**c1["kw"], "seed": seeds[0]}
    other = real(c1["first"], c1["video"], c1["prompt"], **kw).frames
    own = real(c1["first"], c1["video"], c1["prompt"], **c1["kw"]).frames
    np.testing.assert_array_equal(own, c1["frames"])  # the chunk is a function of its inputs and its seed
    assert np.abs(other[1:].astype(int) - c1["frames"][1:].astype(int)).max() > 10  # another seed, another chunk


def test_done_mid_chunk_holds_the_last_command(toy, tmp_path):
    """Eight actions at 10 Hz reach 0.8 s of a 1.6 s chunk, then "done": frames 8-16 keep the joints and the
    gripper of the last action (the gripper closed by it), and the cell ends after that chunk."""
    m = _variant(toy, "done", horizon=49, policies=[_policy(toy, "done", "DoneMidChunk")])
    res = run_closed_loop(m, tmp_path / "done", simulator=toy_simulator, fps=10.0, chunk_frames=17)
    emb = get_embodiment("toyarm")
    closed = closure_to_signal(emb, np.array([1.0]))[0]
    v = np.array([0.2, -0.1, 0.15, 0.05])
    for rec in res.records:
        assert rec["status"] == "ok" and rec["done_by_policy"] and rec["frames"] == 17 and rec["calls"] == 1
        traj = load_trajectory(tmp_path / "done" / rec["trajectory"])
        q0 = load_trajectory(toy.parent / rec["session"] / "state.npz").q[0]
        last = q0 + v * 0.8
        np.testing.assert_allclose(traj.q[:9], q0 + v * np.arange(9)[:, None] / 10.0, atol=1e-9)
        np.testing.assert_allclose(traj.q[8:], np.tile(last, (9, 1)), atol=1e-9)  # held, not drifting on
        assert not np.allclose(traj.gripper[7], closed)  # open before the last action
        np.testing.assert_allclose(traj.gripper[8:], np.tile(closed, (9, 1)), atol=1e-12)  # closed, and held


def test_a_failed_cell_is_a_failure_in_success_rate_and_ranking(toy, tmp_path, monkeypatch):
    """flaky is the exact policy in session 0 and raises in session 1: its success rate is 1 of 2, so it ranks
    below exact (2 of 2) though it is listed first; over its finished cells only it would tie exact at 1.0."""
    from oscar_core.evaluation.cli import load_judge

    data = json.loads(toy.read_text())
    monkeypatch.setenv("FLAKY_TASK", data["sessions"][1]["task"])
    assert data["sessions"][0]["task"] != data["sessions"][1]["task"]
    exact, never = data["policies"]
    m = _variant(toy, "flaky", policies=[_policy(toy, "flaky", "Flaky", **{k: v for k, v in exact.items() if k not in ("name", "policy")}), exact, never])  # fmt: skip
    judge = load_judge("oscar_core.toyworld.judge:ball_moved")
    res = run_closed_loop(
        m, tmp_path / "flaky", simulator=toy_simulator, fps=10.0, chunk_frames=17, judge=judge, log=lambda s: None
    )
    report = json.loads((tmp_path / "flaky" / "report.json").read_text())
    rows = {r["policy"]: r for r in report["policies"]}
    cells = {(c["session"], c["policy"]): c for c in report["cells"]}
    s0, s1 = data["sessions"][0]["session"], data["sessions"][1]["session"]
    assert cells[s0, "flaky"]["status"] == "ok" and cells[s0, "flaky"]["success"] == 1
    assert cells[s1, "flaky"]["status"] == "failed" and "dropped the connection" in cells[s1, "flaky"]["reason"]
    assert rows["flaky"]["failed"] == 1 and rows["flaky"]["ok"] == 1
    assert rows["flaky"]["success_rate"] == 0.5
    assert rows["exact"]["success_rate"] == 1.0 and rows["never_closes"]["success_rate"] == 0.0
    assert report["ranked_by"] == "success_rate"
    assert report["ranking"] == ["exact", "flaky", "never_closes"]
    assert res.report["ranking"] == report["ranking"]


def test_changing_only_a_policys_source_redoes_its_cells(toy, tmp_path):
    """The same declaration under another source (a subclass that changes nothing) is another policy as far as
    the record goes: its cells are redone, the other policy's are reused; the same source again reuses all."""
    m = _variant(toy, "short", horizon=17)
    kwargs = dict(simulator=toy_simulator, fps=10.0, chunk_frames=9, log=lambda s: None)
    first = run_closed_loop(m, tmp_path / "src", **kwargs)
    assert first.counts["done"] == 4
    other = f"{toy.parent.parent / 'policies.py'}:SameAsNeverCloses"
    again = run_closed_loop(m, tmp_path / "src", policy_sources={"never_closes": other}, **kwargs)
    assert again.counts["done"] == 2 and again.counts["reused"] == 2
    redone = {r["policy"] for r in again.records if r["parts"]["policy"]["source"] == other}
    assert redone == {"never_closes"}
    same = run_closed_loop(m, tmp_path / "src", policy_sources={"never_closes": other}, **kwargs)
    assert same.counts["reused"] == 4 and same.counts["done"] == 0
