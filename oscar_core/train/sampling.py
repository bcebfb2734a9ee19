"""What each optimiser step trains on: source mixing, the window prior, and the per-step plan.

* **Source mixing** (the paper): a source i (dataset) is drawn with weight
  w_i ∝ n_frames_i^(1/T), T = 3, n_frames_i its total frame count; inside a
  source, a clip is drawn in proportion to its number of window starts
  (n_frames − window + 1), so every window of a source is equally likely.
* **Window prior**: the start s of a ``window``-frame window is drawn from a
  mixture of trapezoids, one per midpoint crossing c of the binary open/close
  signal (openness > 0.5, any gripper): the weight of s is Σ_c trap(c − s),
  where trap(d) over the crossing's position d ∈ [0, window) inside the window
  rises linearly over the first ``ramp``·window frames, is flat in the middle
  and falls over the last ``ramp``·window frames (ramp 0.25: the plateau is
  the middle half). A clip without a crossing (or whose crossings no window
  can hold) falls back to uniform. ``uniform`` mixes a uniform prior in.
* **Plan**: step k's global batch is a pure function of (seed, k): the clips,
  starts, dropout flags, flow times and noise seeds of its ``batch_size``
  items. Rank r of W takes items [r·B/W, (r+1)·B/W), so no item is seen twice
  per step across ranks, 1 and W processes see the same global batch, and
  resuming at step k needs only k (the data-sampler position).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .flow import sample_sigmas

__all__ = [
    "mixing_weights",
    "crossings",
    "trapezoid",
    "window_prior",
    "PlanItem",
    "StepPlanner",
    "item_noise",
    "item_cond_sigma",
    "item_context",
]


def mixing_weights(
    frames_per_source: dict[str, int], temperature: float = 3.0, explicit: dict[str, float] | None = None
) -> dict[str, float]:
    """Source → probability, w_i ∝ n_frames_i^(1/T), normalised to sum 1 (sources sorted by name).

    explicit: per-source weights (any positive scale) used instead of the temperature rule; they must name
    every source of ``frames_per_source`` and no other (a :class:`ValueError` names the difference).
    """
    if not frames_per_source:
        raise ValueError("mixing_weights: expected at least one source, found none")
    if explicit is not None:
        have, named = set(frames_per_source), set(explicit)
        if have != named:
            raise ValueError(
                f"data.source_weights: expected a weight for every source of the clips ({sorted(have)}) and no "
                f"other, found {sorted(named)} (missing {sorted(have - named)}, unknown {sorted(named - have)})"
            )
        raw = {s: float(explicit[s]) for s in sorted(frames_per_source)}
    else:
        raw = {s: float(n) ** (1.0 / temperature) for s, n in sorted(frames_per_source.items())}
    total = sum(raw.values())
    return {s: v / total for s, v in raw.items()}


def crossings(openness: np.ndarray) -> np.ndarray:
    """Frames t ≥ 1 where the binary signal (openness > 0.5) of any gripper differs from frame t − 1.

    openness: (T, G) in [0, 1]; returns sorted unique int64 frame indices.
    """
    a = np.asarray(openness, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] == 0 or a.shape[0] < 2:
        return np.zeros(0, dtype=np.int64)
    b = a > 0.5
    changed = (b[1:] != b[:-1]).any(axis=1)
    return (np.nonzero(changed)[0] + 1).astype(np.int64)


def trapezoid(d: np.ndarray, window: int, ramp: float) -> np.ndarray:
    """Weight of a crossing at position ``d`` (frames) inside a window of ``window`` frames.

    0 outside [0, window); linear from 1/(r+1) up to 1 over the first r =
    max(1, round(ramp·window)) positions, 1 on the plateau, symmetric down at
    the end.
    """
    d = np.asarray(d, dtype=np.float64)
    r = max(1, int(round(ramp * window)))
    up = (d + 1.0) / (r + 1.0)
    down = (window - d) / (r + 1.0)
    w = np.minimum(1.0, np.minimum(up, down))
    return np.where((d >= 0) & (d < window), w, 0.0)


def window_prior(
    openness: np.ndarray, window: int, ramp: float = 0.25, uniform: float = 0.0, starts: np.ndarray | None = None
) -> np.ndarray:
    """Probabilities over window starts (sum 1).

    openness: (T, G); window: frames; starts: the allowed starts (default all
    0..T−window; cached latents allow only theirs). Falls back to uniform when
    no allowed window holds a crossing.
    """
    T = len(openness)
    if starts is None:
        if T < window:
            raise ValueError(f"window_prior: a clip of {T} frames is shorter than the window ({window})")
        starts = np.arange(T - window + 1)
    starts = np.asarray(starts, dtype=np.int64)
    c = crossings(openness)
    if c.size:
        w = trapezoid(c[None, :] - starts[:, None], window, ramp).sum(axis=1)
    else:
        w = np.zeros(len(starts))
    if w.sum() <= 0:
        return np.full(len(starts), 1.0 / len(starts))
    w = w / w.sum()
    if uniform > 0:
        w = (1.0 - uniform) * w + uniform / len(starts)
    return w


@dataclass(frozen=True)
class PlanItem:
    """One sample of a step: the clip (index into the planner's clips), its window start, whether the
    skeleton is dropped, the flow time σ and the seed of its noise."""

    clip: int
    start: int
    drop: bool
    sigma: float
    noise_seed: int


class StepPlanner:
    """Draws each step's global batch from (seed, step) alone.

    clips: per clip a (source, n_frames, openness (T, G), allowed starts or None);
    window: frames; weights: explicit per-source weights (``data.source_weights``, instead of the
    temperature rule); the other arguments are the config's.
    """

    def __init__(
        self,
        clips: list[tuple[str, int, np.ndarray, np.ndarray | None]],
        window: int,
        *,
        seed: int = 0,
        temperature: float = 3.0,
        weights: dict[str, float] | None = None,
        ramp: float = 0.25,
        uniform: float = 0.0,
        dropout: float = 0.2,
        shift: float = 5.0,
        logit_mean: float = 0.0,
        logit_std: float = 1.0,
    ):
        if not clips:
            raise ValueError("StepPlanner: expected at least one usable clip, found none")
        self.window, self.seed, self.dropout = window, int(seed), float(dropout)
        self.shift, self.logit_mean, self.logit_std = shift, logit_mean, logit_std
        self.starts, self.priors = [], []
        frames: dict[str, int] = {}
        for source, n, op, allowed in clips:
            s = np.arange(n - window + 1) if allowed is None else np.asarray(allowed, dtype=np.int64)
            self.starts.append(s)
            self.priors.append(window_prior(op, window, ramp, uniform, s))
            frames[source] = frames.get(source, 0) + int(n)
        self.weights = mixing_weights(frames, temperature, weights)
        self.clip_sources = [c[0] for c in clips]
        self.sources = list(self.weights)
        self.source_p = np.array([self.weights[s] for s in self.sources])
        self.members = {s: np.array([i for i, c in enumerate(clips) if c[0] == s]) for s in self.sources}
        self.member_p = {}
        for s, idx in self.members.items():
            n_starts = np.array([len(self.starts[i]) for i in idx], dtype=np.float64)
            self.member_p[s] = n_starts / n_starts.sum()

    def plan(self, step: int, batch: int) -> list[PlanItem]:
        """The ``batch`` items of optimiser step ``step`` (0-based)."""
        rng = np.random.default_rng([self.seed, int(step), 0x05CA])
        tgen = torch.Generator().manual_seed(int(rng.integers(2**62)))
        sigmas = sample_sigmas(batch, tgen, self.shift, self.logit_mean, self.logit_std).tolist()
        items = []
        for i in range(batch):
            source = self.sources[int(rng.choice(len(self.sources), p=self.source_p))]
            idx = self.members[source]
            clip = int(idx[int(rng.choice(len(idx), p=self.member_p[source]))])
            start = int(self.starts[clip][int(rng.choice(len(self.starts[clip]), p=self.priors[clip]))])
            drop = bool(rng.random() < self.dropout)
            items.append(PlanItem(clip, start, drop, float(sigmas[i]), int(rng.integers(2**62))))
        return items

    def source_counts(self, items: list[PlanItem]) -> dict[str, int]:
        """Source → how many of ``items`` were drawn from it (every source listed, zeros included)."""
        out = dict.fromkeys(self.sources, 0)
        for it in items:
            out[self.clip_sources[it.clip]] += 1
        return out

    def drawn(self, steps: int, batch: int) -> dict[str, int]:
        """Source → items drawn from it by optimiser steps 0 .. ``steps`` - 1 (replays the plan)."""
        out = dict.fromkeys(self.sources, 0)
        for step in range(steps):
            for s, n in self.source_counts(self.plan(step, batch)).items():
                out[s] += n
        return out

    @staticmethod
    def rank_slice(items: list[PlanItem], rank: int, world: int) -> list[PlanItem]:
        """Rank ``rank``'s share of a global batch (contiguous, equal shares)."""
        if len(items) % world:
            raise ValueError(f"batch_size: expected a multiple of the {world} processes, found {len(items)}")
        n = len(items) // world
        return items[rank * n : (rank + 1) * n]


def item_noise(items: list[PlanItem], shape) -> torch.Tensor:
    """(B, *shape) float32 noise, item i drawn from its own seed (the same on any process count)."""
    return torch.stack([torch.randn(shape, generator=torch.Generator().manual_seed(it.noise_seed)) for it in items])


def item_cond_sigma(items: list[PlanItem], max_sigma: float) -> torch.Tensor:
    """(B,) float64 noise levels of the conditioning frame, item i's U(0, max_sigma) drawn from a stream of its own
    noise seed apart from its noise (the same on any process count)."""
    gens = [torch.Generator().manual_seed((it.noise_seed + 0x5EED) % 2**63) for it in items]
    return torch.tensor([float(torch.rand((), generator=g, dtype=torch.float64)) * max_sigma for g in gens])


def item_context(items: list[PlanItem], latents: int, dropout: float) -> list[int]:
    """Latent frames of clean context per item: ``latents`` (``model.context_frames``' latent frames), or 1 (the
    first frame alone, what a rollout's first chunk has) with probability ``dropout``, item i's draw from a stream
    of its own noise seed apart from its noise and its conditioning noise (the same on any process count)."""
    if latents == 1:
        return [1] * len(items)
    gens = [torch.Generator().manual_seed((it.noise_seed + 0xC0DE) % 2**63) for it in items]
    return [1 if float(torch.rand((), generator=g, dtype=torch.float64)) < dropout else latents for g in gens]
