"""``oscar toyworld decision-fit`` (oscar_core.toyworld.decision_fit): one window per pick episode of a toy clip set,
before the gripper's decision, judged on the model's chunk and on the simulator's frames; agreement per split and
class with Wilson intervals, and the train − held-out gap with Newcombe's interval. Checked against an oracle (the
true frames: every window agrees) and a frozen world (the first frame held: every carry is missed, every ball left
alone is right), against scipy's Wilson interval and Newcombe's published example, and with bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import binomtest

from oscar_core.cli import main
from oscar_core.model.errors import ModelInputError
from oscar_core.plugin.openness import trajectory_openness
from oscar_core.plugin.registry import default_registry
from oscar_core.toyworld.cli_decision_fit import format_table
from oscar_core.toyworld.decision_fit import (
    CLASSES,
    choose_windows,
    decision_fit,
    newcombe_difference,
    wilson_interval,
)
from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
from oscar_core.toyworld.motion import OPEN_THRESHOLD, ToyWorldError
from oscar_core.train.clips import ClipSet

REG = default_registry()
FRAMES = 9  # the window the fake models below roll out (oscar-toy's is 17)


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """30 toyarm episodes of 33 frames: picks that miss, stay open, close early or late, and carry."""
    out = tmp_path_factory.mktemp("fit") / "clips"
    cfg = GenerateConfig(
        ("toyarm",), 30, frames=33, seed=0, pick_miss=0.3, pick_open=0.3, pick_timing=0.4, shard_size=30
    )
    generate_clipset(cfg, out, REG)
    return out


def _cell(report, split, cls):
    return next(r for r in report["table"] if r["split"] == split and r["class"] == cls)


def test_wilson_interval_matches_scipy():
    for k, n in [(0, 1), (0, 12), (3, 12), (12, 12), (81, 263), (1, 2)]:
        ci = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
        assert wilson_interval(k, n) == pytest.approx([ci.low, ci.high], abs=1e-6)
    assert wilson_interval(0, 0) is None


def test_newcombe_difference_matches_the_published_example():
    # Newcombe (1998), Statistics in Medicine 17:873, table II, example (a): 56/70 - 48/80, method 10
    assert newcombe_difference(56, 70, 48, 80) == pytest.approx([0.0524, 0.3339], abs=5e-5)
    # symmetric: swapping the samples negates the interval
    lo, hi = newcombe_difference(48, 80, 56, 70)
    assert [lo, hi] == pytest.approx([-0.3339, -0.0524], abs=5e-5)
    assert newcombe_difference(1, 2, 0, 0) is None


def test_windows_start_before_the_first_close_and_cover_every_class(clips):
    windows = choose_windows([clips], FRAMES, None, REG, lead=2)
    cs = ClipSet(clips)
    assert {w.cls for w in windows} == set(CLASSES)
    assert {w.split for w in windows} == {"train", "heldout"}
    for w in windows:
        rec = cs.record(w.clip_id)
        toy = rec.meta["toyworld"]
        openness = trajectory_openness(REG.get("toyarm"), cs.read_trajectory(rec))[:, 0]
        assert w.cls == ("carried" if any(toy["attached"]) else "open" if toy["never_closed"] else "beside")
        if w.cls != "open":
            assert openness[w.decision] < OPEN_THRESHOLD <= openness[: w.decision].min()
        else:
            assert (openness >= OPEN_THRESHOLD).all()
        assert w.start == min(max(w.decision - 2, 0), rec.n_frames - FRAMES)
    some = choose_windows([clips], FRAMES, 2, REG, seed=3)
    assert some == choose_windows([clips], FRAMES, 2, REG, seed=3)  # the draw is a function of the seed
    groups = {}
    for w in some:
        groups[w.split, w.cls] = groups.get((w.split, w.cls), 0) + 1
    assert max(groups.values()) <= 2 and set(some) <= set(windows)


def test_an_oracle_agrees_everywhere_and_a_frozen_world_never_carries(clips):
    windows = choose_windows([clips], FRAMES, None, REG)
    oracle = decision_fit(windows, lambda clip, emb: clip.rgb, FRAMES)
    assert all("error" not in r and r["truth"] == r["model"] for r in oracle["rows"])
    for r in oracle["table"]:
        assert r["agree"] == r["windows"] and (r["windows"] == 0 or r["rate"] == 1.0)
    assert _cell(oracle, "train", "carried")["windows"] > 0 and _cell(oracle, "train", "beside")["windows"] > 0

    frozen = decision_fit(windows, lambda clip, emb: np.repeat(clip.rgb[:1], len(clip.rgb), 0), FRAMES)
    for split in ("train", "heldout"):
        carried = _cell(frozen, split, "carried")
        assert carried["agree"] == 0 and carried["model_moved"] == 0
        for cls in ("beside", "open"):
            cell = _cell(frozen, split, cls)
            assert cell["agree"] == cell["windows"]
    gap = next(g for g in frozen["gaps"] if g["class"] == "carried")
    assert gap["train_minus_heldout"] in (0.0, None)


def test_a_window_whose_rollout_fails_is_recorded_and_the_rest_are_scored(clips):
    windows = choose_windows([clips], FRAMES, None, REG)
    bad = windows[0].clip_id

    def roll(clip, emb):
        if clip.record.id == bad:
            raise ModelInputError("the model refused this window")
        return clip.rgb

    report = decision_fit(windows, roll, FRAMES)
    failed = [r for r in report["rows"] if "error" in r]
    assert [r["clip_id"] for r in failed] == [bad] and "refused this window" in failed[0]["error"]
    assert sum(r["failed"] for r in report["table"] if r["class"] == "all") == 1
    assert sum(r["windows"] for r in report["table"] if r["class"] == "all") > 0


def test_clip_sets_it_cannot_use_are_refused_by_file_and_field(tmp_path, clips):
    from oscar_core.train.synthetic import write_toy_clipset

    plain = tmp_path / "plain"
    write_toy_clipset(plain, clips=2, frames=9)
    with pytest.raises(ToyWorldError, match=r"plain/oscar_clips.json: meta.toyworld: expected pick-and-place"):
        choose_windows([plain], FRAMES, None, REG)
    with pytest.raises(ToyWorldError, match=r"oscar_clips.json: toyarm-\d+: n_frames: expected at least the model's "):
        choose_windows([clips], 65, None, REG)


def test_the_command_scores_a_zoo_model_and_refuses_bad_input_before_loading_it(clips, tmp_path, capsys):
    out = tmp_path / "new" / "fit.json"  # a missing folder on the way is made
    args = ["toyworld", "decision-fit", "--model", "oscar-toy", "--clips", str(clips), "--out", str(out)]
    assert main([*args, "--per-class", "1", "--steps", "1", "--guidance", "0", "--threads", "1", "--json"]) == 0
    report = json.loads(out.read_text())
    assert {r["class"] for r in report["table"]} == {*CLASSES, "all"}
    assert len(report["rows"]) == len(choose_windows([clips], 17, 1, REG))
    assert all("error" not in r for r in report["rows"])
    printed = json.loads(capsys.readouterr().out)
    assert printed["table"] == report["table"]
    table = format_table(report).splitlines()
    assert "left out: truth not as its class / failed" in table[0] and len(table) == 2 + 8 + 3 + 4
    row = report["table"][0]
    assert f"| {row['split']} | {row['class']} | {row['windows']} | {row['agree']} = " in table[2]

    bad = tmp_path / "bad.json"
    short = tmp_path / "short"
    generate_clipset(GenerateConfig(("toyarm",), 2, frames=9, seed=0, pick_miss=0.5), short, REG)
    assert main(["toyworld", "decision-fit", "--model", "oscar-toy", "--clips", str(short), "--out", str(bad)]) == 2
    assert "n_frames: expected at least the model's 17-frame chunk, found 9" in capsys.readouterr().err
    assert main([*args[:-2], "--out", "/proc/fit.json"]) == 2  # refused before any window is chosen
    assert "/proc/fit.json" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        main([*args[:-2], "--out", str(bad), "--guidance", "-1"])
    assert stop.value.code == 2 and "--guidance: expected a number >= 0, found -1" in capsys.readouterr().err
    assert not bad.exists()
