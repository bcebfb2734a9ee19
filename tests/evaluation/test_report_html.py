"""The HTML reports, opened in a real headless Chromium: every video plays, numbers equal the JSON."""

from __future__ import annotations

import contextlib
import io
import json
import re
import shlex
import shutil
import time

import pytest
from _browser import keep_screenshot, open_page, report_json, require_browser
from _models import tiny_world_model

from oscar_core.cli import main

pytestmark = pytest.mark.slow


def _fmt(v, spec):
    return "n/a" if v is None else format(v, spec)


@pytest.fixture(scope="module")
def eval_report(tmp_path_factory):
    """An `oscar eval run` report folder (2 sessions x 3 policies, a real video, a programmatic judge)."""
    require_browser()
    from _models import export_tiny_world_model
    from _studies import make_study

    root = tmp_path_factory.mktemp("eval")
    mdir = export_tiny_world_model(root / "tiny", skeleton_scale=0.05, name="tiny", chunk_frames=5, fps=15.0)
    manifest = make_study(root / "study")
    out = root / "out"
    argv = [
        "eval",
        "run",
        str(manifest),
        "--model",
        str(mdir),
        "--out",
        str(out),
        "--judge",
        str(manifest.parent / "judge_fns.py:judge"),
        "--pairwise",
        "--steps",
        "1",
        "--no-progress",
    ]
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(argv)
    assert code == 0
    (root / "stdout.txt").write_text(printed.getvalue())
    (root / "command.txt").write_text(shlex.join(["oscar", *argv]))
    return out


