"""``dedup``: semantic deduplication — SigLIP visual candidates, verified by trajectory distance, merged by union-find.

The candidate search of step 2 (:func:`candidate_pairs`, :func:`pca_projection`, :func:`brute_force_pairs`) lives
in :mod:`oscar_core.data.dedup_search` and is re-exported here.

1. **Embed** (a sharded stage, :class:`EmbedStage`): per live episode, the SigLIP
   image embedding of 5 uniformly sampled frames (each frame's pooled
   embedding L2-normalised, averaged, normalised again), and the skeleton's
   3-D points resampled to 64 uniform steps, (64, K, 3) metres.
2. **Candidates** (:func:`candidate_pairs`): every pair with cosine > 0.95,
   found without an all-pairs scan: the embeddings projected onto their top
   128 principal directions (a projection never lengthens a distance, so no
   pair is lost by it), faiss k-means into ``nlist`` lists, each episode
   compared with the members of its own and its ``nprobe`` − 1 nearest other
   lists as one matrix product per list, and every candidate re-checked on
   the full embeddings. Recall against the exact answer is measured in the
   tests and ``benchmarks/data.py``.
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

import hashlib
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._util.optional import require
from ..errors import OscarError
from ._episode import EPISODE_ERRORS, load_row, reason_of
from .dedup_search import (  # _exact_pairs: importable from here as before
    _exact_pairs as _exact_pairs,
    brute_force_pairs,
    candidate_pairs,
    pca_projection,
)

__all__ = [
    "DedupConfig",
    "ModelLoadError",
    "SiglipEmbedder",
    "TrajectoryEmbedder",
    "trajectory_embedding",
    "EmbedStage",
    "resample_points",
    "candidate_pairs",
    "pca_projection",
    "brute_force_pairs",
    "trajectory_rms",
    "motion_scale",
    "adaptive_threshold",
    "UnionFind",
    "dedup_rows",
]


@dataclass(frozen=True)
class DedupConfig:
    """Thresholds and search settings of ``oscar data dedup``."""

    cosine: float = 0.95  # SigLIP cosine above which a pair is a visual candidate (paper)
    frames: int = 5  # uniformly sampled frames per episode (paper)
    steps: int = 64  # resampled trajectory steps (paper)
    rms_alpha: float = 0.25  # duplicate when RMS < rms_alpha x the smaller motion scale ...
    rms_floor: float = 0.01  # ... or below this many metres
    nlist: int | None = None  # k-means clusters; None: 4·sqrt(N) (exact search below 2048 episodes)
    nprobe: int = 16  # clusters searched per episode: its own and the nearest others
    reduce_dim: int | None = 128  # candidate search on this many principal directions (None: full width)


class ModelLoadError(OscarError, RuntimeError):
    """The stage's model cannot be loaded (Hub unreachable, not in the cache, broken folder): the whole stage fails."""


