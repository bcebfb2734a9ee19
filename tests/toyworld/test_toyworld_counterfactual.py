"""The toy world's counterfactual sets: each variant's simulator truth against the carry rule's analytic expectation,
and the whole command on the bundled oscar-toy (tiny: one set, two chunks, two sampler steps)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from oscar_core.plugin.registry import get_embodiment
from oscar_core.toyworld.counterfactual import (
    MISS_RADII,
    VARIANTS,
    _Redraw,
    plan_counterfactual_set,
    set_rng,
)
from oscar_core.toyworld.motion import GRAB_RADII

pytestmark = pytest.mark.usefixtures("one_thread")


def _plan(name: str, index: int, frames: int = 33):
    emb = get_embodiment(name)
    for attempt in range(30):
        try:
            return emb, plan_counterfactual_set(emb, set_rng(0, name, index, attempt), 64, 64, frames, attempt=attempt)
        except _Redraw:
            continue
    raise AssertionError("no set planned")


@pytest.mark.parametrize("name", ["toyarm", "franka"])
def test_each_variants_truth_is_the_carry_rules_analytic_expectation(name):
    emb, cs = _plan(name, 0)
    R, ball = cs.radius, cs.ball
    truth = {n: cs.truth[n]["outcome"] for n in VARIANTS}
    # open: the ball stays; closing at the ball: grabbed and moved; a miss inside the grab distance (1 R, the
    # end-effector 1.4-2.6 R above the floor: at most 1.9 R away) grabs it, one outside (3 R) does not
    assert truth == {
        "close_at_ball": 1,
        "stay_open": 0,
        "close_early": 0,
        "close_late": 0,
        "miss_1R": 1,
        "miss_3R": 0,
    }
    for n, m in cs.motions.items():
        moved = np.linalg.norm(m.object[:, :2] - ball[:2], axis=1).max() / R
        if truth[n] == 0:
            assert moved == 0.0, n  # the ball never leaves its start
        else:
            assert cs.truth[n]["grabbed"] and cs.truth[n]["displacement_radii"] >= 3.0, n
    # the decisions are what their names say, measured on each variant's own end-effector path and gripper
    for n, m in cs.motions.items():
        o = emb.gripper_openness(m.trajectory.gripper)[:, 0]
        d = np.linalg.norm(m.ee - ball, axis=1) / R
        closes = np.flatnonzero((o < 0.5) & np.concatenate([[True], o[:-1] >= 0.5]))
        if n == "stay_open":
            assert len(closes) == 0
            continue
        assert len(closes) == 1, n
        t = closes[0]
        if n == "close_early":
            assert (d[: t + 1] > GRAB_RADII).all() and t < cs.close_at  # closed before ever within reach
            assert (o[t : cs.close_at + 1] < 0.5).all()  # and stays closed through the grasp
        elif n == "close_late":
            assert t > cs.close_at and d[t] > GRAB_RADII and (d[t:] > GRAB_RADII).all()
        elif n.startswith("miss_"):
            k = float(n[5:-1])
            assert t == cs.close_at
            horizontal = np.linalg.norm(m.ee[t, :2] - ball[:2]) / R
            assert horizontal == pytest.approx(k, abs=0.02 * k + 1e-3)
            assert (d[t] <= GRAB_RADII) == (k < GRAB_RADII)
        else:
            assert t == cs.close_at and d[t] <= GRAB_RADII
    # every variant starts where the base starts (one first frame) and only the miss variants move the arm
    for n, m in cs.motions.items():
        assert np.array_equal(m.trajectory.q[0], cs.base.q[0])
        assert np.array_equal(m.trajectory.q, cs.base.q) == (not n.startswith("miss_")), n
    assert MISS_RADII == (1.0, 3.0)


def test_the_command_on_oscar_toy_writes_a_report_and_resumes(tmp_path, monkeypatch):
    from oscar_core.cli import main

    out = tmp_path / "af"
    args = ["toyworld", "action-following", "--model", "oscar-toy", "--sets", "1", "--embodiments", "toyarm"]
    args += ["--chunks", "2", "--steps", "2", "--seed", "0", "--out", str(out), "--threads", "1", "--json"]
    assert main(args) == 0
    report = json.loads((out / "report.json").read_text())
    s = report["scores"]
    assert s["sets"] == 1 and report["chunk_frames"] == 17
    assert [v for v in s["variants"]] == list(VARIANTS)
    assert len(s["chunks"]) == 2 and all(np.isfinite(c["psnr_db"]["value"]) for c in s["chunks"])
    # the simulator's frames are judged as the simulator says (the generator re-draws a set otherwise)
    assert all(v["judge_on_truth"] == {"agree": 1, "of": 1} for v in s["variants"].values())
    summary = (out / "summary.md").read_text()
    assert "decision accuracy" in summary and "nan" not in summary.lower() and "None" not in summary
    # resume: the finished set is kept, the model is not even loaded
    import oscar_zoo

    monkeypatch.setattr(oscar_zoo, "load", lambda *a, **k: pytest.fail("a finished set was rolled out again"))
    assert main(args) == 0
    assert json.loads((out / "report.json").read_text())["timing"]["sets_reused"] == 1
