"""``dedup``: semantic deduplication — SigLIP visual candidates, verified by trajectory distance, merged by union-find.

1. **Embed** (a sharded stage, :class:`EmbedStage`): per live episode, the SigLIP
   image embedding of 5 uniformly sampled frames (each frame's pooled
   embedding L2-normalised, averaged, normalised again), and the skeleton's
   3-D points resampled to 64 uniform steps, (64, K, 3) metres.
2. **Candidates** (:func:`candidate_pairs`): every pair with cosine > 0.95,
   found without an all-pairs scan: faiss k-means into ``nlist`` clusters
   (IVF, inner product), then a range search of each episode within its own
   cluster and its ``nprobe`` − 1 nearest other clusters. Recall against the
   exact answer is measured in the tests and ``benchmarks/data.py``.
3. **Verify** (:func:`trajectory_rms`, :func:`adaptive_threshold`): a candidate
   pair is a duplicate only when both episodes have the same embodiment and
   the per-step RMS distance of their resampled trajectories,
   ``sqrt(mean_t mean_k |a_tk − b_tk|²)`` metres, is below the adaptive threshold
   ``max(rms_floor, rms_alpha · min(scale_a, scale_b))``, where an episode's
   scale is the RMS distance of its points from their mean position over time
   (how much it moves). So two episodes count as the same motion when they
   differ by less than a quarter (``rms_alpha``) of the smaller one's own
   motion: a tight test for small motions, a looser one for sweeping ones,
   and never below 1 cm (``rms_floor``, tracking noise).
4. **Merge** (:class:`UnionFind`): duplicates are joined transitively; each
   group keeps one episode — the longest, ties broken by the smallest id —
   so the choice does not depend on the order of work.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ._episode import EPISODE_ERRORS, load_row, reason_of
from ._optional import require

__all__ = ["DedupConfig", "SiglipEmbedder", "EmbedStage", "resample_points", "candidate_pairs", "brute_force_pairs",
           "trajectory_rms", "motion_scale", "adaptive_threshold", "UnionFind", "dedup_rows"]


@dataclass(frozen=True)
class DedupConfig:
    """Thresholds and search settings of ``oscar data dedup``."""

    cosine: float = 0.95          # SigLIP cosine above which a pair is a visual candidate (paper)
    frames: int = 5               # uniformly sampled frames per episode (paper)
    steps: int = 64               # resampled trajectory steps (paper)
    rms_alpha: float = 0.25       # duplicate when RMS < rms_alpha x the smaller motion scale ...
    rms_floor: float = 0.01       # ... or below this many metres
    nlist: int | None = None      # k-means clusters; None: 4·sqrt(N) (exact search below 2048 episodes)
    nprobe: int = 16              # clusters searched per episode: its own and the nearest others


class SiglipEmbedder:
    """SigLIP image embeddings with transformers' ``SiglipVisionModel``.

    model: a Hub id (``google/siglip-base-patch16-224``) or a local folder
    (``save_pretrained``). The model loads on first use, once per process.
    Frames are resized to the model's square input (PIL bicubic), scaled to
    [0, 1] and normalised with mean = std = 0.5, exactly as transformers'
    ``SiglipImageProcessor`` prepares them (a test checks it).
    """

    def __init__(self, model: str, device: str = "cpu"):
        self.model_name, self.device = str(model), device
        self._model = None

    def __getstate__(self):
        return {"model_name": self.model_name, "device": self.device, "_model": None}

    def model(self):
        if self._model is None:
            tr = require("transformers", "data")
            self._model = tr.SiglipVisionModel.from_pretrained(self.model_name).to(self.device).eval()
        return self._model

    @staticmethod
    def pixel_values(frames: np.ndarray, size: int):
        """(N, H, W, 3) uint8 → (N, 3, size, size) float32 tensor, SigLIP's preprocessing."""
        import torch

        Image = require("PIL.Image", "data")
        x = np.stack([np.asarray(Image.fromarray(np.ascontiguousarray(f)).resize((size, size), Image.BICUBIC))
                      for f in frames])
        return torch.from_numpy(x).permute(0, 3, 1, 2).float().mul(1 / 255.0).sub(0.5).div(0.5)

    def __call__(self, frames: np.ndarray) -> np.ndarray:
        """frames: (N, H, W, 3) uint8 → (N, D) float32 L2-normalised pooled embeddings."""
        import torch

        m = self.model()
        x = self.pixel_values(frames, int(m.config.image_size)).to(self.device)
        with torch.no_grad():
            out = m(pixel_values=x).pooler_output.float().cpu().numpy()
        return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)


