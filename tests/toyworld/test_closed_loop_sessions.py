"""The toy closed-loop sessions show the ball in the first frame from the session's camera."""

from __future__ import annotations

import json

import cv2
import numpy as np

from oscar_core.plugin.registry import get_embodiment
from oscar_core.toyworld.closed_loop import write_closed_loop_sessions
from oscar_core.toyworld.image_policies import perceive_ball
from oscar_core.toyworld.policy_eval import Policy, plan_session, session_rng


def test_every_session_shows_the_ball_in_its_first_frame(tmp_path):
    """Seed 1, 10 franka and 10 kuka sessions: in the first plans of franka-0008 and kuka-0004 the arm hides the
    ball from the camera (all but 0.08 and 0.00 of its disc). Every session's first.png shows the ball (the image
    policies' own perception finds it near where it is); those two are drawn again, every other session is its
    first plan, as before."""
    path = write_closed_loop_sessions(tmp_path / "s", ["franka", "kuka"], 10, seed=1, policies=["exact"])
    rows = json.loads(path.read_text())["sessions"]
    redrawn = []
    for row in rows:
        sim = json.loads((path.parent / row["simulator"]).read_text())
        first = cv2.imread(str(path.parent / row["first_frame"]))[..., ::-1]
        ex = row["extras"]
        seen = perceive_ball(first, ex["toy/intrinsics"], ex["toy/world_to_cv"], sim["radius"])
        assert seen is not None, row["session"]
        assert np.linalg.norm(seen[:2] - np.asarray(sim["ball"])[:2]) < 1.5 * sim["radius"], row["session"]
        name, i = row["embodiment"], int(row["session"].rsplit("-", 1)[1])
        plan0 = plan_session(get_embodiment(name), session_rng(1, name, i, 0), 64, 64, 17, 10.0, (Policy("e", 0.0),))
        if not np.array_equal(plan0.ball, sim["ball"]):
            redrawn.append(row["session"])
    assert redrawn == ["franka-0008", "kuka-0004"]
