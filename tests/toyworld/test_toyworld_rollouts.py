"""Toy-world predictions from a world model: the three skeleton conditions, resume, and the demo's row."""

import numpy as np
import pytest
from _models import tiny_world_model

from oscar_core.model.sampler import SamplerConfig
from oscar_core.model.world_model import ModelCard, OscarWorldModel
from oscar_core.plugin.registry import Registry
from oscar_core.toyworld.demo import side_by_side
from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
from oscar_core.toyworld.rollouts import sampler_for_card, skeleton_partners, write_rollouts
from oscar_core.train.clips import ClipRecord, ClipSet

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    root = tmp_path_factory.mktemp("toy") / "clips"
    generate_clipset(
        GenerateConfig(
            embodiments=("toyarm", "franka"),
            episodes=20,
            width=32,
            height=32,
            frames=9,
            seed=0,
            shard_size=20,
            supersample=1,
        ),
        root,
        Registry(),
    )
    return root


@pytest.fixture(scope="module")
def model():
    """A tiny model whose skeleton embedder is not zero, so the skeleton changes the video."""
    return tiny_world_model(skeleton_scale=0.5, name="tiny", chunk_frames=9, width=32, height=32)


FAST = SamplerConfig(steps=2, guidance=2.0)


def _rec(cid, emb):
    return ClipRecord(
        id=cid, source="s", embodiment=emb, n_frames=9, fps=10.0, width=32, height=32, openness=(), files={}
    )


def test_shuffled_partners_are_a_derangement_within_each_embodiment():
    recs = [_rec("a0", "a"), _rec("b0", "b"), _rec("a1", "a"), _rec("a2", "a"), _rec("b1", "b"), _rec("c0", "c")]
    p = skeleton_partners(recs)
    assert p == {"a0": "a1", "a1": "a2", "a2": "a0", "b0": "b1", "b1": "b0", "c0": "c0"}


def test_conditions_differ_and_zero_ignores_the_skeleton(tmp_path, clips, model):
    runs = {}
    for cond in ("true", "shuffled", "zero"):
        s = write_rollouts(model, clips, tmp_path / cond, cond, split="heldout", sampler=FAST)
        assert (s["written"], s["kept"]) == (4, 0)
        runs[cond] = {p.stem: np.load(p) for p in (tmp_path / cond).glob("*.npy")}
    assert sorted(runs["true"]) == ["franka-000009", "franka-000019", "toyarm-000009", "toyarm-000019"]
    for cid, video in runs["true"].items():
        assert video.shape == (9, 32, 32, 3) and video.dtype == np.uint8
        assert not np.array_equal(video, runs["shuffled"][cid])  # another skeleton, another video
        assert not np.array_equal(video, runs["zero"][cid])
    # zero: the unconditional branch alone, whatever skeleton the clip has
    cs = ClipSet(clips)
    rec = cs.record("franka-000009")
    first = cs.load(rec, frames=1, skeleton=False).rgb[0]
    skel = cs.load(rec, video=False).skeleton
    want = model.rollout(
        first,
        np.zeros_like(skel),
        sampler=SamplerConfig(steps=2, guidance=0.0, guidance_form="standard"),
        progress=False,
    ).frames
    np.testing.assert_array_equal(runs["zero"]["franka-000009"], want)
    # true: the stored skeleton with the given sampler
    want = model.rollout(first, skel, sampler=FAST, progress=False).frames
    np.testing.assert_array_equal(runs["true"]["franka-000009"], want)


def test_train_split_shuffles_across_clips_and_resume_keeps_written(tmp_path, clips, model):
    s = write_rollouts(model, clips, tmp_path / "sh", "shuffled", split="train", limit=3, sampler=FAST)
    assert s["written"] == 3
    a = {p.stem: np.load(p) for p in (tmp_path / "sh").glob("*.npy")}
    t = write_rollouts(model, clips, tmp_path / "tr", "true", split="train", limit=3, sampler=FAST)
    b = {p.stem: np.load(p) for p in (tmp_path / "tr").glob("*.npy")}
    assert {k.split("-")[0] for k in a} == {"franka", "toyarm"}  # the limit spreads over the set
    # partners are drawn among the clips rolled out: the two franka clips swap skeletons, the lone toyarm clip
    # keeps its own
    franka = sorted(k for k in a if k.startswith("franka"))
    assert t["written"] == 3 and len(franka) == 2
    assert all(not np.array_equal(a[k], b[k]) for k in franka)
    toy = next(k for k in a if k.startswith("toyarm"))
    np.testing.assert_array_equal(a[toy], b[toy])
    (tmp_path / "sh" / f"{sorted(a)[0]}.npy").unlink()
    s = write_rollouts(model, clips, tmp_path / "sh", "shuffled", split="train", limit=3, sampler=FAST)
    assert (s["written"], s["kept"]) == (1, 2)
    # other settings into the same folder: refused, naming what changed, never "kept"
    from oscar_core._util.stage import StageChanged

    with pytest.raises(StageChanged, match=r"seed: 0 -> 1.*use another --out"):
        write_rollouts(model, clips, tmp_path / "sh", "shuffled", split="train", limit=3, sampler=FAST, seed=1)
    with pytest.raises(StageChanged, match=r"condition: shuffled -> true"):
        write_rollouts(model, clips, tmp_path / "sh", "true", split="train", limit=3, sampler=FAST)
    with pytest.raises(StageChanged, match=r"sampler.steps: 2 -> 3"):
        write_rollouts(
            model,
            clips,
            tmp_path / "sh",
            "shuffled",
            split="train",
            limit=3,
            sampler=SamplerConfig(steps=3, guidance=2.0),
        )
    with pytest.raises(ValueError, match="condition"):
        write_rollouts(model, clips, tmp_path / "x", "reversed")
    with pytest.raises(ValueError, match="meta.split == 'nope'"):
        write_rollouts(model, clips, tmp_path / "x", "true", split="nope")


