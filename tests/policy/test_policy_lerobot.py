"""LeRobot policies in the loop, against a class with LeRobot's interface (``select_action(batch)``, ``reset()``,
``config.input_features`` / ``output_features``, an action queue): ``lerobot`` 0.4.4 pins torch < 2.11 and
torchvision, so it does not install beside this project's torch. Nothing is downloaded."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch

from oscar_core.evaluation.closed_loop import run_closed_loop
from oscar_core.evaluation.closed_loop_step import observation
from oscar_core.kinematics.trajectory import load_trajectory
from oscar_core.kinematics.workspace import joint_limits
from oscar_core.plugin.registry import get_embodiment
from oscar_core.policy.lerobot import LeRobotMappingError, LeRobotPolicy, parse_source
from oscar_core.policy.loading import load_policy
from oscar_core.policy.protocol import PolicySpec
from oscar_core.toyworld.closed_loop import toy_simulator, write_closed_loop_sessions

STAND_IN = '''
from dataclasses import dataclass
from enum import Enum
import torch


class FeatureType(str, Enum):  # lerobot.configs.types.FeatureType
    STATE = "STATE"
    VISUAL = "VISUAL"
    ENV = "ENV"
    ACTION = "ACTION"


@dataclass
class PolicyFeature:  # lerobot.configs.types.PolicyFeature
    type: FeatureType
    shape: tuple


class Config:
    def __init__(self, input_features, output_features, n_action_steps):
        self.input_features, self.output_features, self.n_action_steps = input_features, output_features, n_action_steps


class QueuePolicy(torch.nn.Module):
    """LeRobot's calling convention: select_action pops an action queue refilled from the current batch every
    n_action_steps calls. Its chunk: the constant joint velocities ``velocity`` and gripper 1 (closed)."""

    def __init__(self, input_features=None, velocity=(0.2, -0.1, 0.15, 0.05), n_action_steps=4):
        super().__init__()
        self.config = Config(
            input_features or {
                "observation.images.front": PolicyFeature(FeatureType.VISUAL, (3, 32, 32)),
                "observation.state": PolicyFeature(FeatureType.STATE, (5,)),
            },
            {"action": PolicyFeature(FeatureType.ACTION, (5,))},
            n_action_steps,
        )
        self.weight = torch.nn.Parameter(torch.zeros(1))
        self.velocity = torch.tensor(list(velocity) + [1.0])
        self.queue, self.batches, self.resets = [], [], 0

    def reset(self):
        self.queue = []
        self.resets += 1

    def select_action(self, batch):
        if not self.queue:
            self.batches.append(batch)
            self.queue = [self.velocity.clone() for _ in range(self.config.n_action_steps)]
        return self.queue.pop(0)[None] + 0 * self.weight


from oscar_core.policy.lerobot import LeRobotPolicy


class Adapted(LeRobotPolicy):  # a class: the loop instantiates it with no arguments, once per cell
    def __init__(self):
        super().__init__(QueuePolicy())
'''


@pytest.fixture(scope="module")
def stand_in(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lerobot")
    (folder / "stand_in.py").write_text(STAND_IN)
    namespace: dict = {}
    exec(compile(STAND_IN, str(folder / "stand_in.py"), "exec"), namespace)
    return folder, namespace


def test_the_batch_holds_lerobots_keys_mapped_from_the_observation(stand_in):
    _, ns = stand_in
    policy = LeRobotPolicy(ns["QueuePolicy"]())
    spec = PolicySpec(name="p", source="x", image_size=(64, 64))
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 256, (64, 64, 3), dtype=np.uint8)
    q = np.array([0.1, -0.2, 0.3, 0.4])
    obs, _ = observation(spec, frame, q, 0.25, "pick it up", {"toy/embodiment": "toyarm"})
    batch = policy.batch(obs)
    assert sorted(batch) == ["observation.images.front", "observation.state", "task"]
    image = batch["observation.images.front"]
    assert image.dtype == torch.float32 and image.shape == (1, 3, 32, 32)
    # area resize by 2 is the mean of each 2 x 2 block rounded half up (a second implementation), / 255, CHW
    blocks = np.floor(frame.astype(np.float64).reshape(32, 2, 32, 2, 3).mean(axis=(1, 3)) + 0.5) / 255.0
    np.testing.assert_allclose(image[0].numpy().transpose(1, 2, 0), blocks, atol=1e-6)
    np.testing.assert_array_equal(batch["observation.state"][0].numpy(), np.float32([0.1, -0.2, 0.3, 0.4, 0.25]))
    assert batch["task"] == ["pick it up"]
    assert policy.infer(obs)["actions"].shape == (1, 5)


def test_a_lerobot_policy_drives_the_loop_and_the_environment(stand_in, tmp_path):
    """Constant velocities from the queue integrate to q0 + v t: one select_action per action, the queue refilled
    every 4 from the then-latest frame; the environment stepping ``act`` gives the command's joint path."""
    folder, _ = stand_in
    manifest = write_closed_loop_sessions(tmp_path / "s", ["toyarm"], 1, seed=3, horizon=33, policies=["exact"])
    data = json.loads(manifest.read_text())
    data["policies"] = [
        {
            "name": "lerobot_stand_in",
            "policy": f"{folder / 'stand_in.py'}:Adapted",
            "action_space": "joint_velocity",
            "control_hz": 10.0,
            "image_size": [64, 64],
            "actions_per_call": 1,
        }
    ]
    manifest.write_text(json.dumps(data))
    res = run_closed_loop(manifest, tmp_path / "cl", simulator=toy_simulator, fps=10.0, chunk_frames=17)
    (rec,) = res.records
    assert rec["status"] == "ok", rec["reason"]
    assert rec["calls"] == 32
    traj = load_trajectory(tmp_path / "cl" / rec["trajectory"])
    q0 = load_trajectory(manifest.parent / rec["session"] / "state.npz").q[0]
    lo, hi = joint_limits(get_embodiment("toyarm"), shrink=0.0)
    expected = np.clip(q0 + np.array([0.2, -0.1, 0.15, 0.05]) * np.arange(33)[:, None] / 10.0, lo, hi)
    np.testing.assert_allclose(traj.q, expected, atol=1e-9)
    calls = json.loads((tmp_path / "cl" / rec["dir"] / "calls.json").read_text())["calls"]
    assert [c["frame"] for c in calls[::4]] == [0, 0, 0, 0, 16, 16, 16, 16]

    gym = pytest.importorskip("gymnasium")
    from oscar_core.envs import ClosedLoopEnv

    env = ClosedLoopEnv(manifest, simulator=toy_simulator, fps=10.0, chunk_frames=17)
    policy = load_policy(f"{folder / 'stand_in.py'}:Adapted")
    obs, _ = env.reset(seed=0)
    policy.reset()
    done = False
    while not done:
        obs, _, done, _, _ = env.step(policy.act(obs))
    np.testing.assert_array_equal(env.joint_path()[0], traj.q)
    assert policy.policy.resets == 1 and len(policy.policy.batches) == 8
    assert isinstance(env.action_space, gym.spaces.Box)


