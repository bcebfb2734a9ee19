"""Closed-loop evaluation on the toy world: the world model and the toy simulator, good and bad policies, resume."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from oscar_core.evaluation.closed_loop import run_closed_loop
from oscar_core.kinematics.trajectory import load_trajectory
from oscar_core.kinematics.workspace import joint_limits
from oscar_core.media.video import read_video
from oscar_core.plugin.registry import get_embodiment
from oscar_core.toyworld.closed_loop import toy_simulator, write_closed_loop_sessions

OSCAR = [sys.executable, "-m", "oscar_core.cli"]


def oscar(capsys, args: list) -> tuple[int, str, str]:
    """``oscar ARGS`` in this process (exit code, stdout, stderr): a fresh process only where one is killed."""
    from oscar_core.cli import main

    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


BAD_POLICIES = '''
import time
import numpy as np

class Line:
    """Constant joint velocities: the joint path must be exactly q0 + v t."""
    def infer(self, obs):
        return {"actions": np.tile([0.2, -0.1, 0.15, 0.05, 0.0], (8, 1))}

class NaN:
    def infer(self, obs):
        a = np.zeros((8, 5)); a[3, 1] = np.nan
        return {"actions": a}

class WrongShape:
    def infer(self, obs):
        return {"actions": np.zeros((8, 3))}

class Raises:
    def __init__(self):
        self.calls = 0
    def reset(self):
        self.calls = 0
    def infer(self, obs):
        self.calls += 1
        if self.calls > 1:
            raise RuntimeError("lost the gripper")
        return {"actions": np.zeros((8, 5))}

class Slow:
    def infer(self, obs):
        time.sleep(float(__import__("os").environ.get("SLOW_POLICY_S", "5")))
        return {"actions": np.zeros((8, 5))}
'''


def _joint_spec(name: str, attr: str, folder: Path) -> dict:
    return {
        "name": name,
        "policy": f"{folder / 'bad_policies.py'}:{attr}",
        "action_space": "joint_velocity",
        "control_hz": 10.0,
        "image_size": [64, 64],
        "actions_per_call": 8,
        "gripper": "position",
    }


@pytest.fixture(scope="module")
def toy(tmp_path_factory) -> Path:
    """Two toyarm sessions, the exact and the never-closing toy policies (manifest.json)."""
    root = tmp_path_factory.mktemp("closed_loop")
    path = write_closed_loop_sessions(
        root / "sessions", ["toyarm"], 2, seed=3, horizon=49, policies=["exact", "never_closes"]
    )
    (root / "bad_policies.py").write_text(BAD_POLICIES)
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


def _sha(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()


def test_simulator_gives_ground_truth_and_ranks(toy, tmp_path):
    res = run_closed_loop(toy, tmp_path / "sim", simulator=toy_simulator, fps=10.0, chunk_frames=17)
    rows = {r["policy"]: r for r in res.report["policies"]}
    assert res.counts == {"cells": 4, "done": 4, "reused": 0, "failed": 0, "retried": 0}
    assert rows["exact"]["sim_success_rate"] == 1.0 and rows["never_closes"]["sim_success_rate"] == 0.0
    assert res.report["ranking"] == ["exact", "never_closes"] and res.report["ranked_by"] == "sim_success_rate"
    assert "black" in res.report["views"]["wrist_image"]
    for rec in res.records:
        assert rec["frames"] == 49 and rec["calls"] == 6  # 48 new frames at 10 fps, 8 actions per call at 10 Hz
        assert rec["outcome"]["grabbed"] == (rec["policy"] == "exact")


def test_velocity_commands_integrate_through_the_loop(toy, tmp_path):
    """The integrated joint path is q0 + v t at every frame: one action dropped or integrated twice shifts it."""
    folder = toy.parent.parent
    m = _variant(toy, "line", horizon=33, policies=[_joint_spec("line", "Line", folder)])
    res = run_closed_loop(m, tmp_path / "line", simulator=toy_simulator, fps=10.0, chunk_frames=17)
    v = np.array([0.2, -0.1, 0.15, 0.05])
    lo, hi = joint_limits(get_embodiment("toyarm"), shrink=0.0)
    for rec in res.records:
        traj = load_trajectory(tmp_path / "line" / rec["trajectory"])
        q0 = load_trajectory(toy.parent / rec["session"] / "state.npz").q[0]
        t = np.arange(33)[:, None] / 10.0
        free = q0 + v * t
        np.testing.assert_allclose(traj.q, np.clip(free, lo, hi), atol=1e-9)  # a monotone path: clip = stop
        at_policy_rate = q0 + v * np.arange(1, 33)[:, None] / 10.0  # the 32 executed actions' targets
        assert rec["clipped_actions"] == int(((at_policy_rate < lo) | (at_policy_rate > hi)).any(1).sum())
        calls = json.loads((tmp_path / "line" / rec["dir"] / "calls.json").read_text())["calls"]
        assert [c["frame"] for c in calls] == [0, 0, 16, 16]  # two calls per 16-frame chunk, each on the latest frame


def test_world_model_frames_received_equal_the_rollout(toy, tmp_path, capsys, one_thread):
    """Every image a policy was sent is the generated frame at its call (hashes), never the simulator's."""
    m = _variant(toy, "short", horizon=17)
    out = tmp_path / "wm"
    cmd = [
        "eval",
        "closed-loop",
        str(m),
        "--model",
        "oscar-toy",
        "--out",
        str(out),
        "--steps",
        "2",
        "--chunk-frames",
        "9",
        "--judge",
        "oscar_core.toyworld.judge:ball_moved",
        "--no-progress",
    ]
    code, _, err = oscar(capsys, cmd)
    assert code == 0, err
    report = json.loads((out / "report.json").read_text())
    assert report["counts"]["done"] == 4 and report["ranked_by"] == "success_rate"
    run_closed_loop(m, tmp_path / "sim", simulator=toy_simulator, fps=10.0, chunk_frames=9)  # the real frames
    later = 0
    for cell in report["cells"]:
        video = read_video(out / cell["video"])
        assert len(video) == 17 and cell["success"] in (0, 1)
        cond = read_video(out / cell["dir"] / "condition.mkv")
        assert cond.shape == video.shape
        calls = json.loads((out / cell["dir"] / "calls.json").read_text())["calls"]
        sim_video = read_video(tmp_path / "sim" / cell["dir"] / "video.mkv")
        for c in calls:
            assert c["image_sha256"] == _sha(video[c["frame"]]), (cell["dir"], c["frame"])
            if c["frame"] > 0:
                later += 1
                assert c["image_sha256"] != _sha(sim_video[c["frame"]])  # the generated frame, not the real one
        traj = load_trajectory(out / cell["dir"] / "trajectory.npz")
        assert traj.q.shape == (17, 4) and traj.fps == 10.0
    assert later >= 4  # calls on generated frames exist (8 frames per chunk, 8 actions per call)