def test_sampler_for_card_defaults():
    s = sampler_for_card(ModelCard())
    assert (s.steps, s.guidance, s.guidance_form) == (35, 6.0, "diffusers")
    s = sampler_for_card(ModelCard(), steps=10, guidance=0.0, guidance_form="standard")
    assert (s.steps, s.guidance, s.guidance_form) == (10, 0.0, "standard")


def test_side_by_side_layout():
    a = np.zeros((5, 4, 6, 3), np.uint8)
    b = np.full((5, 4, 6, 3), 7, np.uint8)
    v = side_by_side(a, b, scale=2, gap=3)
    assert v.shape == (5, 8, 12 + 3 + 12, 3)
    assert (v[:, :, :12] == 0).all() and (v[:, :, 12:15] == 255).all() and (v[:, :, 15:] == 7).all()


def test_demo_adds_the_toy_world_row(tmp_path, model):
    from oscar_core.demo import run_demo

    folder = tmp_path / "m"
    OscarWorldModel(
        model.transformer, model.vae, ModelCard(name="tiny", chunk_frames=9, width=32, height=32)
    ).save_pretrained(folder)
    summary = run_demo(tmp_path / "demo", size=(64, 48), names=["toyarm"], toy_model=str(folder), log=lambda m: None)
    assert (tmp_path / "demo" / "toyworld_rollout.mp4").is_file()
    assert summary["toy_world"]["episode"].startswith("franka-000009")
    from oscar_core.media.video import read_video

    v = read_video(tmp_path / "demo" / "toyworld_rollout.mp4")
    assert v.shape == (9, 64, 3 * 64 + 2 * 2, 3)  # three 32x32 panels scaled 2x, 2-pixel gaps
    # a model that cannot be loaded is reported, not fatal
    summary = run_demo(
        tmp_path / "demo2", size=(64, 48), names=["toyarm"], toy_model=str(tmp_path / "none"), log=lambda m: None
    )
    assert "toy_world" not in summary and any("toy_world" in s for s in summary["skipped"])


def test_package_writes_a_loadable_named_folder_with_a_model_card(tmp_path, model):
    from oscar_core.toyworld.package import file_hashes, package_toy_model

    export = tmp_path / "export"
    model.save_pretrained(export)
    table = {
        "rows": {
            "true skeleton": {
                "clips": 3,
                "psnr_db": 20.0,
                "ssim": 0.5,
                "motion_iou": 0.4,
                "ee_error_px": 5.0,
                "object_error_px": 6.0,
            }
        },
        "markdown": "| condition | clips |\n|---|---|\n| true skeleton | 3 |",
    }
    hashes = package_toy_model(
        export, tmp_path / "out", name="toy-x", training={"steps": 7, "wall": "1 min"}, table=table
    )
    assert hashes == file_hashes(tmp_path / "out") and "README.md" in hashes
    loaded = OscarWorldModel.from_pretrained(tmp_path / "out")
    assert (loaded.card.name, loaded.card.license, loaded.card.text_encoder_id) == ("toy-x", "Apache-2.0", None)
    assert loaded.empty_prompt.shape == (1, 1, model.transformer.text_dim) and not loaded.empty_prompt.any()
    readme = (tmp_path / "out" / "README.md").read_text()
    assert "# toy-x" in readme and "- steps: 7" in readme and "| true skeleton | 3 |" in readme
    assert "Apache-2.0" in readme
    # no prompt given: the stored zero prompt is used, silently (no "zeros" warning)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        emb, source = loaded.resolve_prompt()
    assert not emb.any()
