"""The paper's benchmark protocol (`oscar eval benchmark build | run | table`): rules, set, rollouts, table."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass

import numpy as np
import pytest

from oscar_core._util.stage import StageChanged
from oscar_core.camera import Intrinsics, project_points_cv
from oscar_core.cli import main
from oscar_core.evaluation import benchmark_rules as rules
from oscar_core.evaluation.benchmark_run import run_benchmark
from oscar_core.evaluation.benchmark_set import BenchmarkSetError, build_benchmark_set, load_benchmark_set
from oscar_core.evaluation.benchmark_table import BenchmarkTableError, benchmark_table
from oscar_core.model.sampler import SamplerConfig
from oscar_core.plugin.registry import default_registry
from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
from oscar_core.train.clips import ClipSet

REG = default_registry()


# ----------------------------------------------------------------------------- rules, analytic cases
def test_forward_window_on_an_analytic_pinhole_camera():
    """A point 1 m in front of a 64-px camera (f = 50 px, cx = 31.5) moving right by 0.1 m per frame:
    u_t = 31.5 + 50 * 0.1 t, so it crosses the right edge u = 63.5 between t = 6 (61.5) and t = 7 (66.5)."""
    K = Intrinsics(50.0, 50.0, 31.5, 31.5, 64, 64)
    t = np.arange(10)
    leaves = project_points_cv(np.stack([0.1 * t, 0 * t, 1.0 + 0 * t], axis=1).astype(float), K)
    stays = project_points_cv(np.stack([0.01 * t, 0 * t, 1.0 + 0 * t], axis=1).astype(float), K)
    assert rules.forward_window(leaves.uv, leaves.in_front, 64, 64, frames=10) == 7
    assert rules.forward_window(leaves.uv, leaves.in_front, 64, 64, frames=7) is None  # horizon ends before
    assert rules.forward_window(stays.uv, stays.in_front, 64, 64, frames=10) is None
    # a margin of 3 px: 61.5 >= 64 - 0.5 - 3 = 60.5, so frame 6 is already out
    assert rules.forward_window(leaves.uv, leaves.in_front, 64, 64, frames=10, margin=3) == 6
    behind = project_points_cv(np.array([[0, 0, 1.0], [0, 0, -1.0]]), K)
    assert rules.forward_window(behind.uv, behind.in_front, 64, 64, frames=2) == 1
    assert rules.forward_window(stays.uv[:5], stays.in_front[:5], 64, 64, frames=10) == 5  # too short


def test_motion_magnitude_is_path_length_over_the_diagonal():
    uv = np.array([[0, 0], [3, 4], [3, 4], [6, 8]], float)  # 5 + 0 + 5 px
    assert rules.motion_magnitude(uv, 4, 30, 40) == pytest.approx(10 / 50)
    assert rules.motion_magnitude(uv, 2, 30, 40) == pytest.approx(5 / 50)


def test_sqrt_quotas_against_hand_computed_largest_remainders():
    # sqrt: 10, 5, 2 (sum 17); shares of 10: 5.882, 2.941, 1.176 -> floors 5, 2, 1; the 2 left go to
    # the largest remainders .941 (b) and .882 (a)
    assert rules.sqrt_quotas({"a": 100, "b": 25, "c": 4}, 10) == {"a": 6, "b": 3, "c": 1}
    # sqrt 10 and 1: shares 9.09 and 0.91 -> 9 + 0, the one left goes to b (.91 > .09)
    assert rules.sqrt_quotas({"a": 100, "b": 1}, 10) == {"a": 9, "b": 1}
    # equal corpora (5 each) but b has 1 clip available: b is capped, its 4 go back to a
    assert rules.sqrt_quotas({"a": 100, "b": 1}, 10, corpus={"a": 100, "b": 100}) == {"a": 9, "b": 1}
    assert rules.sqrt_quotas({"a": 2, "b": 1}, 10) == {"a": 2, "b": 1}  # fewer clips than the total


def test_kmeans_keeps_one_per_blob_and_is_deterministic_under_the_seed():
    rng = np.random.default_rng(0)
    centres = np.array([[0, 0], [10, 0], [0, 10]], float)
    x = np.concatenate([c + 0.1 * rng.standard_normal((6, 2)) for c in centres])
    keep = rules.kmeans_representatives(x, 3, seed=1)
    assert sorted(i // 6 for i in keep) == [0, 1, 2]
    assert rules.kmeans_representatives(x, 3, seed=1) == keep
    assert rules.kmeans_representatives(np.repeat(x[:2], 3, axis=0), 5) == [0, 3]  # only 2 distinct rows


def test_text_embedding_equal_texts_equal_vectors():
    a, b = rules.text_embedding("pick up the ball"), rules.text_embedding("Pick up the ball!")
    assert np.allclose(a, b) and np.linalg.norm(a) == pytest.approx(1.0)
    assert not rules.text_embedding(None).any()


# ----------------------------------------------------------------------------- the set
@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    root = tmp_path_factory.mktemp("bench") / "clips"
    generate_clipset(GenerateConfig(("toyarm", "franka"), episodes=4, width=32, height=32, frames=5, seed=3), root, REG)
    return root


def test_end_effector_pixels_match_the_toy_worlds_own_record(clips):
    """A second implementation: the toy world records where it drew the end effector (meta.toyworld.ee_px)."""
    cs = ClipSet(clips)
    for rec in cs:
        clip = cs.load(rec, video=False, skeleton=False, registry=REG)
        emb = REG.get(rec.embodiment)
        uv, front = rules.end_effector_pixels(emb, emb.check_trajectory(clip.trajectory), clip.camera)
        assert front.all()
        assert np.allclose(uv, np.asarray(rec.meta["toyworld"]["ee_px"], float), atol=0.01)


def test_build_quotas_counts_and_determinism(clips, tmp_path):
    a = build_benchmark_set([clips], tmp_path / "a.json", 5, frames=5, split=None, registry=REG)
    b = build_benchmark_set([clips], tmp_path / "b.json", 5, frames=5, split=None, registry=REG)
    assert a["clips"] == b["clips"] and a["fingerprint"] == b["fingerprint"]
    assert {g: q["quota"] for g, q in a["quotas"].items()} == {"franka/toyworld": 3, "toyarm/toyworld": 2}
    assert a["counts"] == {"candidates": 8, "forward_window": 0, "dedup": 0, "quota": 3, "chosen": 5}
    assert load_benchmark_set(tmp_path / "a.json")["fingerprint"] == a["fingerprint"]
    with pytest.raises(
        BenchmarkSetError,
        match=r"found no clip to choose \(8 candidates: 8 dropped by the forward "
        r"window \(horizon 6 frames",
    ):
        build_benchmark_set([clips], tmp_path / "s.json", 5, frames=6, split=None, registry=REG)
    assert not (tmp_path / "s.json").exists()  # an empty set is never written


def test_a_set_smaller_than_total_warns_naming_the_shortfall(clips, tmp_path, caplog):
    with caplog.at_level("WARNING", logger="oscar"):
        data = build_benchmark_set([clips], tmp_path / "s.json", 400, frames=5, split=None, registry=REG)
    assert data["counts"]["chosen"] == 8
    assert [r.getMessage() for r in caplog.records if r.levelname == "WARNING"] == [
        f"benchmark set {tmp_path / 's.json'}: 8 clips, 392 short of --total 400 (8 candidates: 0 dropped by the "
        "forward window (horizon 5 frames, margin 0.0), 0 as near-duplicates)"
    ]
    caplog.clear()
    with caplog.at_level("WARNING", logger="oscar"):
        build_benchmark_set([clips], tmp_path / "f.json", 8, frames=5, split=None, registry=REG)
    assert not [r for r in caplog.records if r.levelname == "WARNING"]  # a full set: no warning


def test_cli_refuses_an_empty_set_and_running_one(clips, tmp_path, capsys):
    code = main(
        [
            "eval",
            "benchmark",
            "build",
            str(clips),
            "--out",
            str(tmp_path / "s.json"),
            "--total",
            "4",
            "--frames",
            "99",
            "--split",
            "all",
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and "no clip to choose" in err and "Traceback" not in err
    # a set file with no clips (an older build wrote them) is refused by run and table before any work
    build_benchmark_set([clips], tmp_path / "one.json", 1, frames=5, split=None, registry=REG)
    d = json.loads((tmp_path / "one.json").read_text())
    d["clips"], d["counts"]["chosen"] = [], 0
    from oscar_core._util import stage

    parts = {k: d[k] for k in ("format", "format_version", "settings", "clipsets")}
    parts["clips"] = []
    d["fingerprint"] = stage.fingerprint(parts)
    (tmp_path / "empty.json").write_text(json.dumps(d))
    code = main(
        [
            "eval",
            "benchmark",
            "run",
            str(tmp_path / "empty.json"),
            "--model",
            "oscar-toy",
            "--out",
            str(tmp_path / "ro"),
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and "field 'clips': expected at least one clip, found an empty set" in err
    assert not (tmp_path / "ro").exists()


def test_dedup_feature_blocks_weigh_the_same_when_few_caption_columns_vary():
    """The caption block's total variance equals the motion column's (1), however many caption columns are
    constant: 13 varying of 256, as toy captions give."""
    rng = np.random.default_rng(0)
    text = np.zeros((20, 256))
    text[:, :13] = rng.normal(size=(20, 13)) * rng.uniform(0.01, 5.0, 13)
    motion = rng.uniform(0.0, 0.3, 20)
    x = rules.dedup_features(text, motion)
    assert x[:, :-1].var(axis=0).sum() == pytest.approx(1.0, rel=1e-12)
    assert x[:, -1].var() == pytest.approx(1.0, rel=1e-12)
    assert not x[:, 13:-1].any()  # constant columns carry nothing
    # every column varies: the block is still worth 1 in all
    full = rules.dedup_features(rng.normal(size=(20, 256)), motion)
    assert full[:, :-1].var(axis=0).sum() == pytest.approx(1.0, rel=1e-12)
    # nothing varies: zeros, no division by zero
    assert not rules.dedup_features(np.ones((5, 8)), np.ones(5)).any()


def test_a_clip_whose_end_effector_leaves_the_frame_is_dropped(clips, tmp_path):
    moved = tmp_path / "clips"
    shutil.copytree(clips, moved)
    cs = ClipSet(moved)
    rec = cs.record("toyarm-000001")
    cam = json.loads(cs.path(rec, "camera").read_text())
    cam["intrinsics"]["cx"] += 200.0  # the whole image content shifts 200 px right: off a 32-px frame
    cs.path(rec, "camera").write_text(json.dumps(cam))
    data = build_benchmark_set([moved], tmp_path / "s.json", 8, frames=5, split=None, registry=REG)
    gone = [d for d in data["dropped"] if d["rule"] == "forward_window"]
    assert [d["id"] for d in gone] == ["toyarm-000001"] and gone[0]["frame"] == 0
    assert "toyarm-000001" not in {c["id"] for c in data["clips"]} and data["counts"]["chosen"] == 7


def test_exact_duplicates_keep_one_per_group(clips, tmp_path):
    dup = tmp_path / "dup"
    shutil.copytree(clips, dup)
    for shard in sorted(dup.glob("shard-*")):  # a copy of every shard, each clip under a new id
        copy = shard.with_name(shard.name + "-copy")
        shutil.copytree(shard, copy)
        lines = [json.loads(x) for x in (copy / "clips.jsonl").read_text().splitlines() if x.strip()]
        (copy / "clips.jsonl").write_text("".join(json.dumps({**d, "id": d["id"] + "-dup"}) + "\n" for d in lines))
    data = build_benchmark_set([dup], tmp_path / "s.json", 16, frames=5, split=None, registry=REG)
    ids = [c["id"] for c in data["clips"]]
    assert len(ids) == 8 and data["counts"]["dedup"] == 8
    assert len({i.removesuffix("-dup") for i in ids}) == 8  # one of every original/copy pair
    with_clusters = build_benchmark_set([dup], tmp_path / "k.json", 4, frames=5, split=None, clusters=4, registry=REG)
    assert with_clusters["counts"]["dedup"] == 8 and with_clusters["counts"]["quota"] == 4
    assert len({c["id"].removesuffix("-dup") for c in with_clusters["clips"]}) == 4


def test_an_edited_set_file_is_refused(clips, tmp_path):
    build_benchmark_set([clips], tmp_path / "s.json", 3, frames=5, split=None, registry=REG)
    d = json.loads((tmp_path / "s.json").read_text())
    d["clips"] = d["clips"][:2]
    (tmp_path / "s.json").write_text(json.dumps(d))
    with pytest.raises(BenchmarkSetError, match="field 'fingerprint'"):
        load_benchmark_set(tmp_path / "s.json")


# ----------------------------------------------------------------------------- rollouts and the table
@dataclass
class _Card:
    condition: str = "skeleton"
    name: str = "truth"


class TruthModel:
    """Stands in for a world model: returns the true video of the clip whose first frame it is given."""

    def __init__(self, clipset_root, frames):
        cs = ClipSet(clipset_root)
        self.videos = {}
        for r in cs:
            v = cs.load(r, skeleton=False).rgb[:frames]
            self.videos[v[0].tobytes()] = v
        self.card = _Card()
        self.calls = 0

    def rollout(self, first, cond, embeds=None, **options):
        self.calls += 1
        assert cond is not None and len(cond) == len(next(iter(self.videos.values())))
        return self.videos[np.asarray(first).tobytes()].copy()


def _l1_lpips(x, y):
    return (x - y).abs().mean(dim=(1, 2, 3))


def test_run_resumes_and_refuses_other_settings_then_the_table_of_truth(clips, tmp_path):
    build_benchmark_set([clips], tmp_path / "s.json", 4, frames=5, split=None, registry=REG)
    bench = load_benchmark_set(tmp_path / "s.json")
    model = TruthModel(clips, 5)
    out = tmp_path / "truth"
    s = run_benchmark(model, bench, out, sampler=SamplerConfig(steps=2), registry=REG, model_id="truth")
    assert (s["written"], s["kept"], model.calls) == (4, 0, 4)
    first = bench["clips"][0]["id"]
    (out / f"{first}.json").unlink()  # as if killed after its video, before its completion record
    s = run_benchmark(model, bench, out, sampler=SamplerConfig(steps=2), registry=REG, model_id="truth")
    assert (s["written"], s["kept"], model.calls) == (1, 3, 5)
    with pytest.raises(StageChanged, match=r"sampler.steps: 2 -> 3"):
        run_benchmark(model, bench, out, sampler=SamplerConfig(steps=3), registry=REG, model_id="truth")

    table = benchmark_table(bench, {"truth": str(out)}, networks={"lpips": _l1_lpips})
    row = table["rows"]["truth"]["mean_over_embodiments"]
    assert row["psnr"] == pytest.approx(100.0) and row["ssim"] == pytest.approx(1.0)
    assert row["lpips"] == pytest.approx(0.0, abs=1e-7) and row["tlpips"] == pytest.approx(0.0, abs=1e-7)
    assert row["fvd"] is None and "fvd" in table["missing"] and "latent_l2" in table["missing"]
    assert set(table["rows"]["truth"]["per_embodiment"]) == {"toyarm", "franka"}

    # a row over another set, and a row lacking a clip, are refused before any scoring
    build_benchmark_set([clips], tmp_path / "t.json", 3, frames=5, split=None, registry=REG)
    other = load_benchmark_set(tmp_path / "t.json")
    with pytest.raises(BenchmarkTableError, match=r"--pred truth=.*rollouts of another set"):
        benchmark_table(other, {"truth": str(out)})
    (out / f"{first}.npy").unlink()
    with pytest.raises(BenchmarkTableError, match=rf"--pred truth=.*found 3 \(lacking {first}\)"):
        benchmark_table(bench, {"truth": str(out)})


def test_cli_end_to_end_with_the_bundled_toy_model(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")
    monkeypatch.setenv("OSCAR_WEIGHTS_CACHE", str(tmp_path / "no-weights"))
    root = tmp_path / "clips"
    generate_clipset(GenerateConfig(("toyarm", "kuka"), episodes=1, width=64, height=64, frames=17, seed=5), root, REG)
    assert (
        main(
            [
                "-q",
                "eval",
                "benchmark",
                "build",
                str(root),
                "--out",
                str(tmp_path / "s.json"),
                "--total",
                "2",
                "--frames",
                "17",
                "--split",
                "all",
            ]
        )
        == 0
    )
    run = [
        "-q",
        "eval",
        "benchmark",
        "run",
        str(tmp_path / "s.json"),
        "--model",
        "oscar-toy",
        "--out",
        str(tmp_path / "toy"),
        "--steps",
        "2",
        "--guidance",
        "3",
    ]
    assert main(run) == 0
    assert "2 rollouts written" in capsys.readouterr().out
    assert main(run) == 0 and "0 rollouts written, 2 kept" in capsys.readouterr().out
    assert main(run[:-1] + ["4"]) == 2  # other guidance into the same folder: refused
    assert "guidance: 3.0 -> 4.0" in capsys.readouterr().err
    assert (
        main(
            [
                "-q",
                "eval",
                "benchmark",
                "table",
                "--set",
                str(tmp_path / "s.json"),
                "--pred",
                f"toy={tmp_path / 'toy'}",
                "--out",
                str(tmp_path / "table.json"),
            ]
        )
        == 0
    )
    table = json.loads((tmp_path / "table.json").read_text())
    row = table["rows"]["toy"]["mean_over_embodiments"]
    assert 5.0 < row["psnr"] < 100.0 and 0.0 < row["ssim"] < 1.0 and row["frames_per_s"] > 0
    assert row["lpips"] is None and "lpips" in table["missing"]
    assert (tmp_path / "table.md").read_text().startswith("Averaged over 2 embodiments (2 clips, first 17 frames)")


SAMPLER_FLAGS = ("steps", "preset", "guidance_interval", "shift", "guidance", "guidance_form")


def test_eval_commands_share_one_sampler_flag_set(capsys):
    from oscar_core.cli import build_parser
    from oscar_core.evaluation.cli_options import resolve_sampler_flags

    parser = build_parser()
    heads = {
        "run": ["eval", "run", "m.json", "--model", "x", "--out", "o"],
        "closed-loop": ["eval", "closed-loop", "m.json", "--model", "x", "--out", "o"],
        "benchmark run": ["eval", "benchmark", "run", "s.json", "--model", "x", "--out", "o"],
    }
    flags = ["--steps", "7", "--guidance-interval", "0.2,0.8", "--shift", "3", "--guidance", "2", "--guidance-form"]
    parsed = {name: parser.parse_args(head + flags + ["diffusers"]) for name, head in heads.items()}
    values = {name: tuple(getattr(a, f) for f in SAMPLER_FLAGS) for name, a in parsed.items()}
    assert len(set(values.values())) == 1, values
    defaults = {name: tuple(getattr(parser.parse_args(h), f) for f in SAMPLER_FLAGS) for name, h in heads.items()}
    assert len(set(defaults.values())) == 1 and defaults["run"][3] == 5.0, defaults
    # the shift reaches the sampler of a benchmark run, over a card that recommends other steps
    cfg = resolve_sampler_flags(parsed["benchmark run"], lambda: {"steps": 20, "guidance": 6.0}).config
    assert (cfg.steps, cfg.shift, cfg.guidance, cfg.guidance_interval) == (7, 3.0, 2.0, (0.2, 0.8))
    for head in heads.values():  # the same checks: a shift must be positive
        with pytest.raises(SystemExit):
            parser.parse_args(head + ["--shift", "0"])
    assert "expected a number > 0" in capsys.readouterr().err
