"""Policy evaluation over rollout seeds and its session bootstrap (oscar_core/metrics/policy_seeds.py)."""

import json

import numpy as np
import pytest

from oscar_core.metrics.cli_policy_seeds import main
from oscar_core.metrics.policy_seeds import cell_rates, session_bootstrap, summarize_runs

POLICIES = ("a", "b", "c")


def report(wm_of, sessions=6, real_of=lambda s, j: int(s % 3 >= j)):
    """An eval-run report: policy j of session s really succeeds when s % 3 >= j; wm_of(s, j) gives its verdict."""
    return {
        "cells": [
            {
                "cell": f"s{s}/{p}",
                "session": f"s{s}",
                "policy": p,
                "real_success": real_of(s, j),
                "wm_success": wm_of(s, j),
            }
            for s in range(sessions)
            for j, p in enumerate(POLICIES)
        ]
    }


def test_rates_average_the_seeds_per_cell():
    sessions, policies, real, wm = cell_rates(
        [report(lambda s, j: 1), report(lambda s, j: 0), report(lambda s, j: int(j == 0))]
    )
    assert policies == list(POLICIES) and len(sessions) == 6
    np.testing.assert_allclose(wm[:, 0], 2 / 3)
    np.testing.assert_allclose(wm[:, 1:], 1 / 3)
    assert real[0].tolist() == [1, 0, 0]


def test_a_world_model_that_agrees_ranks_perfectly_in_every_resample_and_a_reversed_one_never():
    real = np.array([[1, 1, 0], [1, 0, 0], [1, 1, 1], [1, 0, 0]], float)
    boot = session_bootstrap(real, real, resamples=300)
    assert np.all(boot[np.isfinite(boot)] == pytest.approx(1.0))
    boot = session_bootstrap(real, 1 - real, resamples=300)
    assert np.all(boot[np.isfinite(boot)] == pytest.approx(-1.0))
    assert np.array_equal(
        session_bootstrap(real, real, 50, seed=3), session_bootstrap(real, real, 50, seed=3), equal_nan=True
    )


def test_runs_over_different_manifests_are_refused():
    with pytest.raises(ValueError, match="same manifest"):
        cell_rates([report(lambda s, j: 1), report(lambda s, j: 1, real_of=lambda s, j: 1)])


def test_summary_and_command_line(tmp_path, capsys):
    folders = []
    for k in range(3):  # seed k: the world model agrees with the real outcome except one flipped cell per seed
        f = tmp_path / f"run{k}"
        f.mkdir()
        rep = report(lambda s, j, k=k: int(s % 3 >= j) if (s, j) != (k, 1) else 1 - int(s % 3 >= j))
        (f / "report.json").write_text(json.dumps(rep))
        folders.append(f)
    s = summarize_runs(folders, resamples=500)
    assert s["real_success"] == pytest.approx([1.0, 2 / 3, 1 / 3])
    assert s["spearman_rho"] == pytest.approx(1.0) and s["mmrv"] == 0.0
    # policy b: sessions 0-2 each have one flipped seed (1/3, 2/3, 2/3), sessions 3-5 agree (0, 1, 1)
    assert s["wm_success"] == pytest.approx([1.0, 11 / 18, 1 / 3])
    assert 0 < s["p_rho_at_least_0_8"] <= 1 and s["spearman_ci95"][1] == pytest.approx(1.0)
    assert main([str(f) for f in folders]) == 0
    assert "Spearman +1.000" in capsys.readouterr().out
    assert s["judged"] == [[18, 18]] * 3 and s["complete"] is True
    with pytest.raises(SystemExit) as exit_:
        main([])
    assert exit_.value.code == 2
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0 and "rollout seed" in capsys.readouterr().out


