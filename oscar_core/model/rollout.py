"""Autoregressive rollouts of any length, chunk by chunk.

A trajectory of T frames is covered by chunks of L = 4k+1 frames that overlap
by one frame: chunk c spans frames [c(L−1), c(L−1) + L). Chunk 0 is seeded
with the user's first frame; chunk c > 0 with the last decoded frame of
chunk c − 1, re-encoded by the VAE (a latent frame of a chunk's end covers
four pixel frames, so it cannot be reused as a first-frame latent). The
output keeps chunk 0 whole and drops frame 0 of every later chunk (it is the
seed again), so no frame is duplicated, then cuts the video to T frames
(:func:`_new_frames`). The skeleton video of the last chunk is padded with its
last frame when the chunks overrun T.

A model whose card has ``context_frames`` N > 1 (4k + 1 pixel frames,
:mod:`.chunks`) seeds chunk c > 0 with the last N decoded frames of chunk
c − 1, re-encoded by the VAE into k + 1 latent frames that the sampler keeps
clean; chunks then overlap by N frames and a later chunk adds its L − N frames
after the context. Chunk 0 has the user's first frame alone (an episode has
no earlier frame; repeating it N times would show the model a still scene, a
motion it was not given, so chunk 0 is conditioned as a one-frame model's is
and training serves that case with ``flow.context_dropout``). Latent frame k of a chunk is conditioned on latent frame k
of the VAE latent of that chunk's own skeleton frames.

Memory at real sizes: each chunk is decoded, clamped to [-1, 1] and turned
into uint8 frames at once; :func:`iter_rollout` yields them chunk by chunk, so
a writer can stream them to disk while the next chunk is sampled, and the
float video of a chunk is dropped unless ``keep_chunks``. The seed of the
next chunk is the clamped last frame.

:func:`reconstruct_rollout` is the autoencoder's ceiling of a rollout: the true
frames cut into the same chunk plan, each chunk encoded and decoded by the VAE,
and assembled by the same rule — the best any DiT with this VAE can decode.

The unconditional guidance branch sees ``uncond_skeleton``: ``"zero_latent"``
(zeros) or ``"black_video"`` (the VAE latent of an all-black skeleton video of
the chunk's frame count, encoded once per chunk size and reused).

A latent-action model (a card condition that takes actions,
:func:`oscar_core.render.conditions.takes_actions`) is rolled
out from ``actions`` instead of a skeleton video: per-transition features
(N, 14), row i the transition from frame i to i + 1, at least as many as the
padded chunk plan needs (``num_frames`` T gives the video's length); chunk c
gets rows [start, start + L − 1), the (L − 1, 14) window its trainer saw.
``OscarWorldModel.rollout_trajectory`` computes and pads them.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm.auto import tqdm

from .._util.log import progress_bars_enabled
from .chunks import chunk_plan  # kept importable from here, where it was before chunks.py
from .errors import ModelInputError
from .sampler import SamplerConfig, sample_chunk
from .vae import VideoVAE

__all__ = [
    "RolloutResult",
    "chunk_plan",
    "rollout",
    "iter_rollout",
    "rollout_batch",
    "reconstruct_rollout",
    "UNCONDITIONAL_SKELETONS",
]

UNCONDITIONAL_SKELETONS = ("zero_latent", "black_video")


@dataclass
class RolloutResult:
    """A rollout.

    frames: (T, H, W, 3) uint8 RGB, T = the skeleton video's length.
    chunks: per chunk, its decoded video (1, 3, L, H, W) float32 in [-1, 1].
    seeds: per chunk, the seed frame(s) it was conditioned on (1, 3, N, H, W): N = 1 for chunk 0, the card's
        ``context_frames`` after.
    starts: per chunk, the index of its first frame in the trajectory.
    timings: wall seconds spent in ``encode`` (VAE encodes of seeds and condition videos), ``sample`` (the
        denoising loops) and ``decode`` (VAE decodes and the uint8 conversion), summed over chunks; on CUDA each
        is closed by a device synchronisation, so the figures are the GPU's work, not its queueing.
    """

    frames: np.ndarray
    chunks: list[torch.Tensor] = field(default_factory=list)
    seeds: list[torch.Tensor] = field(default_factory=list)
    starts: list[int] = field(default_factory=list)
    timings: dict = field(default_factory=dict)


class _Clock:
    """Adds the wall seconds of each ``with clock(name):`` block to ``timings[name]`` (a no-op without timings)."""

    def __init__(self, timings: dict | None, device):
        self.timings = timings
        self.cuda = timings is not None and torch.device(device).type == "cuda"
        if timings is not None:
            for name in ("encode", "sample", "decode"):
                timings.setdefault(name, 0.0)

    @contextlib.contextmanager
    def __call__(self, name: str):
        if self.timings is None:
            yield
            return
        t0 = time.perf_counter()
        try:
            yield
        finally:
            if self.cuda:
                torch.cuda.synchronize()
            self.timings[name] = self.timings.get(name, 0.0) + time.perf_counter() - t0


def _check_first(first_frame, spatial: int) -> np.ndarray:
    first = np.asarray(first_frame)
    if first.dtype != np.uint8 or first.ndim != 3 or first.shape[-1] != 3:
        raise ModelInputError(f"first frame: expected (H, W, 3) uint8 RGB, found {first.dtype} {first.shape}")
    h, w = first.shape[:2]
    if h % spatial or w % spatial:
        raise ModelInputError(
            f"frame size: expected width and height divisible by {spatial} (VAE x DiT patch), found {w}x{h}"
        )
    return first


def _check_actions(actions, num_frames: int | None, chunk_frames: int, temporal: int, context_frames: int = 1):
    """(actions float32 tensor (N, F), T, chunk starts) of an action rollout, N covering the padded plan."""
    acts = torch.as_tensor(np.asarray(actions), dtype=torch.float32)
    if acts.ndim != 2 or len(acts) < 1:
        raise ModelInputError(f"actions: expected (T - 1, F) per-transition features, found {tuple(acts.shape)}")
    total = int(num_frames) if num_frames is not None else len(acts) + 1
    if context_frames != 1:
        raise ModelInputError(f"context_frames: expected 1 for a latent-action rollout, found {context_frames}")
    starts = chunk_plan(total, chunk_frames, temporal)
    need = starts[-1] + chunk_frames - 1
    if len(acts) < need:
        raise ModelInputError(
            f"actions: expected at least {need} rows (transitions of {len(starts)} chunk(s) of "
            f"{chunk_frames} frames covering {total} frames), found {len(acts)}"
        )
    return acts, total, starts


def _check_inputs(first_frame, skeleton, spatial: int):
    first = np.asarray(first_frame)
    skel = np.asarray(skeleton)
    if skel.dtype != np.uint8 or skel.ndim != 4 or skel.shape[-1] != 3:
        raise ModelInputError(f"skeleton video: expected (T, H, W, 3) uint8 RGB, found {skel.dtype} {skel.shape}")
    if first.dtype != np.uint8 or first.ndim != 3 or first.shape[-1] != 3:
        raise ModelInputError(f"first frame: expected (H, W, 3) uint8 RGB, found {first.dtype} {first.shape}")
    if first.shape != skel.shape[1:]:
        raise ModelInputError(
            f"first frame: expected the skeleton video's size {skel.shape[2]}x{skel.shape[1]} "
            f"(width x height), found {first.shape[1]}x{first.shape[0]}"
        )
    h, w = first.shape[:2]
    if h % spatial or w % spatial:
        raise ModelInputError(
            f"frame size: expected width and height divisible by {spatial} (VAE x DiT patch), found {w}x{h}"
        )
    return first, skel


def _check_grippers(grippers, total: int, padded_len: int) -> list[np.ndarray] | None:
    """B (padded_len, G) float64 openness arrays, each padded with its last row like the condition video, or None.

    grippers: None, or B (T, G) openness arrays in [0, 1] (1 = open) of the condition videos' T frames."""
    if grippers is None:
        return None
    out = []
    for i, g in enumerate(grippers):
        a = np.asarray(g, dtype=np.float64)
        a = a[:, None] if a.ndim == 1 else a
        if a.ndim != 2 or len(a) != total:
            raise ModelInputError(
                f"gripper signal {i}: expected (T={total}, G) openness (one row per condition frame), "
                f"found shape {np.asarray(g).shape}"
            )
        out.append(_hold_last(a, padded_len))
    return out