def episode_embedding(per_frame: np.ndarray) -> np.ndarray:
    """(D,) unit vector: the normalised mean of (N, D) per-frame unit embeddings."""
    v = per_frame.mean(axis=0)
    return (v / max(float(np.linalg.norm(v)), 1e-12)).astype(np.float32)


def resample_points(points: np.ndarray, steps: int = 64) -> np.ndarray:
    """(T, K, 3) points (metres; NaN = missing) → (steps, K, 3), linear in normalised time; missing filled per point."""
    p = np.asarray(points, dtype=np.float64)
    T = p.shape[0]
    flat = p.reshape(T, -1)
    src = np.linspace(0.0, 1.0, T) if T > 1 else np.zeros(1)
    dst = np.linspace(0.0, 1.0, steps)
    out = np.empty((steps, flat.shape[1]))
    for c in range(flat.shape[1]):
        col = flat[:, c]
        ok = np.isfinite(col)
        out[:, c] = np.interp(dst, src[ok], col[ok]) if ok.any() else 0.0
    return out.reshape(steps, *p.shape[1:])


def trajectory_rms(a: np.ndarray, b: np.ndarray) -> float:
    """Per-step RMS distance, metres, of two (S, K, 3) resampled trajectories."""
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=-1))))


def motion_scale(a: np.ndarray) -> float:
    """RMS distance, metres, of an (S, K, 3) trajectory's points from their mean positions."""
    return float(np.sqrt(np.mean(np.sum((a - a.mean(axis=0)) ** 2, axis=-1))))


def adaptive_threshold(scale_a: float, scale_b: float, cfg: DedupConfig = DedupConfig()) -> float:
    """The RMS (metres) below which a visually similar pair counts as the same motion."""
    return max(cfg.rms_floor, cfg.rms_alpha * min(scale_a, scale_b))


@dataclass(frozen=True)
class EmbedStage:
    """Sharded stage: ``dedup_embedding`` (D floats) and ``dedup_traj`` (steps·K·3 floats) per live row."""

    embedder: Any
    config: DedupConfig = DedupConfig()
    plugin_paths: tuple[str, ...] = ()
    name: str = "dedup-embed"

    def __call__(self, rows: list[dict], shard: str = "") -> list[dict]:
        from .manifest import is_alive

        return [self.one(r) if is_alive(r) else r for r in rows]

    def one(self, row: dict) -> dict:
        out = dict(row, dedup_status="ok", dedup_reason=None, dedup_value=None)
        try:
            ep, emb = load_row(row, self.plugin_paths)
            traj = emb.check_trajectory(ep.trajectory)
            n = ep.video.n_frames
            idx = np.linspace(0, n - 1, self.config.frames).round().astype(int)
            vec = episode_embedding(self.embedder(ep.video.read(idx)))
            pts = resample_points(emb.frames(traj).points, self.config.steps)
        except EPISODE_ERRORS as exc:
            out.update(dedup_status="rejected", dedup_reason=f"unreadable: {reason_of(exc)}")
            return out
        out["dedup_embedding"] = vec.astype(np.float32)
        out["dedup_traj"] = pts.astype(np.float32).ravel()
        return out