def test_features_the_mapping_does_not_cover_are_named_in_one_line(stand_in):
    _, ns = stand_in
    F, T = ns["PolicyFeature"], ns["FeatureType"]
    env_state = {
        "observation.images.front": F(T.VISUAL, (3, 32, 32)),
        "observation.environment_state": F(T.ENV, (6,)),
    }
    with pytest.raises(LeRobotMappingError, match=r"^<lerobot>: input feature 'observation.environment_state' \(ENV, "):
        LeRobotPolicy(ns["QueuePolicy"](env_state))
    two = {"observation.images.top": F(T.VISUAL, (3, 8, 8)), "observation.images.side": F(T.VISUAL, (3, 8, 8))}
    with pytest.raises(LeRobotMappingError, match="input feature 'observation.images.top' .* found none$"):
        LeRobotPolicy(ns["QueuePolicy"](two))
    mapped = LeRobotPolicy(
        ns["QueuePolicy"](two), mapping={"observation.images.top": "image", "observation.images.side": "wrist_image"}
    )
    assert mapped.mapping == {"observation.images.top": ("image",), "observation.images.side": ("wrist_image",)}
    with pytest.raises(LeRobotMappingError, match="input feature 'observation.images.side' .* found none$"):
        LeRobotPolicy(ns["QueuePolicy"](two), mapping={"observation.images.top": "image"})  # over the derived ones
    with pytest.raises(LeRobotMappingError, match=r"mapping 'observation.images.top': expected one of image"):
        LeRobotPolicy(
            ns["QueuePolicy"](two), mapping={"observation.images.top": "prompt", "observation.images.side": "image"}
        )
    narrow = LeRobotPolicy(ns["QueuePolicy"]({"observation.state": F(T.STATE, (7,))}))
    spec = PolicySpec(name="p", source="x", image_size=(8, 8))
    obs, _ = observation(spec, np.zeros((8, 8, 3), np.uint8), np.zeros(4), 0.0, "t", {})
    with pytest.raises(LeRobotMappingError, match=r"'observation.state': expected shape \(7,\), found \(5,\) from "):
        narrow.batch(obs)
    with pytest.raises(LeRobotMappingError, match="expected input_features and output_features"):
        LeRobotPolicy(object())


def test_lerobot_sources_parse_and_name_the_missing_package(tmp_path):
    assert parse_source("lerobot:user/act?observation.images.top=image&observation.state=joint_position") == (
        "user/act",
        {"observation.images.top": ("image",), "observation.state": ("joint_position",)},
    )
    assert parse_source("lerobot:/models/act") == ("/models/act", None)
    with pytest.raises(LeRobotMappingError, match="mapping 'observation.state': expected fields of"):
        parse_source("lerobot:user/act?observation.state=joints")
    pytest.importorskip("torch")
    try:
        import lerobot  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match=r"^lerobot is needed here .* pip install lerobot"):
            load_policy("lerobot:user/act")
        # through the command: every policy is loaded before anything runs, so the missing package stops the run
        # with one line naming the policy and the install command, exit 2, no traceback and no cell written
        manifest = write_closed_loop_sessions(tmp_path / "s", ["toyarm"], 1, seed=3, horizon=17, policies=["exact"])
        cmd = [sys.executable, "-m", "oscar_core.cli", "eval", "closed-loop", str(manifest), "--simulator", "toy"]
        cmd += ["--out", str(tmp_path / "cl"), "--policy", "act=lerobot:user/act", "--no-progress", "--json"]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
        lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
        assert len(lines) == 1 and lines[0].startswith("error: policy 'act' cannot be loaded: lerobot:user/act: ")
        assert "pip install lerobot" in lines[0] and not (tmp_path / "cl" / "cells").exists()
    else:
        pytest.skip("lerobot is installed: the missing-package message is not reachable")
