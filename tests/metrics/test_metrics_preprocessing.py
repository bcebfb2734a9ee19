"""What FVD and FID feed their detectors, against references written here: FVD's ``resolution=R`` path is a bilinear
resize of the shorter side to R (half-pixel centres) and a centre crop; float frames become uint8 by rounding."""

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from oscar_core.metrics.frechet import frame_features, video_features  # noqa: E402


class Recorder:
    """An extractor that keeps what it was given and returns a few numbers per item."""

    def __init__(self):
        self.inputs = []

    def __call__(self, x):
        self.inputs.append(x.clone())
        return x.reshape(len(x), -1)[:, :4].double()


def _bilinear(img: np.ndarray, out_h: int, out_w: int) -> np.ndarray:
    """(H, W) float64 → (out_h, out_w): bilinear, pixel centres at +0.5 (align_corners=False), edges clamped;
    written from the definition, one output pixel at a time."""
    h, w = img.shape
    out = np.empty((out_h, out_w))
    for i in range(out_h):
        y = max((i + 0.5) * h / out_h - 0.5, 0.0)
        y0 = min(int(math.floor(y)), h - 1)
        y1, fy = min(y0 + 1, h - 1), y - y0
        for j in range(out_w):
            x = max((j + 0.5) * w / out_w - 0.5, 0.0)
            x0 = min(int(math.floor(x)), w - 1)
            x1, fx = min(x0 + 1, w - 1), x - x0
            top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
            bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
            out[i, j] = top * (1 - fy) + bottom * fy
    return out


def _reference(video: np.ndarray, r: int) -> np.ndarray:
    """(T, H, W, 3) uint8 → (3, T, r, r) in [-1, 1]: shorter side to r (bilinear), then the centre r x r."""
    t, h, w, _ = video.shape
    if h <= w:
        out_h, out_w = r, math.ceil(w * r / h)
    else:
        out_h, out_w = math.ceil(h * r / w), r
    top, left = (out_h - r) // 2, (out_w - r) // 2
    out = np.empty((3, t, r, r))
    for k in range(t):
        for c in range(3):
            resized = _bilinear(video[k, :, :, c].astype(np.float64) / 255.0, out_h, out_w)
            out[c, k] = resized[top : top + r, left : left + r]
    return out * 2.0 - 1.0


@pytest.mark.parametrize(
    "shape, r",
    [
        ((3, 12, 21, 3), 8),  # wide, downscaled: crop columns in the middle
        ((2, 19, 10, 3), 8),  # tall: crop rows in the middle
        ((2, 6, 9, 3), 12),
    ],
)  # upscaled
def test_fvd_resolution_path_is_a_bilinear_resize_and_a_centre_crop(shape, r):
    rng = np.random.default_rng(sum(shape) + r)
    video = rng.integers(0, 256, shape, dtype=np.uint8)
    rec = Recorder()
    video_features([video], rec, n_frames=None, resolution=r)
    got = rec.inputs[0][0].double().numpy()
    want = _reference(video, r)
    assert got.shape == want.shape == (3, shape[0], r, r)
    np.testing.assert_allclose(got, want, atol=2e-6)
    # the checks that can tell: a top-left crop or a nearest-neighbour resize is far from this
    t, h, w, _ = shape
    scale = r / min(h, w)
    nearest = video[:, np.minimum((np.arange(r) / scale).astype(int), h - 1)][
        :, :, np.minimum((np.arange(r) / scale).astype(int), w - 1)
    ]
    assert np.abs(got - (nearest.transpose(3, 0, 1, 2) / 255.0 * 2 - 1)).max() > 0.05


def test_fvd_resolution_path_on_a_ramp_keeps_the_centre():
    # a horizontal ramp, 2x as wide as tall: after the resize the centre crop starts a quarter of the way in
    w, h, r = 32, 16, 8
    ramp = np.tile(np.linspace(0, 255, w).round().astype(np.uint8)[None, :, None], (h, 1, 3))
    rec = Recorder()
    video_features([np.stack([ramp, ramp])], rec, n_frames=None, resolution=r)
    got = (rec.inputs[0][0, 0, 0].numpy() + 1) / 2 * 255  # one row of the first frame, grey levels
    resized = _bilinear(ramp[:, :, 0].astype(np.float64), r, w * r // h)
    np.testing.assert_allclose(got, resized[:, 4:12], atol=1e-3)
    assert got.min() > 60 and got.max() < 195  # neither edge of the ramp is in the centre crop


def test_float_frames_are_rounded_to_uint8_for_fid_and_fvd():
    # grey levels k + 0.3 and k + 0.7 (well away from the .5 ties): rounding gives k and k + 1, truncation k and k
    levels = np.array([0.0, 0.3, 0.7, 10.3, 10.7, 127.7, 200.2, 254.6, 255.0])
    frame = np.broadcast_to((levels / 255.0)[None, :, None], (4, len(levels), 3)).astype(np.float32)
    video = np.stack([frame, frame])
    want = np.array([int(v + 0.5) for v in levels], dtype=np.uint8)  # round half up; no ties here
    rec = Recorder()
    frame_features([video], rec, n_frames=None)
    x = rec.inputs[0]
    assert x.dtype == torch.uint8 and tuple(x.shape) == (2, 3, 4, len(levels))
    np.testing.assert_array_equal(x[0, 0, 0].numpy(), want)
    rec = Recorder()
    video_features([video], rec, n_frames=None)  # resolution=None: uint8 as StyleGAN-V feeds its I3D
    x = rec.inputs[0]
    assert x.dtype == torch.uint8
    np.testing.assert_array_equal(x[0, 0, 0, 0].numpy(), want)
    # and uint8 frames pass through unchanged
    rec = Recorder()
    frame_features([(video * 255).round().astype(np.uint8)], rec, n_frames=None)
    np.testing.assert_array_equal(rec.inputs[0][0, 0, 0].numpy(), want)
