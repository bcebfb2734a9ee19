"""Dedup: SigLIP through a tiny random config of the real class, candidates identical to brute force, trajectory
verification with the adaptive threshold, deterministic union-find groups."""

import numpy as np
import pytest
from _datasets import base_parts, write_episode

from oscar_core.data.dedup import (
    DedupConfig,
    SiglipEmbedder,
    UnionFind,
    adaptive_threshold,
    brute_force_pairs,
    candidate_pairs,
    dedup_rows,
    motion_scale,
    pca_projection,
    resample_points,
    trajectory_rms,
)

transformers = pytest.importorskip("transformers")
pytest.importorskip("faiss")


@pytest.fixture(scope="module")
def tiny_siglip(tmp_path_factory):
    import torch

    torch.manual_seed(0)
    cfg = transformers.SiglipVisionConfig(
        hidden_size=32, intermediate_size=37, num_hidden_layers=2, num_attention_heads=2, image_size=32, patch_size=8
    )
    path = tmp_path_factory.mktemp("siglip") / "tiny-siglip"
    transformers.SiglipVisionModel(cfg).save_pretrained(path)
    return str(path)


def clustered(n, d=64, per=8, spread=0.4, seed=0):
    """(n, d) unit rows around n/per centres; the noise level varies so thousands of pairs sit near 0.95."""
    rng = np.random.default_rng(seed)
    centres = rng.standard_normal((n // per, d))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    x = centres[rng.integers(0, len(centres), n)] + rng.uniform(0, spread, (n, 1)) * rng.standard_normal(
        (n, d)
    ) / np.sqrt(d)
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


def test_found_pairs_are_identical_to_brute_force():
    x = clustered(3000)
    sims = x @ x.T
    near = np.sum((sims > 0.9) & (sims <= 0.95)) // 2
    bf = brute_force_pairs(x)
    assert len(bf) > 3000 and near > 3000  # many pairs on both sides of the threshold
    got = candidate_pairs(x, 0.95, nlist=64, nprobe=8)  # the IVF path: 64 k-means clusters, 8 searched
    np.testing.assert_array_equal(got, bf)
    # and the reference itself against the definition
    i, j = np.nonzero(np.triu(sims > 0.95, 1))
    np.testing.assert_array_equal(bf, np.stack([i, j], 1))


def test_projected_search_loses_no_pair_and_keeps_no_false_one():
    # 256-d rows projected onto 24 principal directions: the projection never lengthens a distance, so probing every
    # list finds exactly the brute-force pairs; the default probes at this size find them all too
    x = clustered(3000, d=256, per=6)
    bf = brute_force_pairs(x)
    assert len(bf) > 2000
    np.testing.assert_array_equal(candidate_pairs(x, 0.95, nlist=32, nprobe=32, reduce_dim=24), bf)
    timings = {}
    np.testing.assert_array_equal(candidate_pairs(x, 0.95, nlist=32, nprobe=8, reduce_dim=24, timings=timings), bf)
    assert set(timings) == {"project", "kmeans", "assign", "blocks", "check"}
    # small blocks (many matrix products per list) give the same pairs
    np.testing.assert_array_equal(candidate_pairs(x, 0.95, nlist=32, nprobe=8, reduce_dim=24, block=1000), bf)


def test_pca_projection_is_orthonormal_and_never_lengthens_a_distance():
    x = clustered(2000, d=96)
    mean, basis = pca_projection(x, 16)
    np.testing.assert_allclose(basis.T @ basis, np.eye(16), atol=1e-5)
    rng = np.random.default_rng(3)
    i, j = rng.integers(0, len(x), (2, 5000))
    full = np.linalg.norm(x[i] - x[j], axis=1)
    proj = np.linalg.norm((x[i] - mean) @ basis - (x[j] - mean) @ basis, axis=1)
    assert np.all(proj <= full + 1e-5) and proj.mean() < full.mean()
    # the first direction is the one of largest variance: it matches numpy's SVD of the centred rows
    _, _, vt = np.linalg.svd(x - x.mean(0), full_matrices=False)
    assert abs(float(basis[:, 0] @ vt[0])) == pytest.approx(1.0, abs=1e-4)


def test_one_probe_misses_pairs_that_more_probes_find():
    # the search really is restricted to nearby clusters (not a hidden all-pairs scan)
    x = clustered(3000)
    assert len(candidate_pairs(x, 0.95, nlist=64, nprobe=1)) < len(brute_force_pairs(x))


def test_union_find_joins_transitively():
    uf = UnionFind(6)
    uf.union(0, 1), uf.union(1, 2), uf.union(4, 5)
    assert uf.find(2) == uf.find(0) and uf.find(3) != uf.find(0) and uf.find(4) == uf.find(5)
    assert not uf.union(2, 0)


def test_rms_scale_and_threshold_closed_forms():
    a = np.zeros((64, 1, 3))
    a[:, 0, 0] = np.where(np.arange(64) < 32, -0.1, 0.1)  # scale: every point 0.1 m from the mean
    assert motion_scale(a) == pytest.approx(0.1)
    assert trajectory_rms(a, a + [0.03, 0.04, 0.0]) == pytest.approx(0.05)
    cfg = DedupConfig()
    assert adaptive_threshold(0.1, 0.4, cfg) == pytest.approx(0.025)
    assert adaptive_threshold(0.001, 0.4, cfg) == cfg.rms_floor
    r = resample_points(np.arange(5, dtype=float).reshape(5, 1, 1).repeat(3, -1), 9)
    np.testing.assert_allclose(r[:, 0, 0], np.arange(9) / 2)


def _row(i, emb, traj, length=81, embodiment="toyarm"):
    return {
        "id": f"s/{i}",
        "embodiment": embodiment,
        "length": length,
        "dedup_status": "ok",
        "dedup_embedding": emb.tolist(),
        "dedup_traj": traj.ravel().tolist(),
    }


def test_groups_keep_the_longest_then_smallest_id_in_any_order():
    rng = np.random.default_rng(1)
    e = rng.standard_normal(8).astype(np.float32)
    e /= np.linalg.norm(e)
    t = rng.standard_normal((64, 2, 3))
    rows = [
        _row("c", e, t, 81),
        _row("a", e, t + 1e-4, 81),
        _row("b", e, t, 90),
        _row("d", e, t + 5.0),  # same scene, another motion
        _row("e", e, t, embodiment="franka"),
    ]  # same numbers, another body
    for order in (rows, rows[::-1]):
        out, summary = dedup_rows(order, DedupConfig())
        by = {r["id"]: r for r in out}
        assert [k for k in sorted(by) if by[k]["dedup_status"] == "ok"] == ["s/b", "s/d", "s/e"]
        assert by["s/a"]["dedup_reason"].startswith("duplicate: of s/b") and by["s/c"]["dedup_group"] == "s/b"
        assert summary == {"episodes": 5, "candidates": 10, "verified": 3, "removed": 2}
        assert "dedup_embedding" not in by["s/a"]


@pytest.mark.slow
def test_embedder_prepares_frames_as_siglips_image_processor(tiny_siglip):
    import torch

    frames = np.random.default_rng(0).integers(0, 255, (3, 40, 56, 3), dtype=np.uint8)
    proc = transformers.SiglipImageProcessorPil(size={"height": 32, "width": 32})
    ref = proc(images=list(frames), return_tensors="pt")["pixel_values"]
    ours = SiglipEmbedder.pixel_values(frames, 32)
    torch.testing.assert_close(ours, ref, atol=1e-5, rtol=0)
    emb = SiglipEmbedder(tiny_siglip)(frames)
    assert emb.shape == (3, 32) and np.allclose(np.linalg.norm(emb, axis=1), 1)


@pytest.mark.slow
def test_same_scene_same_motion_one_kept_different_motion_both_kept(tmp_path, tiny_siglip):
    from oscar_core.data.engine import read_stage
    from oscar_core.data.run import run_dedup, run_ingest

    traj, _ = base_parts()
    src = tmp_path / "src"
    write_episode(src, "a", traj, seed=0)
    noisy = traj.replace(q=traj.q + np.random.default_rng(0).normal(0, 1e-3, traj.q.shape))
    write_episode(src, "b", noisy, seed=0)  # same scene, same motion (sensor noise)
    write_episode(src, "c", traj.replace(q=traj.q[::-1].copy(), gripper=traj.gripper[::-1].copy()), seed=0)  # reversed
    run = str(tmp_path / "run")
    run_ingest(str(src), "npz", run, workers=1, progress=False)
    _, summary = run_dedup(run, SiglipEmbedder(tiny_siglip), workers=1, progress=False)
    rows = {r["id"]: r for r in read_stage(str(tmp_path / "run" / "dedup"))}
    assert summary["candidates"] == 3  # all three look alike: only the trajectories tell c apart
    assert rows["src/a"]["dedup_status"] == "ok" and rows["src/c"]["dedup_status"] == "ok"
    assert rows["src/b"]["dedup_status"] == "rejected" and rows["src/b"]["dedup_reason"].startswith(
        "duplicate: of src/a"
    )
    assert rows["src/b"]["dedup_value"] < 0.01
