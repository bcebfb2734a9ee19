"""Frame counts and chunks: the 4k + 1 frames a video VAE takes, and how a long rollout is cut into chunks.

An autoregressive rollout of ``T`` frames in chunks of ``C`` frames overlaps one frame: chunk k (0-based) starts
from frame ``k (C − 1)`` (its seed, made by chunk k − 1 or given) and makes frames ``k (C − 1) + 1`` to
``(k + 1)(C − 1)``, the last chunk cut at ``T − 1``. :func:`chunk_plan` gives the starts (what a rollout
runs), :func:`chunk_windows` the frames each chunk makes (what per-chunk metrics split by); both come from
:func:`_chunk_starts`. NumPy and torch free, so a metric or a check does not load the model's stack.
"""

from __future__ import annotations

from .errors import ModelInputError

__all__ = ["check_frame_count", "chunk_plan", "chunk_windows"]


def check_frame_count(frames: int, temporal: int = 4, what: str = "video") -> int:
    """Raise unless ``frames`` = temporal·k + 1 (k ≥ 0); returns the latent frame count k + 1."""
    if frames < 1 or (frames - 1) % temporal:
        lower = (max(frames - 1, 0) // temporal) * temporal + 1
        raise ModelInputError(
            f"{what}: expected a frame count of the form {temporal}k+1 (1, 5, 9, ..., 81, ...), "
            f"found {frames} (nearest valid: {lower} or {lower + temporal})"
        )
    return (frames - 1) // temporal + 1


def _chunk_starts(num_frames: int, chunk_frames: int) -> list[int]:
    """Start (seed) frame of each chunk of ``chunk_frames`` ≥ 2 frames covering ``num_frames`` ≥ 2 frames."""
    step = chunk_frames - 1
    count = -(-(num_frames - 1) // step)
    return [k * step for k in range(count)]


def chunk_plan(num_frames: int, chunk_frames: int, temporal: int = 4) -> list[int]:
    """Start frame of each chunk of ``chunk_frames`` covering ``num_frames`` (overlap of one frame)."""
    check_frame_count(chunk_frames, temporal, what="chunk_frames")
    if chunk_frames < 1 + temporal:
        raise ModelInputError(
            f"chunk_frames: expected at least {1 + temporal} (one frame to predict beyond the "
            f"seed), found {chunk_frames}"
        )
    if num_frames < chunk_frames:
        shorter = (max(num_frames - 1, 0) // temporal) * temporal + 1
        hint = (
            f"; use chunk_frames={shorter} (--chunk-frames {shorter}) or a longer trajectory"
            if shorter >= 1 + temporal
            else "; use a longer trajectory"
        )
        raise ModelInputError(
            f"trajectory: expected at least one chunk of {chunk_frames} frames, found {num_frames} frames{hint}"
        )
    return _chunk_starts(num_frames, chunk_frames)


def chunk_windows(num_frames: int, chunk_frames: int) -> list[tuple[int, int]]:
    """The frames each chunk of a rollout makes: [(first, last)] inclusive, chunk 1 first.

    num_frames: frames of the video, the first (given) one included; chunk_frames: frames per chunk, the
    seed frame included (17 for ``oscar-toy``). ``[(1, 16), (17, 32), …]`` for 17; the last window ends at
    ``num_frames − 1`` (a rollout's last chunk is cut there). Any chunk of at least 2 frames and any video of
    at least 2 frames (no 4k + 1 rule: the frames of a finished video are only being split).
    """
    if chunk_frames < 2:
        raise ModelInputError(f"chunk_frames: expected at least 2 frames (the seed and one new), found {chunk_frames}")
    if num_frames < 2:
        raise ModelInputError(f"video: expected at least 2 frames, found {num_frames}")
    return [(s + 1, min(s + chunk_frames - 1, num_frames - 1)) for s in _chunk_starts(num_frames, chunk_frames)]