def test_bad_policies_fail_their_cells_only_and_retry(toy, tmp_path, capsys):
    folder = toy.parent.parent
    specs = [
        _joint_spec("line", "Line", folder),
        _joint_spec("nan", "NaN", folder),
        _joint_spec("shape", "WrongShape", folder),
        _joint_spec("raises", "Raises", folder),
        _joint_spec("slow", "Slow", folder),
    ]
    m = _variant(toy, "bad", horizon=33, policies=specs)
    out = tmp_path / "bad"
    cmd = [
        "eval",
        "closed-loop",
        str(m),
        "--simulator",
        "toy",
        "--out",
        str(out),
        "--policy-timeout",
        "0.5",
        "--no-progress",
        "--json",
    ]
    code, stdout, err = oscar(capsys, cmd)
    assert code == 1, err
    report = json.loads(stdout[stdout.index("{") :])
    reasons = {(c["session"], c["policy"]): c["reason"] for c in report["cells"]}
    for s in ("toyarm-0000", "toyarm-0001"):
        assert reasons[(s, "line")] is None
        assert "finite values, found nan at row 3, column 1" in reasons[(s, "nan")]
        assert "shape (H, 5), found (8, 3)" in reasons[(s, "shape")]
        assert reasons[(s, "raises")] == "infer raised RuntimeError: lost the gripper"
        assert "within 0.5 s" in reasons[(s, "slow")]
    assert report["counts"]["failed"] == 8
    assert not list(out.rglob("*.tmp*"))
    for name in ("nan", "raises"):  # a failed cell keeps its calls and reason, and no video
        rec = json.loads((out / "cells" / "toyarm-0000" / name / "record.json").read_text())
        assert rec["status"] == "failed" and "video" not in rec
    # a re-run reuses failed cells; --retry-failed redoes exactly them
    code, stdout, _ = oscar(capsys, cmd)
    counts = json.loads(stdout[stdout.index("{") :])["counts"]
    assert code == 1 and counts["done"] == 0 and counts["reused"] == 10
    _, stdout, _ = oscar(capsys, cmd + ["--retry-failed"])
    counts = json.loads(stdout[stdout.index("{") :])["counts"]
    assert counts["done"] == 8 and counts["retried"] == 8 and counts["reused"] == 2


