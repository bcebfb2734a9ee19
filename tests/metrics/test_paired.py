"""Paired comparisons (oscar_core/metrics/paired.py) and ``oscar toyworld eval --paired``."""

import json

import numpy as np
import pytest

from oscar_core.cli import main
from oscar_core.metrics.paired import paired_bootstrap_interval, paired_difference


def test_a_constant_difference_has_a_zero_width_interval():
    assert paired_bootstrap_interval(np.full(7, 0.25)) == (0.25, 0.25)


def test_the_interval_of_normal_differences_is_the_textbook_one():
    rng = np.random.default_rng(1)
    d = rng.normal(0.3, 1.0, 400)
    lo, hi = paired_bootstrap_interval(d, resamples=4000)
    se = d.std(ddof=1) / np.sqrt(d.size)
    assert lo == pytest.approx(d.mean() - 1.96 * se, abs=0.25 * se)
    assert hi == pytest.approx(d.mean() + 1.96 * se, abs=0.25 * se)
    assert paired_bootstrap_interval(d, resamples=4000) == (lo, hi)  # seeded
    lo90, hi90 = paired_bootstrap_interval(d, resamples=4000, level=0.9)
    assert lo < lo90 < hi90 < hi


def test_non_finite_values_are_left_out_and_bad_settings_refused():
    assert paired_bootstrap_interval([1.0, np.nan, 1.0]) == (1.0, 1.0)
    assert all(np.isnan(paired_bootstrap_interval([np.nan])))
    with pytest.raises(ValueError, match="level"):
        paired_bootstrap_interval([1.0], level=1.0)
    with pytest.raises(ValueError, match="resamples"):
        paired_bootstrap_interval([1.0], resamples=0)


def test_pairing_uses_the_clips_both_rows_have():
    a = {"c1": {"m": 2.0}, "c2": {"m": 4.0}, "c3": {"m": 9.0}}
    b = {"c1": {"m": 1.0}, "c2": {"m": 1.0}, "c4": {"m": 0.0}}
    d = paired_difference(a, b, "m")
    assert d["clips"] == 2 and d["mean"] == pytest.approx(2.0)
    assert 1.0 <= d["ci"][0] <= d["ci"][1] <= 3.0


def test_toyworld_eval_paired_gives_row_minus_reference(tmp_path, capsys):
    from oscar_core.plugin.registry import Registry
    from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
    from oscar_core.train.clips import ClipSet

    root = tmp_path / "clips"
    generate_clipset(GenerateConfig(("toyarm",), 4, width=32, height=32, frames=9, seed=0), root, Registry())
    cs = ClipSet(root)
    same, still = tmp_path / "same", tmp_path / "still"
    same.mkdir(), still.mkdir()
    for r in cs:
        rgb = cs.load(r, skeleton=False).rgb
        np.save(same / f"{r.id}.npy", rgb)
        np.save(still / f"{r.id}.npy", np.repeat(rgb[:1], len(rgb), axis=0))
    out = tmp_path / "t.json"
    assert (
        main(
            [
                "toyworld",
                "eval",
                "--gt",
                str(root),
                "--pred",
                f"truth={same}",
                "--pred",
                f"still={still}",
                "--paired",
                "truth",
                "--out",
                str(out),
                "--no-html",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "minus 'truth'" in printed and "| still |" in printed
    t = json.loads(out.read_text())
    p = t["paired"]["rows"]["still"]
    per_truth, per_still = t["clips"]["truth"], t["clips"]["still"]
    want = np.mean([per_still[i]["psnr_db"] - per_truth[i]["psnr_db"] for i in per_truth])
    assert p["psnr_db"]["mean"] == pytest.approx(want) and p["psnr_db"]["clips"] == 4
    assert p["psnr_db"]["ci"][0] <= want <= p["psnr_db"]["ci"][1] < 0
    assert p["motion_iou"]["mean"] == pytest.approx(-1.0)  # nothing moves in the still row, all of the truth's does
    assert "truth" not in t["paired"]["rows"]
    assert main(["toyworld", "eval", "--gt", str(root), "--pred", f"truth={same}", "--paired", "nope"]) == 2
    assert "--paired nope" in capsys.readouterr().err
