"""The candidate search of ``oscar data dedup``: every pair of (N, D) unit-length embeddings with cosine above a
threshold, as (P, 2) int64 index pairs i < j, sorted. Below ``exact_below`` rows a flat range search
(:func:`candidate_pairs`'s exact path), above it an inverted-file search done as dense blocks on a contractive PCA
projection (:func:`pca_projection`) and re-checked on the full vectors; :func:`brute_force_pairs` is the all-pairs
reference. Re-exported by :mod:`oscar_core.data.dedup`.
"""

from __future__ import annotations

import numpy as np

from .._util.optional import require

__all__ = ["brute_force_pairs", "candidate_pairs", "pca_projection"]


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
        sims = x[s : s + block] @ x.T
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


def _exact_pairs(x: np.ndarray, threshold: float, batch: int = 65536) -> np.ndarray:
    """(P, 2) sorted pairs with cosine > threshold by faiss's exact (flat) range search: the small-N path."""
    faiss = require("faiss", "data")
    index = faiss.IndexFlatIP(x.shape[1])
    index.add(x)
    out = []
    for s in range(0, len(x), batch):
        lims, _, ids = index.range_search(x[s : s + batch], float(threshold))
        out.append(_pairs_from_lims(lims, ids, s))  # a pair found from either end counts
    return _sorted_pairs(np.concatenate(out)) if out else np.zeros((0, 2), np.int64)


