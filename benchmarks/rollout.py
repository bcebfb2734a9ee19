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
import threading
import time
from pathlib import Path

if __name__ == "__main__" and "MALLOC_MMAP_THRESHOLD_" not in os.environ:
    os.environ["MALLOC_MMAP_THRESHOLD_"] = "65536"
    os.environ["MALLOC_TRIM_THRESHOLD_"] = "0"
    os.execv(sys.executable, [sys.executable, *sys.argv])

import numpy as np  # noqa: E402
import torch  # noqa: E402

from oscar_core.model import ModelCard, OscarTransformer3DModel, OscarWorldModel, SamplerConfig  # noqa: E402
from oscar_core.model.sampler import guided_velocity  # noqa: E402
from oscar_core.model.tiny import COSMOS_2B_TRANSFORMER_CONFIG, build_tiny_transformer, build_tiny_vae  # noqa: E402

SIZES = ((128, 64), (256, 128))  # width x height in pixels
CHUNKS = (9, 17)  # frames per chunk (4k+1)
PATHS = (("batched", True), ("two-pass", False))


# --------------------------------------------------------------------------- measuring


def _rss() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


class PeakMemory:
    """Peak memory (bytes) above the starting level while the block runs."""

    def __init__(self, device: torch.device):
        self.device, self.peak, self._stop = device, 0, threading.Event()

    def __enter__(self):
        if self.device.type == "cuda":
            torch.cuda.synchronize()
            torch.cuda.reset_peak_memory_stats()
            self.base = torch.cuda.memory_allocated()
        else:
            self.base = self.peak_abs = _rss()
            self._thread = threading.Thread(target=self._sample, daemon=True)
            self._thread.start()
        return self

    def _sample(self):
        while not self._stop.is_set():
            self.peak_abs = max(self.peak_abs, _rss())
            time.sleep(0.001)

    def __exit__(self, *exc):
        if self.device.type == "cuda":
            torch.cuda.synchronize()
            self.peak = torch.cuda.max_memory_allocated() - self.base
        else:
            self._stop.set()
            self._thread.join()
            self.peak = max(self.peak_abs, _rss()) - self.base


