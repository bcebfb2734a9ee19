"""A small policy-evaluation study the tests share: 2 sessions x 3 policies of the toy arm, with real outcomes, the
world model's verdicts (through a programmatic judge) and one real video, written as an ``oscar eval run`` manifest."""

import json
from pathlib import Path

import cv2
import numpy as np
from _paths import TOYARM_ASSETS

POLICIES = ["good", "mid", "bad"]
# real and world-model outcomes per (session, policy): real SR good 1, mid 0.5, bad 0; wm SR good 1, mid 0, bad 0.5
REAL = {("s1", "good"): 1, ("s1", "mid"): 1, ("s1", "bad"): 0, ("s2", "good"): 1, ("s2", "mid"): 0, ("s2", "bad"): 0}
WM = {("s1", "good"): 1, ("s1", "mid"): 0, ("s1", "bad"): 1, ("s2", "good"): 1, ("s2", "mid"): 0, ("s2", "bad"): 0}

JUDGE_SOURCE = """
import os

def judge(video, clip):
    # a function of the video: the test checks it gets the whole rollout; the verdict comes from the cell's info
    assert video.dtype.name == "uint8" and video.shape[1:] == (16, 32, 3), video.shape
    log = os.environ.get("OSCAR_TEST_JUDGE_LOG")
    if log:
        with open(log, "a") as f:
            f.write(clip.name + "\\n")
    ok = clip.info["wm"]
    return {"binary": ok, "partial": 100 if ok else 10 * len(video) % 100, "reason": f"{len(video)} frames"}
"""


def make_study(root: Path, frames: int = 5) -> Path:
    """2 sessions x 3 policies of the toy arm; returns the manifest path."""
    root.mkdir(parents=True, exist_ok=True)
    src = np.load(TOYARM_ASSETS / "example_trajectory.npz")
    (root / "camera.json").write_text((TOYARM_ASSETS / "example_camera.json").read_text())
    cells = []
    for s, session in enumerate(("s1", "s2")):
        img = np.random.default_rng(s).integers(0, 256, (360, 640, 3), dtype=np.uint8)
        cv2.imwrite(str(root / f"{session}_first.png"), img)
        for p, policy in enumerate(POLICIES):
            off = 8 * p + 20 * s
            np.savez(
                root / f"{session}_{policy}.npz",
                joint_names=src["joint_names"],
                q=src["q"][off : off + frames],
                fps=src["fps"],
                gripper=src["gripper"][off : off + frames],
                gripper_names=src["gripper_names"],
            )
            cells.append(
                {
                    "session": session,
                    "policy": policy,
                    "first_frame": f"{session}_first.png",
                    "trajectory": f"{session}_{policy}.npz",
                    "real_success": REAL[(session, policy)],
                    "info": {"wm": WM[(session, policy)]},
                }
            )
    np.save(root / "real_s1_good.npy", np.full((frames, 18, 32, 3), 200, np.uint8))
    cells[0]["real_video"] = "real_s1_good.npy"
    manifest = {
        "format": "oscar-eval-manifest",
        "policies": POLICIES,
        "defaults": {
            "embodiment": "toyarm",
            "camera": "camera.json",
            "size": "32x16",
            "task": "put the block in the bin",
        },
        "cells": cells,
    }
    (root / "manifest.json").write_text(json.dumps(manifest, indent=1))
    (root / "judge_fns.py").write_text(JUDGE_SOURCE)
    return root / "manifest.json"
