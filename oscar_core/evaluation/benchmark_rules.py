"""The selection rules of the paper's evaluation benchmark, as pure functions (no files, no clip sets).

The paper (Appendix "Evaluation benchmark selection") curates its 200 clips by
three rules; each is one function here, and :mod:`oscar_core.evaluation.benchmark_set`
applies them to clip sets:

* **forward window** (:func:`end_effector_pixels`, :func:`forward_window`):
  a clip is kept only if its end effector stays inside the image for every
  frame of the evaluation horizon;
* **near-duplicate removal** (:func:`text_embedding`, :func:`motion_magnitude`,
  :func:`dedup_features`, :func:`kmeans_representatives`): k-means in the joint
  space of a caption embedding and the end-effector motion magnitude, one clip
  (the nearest to its centroid) kept per cluster;
* **quotas** (:func:`sqrt_quotas`): per (embodiment, source) group, a share of
  the total proportional to the square root of the group's size, rounded by
  largest remainders.

Where the paper gives no number (margins, the weight of the two feature blocks,
the text embedder of a clip without stored embeddings) the choice is stated in
each function and in docs/evaluation.md ("The benchmark protocol").
"""

from __future__ import annotations

import hashlib
import math
import re
from collections.abc import Hashable, Mapping

import numpy as np

__all__ = [
    "end_effector_pixels",
    "forward_window",
    "motion_magnitude",
    "text_embedding",
    "pooled_embedding",
    "dedup_features",
    "kmeans_representatives",
    "distinct_rows",
    "sqrt_quotas",
    "TEXT_DIM",
]

#: width of the hashed bag-of-words text embedding (:func:`text_embedding`)
TEXT_DIM = 256


def end_effector_pixels(embodiment, trajectory, camera) -> tuple[np.ndarray, np.ndarray]:
    """Where the end effector is in the image: uv (T, 2) pixels and in_front (T,) bool.

    The end effector is the first gripper's indicator point, or the last
    skeleton point for an embodiment without grippers (the toy world's
    ``ee_points`` rule). ``camera`` must already be sized to the clip's frames;
    a camera mounted on a link moves with it (the renderer's projection).
    """
    from ..camera import project
    from ..kinematics.workspace import end_effector

    fr = embodiment.frames(trajectory, mount_link=camera.mount_link)
    p = project(end_effector(embodiment, fr), camera, mount_pose=fr.mount_pose)
    return np.asarray(p.uv, dtype=np.float64), np.asarray(p.in_front, dtype=bool)


def forward_window(
    uv: np.ndarray, in_front: np.ndarray, width: int, height: int, frames: int, margin: float = 0.0
) -> int | None:
    """The first frame in ``[0, frames)`` whose end effector is outside the image, or None when it never leaves.

    uv: (T, 2) pixels (pixel centres at integers); in_front: (T,) bool. A point
    is inside when it is in front of the camera, finite, and
    ``margin - 0.5 <= u < width - 0.5 - margin`` (the same for v with
    ``height``): ``margin`` pixels kept clear of every edge (0: the image's
    pixel-edge extent, as the projection's ``in_image``). A clip shorter than
    ``frames`` returns its length (the horizon is not covered).
    """
    uv = np.asarray(uv, dtype=np.float64)
    if len(uv) < frames:
        return len(uv)
    u, v = uv[:frames, 0], uv[:frames, 1]
    with np.errstate(invalid="ignore"):
        inside = (
            np.asarray(in_front[:frames], bool)
            & np.isfinite(u)
            & np.isfinite(v)
            & (u >= margin - 0.5)
            & (u < width - 0.5 - margin)
            & (v >= margin - 0.5)
            & (v < height - 0.5 - margin)
        )
    bad = np.flatnonzero(~inside)
    return int(bad[0]) if bad.size else None


def motion_magnitude(uv: np.ndarray, frames: int, width: int, height: int) -> float:
    """Path length of the end effector over frames ``[0, frames)`` in the image, divided by the image diagonal.

    uv: (T, 2) pixels. Unitless (1.0 = one diagonal travelled). Pixels rather
    than metres, so a hand (no reach in metres) and every robot are measured
    alike, and a motion the camera does not see (along the optical axis)
    counts for little, as it does in the video.
    """
    p = np.asarray(uv, dtype=np.float64)[:frames]
    if len(p) < 2:
        return 0.0
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
    return float(np.nansum(steps) / math.hypot(width, height))


def text_embedding(text: str | None, dim: int = TEXT_DIM) -> np.ndarray:
    """(dim,) float64 unit vector: a hashed bag of the lower-cased words of ``text`` (zeros for None or empty).

    Weight-free and deterministic (each word's bucket and sign from its
    sha256), so equal captions embed equally and captions sharing words lie
    close; it cannot see synonyms. Used when a clip stores no prompt embedding.
    """
    v = np.zeros(dim)
    for word in re.findall(r"[a-z0-9]+", (text or "").lower()):
        h = int.from_bytes(hashlib.sha256(word.encode()).digest()[:8], "little")
        v[h % dim] += 1.0 if (h >> 63) & 1 else -1.0
    n = np.linalg.norm(v)
    return v / n if n > 0 else v