def _hold_last(a: np.ndarray, length: int) -> np.ndarray:
    """``a`` (T, ...) extended to ``length`` rows by repeating its last row (a robot holding its last pose over a
    chunk plan's padding); ``a`` itself when it is long enough."""
    return a if length <= len(a) else np.concatenate([a, np.repeat(a[-1:], length - len(a), axis=0)])


def _new_frames(video: torch.Tensor, index: int, total: int, emitted: int, context_frames: int = 1) -> np.ndarray:
    """(B, N, H, W, 3) uint8: the frames chunk ``index`` adds to a rollout of ``total`` frames of which ``emitted``
    are out, from its decoded video (B, 3, L, H, W) in [-1, 1] — all L for chunk 0, the L − ``context_frames`` after
    its context for a later chunk (the context is the previous chunk's last frames), cut at ``total``."""
    new = video if index == 0 else video[:, :, context_frames:]
    return VideoVAE.to_uint8(new)[:, : total - emitted]


class _UncondSkeletons:
    """The unconditional branch's skeleton latent per chunk size, computed once (``"black_video"``) or None."""

    def __init__(self, vae: VideoVAE, kind: str):
        if kind not in UNCONDITIONAL_SKELETONS:
            raise ModelInputError(f"uncond_skeleton: expected one of {UNCONDITIONAL_SKELETONS}, found {kind!r}")
        self.vae, self.kind, self.cache = vae, kind, {}
        self.encodes = 0

    def get(self, frames: int, height: int, width: int) -> torch.Tensor | None:
        if self.kind == "zero_latent":
            return None
        key = (frames, height, width)
        if key not in self.cache:
            black = np.zeros((frames, height, width, 3), np.uint8)
            self.cache[key] = self.vae.encode_condition(VideoVAE.to_pixels(black))  # as the conditions are
            self.encodes += 1
        return self.cache[key]


