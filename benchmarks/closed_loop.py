"""Closed-loop policy evaluation on the toy model: where a step's CPU time goes, and cells per CPU-minute at batch 1 vs N.

    python benchmarks/closed_loop.py [--model oscar-toy | --size tiny|2b] [--device cpu|cuda]
                                     [--tiny-decoder FILE|random | --full-decoder] [--tiny-encoder FILE|random]
                                     [--sessions 4] [--horizon 33]
                                     [--steps N] [--guidance W | --no-guidance] [--preset fast]
                                     [--batch 4 [8 ...]] [--repeats 1]
                                     [--compare-norms] [--no-vae-probe] [--probe-repeats 3]
                                     [--json benchmarks/results/closed_loop.json]

``--model`` is a zoo name or a model folder (``oscar-toy-fast``: the distilled 4-step student); its card's
recommended sampler runs unless ``--steps`` / ``--guidance`` replace its figures (the 2026-11-29 table in
docs/closed-loop.md ran ``oscar-toy`` with ``--steps 10``); ``--preset`` a sampler preset, ``--no-guidance`` the
conditional branch alone (a few-step student's way). The decoder is the card's choice, a ``--tiny-decoder`` file
(``random``: ``taew2_1``'s widths with random weights, for speed only), or ``--full-decoder``. The condition encoder
is the full one unless ``--tiny-encoder`` names a file (``random``: ``taew2_1``'s width, random weights).

``--size`` replaces ``--model`` by a random-weights model built in the process: ``tiny`` (oscar_core.model.tiny, 17
frames at 64x64, float32) or ``2b`` (the Cosmos-Predict2.5-2B DiT configuration and the WAN 2.1 VAE, bfloat16, 81-frame
chunks at 512x288: ``make bench-gpu`` runs it with ``--device cuda``); the sessions are drawn at the model card's size.
Its frames are noise, so only the speed means anything. On ``--device cuda`` each row also gives cells per GPU-hour
(cells / wall hours of the run: the GPU is held for the wall time) and the thread-CPU split counts the host's work
only (kernel launches, copies), not the GPU's.

The cells: ``--sessions`` toyarm sessions (``oscar toyworld closed-loop-sessions``, 64x64) x 2 image-based toy
policies (``exact``, ``never_closes``: ``ee_position`` through IK, 8 actions per call at 10 Hz), ``--horizon``
frames (17-frame chunks, 16 new frames per step), the model's sampler, one torch thread (``OMP_NUM_THREADS=1``). The same cells run in one process, into fresh folders,
one at a time (``batch_cells=1``, the naive way) and in lock-step at each ``--batch`` (one batched world-model
call per chunk), the batch sizes interleaved (1, N, M, 1, N, M, ... for ``--repeats`` rounds) so that a change in
the machine's load falls on all of them alike. Cells per CPU-minute is cells / (process CPU seconds / 60), beside
wall time; each batch size's figures sum its rounds. Per closed-loop step (one chunk of one cell) the CPU time
of the thread doing the work (``time.thread_time``, so the policy threads of a batch count too) is split into
the policy's calls, the action adapter (IK), the condition render, the VAE encodes (seed frame and condition
video), the tiny condition encoder's encodes (``--tiny-encoder``), the DiT's denoising loop, the VAE decode, writing the cell's files, the report, and the rest (``other``:
the loop itself, thread hand-offs, the interpreter); the wall milliseconds per step from each cell's record
(``timing_s``: policy, adapter, render, model — a batched call's time shared among its cells) stay beside it.
It checks that every batch's videos agree with batch 1's within one uint8 level. ``--compare-norms`` runs each batch
size twice per round, the VAE's RMS norm as it is (``sums``: ``channel_norm_by_sums`` where that is bit-identical)
and through ``F.normalize`` (the reference's operation), alternating, one row each, and checks that batch 1's videos
are the same frames bit for bit with either.

The latency a policy sees per chunk: the wall and thread-CPU milliseconds of each world step, from a cell's chunk
request to its frames (condition render, VAE encodes, DiT, VAE decode): ``ModelWorld.step`` one cell at a time,
``generate_together`` in lock-step (every policy of the batch waits on the whole call; its CPU is also given per
chunk).

The VAE probe (``--no-vae-probe`` skips it) measures, on one chunk of ``oscar-toy``'s VAE (17 frames at 64x64,
thread CPU, best of ``--probe-repeats``), what could leave the policy's critical path: the full decode; the decode
of the last latent frame alone and whether it equals the full decode's last frames (the WAN decoder is causal and
carries a cache of each convolution's last two input frames, so it does not); whether decoding the first k latent
frames gives the full decode's first 4(k-1)+1 frames bit for bit, and what each further latent frame costs; the
condition encode (17 frames) and the seed encode (1 frame) at batch 1 and per clip at batch 4, and the decode per
clip at batch 4; the share of the decode spent in the WAN RMS norm, and the decode and condition encode with the
norm as it is (from sums of squares where that is bit-identical: ``channel_norm_by_sums``) and through
``F.normalize`` (the reference's operation), the two alternating, with the largest difference between their outputs
(0: bit-identical); and the decode by
the tiny decoder (``oscar_core/model/tiny_decoder.py``, ``taew2_1``'s widths, random weights: its speed only).
Prints a table, writes JSON.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # this checkout's oscar_core, as wan_vae.py measures
from _provenance import with_provenance  # noqa: E402
from _wan_norm import f_normalize_rms_norm  # noqa: E402

PARTS = ("policy", "adapter", "render", "model")
#: the VAE's RMS norm paths ``--compare-norms`` runs: as it is (sums of squares where bit-identical), F.normalize
NORMS = {"sums": contextlib.nullcontext, "F.normalize": f_normalize_rms_norm}
#: the CPU split: part -> (module, attribute) of the function whose calls it sums
CPU_PARTS = {
    "policy": ("oscar_core.evaluation.closed_loop_cell", "call_policy"),
    "adapter": ("oscar_core.policy.spaces", "ActionAdapter.apply"),
    "render": ("oscar_core.evaluation.closed_loop_cell", "ModelWorld._condition"),
    "vae_encode": ("oscar_core.model.vae", "VideoVAE.encode"),
    # the tiny condition encoder's calls (--tiny-encoder): they do not go through VideoVAE.encode
    "tiny_encode": ("oscar_core.model.tiny_encoder", "TinyVideoEncoder.encode"),
    "dit": ("oscar_core.model.rollout", "sample_chunk"),
    "vae_decode": ("oscar_core.model.vae", "VideoVAE.decode"),
    "write": ("oscar_core.evaluation.closed_loop", "_write_cell"),
    "report": ("oscar_core.evaluation.closed_loop", "judge_and_report"),
}


#: the world steps a policy waits on: (module, attribute) -> how many chunks one call generates
WORLD_STEPS = {
    ("oscar_core.evaluation.closed_loop_cell", "ModelWorld.step"): lambda args: 1,
    ("oscar_core.evaluation.closed_loop_batch", "generate_together"): lambda args: len(args[0]),
}


def _patch(module: str, attr: str, make):
    """Replace ``module.attr`` (``Class.method`` allowed) by ``make(fn)``; returns the undo triple."""
    import importlib

    owner = importlib.import_module(module)
    *path, name = attr.split(".")
    for p in path:
        owner = getattr(owner, p)
    fn = getattr(owner, name)
    setattr(owner, name, make(fn))
    return owner, name, fn


@contextlib.contextmanager
def world_latency(calls: list):
    """Append ``(wall s, thread CPU s, chunks)`` of every :data:`WORLD_STEPS` call to ``calls``."""
    undo = []

    def timed(count, fn):
        def wrapper(*args, **kwargs):
            t0, c0 = time.perf_counter(), time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                calls.append((time.perf_counter() - t0, time.thread_time() - c0, count(args)))

        return wrapper

    for (module, attr), count in WORLD_STEPS.items():
        undo.append(_patch(module, attr, lambda fn, count=count: timed(count, fn)))
    try:
        yield calls
    finally:
        for owner, name, fn in undo:
            setattr(owner, name, fn)


@contextlib.contextmanager
def cpu_split(totals: dict):
    """Add the thread CPU seconds of every call of each :data:`CPU_PARTS` function to ``totals[part]``."""
    lock = threading.Lock()
    undo = []

    def timed(part, fn):
        def wrapper(*args, **kwargs):
            c0 = time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                with lock:
                    totals[part] = totals.get(part, 0.0) + time.thread_time() - c0

        return wrapper

    for part, (module, attr) in CPU_PARTS.items():
        undo.append(_patch(module, attr, lambda fn, part=part: timed(part, fn)))
    try:
        yield totals
    finally:
        for owner, name, fn in undo:
            setattr(owner, name, fn)


def _run(manifest, out, model, sampler, batch: int) -> dict:
    from oscar_core.evaluation.closed_loop import run_closed_loop

    cpu_parts: dict = {}
    world_calls: list = []
    with cpu_split(cpu_parts), world_latency(world_calls):
        t0, c0 = time.perf_counter(), time.process_time()
        res = run_closed_loop(manifest, out, model=model, sampler=sampler, batch_cells=batch, log=lambda m: None)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    chunk = model.card.chunk_frames - 1
    steps = sum(-(-(r["frames"] - 1) // chunk) for r in res.records)
    return {
        "batch_cells": batch,
        "cells": len(res.records),
        "steps": steps,
        "failed": res.counts["failed"],
        "wall_s": wall,
        "cpu_s": cpu,
        "wall_ms": {p: 1e3 * sum(r["timing_s"].get(p, 0.0) for r in res.records) for p in PARTS},
        "cpu_parts_s": cpu_parts,
        "world_calls": world_calls,
        "records": res.records,
    }


def _sum_rounds(runs: list[dict]) -> dict:
    """One row per batch size: its rounds summed, the rates and per-step figures computed from the sums."""
    cells, steps = sum(r["cells"] for r in runs), sum(r["steps"] for r in runs)
    wall, cpu = sum(r["wall_s"] for r in runs), sum(r["cpu_s"] for r in runs)
    parts = {p: sum(r["cpu_parts_s"].get(p, 0.0) for r in runs) for p in CPU_PARTS}
    row = {
        "batch_cells": runs[0]["batch_cells"],
        "rounds": len(runs),
        "cells": cells,
        "steps": steps,
        "failed": sum(r["failed"] for r in runs),
        "wall_s": wall,
        "cpu_s": cpu,
        "cells_per_cpu_minute": cells / (cpu / 60.0),
        "cells_per_wall_minute": cells / (wall / 60.0),
        "cpu_ms_per_step": {
            **{p: 1e3 * v / steps for p, v in parts.items()},
            "other": 1e3 * (cpu - sum(parts.values())) / steps,
            "total": 1e3 * cpu / steps,
        },
    }
    row.update({f"{p}_wall_ms_per_step": sum(r["wall_ms"][p] for r in runs) / steps for p in PARTS})
    calls = [c for r in runs for c in r["world_calls"]]
    row["policy_visible"] = {
        "world_calls": len(calls),
        "wall_ms_per_call": 1e3 * sum(c[0] for c in calls) / max(len(calls), 1),
        "cpu_ms_per_call": 1e3 * sum(c[1] for c in calls) / max(len(calls), 1),
        "cpu_ms_per_chunk": 1e3 * sum(c[1] for c in calls) / max(sum(c[2] for c in calls), 1),
    }
    return row


def _best_cpu(fn, repeats: int):
    """(result of the last call, best thread-CPU ms, best wall ms) of ``repeats`` calls of ``fn``."""
    cpu, wall, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.thread_time()
        out = fn()
        cpu.append(time.thread_time() - c0)
        wall.append(time.perf_counter() - t0)
    return out, 1e3 * min(cpu), 1e3 * min(wall)


def vae_probe(model, frames: np.ndarray, repeats: int) -> dict:
    """What of the VAE could leave the policy's critical path, on one chunk ``frames`` (L, H, W, 3) uint8
    (module docstring). CPU and wall in milliseconds, best of ``repeats``."""
    from oscar_core.model import _wan_vae_layers as wan
    from oscar_core.model.vae import VideoVAE

    vae = model.vae
    pixels = VideoVAE.to_pixels(frames)  # (1, 3, L, H, W)
    latent, enc_cpu, enc_wall = _best_cpu(lambda: vae.encode(pixels), repeats)
    _, seed_cpu, _ = _best_cpu(lambda: vae.encode(pixels[:, :, :1]), repeats)
    full, dec_cpu, dec_wall = _best_cpu(lambda: vae.decode(latent), repeats)
    n = latent.shape[2]
    last, last_cpu, _ = _best_cpu(lambda: vae.decode(latent[:, :, -1:]), repeats)
    prefix_cpu, prefix_equal = [], True
    for k in range(1, n):
        out, c, _ = _best_cpu(lambda k=k: vae.decode(latent[:, :, :k]), repeats)
        prefix_cpu.append(c)
        prefix_equal &= bool(torch.equal(out, full[:, :, : out.shape[2]]))
    prefix_cpu.append(dec_cpu)
    four_p, four_l = torch.cat([pixels] * 4), torch.cat([latent] * 4)
    _, enc4_cpu, _ = _best_cpu(lambda: vae.encode(four_p), repeats)
    _, seed4_cpu, _ = _best_cpu(lambda: vae.encode(four_p[:, :, :1]), repeats)
    _, dec4_cpu, _ = _best_cpu(lambda: vae.decode(four_l), repeats)
    norm_cpu = [0.0]
    original = wan.RMSNorm.forward

    def counted(self, x):
        c0 = time.thread_time()
        try:
            return original(self, x)
        finally:
            norm_cpu[0] += time.thread_time() - c0

    wan.RMSNorm.forward = counted
    try:
        _, dec_counted_cpu, _ = _best_cpu(lambda: vae.decode(latent), 1)
    finally:
        wan.RMSNorm.forward = original
    ref_dec, ref_enc, ref_dec_cpu, ref_enc_cpu, cur_dec_cpu, cur_enc_cpu = None, None, [], [], [], []
    for _ in range(repeats):  # the RMS norm's two paths alternating, so a change of load falls on both
        with f_normalize_rms_norm():
            ref_dec, c, _ = _best_cpu(lambda: vae.decode(latent), 1)
            ref_dec_cpu.append(c)
            ref_enc, c, _ = _best_cpu(lambda: vae.encode(pixels), 1)
            ref_enc_cpu.append(c)
        cur_dec_cpu.append(_best_cpu(lambda: vae.decode(latent), 1)[1])
        cur_enc_cpu.append(_best_cpu(lambda: vae.encode(pixels), 1)[1])
    from oscar_core.model.tiny_decoder import TinyDecoderNet

    up = [s_ <= vae.spatial for s_ in (2, 4, 8)]  # the VAE's spatial factor: x2 per stage while it lasts
    torch.manual_seed(0)
    tiny = TinyDecoderNet(latent_channels=vae.z_dim, space_upscale=tuple(up))  # taew2_1's widths, random weights
    vae.use_tiny_decoder(tiny)
    try:
        _, tiny_cpu, _ = _best_cpu(lambda: vae.decode(latent), repeats)
    finally:
        vae.use_tiny_decoder(None)
    u8 = VideoVAE.to_uint8
    return {
        "chunk": list(frames.shape),
        "latent": list(latent.shape),
        "repeats": repeats,
        "decode_cpu_ms": dec_cpu,
        "decode_wall_ms": dec_wall,
        "decode_last_latent_frame_alone_cpu_ms": last_cpu,
        "last_alone_equals_full": bool(torch.equal(last[:, :, -1], full[:, :, -1])),
        "last_alone_max_abs_diff": float((last[:, :, -1] - full[:, :, -1]).abs().max()),
        "last_alone_max_uint8_diff": int(np.abs(u8(last[:, :, -1:]).astype(int) - u8(full[:, :, -1:])).max()),
        "prefix_decodes_bit_identical": prefix_equal,
        "decode_cpu_ms_by_latent_frames": prefix_cpu,
        "encode_condition_cpu_ms": enc_cpu,
        "encode_condition_wall_ms": enc_wall,
        "encode_seed_cpu_ms": seed_cpu,
        "batch4_encode_condition_cpu_ms_per_clip": enc4_cpu / 4,
        "batch4_encode_seed_cpu_ms_per_clip": seed4_cpu / 4,
        "batch4_decode_cpu_ms_per_clip": dec4_cpu / 4,
        "rms_norm_share_of_decode": norm_cpu[0] * 1e3 / dec_counted_cpu,
        "rms_norm_alternating_decode_cpu_ms": min(cur_dec_cpu),
        "rms_norm_alternating_encode_condition_cpu_ms": min(cur_enc_cpu),
        "f_normalize_norm_decode_cpu_ms": min(ref_dec_cpu),
        "f_normalize_norm_encode_condition_cpu_ms": min(ref_enc_cpu),
        "f_normalize_norm_decode_max_abs_diff": float((ref_dec - full).abs().max()),
        "f_normalize_norm_encode_max_abs_diff": float((ref_enc - latent).abs().max()),
        "tiny_decoder_cpu_ms": tiny_cpu,
    }


def _sampler(model, steps: int | None, guidance: float | None, preset: str | None = None, no_guidance: bool = False):
    """The sampler the card recommends (the library's defaults where it is silent), with ``steps``, ``guidance`` and
    ``preset`` replacing its own where given; ``no_guidance``: the conditional branch alone."""
    from dataclasses import replace

    from oscar_core.model.card_sampler import sampler_of_card

    sampler = sampler_of_card(model.card.sampler, model.scheduler_config, steps=steps, guidance=guidance, preset=preset)
    return replace(sampler, guidance=None) if no_guidance else sampler


def random_world_model(size: str, device: str):
    """A random-weights world model (module docstring): ``tiny`` or ``2b``, on ``device``."""
    from oscar_core.model import ModelCard, OscarWorldModel
    from oscar_core.model.tiny import build_random_2b, build_tiny_transformer, build_tiny_vae

    if size == "tiny":
        card = ModelCard(name="bench-tiny", chunk_frames=17, width=64, height=64, fps=10.0)
        transformer, vae = build_tiny_transformer(seed=0, skeleton_scale=0.05), build_tiny_vae(seed=0)
        return OscarWorldModel.from_modules(transformer, vae, card, device=device, dtype=torch.float32)
    transformer, vae = build_random_2b(device, torch.bfloat16)
    card = ModelCard(name="bench-2b", chunk_frames=81, width=512, height=288, fps=10.0)
    return OscarWorldModel.from_modules(transformer, vae, card, device=device, dtype=torch.bfloat16)


def use_random_tiny_decoder(model) -> None:
    """Decode with a tiny decoder at ``taew2_1``'s widths and random weights (its speed only)."""
    from oscar_core.model.tiny_decoder import TinyDecoderNet

    vae = model.vae
    torch.manual_seed(0)
    vae.use_tiny_decoder(
        TinyDecoderNet(latent_channels=vae.z_dim, space_upscale=tuple(f <= vae.spatial for f in (2, 4, 8)))
    )


def use_random_tiny_encoder(model) -> None:
    """Encode the conditions with a tiny encoder at ``taew2_1``'s width and random weights (its speed only)."""
    from oscar_core.model.tiny_encoder import TinyEncoderNet

    vae = model.vae
    torch.manual_seed(0)
    vae.use_tiny_encoder(
        TinyEncoderNet(latent_channels=vae.z_dim, space_downscale=tuple(f <= vae.spatial for f in (2, 4, 8)))
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sessions", type=int, default=4)
    ap.add_argument("--horizon", type=int, default=33)
    ap.add_argument("--model", default="oscar-toy", help="zoo name or model folder (default oscar-toy)")
    ap.add_argument("--size", choices=("tiny", "2b"), default=None, help="a random-weights model instead of --model")
    ap.add_argument("--device", default="cpu", help="where the world model runs (default cpu)")
    ap.add_argument("--steps", type=int, default=None, help="denoising steps (default: the card's)")
    ap.add_argument("--preset", choices=("paper", "fast"), default=None, help="a sampler preset (default: the card's)")
    guidance = ap.add_mutually_exclusive_group()
    guidance.add_argument("--guidance", type=float, default=None, help="guidance, diffusers form (default: the card's)")
    guidance.add_argument("--no-guidance", action="store_true", help="the conditional branch alone")
    decoder = ap.add_mutually_exclusive_group()
    decoder.add_argument(
        "--tiny-decoder",
        default=None,
        help="decode with this tiny decoder file (model/tiny_decoder.py); 'random': taew2_1's widths, random weights",
    )
    decoder.add_argument(
        "--full-decoder", action="store_true", help="the full VAE decoder even if the card names a tiny one"
    )
    ap.add_argument(
        "--tiny-encoder",
        default=None,
        help="encode the conditions with this tiny encoder file (model/tiny_encoder.py); 'random': taew2_1's width, "
        "random weights",
    )
    ap.add_argument("--batch", type=int, nargs="+", default=[4], help="lock-step batch sizes beside batch 1")
    ap.add_argument("--repeats", type=int, default=1, help="interleaved rounds of every batch size")
    ap.add_argument(
        "--compare-norms",
        action="store_true",
        help="run every batch size also with the VAE's RMS norm through F.normalize, alternating (module docstring)",
    )
    ap.add_argument("--no-vae-probe", action="store_true", help="skip the VAE probe (module docstring)")
    ap.add_argument("--probe-repeats", type=int, default=3, help="best of this many calls in the VAE probe")
    ap.add_argument("--json", default="benchmarks/results/closed_loop.json")
    args = ap.parse_args()
    torch.set_num_threads(1)

    import oscar_zoo
    from oscar_core.media.video import read_video
    from oscar_core.toyworld.closed_loop import write_closed_loop_sessions

    tiny = False if args.full_decoder else args.tiny_decoder
    if args.size is not None:
        model = random_world_model(args.size, args.device)
    else:
        model = oscar_zoo.load(
            args.model,
            device=args.device,
            tiny_decoder=None if tiny == "random" else tiny,
            tiny_encoder=None if args.tiny_encoder == "random" else args.tiny_encoder,
        )
    if tiny == "random":
        use_random_tiny_decoder(model)
    if args.tiny_encoder == "random":
        use_random_tiny_encoder(model)
    elif args.tiny_encoder is not None and args.size is not None:
        model.vae.use_tiny_encoder(args.tiny_encoder)
    sampler = _sampler(model, args.steps, args.guidance, args.preset, args.no_guidance)
    with tempfile.TemporaryDirectory() as tmp:
        manifest = write_closed_loop_sessions(
            Path(tmp) / "sessions",
            ["toyarm"],
            args.sessions,
            seed=0,
            width=model.card.width or 64,
            height=model.card.height or 64,
            horizon=args.horizon,
            policies=["exact", "never_closes"],
        )
        sizes = [1, *[b for b in args.batch if b != 1]]
        norms = list(NORMS) if args.compare_norms else ["sums"]
        runs: dict[tuple[int, str], list] = {(b, n): [] for b in sizes for n in norms}
        for k in range(args.repeats):
            for b in sizes:
                for n in norms:  # the norms alternate within each batch size, the batch sizes within each round
                    with NORMS[n]():
                        runs[b, n].append(_run(manifest, Path(tmp) / f"r{k}b{b}{n}", model, sampler, b))
        diff = 0  # every run's videos against batch 1's with the norm as it is
        for b, n in list(runs)[1:]:
            for ra, rb in zip(runs[1, "sums"][0]["records"], runs[b, n][0]["records"]):
                if ra["status"] == rb["status"] == "ok":
                    a = read_video(Path(tmp) / "r0b1sums" / ra["video"]).astype(int)
                    v = read_video(Path(tmp) / f"r0b{b}{n}" / rb["video"]).astype(int)
                    diff = max(diff, int(np.abs(a - v).max()))
        same_with_f_normalize = None
        if args.compare_norms:  # bit for bit: the norms' batch-1 videos are the same files' frames
            pairs = zip(runs[1, "sums"][0]["records"], runs[1, "F.normalize"][0]["records"])
            same_with_f_normalize = all(
                np.array_equal(
                    read_video(Path(tmp) / "r0b1sums" / ra["video"]),
                    read_video(Path(tmp) / "r0b1F.normalize" / rb["video"]),
                )
                for ra, rb in pairs
                if ra["status"] == rb["status"] == "ok"
            )
        probe = None
        if not args.no_vae_probe:  # on the first chunk of the first cell's video: frames the world model made
            first = next(r for r in runs[1, "sums"][0]["records"] if r["status"] == "ok")
            video = read_video(Path(tmp) / "r0b1sums" / first["video"])[: model.card.chunk_frames]
            probe = vae_probe(model, np.ascontiguousarray(video), args.probe_repeats)
    rows = [{**_sum_rounds(runs[key]), "rms_norm": key[1]} for key in runs]
    if args.device.startswith("cuda"):
        for r in rows:
            r["cells_per_gpu_hour"] = r["cells"] / (r["wall_s"] / 3600.0)
    base = {r["rms_norm"]: r for r in rows if r["batch_cells"] == 1}
    speedups = [
        {
            "batch_cells": r["batch_cells"],
            "rms_norm": r["rms_norm"],
            "cells_per_cpu_minute": r["cells_per_cpu_minute"] / base[r["rms_norm"]]["cells_per_cpu_minute"],
            "cells_per_wall_minute": r["cells_per_wall_minute"] / base[r["rms_norm"]]["cells_per_wall_minute"],
        }
        for r in rows
        if r["batch_cells"] != 1
    ]
    cols = [*CPU_PARTS, "other", "total"]
    print(f"{'batch':>5s} {'norm':>11s} {'cells':>5s} {'cells/CPU-min':>13s} {'cells/wall-min':>14s}  CPU ms per step:")
    print(" " * 53 + "".join(f" {c:>10s}" for c in cols))
    for r in rows:
        print(
            f"{r['batch_cells']:5d} {r['rms_norm']:>11s} {r['cells']:5d} {r['cells_per_cpu_minute']:13.2f}"
            f" {r['cells_per_wall_minute']:14.2f}" + "".join(f" {r['cpu_ms_per_step'][c]:10.1f}" for c in cols)
        )
    for sp in speedups:
        print(
            f"batch {sp['batch_cells']} / batch 1 ({sp['rms_norm']} norm), cells per CPU-minute:"
            f" {sp['cells_per_cpu_minute']:.2f}x"
        )
    print(f"videos differ from batch 1's by at most {diff} uint8 level")
    if same_with_f_normalize is not None:
        print(f"batch 1's videos bit-identical with the F.normalize norm: {same_with_f_normalize}")
    print("policy-visible latency per chunk (world step, request to frames):")
    for r in rows:
        pv = r["policy_visible"]
        print(
            f"  batch {r['batch_cells']} ({r['rms_norm']} norm): {pv['wall_ms_per_call']:.0f} wall ms,"
            f" {pv['cpu_ms_per_call']:.0f} CPU ms per call"
            f" ({pv['cpu_ms_per_chunk']:.0f} CPU ms per chunk, {pv['world_calls']} calls)"
            + (f", {r['cells_per_gpu_hour']:.0f} cells per GPU-hour" if "cells_per_gpu_hour" in r else "")
        )
    if probe is not None:
        print(
            f"VAE probe, one chunk {probe['chunk']} -> latent {probe['latent']}, thread CPU ms (best of {probe['repeats']}):"
        )
        for key, value in probe.items():
            if key not in ("chunk", "latent", "repeats"):
                shown = [round(v, 1) for v in value] if isinstance(value, list) else value
                print(f"  {key}: {round(shown, 3) if isinstance(shown, float) else shown}")
    out = with_provenance(
        {
            "model": f"random {args.size}" if args.size else args.model,
            "device": args.device,
            "device_name": torch.cuda.get_device_name() if args.device.startswith("cuda") else None,
            "dtype": str(next(model.transformer.parameters()).dtype).removeprefix("torch."),
            "decoder": ("tiny, random weights" if tiny == "random" else "tiny")
            if model.vae.tiny is not None
            else "full",
            "condition_encoder": ("tiny, random weights" if args.tiny_encoder == "random" else "tiny")
            if model.vae.tiny_encoder is not None
            else "full",
            "threads": 1,
            "sessions": args.sessions,
            "policies": ["exact", "never_closes"],
            "horizon": args.horizon,
            "steps": sampler.steps,
            "guidance": f"{sampler.guidance}, {sampler.guidance_form} form",
            "guidance_interval": sampler.guidance_interval,
            "repeats": args.repeats,
            "rows": rows,
            "speedup_vs_batch_1": speedups,
            "max_uint8_diff": diff,
            "videos_bit_identical_with_f_normalize_norm": same_with_f_normalize,
            "vae_probe": probe,
        }
    )
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
