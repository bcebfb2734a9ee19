"""Distribution metrics of world-model rollouts: FVD (I3D features) and FID (Inception features).

Fréchet distances between Gaussian fits of feature sets; the feature extractors are arguments
(see :mod:`oscar_core.metrics.video`). Clips are cut to their first ``n_frames`` frames first.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np

from ._video_common import DEFAULT_FRAMES, _callable, _frames, _torch, _unit
from .common import MetricInputError

__all__ = [
    "I3D_CALL_KWARGS",
    "I3D_PREPROCESSED_KWARGS",
    "INCEPTION_CALL_KWARGS",
    "feature_statistics",
    "frechet_distance",
    "frechet_distance_from_features",
    "video_features",
    "frame_features",
    "fvd",
    "fid",
]

#: Keyword arguments StyleGAN-V's FVD (``src/metrics/frechet_video_distance.py``) calls
#: ``i3d_torchscript.pt`` with: the detector itself rescales [0, 255] to [-1, 1] and resizes every clip
#: to 224×224 (no crop); return the 400 pre-softmax features.
I3D_CALL_KWARGS = {"rescale": True, "resize": True, "return_features": True}
#: ... and when the caller has already resized and scaled the clips (``video_features(resolution=R)``).
I3D_PREPROCESSED_KWARGS = {"rescale": False, "resize": False, "return_features": True}
#: Keyword arguments of the StyleGAN2-ADA ``inception-2015-12-05.pt``: 2048-d pool features.
INCEPTION_CALL_KWARGS = {"return_features": True}


# --------------------------------------------------------------------------- #
# Fréchet distances
# --------------------------------------------------------------------------- #
def feature_statistics(features) -> tuple[np.ndarray, np.ndarray]:
    """Mean (D,) and covariance (D, D) of features (N, D), N ≥ 2.

    The covariance is the unbiased sample covariance (``np.cov(features,
    rowvar=False)``, divisor N − 1) as in the FID (pytorch-fid, StyleGAN) and
    FVD (StyleGAN-V) reference code.
    """
    f = np.asarray(features, dtype=np.float64)
    if f.ndim != 2:
        raise MetricInputError("features", "shape", "(N, D)", f"shape {f.shape}")
    if len(f) < 2:
        raise MetricInputError("features", "N", "at least 2 samples to estimate a covariance", f"{len(f)}")
    if not np.all(np.isfinite(f)):
        raise MetricInputError("features", "values", "finite numbers", "NaN or inf")
    return f.mean(axis=0), np.atleast_2d(np.cov(f, rowvar=False))


def _sqrt_psd(m: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eigh(0.5 * (m + m.T))
    return (v * np.sqrt(np.clip(w, 0.0, None))) @ v.T


def frechet_distance(mu1, sigma1, mu2, sigma2) -> float:
    """Fréchet distance between Gaussians N(μ1, Σ1) and N(μ2, Σ2) (Dowson & Landau 1982;
    the distance behind FID, Heusel et al. 2017, and FVD, Unterthiner et al. 2018).

    ``d² = ‖μ1 − μ2‖² + tr(Σ1) + tr(Σ2) − 2 tr((Σ1 Σ2)^½)``.

    ``tr((Σ1Σ2)^½)`` is computed as the sum of the square roots of the
    eigenvalues of the symmetric PSD matrix ``Σ1^½ Σ2 Σ1^½`` (same spectrum as
    Σ1Σ2), which avoids the complex round-off of a general matrix square root.
    ``mu``: (D,), ``sigma``: (D, D) symmetric PSD. Returns d² (the quantity
    reported as FID / FVD), a float ≥ 0 up to round-off.
    """
    mu1, mu2 = np.atleast_1d(np.asarray(mu1, np.float64)), np.atleast_1d(np.asarray(mu2, np.float64))
    s1, s2 = np.atleast_2d(np.asarray(sigma1, np.float64)), np.atleast_2d(np.asarray(sigma2, np.float64))
    d = mu1.shape[0]
    for name, m, shape in (("mu1", mu1, (d,)), ("mu2", mu2, (d,)), ("sigma1", s1, (d, d)), ("sigma2", s2, (d, d))):
        if m.shape != shape:
            raise MetricInputError(name, "shape", str(shape), str(m.shape))
    r1 = _sqrt_psd(s1)
    eig = np.linalg.eigvalsh(r1 @ s2 @ r1)
    tr_covmean = float(np.sqrt(np.clip(eig, 0.0, None)).sum())
    diff = mu1 - mu2
    return float(diff @ diff + np.trace(s1) + np.trace(s2) - 2.0 * tr_covmean)


def frechet_distance_from_features(features_a, features_b) -> float:
    """Fréchet distance between Gaussians fitted to two feature sets (N_a, D) and (N_b, D)."""
    mu1, s1 = feature_statistics(features_a)
    mu2, s2 = feature_statistics(features_b)
    return frechet_distance(mu1, s1, mu2, s2)


def _preprocess_i3d(video: np.ndarray, resolution: int | None):
    """(T, H, W, 3) → float32 (3, T, R, R) in [-1, 1]: shorter side to R (bilinear), centre crop."""
    torch = _torch()
    x = torch.from_numpy(np.ascontiguousarray(_unit(video, np.float32))).permute(0, 3, 1, 2)  # T, 3, H, W
    if resolution is not None:
        t, c, h, w = x.shape
        scale = resolution / min(h, w)
        size = (resolution, math.ceil(w * scale)) if h < w else (math.ceil(h * scale), resolution)
        x = torch.nn.functional.interpolate(x, size=size, mode="bilinear", align_corners=False)
        h, w = x.shape[-2:]
        top, left = (h - resolution) // 2, (w - resolution) // 2
        x = x[:, :, top : top + resolution, left : left + resolution]
    return (x * 2.0 - 1.0).permute(1, 0, 2, 3).contiguous()


def _check_features(out, n: int, what: str) -> np.ndarray:
    arr = out.detach().double().cpu().numpy() if hasattr(out, "detach") else np.asarray(out, np.float64)
    if arr.ndim != 2 or arr.shape[0] != n:
        raise MetricInputError(what, "output", f"features of shape ({n}, D)", f"shape {arr.shape}")
    return arr


def video_features(
    videos: Iterable,
    extractor,
    *,
    n_frames: int | None = DEFAULT_FRAMES,
    resolution: int | None = None,
    batch_size: int = 4,
    device="cpu",
    extractor_kwargs: Mapping | None = None,
    source: str = "videos",
) -> np.ndarray:
    """Per-clip features for FVD (one feature vector per video).

    Default (``resolution=None``): exactly what StyleGAN-V's FVD
    (Skorokhodov et al. 2022; ``src/metrics/metric_utils.py``, the PyTorch
    port of Unterthiner et al.'s FVD that uses ``i3d_torchscript.pt``) feeds
    its detector: the first ``n_frames`` frames of each clip as a ``torch.uint8``
    tensor (B, 3, T, H, W) in [0, 255] at the clip's own size, called with
    ``rescale=True, resize=True, return_features=True`` — the TorchScript I3D
    scales to [-1, 1] and resizes the whole clip to 224×224 itself (no crop:
    TF FVD's ``resize_bilinear`` of every frame). Clips of different sizes are
    batched separately. FVD values computed with different frame counts are
    not comparable (the original FVD uses 16 frames, the paper 49).

    ``resolution=R`` instead resizes the shorter side to R (bilinear,
    ``align_corners=False``), centre-crops R×R and maps to [-1, 1] float32
    here (the content-debiased-FVD style), calling the detector with
    ``rescale=False, resize=False``. The two give different numbers on clips
    that are not square.

    ``extractor``: callable (B, 3, T, H, W) → (B, D) features, or a path to a
    TorchScript file called with ``extractor_kwargs`` (default as above).
    Returns (N, D) float64.
    """
    torch = _torch()
    if extractor_kwargs is None:
        extractor_kwargs = I3D_CALL_KWARGS if resolution is None else I3D_PREPROCESSED_KWARGS
    f = _callable(extractor, "fvd_extractor", extractor_kwargs, device=device)
    feats, batch = [], []

    def flush():
        x = torch.stack(batch).to(device)
        with torch.no_grad():
            feats.append(_check_features(f(x), len(batch), "fvd_extractor"))
        batch.clear()

    for k, v in enumerate(videos):
        clip = _frames(v, n_frames, f"{source}[{k}]")
        if resolution is None:
            u8 = clip if clip.dtype == np.uint8 else np.round(_unit(clip, np.float32) * 255.0).astype(np.uint8)
            item = torch.from_numpy(np.ascontiguousarray(u8)).permute(3, 0, 1, 2).contiguous()  # 3, T, H, W
        else:
            item = _preprocess_i3d(clip, resolution)
        if batch and (len(batch) == batch_size or batch[0].shape != item.shape):
            flush()
        batch.append(item)
    if batch:
        flush()
    if not feats:
        raise MetricInputError(source, "videos", "at least one video", "none")
    return np.concatenate(feats)


def frame_features(
    videos: Iterable,
    extractor,
    *,
    n_frames: int | None = DEFAULT_FRAMES,
    batch_size: int = 32,
    device="cpu",
    extractor_kwargs: Mapping | None = None,
    source: str = "videos",
) -> np.ndarray:
    """Per-frame features for FID: every frame of every clip is one sample.

    Each batch is passed as a ``torch.uint8`` tensor (B, 3, H, W) in [0, 255]
    at the video's own resolution — the input of the StyleGAN2-ADA
    ``inception-2015-12-05.pt`` TorchScript Inception (which resizes to 299×299
    itself). ``extractor``: callable → (B, D), or a path to a TorchScript file
    called with ``extractor_kwargs`` (default ``return_features=True``: 2048-d
    pool features). Returns (N·T', D) float64.
    """
    torch = _torch()
    kwargs = INCEPTION_CALL_KWARGS if extractor_kwargs is None else extractor_kwargs
    f = _callable(extractor, "fid_extractor", kwargs, device=device)
    feats = []
    with torch.no_grad():
        for k, v in enumerate(videos):
            v = _frames(v, n_frames, f"{source}[{k}]")
            u8 = v if v.dtype == np.uint8 else np.round(_unit(v, np.float32) * 255.0).astype(np.uint8)
            for s in range(0, len(u8), batch_size):
                x = torch.from_numpy(np.ascontiguousarray(u8[s : s + batch_size])).permute(0, 3, 1, 2).to(device)
                feats.append(_check_features(f(x), len(x), "fid_extractor"))
    if not feats:
        raise MetricInputError(source, "videos", "at least one video", "none")
    return np.concatenate(feats)


def fvd(pred_videos: Iterable, gt_videos: Iterable, extractor, **kwargs) -> float:
    """Fréchet Video Distance (Unterthiner et al. 2018): :func:`frechet_distance` between Gaussians
    fitted to :func:`video_features` of the predicted and the ground-truth clips (≥ 2 clips each;
    ``kwargs`` go to :func:`video_features`). Lower is better."""
    return frechet_distance_from_features(
        video_features(pred_videos, extractor, source="pred_videos", **kwargs),
        video_features(gt_videos, extractor, source="gt_videos", **kwargs),
    )


def fid(pred_videos: Iterable, gt_videos: Iterable, extractor, **kwargs) -> float:
    """Fréchet Inception Distance over frames (Heusel et al. 2017): :func:`frechet_distance` between
    Gaussians fitted to :func:`frame_features` of all predicted and all ground-truth frames
    (``kwargs`` go to :func:`frame_features`). Lower is better."""
    return frechet_distance_from_features(
        frame_features(pred_videos, extractor, source="pred_videos", **kwargs),
        frame_features(gt_videos, extractor, source="gt_videos", **kwargs),
    )
