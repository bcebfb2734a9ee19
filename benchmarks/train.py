"""Training speed (measured, tiny config, CPU) and the 2B recipe's memory (computed).

    python benchmarks/train.py [--steps 20] [--json benchmarks/results/train.json] [--skip-speed]
    python benchmarks/train.py --step-table [--step-size toy|tiny] [--step-repeats 5]      (this CPU)
    python benchmarks/train.py --step-table --step-size 2b --device cuda                   (a GPU user)

Speed — measured on this machine, the tiny config (``oscar_core.model.tiny``)
on a synthetic toy-arm clip set (``oscar_core.train.synthetic``), 32x32, 9-frame
windows, global batch 4, one thread per process:

* 1 process (gradient accumulation 4) against 2 processes under DDP (gloo,
  accumulation 2): the same global batch, so the same training;
* cached latents against the naive way, encoding RGB and rendered skeleton
  with the VAE in the loop (1 process);
* that on-the-fly run again with ``data.workers: 2`` (threads loading the
  next micro-batches while the step runs; the same batches, so the same loss).
  The two on-the-fly runs alternate ``--repeats`` times (0, 2, 0, 2, ...) and
  each row is the median, so that a load change on a shared machine hits both.

Steps/s is taken from the run's ``metrics.jsonl`` over the steps after the
first (which pays for imports and allocation).

Memory — computed, no GPU here: the 2B transformer is built on the meta
device from ``COSMOS_2B_TRANSFORMER_CONFIG`` for its exact parameter count P.
Training state per GPU under FSDP2 (everything sharded over N GPUs): fp32
weights 4P + fp32 gradients 4P + AdamW moments 8P + fp32 EMA 4P = 20P/N
bytes, plus the all-gathered fp32 weights of two blocks (the current one
and the prefetched next), plus what the older table left out: autocast's
cached bf16 copy of every weight (2P) and the foreach AdamW step's fp32
temporary (4P/N; none with ``fused=True``) — all from
``oscar_core.train.memory``, the model ``activation_checkpointing: auto``
decides with. Activations per 81-frame 512x288 clip (21 latent
frames x 18 x 32 tokens after 2x2 patches = 12,096 tokens): the bytes
autograd saves for backward are counted with ``saved_tensors_hooks`` on one
real-width block (hidden 2048, 16 heads) under bf16 autocast for a few
token counts on the CPU, fitted linearly per token (attention runs through
SDPA's flash kernel, which saves O(tokens) — checked: no saved tensor
grows as tokens²) and multiplied to 12,096 tokens and 28 blocks. With
gradient checkpointing each block keeps only its input (the residual
stream, fp32) plus one block's full activations while it is recomputed.

Step table (``--step-table``, measured; only this section runs, JSON in
``benchmarks/results/train_step.json``) — oscar's own training step
(``oscar_core.train.loop``: ``build_transformer`` and ``prepare_for_training``
with the config's policy, ``build_optimizer``, ``step_loss``, backward,
``apply_update``) with one micro-batch of random data of the trainer's shapes
(clean and skeleton latents of a window, a text embedding), for
``activation_checkpointing`` none / full x ``model.compile`` false / true.
Sizes: ``tiny`` (configs/train/tiny-cpu.yaml: the test), ``toy``
(configs/train/toyworld.yaml: oscar-toy's model, 17 frames 64x64, micro-batch
8), ``2b`` (configs/train/oscar-2b.yaml: Cosmos-Predict2.5-2B, 81 frames
512x288, bf16 autocast; CUDA only). Each variant runs in a fresh process (a
clean memory level, glibc told to return freed memory; a cold, private
inductor cache) and reports: the first step's time (with the compile when
compiled: its extra time is the compile cost), then median and best wall
time and CPU seconds of ``--step-repeats`` steps after ``--step-warmup``;
peak memory above the level before the variant (CUDA:
``torch.cuda.max_memory_allocated``; CPU: the peak resident size sampled by
a thread, ``benchmarks/_peak_memory.py``) and the peak during the timed
steps above the state kept between them, each beside what
``oscar_core.train.memory`` computes; for the eager variants the bytes
autograd saves in one forward (a count). The variants' first-step losses,
gradient norms and per-parameter gradient norms must agree with the first
variant's (relative 1e-4 in float32, 5e-2 under bf16): if not, the JSON is
written and the script exits 1 naming the variants.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
GIB = 1024**3


# --------------------------------------------------------------------------- speed
def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _speed_run(work: Path, name: str, clips: Path, steps: int, nproc: int, size: int = 32, workers: int = 0) -> dict:
    import yaml

    cfg = {
        "run_dir": str(work / name),
        "steps": steps,
        "batch_size": 4,
        "micro_batch": 1,
        "save_every": steps,
        "log_every": 1,
        "export": False,
        "model": {"transformer": "tiny", "vae": "tiny"},
        "data": {"clips": [str(clips)], "window": 9, "width": size, "height": size, "workers": workers},
        "optim": {"lr": 1e-3, "warmup_steps": 0, "grad_clip": 1.0},
    }
    path = work / f"{name}.yaml"
    path.write_text(yaml.safe_dump(cfg))
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    if nproc == 1:
        cmd = [sys.executable, "-m", "oscar_core.train", str(path), "--no-progress"]
    else:
        cmd = [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--nproc-per-node",
            str(nproc),
            "--master-addr",
            "127.0.0.1",
            "--master-port",
            str(_port()),
            "-m",
            "oscar_core.train",
            str(path),
            "--no-progress",
        ]
    t0 = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if out.returncode:
        raise RuntimeError(f"{name}: training failed:\n{out.stderr[-2000:]}")
    rows = [json.loads(l) for l in (work / name / "metrics.jsonl").read_text().splitlines()]
    rows = [r for r in rows if "loss" in r]
    first, last = rows[0], rows[-1]
    rate = (last["step"] - first["step"]) / (last["elapsed_s"] - first["elapsed_s"])
    return {
        "run": name,
        "processes": nproc,
        "workers": workers,
        "steps": steps,
        "steps_per_s": rate,
        "wall_s": wall,
        "final_loss": last["loss"],
    }


def speed(steps: int, repeats: int = 3) -> list[dict]:
    from oscar_core.train.synthetic import write_toy_clipset

    work = Path(tempfile.mkdtemp(prefix="oscar-train-bench-"))
    cached = write_toy_clipset(
        work / "cached", clips=4, frames=13, width=32, height=32, latents_vae="random", latents_window=9, prompt_dim=48
    )
    raw = write_toy_clipset(work / "raw", clips=4, frames=13, width=32, height=32, prompt_dim=48)
    rows = [_speed_run(work, "cached-1proc", cached, steps, 1), _speed_run(work, "cached-2proc-ddp", cached, steps, 2)]
    pair: dict[int, list[dict]] = {0: [], 2: []}
    for r in range(repeats):
        for workers in (0, 2):
            name = "on-the-fly-1proc" if workers == 0 else "on-the-fly-2workers"
            pair[workers].append(_speed_run(work, f"{name}-{r}", raw, steps, 1, workers=workers))
    for workers, runs in pair.items():
        runs = sorted(runs, key=lambda x: x["steps_per_s"])
        row = dict(runs[len(runs) // 2])
        row["run"] = "on-the-fly-1proc" if workers == 0 else "on-the-fly-2workers"
        row["repeats_steps_per_s"] = [x["steps_per_s"] for x in pair[workers]]
        rows.append(row)
    return rows


# --------------------------------------------------------------------------- memory (computed)
def _param_counts() -> tuple[int, int, int]:
    from oscar_core.model.tiny import COSMOS_2B_TRANSFORMER_CONFIG
    from oscar_core.model.transformer import OscarTransformer3DModel

    with torch.device("meta"):
        model = OscarTransformer3DModel(**COSMOS_2B_TRANSFORMER_CONFIG)
    total = sum(p.numel() for p in model.parameters())
    block = sum(p.numel() for p in model.transformer_blocks[0].parameters())
    return total, block, len(model.transformer_blocks)


def _saved_bytes_per_token() -> dict:
    """Autograd-saved bytes of one 2B-width block per token (bf16 autocast, CPU), fitted over token counts."""
    from torch.autograd.graph import saved_tensors_hooks

    from oscar_core.model.tiny import COSMOS_2B_TRANSFORMER_CONFIG
    from oscar_core.model.transformer import OscarTransformer3DModel

    cfg = {**COSMOS_2B_TRANSFORMER_CONFIG, "num_layers": 1, "crossattn_proj_in_channels": 64}
    torch.manual_seed(0)
    model = OscarTransformer3DModel(**cfg)
    block = model.transformer_blocks[0]
    D = 2048
    points, quadratic = [], False
    for frames in (1, 3, 5):
        h, w = 8, 12  # latent pixels -> 4 x 6 = 24 tokens per frame (never the head size 128: shapes stay unambiguous)
        n = frames * (h // 2) * (w // 2)
        x = torch.randn(1, 17, frames, h, w)
        seen: dict[int, int] = {}

        def pack(t):
            if list(t.shape).count(n) >= 2:
                nonlocal quadratic
                quadratic = True
            key = t.untyped_storage().data_ptr()
            seen[key] = max(seen.get(key, 0), t.untyped_storage().nbytes())
            return t

        # the block's inputs exactly as the model builds them
        captured = {}

        def grab(mod, args):
            captured["args"] = args

        hook = block.register_forward_pre_hook(grab)
        with torch.no_grad():
            model(
                hidden_states=x[:, :16],
                timestep=torch.full((1, 1, frames, 1, 1), 0.5),
                encoder_hidden_states=torch.randn(1, 8, 64),
                condition_mask=x[:, 16:],
                return_dict=False,
            )
        hook.remove()
        args = [
            a.detach().requires_grad_(a.is_floating_point()) if isinstance(a, torch.Tensor) else a
            for a in captured["args"]
        ]
        with saved_tensors_hooks(pack, lambda t: t), torch.autocast("cpu", dtype=torch.bfloat16):
            out = block(*args)
        out.float().sum().backward()
        # parameters (and their bf16 casts) are saved too: count them once, separately
        param_bytes = sum(p.numel() * 2 for p in block.parameters())
        points.append((n, sum(seen.values()), param_bytes))
    (n0, b0, _), (n1, b1, _) = points[0], points[-1]
    per_token = (b1 - b0) / (n1 - n0)
    return {
        "per_token_bytes": per_token,
        "hidden": D,
        "points": points,
        "quadratic_saved": quadratic,
        "residual_bytes_per_token": 4 * D,
    }


def memory_table() -> dict:
    """The 2B recipe's memory per GPU from ``oscar_core.train.memory`` (the model ``activation_checkpointing: auto``
    uses), with the activation constant measured again here (a drift check of the library's constant)."""
    from oscar_core.train.memory import (
        ACT_BYTES_PER_TOKEN_PER_WIDTH,
        estimate_memory,
        tokens_per_clip,
    )

    total, block, layers = _param_counts()
    act = _saved_bytes_per_token()
    tokens = tokens_per_clip(81, 512, 288)
    hidden = act["hidden"]
    rows = []
    for n in (1, 2, 4, 8):
        est = estimate_memory(total, block, layers, hidden, tokens, shards=n)
        fused = estimate_memory(total, block, layers, hidden, tokens, shards=n, fused_adamw=True)
        rows.append(
            {
                "gpus": n,
                **{f"{k}_gib": v / GIB for k, v in est.as_dict().items()},
                "total_ckpt_fused_adamw_gib": fused.total("full") / GIB,
                # the older figures, without autocast's weight copies and AdamW's temporaries
                "old_total_ckpt_gib": (est.state + est.gathered + est.activations_full) / GIB,
                "old_total_no_ckpt_gib": (est.state + est.gathered + est.activations_none) / GIB,
            }
        )
    measured = act["per_token_bytes"] / hidden
    return {
        "params": total,
        "block_params": block,
        "layers": layers,
        "tokens_per_clip": tokens,
        "activation_bytes_per_token_per_block": act["per_token_bytes"],
        "library_bytes_per_token_per_width": ACT_BYTES_PER_TOKEN_PER_WIDTH,
        "measured_bytes_per_token_per_width": measured,
        "activations_no_ckpt_gib": rows[0]["activations_none_gib"],
        "activations_ckpt_gib": rows[0]["activations_full_gib"],
        "quadratic_saved_tensor": act["quadratic_saved"],
        "rows": rows,
    }


# --------------------------------------------------------------------------- step table (measured)
#: (activation_checkpointing, model.compile) of the step table, in the order they run; the first is the reference
STEP_VARIANTS = (("none", False), ("full", False), ("none", True), ("full", True))
#: size -> (config under configs/train/, the VAE's spatial compression, prompt tokens L of the text embedding)
STEP_SIZES = {
    "tiny": ("tiny-cpu.yaml", 8, 4),  # oscar_core.model.tiny, 9 frames 32x32 (the tiny VAE: 8x in space)
    "toy": ("toyworld.yaml", 4, 1),  # oscar-toy's recipe, 17 frames 64x64 (the toy VAE: 4x in space; no prompt)
    "2b": ("oscar-2b.yaml", 8, 512),  # Cosmos-Predict2.5-2B, 81 frames 512x288, bf16 autocast, 512 prompt tokens
}
#: first-step loss and gradients of every variant against the reference: largest relative difference allowed
STEP_TOLERANCE = {"float32": 1e-4, "bfloat16": 5e-2}
MIB = 2**20


def variant_name(checkpointing: str, compiled: bool) -> str:
    return f"{checkpointing}{'+compile' if compiled else ''}"


def step_config(size: str, checkpointing: str, compiled: bool):
    """The TrainConfig of one step-table variant: the size's shipped config with random weights, the policy set."""
    from oscar_core.train.config import load_config

    name = STEP_SIZES[size][0]
    # random weights (no model.init) and the checkpointing policy of the variant
    return load_config(
        REPO / "configs" / "train" / name,
        {"model.init": None, "model.compile": compiled, "activation_checkpointing": checkpointing},
    )


def step_batch(config, size: str, text_dim: int):
    """One micro-batch of random data of the trainer's shapes and its plan items (fixed seed, every variant alike).

    z0 and skeleton: (micro_batch, 16, T', H / s, W / s) with T' = (window − 1) / 4 + 1 latent frames and s the
    VAE's spatial factor; text: (micro_batch, L, text_dim); σ and noise seeds as the planner would draw them."""
    from oscar_core.train.data import Batch
    from oscar_core.train.sampling import PlanItem

    _, spatial, text_len = STEP_SIZES[size]
    d, b = config.data, config.micro_batch
    shape = (b, 16, (d.window - 1) // 4 + 1, d.height // spatial, d.width // spatial)
    g = torch.Generator().manual_seed(0)
    batch = Batch(
        z0=torch.randn(shape, generator=g),
        skeleton=torch.randn(shape, generator=g),
        text=torch.randn(b, text_len, text_dim, generator=g),
        actions=None,
    )
    sigmas = torch.rand(b, generator=g, dtype=torch.float64).tolist()
    items = [PlanItem(clip=0, start=0, drop=False, sigma=s, noise_seed=1000 + i) for i, s in enumerate(sigmas)]
    return batch, items


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def _saved_bytes(model, batch, items, config, device, autocast) -> int:
    """Bytes of the distinct non-parameter storages autograd saves for backward in one forward (a count, exact).

    Under ``full`` checkpointing a block's insides are saved by the checkpoint's own hooks, not these: the count is
    what the step keeps besides the checkpointed blocks' inputs."""
    from torch.autograd.graph import saved_tensors_hooks

    from oscar_core.train.loop import step_loss

    params = {p.untyped_storage().data_ptr() for p in model.parameters()}
    seen: dict[int, int] = {}

    def pack(t):
        s = t.untyped_storage()
        if s.data_ptr() not in params:
            seen[s.data_ptr()] = max(seen.get(s.data_ptr(), 0), s.nbytes())
        return t

    with saved_tensors_hooks(pack, lambda t: t):
        loss = step_loss(model, batch, items, config, device, autocast)
    del loss
    return sum(seen.values())


def step_variant(size: str, device: str, checkpointing: str, compiled: bool, warmup: int, repeats: int) -> dict:
    """Build oscar's training step for one variant and measure it (run in a fresh process: see :func:`step_table`).

    The step is the trainer's (``oscar_core.train.loop``) with one micro-batch: zero the gradients,
    ``step_loss`` (rectified-flow MSE), backward, ``apply_update`` (clip, AdamW, EMA). Times in seconds, memory
    in bytes; ``first_*`` is step 0 (with the compile when compiled), then ``warmup`` steps, then ``repeats`` timed.
    """
    import sys as _sys

    _sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _peak_memory import PeakMemory

    from oscar_core.train.loop import (
        apply_update,
        autocast_for,
        build_optimizer,
        step_loss,
    )
    from oscar_core.train.memory import estimate_memory, tokens_per_clip
    from oscar_core.train.models import build_transformer, prepare_for_training

    dev = torch.device(device)
    config = step_config(size, checkpointing, compiled)
    # imports the build and the compile would do lazily, done before the memory window opens (their memory is the
    # process's, not the step's): the model classes, the checkpoint machinery, dynamo and inductor
    import importlib

    for module in (
        "diffusers",
        "torch._dynamo",
        "torch._inductor.compile_fx",
        "torch.utils.checkpoint",
        "oscar_core.model.latent_action",
        "oscar_core.model.transformer",
    ):
        importlib.import_module(module)
    if dev.type != "cuda" and config.model.dtype == "bfloat16":
        raise SystemExit(
            f"--step-size {size}: its config trains under bf16 autocast, which is for CUDA; run it with --device cuda"
        )
    with PeakMemory(dev) as build_and_first:
        model = build_transformer(config)
        chosen, why = prepare_for_training(model, config, dev, compression=(4, STEP_SIZES[size][1]))
        model.to(dev)
        batch, items = step_batch(config, size, model.text_dim)
        optimizer = build_optimizer(model, config)
        ema = {n: p.detach().clone().float() for n, p in model.named_parameters()}
        autocast = autocast_for(config, dev)

        def step(probe: bool = False):
            optimizer.zero_grad(set_to_none=True)
            loss = step_loss(model, batch, items, config, dev, autocast)
            loss.backward()
            norms = [float(p.grad.norm()) for p in model.parameters() if p.grad is not None] if probe else None
            grad_norm = apply_update(model, model, optimizer, ema, config)
            _sync(dev)
            return float(loss.detach()), grad_norm, norms

        t0, c0 = time.perf_counter(), time.process_time()
        loss0, grad_norm0, param_norms = step(probe=True)
        first_s, first_cpu = time.perf_counter() - t0, time.process_time() - c0
        for _ in range(warmup):
            step()
    times, cpus = [], []
    with PeakMemory(dev) as steady:
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            step()
            times.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
    optimizer.zero_grad(set_to_none=True)
    saved = None
    if not compiled:
        try:
            saved = _saved_bytes(model, batch, items, config, dev, autocast)
        except torch.cuda.OutOfMemoryError:  # after the measurement: the row stands without the count
            saved = None
    # the variant's peak: the larger of the two windows, the second shifted by the level it started from
    peak = max(build_and_first.peak, steady.peak + steady.base - build_and_first.base)
    P = sum(p.numel() for p in model.parameters())
    blocks = list(model.transformer_blocks)
    cfg = model.config
    hidden = int(cfg.num_attention_heads) * int(cfg.attention_head_dim)
    z = batch.z0.shape
    tokens = z[2] * (z[3] // cfg.patch_size[1]) * (z[4] // cfg.patch_size[2])
    est = estimate_memory(
        P,
        sum(p.numel() for p in blocks[0].parameters()),
        len(blocks),
        hidden,
        tokens,
        micro_batch=config.micro_batch,
        bf16_autocast=config.model.dtype == "bfloat16",
    )
    d = config.data
    return {
        "variant": variant_name(checkpointing, compiled),
        "activation_checkpointing": chosen,
        "why": why,
        "compile": compiled,
        "dtype": config.model.dtype,
        "device": str(dev),
        "params": P,
        "layers": len(blocks),
        "hidden": hidden,
        "micro_batch": config.micro_batch,
        "latent_shape": list(z),
        "tokens_per_clip": tokens,
        # what oscar_core.train.memory.model_estimate counts for this config and VAE (must equal tokens_per_clip)
        "library_tokens_per_clip": tokens_per_clip(
            d.window, d.width, d.height, tuple(cfg.patch_size), 4, STEP_SIZES[size][1]
        ),
        "first_step_loss": loss0,
        "first_step_grad_norm": grad_norm0,
        "first_step_param_grad_norms": param_norms,
        "first_step_s": first_s,
        "first_step_cpu_s": first_cpu,
        "warmup": warmup,
        "repeats": repeats,
        "step_s": times,
        "step_cpu_s": cpus,
        "median_step_s": statistics.median(times),
        "best_step_s": min(times),
        "median_step_cpu_s": statistics.median(cpus),
        "compile_s": max(first_s - statistics.median(times), 0.0) if compiled else None,
        "peak_bytes": peak,
        "steady_peak_bytes": steady.peak,
        "persistent_bytes": steady.base - build_and_first.base,
        "saved_activation_bytes": saved,
        "modelled": {
            **est.as_dict(),
            "total": est.total(checkpointing),
            # the part of the total a step allocates and frees (all but weights, moments and EMA: 16P)
            "transient": est.total(checkpointing) - 16 * P,
            "activations": est.activations_full if checkpointing == "full" else est.activations_none,
        },
    }


def _compare(rows: list[dict]) -> list[dict]:
    """Each variant's first-step loss, gradient norm and per-parameter gradient norms against the first measured
    row's: relative differences (per-parameter ones relative to the whole gradient's norm). Rows that ran out of
    device memory are left out."""
    rows = [r for r in rows if not r.get("out_of_memory")]
    if not rows:
        return []
    ref = rows[0]
    out = []
    for r in rows:
        loss = abs(r["first_step_loss"] - ref["first_step_loss"]) / abs(ref["first_step_loss"])
        grad = abs(r["first_step_grad_norm"] - ref["first_step_grad_norm"]) / ref["first_step_grad_norm"]
        a, b = r["first_step_param_grad_norms"], ref["first_step_param_grad_norms"]
        if len(a) != len(b):
            per = float("inf")
        else:
            per = max((abs(x - y) for x, y in zip(a, b)), default=0.0) / ref["first_step_grad_norm"]
        out.append(
            {
                "variant": r["variant"],
                "loss_rel_diff": loss,
                "grad_norm_rel_diff": grad,
                "param_grad_norm_max_diff": per,
                "max_diff": max(loss, grad, per),
            }
        )
    return out


def step_table(
    size: str, device: str, variants, warmup: int, repeats: int, tolerance: float | None, checkpoint=None
) -> dict:
    """The four (or the chosen) variants, each in a fresh process of this script, their table and the check.

    A fresh process per variant: its memory starts clean (with glibc told to give freed memory back, see
    ``_peak_memory``), and its compile starts cold (an empty inductor cache of its own). ``checkpoint(table)``,
    if given, is called with the table of the variants so far after each one that leaves a measured row, so a
    run stopped by a time limit keeps them."""
    import subprocess as sp

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _peak_memory import MALLOC_ENV

    rows = []
    work = Path(tempfile.mkdtemp(prefix="oscar-step-table-"))
    for ckpt, compiled in variants:
        name = variant_name(ckpt, compiled)
        out = work / f"{name}.json"
        env = {
            **os.environ,
            **MALLOC_ENV,
            "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1"),
            "TORCHINDUCTOR_CACHE_DIR": str(work / f"inductor-{name}"),
        }
        cmd = [
            sys.executable,
            str(Path(__file__).resolve()),
            "--step-variant",
            f"{ckpt},{int(compiled)}",
            "--step-size",
            size,
            "--device",
            device,
            "--step-warmup",
            str(warmup),
            "--step-repeats",
            str(repeats),
            "--json",
            str(out),
        ]
        print(f"step table: {name} ...", flush=True)
        proc = sp.run(cmd, capture_output=True, text=True, env=env, check=False)
        if proc.returncode:
            raise RuntimeError(f"step table, variant {name}: failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
        rows.append(json.loads(out.read_text()))
        print(f"step table: {name}: {json.dumps(rows[-1])}", flush=True)
        if checkpoint is not None and any(not r.get("out_of_memory") for r in rows):
            checkpoint(summarise_step_rows(size, device, rows, tolerance))
    return summarise_step_rows(size, device, rows, tolerance)


def summarise_step_rows(size: str, device: str, rows: list[dict], tolerance: float | None) -> dict:
    """The step table of measured variant ``rows`` (the first measured one is the reference): their first-step
    agreement against ``tolerance`` (default by dtype) and which ran out of memory."""
    measured = [r for r in rows if not r.get("out_of_memory")]
    if not measured:
        raise RuntimeError(
            f"step table: every variant ran out of {device} memory: "
            + "; ".join(f"{r['variant']}: {r['error']}" for r in rows)
        )
    dtype = measured[0]["dtype"]
    tol = STEP_TOLERANCE[dtype] if tolerance is None else tolerance
    checks = _compare(rows)
    bad = [c["variant"] for c in checks if not c["max_diff"] <= tol]
    return {
        "size": size,
        "device": device,
        "dtype": dtype,
        "tolerance": tol,
        "variants": rows,
        "agreement": checks,
        "max_diff": max(c["max_diff"] for c in checks),
        "disagreeing": bad,
        "out_of_memory": [r["variant"] for r in rows if r.get("out_of_memory")],
    }


def print_step_table(t: dict) -> None:
    r0 = next(r for r in t["variants"] if not r.get("out_of_memory"))
    print(
        f"\nTraining step, --step-size {t['size']} on {t['device']} ({t['dtype']}; {r0['params'] / 1e6:.2f} M "
        f"parameters, {r0['layers']} blocks, hidden {r0['hidden']}; micro-batch {r0['micro_batch']} x "
        f"{r0['tokens_per_clip']} tokens; MEASURED)"
    )
    print(
        f"{'variant':<13} {'median ms':>9} {'best ms':>8} {'CPU s':>6} {'compile s':>9} {'peak MiB':>8} "
        f"{'(model)':>8} {'step MiB':>8} {'(model)':>8} {'saved MiB':>9} {'(model)':>8} {'max diff':>9}"
    )
    agreement = {c["variant"]: c for c in t["agreement"]}
    for r in t["variants"]:
        if r.get("out_of_memory"):
            print(f"{r['variant']:<13} out of {t['device']} memory ({r['error'][:90]})")
            continue
        c, m = agreement[r["variant"]], r["modelled"]
        comp = f"{r['compile_s']:.1f}" if r["compile_s"] is not None else "-"
        saved = f"{r['saved_activation_bytes'] / MIB:.1f}" if r["saved_activation_bytes"] is not None else "-"
        print(
            f"{r['variant']:<13} {1e3 * r['median_step_s']:>9.1f} {1e3 * r['best_step_s']:>8.1f} "
            f"{r['median_step_cpu_s']:>6.2f} {comp:>9} {r['peak_bytes'] / MIB:>8.1f} {m['total'] / MIB:>8.1f} "
            f"{r['steady_peak_bytes'] / MIB:>8.1f} {m['transient'] / MIB:>8.1f} {saved:>9} "
            f"{m['activations'] / MIB:>8.1f} {c['max_diff']:>9.1e}"
        )
    print(
        "median/best ms: wall per step after warm-up; CPU s: process CPU seconds per step (median); compile s: the "
        "first step's extra time; peak MiB: above the level before the variant (the model built, first step and "
        "compile included) beside oscar_core.train.memory's total; step MiB: peak during the timed steps above "
        "the state kept between them, beside the model's total less 16P (weights, AdamW moments, EMA); saved MiB: "
        "non-parameter bytes autograd saves in one forward (counted, eager only; under full, the checkpointed "
        "blocks' insides are not saved) beside the model's activations; max diff: first-step loss and gradient "
        f"norms against {r0['variant']} (relative; tolerance {t['tolerance']:.0e})"
    )


# --------------------------------------------------------------------------- report
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20, help="optimiser steps per speed run (default 20)")
    ap.add_argument("--json", default=None, help="where the JSON goes (default benchmarks/results/train.json)")
    ap.add_argument("--skip-speed", action="store_true", help="only the computed memory table")
    ap.add_argument("--skip-memory", action="store_true", help="only the measured speed table")
    ap.add_argument("--repeats", type=int, default=3, help="alternating repeats of the on-the-fly pair (median)")
    st = ap.add_argument_group(
        "step table (--step-table: only this section; JSON default benchmarks/results/train_step.json)"
    )
    st.add_argument(
        "--step-table",
        action="store_true",
        help="measure one training step for activation checkpointing none/full x model.compile false/true",
    )
    st.add_argument(
        "--step-size",
        choices=sorted(STEP_SIZES),
        default="toy",
        help="tiny (the test), toy (oscar-toy's config, the default), 2b (CUDA only)",
    )
    st.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    st.add_argument("--step-warmup", type=int, default=1, help="untimed steps after the first (default 1)")
    st.add_argument("--step-repeats", type=int, default=5, help="timed steps per variant (default 5)")
    st.add_argument(
        "--step-variants",
        default="none,full,none+compile,full+compile",
        help="comma list among none, full, none+compile, full+compile (the first is the reference)",
    )
    st.add_argument(
        "--step-tolerance",
        type=float,
        default=None,
        help="largest relative first-step difference "
        f"against the reference (default {STEP_TOLERANCE['float32']:g} float32, "
        f"{STEP_TOLERANCE['bfloat16']:g} bf16)",
    )
    st.add_argument("--step-variant", default=None, help=argparse.SUPPRESS)  # internal: one variant, in a child
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    if args.step_table or args.step_variant:
        return _step_main(args, ap)
    if args.json is None:
        args.json = str(REPO / "benchmarks" / "results" / "train.json")
    result = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(), "torch": torch.__version__}
    if not args.skip_speed:
        runs = speed(args.steps, args.repeats)
        result["speed"] = runs
        base = runs[0]["steps_per_s"]
        print("\nTiny config, CPU, global batch 4 (measured; one thread per process)")
        print(f"{'run':<20} {'procs':>5} {'steps/s':>8} {'vs 1 proc cached':>17} {'final loss':>10}")
        for r in runs:
            print(
                f"{r['run']:<20} {r['processes']:>5} {r['steps_per_s']:>8.2f} {r['steps_per_s'] / base:>16.2f}x "
                f"{r['final_loss']:>10.4f}"
                + (
                    f"  (median of {', '.join(f'{v:.2f}' for v in r['repeats_steps_per_s'])})"
                    if "repeats_steps_per_s" in r
                    else ""
                )
            )
    if args.skip_memory:
        return _write(result, args.json)
    mem = memory_table()
    result["memory"] = mem
    print(
        "\nOSCAR-2B training memory per GPU, FSDP2, AdamW + EMA, bf16 autocast (COMPUTED, not measured: no GPU "
        "here; oscar_core.train.memory)"
    )
    print(
        f"parameters {mem['params'] / 1e9:.3f} B; {mem['tokens_per_clip']} tokens per 81-frame 512x288 clip; "
        f"{mem['activation_bytes_per_token_per_block']:.0f} saved bytes/token/block measured now "
        f"({mem['measured_bytes_per_token_per_width']:.1f} per unit of width; the library uses "
        f"{mem['library_bytes_per_token_per_width']:.1f})"
    )
    drift = abs(mem["measured_bytes_per_token_per_width"] / mem["library_bytes_per_token_per_width"] - 1)
    if drift > 0.05:
        print(f"WARNING: the measured activation constant differs from oscar_core.train.memory's by {drift:.0%}")
    print(
        f"activations per clip: {mem['activations_no_ckpt_gib']:.1f} GiB without checkpointing, "
        f"{mem['activations_ckpt_gib']:.1f} GiB with (a tokens x tokens saved tensor: "
        f"{'yes' if mem['quadratic_saved_tensor'] else 'none'})"
    )
    print(
        f"{'GPUs':>4} {'state':>6} {'bf16 w':>6} {'AdamW tmp':>9} {'gather':>6} {'total none':>10} "
        f"{'total full':>10} {'full+fused':>10} {'old full':>8}  fits 80 GB (full / none)"
    )
    for r in mem["rows"]:
        fits = lambda g: "yes" if g * GIB < 80e9 * 0.95 else "no"  # noqa: E731 - 5 % for the allocator and CUDA
        print(
            f"{r['gpus']:>4} {r['state_gib']:>6.1f} {r['autocast_weights_gib']:>6.1f} "
            f"{r['optimizer_temporaries_gib']:>9.1f} {r['gathered_gib']:>6.2f} {r['total_none_gib']:>10.1f} "
            f"{r['total_full_gib']:>10.1f} {r['total_ckpt_fused_adamw_gib']:>10.1f} {r['old_total_ckpt_gib']:>8.1f}  "
            f"{fits(r['total_full_gib'])} / {fits(r['total_none_gib'])}"
        )
    print(
        "GiB per GPU; bf16 w: autocast's cached bf16 weight copies (whole model, an upper bound under FSDP); "
        "AdamW tmp: the foreach step's fp32 temporary (0 with fused=True); old full: the table before these two"
    )
    return _write(result, args.json)


def _step_main(args, ap) -> int:
    """--step-table (the parent) or --step-variant (one variant, in a child process)."""
    device = args.device
    if device not in ("cpu", "cuda"):
        ap.error(f"--device: expected cpu or cuda, found {device!r}")
    if device == "cuda" and not torch.cuda.is_available():
        print(
            "benchmarks/train.py: --device cuda: CUDA is not available here (torch.cuda.is_available() is False); "
            "run the GPU sizes on a machine with a GPU, or use --device cpu",
            file=sys.stderr,
        )
        return 2
    if args.step_size == "2b" and device != "cuda":
        print(
            "benchmarks/train.py: --step-size 2b: the 2B recipe trains under bf16 autocast on a GPU "
            "(81 frames 512x288); run it with --device cuda",
            file=sys.stderr,
        )
        return 2
    if args.step_variant:  # a child: one variant, its row as JSON
        ckpt, compiled = args.step_variant.split(",")
        try:
            row = step_variant(args.step_size, device, ckpt, bool(int(compiled)), args.step_warmup, args.step_repeats)
        except torch.cuda.OutOfMemoryError as exc:  # a row that says so: the other variants still measure
            row = {
                "variant": variant_name(ckpt, bool(int(compiled))),
                "out_of_memory": True,
                "error": str(exc).splitlines()[0],
            }
        return _write(row, args.json, quiet=True)
    names = {variant_name(c, k): (c, k) for c, k in STEP_VARIANTS}
    chosen = [v.strip() for v in args.step_variants.split(",") if v.strip()]
    unknown = [v for v in chosen if v not in names]
    if unknown or not chosen:
        ap.error(f"--step-variants: expected a comma list among {', '.join(names)}, found {args.step_variants!r}")
    if args.step_repeats < 1 or args.step_warmup < 0:
        ap.error("--step-repeats: expected >= 1 and --step-warmup >= 0")
    path = args.json or REPO / "benchmarks" / "results" / "train_step.json"

    def result(table: dict, complete: bool) -> dict:
        return {
            "machine": platform.processor() or platform.machine(),
            "cpus": os.cpu_count(),
            "torch": torch.__version__,
            "complete": complete,
            "step_table": table,
        }

    table = step_table(
        args.step_size,
        device,
        [names[v] for v in chosen],
        args.step_warmup,
        args.step_repeats,
        args.step_tolerance,
        checkpoint=lambda partial: _write(result(partial, False), path, quiet=True, device=device, provenance=True),
    )
    print_step_table(table)
    _write(result(table, True), path, device=device)
    if table["disagreeing"]:
        worst = {c["variant"]: c["max_diff"] for c in table["agreement"]}
        print(
            "benchmarks/train.py: FAILED: first-step loss or gradients differ from "
            f"{table['agreement'][0]['variant']} beyond {table['tolerance']:.0e} in "
            + ", ".join(f"{v} ({worst[v]:.2e})" for v in table["disagreeing"]),
            file=sys.stderr,
        )
        return 1
    return 0


def _write(result: dict, path, quiet: bool = False, device: str | None = None, provenance: bool | None = None) -> int:
    """Write ``result`` as JSON; a top-level result (``provenance``; by default: not ``quiet``, since a child's row
    is quiet) gets the provenance block; ``quiet`` prints nothing."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))  # benchmarks/: also when a test loads this file
    from _provenance import with_provenance

    from oscar_core._util.atomic import atomic_write_bytes

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    data = with_provenance(result, device) if (not quiet if provenance is None else provenance) else result
    out = atomic_write_bytes(Path(path), (json.dumps(data, indent=2) + "\n").encode())
    if not quiet:
        print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