def _pairs_from_lims(lims, ids, offset: int) -> np.ndarray:
    """(P, 2) pairs (smaller index first, self-matches dropped) from a faiss range-search result of rows offset…"""
    counts = np.diff(np.asarray(lims, dtype=np.int64))
    rows = np.repeat(np.arange(len(counts), dtype=np.int64) + offset, counts)
    cols = np.asarray(ids, dtype=np.int64)
    keep = rows != cols
    return np.sort(np.stack([rows[keep], cols[keep]], axis=1), axis=1)


def brute_force_pairs(emb: np.ndarray, threshold: float = 0.95, block: int = 4096) -> np.ndarray:
    """(P, 2) int64 pairs i < j with cosine > threshold, by an all-pairs scan (the reference; O(N²))."""
    x = np.ascontiguousarray(emb, dtype=np.float32)
    out = []
    for s in range(0, len(x), block):
        sims = x[s:s + block] @ x.T
        i, j = np.nonzero(sims > threshold)
        i = i + s
        keep = i < j
        out.append(np.stack([i[keep], j[keep]], axis=1))
    pairs = np.concatenate(out) if out else np.zeros((0, 2), np.int64)
    return _sorted_pairs(pairs)


def _sorted_pairs(pairs: np.ndarray) -> np.ndarray:
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if not len(pairs):
        return pairs
    pairs = np.unique(pairs, axis=0)
    return pairs