def pooled_embedding(prompt_embeds) -> np.ndarray:
    """(L, D) or (1, L, D) token embeddings → (D,) float64 unit vector: the mean over tokens, L2-normalised."""
    a = np.asarray(prompt_embeds, dtype=np.float64)
    a = a.reshape(-1, a.shape[-1]).mean(axis=0)
    n = np.linalg.norm(a)
    return a / n if n > 0 else a


def dedup_features(text: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """(N, D + 1) features for k-means: standardised text (N, D) and motion (N,) blocks, each weighing as much.

    Every column is standardised (zero mean, unit deviation; a constant
    column becomes zeros), then the text block is divided by sqrt(V), V the
    number of its columns that vary: the text block's total variance (the sum
    over its columns) is then 1, the motion column's. Dividing by sqrt(D)
    instead would let the constant columns of a short caption vocabulary
    shrink the text block (13 varying of 256 toy-caption columns: 0.05).
    A block with no varying column stays zeros.
    """
    text = np.asarray(text, dtype=np.float64).reshape(len(motion), -1)
    x = np.concatenate([text, np.asarray(motion, dtype=np.float64).reshape(-1, 1)], axis=1)
    sd = x.std(axis=0)
    varies = sd > 1e-12
    x = (x - x.mean(axis=0)) / np.where(varies, sd, 1.0)
    x[:, :-1] /= math.sqrt(max(int(varies[:-1].sum()), 1))
    return x


def kmeans_representatives(x: np.ndarray, k: int, seed: int = 0) -> list[int]:
    """Indices (sorted) of ``k`` rows of ``x`` (N, D): the row nearest each k-means centroid.

    scipy's ``kmeans2`` (k-means++ start, seeded by ``seed``). Ties go to the
    smaller index. If a cluster comes out empty or two centroids share their
    nearest row, the missing representatives are the rows farthest from those
    already chosen (farthest-point). Exact duplicates are never both chosen:
    ``min(k, distinct_rows(x))`` rows are returned. Deterministic for a given
    (x, k, seed).
    """
    from scipy.cluster.vq import kmeans2

    x = np.asarray(x, dtype=np.float64)
    n = len(x)
    k = min(int(k), distinct_rows(x))
    if k <= 0:
        return []
    if k == n:
        return list(range(n))
    centroids, labels = kmeans2(x, k, minit="++", seed=np.random.default_rng(seed), missing="warn")
    chosen: list[int] = []
    for c in range(k):
        members = np.flatnonzero(labels == c)
        if members.size == 0:
            continue
        d = np.linalg.norm(x[members] - centroids[c], axis=1)
        best = int(members[np.lexsort((members, d))[0]])
        if best not in chosen:
            chosen.append(best)
    while len(chosen) < k:  # farthest-point fill
        d = np.min(np.linalg.norm(x[:, None, :] - x[chosen][None, :, :], axis=2), axis=1)
        d[chosen] = -1.0
        chosen.append(int(np.lexsort((np.arange(n), -d))[0]))
    return sorted(chosen)


def distinct_rows(x: np.ndarray) -> int:
    """How many different rows (N, D) ``x`` has (compared after rounding to 1e-9)."""
    x = np.asarray(x, dtype=np.float64)
    return len(np.unique(np.round(x.reshape(len(x), -1), 9), axis=0)) if len(x) else 0


def sqrt_quotas(
    available: Mapping[Hashable, int], total: int, *, corpus: Mapping[Hashable, int] | None = None
) -> dict[Hashable, int]:
    """Clips per group: ``total`` split in proportion to sqrt(N) of each group, by largest remainders.

    available: group → clips that may be chosen; corpus: group → N, the size
    of its source corpus (default: ``available``). Share_g = total · sqrt(N_g)
    / Σ sqrt(N); each group gets floor(share), the remaining clips go one by
    one to the largest fractional parts (ties: the group that sorts first).
    A group never gets more than it has available: the excess is shared out
    again over the groups with room, by the same rule. The quotas sum to
    ``min(total, Σ available)``.
    """
    corpus = dict(available if corpus is None else corpus)
    avail = {g: int(n) for g, n in available.items()}
    total = min(int(total), sum(avail.values()))
    out = {g: 0 for g in avail}
    open_ = [g for g in sorted(avail, key=str) if avail[g] > 0]
    left = total
    while left > 0 and open_:
        w = {g: math.sqrt(max(int(corpus.get(g, avail[g])), 0)) for g in open_}
        s = sum(w.values()) or float(len(open_))
        share = {g: left * (w[g] / s if sum(w.values()) else 1.0 / len(open_)) for g in open_}
        give = {g: math.floor(share[g]) for g in open_}
        rest = left - sum(give.values())
        for g in sorted(open_, key=lambda g: (-(share[g] - give[g]), str(g)))[:rest]:
            give[g] += 1
        for g in open_:
            out[g] += min(give[g], avail[g] - out[g])
        left = total - sum(out.values())
        open_ = [g for g in open_ if out[g] < avail[g]]
    return out
