"""The toy tiny condition encoder against `oscar-toy`'s full VAE encoder: latent error, the rollouts it changes, speed.

    python benchmarks/tiny_encoder.py [--tiny zoo/assets/oscar-toy/tiny_encoder.safetensors]
        [--clips /work/exp/clipsets/cf49-latents ...] [--rollouts-per-embodiment 4] [--horizon 33]
        [--models oscar-toy-fast oscar-toy:10] [--speed-repeats 5] [--json benchmarks/results/tiny_encoder.json]

Three parts, one process, one torch thread (``OMP_NUM_THREADS=1``):

- ``latents``: the held-out clips of the toy clip sets (``meta.episode % 10 == 8``, as ``oscar toyworld
  train-tiny-encoder`` holds them out), each clip's condition video (its ``skeleton`` file) cut into the closed loop's
  17-frame chunks (starts 0, 16, 32, ...) and encoded by both encoders; the relative RMS error of the tiny encoder's
  normalised latents against the full encoder's (sqrt(sum (tiny − full)²) / sqrt(sum full²), per window, and over all
  windows) and the largest per-window error. Beside it, the same error on each held-out clip's first RGB frame (one
  frame, what a seed frame is): the toy tiny encoder was trained on conditions only, and this says whether it could
  also take the seed frame's encode (it does not: the option keeps the seed with the full encoder).
- ``rollouts``: per model (``NAME`` with its card's sampler, or ``NAME:STEPS``), ``--rollouts-per-embodiment``
  held-out clips of each embodiment rolled out from their first frame along their condition video for ``--horizon``
  frames, twice with the same seed: the full encoder's conditions and the tiny encoder's. PSNR (dB, mean over the
  generated frames, frame 0 excluded: it is the given first frame) of the tiny-encoder rollout against the
  full-encoder rollout, per chunk; beside it, the same PSNR between two full-encoder rollouts with different seeds
  (the sampler's own spread) and each rollout's PSNR against the clip's true frames.
- ``speed``: thread CPU and wall milliseconds of one 17-frame 64 x 64 condition encode and one 1-frame seed encode by
  each encoder at batch 1 (best of ``--speed-repeats``, the two interleaved).
- ``flop_rates_wan21_shapes``: the full WAN 2.1 encoder and the tiny encoder at ``taew2_1``'s width (random weights)
  on one 9-frame 64 x 64 clip: FLOPs counted, CPU ms, and so the FLOP rate each reaches on this CPU (the 2B computed
  rows of benchmarks/distill_speed.py assume one rate for both on a GPU; this is the CPU's side of that question).

Prints a table, writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import with_provenance  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
DEFAULT_CLIPS = [f"/work/exp/clipsets/cf49{e}-latents" for e in ("", "-kuka", "-toyarm")]
DEFAULT_TINY = REPO / "zoo" / "assets" / "oscar-toy" / "tiny_encoder.safetensors"


def _thread_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_THREAD)
    return r.ru_utime + r.ru_stime


def relative_rms(pred: np.ndarray, target: np.ndarray) -> float:
    from oscar_core.toyworld.tiny_encoder_train import relative_rms as rel

    return rel(pred, target)


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over frames of the per-frame PSNR (dB) of two (T, H, W, 3) uint8 videos."""
    from oscar_core.metrics import psnr

    return float(psnr(a, b, n_frames=None).mean())


def heldout_clips(clipsets) -> list[tuple[str, object, object]]:
    """``(embodiment, clip set, record)`` of every held-out clip (``meta.episode % 10 == 8``), in clip-set order."""
    from oscar_core.train.clips import ClipSet

    out = []
    for root in clipsets:
        cs = ClipSet(root)
        out += [(rec.embodiment, cs, rec) for rec in cs if int(rec.meta.get("episode", 0)) % 10 == 8]
    return out


def latents(vae, tiny, clips, window: int) -> dict:
    """The tiny encoder's latent error against the full encoder's on the held-out conditions' chunks and on their
    first RGB frames (module docstring)."""
    from oscar_core.media.video import read_video

    rows, seeds = [], []
    all_pred, all_full, seed_pred, seed_full = [], [], [], []
    for _, cs, rec in clips:
        skel = read_video(cs.path(rec, "skeleton"))
        for start in range(0, len(skel) - window + 1, window - 1):
            pixels = vae.to_pixels(skel[start : start + window])
            full, small = vae.encode(pixels).numpy(), tiny.encode(pixels).numpy()
            all_pred.append(small), all_full.append(full)
            rows.append({"clip": rec.id, "start": start, "relative_rms": relative_rms(small, full)})
        first = vae.to_pixels(read_video(cs.path(rec, "rgb"), max_frames=1))
        full, small = vae.encode(first).numpy(), tiny.encode(first).numpy()
        seed_pred.append(small), seed_full.append(full)
        seeds.append(relative_rms(small, full))
    return {
        "windows": len(rows),
        "clips": len(clips),
        "window_frames": window,
        "relative_rms": relative_rms(np.concatenate(all_pred), np.concatenate(all_full)),
        "relative_rms_window_mean": float(np.mean([r["relative_rms"] for r in rows])),
        "relative_rms_window_max": float(np.max([r["relative_rms"] for r in rows])),
        "seed_frame_relative_rms": relative_rms(np.concatenate(seed_pred), np.concatenate(seed_full)),
        "seed_frame_relative_rms_max": float(np.max(seeds)),
        "rows": rows,
    }


