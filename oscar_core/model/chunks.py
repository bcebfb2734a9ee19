"""Frame counts and chunks: the 4k + 1 frames a video VAE takes, and how a long rollout is cut into chunks.

An autoregressive rollout of ``T`` frames in chunks of ``C`` frames overlaps one frame: chunk k (0-based) starts
from frame ``k (C − 1)`` (its seed, made by chunk k − 1 or given) and makes frames ``k (C − 1) + 1`` to
``(k + 1)(C − 1)``, the last chunk cut at ``T − 1``. :func:`chunk_plan` gives the starts (what a rollout
runs), :func:`chunk_windows` the frames each chunk makes (what per-chunk metrics split by); both come from
:func:`_chunk_starts`. NumPy and torch free, so a metric or a check does not load the model's stack.

A model with a longer context (``context_frames`` N = 4k + 1 pixel frames, k + 1 latent frames: the card's
``context_frames``) continues each chunk after the first from the previous chunk's last N decoded frames, so
chunks overlap by N frames: chunk 0 starts at frame 0 from the given first frame alone (a 1-frame context: an
episode has no earlier frames; the model is trained with some items at a 1-frame context to serve it,
``flow.context_dropout``) and makes frames 1 to C − 1; chunk j ≥ 1 starts at ``j (C − N)`` and makes frames
``j (C − N) + N`` to ``j (C − N) + C − 1``, the last cut at ``T − 1``. N = 1 is the plan above.
"""

from __future__ import annotations

from .errors import ModelInputError

__all__ = ["check_context_frames", "check_frame_count", "chunk_plan", "chunk_windows"]


def check_frame_count(frames: int, temporal: int = 4, what: str = "video") -> int:
    """Raise unless ``frames`` = temporal·k + 1 (k ≥ 0); returns the latent frame count k + 1."""
    if frames < 1 or (frames - 1) % temporal:
        lower = (max(frames - 1, 0) // temporal) * temporal + 1
        raise ModelInputError(
            f"{what}: expected a frame count of the form {temporal}k+1 (1, 5, 9, ..., 81, ...), "
            f"found {frames} (nearest valid: {lower} or {lower + temporal})"
        )
    return (frames - 1) // temporal + 1


def check_context_frames(context_frames, chunk_frames: int, temporal: int = 4, what: str = "context_frames") -> int:
    """Raise unless ``context_frames`` = temporal·k + 1 (k ≥ 0) pixel frames whose k + 1 latent frames are fewer
    than the ``chunk_frames``-frame chunk's (at least one latent frame left to generate); returns k + 1."""
    chunk_latents = (int(chunk_frames) - 1) // temporal + 1
    ok = (
        isinstance(context_frames, int)
        and not isinstance(context_frames, bool)
        and context_frames >= 1
        and (context_frames - 1) % temporal == 0
        and (context_frames - 1) // temporal + 1 < chunk_latents
    )
    if not ok:
        most = (chunk_latents - 2) * temporal + 1
        raise ModelInputError(
            f"{what}: expected pixel frames of the form {temporal}k+1 (1, {1 + temporal}, ...) covering fewer latent "
            f"frames than the {chunk_frames}-frame chunk's {chunk_latents} (at most {most}), found {context_frames!r}"
        )
    return (context_frames - 1) // temporal + 1


def _chunk_starts(num_frames: int, chunk_frames: int, context_frames: int = 1) -> list[int]:
    """Start frame of each chunk of ``chunk_frames`` ≥ 2 frames covering ``num_frames`` ≥ 2 frames, chunks after
    the first overlapping their predecessor by ``context_frames`` frames (module docstring)."""
    step = chunk_frames - context_frames
    count = 1 + max(0, -(-(num_frames - chunk_frames) // step))
    return [k * step for k in range(count)]


def chunk_plan(num_frames: int, chunk_frames: int, temporal: int = 4, context_frames: int = 1) -> list[int]:
    """Start frame of each chunk of ``chunk_frames`` covering ``num_frames``: chunk j ≥ 1 starts
    ``chunk_frames − context_frames`` frames after chunk j − 1 (an overlap of one frame with the default context;
    module docstring)."""
    check_frame_count(chunk_frames, temporal, what="chunk_frames")
    if chunk_frames < 1 + temporal:
        raise ModelInputError(
            f"chunk_frames: expected at least {1 + temporal} (one frame to predict beyond the "
            f"seed), found {chunk_frames}"
        )
    check_context_frames(context_frames, chunk_frames, temporal)
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
    return _chunk_starts(num_frames, chunk_frames, context_frames)


def chunk_windows(num_frames: int, chunk_frames: int, context_frames: int = 1) -> list[tuple[int, int]]:
    """The frames each chunk of a rollout makes: [(first, last)] inclusive, chunk 1 first.

    num_frames: frames of the video, the first (given) one included; chunk_frames: frames per chunk, the
    seed frame included (17 for ``oscar-toy``). ``[(1, 16), (17, 32), …]`` for 17; the last window ends at
    ``num_frames − 1`` (a rollout's last chunk is cut there). Any chunk of at least 2 frames and any video of
    at least 2 frames (no 4k + 1 rule: the frames of a finished video are only being split).
    context_frames: the model card's (module docstring): ``[(1, 16), (17, 28), (29, 40), …]`` for 17 and 5.
    """
    if chunk_frames < 2:
        raise ModelInputError(f"chunk_frames: expected at least 2 frames (the seed and one new), found {chunk_frames}")
    if num_frames < 2:
        raise ModelInputError(f"video: expected at least 2 frames, found {num_frames}")
    if not 1 <= context_frames < chunk_frames:
        raise ModelInputError(
            f"context_frames: expected 1 to {chunk_frames - 1} (fewer than the chunk's frames), found {context_frames}"
        )
    starts = _chunk_starts(num_frames, chunk_frames, context_frames)
    return [
        (s + (1 if j == 0 else context_frames), min(s + chunk_frames - 1, num_frames - 1)) for j, s in enumerate(starts)
    ]