@torch.no_grad()
def iter_rollout(
    transformer,
    vae: VideoVAE,
    first_frame,
    skeleton,
    prompt_embeds: torch.Tensor,
    *,
    chunk_frames: int = 81,
    sampler: SamplerConfig = SamplerConfig(),
    seed: int = 0,
    progress: bool = True,
    uncond_skeleton: str = "zero_latent",
    result: RolloutResult | None = None,
    keep_chunks: bool = False,
    actions=None,
    num_frames: int | None = None,
    gripper=None,
    context_frames: int = 1,
):
    """Like :func:`rollout`, but yields each chunk's new frames as soon as they are decoded.

    Yields (N_c, H, W, 3) uint8 arrays whose concatenation is the T-frame
    rollout (chunk 0 whole, later chunks without their seed frame, the last
    one cut at T). ``result``, when given, receives ``starts`` (and
    ``chunks``/``seeds`` with ``keep_chunks``). With ``actions`` (a
    latent-action model; module docstring) ``skeleton`` is None. ``gripper``: (T, G) openness of a model with
    a gripper signal (:mod:`oscar_core.model.gripper_signal`), else None.
    """
    patch = int(transformer.config.patch_size[1])
    grips = None
    if actions is not None:
        if skeleton is not None or gripper is not None:
            raise ModelInputError("rollout: expected a skeleton video or actions, found both")
        first = _check_first(first_frame, vae.spatial * patch)
        acts, total, starts = _check_actions(actions, num_frames, chunk_frames, vae.temporal, context_frames)
        skel = None
    else:
        first, skel = _check_inputs(first_frame, skeleton, vae.spatial * patch)
        total = len(skel)
        starts = chunk_plan(total, chunk_frames, vae.temporal, context_frames)
        padded_len = starts[-1] + chunk_frames
        grips = _check_grippers(None if gripper is None else [gripper], total, padded_len)
        skel = _hold_last(skel, padded_len)
    uncond = _UncondSkeletons(vae, uncond_skeleton)
    generator = torch.Generator(device="cpu").manual_seed(int(seed))
    if result is not None:
        result.starts = list(starts)
    results = [result] if result is not None else None
    for frames in _chunks(
        transformer,
        vae,
        [first],
        None if skel is None else [skel],
        None if skel is not None else acts,
        prompt_embeds,
        starts,
        total,
        chunk_frames,
        sampler,
        [generator],
        progress,
        uncond,
        results,
        keep_chunks,
        timings=result.timings if result is not None else None,
        grippers=grips,
        context_frames=context_frames,
    ):
        yield frames[0]


