"""The re-perceiving toy policies (``retry``, ``retry_far``): they look at the world after the grasp and try again
when the ball still lies where it was. Driven through the closed loop in the toy simulator, where the truth is
known: a sure miss followed by an exact second aim succeeds only with the retry, and a grasp that took the ball
along is not retried."""

import numpy as np
import pytest

from oscar_core.evaluation.closed_loop import run_closed_loop
from oscar_core.toyworld.closed_loop import toy_simulator, write_closed_loop_sessions
from oscar_core.toyworld.image_policies import CLASSIC, POLICIES, policy_specs

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py

POLICY_FILE = '''
import numpy as np
from oscar_core.toyworld.image_policies import RetryPolicy


class MissThenExact(RetryPolicy):
    """The first aim is 4 ball radii off (a sure miss), every later one exact."""

    aim_sigma_radii = 0.0

    def _setup(self, obs):
        super()._setup(obs)
        self.aim = np.array([4.0 * self.R, 0.0])


class MissNoRetry(MissThenExact):
    retries = 0


class ExactRetry(RetryPolicy):
    aim_sigma_radii = 0.0
'''


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("retry")
    (root / "retry_policies.py").write_text(POLICY_FILE)
    manifest = write_closed_loop_sessions(root / "sessions", ["toyarm"], 1, seed=3, horizon=97, policies=["exact"])
    import json

    data = json.loads(manifest.read_text())
    spec = data["policies"][0]
    data["policies"] = [
        {**spec, "name": name, "policy": f"{root / 'retry_policies.py'}:{name}"}
        for name in ("MissThenExact", "MissNoRetry", "ExactRetry")
    ]
    manifest.write_text(json.dumps(data))
    res = run_closed_loop(manifest, root / "sim", simulator=toy_simulator, fps=10.0, chunk_frames=17)
    return root / "sim", {r["policy"]: r for r in res.records}


def _closings(out, record) -> int:
    """How many times the commanded gripper went from open to closed over the cell."""
    traj = np.load(out / "cells" / record["session"] / record["policy"] / "trajectory.npz")
    closed = traj["gripper"][:, 0] < np.median([traj["gripper"][:, 0].min(), traj["gripper"][:, 0].max()])
    return int(np.sum(closed[1:] & ~closed[:-1]))


def test_a_missed_grasp_is_seen_and_tried_again(run):
    out, rows = run
    assert rows["MissThenExact"]["outcome"]["grabbed"] and rows["MissThenExact"]["outcome"]["success"]
    assert _closings(out, rows["MissThenExact"]) == 2
    assert not rows["MissNoRetry"]["outcome"]["grabbed"] and not rows["MissNoRetry"]["outcome"]["success"]
    assert _closings(out, rows["MissNoRetry"]) == 1


def test_a_grasp_that_took_the_ball_is_not_retried(run):
    out, rows = run
    assert rows["ExactRetry"]["outcome"]["success"] and _closings(out, rows["ExactRetry"]) == 1


def test_the_re_perceiving_policies_are_named_but_not_in_the_default_list():
    assert {"retry", "retry_far"} <= set(POLICIES) and not {"retry", "retry_far"} & set(CLASSIC)
    assert [p["name"] for p in policy_specs()] == list(CLASSIC)
    assert [p["name"] for p in policy_specs(["retry"])] == ["retry"]
