"""Golden-image comparison for skeleton renders (usable by plugin authors too).

Images are compared by RMS over all pixels and channels on the 0-255 scale
with an explicit tolerance (``tol=0`` means exact); a size mismatch always
fails. On failure the actual, expected and an amplified difference image are
written to a results folder and their paths are in the assertion message.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["compare_images", "assert_matches_golden", "read_png", "write_png"]

DIFF_GAIN = 10


def compare_images(actual: np.ndarray, expected: np.ndarray) -> float:
    """RMS difference of two (H, W, C) images on the 0-255 scale (float64)."""
    a, e = np.asarray(actual), np.asarray(expected)
    if a.shape != e.shape:
        raise ValueError(f"image sizes differ: actual {a.shape}, expected {e.shape}")
    d = a.astype(np.float64) - e.astype(np.float64)
    return float(np.sqrt(np.mean(d * d))) if d.size else 0.0


def read_png(path: str | Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB from a PNG file."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(f"{path}: not a readable image")
    return np.ascontiguousarray(img[..., ::-1])


def write_png(path: str | Path, image: np.ndarray) -> Path:
    """Write (H, W, 3) uint8 RGB as PNG, atomically."""
    import cv2

    from .._util.atomic import atomic_output

    path = Path(path)
    with atomic_output(path) as tmp:
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(np.asarray(image)[..., ::-1])):
            raise OSError(f"{path}: could not encode PNG")
    return path


def assert_matches_golden(
    actual: np.ndarray, golden_path: str | Path, *, tol: float, results_dir: str | Path, regenerate: bool = False
) -> None:
    """Compare ``actual`` (H, W, 3) uint8 RGB with the PNG at ``golden_path``.

    regenerate: write ``actual`` as the new golden instead of comparing (only
    through an explicit option: a person looks at new goldens before commit).
    """
    actual = np.asarray(actual)
    if actual.dtype != np.uint8 or actual.ndim != 3 or actual.shape[2] != 3:
        raise AssertionError(f"expected an (H, W, 3) uint8 image, found {actual.dtype} {actual.shape}")
    golden_path = Path(golden_path)
    if regenerate:
        golden_path.parent.mkdir(parents=True, exist_ok=True)
        write_png(golden_path, actual)
        return
    if not golden_path.is_file():
        raise AssertionError(
            f"golden image {golden_path} does not exist; create it with pytest --oscar-regen-golden "
            "and look at it before committing"
        )
    expected = read_png(golden_path)
    if expected.shape != actual.shape:
        raise AssertionError(
            f"golden {golden_path}: size {expected.shape[1]}x{expected.shape[0]}, "
            f"actual {actual.shape[1]}x{actual.shape[0]}"
        )
    rms = compare_images(actual, expected)
    if rms <= tol:
        return
    results_dir = Path(results_dir)
    results_dir.mkdir(parents=True, exist_ok=True)
    stem = golden_path.stem
    paths = [results_dir / f"{stem}-{kind}.png" for kind in ("actual", "expected", "diff")]
    diff = np.clip(np.abs(actual.astype(np.int16) - expected.astype(np.int16)) * DIFF_GAIN, 0, 255).astype(np.uint8)
    for p, img in zip(paths, (actual, expected, diff)):
        write_png(p, img)
    raise AssertionError(
        f"{golden_path.name}: RMS {rms:.3f} > tolerance {tol} (0-255 scale)\n"
        f"  actual:   {paths[0]}\n  expected: {paths[1]}\n  diff x{DIFF_GAIN}: {paths[2]}"
    )