def measure(fn, repeats: int, device: torch.device) -> dict:
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
    return {"median_ms": 1e3 * statistics.median(times), "best_ms": 1e3 * min(times),
            "peak_mib": max(peaks) / 2**20}


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
            model.rollout(first, skeleton, text, chunk_frames=chunk, sampler=config, seed=0, progress=False,
                          keep_chunks=False)

        row[f"step_{name}"] = measure(step, args.repeats, device)
        row[f"rollout_{name}"] = measure(roll, max(1, args.repeats // 2), device)
    row["rollout_frames"] = len(skeleton)
    return row


H100_BF16_TFLOPS = 989.4  # NVIDIA H100 SXM dense bf16 (the GH200's GPU has the same tensor-core peak)
PAPER_FPS_GH200 = 2.214  # the paper's reported rollout speed
UTILISATIONS = (0.2, 0.3, 0.4, 0.5, 1.0)


def _dit_inputs(batch, frames, width, height, device, dtype):
    t, h, w = (frames - 1) // 4 + 1, height // 8, width // 8
    return dict(hidden_states=torch.zeros(batch, 16, t, h, w, device=device, dtype=dtype),
                timestep=torch.full((batch, 1, t, 1, 1), 0.5, device=device),
                encoder_hidden_states=torch.zeros(batch, 512, 1024, device=device, dtype=dtype),
                condition_mask=torch.zeros(batch, 1, t, h, w, device=device, dtype=dtype), padding_mask=None,
                skeleton_latents=torch.zeros(batch, 16, t, h, w, device=device, dtype=dtype), return_dict=False,
                text_projected=True)


def computed_2b(steps: int = 35, frames: int = 81, width: int = 512, height: int = 288) -> dict:
    """FLOPs of one guided step and one chunk of the 2B model, counted on the meta device (no memory used)."""
    from diffusers import AutoencoderKLWan
    from torch.utils.flop_counter import FlopCounterMode

    with torch.device("meta"):
        model = OscarTransformer3DModel(**COSMOS_2B_TRANSFORMER_CONFIG)
        vae = AutoencoderKLWan()  # diffusers' defaults are the WAN 2.1 VAE's configuration
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
    return {"steps": steps, "frames": frames, "size": f"{width}x{height}", "tflop_per_guided_step": step / 1e12,
            "tflop_text_projection": text / 1e12, "tflop_vae_encode_chunk": encode / 1e12,
            "tflop_vae_encode_seed": encode_seed / 1e12, "tflop_vae_decode_chunk": decode / 1e12,
            "tflop_per_chunk": chunk / 1e12, "new_frames_per_chunk": new_frames,
            "h100_bf16_tflops": H100_BF16_TFLOPS, "h100": table, "paper_fps_gh200": PAPER_FPS_GH200,
            "paper_fps_implied_utilisation": PAPER_FPS_GH200 * chunk / new_frames / (H100_BF16_TFLOPS * 1e12)}


def gpu_2b(args) -> dict:
    """Measured on CUDA: the real-size DiT and VAE with random weights in bf16."""
    from diffusers import AutoencoderKLWan

    from oscar_core.model.sampler import sample_chunk
    from oscar_core.model.vae import VideoVAE

    if not torch.cuda.is_available():
        raise SystemExit("--gpu needs a CUDA device (torch.cuda.is_available() is False here)")
    device, dtype = torch.device("cuda"), torch.bfloat16
    torch.manual_seed(0)
    with device:
        transformer = OscarTransformer3DModel(**COSMOS_2B_TRANSFORMER_CONFIG).to(dtype).eval()
        vae = VideoVAE(AutoencoderKLWan().eval(), device=device, dtype=dtype)
    frames, width, height = 81, 512, 288
    inputs = _dit_inputs(2, frames, width, height, device, dtype)
    text = torch.zeros(1, 512, 100352)
    rng = np.random.default_rng(0)
    first = VideoVAE.to_pixels(rng.integers(0, 256, (1, height, width, 3), dtype=np.uint8))
    skeleton = VideoVAE.to_pixels(rng.integers(0, 256, (frames, height, width, 3), dtype=np.uint8))
    out = {"device": torch.cuda.get_device_name(), "dtype": "bfloat16", "steps": args.gpu_steps}
    latent = torch.randn(1, 16, (frames - 1) // 4 + 1, height // 8, width // 8, device=device)

    def vae_work():  # what a chunk asks of the VAE: seed and skeleton encodes, one decode
        with torch.no_grad():
            vae.encode(first)
            vae.encode(skeleton)
            vae.decode(latent)

    out["vae_per_chunk"] = measure(vae_work, 1, device)
    variants = ["eager"] + (["compiled"] if args.compile else [])
    for name in variants:
        if name == "compiled":  # the library's path: oscar_core.model.compile_policy, as oscar rollout compiles
            from oscar_core.model.compile_policy import compile_transformer

            compile_transformer(transformer)

            def first_call():
                with torch.no_grad():
                    transformer(**inputs)

            t0 = time.perf_counter()
            first_call()  # the compile itself (cold or warm cache, whichever this machine has)
            torch.cuda.synchronize()
            out["compile_first_call_s"] = time.perf_counter() - t0

        def step():
            with torch.no_grad():
                transformer(**inputs)

        def chunk():
            with torch.no_grad():
                latent = sample_chunk(transformer, vae.encode(first),
                                      vae.encode(skeleton), text,
                                      SamplerConfig(steps=args.gpu_steps, guidance=6.0, solver="unipc"))
                vae.decode(latent)

        out[f"step_{name}"] = measure(step, args.repeats, device)
        out[f"chunk_{name}"] = measure(chunk, 1, device)
        out[f"vae_share_{name}"] = out["vae_per_chunk"]["median_ms"] / out[f"chunk_{name}"]["median_ms"]
        out[f"frames_per_s_{name}"] = (frames - 1) / (out[f"chunk_{name}"]["median_ms"] / 1e3)
    return out


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
        "config": {k: COSMOS_2B_TRANSFORMER_CONFIG[k] for k in ("num_layers", "num_attention_heads", "attention_head_dim",
                                                                "in_channels", "crossattn_proj_in_channels")},
        "parameters": total, "parameters_blocks": blocks, "parameters_text_projection": text_proj,
        "parameters_pe_s": pe_s, "weights_bf16_gib": total * 2 / 2**30,
        "latent_tokens_per_chunk": {"81 frames 512x288 (paper)": tokens(81, 512, 288),
                                    "93 frames 1280x704 (Cosmos default)": tokens(93, 1280, 704)},
        "text_tokens": 512,
    }


# --------------------------------------------------------------------------- report


def print_table(rows: list[dict]) -> None:
    head = ("size", "chunk", "tokens", "step batched", "step 2-pass", "ratio", "peak b/2p MiB",
            "rollout batched", "rollout 2-pass", "ratio")
    lines = [head]
    for r in rows:
        sb, s2, rb, r2 = r["step_batched"], r["step_two-pass"], r["rollout_batched"], r["rollout_two-pass"]
        lines.append((r["size"], str(r["chunk_frames"]), str(r["latent_tokens"]),
                      f"{sb['median_ms']:.1f} ms", f"{s2['median_ms']:.1f} ms", f"{s2['median_ms'] / sb['median_ms']:.2f}x",
                      f"{sb['peak_mib']:.1f}/{s2['peak_mib']:.1f}",
                      f"{rb['median_ms'] / 1e3:.2f} s", f"{r2['median_ms'] / 1e3:.2f} s",
                      f"{r2['median_ms'] / rb['median_ms']:.2f}x"))
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    for line in lines:
        print("  ".join(c.rjust(w) for c, w in zip(line, widths)))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--steps", type=int, default=4, help="denoising steps per chunk in the rollout timing")
    p.add_argument("--device", default="cpu")
    p.add_argument("--gpu", action="store_true", help="measure the real 2B size on CUDA (random weights, bf16)")
    p.add_argument("--gpu-steps", type=int, default=35, help="UniPC steps per chunk in --gpu mode and in the "
                   "computed table")
    p.add_argument("--compile", action="store_true", help="--gpu: also time a torch.compile'd DiT")
    p.add_argument("--skip-tiny", action="store_true", help="skip the tiny CPU timings")
    p.add_argument("--json", default=str(Path(__file__).parent / "results" / "rollout.json"))
    args = p.parse_args(argv)
    device = torch.device(args.device)
    model = OscarWorldModel.from_modules(build_tiny_transformer(seed=0, skeleton_scale=0.05), build_tiny_vae(seed=0),
                                         ModelCard(name="tiny", chunk_frames=9), device=device)
    params = sum(q.numel() for q in model.transformer.parameters())
    print(f"tiny DiT: {params / 1e3:.0f} k parameters; torch {torch.__version__}, {torch.get_num_threads()} threads, "
          f"{device}; rollout = 2 chunks x {args.steps} steps, guidance w = 6")
    rows = []
    for width, height in SIZES:
        for chunk in CHUNKS if not args.skip_tiny else ():
            rows.append(bench_case(model, width, height, chunk, args, device))
            print(f"  done {width}x{height}, {chunk} frames", file=sys.stderr)
    if rows:
        print_table(rows)
    big = expected_2b()
    print(f"\n2B model (from its config): {big['parameters'] / 1e9:.3f} B parameters "
          f"({big['parameters_blocks'] / 1e9:.3f} B in the 28 blocks, {big['parameters_text_projection'] / 1e6:.1f} M "
          f"text projection, {big['parameters_pe_s']:,} PE_s), {big['weights_bf16_gib']:.2f} GiB of bf16 weights")
    for what, n in big["latent_tokens_per_chunk"].items():
        print(f"  latent tokens per chunk, {what}: {n:,} (x2 with batched guidance)")
    comp = computed_2b(args.gpu_steps)
    print(f"\nComputed (FLOPs counted on the meta device, not measured): one guided step (batch 2, "
          f"{big['latent_tokens_per_chunk']['81 frames 512x288 (paper)']:,} tokens each) = "
          f"{comp['tflop_per_guided_step']:.1f} TFLOP; an 81-frame 512x288 chunk with {comp['steps']} steps = "
          f"{comp['tflop_per_chunk']:.0f} TFLOP (VAE encode {comp['tflop_vae_encode_chunk']:.1f} + decode "
          f"{comp['tflop_vae_decode_chunk']:.1f}, text projection {comp['tflop_text_projection']:.2f})")
    print(f"  one H100 ({H100_BF16_TFLOPS:g} TFLOP/s dense bf16), {comp['new_frames_per_chunk']} new frames per chunk:")
    print("  utilisation  s/chunk  frames/s")
    for row in comp["h100"]:
        print(f"  {row['utilisation']:>10.0%}  {row['seconds_per_chunk']:7.2f}  {row['frames_per_second']:8.2f}")
    print(f"  paper: {PAPER_FPS_GH200} frames/s on a GH200 = {comp['paper_fps_implied_utilisation']:.1%} utilisation "
          f"at these FLOPs")
    gpu = None
    if args.gpu:
        gpu = gpu_2b(args)
        print(f"\nMeasured on {gpu['device']} (bf16, random weights):")
        for key, value in gpu.items():
            if isinstance(value, dict):
                print(f"  {key}: median {value['median_ms'] / 1e3:.3f} s, best {value['best_ms'] / 1e3:.3f} s, "
                      f"peak {value['peak_mib'] / 1024:.1f} GiB")
            elif key.startswith(("vae_share", "frames_per_s", "compile_first")):
                print(f"  {key}: {value:.3f}")
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": {"python": platform.python_version(), "torch": torch.__version__,
                                           "threads": torch.get_num_threads(), "cpu_count": os.cpu_count(),
                                           "device": str(device)},
                               "settings": {"repeats": args.repeats, "steps": args.steps, "guidance": 6.0},
                               "tiny": rows, "expected_2b": big, "computed_2b": comp, "gpu_2b": gpu},
                              indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