def _chunks(
    transformer,
    vae: VideoVAE,
    firsts: list,
    skels: list | None,
    acts,
    prompt_embeds,
    starts,
    total: int,
    chunk_frames: int,
    sampler: SamplerConfig,
    generators: list,
    progress: bool,
    uncond: _UncondSkeletons,
    results: list | None,
    keep_chunks: bool,
    timings: dict | None = None,
    grippers: list | None = None,
    context_frames: int = 1,
):
    """The chunk loop of B rollouts sharing one chunk plan: yields, per chunk, B arrays (N_c, H, W, 3) uint8.

    firsts: B (H, W, 3) seed frames; skels: B padded (≥ starts[-1] + L, H, W, 3) condition videos, or None with
    ``acts`` (N, F) for one latent-action rollout; generators: one CPU generator per rollout (its noise);
    results: None or B RolloutResult receiving chunks and seeds with ``keep_chunks``; timings: None or a dict
    receiving the encode / sample / decode seconds (:class:`RolloutResult`); grippers: None or B padded
    (≥ starts[-1] + L, G) openness arrays, appended to the condition latent (:mod:`.gripper_signal`);
    context_frames: decoded frames of chunk c − 1 that seed chunk c > 0 (chunk 0: the first frame alone).
    """
    b = len(firsts)
    clock = _Clock(timings, next(transformer.parameters()).device if timings is not None else "cpu")
    seed_pixels = torch.cat([VideoVAE.to_pixels(f[None]) for f in firsts])  # (B, 3, N, H, W): N = 1 at chunk 0
    height, width = firsts[0].shape[:2]
    emitted = 0
    progress = progress and progress_bars_enabled()  # a bar only on a terminal, never with -q / --no-progress
    outer = tqdm(total=len(starts), desc="rollout chunks", unit="chunk", disable=not progress)
    try:
        for index, start in enumerate(starts):
            with clock("encode"):
                first_latent = vae.encode(seed_pixels)
            with tqdm(
                total=sampler.steps,
                desc=f"chunk {index + 1}/{len(starts)}",
                unit="step",
                leave=False,
                disable=not progress,
            ) as bar:
                if skels is None:
                    with clock("sample"):
                        latent = sample_chunk(
                            transformer,
                            first_latent,
                            None,
                            prompt_embeds,
                            sampler,
                            generator=generators[0],
                            progress=bar,
                            actions=acts[None, start : start + chunk_frames - 1],
                            latent_frames=(chunk_frames - 1) // vae.temporal + 1,
                        )
                else:
                    window = np.stack([s[start : start + chunk_frames] for s in skels])  # (B, L, H, W, 3)
                    with clock("encode"):
                        skeleton_latent = vae.encode_condition(VideoVAE.to_pixels(window))
                        uncond_latent = uncond.get(chunk_frames, height, width)
                    if grippers is not None:
                        skeleton_latent, uncond_latent = _add_gripper_signal(
                            skeleton_latent, uncond_latent, [g[start : start + chunk_frames] for g in grippers], vae
                        )
                    with clock("sample"):
                        latent = sample_chunk(
                            transformer,
                            first_latent,
                            skeleton_latent,
                            prompt_embeds,
                            sampler,
                            progress=bar,
                            uncond_skeleton=uncond_latent,
                            **({"generator": generators[0]} if b == 1 else {"generators": generators}),
                        )
            with clock("decode"):
                video = vae.decode(latent).cpu().clamp_(-1.0, 1.0)  # (B, 3, L, H, W)
            if keep_chunks and results is not None:
                for i, res in enumerate(results):
                    res.chunks.append(video[i : i + 1])
                    res.seeds.append(seed_pixels[i : i + 1])
            with clock("decode"):
                frames = _new_frames(video, index, total, emitted, context_frames)
            emitted += frames.shape[1]
            seed_pixels = video[:, :, -context_frames:].clone()  # clamped: the re-encoded seed is a valid image
            del video, latent
            outer.update(1)
            yield [frames[i] for i in range(b)]
    finally:
        outer.close()