class SiglipEmbedder:
    """SigLIP image embeddings with transformers' ``SiglipVisionModel``.

    model: a Hub id (``google/siglip-base-patch16-224``) or a local folder
    (``save_pretrained``). :meth:`prepare` (called once by ``run_dedup``,
    before any episode) finds the model — a local folder as is, a Hub id in
    the Hub cache, else downloaded after one reachability check bounded by
    ``OSCAR_HUB_TIMEOUT`` seconds (default 10) — and raises
    :class:`ModelLoadError` naming the cause and the fix when it cannot;
    workers then load that local folder only. The model loads on first use,
    once per process. Frames are resized to the model's square input (PIL
    bicubic), scaled to [0, 1] and normalised with mean = std = 0.5, exactly
    as transformers' ``SiglipImageProcessor`` prepares them (a test checks it).
    """

    def __init__(self, model: str, device: str = "cpu"):
        self.model_name, self.device = str(model), device
        self._model = None
        self._folder: str | None = None  # the local folder prepare() resolved
        self.revision: str | None = None  # the Hub commit, or a hash of a local folder's config and weight sizes

    def __getstate__(self):
        return {
            "model_name": self.model_name,
            "device": self.device,
            "_model": None,
            "_folder": self._folder,
            "revision": self.revision,
        }

    def identity(self) -> dict:
        """What the embeddings depend on: model name, resolved revision, device kind (part of the stage fingerprint)."""
        if self._folder is None:
            self.prepare()
        return {"model": self.model_name, "revision": self.revision, "device": str(self.device).split(":")[0]}

    def prepare(self) -> str:
        """The model's local folder (downloading it if needed); :class:`ModelLoadError` naming cause and fix."""
        if self._folder is not None:
            return self._folder
        local = Path(self.model_name).expanduser()
        if local.is_dir():
            if not (local / "config.json").is_file():
                raise ModelLoadError(
                    f"--siglip {self.model_name}: expected a model folder with config.json "
                    "(save_pretrained), found none"
                )
            self._folder, self.revision = str(local.resolve()), _folder_hash(local)
            return self._folder
        if local.exists() or self.model_name.count("/") != 1 or self.model_name.startswith(("/", ".", "~")):
            raise ModelLoadError(
                f"--siglip {self.model_name}: expected a Hub id (owner/name) or a model folder, found neither"
            )
        self._folder, self.revision = _hub_folder(self.model_name)
        return self._folder

    def model(self):
        if self._model is None:
            tr = require("transformers", "data")
            folder = self.prepare()
            try:
                self._model = tr.SiglipVisionModel.from_pretrained(folder, local_files_only=True).to(self.device).eval()
            except (OSError, ValueError, RuntimeError) as exc:
                raise ModelLoadError(
                    f"--siglip {self.model_name}: cannot load the model from {folder} "
                    f"({type(exc).__name__}: {str(exc)[:300]})"
                ) from None
        return self._model

    @staticmethod
    def pixel_values(frames: np.ndarray, size: int):
        """(N, H, W, 3) uint8 → (N, 3, size, size) float32 tensor, SigLIP's preprocessing."""
        import torch

        Image = require("PIL.Image", "data")
        x = np.stack(
            [np.asarray(Image.fromarray(np.ascontiguousarray(f)).resize((size, size), Image.BICUBIC)) for f in frames]
        )
        return torch.from_numpy(x).permute(0, 3, 1, 2).float().mul(1 / 255.0).sub(0.5).div(0.5)

    def __call__(self, frames: np.ndarray) -> np.ndarray:
        """frames: (N, H, W, 3) uint8 → (N, D) float32 L2-normalised pooled embeddings."""
        import torch

        m = self.model()
        x = self.pixel_values(frames, int(m.config.image_size)).to(self.device)
        with torch.no_grad():
            out = m(pixel_values=x).pooler_output.float().cpu().numpy()
        return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)


_WEIGHT_FILES = ("config.json", "model.safetensors", "pytorch_model.bin", "model.safetensors.index.json")


def _folder_hash(folder: Path) -> str:
    """sha256 of a model folder's config.json and the names and sizes of its files (a cheap identity)."""
    h = hashlib.sha256((folder / "config.json").read_bytes())
    for p in sorted(folder.iterdir()):
        if p.is_file():
            h.update(f"{p.name}:{p.stat().st_size};".encode())
    return h.hexdigest()[:16]


def _hub_timeout() -> float:
    return float(os.environ.get("OSCAR_HUB_TIMEOUT") or 10.0)


def _hub_folder(repo_id: str) -> tuple[str, str]:
    """(local snapshot folder, commit) of a Hub model: from the cache, else downloaded after a bounded check.

    Offline (``HF_HUB_OFFLINE=1``) only the cache is read. Online, a model
    already cached at the branch's last known commit is used as is (no
    request); otherwise one request (``GET /api/models/{id}/revision/main``)
    must answer within ``OSCAR_HUB_TIMEOUT`` seconds in all (a thread with a
    deadline, whatever the socket does) before the download starts.
    """
    from huggingface_hub import constants, snapshot_download
    from huggingface_hub.errors import LocalEntryNotFoundError

    patterns = ["*.json", "*.safetensors", "*.txt"]
    cache_dir = os.environ.get("HF_HUB_CACHE") or None  # read now, not when huggingface_hub was imported
    offline = os.environ.get("HF_HUB_OFFLINE", "").strip().lower() in ("1", "true", "yes", "on")
    try:
        folder = snapshot_download(repo_id, allow_patterns=patterns, local_files_only=True, cache_dir=cache_dir)
    except (LocalEntryNotFoundError, OSError, ValueError):
        folder = None
    if folder is not None and (Path(folder) / "config.json").is_file():
        return folder, Path(folder).name
    if offline:
        raise ModelLoadError(
            f"--siglip {repo_id}: not in the Hub cache ({cache_dir or constants.HF_HUB_CACHE}) and HF_HUB_OFFLINE "
            "is set; run once online (unset HF_HUB_OFFLINE) or pass a local model folder"
        )
    base = (os.environ.get("HF_ENDPOINT") or constants.ENDPOINT).rstrip("/")
    _check_reachable(f"{base}/api/models/{repo_id}/revision/main", base, repo_id)
    try:
        folder = snapshot_download(repo_id, allow_patterns=patterns, etag_timeout=_hub_timeout(), cache_dir=cache_dir)
    except Exception as exc:  # noqa: BLE001 - any failure here is the whole stage's, named with its cause
        raise ModelLoadError(
            f"--siglip {repo_id}: download failed ({type(exc).__name__}: {str(exc)[:300]}); with "
            "the model in the cache, HF_HUB_OFFLINE=1 skips the Hub"
        ) from None
    return folder, Path(folder).name