def pca_projection(x: np.ndarray, dim: int, sample: int = 20000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(mean (D,), basis (D, dim) with orthonormal columns): the top principal directions of a sample of rows.

    Projecting onto orthonormal columns never lengthens a vector, so
    ``|(a − b) @ basis| <= |a − b|``: a pair within a distance in the full
    space is within it in the projected one (the candidate search loses no
    pair by projecting; the exact check on the full vectors removes the extra
    ones).
    """
    rng = np.random.default_rng(seed)
    s = x if len(x) <= sample else x[np.sort(rng.choice(len(x), sample, replace=False))]
    c = np.asarray(s, np.float64)
    mean = c.mean(axis=0)
    c -= mean
    w, v = np.linalg.eigh(c.T @ c)  # ascending eigenvalues; columns orthonormal
    return mean.astype(np.float32), np.ascontiguousarray(v[:, ::-1][:, :dim], dtype=np.float32)


def _contractive_projection(x: np.ndarray, reduce_dim: int | None, seed: int) -> np.ndarray:
    """x (N, D) float32 projected onto its top ``reduce_dim`` principal directions ((N, reduce_dim) float32,
    :func:`pca_projection`), or ``x`` itself when D <= reduce_dim or ``reduce_dim`` is None."""
    n, d = x.shape
    if reduce_dim is None or d <= reduce_dim:
        return x
    mean, basis = pca_projection(x, int(reduce_dim), seed=seed)
    z = np.empty((n, basis.shape[1]), np.float32)
    for s in range(0, n, 65536):
        np.matmul(x[s : s + 65536] - mean, basis, out=z[s : s + 65536])
    return z


def _kmeans_centroids(faiss, z: np.ndarray, k: int, train_per_list: int, niter: int, seed: int) -> np.ndarray:
    """(k, R) float32 k-means centroids of the rows of z (N, R), trained on at most ``train_per_list`` (≥ 39)
    sampled rows per list."""
    n, r = z.shape
    rng = np.random.default_rng(seed)
    m = min(n, max(39, train_per_list) * k)
    train = z if m >= n else z[np.sort(rng.choice(n, m, replace=False))]
    km = faiss.Kmeans(r, k, niter=niter, seed=seed, verbose=False)
    km.train(np.ascontiguousarray(train))
    return km.centroids


def _list_rows(faiss, z: np.ndarray, centroids: np.ndarray, probes: int):
    """Which rows belong to and which probe each of the k lists. Returns ``(member_order, member_start,
    query_order, query_start)``: the members of list l are ``member_order[member_start[l]:member_start[l + 1]]``
    (rows whose nearest centroid is l) and its queries ``query_order[query_start[l]:query_start[l + 1]]`` (rows
    with l among their ``probes`` nearest centroids); the starts are (k + 1,)."""
    k = len(centroids)
    quant = faiss.IndexFlatL2(z.shape[1])
    quant.add(centroids)
    _, probe = quant.search(z, probes)  # (n, probes) nearest lists, nearest first
    own = probe[:, 0]
    member_order = np.argsort(own, kind="stable")
    member_start = np.searchsorted(own[member_order], np.arange(k + 1))
    flat = probe.ravel()
    query_order = np.argsort(flat, kind="stable")
    query_start = np.searchsorted(flat[query_order], np.arange(k + 1))
    query_order //= probes
    return member_order, member_start, query_order, query_start


def _augmented_rows(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(qa, ma)``, each (N, R + 2): rows with qa_i · ma_j = 2 z_i · z_j − |z_i|² − |z_j|² = −|z_i − z_j|², so one
    matrix product gives a block of negated squared distances."""
    sq = np.einsum("ij,ij->i", z, z)[:, None]
    qa = np.hstack([z, sq, np.ones_like(sq)])
    ma = np.hstack([2.0 * z, -np.ones_like(sq), -sq])
    return qa, ma


def _block_pairs(qa, ma, lists, radius: float, block: int) -> np.ndarray:
    """(P, 2) int64 unique pairs i < j of a list's query and member within squared distance ``radius``, per list
    of ``lists`` (:func:`_list_rows`) in products of at most ``block`` entries."""
    member_order, member_start, query_order, query_start = lists
    n = len(qa)
    found = []
    for lst in range(len(member_start) - 1):
        mem = member_order[member_start[lst] : member_start[lst + 1]]
        if not len(mem):
            continue
        qry = query_order[query_start[lst] : query_start[lst + 1]]
        mt = np.ascontiguousarray(ma[mem].T)
        step = max(1, block // len(mem))
        for s in range(0, len(qry), step):
            q = qry[s : s + step]
            qi, mj = np.nonzero(qa[q] @ mt > -radius)
            a, b = q[qi], mem[mj]
            keep = a != b
            found.append(np.minimum(a[keep], b[keep]) * n + np.maximum(a[keep], b[keep]))
    keys = np.unique(np.concatenate(found)) if found else np.zeros(0, np.int64)
    return np.stack([keys // n, keys % n], axis=1)


def _exact_check(x: np.ndarray, pairs: np.ndarray, threshold: float) -> np.ndarray:
    """The pairs ((P, 2) int64) whose full rows of x (unit, (N, D)) have cosine > ``threshold``."""
    ok = np.zeros(len(pairs), bool)
    for s in range(0, len(pairs), 65536):
        p = pairs[s : s + 65536]
        ok[s : s + 65536] = np.einsum("ij,ij->i", x[p[:, 0]], x[p[:, 1]]) > threshold
    return pairs[ok]


def candidate_pairs(
    emb: np.ndarray,
    threshold: float = 0.95,
    *,
    nlist: int | None = None,
    nprobe: int = 16,
    exact_below: int = 2048,
    reduce_dim: int | None = 128,
    train_per_list: int = 40,
    niter: int = 10,
    block: int = 1 << 24,
    seed: int = 0,
    timings: dict[str, float] | None = None,
) -> np.ndarray:
    """(P, 2) int64 sorted pairs i < j with cosine(emb_i, emb_j) > threshold; emb: (N, D) unit rows.

    Below ``exact_below`` rows (and with no ``nlist``) an exact flat range
    search. Otherwise an inverted-file search done as dense blocks:

    1. the rows are projected onto their top ``reduce_dim`` principal
       directions (:func:`pca_projection`; skipped when D <= reduce_dim), which
       never lengthens a distance, so every pair with cosine > threshold —
       squared distance < 2 − 2·threshold for unit rows — is still within
       that radius;
    2. k-means (faiss, ``niter`` iterations on at most ``train_per_list``
       sampled rows per list) into ``nlist`` lists (default 4·sqrt(N)); each
       row belongs to the list of its nearest centroid and probes its
       ``nprobe`` nearest lists (its own first) — the pairs an IVF range
       search with this ``nprobe`` finds;
    3. per list, the rows that probe it against its members in one matrix
       product (BLAS; the list's members are read once for all of them, not
       once per query as a per-query scan does), in blocks of at most
       ``block`` entries; pairs within the radius are candidates;
    4. each candidate is checked exactly on the full vectors (cosine >
       threshold), so the result holds no false pair; pairs are missed only
       when neither row probes the other's list (recall is measured in the
       tests and ``benchmarks/data.py``).

    ``timings``, when given, receives the seconds of each phase (``project``,
    ``kmeans``, ``assign``, ``blocks``, ``check``).
    """
    import time

    faiss = require("faiss", "data")
    clock = [time.perf_counter()]

    def lap(name: str) -> None:
        now = time.perf_counter()
        if timings is not None:
            timings[name] = timings.get(name, 0.0) + now - clock[0]
        clock[0] = now

    x = np.ascontiguousarray(emb, dtype=np.float32)
    n = len(x)
    if n < 2:
        return np.zeros((0, 2), np.int64)
    if nlist is None and n < exact_below:
        return _exact_pairs(x, threshold)
    k = int(nlist or max(1, round(4 * np.sqrt(n))))
    k = max(1, min(k, n // 39 if n >= 78 else 1))  # faiss wants >= 39 training points per list
    probes = max(1, min(int(nprobe), k))
    z = _contractive_projection(x, reduce_dim, seed)  # 1.
    lap("project")
    centroids = _kmeans_centroids(faiss, z, k, train_per_list, niter, seed)  # 2.
    lap("kmeans")
    lists = _list_rows(faiss, z, centroids, probes)
    qa, ma = _augmented_rows(z)
    del z  # the projected copy (x itself stays)
    radius = (2.0 - 2.0 * float(threshold)) * (1 + 1e-4) + 1e-5  # squared, a hair wider than exact: rechecked below
    lap("assign")
    pairs = _block_pairs(qa, ma, lists, radius, block)  # 3.
    lap("blocks")
    pairs = _exact_check(x, pairs, threshold)  # 4.
    lap("check")
    return pairs