def rollout_pair(model, tiny_net, first: np.ndarray, condition: np.ndarray, sampler, seed: int) -> dict:
    """Three rollouts of one clip: the full encoder's conditions at ``seed`` and ``seed + 1000``, the tiny encoder's
    at ``seed``; returns their frames (T, H, W, 3) uint8 as ``full``, ``full_other_seed``, ``tiny``. The model's
    condition encoder is the full one again afterwards."""
    model.vae.use_tiny_encoder(None)
    out = {
        "full": model.rollout(first, condition, sampler=sampler, seed=seed, progress=False).frames,
        "full_other_seed": model.rollout(first, condition, sampler=sampler, seed=seed + 1000, progress=False).frames,
    }
    model.vae.use_tiny_encoder(tiny_net)
    try:
        out["tiny"] = model.rollout(first, condition, sampler=sampler, seed=seed, progress=False).frames
    finally:
        model.vae.use_tiny_encoder(None)
    return out


def chunk_psnrs(a: np.ndarray, b: np.ndarray, starts: list[int], chunk: int) -> list[float]:
    """PSNR of each chunk's generated frames (frame 0 of the rollout excluded; chunk c: frames starts[c] + 1 to
    starts[c] + chunk − 1)."""
    return [_psnr(a[s + 1 : s + chunk], b[s + 1 : s + chunk]) for s in starts if s + 1 < len(a)]


def rollouts(spec: str, tiny_net, clips, per_embodiment: int, horizon: int) -> dict:
    """The tiny-encoder rollouts against the full-encoder ones (module docstring) for the model ``spec``."""
    import oscar_zoo
    from oscar_core.media.video import read_video
    from oscar_core.model.chunks import chunk_plan

    name, _, steps = spec.partition(":")
    model = oscar_zoo.load(name)
    sampler = model.recommended_sampler(**({"steps": int(steps)} if steps else {}))
    chunk = int(model.card.chunk_frames)
    starts = chunk_plan(horizon, chunk, model.vae.temporal)
    chosen, taken = [], {}
    for emb, cs, rec in clips:
        if taken.get(emb, 0) < per_embodiment:
            taken[emb] = taken.get(emb, 0) + 1
            chosen.append((emb, cs, rec))
    rows = []
    for i, (emb, cs, rec) in enumerate(chosen):
        truth = read_video(cs.path(rec, "rgb"))[:horizon]
        condition = read_video(cs.path(rec, "skeleton"))[:horizon]
        v = rollout_pair(model, tiny_net, truth[0], condition, sampler, seed=i)
        rows.append(
            {
                "clip": rec.id,
                "embodiment": emb,
                "seed": i,
                "psnr_tiny_vs_full": _psnr(v["tiny"][1:], v["full"][1:]),
                "psnr_tiny_vs_full_per_chunk": chunk_psnrs(v["tiny"], v["full"], starts, chunk),
                "psnr_full_other_seed_vs_full": _psnr(v["full_other_seed"][1:], v["full"][1:]),
                "psnr_full_vs_true": _psnr(v["full"][1:], truth[1:]),
                "psnr_tiny_vs_true": _psnr(v["tiny"][1:], truth[1:]),
            }
        )
        print(f"  {spec} {rec.id}: tiny vs full {rows[-1]['psnr_tiny_vs_full']:.2f} dB", flush=True)
    keys = [k for k in rows[0] if k.startswith("psnr") and not k.endswith("per_chunk")]
    per_chunk = np.array([r["psnr_tiny_vs_full_per_chunk"] for r in rows])
    return {
        "model": name,
        "steps": sampler.steps,
        "guidance": sampler.guidance,
        "horizon": horizon,
        "chunk_frames": chunk,
        "rollouts": len(rows),
        **{k: float(np.mean([r[k] for r in rows])) for k in keys},
        "psnr_tiny_vs_full_min": float(min(r["psnr_tiny_vs_full"] for r in rows)),
        "psnr_tiny_vs_full_per_chunk": [float(x) for x in per_chunk.mean(axis=0)],
        "rows": rows,
    }


