"""Closed loop at scale: --batch-cells (lock-step, one batched world-model call per chunk), --engine ray, and the
report (report.html, fidelity figures with session intervals, pairwise preferences)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from oscar_core.evaluation.closed_loop import run_closed_loop
from oscar_core.media.video import read_video
from oscar_core.model import SamplerConfig
from oscar_core.toyworld.closed_loop import toy_simulator, write_closed_loop_sessions

NAN_POLICY = """
import numpy as np

class NaN:
    def infer(self, obs):
        a = np.zeros((8, 5)); a[3, 1] = np.nan
        return {"actions": a}
"""


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> Path:
    """Two toyarm sessions of different horizons (17 and 25 frames: 2 and 3 chunks of 9 frames), two policies."""
    root = tmp_path_factory.mktemp("cl_batch")
    path = write_closed_loop_sessions(
        root / "sessions", ["toyarm"], 2, seed=3, horizon=17, policies=["exact", "never_closes"]
    )
    data = json.loads(path.read_text())
    data["sessions"][1]["horizon"] = 25
    path.write_text(json.dumps(data))
    return path


@pytest.fixture(scope="module")
def toy_model():
    import oscar_zoo

    return oscar_zoo.load("oscar-toy")


def _videos(out: Path, report: dict) -> dict:
    return {(c["session"], c["policy"]): read_video(out / c["video"]) for c in report["cells"]}


def test_batched_cells_equal_one_at_a_time_and_waiting_cells_join(sessions, toy_model, tmp_path, monkeypatch):
    kwargs = dict(model=toy_model, sampler=SamplerConfig(steps=2), chunk_frames=9, log=lambda m: None)
    one = run_closed_loop(sessions, tmp_path / "one", **kwargs)
    batches, singles = [], []
    real_batch, real_single = toy_model.rollout_batch, toy_model.rollout
    monkeypatch.setattr(toy_model, "rollout_batch", lambda f, *a, **k: batches.append(len(f)) or real_batch(f, *a, **k))
    monkeypatch.setattr(toy_model, "rollout", lambda *a, **k: singles.append(1) or real_single(*a, **k))
    many = run_closed_loop(sessions, tmp_path / "many", batch_cells=3, **kwargs)
    # 4 cells, 3 in flight: two rounds of 3; the session-0 cells end after 2 chunks and the waiting cell joins
    # the third round beside the last session-1 cell (2); then it runs alone for its last 2 chunks
    assert batches == [3, 3, 2] and len(singles) == 2
    assert many.counts == one.counts == {"cells": 4, "done": 4, "reused": 0, "failed": 0, "retried": 0}
    a, b = _videos(tmp_path / "one", one.report), _videos(tmp_path / "many", many.report)
    assert a.keys() == b.keys()
    for key in a:
        assert a[key].shape == b[key].shape and len(a[key]) in (17, 25)
        assert np.abs(a[key].astype(int) - b[key].astype(int)).max() <= 1, key  # one uint8 level
    for ra, rb in zip(one.records, many.records):
        ta = np.load(tmp_path / "one" / ra["trajectory"])["q"]
        tb = np.load(tmp_path / "many" / rb["trajectory"])["q"]
        np.testing.assert_allclose(ta, tb, atol=1e-9)
        assert ra["calls"] == rb["calls"]
    again = run_closed_loop(sessions, tmp_path / "many", batch_cells=3, **kwargs)  # resume: nothing redone
    assert again.counts["reused"] == 4 and again.counts["done"] == 0


@pytest.mark.slow
def test_ray_engine_gives_the_local_run(sessions, tmp_path):
    ray = pytest.importorskip("ray", reason='ray is not installed (pip install "oscar-wm[ray]")')
    started = not ray.is_initialized()
    if started:  # a fixed local cluster: two CPUs, so two workers whatever the machine
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        kwargs = dict(model_spec="oscar-toy", sampler=SamplerConfig(steps=2), chunk_frames=9, log=lambda m: None)
        local = run_closed_loop(sessions, tmp_path / "local", **kwargs)
        remote = run_closed_loop(sessions, tmp_path / "ray", engine="ray", workers=2, **kwargs)
        assert remote.counts == local.counts
        a, b = _videos(tmp_path / "local", local.report), _videos(tmp_path / "ray", remote.report)
        for key in a:
            assert np.abs(a[key].astype(int) - b[key].astype(int)).max() <= 1, key
        for ra, rb in zip(local.records, remote.records):
            assert (ra["session"], ra["policy"], ra["calls"], ra["frames"]) == (
                rb["session"],
                rb["policy"],
                rb["calls"],
                rb["frames"],
            )
            assert (tmp_path / "ray" / rb["dir"] / "condition.mkv").is_file()
        sim = run_closed_loop(
            sessions, tmp_path / "sim_ray", simulator=toy_simulator, fps=10.0, chunk_frames=9, engine="ray",
            workers=2, batch_cells=2, log=lambda m: None,
        )  # fmt: skip
        assert [r["outcome"]["grabbed"] for r in sim.records] == [r["policy"] == "exact" for r in sim.records]
    finally:
        if started:
            ray.shutdown()


def test_report_ranks_compares_with_real_outcomes_and_names_failures(sessions, tmp_path):
    """Simulator run with real outcomes in the manifest: the figures equal scipy's, the intervals are the session
    bootstrap, failures carry their reasons in JSON, summary and page, and the page says what the views get."""
    from oscar_core.evaluation.cli import load_judge
    from oscar_core.metrics.policy_seeds import session_bootstrap_figures

    data = json.loads(sessions.read_text())
    (tmp_path / "nan_policy.py").write_text(NAN_POLICY)
    data["policies"].append(
        {
            "name": "nan",
            "policy": f"{tmp_path / 'nan_policy.py'}:NaN",
            "action_space": "joint_velocity",
            "control_hz": 10.0,
            "image_size": [64, 64],
        }
    )
    base = sessions.parent
    for s in data["sessions"]:
        for key in ("first_frame", "camera", "initial_state", "simulator"):
            if key in s:
                s[key] = str(base / s[key])
    for key in ("first_frame", "camera", "initial_state", "simulator"):
        if key in data["defaults"]:
            data["defaults"][key] = str(base / data["defaults"][key])
    # made-up real outcomes: exact succeeds in both sessions, never_closes in one, nan in none
    real = [{"exact": 1, "never_closes": 1, "nan": 0}, {"exact": 1, "never_closes": 0, "nan": 0}]
    for s, r in zip(data["sessions"], real):
        s["real_success"] = r
        s["horizon"] = 49  # long enough for the exact policy to carry the ball
    m = tmp_path / "manifest.json"
    m.write_text(json.dumps(data))
    judge = load_judge("oscar_core.toyworld.judge:ball_moved")
    res = run_closed_loop(
        m, tmp_path / "out", simulator=toy_simulator, fps=10.0, chunk_frames=9, judge=judge, log=lambda x: None
    )
    rep = res.report
    failed = [c for c in rep["cells"] if c["status"] == "failed"]
    assert len(failed) == 2 and all(c["policy"] == "nan" and "row 3" in c["reason"] for c in failed)
    ev = rep["eval"]
    wm = {p["policy"]: p["wm_success_rate"] for p in ev["policies"]}
    assert wm == {"exact": 1.0, "never_closes": 0.0, "nan": 0.0}  # a failed cell is a failure
    real_sr = {"exact": 1.0, "never_closes": 0.5, "nan": 0.0}
    names = list(real_sr)
    metrics = ev["comparison"]["metrics"]
    expect = stats.spearmanr([real_sr[p] for p in names], [wm[p] for p in names]).statistic
    assert metrics["spearman_rho"] == pytest.approx(expect)
    # the intervals: percentiles of the per-resample figures, ρ from the same draws as scipy computes it
    cells = {(c["session"], c["policy"]): c for c in ev["cells"]}
    sess = sorted({c["session"] for c in ev["cells"]})
    R = np.array([[cells[s, p]["real_success"] for p in names] for s in sess], float)
    W = np.array([[cells[s, p]["wm_success"] for p in names] for s in sess], float)
    boot = session_bootstrap_figures(R, W, 2000, 0)
    rng = np.random.default_rng(0)
    for k in range(50):
        idx = rng.integers(0, 2, 2)
        r, w = R[idx].mean(0), W[idx].mean(0)
        want = stats.spearmanr(r, w).statistic if np.ptp(r) > 0 and np.ptp(w) > 0 else np.nan
        assert (np.isnan(want) and np.isnan(boot["spearman_rho"][k])) or boot["spearman_rho"][k] == pytest.approx(want)
        assert boot["sisr_delta_pp"][k] == pytest.approx(100 * np.abs(r - w).mean())
    ok = boot["spearman_rho"][np.isfinite(boot["spearman_rho"])]
    assert rep["intervals"]["spearman_rho"] == pytest.approx([np.percentile(ok, 2.5), np.percentile(ok, 97.5)])
    summary = (tmp_path / "out" / "summary.md").read_text()
    assert "Spearman ρ" in summary and "row 3" in summary
    html = (tmp_path / "out" / "report.html").read_text()
    assert 'id="closed-loop"' in html and "black" in html and "row 3" in html and 'id="intervals"' in html
    assert 'data-field="clipped_actions"' in html and "mean latency" in html


def test_session_bootstrap_figures_equal_scipy_on_the_same_draws():
    """Every resample's ρ, r, MMRV and SISR_Δ against scipy / the definitions on the same session draws; the
    ρ series is the one session_bootstrap has always given."""
    from oscar_core.metrics.policy import mmrv_rank
    from oscar_core.metrics.policy_seeds import session_bootstrap, session_bootstrap_figures, session_intervals

    rng = np.random.default_rng(7)
    real = rng.integers(0, 2, (9, 4)).astype(float)
    wm = rng.random((9, 4))
    boot = session_bootstrap_figures(real, wm, 300, 5)
    draws = np.random.default_rng(5)
    for k in range(300):
        idx = draws.integers(0, 9, 9)
        r, w = real[idx].mean(0), wm[idx].mean(0)
        if np.ptp(r) > 0:
            assert boot["spearman_rho"][k] == pytest.approx(stats.spearmanr(r, w).statistic)
            assert boot["pearson_r"][k] == pytest.approx(stats.pearsonr(r, w).statistic)
        else:
            assert np.isnan(boot["spearman_rho"][k]) and np.isnan(boot["pearson_r"][k])
        assert boot["sisr_delta_pp"][k] == pytest.approx(100 * np.abs(r - w).mean())
        assert boot["mmrv"][k] == pytest.approx(mmrv_rank(r, w))
    np.testing.assert_array_equal(session_bootstrap(real, wm, 300, 5), boot["spearman_rho"])
    iv = session_intervals(real, wm, 300, 5)
    ok = boot["pearson_r"][np.isfinite(boot["pearson_r"])]
    assert iv["pearson_r"] == pytest.approx([np.percentile(ok, 2.5), np.percentile(ok, 97.5)])
