"""Make the README's picture: skeleton frames beside the bundled oscar-toy model's rollout of them.

    python docs/make_readme_figure.py [--out docs/images/readme-skeleton-rollout.png]

The toy world's held-out demo episode (``oscar_core.toyworld.demo``, the one ``make demo`` rolls out) is rendered
as a skeleton video and rolled out by ``oscar-toy`` from its first frame (20 UniPC steps, guidance 3, seed 0).
The picture has two rows and three columns: the skeleton (top) and the rollout (bottom) at frames 0, 8 and 16 of
the 17-frame chunk, each 64×64 frame scaled up 3× by nearest neighbour (the pixels are the model's). No text in
the image: the README's caption says what it shows.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
FRAMES = (0, 8, 16)
SCALE = 3
GAP = 4


def figure(frames=FRAMES, scale: int = SCALE, gap: int = GAP) -> np.ndarray:
    """(2·64·scale + gap, n·64·scale + (n − 1)·gap, 3) uint8 RGB on white: skeleton row above rollout row."""
    from oscar_core.toyworld.demo import toy_rollout_demo

    with tempfile.TemporaryDirectory() as tmp:
        video, _ = toy_rollout_demo(tmp)  # (T, 2H, 3·2W + 2·2, 3): rollout | ground truth | skeleton, scaled 2x
    h = video.shape[1] // 2
    w = (video.shape[2] - 2 * 2) // 3 // 2
    rollout = video[:, ::2, : 2 * w : 2]
    skeleton = video[:, ::2, -2 * w :: 2]
    assert rollout.shape[1:3] == skeleton.shape[1:3] == (h, w), (rollout.shape, skeleton.shape)

    def up(img):
        return np.repeat(np.repeat(img, scale, axis=0), scale, axis=1)

    tile_h, tile_w = h * scale, w * scale
    out = np.full((2 * tile_h + gap, len(frames) * tile_w + (len(frames) - 1) * gap, 3), 255, np.uint8)
    for col, t in enumerate(frames):
        x = col * (tile_w + gap)
        out[:tile_h, x : x + tile_w] = up(skeleton[t])
        out[tile_h + gap :, x : x + tile_w] = up(rollout[t])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(REPO / "docs" / "images" / "readme-skeleton-rollout.png"))
    args = ap.parse_args(argv)
    import cv2

    from oscar_core._util.atomic import atomic_write_bytes

    ok, png = cv2.imencode(".png", np.ascontiguousarray(figure()[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:
        raise SystemExit("error: OpenCV could not encode the figure as PNG")
    out = atomic_write_bytes(Path(args.out), png.tobytes())
    print(f"wrote {out} ({len(png.tobytes()) / 1024:.0f} KB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