def test_a_partial_run_is_flagged_and_exits_1(tmp_path, capsys):
    """A run that judged fewer cells than it holds must not print as a complete seed average."""
    folders = []
    for k in range(2):
        f = tmp_path / f"run{k}"
        f.mkdir()
        rep = report(lambda s, j: int(s % 3 >= j))
        if k == 1:
            for cell in rep["cells"][:4]:
                cell["wm_success"] = None  # not judged (an error, an interrupted run)
        (f / "report.json").write_text(json.dumps(rep))
        folders.append(str(f))
    assert summarize_runs(folders, resamples=50)["judged"] == [[18, 18], [14, 18]]
    assert main(folders + ["--resamples", "50"]) == 1
    err = capsys.readouterr().err
    assert "PARTIAL" in err and "14/18" in err


@pytest.mark.parametrize(
    "make, expected",
    [
        (lambda root: root / "missing", "found no such folder"),
        (lambda root: root, "found a folder without report.json"),
        (lambda root: (root / "report.json").write_text("{not json") and root, "unreadable"),
        (lambda root: (root / "report.json").write_text('{"cells": 3}') and root, "expected a list of judged cells"),
    ],
)
def test_bad_run_folders_are_named_before_any_work(tmp_path, capsys, make, expected):
    folder = make(tmp_path)
    assert main([str(folder)]) == 2
    err = capsys.readouterr().err
    assert expected in err and str(tmp_path) in err


def test_the_module_command_still_runs_as_documented(tmp_path):
    """``python -m oscar_core.metrics.policy_seeds`` is the command (its parsing and printing in cli_policy_seeds)."""
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "oscar_core.metrics.policy_seeds", str(tmp_path / "nope")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2 and done.stderr.startswith(f"error: {tmp_path / 'nope'}: field 'report.json'")
    usage = subprocess.run(
        [sys.executable, "-m", "oscar_core.metrics.policy_seeds", "--help"], capture_output=True, text=True, timeout=120
    )
    assert usage.returncode == 0 and usage.stdout.startswith("usage: python -m oscar_core.metrics.policy_seeds")


def closed_loop_report(success_of, sessions=6, sim=False, status_of=lambda s, j: "ok"):
    """An ``oscar eval closed-loop`` report; in a simulator (sim=True) ``sim_success`` is success_of's value."""
    cells = []
    for s in range(sessions):
        for j, p in enumerate(POLICIES):
            v = success_of(s, j)
            cells.append(
                {
                    "session": f"s{s}",
                    "policy": p,
                    "status": status_of(s, j),
                    "success": None if sim else v,
                    "sim_success": v if sim else None,
                }
            )
    return {"format": "oscar-closed-loop-report", "cells": cells}


def write_runs(tmp_path, reports):
    folders = []
    for name, rep in reports.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "report.json").write_text(json.dumps(rep))
        folders.append(str(tmp_path / name))
    return folders


def test_closed_loop_runs_take_their_real_outcomes_from_the_simulator_run(tmp_path, capsys):
    truth = lambda s, j: int(s % 3 >= j)  # noqa: E731
    sim, wm0, wm1 = write_runs(
        tmp_path,
        {
            "sim": closed_loop_report(truth, sim=True),
            # seed 0 agrees except policy c of session 5 (a failed cell: counts as a failure, real 1)
            "wm0": closed_loop_report(truth, status_of=lambda s, j: "failed" if (s, j) == (5, 2) else "ok"),
            # seed 1 says every cell succeeded
            "wm1": closed_loop_report(lambda s, j: 1),
        },
    )
    s = summarize_runs([wm0, wm1], resamples=200, truth=sim)
    assert s["real_success"] == pytest.approx([1.0, 2 / 3, 1 / 3]) and s["truth"] == sim
    # per policy, over 6 sessions: the mean of seed 0's rate and seed 1's (all ones)
    assert s["wm_success"] == pytest.approx([1.0, (4 / 6 + 1) / 2, (1 / 6 + 1) / 2])
    assert s["spearman_rho"] == pytest.approx(1.0) and s["complete"] is True
    assert main([wm0, wm1, "--truth", sim, "--resamples", "50"]) == 0
    assert "Spearman +1.000" in capsys.readouterr().out