def _check_reachable(url: str, base: str, repo_id: str) -> None:
    """ModelLoadError unless ``url`` answers (any HTTP status below 500) within the Hub timeout, start to end."""
    import httpx

    seconds = _hub_timeout()
    result: dict[str, Any] = {}

    def get() -> None:
        try:
            result["status"] = httpx.get(url, timeout=seconds, follow_redirects=True).status_code
        except Exception as exc:  # noqa: BLE001 - reported below
            result["error"] = f"{type(exc).__name__}: {exc}"

    t = threading.Thread(target=get, daemon=True, name="oscar-hub-check")
    t.start()
    t.join(seconds)
    fix = (
        f"set HF_HUB_OFFLINE=1 to use the cache ({repo_id} must be in it: download it once online) or pass a "
        "local model folder to --siglip"
    )
    if t.is_alive():
        raise ModelLoadError(
            f"--siglip {repo_id}: cannot reach the Hub ({base}: no answer within {seconds:g} s, "
            f"OSCAR_HUB_TIMEOUT); {fix}"
        )
    if "error" in result:
        raise ModelLoadError(f"--siglip {repo_id}: cannot reach the Hub ({base}: {result['error'][:200]}); {fix}")
    if result["status"] >= 500:
        raise ModelLoadError(f"--siglip {repo_id}: cannot reach the Hub ({base}: HTTP {result['status']}); {fix}")
    if result["status"] in (401, 403, 404):
        raise ModelLoadError(
            f"--siglip {repo_id}: the Hub has no accessible model {repo_id} (HTTP "
            f"{result['status']}); check the id and your token (HF_TOKEN)"
        )


class TrajectoryEmbedder:
    """The weight-free candidate search: an episode's motion as its embedding, no image model.

    ``--embedder trajectory``: in place of SigLIP's picture, the embedding is
    the path of the skeleton's centroid over the resampled steps, centred on
    its mean and L2-normalised ((steps · 3) floats; :func:`trajectory_embedding`),
    so cosine > ``cosine`` finds episodes whose motion has the same shape;
    the verification (trajectory RMS under the adaptive threshold) and the
    merge are the same as with SigLIP. It reads no video and downloads
    nothing. It cannot see that two different motions happened in the same
    scene, nor tell apart visually different episodes with the same motion
    before the RMS check (which then decides alone).
    """

    name = "trajectory"
    uses_video = False


def trajectory_embedding(points: np.ndarray) -> np.ndarray:
    """(steps, K, 3) resampled skeleton points → (steps · 3,) the centroid path, centred, unit length."""
    path = np.asarray(points, dtype=np.float64).mean(axis=1)
    path = (path - path.mean(axis=0)).ravel()
    n = np.linalg.norm(path)
    return path / n if n > 1e-12 else path


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

        if any(is_alive(r) for r in rows) and hasattr(self.embedder, "model"):
            self.embedder.model()  # a model that cannot load fails the stage, not each episode
        return [self.one(r) if is_alive(r) else r for r in rows]

    def one(self, row: dict) -> dict:
        out = dict(row, dedup_status="ok", dedup_reason=None, dedup_value=None)
        try:
            ep, emb = load_row(row, self.plugin_paths)
            traj = emb.check_trajectory(ep.trajectory)
            pts = resample_points(emb.frames(traj).points, self.config.steps)
            if getattr(self.embedder, "uses_video", True):
                n = ep.video.n_frames
                idx = np.linspace(0, n - 1, self.config.frames).round().astype(int)
                vec = episode_embedding(self.embedder(ep.video.read(idx)))
            else:
                vec = trajectory_embedding(pts)
        except EPISODE_ERRORS as exc:
            out.update(dedup_status="rejected", dedup_reason=f"unreadable: {reason_of(exc)}")
            return out
        out["dedup_embedding"] = vec.astype(np.float32)
        out["dedup_traj"] = pts.astype(np.float32).ravel()
        return out


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
    pairs = candidate_pairs(emb, cfg.cosine, nlist=cfg.nlist, nprobe=cfg.nprobe, reduce_dim=cfg.reduce_dim)
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
                o.update(
                    dedup_status="rejected",
                    dedup_value=d,
                    dedup_reason=f"duplicate: of {kept_id} (rms {d:.4g} m < {thr:.4g} m)",
                )
                summary["removed"] += 1
    return out, summary
