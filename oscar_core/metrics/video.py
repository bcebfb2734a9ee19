"""Video quality of world-model rollouts against ground truth.

The OSCAR paper (Sec. "Experimental Settings", Tables 1–2 and the
per-embodiment tables of the Appendix) reports reconstruction quality (PSNR,
SSIM, LPIPS), temporal coherence (tLPIPS), distribution fidelity (FVD, FID,
latent L2), computed on the **first 49 frames** of every clip ("following the
Kinema4D protocol"); ``n_frames`` defaults to :data:`DEFAULT_FRAMES` = 49
everywhere here and ``None`` uses every frame.

Videos
------
A video is an array ``(T, H, W, 3)``: ``uint8`` in [0, 255] or floating point
in [0, 1] (RGB; a torch tensor of that layout is accepted too). A prediction
and its ground truth must have the same height and width (resize beforehand;
nothing is resized silently) and at least ``n_frames`` frames each; both are
cut to their first ``n_frames`` frames.

Networks are arguments
----------------------
LPIPS, the VAE of latent L2 and the FVD / FID feature extractors are passed in
by the caller — a Python callable (e.g. an ``lpips.LPIPS`` instance, a
``torch.nn.Module``) or a path to a TorchScript file loaded with
``torch.jit.load`` (e.g. the standard ``i3d_torchscript.pt``). Nothing is
downloaded. Their input conventions are stated in each function.

Per-frame functions (:func:`psnr`, :func:`ssim`, :func:`lpips`,
:func:`tlpips`) return one value per frame (per step for tLPIPS); a clip's
score is their mean. :func:`evaluate_videos` computes everything for a list
of :class:`Clip` s, with per-clip rows, aggregates, and a per-embodiment
breakdown when clips carry an ``embodiment`` tag.

FVD and FID live in :mod:`oscar_core.metrics.frechet`, the shared input checks, video
reading and TorchScript loading in :mod:`oscar_core.metrics._video_common`; this module
re-exports their public names.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from .._util.log import progress_bars_enabled
from ._video_common import (
    DEFAULT_FRAMES,
    _callable,
    _flat,
    _pair,
    _to_tensor_nchw,
    _torch,
    _unit,
    load_torchscript,
    load_video,
)
from .common import MetricInputError, nan_to_none
from .frechet import (
    I3D_CALL_KWARGS,
    I3D_PREPROCESSED_KWARGS,
    INCEPTION_CALL_KWARGS,
    feature_statistics,
    fid,
    frame_features,
    frechet_distance,
    frechet_distance_from_features,
    fvd,
    video_features,
)

__all__ = [
    "DEFAULT_FRAMES",
    "PSNR_CAP_DB",
    "psnr",
    "ssim",
    "lpips",
    "tlpips",
    "latent_l2",
    "feature_statistics",
    "frechet_distance",
    "frechet_distance_from_features",
    "video_features",
    "frame_features",
    "fvd",
    "fid",
    "load_torchscript",
    "Clip",
    "VideoReport",
    "evaluate_videos",
    "load_video",
]

#: Per-frame PSNR cap in dB (see :func:`psnr`): identical frames score this instead of inf.
PSNR_CAP_DB = 100.0


# --------------------------------------------------------------------------- #
# PSNR and SSIM
# --------------------------------------------------------------------------- #
def psnr(pred, gt, *, n_frames: int | None = DEFAULT_FRAMES, cap: float | None = PSNR_CAP_DB) -> np.ndarray:
    """Peak signal-to-noise ratio per frame, in dB, capped at ``cap``.

    ``PSNR_t = min(10 log10(MAX² / MSE_t), cap)`` with ``MSE_t`` the mean
    squared error over all pixels and channels of frame t and MAX the data
    range (255 for uint8, 1 for float frames). Below the cap this is
    ``skimage.metrics.peak_signal_noise_ratio(gt[t], pred[t], data_range=MAX)``.

    Convention: a frame identical to its ground truth has MSE 0 and an infinite
    PSNR. Every frame is capped at :data:`PSNR_CAP_DB` = 100 dB (an MSE of
    1e-10 of the squared range; one 8-bit level of difference in a single
    value of a 512×288 RGB frame already scores 104.6 dB, so frames at the cap
    are identical for every practical purpose). This keeps one identical
    frame — typically the conditioning first frame — from turning a clip mean,
    and with it a whole table, into inf. ``cap=None`` gives the uncapped value
    (``inf`` for identical frames).

    ``pred``, ``gt``: videos (T, H, W, 3). Returns (T',) float64, T' = ``n_frames`` (or T).
    The clip PSNR is the mean over frames.
    """
    if cap is not None and not (isinstance(cap, (int, float)) and math.isfinite(cap) and cap > 0):
        raise MetricInputError("cap", "value", "a positive number of dB or None", repr(cap))
    pred, gt = _pair(pred, gt, n_frames)
    out = np.empty(len(pred))
    for t in range(len(pred)):
        mse = float(np.mean((_unit(pred[t]) - _unit(gt[t])) ** 2))
        out[t] = np.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)
    return out if cap is None else np.minimum(out, float(cap))


def _gaussian_window(size: int = 11, sigma: float = 1.5) -> np.ndarray:
    r = size // 2
    x = np.arange(-r, r + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def ssim(pred, gt, *, n_frames: int | None = DEFAULT_FRAMES) -> np.ndarray:
    """Structural similarity per frame (Wang et al. 2004, "Image quality assessment: from error
    visibility to structural similarity").

    Gaussian-weighted local statistics (11×11 window, σ = 1.5), K1 = 0.01,
    K2 = 0.03, population (not sample) covariances, the SSIM map averaged over
    the positions where the whole window fits inside the frame, computed for
    each RGB channel and averaged over channels. This is
    ``skimage.metrics.structural_similarity(gt[t], pred[t], data_range=MAX,
    channel_axis=-1, gaussian_weights=True, sigma=1.5, use_sample_covariance=False)``
    (scikit-image's own defaults — a 7×7 box window with sample covariance — are
    *not* Wang et al.'s). Frames must be at least 11×11.

    ``pred``, ``gt``: videos (T, H, W, 3). Returns (T',) float64 in [-1, 1].
    """
    import cv2

    pred, gt = _pair(pred, gt, n_frames)
    H, W = pred.shape[1:3]
    if H < 11 or W < 11:
        raise MetricInputError("pred", "frame size", "at least 11x11 pixels for the SSIM window", f"{W}x{H}")
    g = _gaussian_window().reshape(-1, 1)
    c1, c2 = 0.01**2, 0.03**2  # data range 1 after scaling to [0, 1]

    def blur(img):  # separable Gaussian; the 5-pixel border it touches is cropped, so the border mode is moot
        return cv2.sepFilter2D(img, cv2.CV_64F, g, g, borderType=cv2.BORDER_REFLECT)[5:-5, 5:-5]

    out = np.empty(len(pred))
    for t in range(len(pred)):
        x, y = _unit(pred[t]), _unit(gt[t])
        ux, uy = blur(x), blur(y)
        vx = blur(x * x) - ux * ux
        vy = blur(y * y) - uy * uy
        vxy = blur(x * y) - ux * uy
        smap = ((2 * ux * uy + c1) * (2 * vxy + c2)) / ((ux * ux + uy * uy + c1) * (vx + vy + c2))
        out[t] = float(smap.mean(axis=(0, 1)).mean())  # per-channel means, then their mean
    return out


# --------------------------------------------------------------------------- #
# networks passed by the caller
# --------------------------------------------------------------------------- #
def _lpips_pairs(a: np.ndarray, b: np.ndarray, net: Callable, batch_size: int, device) -> np.ndarray:
    torch = _torch()
    out = np.empty(len(a))
    with torch.no_grad():
        for s in range(0, len(a), batch_size):
            x, y = _to_tensor_nchw(a[s : s + batch_size], device), _to_tensor_nchw(b[s : s + batch_size], device)
            out[s : s + batch_size] = _flat(net(x, y), len(x), "lpips_net")
    return out


def lpips(pred, gt, net, *, n_frames: int | None = DEFAULT_FRAMES, batch_size: int = 16, device="cpu") -> np.ndarray:
    """LPIPS distance per frame (Zhang et al. 2018), with the LPIPS network given by the caller.

    ``net(x, y)`` receives two float32 tensors (B, 3, H, W) in [-1, 1] (RGB, no
    resizing) and returns B distances in any shape with B elements — the
    calling convention of ``lpips.LPIPS`` (e.g. ``lpips.LPIPS(net="alex")``,
    whose torchvision backbone must already be on disk). ``net`` may also be a
    path to a TorchScript module taking ``(x, y)``.

    ``pred``, ``gt``: videos (T, H, W, 3). Returns (T',) float64, lower is better.
    """
    pred, gt = _pair(pred, gt, n_frames)
    return _lpips_pairs(pred, gt, _callable(net, "lpips_net", device=device), batch_size, device)


def tlpips(pred, gt, net, *, n_frames: int | None = DEFAULT_FRAMES, batch_size: int = 16, device="cpu") -> np.ndarray:
    """Temporal LPIPS per step, as TecoGAN defines tLP (Chu et al. 2020, "Learning temporal
    coherence via self-supervision for GAN-based video generation").

    ``tLP_t = | LPIPS(gt[t−1], gt[t]) − LPIPS(pred[t−1], pred[t]) |`` for
    t = 1 … T'−1; the clip value is the mean over t. (TecoGAN prints it ×100;
    we do not scale.) ``net`` as in :func:`lpips`.

    ``pred``, ``gt``: videos (T, H, W, 3), T' ≥ 2 frames. Returns (T'−1,) float64, lower is better.
    """
    pred, gt = _pair(pred, gt, n_frames)
    if len(pred) < 2:
        raise MetricInputError("pred", "frames", "at least 2 frames for tLPIPS", f"{len(pred)} frames")
    f = _callable(net, "lpips_net", device=device)
    d_gt = _lpips_pairs(gt[:-1], gt[1:], f, batch_size, device)
    d_pred = _lpips_pairs(pred[:-1], pred[1:], f, batch_size, device)
    return np.abs(d_gt - d_pred)


def latent_l2(pred, gt, encoder, *, n_frames: int | None = DEFAULT_FRAMES, device="cpu") -> float:
    """Latent L2: mean squared difference between the VAE latents of prediction and ground truth.

    ``encoder(x)`` receives a float32 tensor (1, 3, T', H, W) in [-1, 1] (the
    layout of video tokenizers such as Cosmos' or Wan's VAE; wrap an image
    VAE to encode frame by frame) and returns a latent tensor; both latents
    must have the same shape. The paper names the metric "latent-ℓ2" without a
    formula; we report ``mean((z_pred − z_gt)²)`` over all latent elements,
    i.e. the squared ℓ2 distance divided by the number of latent elements, so
    the value does not grow with resolution or clip length. ``encoder`` may be
    a path to a TorchScript module.

    ``pred``, ``gt``: videos (T, H, W, 3). Returns a float ≥ 0, lower is better.
    """
    torch = _torch()
    pred, gt = _pair(pred, gt, n_frames)
    f = _callable(encoder, "vae", device=device)
    with torch.no_grad():
        z = []
        for v in (pred, gt):
            x = _to_tensor_nchw(v, device).permute(1, 0, 2, 3).unsqueeze(0)  # (1, 3, T, H, W)
            out = f(x)
            if hasattr(out, "latent_dist"):  # diffusers AutoencoderKL output
                out = out.latent_dist.mean
            if not hasattr(out, "shape"):
                raise MetricInputError("vae", "output", "a latent tensor", type(out).__name__)
            z.append(out.detach().double().cpu())
    if z[0].shape != z[1].shape:
        raise MetricInputError(
            "vae", "output shape", f"the same latent shape for both videos {tuple(z[1].shape)}", f"{tuple(z[0].shape)}"
        )
    return float(((z[0] - z[1]) ** 2).mean())


# --------------------------------------------------------------------------- #
# many clips at once
# --------------------------------------------------------------------------- #
@dataclass
class Clip:
    """One predicted clip and its ground truth.

    ``pred`` / ``gt``: arrays (T, H, W, 3) or paths (read with :func:`load_video` when needed).
    ``embodiment``: optional tag (e.g. ``"franka"``) for the per-embodiment breakdown.
    """

    name: str
    pred: object
    gt: object
    embodiment: str | None = None

    def load(self, max_frames: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(pred, gt) arrays; paths are read (at most ``max_frames`` frames)."""

        def get(v):
            return load_video(v, max_frames=max_frames) if isinstance(v, (str, os.PathLike)) else v

        return get(self.pred), get(self.gt)


PER_CLIP_METRICS = ("psnr", "ssim", "lpips", "tlpips", "latent_l2")
SET_METRICS = ("fvd", "fid")


def _mean(values) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


@dataclass
class VideoReport:
    """Results of :func:`evaluate_videos`.

    ``clips``: one row per clip (``name``, ``embodiment``, ``frames`` and each
    computed per-clip metric, the mean over its frames/steps). ``aggregate``:
    mean over clips of each per-clip metric, plus FVD / FID over all clips.
    ``per_embodiment``: ``{tag: {"clips": n, metric: mean over its clips}}``
    (only when clips carry tags), and ``mean_over_embodiments``: the unweighted
    mean of those per-embodiment means (how the paper's main table averages
    "over all embodiments").
    """

    n_frames: int | None
    clips: list[dict]
    aggregate: dict
    per_embodiment: dict = field(default_factory=dict)
    mean_over_embodiments: dict = field(default_factory=dict)

    @property
    def metrics(self) -> list[str]:
        return [m for m in PER_CLIP_METRICS if any(m in c for c in self.clips)]

    def to_dict(self) -> dict:
        """JSON-ready dictionary (NaN / inf → null)."""
        return nan_to_none(
            {
                "n_frames": self.n_frames,
                "aggregate": self.aggregate,
                "clips": self.clips,
                "per_embodiment": self.per_embodiment,
                "mean_over_embodiments": self.mean_over_embodiments,
            }
        )

    def format_table(self) -> str:
        """Per-clip rows, then per-embodiment means and the overall means."""
        metrics = self.metrics
        header = ("clip", "embodiment", *metrics)

        def fmt(v, m):
            if v is None:
                return "-"
            if isinstance(v, float) and math.isinf(v):
                return "inf"
            return f"{v:.2f}" if m in ("psnr", "fvd", "fid") else f"{v:.4f}"

        rows = [header] + [
            (c["name"], c.get("embodiment") or "-", *(fmt(c.get(m), m) for m in metrics)) for c in self.clips
        ]
        for tag, res in self.per_embodiment.items():
            rows.append((f"[mean] {tag} ({res['clips']})", tag, *(fmt(res.get(m), m) for m in metrics)))
        if self.mean_over_embodiments:
            rows.append(("[mean over embodiments]", "-", *(fmt(self.mean_over_embodiments.get(m), m) for m in metrics)))
        rows.append((f"[mean over clips] ({len(self.clips)})", "-", *(fmt(self.aggregate.get(m), m) for m in metrics)))
        widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
        lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
        extra = [f"{m.upper()} {fmt(self.aggregate[m], m)}" for m in SET_METRICS if self.aggregate.get(m) is not None]
        if extra:
            lines.append("   ".join(extra) + f"   (over {len(self.clips)} clips)")
        return "\n".join(lines)


def evaluate_videos(
    clips: Sequence[Clip],
    *,
    n_frames: int | None = DEFAULT_FRAMES,
    lpips_net=None,
    vae=None,
    fvd_extractor=None,
    fid_extractor=None,
    device="cpu",
    fvd_resolution: int | None = None,
    progress: bool = False,
) -> VideoReport:
    """Every video metric for a list of clips.

    Always computes PSNR and SSIM; LPIPS and tLPIPS when ``lpips_net`` is given
    (see :func:`lpips`), latent L2 with ``vae`` (:func:`latent_l2`), FVD with
    ``fvd_extractor`` (:func:`video_features`, needs ≥ 2 clips) and FID with
    ``fid_extractor`` (:func:`frame_features`). Each may be a callable or a
    TorchScript path. Clips are loaded one at a time; only features are kept.
    ``progress`` shows a tqdm bar on stderr.
    """
    if not clips:
        raise MetricInputError("clips", "clips", "at least one clip", "none")
    names = [c.name for c in clips]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise MetricInputError("clips", "name", "unique clip names", f"duplicates {dup}")
    lp = _callable(lpips_net, "lpips_net", device=device) if lpips_net is not None else None
    enc = _callable(vae, "vae", device=device) if vae is not None else None
    i3d_kwargs = I3D_CALL_KWARGS if fvd_resolution is None else I3D_PREPROCESSED_KWARGS
    fv = _callable(fvd_extractor, "fvd_extractor", i3d_kwargs, device) if fvd_extractor is not None else None
    fi = _callable(fid_extractor, "fid_extractor", INCEPTION_CALL_KWARGS, device) if fid_extractor is not None else None
    if fv is not None and len(clips) < 2:
        raise MetricInputError(
            "clips", "clips", "at least 2 clips for FVD (a covariance needs 2 samples)", f"{len(clips)}"
        )
    iterator = clips
    if progress and progress_bars_enabled():
        from tqdm import tqdm

        iterator = tqdm(clips, desc="eval video", unit="clip")
    rows, fvd_feats, fid_feats = [], ([], []), ([], [])
    for clip in iterator:
        pred, gt = clip.load(max_frames=n_frames)
        src = f"{clip.name}: "
        pred, gt = _pair(pred, gt, n_frames, src)
        row = {"name": clip.name, "embodiment": clip.embodiment, "frames": len(pred)}
        row["psnr"] = float(np.mean(psnr(pred, gt, n_frames=None)))
        row["ssim"] = float(np.mean(ssim(pred, gt, n_frames=None)))
        if lp is not None:
            row["lpips"] = float(np.mean(lpips(pred, gt, lp, n_frames=None, device=device)))
            if len(pred) > 1:
                row["tlpips"] = float(np.mean(tlpips(pred, gt, lp, n_frames=None, device=device)))
        if enc is not None:
            row["latent_l2"] = latent_l2(pred, gt, enc, n_frames=None, device=device)
        if fv is not None:
            fvd_feats[0].append(
                video_features(
                    [pred], fv, n_frames=None, resolution=fvd_resolution, device=device, source=f"{clip.name}: pred"
                )
            )
            fvd_feats[1].append(
                video_features(
                    [gt], fv, n_frames=None, resolution=fvd_resolution, device=device, source=f"{clip.name}: gt"
                )
            )
        if fi is not None:
            fid_feats[0].append(frame_features([pred], fi, n_frames=None, device=device))
            fid_feats[1].append(frame_features([gt], fi, n_frames=None, device=device))
        rows.append(row)

    metrics = [m for m in PER_CLIP_METRICS if any(m in r for r in rows)]
    aggregate = {m: _mean(r.get(m) for r in rows) for m in metrics}
    if fv is not None:
        aggregate["fvd"] = frechet_distance_from_features(np.concatenate(fvd_feats[0]), np.concatenate(fvd_feats[1]))
    if fi is not None:
        aggregate["fid"] = frechet_distance_from_features(np.concatenate(fid_feats[0]), np.concatenate(fid_feats[1]))
    per_emb, macro = {}, {}
    tags = [r["embodiment"] for r in rows if r["embodiment"] is not None]
    if tags:
        for tag in dict.fromkeys(tags):
            sel = [r for r in rows if r["embodiment"] == tag]
            per_emb[tag] = {"clips": len(sel), **{m: _mean(r.get(m) for r in sel) for m in metrics}}
        untagged = [r for r in rows if r["embodiment"] is None]
        if untagged:
            per_emb["(untagged)"] = {"clips": len(untagged), **{m: _mean(r.get(m) for r in untagged) for m in metrics}}
        macro = {m: _mean(v.get(m) for v in per_emb.values()) for m in metrics}
    return VideoReport(
        n_frames=n_frames, clips=rows, aggregate=aggregate, per_embodiment=per_emb, mean_over_embodiments=macro
    )
