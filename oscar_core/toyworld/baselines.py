"""Reference predictions for the toy-world table that need no model.

``first_frame``: every frame is the clip's first frame (a world model that
ignores the actions). Any model worth shipping must beat it on the
end-effector and object errors.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from .._util.atomic import atomic_write_bytes

__all__ = ["BASELINES", "write_baseline"]

BASELINES = ("first_frame",)


def write_baseline(
    clipset, out, kind: str = "first_frame", split: str | None = "heldout", limit: int | None = None
) -> list[str]:
    """Write the ``kind`` prediction of each clip (of ``split``; at most ``limit``, every k-th) as
    ``OUT/<clip id>.npy`` ((T, H, W, 3) uint8)."""
    from ..train.clips import ClipSet
    from .rollouts import spread

    if kind not in BASELINES:
        raise ValueError(f"baseline: expected one of {BASELINES}, found {kind!r}")
    cs = ClipSet(clipset)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ids = []
    for r in spread([r for r in cs if split is None or r.meta.get("split") == split], limit):
        rgb = cs.load(r, frames=1, skeleton=False).rgb
        pred = np.repeat(rgb[:1], r.n_frames, axis=0)
        buf = io.BytesIO()
        np.save(buf, pred)
        atomic_write_bytes(out / f"{r.id}.npy", buf.getvalue())
        ids.append(r.id)
    return ids
