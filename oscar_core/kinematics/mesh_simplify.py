"""Mesh simplification by vertex clustering (Rossignac & Borrel, 1993).

Vertices are snapped to a grid of ``cell`` metres; all vertices in one cell
become one (their mean), triangles that collapse (two corners in one cell) are
dropped, and duplicate triangles are kept once. Every vertex moves by at most
``cell * sqrt(3)`` metres, which bounds the silhouette error: at a distance d
from a camera of focal length f pixels, at most ``f * cell * sqrt(3) / d``
pixels (``benchmarks/render.py`` measures the silhouette IoU against the full
meshes). Thin parts narrower than a cell can vanish; that is the price of speed.
"""

from __future__ import annotations

import numpy as np

__all__ = ["cluster_vertices"]


def cluster_vertices(vertices, faces, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering of one mesh.

    vertices: (V, 3) metres; faces: (F, 3) int; cell: grid size in metres (> 0).
    Returns (V', 3) float64 vertices (cluster means) and (F', 3) int64 faces,
    F' ≤ F, the orientation of every kept face unchanged.
    """
    if not cell > 0:
        raise ValueError(f"cell: expected a positive grid size in metres, found {cell!r}")
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(v) == 0 or len(f) == 0:
        return v.reshape(-1, 3), f.reshape(-1, 3)
    keys = np.floor(v / cell).astype(np.int64)
    _, label, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    label = label.reshape(-1)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, label, v)
    centres = sums / counts[:, None]
    g = label[f]
    keep = (g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 0] != g[:, 2])
    g = g[keep]
    # the same triangle with the same orientation: keep once (rotate so the smallest index is first)
    r = np.argmin(g, axis=1)
    canon = np.stack([g[np.arange(len(g)), (r + k) % 3] for k in range(3)], axis=1)
    _, first = np.unique(canon, axis=0, return_index=True)
    g = g[np.sort(first)]
    used, g = np.unique(g, return_inverse=True)
    return centres[used], g.reshape(-1, 3).astype(np.int64)