def candidate_pairs(emb: np.ndarray, threshold: float = 0.95, *, nlist: int | None = None, nprobe: int = 16,
                    exact_below: int = 2048, batch: int = 65536, train_per_list: int = 40, niter: int = 10,
                    seed: int = 0) -> np.ndarray:
    """(P, 2) int64 sorted pairs i < j with cosine(emb_i, emb_j) > threshold; emb: (N, D) unit rows.

    Below ``exact_below`` rows (and with no ``nlist``) a flat range search
    (exact); otherwise faiss IVF: k-means (``niter`` iterations on at most
    ``train_per_list`` sampled points per cluster) into ``nlist`` clusters
    (default 4·sqrt(N)), then each row's range search visits its ``nprobe``
    nearest clusters. Queries run in batches of ``batch`` rows to bound memory.
    """
    faiss = require("faiss", "data")
    x = np.ascontiguousarray(emb, dtype=np.float32)
    n, d = x.shape
    if n < 2:
        return np.zeros((0, 2), np.int64)
    if nlist is None and n < exact_below:
        index = faiss.IndexFlatIP(d)
    else:
        k = int(nlist or max(1, round(4 * np.sqrt(n))))
        k = max(1, min(k, n // 39 if n >= 78 else 1))  # faiss wants >= 39 training points per cluster
        rng = np.random.default_rng(seed)
        m = min(n, max(39, train_per_list) * k)
        train = x if m >= n else x[np.sort(rng.choice(n, m, replace=False))]
        km = faiss.Kmeans(d, k, niter=niter, seed=seed, spherical=True, verbose=False)
        km.train(train)
        quant = faiss.IndexFlatIP(d)
        quant.add(km.centroids)
        index = faiss.IndexIVFFlat(quant, d, k, faiss.METRIC_INNER_PRODUCT)
        index.is_trained = True
        index.nprobe = min(nprobe, k)
    index.add(x)
    out = []
    for s in range(0, n, batch):
        lims, _, ids = index.range_search(x[s:s + batch], float(threshold))
        out.append(_pairs_from_lims(lims, ids, s))  # a pair found from either end counts
    return _sorted_pairs(np.concatenate(out)) if out else np.zeros((0, 2), np.int64)


class UnionFind:
    """Disjoint sets over 0..n-1 with path halving and union by size."""

    def __init__(self, n: int):
        self.parent = np.arange(n)
        self.size = np.ones(n, dtype=np.int64)

    def find(self, i: int) -> int:
        p = self.parent
        while p[i] != i:
            p[i] = p[p[i]]
            i = p[i]
        return int(i)

    def union(self, a: int, b: int) -> bool:
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return False
        if self.size[ra] < self.size[rb]:
            ra, rb = rb, ra
        self.parent[rb] = ra
        self.size[ra] += self.size[rb]
        return True


def dedup_rows(rows, cfg: DedupConfig = DedupConfig()) -> tuple[list[dict], dict[str, Any]]:
    """Decide duplicates among embedded rows; returns (rows with ``dedup_*`` set and the big columns dropped, summary).

    rows: the embed stage's manifest, a pyarrow Table (read columnar: the
    embeddings become one (N, D) float32 array) or a list of row dicts.
    A duplicate gets ``dedup_status = "rejected"``, ``dedup_reason =
    "duplicate: of <kept id> (rms … m < … m)"`` and ``dedup_value`` = its
    verifying RMS; every row in a group gets ``dedup_group`` = the kept id.
    """
    import pyarrow as pa
    import pyarrow.compute as pc

    table = rows if isinstance(rows, pa.Table) else pa.Table.from_pylist(list(rows))
    big = [c for c in ("dedup_embedding", "dedup_traj") if c in table.column_names]
    out = table.drop_columns(big).to_pylist()
    summary: dict[str, Any] = {"episodes": 0, "candidates": 0, "verified": 0, "removed": 0}
    if "dedup_embedding" not in big:
        return out, summary
    emb_col = table.column("dedup_embedding").combine_chunks()
    traj_col = table.column("dedup_traj").combine_chunks()
    valid = emb_col.is_valid().to_numpy(zero_copy_only=False)
    ok = np.array([r.get("dedup_status") == "ok" for r in out], dtype=bool)
    live = np.nonzero(valid & ok)[0]
    summary["episodes"] = int(len(live))
    if len(live) < 2:
        return out, summary
    live_col = emb_col.take(pa.array(live))
    dim = len(live_col[0])
    emb = np.asarray(pc.list_flatten(live_col).to_numpy(zero_copy_only=False), dtype=np.float32).reshape(len(live), dim)
    pairs = candidate_pairs(emb, cfg.cosine, nlist=cfg.nlist, nprobe=cfg.nprobe)
    summary["candidates"] = int(len(pairs))
    trajs: dict[int, np.ndarray] = {}
    scales: dict[int, float] = {}

    def traj(k: int) -> np.ndarray:
        if k not in trajs:
            flat = traj_col[int(live[k])].values.to_numpy(zero_copy_only=False)
            trajs[k] = np.asarray(flat, dtype=np.float64).reshape(cfg.steps, -1, 3)
            scales[k] = motion_scale(trajs[k])
        return trajs[k]

    rows = out
    uf = UnionFind(len(live))
    link_rms: dict[int, tuple[float, float]] = {}
    for a, b in pairs.tolist():
        ra, rb = rows[live[a]], rows[live[b]]
        if ra["embodiment"] != rb["embodiment"]:
            continue
        ta, tb = traj(a), traj(b)
        if ta.shape != tb.shape:
            continue
        d = trajectory_rms(ta, tb)
        thr = adaptive_threshold(scales[a], scales[b], cfg)
        if d < thr:
            summary["verified"] += 1
            uf.union(a, b)
            for k in (a, b):
                if k not in link_rms or d < link_rms[k][0]:
                    link_rms[k] = (d, thr)
    groups: dict[int, list[int]] = {}
    for k in range(len(live)):
        groups.setdefault(uf.find(k), []).append(k)
    for members in groups.values():
        if len(members) < 2:
            continue
        keep = min(members, key=lambda k: (-(rows[live[k]].get("length") or 0), rows[live[k]]["id"]))
        kept_id = rows[live[keep]]["id"]
        for k in members:
            o = out[live[k]]
            o["dedup_group"] = kept_id
            if k != keep:
                d, thr = link_rms[k]
                o.update(dedup_status="rejected", dedup_value=d,
                         dedup_reason=f"duplicate: of {kept_id} (rms {d:.4g} m < {thr:.4g} m)")
                summary["removed"] += 1
    return out, summary
