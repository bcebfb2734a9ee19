"""The toy tiny decoder against `oscar-toy`'s full VAE decoder: quality, speed, and whether the judge's verdicts change.

    python benchmarks/tiny_decoder.py [--tiny zoo/assets/oscar-toy/tiny_decoder.safetensors]
        [--clips /work/exp/clipsets/cf49-latents ...] [--windows-per-clip 2] [--sets 1] [--chunks 6] [--steps 10]
        [--speed-repeats 5] [--rollouts benchmarks/results/tiny_decoder_rollouts] [--rollouts-only]
        [--json benchmarks/results/tiny_decoder.json]

Three parts, one process, one torch thread (``OMP_NUM_THREADS=1``):

- ``quality``: held-out latent windows of toy clips (cached latents of `oscar-toy`'s VAE, ``oscar train
  --cache-latents``; held out as ``oscar toyworld train-tiny-decoder`` holds them out: ``meta.episode % 10 == 8``;
  the first and last ``--windows-per-clip`` windows of each such clip) decoded by both decoders. PSNR (dB, mean over
  windows of the per-frame mean) and motion IoU (:func:`oscar_core.toyworld.frame_metrics.motion_mask`: pixels whose
  grey level changed from frame 0 by more than 24 levels, pooled over a window's frames) of the tiny decode against
  the full decode, and of each against the true frames of the clip (its ``rgb.mkv``).
- ``speed``: thread CPU and wall milliseconds per 17-frame 64x64 chunk (5 latent frames of 16x16) for each decoder
  at batch 1 (best of ``--speed-repeats``, the two decoders interleaved) and per chunk within the batched calls of
  the verdict part (all calls summed / chunks decoded).
- ``verdicts``: counterfactual toy sets (``oscar toyworld action-following``'s, ``--sets`` per embodiment of toyarm,
  franka, kuka; 6 variants each, ``--chunks`` chunks) rolled out by `oscar-toy` with ``--steps`` sampler steps
  (the card's guidance) and the full decoder, as the benchmark does. Every chunk's latents are also decoded by the tiny
  decoder (the rollout itself goes on with the full decoder's frames, so both videos come from the same latents), and
  the toy judge (:func:`oscar_core.toyworld.judge.ball_moved`) gives a verdict on both videos of every variant:
  agreement between the two, and of each with the verdict on the true video. The full decoder's video rebuilt from
  the recorded decodes is checked to equal the rollout's own (so the tiny video is assembled the same way). The
  rollouts (each chunk's latents and the full decoder's videos) are kept in ``--rollouts`` and read back by a later
  run, so ``--rollouts-only`` can roll them out before a tiny decoder exists; the tiny decoder then decodes the
  stored latents.

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
from types import SimpleNamespace

for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import with_provenance  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
DEFAULT_CLIPS = [f"/work/exp/clipsets/cf49{e}-latents" for e in ("", "-kuka", "-toyarm")]


def _thread_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_THREAD)
    return r.ru_utime + r.ru_stime


def _u8(x: torch.Tensor) -> np.ndarray:
    """(B, 3, T, H, W) in [-1, 1] -> (B, T, H, W, 3) uint8 (VideoVAE.to_uint8's rule)."""
    from oscar_core.model.vae import VideoVAE

    return VideoVAE.to_uint8(x.clamp(-1, 1))


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    from oscar_core.metrics import psnr

    return float(psnr(a, b, n_frames=None).mean())


def _motion_iou(a: np.ndarray, b: np.ndarray) -> float:
    from oscar_core.toyworld.frame_metrics import mask_iou, motion_mask

    return mask_iou(motion_mask(a), motion_mask(b))


def quality(vae, tiny, clipsets, windows_per_clip: int) -> dict:
    """PSNR and motion IoU of the tiny decode against the full decode (and both against the truth) on held-out
    windows (module docstring)."""
    from safetensors.numpy import load_file

    from oscar_core.media.video import read_video
    from oscar_core.train.clips import ClipSet

    rows = []
    for root in clipsets:
        cs = ClipSet(root)
        for rec in cs:
            if int(rec.meta.get("episode", 0)) % 10 != 8:
                continue
            lat = load_file(str(cs.path(rec, "latents")))
            starts, z = lat["starts"], lat["video"]
            truth = read_video(cs.path(rec, "rgb"))
            pick = sorted({0, len(starts) - 1}) if windows_per_clip >= 2 else [0]
            for w in pick:
                zz = torch.from_numpy(np.ascontiguousarray(z[w : w + 1]))
                full = _u8(vae.decode(zz))[0]
                small = _u8(tiny.decode(zz))[0]
                true = truth[int(starts[w]) : int(starts[w]) + full.shape[0]]
                rows.append(
                    {
                        "clip": rec.id,
                        "start": int(starts[w]),
                        "psnr_tiny_vs_full": _psnr(small, full),
                        "motion_iou_tiny_vs_full": _motion_iou(small, full),
                        "psnr_full_vs_true": _psnr(full, true),
                        "psnr_tiny_vs_true": _psnr(small, true),
                        "motion_iou_full_vs_true": _motion_iou(full, true),
                        "motion_iou_tiny_vs_true": _motion_iou(small, true),
                    }
                )
    keys = [k for k in rows[0] if k not in ("clip", "start")]
    summary = {k: float(np.nanmean([r[k] for r in rows])) for k in keys}
    summary["motion_iou_tiny_vs_full_min"] = float(np.nanmin([r["motion_iou_tiny_vs_full"] for r in rows]))
    summary["psnr_tiny_vs_full_min"] = float(min(r["psnr_tiny_vs_full"] for r in rows))
    return {"windows": len(rows), "clips": len({r["clip"] for r in rows}), **summary, "rows": rows}


def speed(vae, tiny, repeats: int) -> dict:
    """Best-of-``repeats`` thread CPU and wall ms of one chunk's decode by each decoder, interleaved."""
    z = torch.randn(1, 16, 5, 16, 16, generator=torch.Generator().manual_seed(0))
    best = {"full": [1e9, 1e9], "tiny": [1e9, 1e9]}
    for _ in range(repeats):
        for name, dec in (("full", vae), ("tiny", tiny)):
            c, t = _thread_cpu(), time.perf_counter()
            dec.decode(z)
            best[name] = [min(best[name][0], _thread_cpu() - c), min(best[name][1], time.perf_counter() - t)]
    return {f"{k}_{m}_ms": round(1000 * v[i], 1) for k, v in best.items() for i, m in enumerate(("cpu", "wall"))}


class _RecordingVAE:
    """Stands in for the model's VideoVAE: ``decode`` is the full decoder's (the rollout goes on with its frames); it
    records each call's latents and frames and the decoder's thread CPU seconds."""

    def __init__(self, vae):
        self._vae = vae
        self.latents: list[torch.Tensor] = []
        self.frames: list[torch.Tensor] = []
        self.cpu = 0.0
        self.chunks = 0

    def __getattr__(self, name):
        return getattr(self._vae, name)

    def decode(self, latents):
        c = _thread_cpu()
        full = self._vae.decode(latents)
        self.cpu += _thread_cpu() - c
        self.latents.append(latents.detach().cpu().clone())
        self.frames.append(full.cpu().clamp(-1, 1))
        self.chunks += latents.shape[0]
        return full


def _assemble(decodes: list, total: int) -> np.ndarray:
    """The (B, T, H, W, 3) uint8 videos ``iter_rollout`` makes of a sequence of chunk decodes (B, 3, L, H, W)
    (chunk 0 whole, then each chunk without its first frame, cut at ``total``)."""
    pieces = [_u8(d if i == 0 else d[:, :, 1:]) for i, d in enumerate(decodes)]
    return np.concatenate(pieces, axis=1)[:, :total]


def _sets(sets: int, chunks: int, L: int, seed: int, folder: Path, embodiments=("toyarm", "franka", "kuka")):
    from oscar_core.evaluation.action_following_manifest import load_action_following
    from oscar_core.toyworld.counterfactual import write_counterfactual_sets

    return load_action_following(
        write_counterfactual_sets(folder, list(embodiments), sets, seed=seed, frames=1 + chunks * (L - 1))
    )


def rollouts(model, manifest, steps: int, seed: int, cache: Path) -> dict:
    """Roll every set's variants out with the full decoder (as ``oscar toyworld action-following`` does) and keep
    each chunk's latents and the videos in ``cache/<set>.npz`` (a set already there is read back, not rolled out
    again). Returns the full decoder's CPU per chunk in these batched calls and whether the video rebuilt from the
    recorded decodes equals the rollout's (so the tiny decoder's video is assembled the same way)."""
    from oscar_core.evaluation.action_following import _prompt, _set_inputs, roll_out_variants
    from oscar_core.model.card_sampler import resolve_sampler

    sampler = resolve_sampler(
        model.card.sampler,
        steps=steps,
        preset=None,
        guidance_interval=None,
        shift=5.0,
        guidance=None,
        guidance_form=None,
        defaults={"guidance_form": "standard"},
    ).config
    cache.mkdir(parents=True, exist_ok=True)
    rec = _RecordingVAE(model.vae)
    equal, t0, c0 = True, time.perf_counter(), time.process_time()
    model.vae = rec
    try:
        for s in manifest.sets:
            path = cache / f"{s.set.replace('/', '_')}.npz"
            if path.is_file():
                continue
            emb, camera, first = _set_inputs(s, ())
            h, w = first.shape[:2]
            inputs = [
                model.rollout_inputs(v.trajectory, camera, emb, (w, h), resize_mode="crop", camera_source=str(s.camera))
                for v in s.variants
            ]
            rec.latents.clear(), rec.frames.clear()
            videos = roll_out_variants(model, first, inputs, _prompt(s), sampler=sampler, seed=seed, chunk_frames=None)
            videos = np.stack([np.asarray(v) for v in videos])
            equal &= bool(np.array_equal(_assemble(rec.frames, videos.shape[1]), videos))
            np.savez(path, latents=torch.stack(rec.latents).numpy(), videos=videos)
    finally:
        model.vae = rec._vae
    return {
        "full_decode_cpu_ms_per_chunk_batched": round(1000 * rec.cpu / rec.chunks, 1) if rec.chunks else None,
        "full_video_rebuilt_equals_rollout": equal,
        "wall_s": round(time.perf_counter() - t0, 1),
        "cpu_s": round(time.process_time() - c0, 1),
    }


def verdicts(manifest, vae, tiny, cache: Path) -> dict:
    """The toy judge on both decoders' videos of the same latents (module docstring); and on both decoders' videos of
    the VAE latents of each variant's true video (``roundtrip_*``: cells where the ball does move)."""
    from oscar_core.media.video import read_video
    from oscar_core.model.vae import VideoVAE
    from oscar_core.toyworld.judge import ball_moved

    rows, cpu, chunks = [], 0.0, 0
    for s in manifest.sets:
        data = np.load(cache / f"{s.set.replace('/', '_')}.npz")
        full_v = data["videos"]
        decodes = []
        for z in data["latents"]:
            c = _thread_cpu()
            decodes.append(tiny.decode(torch.from_numpy(z)).clamp(-1, 1))
            cpu += _thread_cpu() - c
            chunks += z.shape[0]
        tiny_v = _assemble(decodes, full_v.shape[1])
        for v, fv, tv in zip(s.variants, full_v, tiny_v):
            clip = SimpleNamespace(info=s.info)
            vf, vt = ball_moved(fv, clip), ball_moved(tv, clip)
            truth, rt = None, {}
            if v.video is not None:
                true_video = read_video(v.video)
                truth = ball_moved(true_video, clip)["binary"]
                z = vae.encode(VideoVAE.to_pixels(true_video))
                rt_full, rt_tiny = _u8(vae.decode(z))[0], _u8(tiny.decode(z))[0]
                rt = {
                    "roundtrip_full": ball_moved(rt_full, clip)["binary"],
                    "roundtrip_tiny": ball_moved(rt_tiny, clip)["binary"],
                    "roundtrip_psnr_tiny_vs_full": _psnr(rt_tiny, rt_full),
                    "roundtrip_motion_iou_tiny_vs_full": _motion_iou(rt_tiny, rt_full),
                }
            rows.append(
                {
                    "set": s.set,
                    "variant": v.name,
                    "full": vf["binary"],
                    "tiny": vt["binary"],
                    "truth": truth,
                    "full_partial": vf["partial"],
                    "tiny_partial": vt["partial"],
                    "psnr_tiny_vs_full": _psnr(tv, fv),
                    "motion_iou_tiny_vs_full": _motion_iou(tv, fv),
                    **rt,
                }
            )
    truth_rows = [r for r in rows if r["truth"] is not None]
    return {
        "sets": len(manifest.sets),
        "variants": len(rows),
        "verdicts_agree": sum(r["full"] == r["tiny"] for r in rows),
        "verdicts_differ": [
            f"{r['set']}/{r['variant']}: full {r['full']}, tiny {r['tiny']}" for r in rows if r["full"] != r["tiny"]
        ],
        "full_success": sum(r["full"] for r in rows),
        "tiny_success": sum(r["tiny"] for r in rows),
        "full_agrees_with_truth": sum(r["full"] == r["truth"] for r in truth_rows),
        "tiny_agrees_with_truth": sum(r["tiny"] == r["truth"] for r in truth_rows),
        "with_truth": len(truth_rows),
        "mean_abs_partial_difference": float(np.mean([abs(r["full_partial"] - r["tiny_partial"]) for r in rows])),
        "psnr_tiny_vs_full": float(np.mean([r["psnr_tiny_vs_full"] for r in rows])),
        "motion_iou_tiny_vs_full": float(np.nanmean([r["motion_iou_tiny_vs_full"] for r in rows])),
        "tiny_decode_cpu_ms_per_chunk_batched": round(1000 * cpu / chunks, 1),
        "truth_success": sum(r["truth"] for r in truth_rows),
        "roundtrip_verdicts_agree": sum(r["roundtrip_full"] == r["roundtrip_tiny"] for r in truth_rows),
        "roundtrip_full_success": sum(r["roundtrip_full"] for r in truth_rows),
        "roundtrip_tiny_success": sum(r["roundtrip_tiny"] for r in truth_rows),
        "roundtrip_full_agrees_with_truth": sum(r["roundtrip_full"] == r["truth"] for r in truth_rows),
        "roundtrip_tiny_agrees_with_truth": sum(r["roundtrip_tiny"] == r["truth"] for r in truth_rows),
        "roundtrip_psnr_tiny_vs_full": float(np.mean([r["roundtrip_psnr_tiny_vs_full"] for r in truth_rows])),
        "roundtrip_motion_iou_tiny_vs_full": float(
            np.nanmean([r["roundtrip_motion_iou_tiny_vs_full"] for r in truth_rows])
        ),
        "rows": rows,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tiny", default=str(REPO / "zoo" / "assets" / "oscar-toy" / "tiny_decoder.safetensors"))
    ap.add_argument("--clips", nargs="+", default=DEFAULT_CLIPS, help="cached-latents clip sets of oscar-toy's VAE")
    ap.add_argument("--windows-per-clip", type=int, default=2, choices=(1, 2))
    ap.add_argument("--sets", type=int, default=1, help="counterfactual sets per embodiment (0: skip the verdicts)")
    ap.add_argument("--embodiments", default="toyarm,franka,kuka", help="of the counterfactual sets")
    ap.add_argument("--chunks", type=int, default=6)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--speed-repeats", type=int, default=5)
    ap.add_argument(
        "--rollouts",
        default="benchmarks/results/tiny_decoder_rollouts",
        help="where the sets, their latents and full-decoder videos are kept (a set there is not rolled out again)",
    )
    ap.add_argument("--rollouts-only", action="store_true", help="roll the sets out into --rollouts and stop")
    ap.add_argument("--json", default="benchmarks/results/tiny_decoder.json")
    args = ap.parse_args()
    torch.set_num_threads(1)

    import oscar_zoo
    from oscar_core.model.tiny_decoder import TinyVideoDecoder, load_tiny_decoder

    model = oscar_zoo.load("oscar-toy")
    t0, c0 = time.perf_counter(), time.process_time()
    if args.rollouts_only:
        cache = Path(args.rollouts)
        manifest = _sets(
            args.sets, args.chunks, int(model.card.chunk_frames), args.seed, cache / "sets", args.embodiments.split(",")
        )
        print(f"rollouts kept in {cache}: {rollouts(model, manifest, args.steps, args.seed, cache)}")
        return 0
    net = load_tiny_decoder(args.tiny)
    tiny = TinyVideoDecoder(net, model.vae.mean, model.vae.std)
    sp = speed(model.vae, tiny, args.speed_repeats)
    print(
        f"speed, one chunk (thread CPU ms, best of {args.speed_repeats}): full {sp['full_cpu_ms']}, tiny {sp['tiny_cpu_ms']}"
    )
    q = quality(model.vae, tiny, args.clips, args.windows_per_clip)
    print(
        f"quality, {q['windows']} held-out windows of {q['clips']} clips: tiny vs full PSNR {q['psnr_tiny_vs_full']:.2f} dB, "
        f"motion IoU {q['motion_iou_tiny_vs_full']:.3f}; against the truth PSNR full {q['psnr_full_vs_true']:.2f} / "
        f"tiny {q['psnr_tiny_vs_true']:.2f} dB, motion IoU full {q['motion_iou_full_vs_true']:.3f} / tiny "
        f"{q['motion_iou_tiny_vs_true']:.3f}"
    )
    v = None
    if args.sets:
        cache = Path(args.rollouts)
        manifest = _sets(
            args.sets, args.chunks, int(model.card.chunk_frames), args.seed, cache / "sets", args.embodiments.split(",")
        )
        r = rollouts(model, manifest, args.steps, args.seed, cache)
        v = {
            "chunks_per_variant": args.chunks,
            "steps": args.steps,
            "seed": args.seed,
            **r,
            **verdicts(manifest, model.vae, tiny, cache),
        }
        print(
            f"verdicts, {v['variants']} variants of {v['sets']} sets: agree {v['verdicts_agree']}/{v['variants']}; "
            f"successes full {v['full_success']}, tiny {v['tiny_success']}; with the truth full "
            f"{v['full_agrees_with_truth']}/{v['with_truth']}, tiny {v['tiny_agrees_with_truth']}/{v['with_truth']}; "
            f"true videos through the VAE: agree {v['roundtrip_verdicts_agree']}/{v['with_truth']}, successes truth "
            f"{v['truth_success']}, full {v['roundtrip_full_success']}, tiny {v['roundtrip_tiny_success']}"
        )
    size = Path(args.tiny).stat().st_size
    out = with_provenance(
        {
            "tiny_decoder": {
                "file": Path(args.tiny).resolve().relative_to(REPO).as_posix()
                if Path(args.tiny).resolve().is_relative_to(REPO)
                else args.tiny,
                "bytes": size,
                "parameters": sum(p.numel() for p in net.parameters()),
                "widths": list(net.widths),
            },
            "speed": sp,
            "quality": q,
            "verdicts": v,
            "wall_s": round(time.perf_counter() - t0, 1),
            "cpu_s": round(time.process_time() - c0, 1),
        }
    )
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