def speed(vae, tiny, repeats: int, window: int = 17, size: int = 64) -> dict:
    """Best-of-``repeats`` thread CPU and wall ms of one condition encode (``window`` frames) and one seed encode (1
    frame) at ``size`` x ``size`` by each encoder, interleaved."""
    rng = np.random.default_rng(0)
    clips = {
        "condition": vae.to_pixels(rng.integers(0, 256, (window, size, size, 3), dtype=np.uint8)),
        "seed": vae.to_pixels(rng.integers(0, 256, (1, size, size, 3), dtype=np.uint8)),
    }
    fns = {"full": vae.encode, "tiny": tiny.encode}
    best = {(c, e): [float("inf"), float("inf")] for c in clips for e in fns}
    for _ in range(repeats + 1):  # the first round warms up, and counts like the others (best of all)
        for c, x in clips.items():
            for e, fn in fns.items():
                w0, c0 = time.perf_counter(), _thread_cpu()
                fn(x)
                cpu, wall = _thread_cpu() - c0, time.perf_counter() - w0
                best[c, e] = [min(best[c, e][0], cpu * 1e3), min(best[c, e][1], wall * 1e3)]
    out = {"repeats": repeats, "window_frames": window, "size": f"{size}x{size}"}
    for (c, e), (cpu, wall) in best.items():
        out[f"{c}_{e}_cpu_ms"], out[f"{c}_{e}_wall_ms"] = round(cpu, 1), round(wall, 1)
    return out