def _add_gripper_signal(skeleton_latent, uncond_latent, windows: list, vae: VideoVAE):
    """(condition latent, unconditional latent or None) with the windows' gripper features appended; the
    unconditional branch gets zero features ("no information", as in training's dropped condition)."""
    from .gripper_signal import batch_features, with_gripper_channels

    feats = batch_features(windows, vae.temporal)
    cond = with_gripper_channels(skeleton_latent, feats)
    if uncond_latent is not None:
        uncond_latent = with_gripper_channels(uncond_latent, torch.zeros_like(feats[:1]))
    return cond, uncond_latent


@torch.no_grad()
def rollout_batch(
    transformer,
    vae: VideoVAE,
    first_frames,
    skeletons,
    prompt_embeds: torch.Tensor,
    *,
    chunk_frames: int = 81,
    sampler: SamplerConfig = SamplerConfig(),
    seeds=None,
    progress: bool = False,
    uncond_skeleton: str = "zero_latent",
    grippers=None,
    context_frames: int = 1,
) -> list[np.ndarray]:
    """B rollouts in one batch: each equals :func:`rollout` of its own inputs and seed, up to float rounding.

    first_frames: B (H, W, 3) uint8 images; skeletons: B (T, H, W, 3) uint8 condition videos, all of the same
    length and size (one chunk plan); prompt_embeds: (1 or B, L, D); seeds: B integers (default 0 each).
    Every model call and VAE pass runs on the batch; each rollout's noise comes from its own generator, so a
    rollout does not depend on its batch mates. grippers: None, or B (T, G) openness arrays (a model with a
    gripper signal); context_frames: the card's (module docstring). Returns B (T, H, W, 3) uint8 videos.
    """
    b = len(first_frames)
    if b == 0 or len(skeletons) != b:
        raise ModelInputError(
            f"rollout_batch: expected as many skeleton videos as first frames (>= 1), found {len(skeletons)} and {b}"
        )
    seeds = [0] * b if seeds is None else [int(s) for s in seeds]
    if len(seeds) != b:
        raise ModelInputError(f"rollout_batch: expected {b} seeds, found {len(seeds)}")
    patch = int(transformer.config.patch_size[1])
    pairs = [_check_inputs(f, s, vae.spatial * patch) for f, s in zip(first_frames, skeletons)]
    shapes = {s.shape for _, s in pairs}
    if len(shapes) != 1:
        raise ModelInputError(f"rollout_batch: expected skeleton videos of one length and size, found {sorted(shapes)}")
    total = len(pairs[0][1])
    starts = chunk_plan(total, chunk_frames, vae.temporal, context_frames)
    padded_len = starts[-1] + chunk_frames
    skels = [_hold_last(s, padded_len) for _, s in pairs]
    if grippers is not None and len(grippers) != b:
        raise ModelInputError(f"rollout_batch: expected {b} gripper signals, found {len(grippers)}")
    grips = _check_grippers(grippers, total, padded_len)
    if prompt_embeds.shape[0] not in (1, b):
        raise ModelInputError(f"prompt_embeds: expected batch 1 or {b}, found shape {tuple(prompt_embeds.shape)}")
    generators = [torch.Generator(device="cpu").manual_seed(s) for s in seeds]
    pieces = [[] for _ in range(b)]
    for frames in _chunks(
        transformer,
        vae,
        [f for f, _ in pairs],
        skels,
        None,
        prompt_embeds,
        starts,
        total,
        chunk_frames,
        sampler,
        generators,
        progress,
        _UncondSkeletons(vae, uncond_skeleton),
        None,
        False,
        grippers=grips,
        context_frames=context_frames,
    ):
        for i, f in enumerate(frames):
            pieces[i].append(f)
    return [np.concatenate(p, axis=0) for p in pieces]