def test_closed_loop_runs_without_a_usable_truth_are_refused_before_any_work(tmp_path, capsys):
    sim, wm, ev = write_runs(
        tmp_path,
        {
            "sim": closed_loop_report(lambda s, j: 1, sessions=2, sim=True),
            "wm": closed_loop_report(lambda s, j: 1, sessions=3),
            "ev": report(lambda s, j: 1),
        },
    )
    assert main([wm]) == 2
    assert "field '--truth': expected the simulator's closed-loop run" in capsys.readouterr().err
    assert main([wm, "--truth", sim]) == 2
    assert "s2/a not in it" in capsys.readouterr().err
    assert main([wm, "--truth", wm]) == 2  # a world model's run holds no simulator outcome
    assert "no simulator outcome" in capsys.readouterr().err
    assert main([wm, ev, "--truth", sim]) == 2
    assert "eval-run and closed-loop" in capsys.readouterr().err
    assert main([ev, "--truth", sim]) == 2


def test_undefined_figures_are_sentences_never_nan_or_none(tmp_path, capsys):
    """The tour's last line on one session where the world model judges every cell a failure: ρ and r of equal
    rates and a one-session interval are undefined, each printed as a sentence saying why; the JSON holds None
    with the reason, never NaN."""
    f = tmp_path / "run"
    f.mkdir()
    (f / "report.json").write_text(json.dumps(report(lambda s, j: 0, sessions=1, real_of=lambda s, j: int(j == 0))))
    s = summarize_runs([f], resamples=50)
    assert s["spearman_rho"] is None and s["pearson_r"] is None and s["p_rho_at_least_0_8"] is None
    assert s["mmrv"] is not None and s["spearman_ci95"] is None
    assert "rates are all equal (0.000)" in s["undefined"]["spearman_rho"]
    assert "1 session" in s["undefined"]["p_rho_at_least_0_8"]
    assert main([str(f), "--resamples", "50"]) == 0
    out = capsys.readouterr().out
    assert "nan" not in out.lower() and "None" not in out
    assert "Spearman undefined (the world model's rates are all equal (0.000), so they rank nothing)" in out
    assert "P(rho >= 0.8) undefined (1 session: resampling the sessions needs at least 2)" in out
    assert main([str(f), "--resamples", "50", "--json"]) == 0
    assert "NaN" not in capsys.readouterr().out
    # one session that ranks: ρ is defined, its interval is not (one session resampled is itself)
    (f / "report.json").write_text(
        json.dumps(report(lambda s, j: int(j == 0), sessions=1, real_of=lambda s, j: int(j == 0)))
    )
    assert main([str(f), "--resamples", "50"]) == 0
    out = capsys.readouterr().out
    assert "Spearman +1.000, no interval (1 session" in out and "[+1.00, +1.00]" not in out


def test_closed_loop_summary_says_cell_by_cell_whether_the_verdicts_follow_the_truth(tmp_path, capsys):
    # truth: policy a always succeeds, c never, b in half the sessions; the world model says every cell succeeded
    truth = lambda s, j: int(j == 0 or (j == 1 and s % 2 == 0))  # noqa: E731
    sim, wm = write_runs(
        tmp_path, {"sim": closed_loop_report(truth, sim=True), "wm": closed_loop_report(lambda s, j: 1)}
    )
    s = summarize_runs([wm], resamples=100, truth=sim)
    cells = s["cells"]
    # 18 cells, 9 real successes: a copy of "always 1" agrees on those 9
    assert cells["agreement"] == pytest.approx(9 / 18) and cells["cells_judged"] == 18
    assert cells["kappa"] == pytest.approx(0.0)  # p_o = 1/2 = p_e: no better than chance
    pair = cells["pairs"][f"{POLICIES[0]} vs {POLICIES[2]}"]  # the truth's best and worst, told apart in 0 of 6
    assert pair["separated"] == 0.0 and pair["sessions"] == 6
    assert main([wm, "--truth", sim, "--resamples", "50", "--pair", f"{POLICIES[0]},{POLICIES[1]}"]) == 0
    out = capsys.readouterr().out
    assert "cells: verdict = truth in 0.500" in out
    assert (
        f"{POLICIES[0]} vs {POLICIES[1]}: told apart the right way round in 0.000" in out and "of the 3 sessions" in out
    )
    assert main([wm, "--truth", sim, "--pair", "a"]) == 2
