"""World-model speed and memory: one denoising step and one rollout, batched CFG against two passes.

    python benchmarks/rollout.py [--repeats 5] [--steps 4] [--json benchmarks/results/rollout.json]
    python benchmarks/rollout.py --gpu [--gpu-steps 35] [--compile]     (CUDA: the real 2B size, bf16)

For the tiny configuration (``oscar_core.model.tiny``: a 2-block DiT of
hidden 64 and a WAN 2.1 VAE of base width 8) at two resolutions and two
chunk lengths, it measures

* one denoising step (the guided velocity: DiT forward(s) for both guidance
  branches) — the batched path (one forward of batch 2) against the naive
  two-pass path (two forwards of batch 1), in the same run;
* one rollout of two chunks (VAE encode of seed and skeleton, ``--steps``
  steps per chunk, VAE decode), both guidance paths.

Time: median and best of ``--repeats`` runs. Peak memory: on CUDA,
``torch.cuda.max_memory_allocated``; on the CPU, the peak resident set size
above the level just before the call, sampled every millisecond by a thread
(the script re-executes itself with ``MALLOC_MMAP_THRESHOLD_`` and
``MALLOC_TRIM_THRESHOLD_`` set so freed tensors leave the process and each
call starts from a clean level). Timings on shared machines swing; compare
ratios within one run.

It also prints what the 2B model implies, computed from its configuration
(``COSMOS_2B_TRANSFORMER_CONFIG``, diffusers' conversion of
Cosmos-Predict2.5-2B) on the meta device: parameters, bf16 weight memory,
latent tokens per chunk, and FLOPs counted by ``torch.utils.flop_counter``
on the meta device (one guided DiT step = one forward of batch 2; the WAN
2.1 VAE encode/decode of an 81-frame 512x288 chunk), turned into seconds
per chunk and frames/s on one H100 (989 TFLOP/s dense bf16) at stated
utilisations, beside the paper's 2.214 frames/s on a GH200. These are
*computed*, not measured.

``--gpu`` (CUDA only) measures the real size with random weights in bf16:
seconds per guided denoising step (batched guidance, batch 2), seconds per
81-frame 512x288 chunk (``--gpu-steps`` UniPC steps, VAE encodes and decode
included), the VAE's work per chunk and its share of the chunk, frames/s (80
new frames per chunk), peak GPU memory, and with ``--compile`` the same
compiled through ``oscar_core.model.compile_policy`` (the path ``oscar
rollout`` takes) plus the seconds of the first compiled call (the compile).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _peak_memory import MALLOC_ENV, PeakMemory

if __name__ == "__main__" and not all(k in os.environ for k in MALLOC_ENV):
    for key, value in MALLOC_ENV.items():
        os.environ.setdefault(key, value)
    os.execv(sys.executable, [sys.executable, *sys.argv])

import numpy as np
import torch

from oscar_core.model import ModelCard, OscarTransformer3DModel, OscarWorldModel, SamplerConfig
from oscar_core.model.sampler import guided_velocity
from oscar_core.model.tiny import COSMOS_2B_TRANSFORMER_CONFIG, build_tiny_transformer, build_tiny_vae

SIZES = ((128, 64), (256, 128))  # width x height in pixels
CHUNKS = (9, 17)  # frames per chunk (4k+1)
PATHS = (("batched", True), ("two-pass", False))


# --------------------------------------------------------------------------- measuring


def measure(fn, repeats: int, device: torch.device, warmup: bool = True) -> dict:
    if warmup:
        fn()  # warm-up (allocator, thread pools)
    times, peaks = [], []
    for _ in range(repeats):
        with PeakMemory(device) as mem:
            t0 = time.perf_counter()
            fn()
            if device.type == "cuda":
                torch.cuda.synchronize()
            times.append(time.perf_counter() - t0)
        peaks.append(mem.peak)
    return {"median_ms": 1e3 * statistics.median(times), "best_ms": 1e3 * min(times), "peak_mib": max(peaks) / 2**20}


# --------------------------------------------------------------------------- cases


def bench_case(model: OscarWorldModel, width: int, height: int, chunk: int, args, device) -> dict:
    transformer = model.transformer
    t = (chunk - 1) // 4 + 1
    h, w = height // 8, width // 8
    g = torch.Generator().manual_seed(0)
    x = torch.randn(1, 16, t, h, w, generator=g).to(device)
    skel = torch.randn(1, 16, t, h, w, generator=g).to(device)
    mask = torch.zeros(1, 1, t, h, w, device=device)
    mask[:, :, 0] = 1
    timestep = torch.full((1, 1, t, 1, 1), 0.5, device=device)
    text = torch.zeros(1, 1, transformer.text_dim, device=device)  # timing only: any embedding of the right width
    padding = torch.zeros(1, 1, h, w, device=device)
    rng = np.random.default_rng(0)
    first = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    skeleton = rng.integers(0, 256, (2 * (chunk - 1) + 1, height, width, 3), dtype=np.uint8)
    row = {"size": f"{width}x{height}", "chunk_frames": chunk, "latent_tokens": t * (h // 2) * (w // 2)}
    for name, batched in PATHS:
        config = SamplerConfig(steps=args.steps, guidance=6.0, batched_cfg=batched)

        def step():
            with torch.no_grad():
                guided_velocity(transformer, x, timestep, text, skel, mask, padding, config)

        def roll():
            model.rollout(
                first, skeleton, text, chunk_frames=chunk, sampler=config, seed=0, progress=False, keep_chunks=False
            )

        row[f"step_{name}"] = measure(step, args.repeats, device)
        row[f"rollout_{name}"] = measure(roll, max(1, args.repeats // 2), device)
    row["rollout_frames"] = len(skeleton)
    return row


H100_BF16_TFLOPS = 989.4  # NVIDIA H100 SXM dense bf16 (the GH200's GPU has the same tensor-core peak)
PAPER_FPS_GH200 = 2.214  # the paper's reported rollout speed
UTILISATIONS = (0.2, 0.3, 0.4, 0.5, 1.0)


def _dit_inputs(batch, frames, width, height, device, dtype):
    t, h, w = (frames - 1) // 4 + 1, height // 8, width // 8
    return dict(
        hidden_states=torch.zeros(batch, 16, t, h, w, device=device, dtype=dtype),
        timestep=torch.full((batch, 1, t, 1, 1), 0.5, device=device),
        encoder_hidden_states=torch.zeros(batch, 512, 1024, device=device, dtype=dtype),
        condition_mask=torch.zeros(batch, 1, t, h, w, device=device, dtype=dtype),
        padding_mask=None,
        skeleton_latents=torch.zeros(batch, 16, t, h, w, device=device, dtype=dtype),
        return_dict=False,
        text_projected=True,
    )


def computed_2b(steps: int = 35, frames: int = 81, width: int = 512, height: int = 288) -> dict:
    """FLOPs of one guided step and one chunk of the 2B model, counted on the meta device (no memory used)."""
    from torch.utils.flop_counter import FlopCounterMode

    from oscar_core.model.wan_vae import WanVAE

    with torch.device("meta"):
        model = OscarTransformer3DModel(**COSMOS_2B_TRANSFORMER_CONFIG)
        vae = WanVAE()  # its defaults (diffusers' AutoencoderKLWan's) are the WAN 2.1 VAE's configuration
    with FlopCounterMode(display=False) as fc, torch.no_grad():
        model(**_dit_inputs(2, frames, width, height, "meta", torch.float32))
    step = fc.get_total_flops()
    with FlopCounterMode(display=False) as fc, torch.no_grad():
        model.crossattn_proj(torch.zeros(1, 512, 100352, device="meta"))
    text = fc.get_total_flops()
    with FlopCounterMode(display=False) as fc, torch.no_grad():
        z = vae.encode(torch.zeros(1, 3, frames, height, width, device="meta")).latent_dist.mode()
    encode = fc.get_total_flops()
    with FlopCounterMode(display=False) as fc, torch.no_grad():
        vae.encode(torch.zeros(1, 3, 1, height, width, device="meta"))
    encode_seed = fc.get_total_flops()
    with FlopCounterMode(display=False) as fc, torch.no_grad():
        vae.decode(z)
    decode = fc.get_total_flops()
    chunk = steps * step + text + encode + encode_seed + decode
    new_frames = frames - 1  # the seed frame of every chunk after the first is the previous chunk's last
    table = []
    for u in UTILISATIONS:
        seconds = chunk / (H100_BF16_TFLOPS * 1e12 * u)
        table.append({"utilisation": u, "seconds_per_chunk": seconds, "frames_per_second": new_frames / seconds})
    from oscar_core.model.presets import SAMPLER_PRESETS
    from oscar_core.model.sampler import apply_preset, model_calls

    presets = {}
    for name in SAMPLER_PRESETS:  # one DiT evaluation of batch 1 is half a guided step
        config = apply_preset(SamplerConfig(guidance=6.0, solver="unipc"), name)
        flops = model_calls(config) * step / 2 + text + encode + encode_seed + decode
        presets[name] = {
            "steps": config.steps,
            "dit_evaluations": model_calls(config),
            "tflop_per_chunk": flops / 1e12,
            "h100_frames_per_s": {str(u): new_frames * H100_BF16_TFLOPS * 1e12 * u / flops for u in UTILISATIONS},
        }
    return {
        "steps": steps,
        "frames": frames,
        "size": f"{width}x{height}",
        "tflop_per_guided_step": step / 1e12,
        "tflop_text_projection": text / 1e12,
        "tflop_vae_encode_chunk": encode / 1e12,
        "tflop_vae_encode_seed": encode_seed / 1e12,
        "tflop_vae_decode_chunk": decode / 1e12,
        "tflop_per_chunk": chunk / 1e12,
        "new_frames_per_chunk": new_frames,
        "h100_bf16_tflops": H100_BF16_TFLOPS,
        "h100": table,
        "paper_fps_gh200": PAPER_FPS_GH200,
        "paper_fps_implied_utilisation": PAPER_FPS_GH200 * chunk / new_frames / (H100_BF16_TFLOPS * 1e12),
        "presets": presets,
    }


#: dense bf16 tensor-core peak (TFLOP/s) by device name, first match wins; ``--peak-tflops`` overrides
PEAK_BF16_TFLOPS = (("GH200", 989.4), ("H200", 989.4), ("H100 PCIe", 756.5), ("H100", 989.4), ("A100", 312.0))
MEASURE_SIZES = {"2b": (81, 512, 288), "tiny": (9, 128, 64)}  # frames per chunk, width, height


def peak_tflops_of(device_name: str) -> float | None:
    """The dense bf16 peak of a GPU named ``device_name`` (e.g. "NVIDIA H200"), None when unknown."""
    for key, tflops in PEAK_BF16_TFLOPS:
        if key in device_name:
            return tflops
    return None


def count_flops(fn) -> int:
    """FLOPs of one call of ``fn`` as ``torch.utils.flop_counter`` counts the operators it runs."""
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter, torch.no_grad():
        fn()
    return counter.get_total_flops()


def build_measured(size: str, device: torch.device, dtype: torch.dtype):
    """(transformer, VideoVAE) with random weights: the 2B (WAN 2.1 VAE) or the tiny test configuration."""
    from oscar_core.model.tiny import build_random_2b
    from oscar_core.model.vae import VideoVAE

    if size == "2b":
        transformer, vae = build_random_2b(device, dtype)  # initialised on the device in dtype: no host detour
    else:
        transformer = build_tiny_transformer(seed=0, skeleton_scale=0.05).to(device).eval()
        if dtype != torch.float32:
            transformer = transformer.to(dtype)
        vae = build_tiny_vae(seed=0).to(device)
    return transformer, VideoVAE(vae, device=device, dtype=dtype)


def check_measure_args(args) -> None:
    """Refuse a ``--measure`` setting this machine cannot run, before any work (SystemExit naming it)."""
    from oscar_core.model.presets import SAMPLER_PRESETS

    if args.presets is not None:
        unknown = [p for p in args.presets.split(",") if p not in SAMPLER_PRESETS]
        if unknown or not args.presets:
            raise SystemExit(
                f"--presets: expected comma-separated names from {sorted(SAMPLER_PRESETS)}, found {args.presets!r}"
            )
    if args.peak_tflops is not None and not args.peak_tflops > 0:
        raise SystemExit(f"--peak-tflops: expected a positive number, found {args.peak_tflops}")
    if not args.measure:
        return
    try:
        device = torch.device(args.measure)
    except RuntimeError as exc:
        raise SystemExit(
            f"--measure: expected a torch device (cuda, cuda:1, cpu), found {args.measure!r}: {exc}"
        ) from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise SystemExit(
            f"--gpu / --measure {args.measure} needs a CUDA device (torch.cuda.is_available() is False here)"
        )
    if device.type not in ("cuda", "cpu"):
        raise SystemExit(f"--measure: expected a cuda or cpu device, found {args.measure!r}")


def measure_real(args, checkpoint=lambda out: None) -> dict:
    """Measured: seconds per denoising step and per chunk, frames/s and MFU of every sampling preset.

    The model has random weights (speed does not depend on them). Per variant (eager; compiled through
    ``oscar_core.model.compile_policy`` as ``oscar rollout`` compiles): one guided step (both branches, batch
    2) and one conditional-only step (batch 1); per preset a whole chunk (seed and condition encodes,
    the preset's UniPC steps at w = 6, decode). FLOPs are counted once per preset on the eager model
    (``torch.utils.flop_counter``); MFU = counted FLOPs / (seconds x the device's dense bf16 peak).

    ``checkpoint(out)`` is called with the results so far after the FLOP counts and the VAE's chunk work, after
    each preset's row and after the VAE variants (measured last), so a run stopped by a time limit keeps what it
    measured.
    """
    from oscar_core.model.compile_policy import compile_transformer
    from oscar_core.model.presets import SAMPLER_PRESETS
    from oscar_core.model.sampler import apply_preset, model_calls, sample_chunk

    check_measure_args(args)
    device = torch.device(args.measure)
    dtype = torch.bfloat16 if device.type == "cuda" else torch.float32
    transformer, vae = build_measured(args.measure_size, device, dtype)
    frames, width, height = MEASURE_SIZES[args.measure_size]
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor() or "cpu"
    peak = args.peak_tflops if args.peak_tflops is not None else peak_tflops_of(name) if device.type == "cuda" else None
    presets = args.presets.split(",") if args.presets else sorted(SAMPLER_PRESETS, key=lambda n: n != "paper")

    rng = np.random.default_rng(0)
    first = vae.to_pixels(rng.integers(0, 256, (1, height, width, 3), dtype=np.uint8))
    condition = vae.to_pixels(rng.integers(0, 256, (frames, height, width, 3), dtype=np.uint8))
    text = torch.zeros(1, 512, transformer.text_dim)
    t, h, w = (frames - 1) // vae.temporal + 1, height // vae.spatial, width // vae.spatial
    g = torch.Generator().manual_seed(0)
    x = torch.randn(1, vae.z_dim, t, h, w, generator=g).to(device)
    skeleton = torch.randn(1, vae.z_dim, t, h, w, generator=g).to(device)
    mask = torch.zeros(1, 1, t, h, w, device=device)
    mask[:, :, 0] = 1
    timestep = torch.full((1, 1, t, 1, 1), 0.5, device=device)
    with torch.no_grad():
        projected = transformer.project_text(text).to(device)
    base = SamplerConfig(steps=35, guidance=6.0, solver="unipc")
    configs = {p: apply_preset(base, p) for p in presets}

    def step_fn(config):
        def step():
            with torch.no_grad():
                guided_velocity(transformer, x, timestep, projected, skeleton, mask, None, config, text_projected=True)

        return step

    steps = {"guided": step_fn(SamplerConfig(guidance=6.0)), "conditional": step_fn(SamplerConfig(guidance=None))}

    vae_work = vae_chunk_work(vae, first, condition)

    def sync():
        if device.type == "cuda":
            torch.cuda.synchronize()

    def chunk_fn(config, parts: dict | None = None):
        """One chunk; with ``parts``, the seconds of its encodes, sampling and decode are added to it."""

        def chunk():
            marks = [time.perf_counter()]
            with torch.no_grad():
                seed, cond = vae.encode(first), vae.encode(condition)
                sync()
                marks.append(time.perf_counter())
                latent = sample_chunk(transformer, seed, cond, text, config, generator=torch.Generator().manual_seed(0))
                sync()
                marks.append(time.perf_counter())
                vae.decode(latent)
                sync()
                marks.append(time.perf_counter())
            if parts is not None:
                for key, a, b in zip(("encode", "sample", "decode"), marks, marks[1:]):
                    parts.setdefault(key, []).append(b - a)

        return chunk

    out = {
        "device": name,
        "dtype": str(dtype).replace("torch.", ""),
        "size": args.measure_size,
        "frames": frames,
        "width": width,
        "height": height,
        "latent_tokens": t * (h // 2) * (w // 2),
        "guidance": 6.0,
        "peak_tflops": peak,
        "flops": {},
        "vae": {},
        "steps": {},
        "presets": [],
    }
    out["flops"]["step_" + "guided"] = count_flops(steps["guided"])
    out["flops"]["step_conditional"] = count_flops(steps["conditional"])
    out["flops"]["vae_per_chunk"] = count_flops(vae_work)
    out["flops"]["text_projection"] = count_flops(lambda: transformer.project_text(text))
    for p in presets:
        out["flops"][f"chunk_{p}"] = count_flops(chunk_fn(configs[p]))
    out["vae"] = measure(vae_work, args.repeats, device)
    checkpoint(out)
    variants = ["eager"] + (["compiled"] if args.compile else [])
    for variant in variants:
        if variant == "compiled":
            t0 = time.perf_counter()
            out["compiled"] = compile_transformer(transformer)
            steps["guided"]()  # the compile itself (cold or warm cache, whichever this machine has)
            if device.type == "cuda":
                torch.cuda.synchronize()
            out["compile_first_call_s"] = time.perf_counter() - t0
        for kind, fn in steps.items():
            out["steps"][f"{kind}_{variant}"] = measure(fn, args.repeats, device)
        for p in presets:
            config = configs[p]
            parts: dict[str, list[float]] = {}
            chunk_fn(config)()  # warm-up (and, compiled, any recompile for this preset's batch sizes)
            chunk = measure(chunk_fn(config, parts), max(1, args.repeats // 2), device, warmup=False)
            chunk_s = chunk["median_ms"] / 1e3
            part_s = {key: statistics.median(v) for key, v in parts.items()}  # the same runs, split
            sample_s = part_s["sample"]
            dit_flops = out["flops"][f"chunk_{p}"] - out["flops"]["vae_per_chunk"]  # + the text projection, once
            row = {
                "preset": p,
                "variant": variant,
                "steps": config.steps,
                "guidance_interval": list(config.guidance_interval) if config.guidance_interval else None,
                "dit_evaluations": model_calls(config),
                "tflop_per_chunk": out["flops"][f"chunk_{p}"] / 1e12,
                "chunk": chunk,
                "seconds_per_chunk": chunk_s,
                "seconds_parts": part_s,
                "seconds_per_step": sample_s / config.steps,
                "vae_share": (part_s["encode"] + part_s["decode"]) / sum(part_s.values()),
                "frames_per_s": (frames - 1) / chunk_s,
                "mfu_sampling": dit_flops / (sample_s * peak * 1e12) if peak else None,
                "mfu_chunk": out["flops"][f"chunk_{p}"] / (chunk_s * peak * 1e12) if peak else None,
            }
            out["presets"].append(row)
            checkpoint(out)
    if args.vae_variants:  # after the DiT's rows: a run stopped by a time limit keeps those first
        out["vae_variants"] = measure_vae_variants(vae, first, condition, args.repeats, device)
        checkpoint(out)
    return out


VAE_VARIANTS = ("eager", "channels_last", "tiling", "compiled")


def _set_conv_format(module: torch.nn.Module, memory_format) -> None:
    """Every 5-D parameter of ``module`` in ``memory_format`` (values unchanged)."""
    for param in module.parameters():
        if param.ndim == 5:
            param.data = param.data.contiguous(memory_format=memory_format)


def vae_chunk_work(vae, first: torch.Tensor, condition: torch.Tensor):
    """What a chunk asks of the VAE, as a call: the seed frame's and the condition video's encodes, then one
    decode of a chunk's latent; the call returns the decoded pixels (B, 3, T, H, W)."""

    def work() -> torch.Tensor:
        with torch.no_grad():
            vae.encode(first)
            return vae.decode(vae.encode(condition))

    return work


def measure_vae_variants(vae, first: torch.Tensor, condition: torch.Tensor, repeats: int, device) -> list[dict]:
    """The VAE's work per chunk (seed and condition encodes, one decode) under each of :data:`VAE_VARIANTS`.

    channels_last: 5-D convolutions in ``torch.channels_last_3d``; tiling: the VAE's spatial tiling (engages
    only above its 256-pixel tile); compiled: ``torch.compile`` of the encoder and decoder modules. Each row
    gives seconds, its share against eager, and how far its decoded frames are from eager's (max |difference|
    in [-1, 1] pixels and PSNR in dB; None when equal). A variant that fails is a row with its reason. The VAE
    is put back as it was after each variant.
    """
    module = vae.vae
    work = vae_chunk_work(vae, first, condition)
    reference = work().float().cpu()
    rows = []
    for name in VAE_VARIANTS:
        saved = (module.encoder, module.decoder)
        try:
            if name == "channels_last":  # the 5-D convolution weights (Module.to would refuse the 1-D biases)
                _set_conv_format(module, torch.channels_last_3d)
            elif name == "tiling":
                module.enable_tiling()
            elif name == "compiled":
                module.encoder = torch.compile(module.encoder, dynamic=False)
                module.decoder = torch.compile(module.decoder, dynamic=False)
            t0 = time.perf_counter()
            decoded = work().float().cpu()  # warm-up; for compiled, the compile itself
            first_s = time.perf_counter() - t0
            timing = measure(work, repeats, device, warmup=False)
            diff = float((decoded - reference).abs().max())
            mse = float(((decoded - reference) ** 2).mean())
            rows.append(
                {
                    "variant": name,
                    "seconds": timing["median_ms"] / 1e3,
                    "first_call_s": first_s,
                    "peak_mib": timing["peak_mib"],
                    "max_abs_diff": diff,
                    "psnr_db_vs_eager": None if mse == 0 else 10 * np.log10(4.0 / mse),
                }
            )  # range 2: peak² = 4
        except Exception as exc:  # noqa: BLE001 - a variant this machine cannot run is a row saying why
            rows.append({"variant": name, "failed": f"{type(exc).__name__}: {str(exc).strip()[:300]}"})
        finally:
            module.encoder, module.decoder = saved
            _set_conv_format(module, torch.contiguous_format)
            module.disable_tiling()
    eager = rows[0].get("seconds")
    for row in rows:
        row["vs_eager"] = row["seconds"] / eager if eager and "seconds" in row else None
    return rows


def print_measured(m: dict) -> None:
    peak = f"{m['peak_tflops']:g} TFLOP/s dense bf16 peak" if m["peak_tflops"] else "no known peak: MFU not given"
    print(
        f"\nMeasured on {m['device']} ({m['dtype']}, random weights, {m['size']}: {m['frames']}-frame "
        f"{m['width']}x{m['height']} chunk, w = {m['guidance']:g}; {peak}):"
    )
    for key, value in m["steps"].items():
        print(
            f"  one {key.replace('_', ' step, ')}: median {value['median_ms'] / 1e3:.4f} s, "
            f"peak {value['peak_mib'] / 1024:.2f} GiB"
        )
    print(f"  VAE per chunk (2 encodes + decode): median {m['vae']['median_ms'] / 1e3:.3f} s")
    for row in m.get("vae_variants") or ():
        if "failed" in row:
            print(f"  VAE {row['variant']}: failed ({row['failed']})")
        else:
            psnr = "identical" if row["psnr_db_vs_eager"] is None else f"{row['psnr_db_vs_eager']:.1f} dB vs eager"
            print(
                f"  VAE {row['variant']}: {row['seconds']:.3f} s ({row['vs_eager']:.2f}x eager; first call "
                f"{row['first_call_s']:.1f} s; max |diff| {row['max_abs_diff']:.2e}, {psnr})"
            )
    if "compile_first_call_s" in m:
        print(f"  compile (first compiled call): {m['compile_first_call_s']:.1f} s, compiled: {m['compiled']}")
    head = (
        "preset",
        "variant",
        "steps",
        "DiT evals",
        "TFLOP/chunk",
        "s/step",
        "s/chunk",
        "VAE share",
        "frames/s",
        "MFU sampling",
        "MFU chunk",
    )
    lines = [head]
    for r in m["presets"]:
        mfu = [f"{v:.1%}" if v is not None else "-" for v in (r["mfu_sampling"], r["mfu_chunk"])]
        lines.append(
            (
                r["preset"],
                r["variant"],
                str(r["steps"]),
                str(r["dit_evaluations"]),
                f"{r['tflop_per_chunk']:.4g}",
                f"{r['seconds_per_step']:.4f}",
                f"{r['seconds_per_chunk']:.3f}",
                f"{r['vae_share']:.1%}",
                f"{r['frames_per_s']:.2f}",
                *mfu,
            )
        )
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    for line in lines:
        print("  " + "  ".join(c.rjust(wd) for c, wd in zip(line, widths)))


def expected_2b() -> dict:
    """Figures implied by the 2B configuration (meta device: no memory, no download)."""
    with torch.device("meta"):
        model = OscarTransformer3DModel(**COSMOS_2B_TRANSFORMER_CONFIG)
    total = sum(p.numel() for p in model.parameters())
    blocks = sum(p.numel() for p in model.transformer_blocks.parameters())
    text_proj = sum(p.numel() for p in model.crossattn_proj.parameters())
    pe_s = model.skeleton_embed.proj.weight.numel()
    cfg = model.config
    p_t, p_h, p_w = cfg.patch_size

    def tokens(frames, width, height):
        return ((frames - 1) // 4 + 1) // p_t * (height // 8 // p_h) * (width // 8 // p_w)

    return {
        "config": {
            k: COSMOS_2B_TRANSFORMER_CONFIG[k]
            for k in (
                "num_layers",
                "num_attention_heads",
                "attention_head_dim",
                "in_channels",
                "crossattn_proj_in_channels",
            )
        },
        "parameters": total,
        "parameters_blocks": blocks,
        "parameters_text_projection": text_proj,
        "parameters_pe_s": pe_s,
        "weights_bf16_gib": total * 2 / 2**30,
        "latent_tokens_per_chunk": {
            "81 frames 512x288 (paper)": tokens(81, 512, 288),
            "93 frames 1280x704 (Cosmos default)": tokens(93, 1280, 704),
        },
        "text_tokens": 512,
    }


# --------------------------------------------------------------------------- report


def print_table(rows: list[dict]) -> None:
    head = (
        "size",
        "chunk",
        "tokens",
        "step batched",
        "step 2-pass",
        "ratio",
        "peak b/2p MiB",
        "rollout batched",
        "rollout 2-pass",
        "ratio",
    )
    lines = [head]
    for r in rows:
        sb, s2, rb, r2 = r["step_batched"], r["step_two-pass"], r["rollout_batched"], r["rollout_two-pass"]
        lines.append(
            (
                r["size"],
                str(r["chunk_frames"]),
                str(r["latent_tokens"]),
                f"{sb['median_ms']:.1f} ms",
                f"{s2['median_ms']:.1f} ms",
                f"{s2['median_ms'] / sb['median_ms']:.2f}x",
                f"{sb['peak_mib']:.1f}/{s2['peak_mib']:.1f}",
                f"{rb['median_ms'] / 1e3:.2f} s",
                f"{r2['median_ms'] / 1e3:.2f} s",
                f"{r2['median_ms'] / rb['median_ms']:.2f}x",
            )
        )
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    for line in lines:
        print("  ".join(c.rjust(w) for c, w in zip(line, widths)))


def print_computed(big: dict, comp: dict) -> None:
    print(
        f"\n2B model (from its config): {big['parameters'] / 1e9:.3f} B parameters "
        f"({big['parameters_blocks'] / 1e9:.3f} B in the 28 blocks, {big['parameters_text_projection'] / 1e6:.1f} M "
        f"text projection, {big['parameters_pe_s']:,} PE_s), {big['weights_bf16_gib']:.2f} GiB of bf16 weights"
    )
    for what, n in big["latent_tokens_per_chunk"].items():
        print(f"  latent tokens per chunk, {what}: {n:,} (x2 with batched guidance)")
    print(
        f"\nComputed (FLOPs counted on the meta device, not measured): one guided step (batch 2, "
        f"{big['latent_tokens_per_chunk']['81 frames 512x288 (paper)']:,} tokens each) = "
        f"{comp['tflop_per_guided_step']:.1f} TFLOP; an 81-frame 512x288 chunk with {comp['steps']} steps = "
        f"{comp['tflop_per_chunk']:.0f} TFLOP (VAE encode {comp['tflop_vae_encode_chunk']:.1f} + decode "
        f"{comp['tflop_vae_decode_chunk']:.1f}, text projection {comp['tflop_text_projection']:.2f})"
    )
    print(f"  one H100 ({H100_BF16_TFLOPS:g} TFLOP/s dense bf16), {comp['new_frames_per_chunk']} new frames per chunk:")
    print("  utilisation  s/chunk  frames/s")
    for row in comp["h100"]:
        print(f"  {row['utilisation']:>10.0%}  {row['seconds_per_chunk']:7.2f}  {row['frames_per_second']:8.2f}")
    print(
        f"  paper: {PAPER_FPS_GH200} frames/s on a GH200 = {comp['paper_fps_implied_utilisation']:.1%} utilisation "
        f"at these FLOPs"
    )
    print("  per sampling preset (w = 6), frames/s on one H100 at each utilisation:")
    print("  preset  steps  DiT evals  TFLOP/chunk  " + "  ".join(f"{float(u):>5.0%}" for u in UTILISATIONS))
    for name, row in comp["presets"].items():
        fps = "  ".join(f"{v:5.1f}" for v in row["h100_frames_per_s"].values())
        print(f"  {name:>6}  {row['steps']:5d}  {row['dit_evaluations']:9d}  {row['tflop_per_chunk']:11.0f}  {fps}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--steps", type=int, default=4, help="denoising steps per chunk in the rollout timing")
    p.add_argument("--device", default="cpu")
    p.add_argument(
        "--gpu",
        action="store_true",
        help="measure the real 2B size on CUDA (random weights, bf16): the same as --measure cuda --measure-size 2b",
    )
    p.add_argument(
        "--measure",
        metavar="DEVICE",
        help="measure steps, chunks, frames/s and MFU of every sampling preset on DEVICE (cuda: bf16; cpu: float32)",
    )
    p.add_argument(
        "--measure-size",
        choices=sorted(MEASURE_SIZES),
        default="2b",
        help="model size measured by --measure (tiny: the test configuration)",
    )
    p.add_argument("--presets", help="comma-separated sampling presets to measure (default: all)")
    p.add_argument("--peak-tflops", type=float, help="the device's peak for MFU (default: known GPUs' dense bf16)")
    p.add_argument("--gpu-steps", type=int, default=35, help="UniPC steps per chunk in the computed table")
    p.add_argument("--compile", action="store_true", help="--measure: also time the compiled DiT")
    p.add_argument(
        "--vae-variants",
        action="store_true",
        help="--measure: also time the VAE's work per chunk "
        "with channels-last, tiling and torch.compile against eager (and how far each output moves)",
    )
    p.add_argument("--skip-computed", action="store_true", help="skip the 2B figures computed from its configuration")
    p.add_argument("--skip-tiny", action="store_true", help="skip the tiny CPU timings")
    p.add_argument("--json", default=str(Path(__file__).parent / "results" / "rollout.json"))
    args = p.parse_args(argv)
    if args.gpu:
        args.measure, args.measure_size = "cuda", "2b"
    check_measure_args(args)  # before any work
    device = torch.device(args.device)
    rows = []
    if not args.skip_tiny:
        model = OscarWorldModel.from_modules(
            build_tiny_transformer(seed=0, skeleton_scale=0.05),
            build_tiny_vae(seed=0),
            ModelCard(name="tiny", chunk_frames=9),
            device=device,
        )
        params = sum(q.numel() for q in model.transformer.parameters())
        print(
            f"tiny DiT: {params / 1e3:.0f} k parameters; torch {torch.__version__}, {torch.get_num_threads()} "
            f"threads, {device}; rollout = 2 chunks x {args.steps} steps, guidance w = 6"
        )
        for width, height in SIZES:
            for chunk in CHUNKS:
                rows.append(bench_case(model, width, height, chunk, args, device))
                print(f"  done {width}x{height}, {chunk} frames", file=sys.stderr)
        print_table(rows)
    big = comp = None
    if not args.skip_computed:
        big, comp = expected_2b(), computed_2b(args.gpu_steps)
        print_computed(big, comp)
    from _provenance import with_provenance

    from oscar_core._util.atomic import atomic_write_bytes

    def write(measured, complete: bool) -> Path:
        result = json.dumps(
            with_provenance(
                {
                    "machine": {
                        "python": platform.python_version(),
                        "torch": torch.__version__,
                        "threads": torch.get_num_threads(),
                        "cpu_count": os.cpu_count(),
                        "device": str(device),
                    },
                    "settings": {"repeats": args.repeats, "steps": args.steps, "guidance": 6.0},
                    "complete": complete,
                    "tiny": rows,
                    "expected_2b": big,
                    "computed_2b": comp,
                    "measured": measured,
                },
                device=str(device),
            ),
            indent=2,
        )
        return atomic_write_bytes(args.json, (result + chr(10)).encode())

    measured = None
    if args.measure:
        measured = measure_real(args, checkpoint=lambda partial: write(partial, complete=False))
        print_measured(measured)
    print(f"wrote {write(measured, complete=True)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
