"""Quality against chunk index: long rollouts chunk after chunk, and the toy-world metrics split by chunk."""

import json

import numpy as np
import pytest
from _models import tiny_world_model

from oscar_core.cli import main
from oscar_core.model.sampler import SamplerConfig
from oscar_core.plugin.registry import Registry
from oscar_core.toyworld.evaluate import PSNR_CAP, evaluate_conditions
from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
from oscar_core.toyworld.per_chunk import chunk_metrics
from oscar_core.toyworld.rollouts import write_rollouts
from oscar_core.train.clips import ClipSet

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def test_per_chunk_refuses_a_one_frame_chunk_or_video_naming_the_flag():
    # the windows are the rollout's (tests/model/test_rollout.py); the flag's own messages stay here
    with pytest.raises(ValueError, match="--per-chunk: expected a chunk of at least 2 frames"):
        chunk_metrics(np.zeros((9, 16, 16, 3), np.uint8), np.zeros((9, 16, 16, 3), np.uint8), 1)
    with pytest.raises(ValueError, match="--per-chunk: expected a video of at least 2 frames"):
        chunk_metrics(np.zeros((1, 16, 16, 3), np.uint8), np.zeros((1, 16, 16, 3), np.uint8), 17)


def test_per_chunk_psnr_and_motion_iou_of_a_known_error():
    """Chunk 1 exact; chunk 2 off by a constant 10 levels (PSNR 20 log10(255 / 10)) and its moving square shifted
    by half its width (motion IoU 1/3)."""
    rng = np.random.default_rng(0)
    gt = rng.integers(40, 50, (25, 32, 32, 3), dtype=np.uint8)  # noise: below the motion threshold, even + 10
    gt[1:, :8, :16] = 200  # a rectangle that appears (changed from frame 0 by > 24 levels) from frame 1 on
    pred = gt.copy()
    pred[9:] = gt[9:] + 10
    pred[9:, :8, :8] = gt[0, :8, :8] + 10  # chunks 2-3: no change there ...
    pred[9:, :8, 8:24] = 200  # ... the rectangle 8 pixels right: intersection 64, union 192
    per = chunk_metrics(pred, gt, chunk_frames=9)
    assert [c["frames"] for c in per] == [[1, 8], [9, 16], [17, 24]]
    assert per[0]["psnr_db"] == PSNR_CAP and per[0]["motion_iou"] == 1.0 and per[0]["ssim"] == pytest.approx(1.0)
    for c in per[1:]:
        assert c["motion_iou"] == pytest.approx(1 / 3)
    off = np.ones((32, 32), bool)
    off[:8, :24] = False  # outside both squares: exactly 10 levels
    d = pred[9:17].astype(np.float64) - gt[9:17]
    assert np.all(d[:, off] == 10)
    mse = (d**2).mean(axis=(1, 2, 3))
    assert per[1]["psnr_db"] == pytest.approx(np.mean(10 * np.log10(255.0**2 / mse)), abs=1e-9)

    const = gt.copy()
    const[9:] = gt[9:] + 10  # a constant error everywhere in chunks 2 and 3
    per = chunk_metrics(const, gt, chunk_frames=9)
    assert per[0]["psnr_db"] == PSNR_CAP
    assert per[1]["psnr_db"] == pytest.approx(20 * np.log10(255 / 10), abs=1e-9)  # 28.13 dB
    assert per[2]["psnr_db"] == pytest.approx(20 * np.log10(255 / 10), abs=1e-9)


@pytest.fixture(scope="module")
def long_clips(tmp_path_factory):
    """Episodes of 25 frames: three 9-frame chunks (1 + 3 x 8); toyarm-000009 is the held-out one."""
    root = tmp_path_factory.mktemp("long") / "clips"
    cfg = GenerateConfig(
        embodiments=("toyarm",), episodes=10, width=32, height=32, frames=25, seed=1, shard_size=10, supersample=1
    )
    generate_clipset(cfg, root, Registry())
    return root


def test_a_long_clip_rolls_out_chunk_after_chunk(tmp_path, long_clips):
    model = tiny_world_model(skeleton_scale=0.5, name="tiny", chunk_frames=9, width=32, height=32)
    sampler = SamplerConfig(steps=2, guidance=2.0)
    calls = []
    hook = model.transformer.register_forward_pre_hook(lambda m, a: calls.append(1))
    try:
        cs = ClipSet(long_clips)
        rec = cs.record("toyarm-000009")
        first = cs.load(rec, frames=1, skeleton=False).rgb[0]
        skel = cs.load(rec, video=False).skeleton
        model.rollout(first, skel[:9], sampler=sampler, progress=False)
        one_chunk = len(calls)
        calls.clear()
        s = write_rollouts(model, long_clips, tmp_path / "pred", split="heldout", sampler=sampler)
    finally:
        hook.remove()
    assert s["written"] == 1 and one_chunk > 0
    assert len(calls) == 3 * one_chunk  # three chunks of the DiT's evaluations
    video = np.load(tmp_path / "pred" / "toyarm-000009.npy")
    assert video.shape == (25, 32, 32, 3)

    # the per-chunk table of that rollout, against itself and against a prediction frozen after chunk 1
    frozen = tmp_path / "frozen"
    frozen.mkdir()
    still = video.copy()
    still[9:] = video[8]
    np.save(frozen / "toyarm-000009.npy", still)
    out = tmp_path / "drift.json"
    rc = main(
        [
            "toyworld",
            "eval",
            "--gt",
            str(long_clips),
            "--pred",
            f"model={tmp_path / 'pred'}",
            "--pred",
            f"frozen={frozen}",
            "--paired",
            "model",
            "--per-chunk",
            "9",
            "--out",
            str(out),
            "--no-html",
        ]
    )
    assert rc == 0
    table = json.loads(out.read_text())
    assert table["per_chunk"] == 9
    rows = table["rows"]
    assert [c["clips"] for c in rows["model"]["chunks"]] == [1, 1, 1]
    gt = ClipSet(long_clips).load(rec, skeleton=False).rgb
    want = chunk_metrics(video, gt, 9)
    for k in range(3):
        assert rows["model"]["chunks"][k]["psnr_db"] == pytest.approx(want[k]["psnr_db"])
    paired = table["paired"]["chunks"]["frozen"]
    assert len(paired) == 3
    assert paired[0]["psnr_db"]["mean"] == 0.0 and paired[0]["psnr_db"]["ci"] == [0.0, 0.0]  # chunk 1 is the same
    assert paired[1]["psnr_db"]["mean"] == pytest.approx(chunk_metrics(still, gt, 9)[1]["psnr_db"] - want[1]["psnr_db"])
    # without --per-chunk the table has no chunks
    plain = evaluate_conditions(long_clips, {"model": str(tmp_path / "pred")})
    assert plain["per_chunk"] is None and "chunks" not in plain["rows"]["model"]