@torch.no_grad()
def rollout(
    transformer,
    vae: VideoVAE,
    first_frame,
    skeleton,
    prompt_embeds: torch.Tensor,
    *,
    chunk_frames: int = 81,
    sampler: SamplerConfig = SamplerConfig(),
    seed: int = 0,
    progress: bool = True,
    keep_chunks: bool = True,
    uncond_skeleton: str = "zero_latent",
    actions=None,
    num_frames: int | None = None,
    gripper=None,
    context_frames: int = 1,
) -> RolloutResult:
    """Roll the world model out along a skeleton video.

    transformer: OscarTransformer3DModel; vae: VideoVAE.
    first_frame: (H, W, 3) uint8 RGB image I_0; skeleton: (T, H, W, 3) uint8
        skeleton video S_1..T of the same size (frame 0 matches I_0).
    prompt_embeds: (1, L, D) text embedding.
    chunk_frames: L = 4k+1 frames per chunk; sampler: SamplerConfig.
    seed: seeds the noise of every chunk (one CPU generator, drawn in order):
        the same seed gives the same video.
    uncond_skeleton: "zero_latent" or "black_video" (module docstring).
    actions: for a latent-action model, (≥ T − 1, 14) features instead of a
        skeleton video (then ``skeleton`` is None; ``num_frames`` T, default
        len(actions) + 1; module docstring).
    gripper: (T, G) openness in [0, 1] per condition frame for a model with a gripper signal
        (:mod:`oscar_core.model.gripper_signal`), else None.
    context_frames: N = 4k+1 decoded frames of a chunk that seed the next (the card's ``context_frames``; module
        docstring); 1: its last frame.
    returns: RolloutResult with T frames.
    """
    result = RolloutResult(frames=np.empty(0, np.uint8))
    pieces = list(
        iter_rollout(
            transformer,
            vae,
            first_frame,
            skeleton,
            prompt_embeds,
            chunk_frames=chunk_frames,
            sampler=sampler,
            seed=seed,
            progress=progress,
            uncond_skeleton=uncond_skeleton,
            result=result,
            keep_chunks=keep_chunks,
            actions=actions,
            num_frames=num_frames,
            gripper=gripper,
            context_frames=context_frames,
        )
    )
    result.frames = np.concatenate(pieces, axis=0)
    return result


@torch.no_grad()
def reconstruct_rollout(vae: VideoVAE, frames, *, chunk_frames: int = 81, context_frames: int = 1) -> np.ndarray:
    """The autoencoder's ceiling of a rollout: (T, H, W, 3) uint8 true frames → (T, H, W, 3) uint8, what the VAE
    makes of them chunk by chunk exactly as a rollout of T frames decodes its chunks.

    The chunk plan is the rollout's (:func:`chunk_plan`: chunk c is frames [c(L − 1), c(L − 1) + L), the frames
    held at the last one past T); each chunk of true frames is encoded and decoded by ``vae`` (clamped to
    [-1, 1]) and the pieces are put together by the rollout's own rule (:func:`_new_frames`: chunk 0 whole, then
    each later chunk without its first frame, cut at T). A world model whose DiT predicted every chunk's latent
    exactly (the VAE's encoding of the true frames) would roll out this video; so no DiT with this VAE does better
    on a score of the frames. chunk_frames: L = 4k + 1; context_frames: the model card's (chunks overlap by that
    many frames, module docstring). Deterministic: the VAE encodes to its posterior's mode.
    """
    video = np.asarray(frames)
    if video.dtype != np.uint8 or video.ndim != 4 or video.shape[-1] != 3:
        raise ModelInputError(f"frames: expected (T, H, W, 3) uint8 RGB, found {video.dtype} {video.shape}")
    total = len(video)
    starts = chunk_plan(total, chunk_frames, vae.temporal, context_frames)
    padded = _hold_last(video, starts[-1] + chunk_frames)
    pieces, emitted = [], 0
    for index, start in enumerate(starts):
        window = VideoVAE.to_pixels(padded[start : start + chunk_frames])  # (1, 3, L, H, W)
        decoded = vae.decode(vae.encode(window)).cpu().clamp_(-1.0, 1.0)
        piece = _new_frames(decoded, index, total, emitted, context_frames)[0]
        emitted += len(piece)
        pieces.append(piece)
    return np.concatenate(pieces, axis=0)