def flop_rates(repeats: int, frames: int = 9, size: int = 64) -> dict:
    """The FLOP rate each encoder reaches on this CPU at the WAN 2.1 shapes (random weights): the full WAN 2.1 VAE
    encoder (oscar's WanVAE at its default configuration, through VideoVAE as a rollout runs it) and the tiny encoder
    at ``taew2_1``'s width, on one ``frames``-frame ``size`` x ``size`` clip; FLOPs from torch's FLOP counter,
    thread CPU ms best of ``repeats``. What the 2B computed rows assume (both at one rate) is checked here on a CPU
    only."""
    from torch.utils.flop_counter import FlopCounterMode

    from oscar_core.model.tiny_encoder import TinyEncoderNet, TinyVideoEncoder
    from oscar_core.model.vae import VideoVAE
    from oscar_core.model.wan_vae import WanVAE

    def flops(fn, x) -> float:
        with FlopCounterMode(display=False) as fc:
            fn(x)
        return fc.get_total_flops() / 1e9

    # counted on the meta device, the modules as built: VideoVAE sends the CPU's 3-D convolutions to oneDNN
    # (cpu_conv.py), whose calls torch's FLOP counter does not see
    with torch.device("meta"):
        counted = {"full": flops(lambda x: WanVAE().encode(x), torch.zeros(1, 3, frames, size, size))}
        counted["tiny"] = flops(TinyEncoderNet(), torch.zeros(1, frames, 3, size, size))
    torch.manual_seed(0)
    full = VideoVAE(WanVAE())
    tiny = TinyVideoEncoder(TinyEncoderNet(), full.mean, full.std)
    x = torch.rand(1, 3, frames, size, size) * 2 - 1
    out = {"frames": frames, "size": f"{size}x{size}", "repeats": repeats}
    for name, fn in (("full", full.encode), ("tiny", tiny.encode)):
        best = float("inf")
        for _ in range(repeats + 1):  # the first call warms up and counts like the others
            c0 = _thread_cpu()
            fn(x)
            best = min(best, _thread_cpu() - c0)
        out[f"{name}_gflop"] = counted[name]
        out[f"{name}_cpu_ms"] = round(best * 1e3, 1)
        out[f"{name}_gflop_per_cpu_s"] = counted[name] / best
    out["tiny_rate_vs_full"] = out["tiny_gflop_per_cpu_s"] / out["full_gflop_per_cpu_s"]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tiny", default=str(DEFAULT_TINY), help="the tiny encoder (.safetensors)")
    ap.add_argument("--clips", nargs="+", default=DEFAULT_CLIPS, help="clip sets whose clips hold a skeleton video")
    ap.add_argument("--rollouts-per-embodiment", type=int, default=4, help="held-out clips rolled out per embodiment")
    ap.add_argument("--horizon", type=int, default=33, help="frames per rollout (33: two 17-frame chunks)")
    ap.add_argument(
        "--models", nargs="+", default=["oscar-toy-fast", "oscar-toy:10"], help="NAME or NAME:STEPS (0 models: none)"
    )
    ap.add_argument("--speed-repeats", type=int, default=5)
    ap.add_argument(
        "--rate-repeats", type=int, default=2, help="best of N in the FLOP-rate part at the WAN 2.1 shapes (0: skip it)"
    )
    ap.add_argument("--json", default="benchmarks/results/tiny_encoder.json")
    args = ap.parse_args(argv)
    if not Path(args.tiny).is_file():
        ap.error(f"--tiny {args.tiny}: expected a tiny-encoder .safetensors file, found none")
    torch.set_num_threads(1)

    import oscar_zoo
    from oscar_core.model.tiny_encoder import TinyVideoEncoder, load_tiny_encoder

    t0, c0 = time.perf_counter(), time.process_time()
    vae = oscar_zoo.load("oscar-toy").vae
    net = load_tiny_encoder(args.tiny)
    tiny = TinyVideoEncoder(net, vae.mean, vae.std)
    sp = speed(vae, tiny, args.speed_repeats)
    clips = heldout_clips(args.clips)
    lat = latents(vae, tiny, clips, 17)
    rolls = [rollouts(spec, net, clips, args.rollouts_per_embodiment, args.horizon) for spec in args.models]
    rates = flop_rates(args.rate_repeats) if args.rate_repeats else None
    print(f"\ntiny condition encoder {args.tiny} ({sum(p.numel() for p in net.parameters())} parameters), one thread")
    print(f"{'encode':34s} {'full CPU ms':>12s} {'tiny CPU ms':>12s} {'full/tiny':>10s}")
    for c, words in (("condition", "condition, 17 frames 64x64"), ("seed", "seed frame, 1 frame 64x64")):
        full, small = sp[f"{c}_full_cpu_ms"], sp[f"{c}_tiny_cpu_ms"]
        print(f"{words:34s} {full:12.1f} {small:12.1f} {full / small:9.2f}x")
    print(
        f"latents, {lat['windows']} held-out chunks of {lat['clips']} clips: relative RMS {lat['relative_rms']:.4f} "
        f"(per chunk mean {lat['relative_rms_window_mean']:.4f}, max {lat['relative_rms_window_max']:.4f}); on the "
        f"clips' first RGB frames {lat['seed_frame_relative_rms']:.4f}"
    )
    print(f"{'rollouts (PSNR dB, frames 1..)':34s} {'tiny vs full':>12s} {'min':>6s} {'per chunk':>14s} "
          f"{'other seed':>10s} {'full/true':>9s} {'tiny/true':>9s}")  # fmt: skip
    for r in rolls:
        chunks = " / ".join(f"{x:.1f}" for x in r["psnr_tiny_vs_full_per_chunk"])
        label = f"{r['model']}, {r['steps']} steps, {r['rollouts']} clips"
        print(
            f"{label:34s} "
            f"{r['psnr_tiny_vs_full']:12.2f} {r['psnr_tiny_vs_full_min']:6.2f} {chunks:>14s} "
            f"{r['psnr_full_other_seed_vs_full']:10.2f} {r['psnr_full_vs_true']:9.2f} {r['psnr_tiny_vs_true']:9.2f}"
        )
    if rates:
        print(
            f"FLOP rate on this CPU, {rates['frames']} frames {rates['size']}, WAN 2.1 shapes: full encoder "
            f"{rates['full_gflop']:.1f} GFLOP in {rates['full_cpu_ms']:.0f} CPU ms ({rates['full_gflop_per_cpu_s']:.1f} "
            f"GFLOP/s), tiny at taew2_1's width {rates['tiny_gflop']:.2f} GFLOP in {rates['tiny_cpu_ms']:.0f} CPU ms "
            f"({rates['tiny_gflop_per_cpu_s']:.1f} GFLOP/s, {rates['tiny_rate_vs_full']:.2f}x the full encoder's rate)"
        )
    tiny_path = Path(args.tiny).resolve()
    out = with_provenance(
        {
            "tiny_encoder": {
                "file": tiny_path.relative_to(REPO).as_posix() if tiny_path.is_relative_to(REPO) else args.tiny,
                "bytes": tiny_path.stat().st_size,
                "parameters": sum(p.numel() for p in net.parameters()),
                "width": net.width,
            },
            "speed": sp,
            "latents": lat,
            "rollouts": rolls,
            "flop_rates_wan21_shapes": rates,
            "wall_s": round(time.perf_counter() - t0, 1),
            "cpu_s": round(time.process_time() - c0, 1),
        }
    )
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(out, indent=2) + "\n")
    tmp.replace(path)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