def test_eval_run_report_plays_and_matches_report_json(eval_report, tmp_path, monkeypatch):
    monkeypatch.setenv("OSCAR_TEST_JUDGE_LOG", str(tmp_path / "judge.log"))
    report = report_json(eval_report)
    check = open_page(
        eval_report / "report.html",
        tmp_path / "eval.png",
        select={
            "policy": "#policies td[data-field]",
            "metric": "#fidelity td[data-metric]",
            "cell": ".item [data-field]",
            "items": ".item",
        },
        screenshot_at="#rollouts",
    )
    assert check.problems == []
    assert len(check.videos) == 7  # 6 rollouts + the one real video
    assert all(v["width"] > 0 for v in check.videos)
    pol = {p["policy"]: p for p in report["policies"]}
    specs = {
        "cells": "d",
        "real_success_rate": ".3f",
        "wm_success_rate": ".3f",
        "wm_mean_partial": ".1f",
        "not_judged": "d",
        "real_score": ".4g",
        "bt_elo": ".1f",
    }
    # each td sits in a row whose data-policy names the policy: read it through the row order
    tds = check.texts["policy"]
    assert len(tds) == len(pol) * len(specs)
    for k, td in enumerate(tds):
        p = report["policies"][k // len(specs)]
        assert td["text"] == _fmt(p[td["data"]["field"]], specs[td["data"]["field"]]), (p["policy"], td)
    m = report["comparison"]["metrics"]
    mspecs = {"mmrv": ".3f", "mmrv_simpler": ".3f", "spearman_rho": "+.3f", "pearson_r": "+.3f", "sisr_delta_pp": ".2f"}
    assert {t["data"]["metric"]: t["text"] for t in check.texts["metric"]} == {
        k: _fmt(m[k], s) for k, s in mspecs.items()
    }
    cells = {c["cell"]: c for c in report["cells"]}
    assert sorted(i["data"]["cell"] for i in check.texts["items"]) == sorted(cells)
    for item in check.texts["items"]:
        c = cells[item["data"]["cell"]]
        want = "none" if c["wm_success"] is None else ("success" if c["wm_success"] else "failure")
        assert item["data"]["verdict"] == want
        assert f"partial {_fmt(c['wm_partial'], '.0f')}" in item["text"]
        assert c["reason"] in item["text"]
    keep_screenshot(check, "report-eval-run.png")


def _check_provenance(check, command: str):
    """The page says when it was made (today, UTC), by which command and which oscar version."""
    import oscar_core

    made = {t["data"]["field"]: t["text"] for t in check.texts["made"]}
    assert made["command"] == command
    assert made["version"] == oscar_core.__version__
    assert made["date"][:10] == time.strftime("%Y-%m-%d", time.gmtime())


def test_eval_run_prints_the_page_and_the_page_says_what_made_it_and_defines_its_metrics(eval_report, tmp_path):
    printed = (eval_report.parent / "stdout.txt").read_text()
    assert f"open {eval_report / 'report.html'} in a browser" in printed
    check = open_page(
        eval_report / "report.html",
        tmp_path / "eval.png",
        select={"made": "#provenance [data-field]", "defs": "#definitions dd"},
    )
    _check_provenance(check, (eval_report.parent / "command.txt").read_text())
    defs = {d["data"]["define"]: d["text"] for d in check.texts["defs"]}
    assert set(defs) == {"mmrv", "mmrv_simpler", "sisr_delta_pp"}
    # the definitions of oscar_core.metrics.policy: rank distance / success-rate gap of a misordered pair, mean |gap|
    assert "largest distance in real rank" in defs["mmrv"] and "averaged over the 3 policies" in defs["mmrv"]
    assert "at most 1.667 here" in defs["mmrv"]  # mmrv_rank_max(3) = (max(0, 2) + max(1, 1) + max(2, 0)) / 3
    assert "real success rates in place of their rank distance" in defs["mmrv_simpler"]
    assert "|real success rate − world-model success rate|, in percentage points" in defs["sisr_delta_pp"]


def test_a_bradley_terry_fit_at_the_bound_shows_no_board(eval_report, tmp_path):
    """Preferences that are ties but for one: the fit's tie parameter goes to the optimiser's bound; the page says
    so and shows neither Elo nor ν."""
    from oscar_core.evaluation import load_manifest
    from oscar_core.evaluation.html import write_html_report
    from oscar_core.metrics.bradley_terry import fit_bradley_terry

    prefs = [("good", "mid", "tie")] * 40 + [("good", "mid", "a")] + [("mid", "bad", "tie")] * 40
    bt = fit_bradley_terry(prefs)
    assert bt.degenerate and "optimiser's bound" in bt.degenerate
    folder = tmp_path / "copy"
    shutil.copytree(eval_report, folder)
    report = report_json(folder)
    report["bradley_terry"] = {**bt.to_dict(), "warnings": [], "partial": None}
    write_html_report(folder, report, load_manifest(report["manifest"]), [], progress=False)
    check = open_page(folder / "report.html", tmp_path / "bt.png", select={"note": "#bt-degenerate", "board": "#board"})
    assert check.texts["board"] == []
    (note,) = check.texts["note"]
    assert "the tie parameter reached the optimiser's bound" in note["text"] and "not shown" in note["text"]
    html = (folder / "report.html").read_text()
    assert f"{bt.tie_nu:.4f}" not in html and "Elo</th>" in html  # the per-policy column stays, as n/a


def test_missing_truncated_and_dropped_videos_are_named_on_their_cards(eval_report, tmp_path):
    """Checked when the page is written: a deleted rollout, a rollout cut to 2 of its frames and an unreadable real
    video each say so on their card."""
    import dataclasses

    from oscar_core.evaluation import load_manifest
    from oscar_core.evaluation.html import write_html_report
    from oscar_core.media.video import read_video, write_video

    folder = tmp_path / "copy"
    shutil.copytree(eval_report, folder)
    report = report_json(folder)
    cells = {c["cell"]: c for c in report["cells"]}
    gone, cut = folder / cells["s2/bad"]["video"], folder / cells["s2/good"]["video"]
    gone.unlink()
    frames = read_video(cut)
    write_video(cut, frames[:2], 15.0)
    assert cells["s2/good"]["frames"] == len(frames) > 2
    manifest = load_manifest(report["manifest"])
    junk = tmp_path / "real.mkv"
    junk.write_bytes(b"cut short")
    manifest = dataclasses.replace(
        manifest,
        cells=tuple(dataclasses.replace(c, real_video=junk) if c.id == "s1/good" else c for c in manifest.cells),
    )
    write_html_report(folder, report, manifest, [], progress=False)
    check = open_page(
        folder / "report.html", tmp_path / "cards.png", select={"problems": ".item .media-problem", "items": ".item"}
    )
    problems = {p["data"]["problem"] + " " + p["text"] for p in check.texts["problems"]}
    assert len(problems) == 3, problems
    assert any(t.startswith("rollout rollout video: missing:") and gone.name in t for t in problems)
    assert any(f"truncated: {cut} holds 2 of the {len(frames)} frames" in t for t in problems)
    assert any(t.startswith("real real video dropped: unreadable") for t in problems)
    items = {i["data"]["cell"]: i["text"] for i in check.texts["items"]}
    assert "missing" in items["s2/bad"] and "truncated" in items["s2/good"] and "dropped" in items["s1/good"]
    assert not [p for p in check.problems if "s2/bad" in p]  # no <video> was left pointing at the missing file


def test_a_broken_video_path_fails_the_check(eval_report, tmp_path):
    broken = tmp_path / "copy"
    shutil.copytree(eval_report, broken)
    media = sorted((broken / "media" / "rollouts").rglob("*.mp4"))
    media[0].unlink()  # a missing file
    media[1].write_bytes(b"not a video")  # a file the browser cannot decode
    check = open_page(broken / "report.html", tmp_path / "broken.png", select={"errors": ".video-error"})
    bad = [v for v in check.videos if v["error"] or not v["played"]]
    assert len(bad) == 2 and len(check.problems) >= 2
    assert any(media[0].name in p for p in check.problems)
    # the page itself says so, on the cards of the two videos the browser could not play
    errors = [e["text"] for e in check.texts["errors"]]
    assert len(errors) == 2 and all(e.startswith("cannot play media/rollouts/") for e in errors)
    assert any(media[0].name in e for e in errors) and any(media[1].name in e for e in errors)


def test_the_report_references_media_relatively_and_has_no_network(eval_report):
    html = (eval_report / "report.html").read_text()
    assert "http://" not in html and "https://" not in html
    # media by relative paths: no src/href names the run folder (the page's command line may, as the user typed it)
    links = re.findall(r'(?:src|href)="([^"]*)"', html)
    assert links and not any(str(eval_report) in link or link.startswith("/") for link in links)
    assert 'preload="none"' in html and "IntersectionObserver" in html
    files = json.loads((eval_report / "report.json").read_text())["files"]
    assert files["html"].endswith("report.html")


@pytest.fixture(scope="module")
def toy_report(tmp_path_factory):
    """`oscar toyworld eval` of two conditions (the truth itself, the first frame held) on a small clip set."""
    require_browser()
    import numpy as np

    from oscar_core.train.clips import ClipSet

    root = tmp_path_factory.mktemp("toy")
    assert (
        main(
            [
                "toyworld",
                "generate",
                "--embodiments",
                "toyarm,franka",
                "--episodes",
                "2",
                "--size",
                "48x48",
                "--frames",
                "9",
                "--out",
                str(root / "clips"),
                "--no-progress",
                "--json",
            ]
        )
        == 0
    )
    cs = ClipSet(root / "clips")
    (root / "same").mkdir()
    for r in cs:
        np.save(root / "same" / f"{r.id}.npy", cs.load(r, skeleton=False).rgb)
    assert main(["toyworld", "baseline", str(root / "clips"), "--split", "all", "--out", str(root / "ff")]) == 0
    # a world model's rollouts: the page names the model they came from
    import torch

    import oscar_zoo

    model = tiny_world_model(name="tiny-toy", chunk_frames=9, fps=10.0, empty_prompt=torch.zeros(1, 1, 48))
    mdir = oscar_zoo.export(model, root / "tiny-toy")
    assert (
        main(
            [
                "toyworld",
                "rollout",
                str(root / "clips"),
                "--model",
                str(mdir),
                "--split",
                "all",
                "--steps",
                "1",
                "--out",
                str(root / "wm"),
            ]
        )
        == 0
    )
    argv = [
        "toyworld",
        "eval",
        "--gt",
        str(root / "clips"),
        "--pred",
        f"true={root / 'same'}",
        "--pred",
        f"first_frame={root / 'ff'}",
        "--pred",
        f"tiny={root / 'wm'}",
        "--out",
        str(root / "table.json"),
        "--plot",
        str(root / "table.png"),
    ]
    assert main(argv) == 0
    (root / "command.txt").write_text(shlex.join(["oscar", *argv]))
    return root


def test_toyworld_eval_page_plays_and_matches_the_table(toy_report, tmp_path):
    table = json.loads((toy_report / "table.json").read_text())
    check = open_page(
        toy_report / "table.html",
        tmp_path / "toy.png",
        select={"row": "#rows td[data-field]", "fig": ".item figure[data-condition] [data-field]", "items": ".item"},
        screenshot_at="#clips",
    )
    assert check.problems == []
    n_clips = len(check.texts["items"])
    assert n_clips == 4 and len(check.videos) == n_clips * 4  # truth + 3 conditions per clip
    specs = {
        "clips": "d",
        "psnr_db": ".2f",
        "ssim": ".3f",
        "motion_iou": ".3f",
        "ee_error_px": ".2f",
        "object_error_px": ".2f",
        "moved_object_error_px": ".2f",
    }
    tds = check.texts["row"]
    names = list(table["rows"])
    assert len(tds) == len(names) * len(specs)
    for k, td in enumerate(tds):
        f = td["data"]["field"]
        assert td["text"] == _fmt(table["rows"][names[k // len(specs)]][f], specs[f])
    assert "100.00" in [t["text"] for t in check.texts["fig"]]  # the truth against itself, per clip
    keep_screenshot(check, "report-toyworld-eval.png")


@pytest.mark.parametrize("page", ["eval_report", "toy_report"])
def test_small_videos_are_shown_large_and_sharp_with_no_controls_over_them(page, request, tmp_path):
    """A small rollout (32x16 in eval run's page, 64x64 in the toy world's) is shown at a whole multiple of its
    size, at least 256 px wide, its aspect kept, with no player controls drawn over the frame."""
    folder = request.getfixturevalue(page)
    html = folder / ("report.html" if page == "eval_report" else "table.html")
    check = open_page(html, tmp_path / "videos.png")
    assert check.problems == [] and check.videos
    for v in check.videos:
        assert v["controls"] is False, v["src"]
        k = v["shown_width"] / v["width"]
        assert v["shown_width"] >= 256 and k == int(k), (v["src"], v["width"], v["shown_width"])
        assert v["shown_height"] == pytest.approx(k * v["height"], abs=1), v["src"]


def test_toyworld_eval_page_names_its_model_and_what_made_it(toy_report, tmp_path):
    from oscar_core._util.stage import model_identity

    check = open_page(
        toy_report / "table.html",
        tmp_path / "toy.png",
        select={"made": "#provenance [data-field]", "model": "#model", "by": "#rows td[data-made-by]"},
    )
    _check_provenance(check, (toy_report / "command.txt").read_text())
    assert check.texts["model"][0]["text"] == "model tiny-toy"
    by = {t["data"]["madeBy"]: t["text"] for t in check.texts["by"]}
    assert by["tiny"] == f"tiny-toy ({model_identity(toy_report / 'tiny-toy')}), true skeleton"
    assert by["true"] == by["first_frame"] == "no model recorded (not written by oscar toyworld rollout)"


@pytest.fixture(scope="module")
def data_run(tmp_path_factory):
    """A data run of four episodes: two kept, one too short, one filmed by a panning camera."""
    require_browser()
    from _datasets import base_parts, write_episode

    root = tmp_path_factory.mktemp("data")
    traj, _ = base_parts()
    write_episode(root / "src", "ep0", seed=0, task="wave")
    write_episode(root / "src", "ep1", seed=1)
    write_episode(root / "src", "short", traj.time_slice(0, 40), seed=2)
    write_episode(root / "src", "pan", seed=3, pan=1.5)
    run = root / "run"
    common = ["--workers", "1", "--no-progress"]
    assert main(["data", "ingest", str(root / "src"), "--reader", "npz", "--out", str(run), *common]) == 0
    assert main(["data", "filter", str(run), *common]) == 0
    assert main(["data", "stats", str(run)]) == 0
    return run


def test_data_stats_page_shows_the_funnel_of_stats_json_with_thumbnails(data_run, tmp_path):
    stats = json.loads((data_run / "stats.json").read_text())
    check = open_page(
        data_run / "stats.html",
        tmp_path / "stats.png",
        select={"funnel": "#funnel tr[data-key] td[data-field]", "rows": "#funnel tr[data-key]", "items": ".item"},
    )
    assert check.problems == []
    keys = [r["data"]["key"] for r in check.texts["rows"]]
    assert keys == ["public", *stats["columns"], "kept"] and len(stats["columns"]) == 2
    want = [
        stats["total"]["public"],
        *[stats["total"]["rejected"][c] for c in stats["columns"]],
        stats["total"]["kept"],
    ]
    assert [int(t["text"]) for t in check.texts["funnel"]] == want
    # one example per rejection (each reason has one episode), two kept, each with its middle frame
    assert sorted(i["data"]["column"] for i in check.texts["items"]) == sorted([*stats["columns"], "kept", "kept"])
    assert len(check.images) == 4 and all(i["width"] > 0 for i in check.images)
    keep_screenshot(check, "report-data-stats.png")


def test_data_stats_page_says_what_made_it(data_run, tmp_path):
    check = open_page(data_run / "stats.html", tmp_path / "stats.png", select={"made": "#provenance [data-field]"})
    _check_provenance(check, shlex.join(["oscar", "data", "stats", str(data_run)]))


def test_a_missing_thumbnail_fails_the_check(data_run, tmp_path):
    broken = tmp_path / "run"
    shutil.copytree(data_run, broken)
    next((broken / "stats_media").rglob("*.png")).unlink()
    check = open_page(broken / "stats.html", tmp_path / "broken.png")
    assert len([i for i in check.images if not i["ok"]]) == 1 and any("image" in p for p in check.problems)


def test_the_filters_keep_only_the_chosen_cells(eval_report):
    """Choosing a verdict, a policy or a session hides every other cell (and sessions left empty)."""
    import tempfile

    from _browser import FLAGS
    from playwright.sync_api import sync_playwright

    report = report_json(eval_report)
    exe = require_browser()
    with tempfile.TemporaryDirectory() as profile, sync_playwright() as p:
        ctx = p.chromium.launch_persistent_context(profile, executable_path=exe, headless=True, args=FLAGS)
        try:
            page = ctx.new_page()
            page.goto((eval_report / "report.html").resolve().as_uri())

            def shown():
                return sorted(page.eval_on_selector_all(".item:not([hidden])", "els => els.map(e => e.dataset.cell)"))

            assert shown() == sorted(c["cell"] for c in report["cells"])
            page.select_option("select[data-filter=verdict]", "failure")
            failures = sorted(c["cell"] for c in report["cells"] if c["wm_success"] is not None and not c["wm_success"])
            assert failures and shown() == failures
            assert page.inner_text("#shown") == str(len(shown()))
            page.select_option("select[data-filter=verdict]", "")
            page.select_option("select[data-filter=policy]", "good")
            page.select_option("select[data-filter=session]", "s2")
            assert shown() == ["s2/good"]
            hidden = page.eval_on_selector_all("section[data-group][hidden]", "els => els.map(e => e.dataset.group)")
            assert hidden == ["s1"]
        finally:
            ctx.close()


def test_closed_loop_page_ranks_as_the_summary_ties_shared(tmp_path):
    """The simulator run of the README's tour: exact and late succeed, noisy, never_closes and random fail. The
    page's rank column, read back in the browser, equals report.json's ranks and summary.md's: 1, 1, 3, 3, 3."""
    require_browser()
    from oscar_core.evaluation.closed_loop import run_closed_loop
    from oscar_core.toyworld.closed_loop import toy_simulator, write_closed_loop_sessions

    manifest = write_closed_loop_sessions(tmp_path / "sessions", ["toyarm"], 1, seed=0, horizon=49)
    out = tmp_path / "cl_sim"
    res = run_closed_loop(manifest, out, simulator=toy_simulator, fps=10.0, chunk_frames=17)
    rates = {p["policy"]: p["sim_success_rate"] for p in res.report["policies"]}
    assert rates == {"exact": 1.0, "late": 1.0, "noisy": 0.0, "never_closes": 0.0, "random": 0.0}
    expected = {"exact": 1, "late": 1, "noisy": 3, "never_closes": 3, "random": 3}
    assert res.report["ranks"] == expected
    check = open_page(
        out / "report.html",
        tmp_path / "page.png",
        select={"rows": "#closed-loop-policies tr[data-policy]", "ranks": "#closed-loop-policies [data-field=rank]"},
    )
    page = {row["data"]["policy"]: int(rank["text"]) for row, rank in zip(check.texts["rows"], check.texts["ranks"])}
    assert page == expected
    summary = (out / "summary.md").read_text()
    table = [
        line.split("|")
        for line in summary.splitlines()
        if line.startswith("| ") and line.split("|")[2].strip() in expected
    ]
    assert {cols[2].strip(): int(cols[1]) for cols in table} == expected
