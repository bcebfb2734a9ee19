"""Video metrics: PSNR/SSIM against scikit-image, Frechet distances against closed forms,
LPIPS/tLPIPS/latent-L2/FVD/FID with small deterministic stand-in networks."""

import json
import math
import warnings

import numpy as np
import pytest
import scipy.linalg
import torch

from oscar_core.metrics import (
    DEFAULT_FRAMES,
    Clip,
    MetricInputError,
    evaluate_videos,
    feature_statistics,
    fid,
    frame_features,
    frechet_distance,
    frechet_distance_from_features,
    fvd,
    latent_l2,
    load_torchscript,
    lpips,
    psnr,
    ssim,
    tlpips,
    video_features,
)

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.script` is deprecated:DeprecationWarning")


def _videos(seed=0, shape=(4, 24, 32, 3), noise=25):
    rng = np.random.default_rng(seed)
    gt = rng.integers(0, 256, shape, dtype=np.uint8)
    pred = np.clip(gt.astype(int) + rng.integers(-noise, noise + 1, shape), 0, 255).astype(np.uint8)
    return pred, gt


# --------------------------------------------------------------------------- #
# PSNR / SSIM against scikit-image
# --------------------------------------------------------------------------- #
def test_psnr_ssim_match_scikit_image():
    skm = pytest.importorskip("skimage.metrics")
    for seed, shape in [(0, (3, 24, 32, 3)), (1, (2, 11, 11, 3)), (2, (2, 40, 17, 3))]:
        pred, gt = _videos(seed, shape)
        p, s = psnr(pred, gt, n_frames=None), ssim(pred, gt, n_frames=None)
        for t in range(len(gt)):
            assert p[t] == pytest.approx(skm.peak_signal_noise_ratio(gt[t], pred[t], data_range=255), abs=1e-10)
            ref = skm.structural_similarity(
                gt[t],
                pred[t],
                data_range=255,
                channel_axis=-1,
                gaussian_weights=True,
                sigma=1.5,
                use_sample_covariance=False,
            )
            assert s[t] == pytest.approx(ref, abs=1e-10)
    # float frames in [0, 1] with data range 1 give the same numbers as their uint8 originals
    pred, gt = _videos(3)
    assert psnr(pred / 255.0, gt / 255.0, n_frames=None) == pytest.approx(psnr(pred, gt, n_frames=None))
    assert ssim(pred / 255.0, gt / 255.0, n_frames=None) == pytest.approx(ssim(pred, gt, n_frames=None))


def test_psnr_hand_worked_and_identity():
    gt = np.zeros((1, 12, 12, 3), np.uint8)
    pred = np.full_like(gt, 51)  # every pixel off by 51/255 = 0.2 -> MSE 0.04 -> 10 log10(1/0.04) = 13.979 dB
    assert psnr(pred, gt, n_frames=None)[0] == pytest.approx(10 * math.log10(25))
    # identical frames: capped at 100 dB by convention (one identical frame must not make a clip mean inf) ...
    assert psnr(gt, gt, n_frames=None).tolist() == [100.0]
    assert np.isinf(psnr(gt, gt, n_frames=None, cap=None)).all()  # ... uncapped on request
    video = np.stack([gt[0], pred[0]])  # frame 0 identical, frame 1 off: the clip mean stays finite
    assert psnr(video, np.stack([gt[0], gt[0]]), n_frames=None).mean() == pytest.approx((100 + 10 * math.log10(25)) / 2)
    # one 8-bit level in one value of a 512x288 frame is above the cap: 10 log10(255^2 * 512*288*3) = 104.6 dB
    big = np.zeros((1, 288, 512, 3), np.uint8)
    one = big.copy()
    one[0, 0, 0, 0] = 1
    assert psnr(one, big, n_frames=None, cap=None)[0] == pytest.approx(10 * math.log10(255**2 * 512 * 288 * 3))
    assert psnr(one, big, n_frames=None)[0] == 100.0
    with pytest.raises(MetricInputError, match="cap"):
        psnr(gt, gt, cap=float("inf"), n_frames=None)
    assert ssim(gt, gt, n_frames=None) == pytest.approx([1.0])


def test_first_49_frames_by_default():
    assert DEFAULT_FRAMES == 49
    pred, gt = _videos(4, (52, 12, 12, 3))
    pred[49:] = 0  # frames after the 49th must not count
    assert len(psnr(pred, gt)) == 49
    assert psnr(pred, gt) == pytest.approx(psnr(pred[:49], gt[:49], n_frames=None))
    assert len(ssim(pred, gt, n_frames=10)) == 10
    with pytest.raises(MetricInputError, match=r"pred: field 'frames': expected at least 49 frames .* found 20"):
        psnr(pred[:20], gt)


@pytest.mark.parametrize(
    "pred, gt, words",
    [
        (np.zeros((2, 12, 12, 3), np.uint8), np.zeros((2, 12, 14, 3), np.uint8), ["frame size", "14x12", "12x12"]),
        (np.zeros((2, 12, 12), np.uint8), np.zeros((2, 12, 12, 3), np.uint8), ["pred", "(T, H, W, 3)", "(2, 12, 12)"]),
        (np.full((2, 12, 12, 3), 2.0), np.zeros((2, 12, 12, 3)), ["pred", "values", "[0, 1]", "[2, 2]"]),
        (np.zeros((2, 12, 12, 3), np.int32), np.zeros((2, 12, 12, 3), np.uint8), ["dtype", "int32"]),
        (np.zeros((3, 12, 12, 3), np.uint8), np.zeros((2, 12, 12, 3), np.uint8), ["frames", "n_frames=None"]),
    ],
)
def test_video_input_errors(pred, gt, words):
    with pytest.raises(MetricInputError) as exc:
        psnr(pred, gt, n_frames=None)
    for w in words:
        assert w in str(exc.value)


# --------------------------------------------------------------------------- #
# Frechet distance
# --------------------------------------------------------------------------- #
def test_frechet_distance_closed_forms():
    # 1-D: N(0, 1) vs N(1, 4): (0 - 1)^2 + 1 + 4 - 2 sqrt(1 * 4) = 1 + 5 - 4 = 2
    assert frechet_distance([0.0], [[1.0]], [1.0], [[4.0]]) == pytest.approx(2.0)
    # diagonal covariances commute: |dmu|^2 + sum (sqrt(a) - sqrt(b))^2
    a, b = np.array([1.0, 4.0, 9.0]), np.array([4.0, 1.0, 16.0])
    mu1, mu2 = np.array([0.0, 1.0, 2.0]), np.array([1.0, 1.0, 0.0])
    expected = 1 + 0 + 4 + (1 - 2) ** 2 + (2 - 1) ** 2 + (3 - 4) ** 2
    assert frechet_distance(mu1, np.diag(a), mu2, np.diag(b)) == pytest.approx(expected)
    # general SPD: the textbook formula with scipy's matrix square root
    rng = np.random.default_rng(0)
    A, B = rng.normal(size=(5, 5)), rng.normal(size=(5, 5))
    s1, s2 = A @ A.T + 0.1 * np.eye(5), B @ B.T + 0.1 * np.eye(5)
    m1, m2 = rng.normal(size=5), rng.normal(size=5)
    covmean = np.real(scipy.linalg.sqrtm(s1 @ s2))
    ref = np.sum((m1 - m2) ** 2) + np.trace(s1) + np.trace(s2) - 2 * np.trace(covmean)
    assert frechet_distance(m1, s1, m2, s2) == pytest.approx(ref, rel=1e-9)
    assert frechet_distance(m1, s1, m1, s1) == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(MetricInputError, match="sigma2: field 'shape'"):
        frechet_distance(m1, s1, m2, s2[:4, :4])


def test_feature_statistics_and_sampled_gaussians():
    rng = np.random.default_rng(1)
    f = rng.normal(size=(50, 3))
    mu, sigma = feature_statistics(f)
    assert mu == pytest.approx(f.mean(0)) and sigma == pytest.approx(np.cov(f, rowvar=False))
    # samples from N(0, I) and N(m, diag(s^2)) -> distance close to |m|^2 + sum (1 - s)^2
    n = 20000
    m, s = np.array([1.0, -0.5]), np.array([2.0, 0.5])
    x, y = rng.normal(size=(n, 2)), rng.normal(size=(n, 2)) * s + m
    expected = np.sum(m**2) + np.sum((1 - s) ** 2)
    assert frechet_distance_from_features(x, y) == pytest.approx(expected, abs=0.05)
    with pytest.raises(MetricInputError, match="at least 2 samples"):
        feature_statistics(f[:1])


# --------------------------------------------------------------------------- #
# stand-in networks
# --------------------------------------------------------------------------- #
class TinyLPIPS(torch.nn.Module):
    """Deterministic LPIPS-shaped stand-in: unit-normalised conv features, squared difference, spatial mean."""

    def __init__(self):
        super().__init__()
        g = torch.Generator().manual_seed(0)
        self.conv = torch.nn.Conv2d(3, 4, 3, padding=1)
        with torch.no_grad():
            self.conv.weight.copy_(torch.randn(self.conv.weight.shape, generator=g))
            self.conv.bias.zero_()

    def forward(self, x, y):
        fx, fy = self.conv(x), self.conv(y)
        fx = fx / (torch.sqrt((fx * fx).sum(dim=1, keepdim=True)) + 1e-10)
        fy = fy / (torch.sqrt((fy * fy).sum(dim=1, keepdim=True)) + 1e-10)
        return ((fx - fy) ** 2).sum(dim=1, keepdim=True).mean(dim=(2, 3), keepdim=True)  # (B, 1, 1, 1) like lpips


def _l1(x, y):  # a trivial "LPIPS": mean absolute difference per image in [-1, 1] units
    return (x - y).abs().mean(dim=(1, 2, 3))


def test_tlpips_arithmetic():
    # constant grey frames (float, [0, 1]); in the network's [-1, 1] units:
    #   gt   = 0, 0.5, 0.5   -> -1, 0, 0      -> d_gt   = |(-1) - 0|, |0 - 0|     = 1.0, 0.0
    #   pred = 0, 0.25, 1.0  -> -1, -0.5, 1   -> d_pred = |(-1) - (-0.5)|, |(-0.5) - 1| = 0.5, 1.5
    #   tLP  = |1.0 - 0.5|, |0.0 - 1.5| = 0.5, 1.5  -> clip tLPIPS 1.0
    gt = np.stack([np.full((12, 12, 3), v) for v in (0.0, 0.5, 0.5)])
    pred = np.stack([np.full((12, 12, 3), v) for v in (0.0, 0.25, 1.0)])
    steps = tlpips(pred, gt, _l1, n_frames=None)
    assert steps == pytest.approx([0.5, 1.5])
    assert steps.mean() == pytest.approx(1.0)
    # per-frame LPIPS of the same stand-in: |(-1)-(-1)|, |0-(-0.5)|, |0-1| = 0, 0.5, 1
    assert lpips(pred, gt, _l1, n_frames=None) == pytest.approx([0.0, 0.5, 1.0])


def test_lpips_with_a_network_and_a_torchscript_file(tmp_path):
    pred, gt = _videos(5, (5, 16, 20, 3))
    net = TinyLPIPS().eval()
    per_frame = lpips(pred, gt, net, n_frames=None, batch_size=2)
    with torch.no_grad():
        x = torch.from_numpy(pred / 255.0).float().permute(0, 3, 1, 2) * 2 - 1
        y = torch.from_numpy(gt / 255.0).float().permute(0, 3, 1, 2) * 2 - 1
        direct = net(x, y).flatten().numpy()
    assert per_frame == pytest.approx(direct, rel=1e-5)
    assert lpips(gt, gt, net, n_frames=None) == pytest.approx(np.zeros(5), abs=1e-6)
    # the same network as a TorchScript file
    path = tmp_path / "tiny_lpips.pt"
    torch.jit.script(net).save(str(path))
    assert lpips(pred, gt, path, n_frames=None) == pytest.approx(per_frame, rel=1e-5)
    t_steps = tlpips(pred, gt, path, n_frames=None)
    d_gt = np.array([direct_pair(net, gt[t - 1], gt[t]) for t in range(1, 5)])
    d_pred = np.array([direct_pair(net, pred[t - 1], pred[t]) for t in range(1, 5)])
    assert t_steps == pytest.approx(np.abs(d_gt - d_pred), rel=1e-4, abs=1e-7)
    with pytest.raises(MetricInputError, match="no such file"):
        lpips(pred, gt, tmp_path / "missing.pt", n_frames=None)
    with pytest.raises(MetricInputError, match=r"lpips_net: field 'output': expected 5 values"):
        lpips(pred, gt, lambda a, b: torch.zeros(3), n_frames=None)


def direct_pair(net, a, b):
    with torch.no_grad():
        x = torch.from_numpy(a / 255.0).float().permute(2, 0, 1)[None] * 2 - 1
        y = torch.from_numpy(b / 255.0).float().permute(2, 0, 1)[None] * 2 - 1
        return float(net(x, y))


def test_latent_l2_with_a_stand_in_encoder():
    pred, gt = _videos(6, (4, 16, 16, 3))

    def encoder(x):  # (1, 3, T, H, W) -> a 4x-downsampled "latent"
        assert x.shape == (1, 3, 4, 16, 16) and x.min() >= -1 and x.max() <= 1
        return torch.nn.functional.avg_pool3d(x, (1, 4, 4))

    def numpy_latent(v):
        u = v / 255.0 * 2 - 1  # T, H, W, 3
        return u.reshape(4, 4, 4, 4, 4, 3).mean(axis=(2, 4))

    expected = np.mean((numpy_latent(pred) - numpy_latent(gt)) ** 2)
    assert latent_l2(pred, gt, encoder, n_frames=None) == pytest.approx(expected, rel=1e-5)
    assert latent_l2(gt, gt, encoder, n_frames=None) == 0.0


class TinyI3D(torch.nn.Module):
    """Stand-in with the StyleGAN-V i3d_torchscript.pt call signature: per-channel mean/std over (T, H, W)."""

    def forward(self, x, rescale: bool = True, resize: bool = True, return_features: bool = False):
        assert not rescale and not resize and return_features
        return torch.cat([x.mean(dim=(2, 3, 4)), x.std(dim=(2, 3, 4))], dim=1)


def test_fvd_preprocessing_and_torchscript_path(tmp_path):
    seen = []

    def extractor(x):
        seen.append(tuple(x.shape))
        assert x.dtype == torch.float32 and x.min() >= -1 and x.max() <= 1
        return torch.cat([x.mean(dim=(2, 3, 4)), x.std(dim=(2, 3, 4))], dim=1)

    rng = np.random.default_rng(7)
    vids = [rng.integers(0, 256, (10, 36, 64, 3), dtype=np.uint8) for _ in range(3)]
    feats = video_features(vids, extractor, n_frames=8, resolution=16, batch_size=2)
    # shorter side 36 -> 16, width 64 -> ceil(64 * 16 / 36) = 29, centre crop 16x16; (B, 3, T, 16, 16)
    assert seen == [(2, 3, 8, 16, 16), (1, 3, 8, 16, 16)]
    assert feats.shape == (3, 6)
    path = tmp_path / "tiny_i3d.pt"
    torch.jit.script(TinyI3D()).save(str(path))
    assert video_features(vids, path, n_frames=8, resolution=16) == pytest.approx(feats, rel=1e-6)
    gts = [np.clip(v.astype(int) + 40, 0, 255).astype(np.uint8) for v in vids]
    value = fvd(vids, gts, path, n_frames=8, resolution=16)
    ref = frechet_distance_from_features(feats, video_features(gts, extractor, n_frames=8, resolution=16))
    assert value == pytest.approx(ref, rel=1e-6) and value > 0
    assert fvd(vids, vids, extractor, n_frames=8, resolution=16) == pytest.approx(0.0, abs=1e-9)
    assert isinstance(load_torchscript(path, rescale=False, resize=False, return_features=True), object)


def test_fid_frame_features():
    def extractor(x):
        assert x.dtype == torch.uint8 and x.shape[1:] == (3, 12, 12)
        return x.double().mean(dim=(2, 3))

    pred, gt = _videos(8, (6, 12, 12, 3))
    f = frame_features([pred, gt], extractor, n_frames=5, batch_size=4)
    assert f.shape == (10, 3)
    assert f[:5] == pytest.approx(pred[:5].reshape(5, -1, 3).mean(axis=1))
    value = fid([pred], [gt], extractor, n_frames=None)
    ref = frechet_distance_from_features(pred.reshape(6, -1, 3).mean(1), gt.reshape(6, -1, 3).mean(1))
    assert value == pytest.approx(ref, rel=1e-9)


# --------------------------------------------------------------------------- #
# many clips
# --------------------------------------------------------------------------- #
def test_evaluate_videos_per_clip_aggregate_and_embodiments(tmp_path):
    clips = []
    for k, emb in enumerate(["franka", "franka", "kuka", "kuka", "kuka"]):
        pred, gt = _videos(10 + k, (6, 16, 16, 3), noise=10 + 10 * k)
        if k == 0:  # one clip from files (.npy)
            np.save(tmp_path / "p0.npy", pred)
            np.save(tmp_path / "g0.npy", gt)
            clips.append(Clip(f"clip{k}", tmp_path / "p0.npy", tmp_path / "g0.npy", emb))
        else:
            clips.append(Clip(f"clip{k}", pred, gt, emb))
    rep = evaluate_videos(
        clips,
        n_frames=5,
        lpips_net=TinyLPIPS().eval(),
        vae=lambda x: x[:, :, :, ::4, ::4],
        fvd_extractor=lambda x: x.float().mean(dim=(2, 3, 4)),
        fid_extractor=lambda x: x.float().mean((2, 3)),
    )
    assert [c["name"] for c in rep.clips] == [f"clip{k}" for k in range(5)]
    pred1, gt1 = clips[1].pred, clips[1].gt
    row = rep.clips[1]
    assert row["frames"] == 5
    assert row["psnr"] == pytest.approx(psnr(pred1, gt1, n_frames=5).mean())
    assert row["ssim"] == pytest.approx(ssim(pred1, gt1, n_frames=5).mean())
    assert row["tlpips"] == pytest.approx(tlpips(pred1, gt1, TinyLPIPS().eval(), n_frames=5).mean(), rel=1e-6)
    assert rep.aggregate["psnr"] == pytest.approx(np.mean([c["psnr"] for c in rep.clips]))
    assert set(rep.per_embodiment) == {"franka", "kuka"} and rep.per_embodiment["kuka"]["clips"] == 3
    kuka = np.mean([c["ssim"] for c in rep.clips if c["embodiment"] == "kuka"])
    assert rep.per_embodiment["kuka"]["ssim"] == pytest.approx(kuka)
    assert rep.mean_over_embodiments["ssim"] == pytest.approx(
        (rep.per_embodiment["kuka"]["ssim"] + rep.per_embodiment["franka"]["ssim"]) / 2
    )
    assert rep.aggregate["fvd"] >= 0 and rep.aggregate["fid"] >= 0
    data = json.loads(json.dumps(rep.to_dict()))
    assert data["n_frames"] == 5 and set(data["aggregate"]) == {
        "psnr",
        "ssim",
        "lpips",
        "tlpips",
        "latent_l2",
        "fvd",
        "fid",
    }
    table = rep.format_table()
    assert "[mean] kuka (3)" in table and "FVD" in table
    with pytest.raises(MetricInputError, match="duplicates"):
        evaluate_videos([clips[1], clips[1]], n_frames=5)
    with pytest.raises(MetricInputError, match=r"clip1: pred: field 'frames': expected at least 49 frames"):
        evaluate_videos(clips[1:3], n_frames=49)


class RefI3D(torch.nn.Module):
    """Fixture with the i3d_torchscript.pt interface: rescales [0, 255] and resizes to 224x224 itself when asked,
    and returns features that see *where* things are (a 4x4 grid of channel means), so a crop changes them."""

    def forward(self, x, rescale: bool = False, resize: bool = False, return_features: bool = False):
        x = x.float()
        if rescale:
            x = x / 127.5 - 1.0
        if resize:
            x = torch.nn.functional.interpolate(x, size=(x.shape[2], 224, 224), mode="trilinear", align_corners=False)
        return torch.nn.functional.adaptive_avg_pool3d(x, (1, 4, 4)).flatten(1)


class RefInception(torch.nn.Module):
    """Fixture with the inception-2015-12-05.pt interface: uint8 (B, 3, H, W), resized to 299x299 inside."""

    def forward(self, x, return_features: bool = False):
        assert x.dtype == torch.uint8
        x = torch.nn.functional.interpolate(x.float(), size=(299, 299), mode="bilinear", align_corners=False)
        return torch.nn.functional.adaptive_avg_pool2d(x, (3, 3)).flatten(1)


def _wide_clips(seed, n=4, t=6):
    """Non-square (36x96) clips whose left and right thirds differ from the middle: a centre crop loses them."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        v = rng.integers(90, 110, (t, 36, 96, 3)).astype(np.uint8)
        v[:, :, :32] = rng.integers(0, 256)  # the edges carry most of the difference between clips
        v[:, :, 64:] = rng.integers(0, 256)
        out.append(v)
    return out


def test_fvd_and_fid_preprocessing_match_the_reference_code(tmp_path):
    # StyleGAN-V: uint8 (B, 3, T, H, W) straight into the detector, called with rescale=True, resize=True
    i3d_path = tmp_path / "i3d.pt"
    torch.jit.script(RefI3D()).save(str(i3d_path))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        det = torch.jit.load(str(i3d_path))
    pred, gt = _wide_clips(1), _wide_clips(2)

    def reference_features(clips):
        x = torch.from_numpy(np.stack(clips)).permute(0, 4, 1, 2, 3).contiguous()  # [b, c, t, h, w] uint8
        return det(x, rescale=True, resize=True, return_features=True).double().numpy()

    ref = frechet_distance_from_features(reference_features(pred), reference_features(gt))
    ours = fvd(pred, gt, i3d_path, n_frames=None)
    assert ours == pytest.approx(ref, rel=1e-9) and ref > 1.0
    # a centre crop (shorter side -> 224, crop 224x224) or our own stretch to [-1, 1] change the number
    cropped = fvd(pred, gt, i3d_path, n_frames=None, resolution=224)
    assert abs(cropped - ref) > 0.1 * ref
    seen = []
    video_features(
        pred[:2] + [pred[2][:, :, :48]],
        lambda x: seen.append((x.dtype, tuple(x.shape))) or torch.zeros(len(x), 2),
        n_frames=4,
    )
    assert seen == [(torch.uint8, (2, 3, 4, 36, 96)), (torch.uint8, (1, 3, 4, 36, 48))]  # sizes batched apart
    # StyleGAN2-ADA FID: uint8 (B, 3, H, W) frames at their own size; the detector resizes to 299x299
    inc_path = tmp_path / "inception.pt"
    torch.jit.script(RefInception()).save(str(inc_path))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        inc = torch.jit.load(str(inc_path))

    def reference_frames(clips):
        x = torch.from_numpy(np.concatenate(clips)).permute(0, 3, 1, 2).contiguous()
        return inc(x, return_features=True).double().numpy()

    ref_fid = frechet_distance_from_features(reference_frames(pred), reference_frames(gt))
    assert fid(pred, gt, inc_path, n_frames=None) == pytest.approx(ref_fid, rel=1e-9)
    crop = lambda clips: [np.ascontiguousarray(c[:, :, 30:66]) for c in clips]  # noqa: E731 - a centre crop first
    assert abs(fid(crop(pred), crop(gt), inc_path, n_frames=None) - ref_fid) > 0.1 * ref_fid