def test_kill_and_resume_and_fingerprint(toy, tmp_path, capsys, monkeypatch):
    folder = toy.parent.parent
    m = _variant(
        toy, "slowish", horizon=33, policies=[_joint_spec("a", "Slow", folder), _joint_spec("b", "Slow", folder)]
    )
    out = tmp_path / "resume"
    cmd = ["eval", "closed-loop", str(m), "--simulator", "toy", "--out", str(out), "--no-progress"]
    env = {**os.environ, "SLOW_POLICY_S": "0.3"}
    proc = subprocess.Popen(OSCAR + cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    first = out / "cells" / "toyarm-0000" / "a" / "record.json"
    deadline = time.time() + 120
    while not first.exists() and time.time() < deadline:
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert first.exists()
    before = first.read_bytes()
    monkeypatch.setenv("SLOW_POLICY_S", "0.3")  # the resumed runs in this process
    code, stdout, err = oscar(capsys, cmd + ["--json"])
    assert code == 0, err
    counts = json.loads(stdout[stdout.index("{") :])["counts"]
    assert counts["reused"] >= 1 and counts["reused"] + counts["done"] == 4
    assert first.read_bytes() == before  # the finished cell was not redone
    assert not list(out.rglob("*.tmp*")) and not list(out.rglob(".*.tmp*"))
    # a changed setting is noticed: every cell redone
    _, stdout, _ = oscar(capsys, cmd + ["--json", "--replan-every", "4"])
    counts = json.loads(stdout[stdout.index("{") :])["counts"]
    assert counts["done"] == 4 and counts["reused"] == 0


def test_manifest_errors_name_the_field(toy, tmp_path, capsys):
    data = json.loads(toy.read_text())
    data["sessions"][1]["horizon"] = 1
    bad = toy.parent / "bad_fields.json"  # beside the session folders its paths name
    bad.write_text(json.dumps(data))
    code, _, err = oscar(capsys, ["eval", "closed-loop", bad, "--simulator", "toy", "--out", tmp_path / "o"])
    assert code == 2
    assert "sessions[1] ('toyarm-0001'): field 'horizon': expected an integer >= 2" in err
    data = json.loads(toy.read_text())
    data["policies"][0]["action_space"] = "torque"
    bad.write_text(json.dumps(data))
    code, _, err = oscar(capsys, ["eval", "closed-loop", bad, "--simulator", "toy", "--out", tmp_path / "o"])
    assert code == 2 and "action_space" in err and "'torque'" in err


def test_a_judge_that_cannot_judge_fails_the_run_loudly(toy, tmp_path, capsys):
    """Sessions without the judge's ``info``: exit 1, the reason on stderr, in summary.md, report.json and the log."""
    data = json.loads(_variant(toy, "no_info", horizon=17).read_text())
    for s in data["sessions"]:
        s.pop("info", None)
    data["defaults"].pop("info", None)
    m = toy.parent / "no_info.json"
    m.write_text(json.dumps(data))
    out = tmp_path / "no_info"
    judge = "oscar_core.toyworld.judge:ball_moved"
    cmd = ["eval", "closed-loop", m, "--simulator", "toy", "--judge", judge, "--out", out, "--no-progress"]
    code, _, err = oscar(capsys, cmd)
    assert code == 1, err
    why = "expected 'px_to_floor_radii'"
    assert "error: the judge could not judge 4 of 4 finished cells" in err and why in err
    summary = (out / "summary.md").read_text()
    assert "FAILED: the judge could not judge 4 of 4 finished cells" in summary
    assert summary.count(why) == 4
    report = json.loads((out / "report.json").read_text())
    assert [f["cell"] for f in report["judge_failures"]] == [
        f"{s}/{p}" for s in ("toyarm-0000", "toyarm-0001") for p in ("exact", "never_closes")
    ]
    (log,) = (out / "logs").glob("*.log")
    assert log.read_text().count("ERROR oscar.evaluation.closed_loop: the judge could not judge") == 4


def test_policies_resolve_from_the_manifest_and_load_before_the_model(toy, tmp_path, capsys, monkeypatch):
    """A policy's file.py:attr is found beside the manifest, whatever the working folder; policies that cannot be
    loaded are one line each and exit 2 before the world model loads or any cell runs."""
    data = json.loads(_variant(toy, "rel", horizon=17).read_text())
    line = _joint_spec("line", "Line", toy.parent.parent)
    data["policies"] = [{**line, "policy": "../bad_policies.py:Line"}]  # relative to the manifest's folder
    m = toy.parent / "relative.json"
    m.write_text(json.dumps(data))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # neither the manifest's folder nor its parent
    args = ["eval", "closed-loop", m, "--simulator", "toy", "--out", tmp_path / "rel", "--json", "--no-progress"]
    code, out, err = oscar(capsys, args)
    assert code == 0, err
    assert json.loads(out[out.index("{") :])["counts"]["done"] == 2
    data["policies"] += [
        {**line, "name": "nofile", "policy": "no_such_policies.py:Line"},
        {**line, "name": "noclass", "policy": "../bad_policies.py:NoSuchClass"},
    ]
    m.write_text(json.dumps(data))
    missing = tmp_path / "missing"
    args = ["eval", "closed-loop", m, "--model", "oscar-toy", "--out", missing, "--no-progress", "-v"]
    code, out, err = oscar(capsys, args)
    assert code == 2, err
    errors = [x for x in err.splitlines() if x.startswith("error:")]
    assert len(errors) == 2, err
    assert errors[0].startswith("error: policy 'nofile' cannot be loaded: ")
    assert str(toy.parent / "no_such_policies.py") in errors[0] and "no such file" in errors[0]
    assert errors[1].startswith("error: policy 'noclass' cannot be loaded: ") and "NoSuchClass" in errors[1]
    assert "loading world model" not in err and not (missing / "cells").exists()


def test_a_policy_that_never_loaded_is_not_ranked_and_a_reused_failure_says_so(toy, tmp_path, capsys):
    """A cell recorded as 'cannot load' by an earlier run is reused as it is, with a line naming --retry-failed;
    its policy, never loaded, is not ranked."""
    m = _variant(toy, "reuse", horizon=17)
    out = tmp_path / "reuse"
    args = ["eval", "closed-loop", m, "--simulator", "toy", "--out", out, "--no-progress"]
    assert oscar(capsys, args)[0] == 0
    for s in ("toyarm-0000", "toyarm-0001"):  # as an earlier run that could not load never_closes left them
        path = out / "cells" / s / "never_closes" / "record.json"
        rec = json.loads(path.read_text())
        rec.update(status="failed", reason="cannot load my_policy.py:Policy: no such file", video=None)
        path.write_text(json.dumps(rec))
    code, stdout, err = oscar(capsys, [*args, "--json"])
    assert code == 1
    assert "reused 2 failed cell(s) of an earlier run as they are" in err
    assert "--retry-failed redoes them" in err
    report = json.loads(stdout[stdout.index("{") :])
    assert report["ranking"] == ["exact"] and report["ranks"] == {"exact": 1}
    assert report["never_loaded"] == ["never_closes"]
    summary = (out / "summary.md").read_text()
    assert "2 failed cells reused from an earlier run as they are: --retry-failed redoes them" in summary
    assert "| not ranked: the policy never loaded | never_closes |" in summary


def test_undefined_report_figures_say_why(toy):
    """A world model's failed cell is no simulator failure (no 'simulator SR 0.000'); a joint-space policy has no
    IK residual (not 0.00e+00); a policy whose calls never answered has no latency. Each says why in summary.md."""
    from oscar_core.evaluation.closed_loop_manifest import load_closed_loop_manifest
    from oscar_core.evaluation.closed_loop_report import build_closed_loop_report, format_closed_loop_summary
    from oscar_core.policy.protocol import PolicySpec

    manifest = load_closed_loop_manifest(toy)
    specs = [PolicySpec.from_dict(_joint_spec("line", "Line", toy.parent.parent))]
    records = [
        {"session": s, "policy": "line", "status": "failed", "reason": "infer raised RuntimeError: x", "frames": 1,
         "calls": 1, "clipped_actions": 0, "latency_s": {"mean": None, "max": None}, "ik_max_position_error_m": None,
         "outcome": None, "verdict": None, "dir": f"cells/{s}/line"}
        for s in ("toyarm-0000", "toyarm-0001")
    ]  # fmt: skip
    counts = {"cells": 2, "done": 2, "reused": 0, "failed": 2, "retried": 0}
    report = build_closed_loop_report(manifest, specs, records, counts, {"kind": "world-model"}, None)
    (row,) = report["policies"]
    assert row["sim_success_rate"] is None and row["ik_max_position_error_m"] is None and row["max_latency_s"] is None
    assert report["ranking"] == [] and "no judge ran" in report["unranked_why"]
    table = next(line for line in format_closed_loop_summary(report).splitlines() if line.startswith("| - | line |"))
    assert "0.000" not in table and "0.00e+00" not in table and "n/a" not in table, table
    assert "no simulator (a world model has no outcome of its own)" in table
    assert "no IK: joint_velocity actions are joint positions" in table and "no policy call answered" in table
    assert "no judge ran" in table
    sim = build_closed_loop_report(manifest, specs, records, counts, {"kind": "simulator"}, None)
    assert sim["policies"][0]["sim_success_rate"] == 0.0  # in a simulator a failed cell is a failure
