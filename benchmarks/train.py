"""Training speed (measured, tiny config, CPU) and the 2B recipe's memory (computed).

    python benchmarks/train.py [--steps 20] [--json benchmarks/results/train.json] [--skip-speed]

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
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
GIB = 1024 ** 3


# --------------------------------------------------------------------------- speed
def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _speed_run(work: Path, name: str, clips: Path, steps: int, nproc: int, size: int = 32, workers: int = 0) -> dict:
    import yaml

    cfg = {"run_dir": str(work / name), "steps": steps, "batch_size": 4, "micro_batch": 1, "save_every": steps,
           "log_every": 1, "export": False, "model": {"transformer": "tiny", "vae": "tiny"},
           "data": {"clips": [str(clips)], "window": 9, "width": size, "height": size, "workers": workers},
           "optim": {"lr": 1e-3, "warmup_steps": 0, "grad_clip": 1.0}}
    path = work / f"{name}.yaml"
    path.write_text(yaml.safe_dump(cfg))
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    if nproc == 1:
        cmd = [sys.executable, "-m", "oscar_core.train", str(path), "--no-progress"]
    else:
        cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc-per-node", str(nproc), "--master-addr",
               "127.0.0.1", "--master-port", str(_port()), "-m", "oscar_core.train", str(path), "--no-progress"]
    t0 = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if out.returncode:
        raise RuntimeError(f"{name}: training failed:\n{out.stderr[-2000:]}")
    rows = [json.loads(l) for l in (work / name / "metrics.jsonl").read_text().splitlines()]
    rows = [r for r in rows if "loss" in r]
    first, last = rows[0], rows[-1]
    rate = (last["step"] - first["step"]) / (last["elapsed_s"] - first["elapsed_s"])
    return {"run": name, "processes": nproc, "workers": workers, "steps": steps, "steps_per_s": rate, "wall_s": wall,
            "final_loss": last["loss"]}


def speed(steps: int, repeats: int = 3) -> list[dict]:
    from oscar_core.train.synthetic import write_toy_clipset

    work = Path(tempfile.mkdtemp(prefix="oscar-train-bench-"))
    cached = write_toy_clipset(work / "cached", clips=4, frames=13, width=32, height=32, latents_vae="random",
                               latents_window=9, prompt_dim=48)
    raw = write_toy_clipset(work / "raw", clips=4, frames=13, width=32, height=32, prompt_dim=48)
    rows = [_speed_run(work, "cached-1proc", cached, steps, 1),
            _speed_run(work, "cached-2proc-ddp", cached, steps, 2)]
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
            model(hidden_states=x[:, :16], timestep=torch.full((1, 1, frames, 1, 1), 0.5),
                  encoder_hidden_states=torch.randn(1, 8, 64), condition_mask=x[:, 16:], return_dict=False)
        hook.remove()
        args = [a.detach().requires_grad_(a.is_floating_point()) if isinstance(a, torch.Tensor) else a
                for a in captured["args"]]
        with saved_tensors_hooks(pack, lambda t: t), torch.autocast("cpu", dtype=torch.bfloat16):
            out = block(*args)
        out.float().sum().backward()
        # parameters (and their bf16 casts) are saved too: count them once, separately
        param_bytes = sum(p.numel() * 2 for p in block.parameters())
        points.append((n, sum(seen.values()), param_bytes))
    (n0, b0, _), (n1, b1, _) = points[0], points[-1]
    per_token = (b1 - b0) / (n1 - n0)
    return {"per_token_bytes": per_token, "hidden": D, "points": points, "quadratic_saved": quadratic,
            "residual_bytes_per_token": 4 * D}


def memory_table() -> dict:
    """The 2B recipe's memory per GPU from ``oscar_core.train.memory`` (the model ``activation_checkpointing: auto``
    uses), with the activation constant measured again here (a drift check of the library's constant)."""
    from oscar_core.train.memory import ACT_BYTES_PER_TOKEN_PER_WIDTH, estimate_memory, tokens_per_clip

    total, block, layers = _param_counts()
    act = _saved_bytes_per_token()
    tokens = tokens_per_clip(81, 512, 288)
    hidden = act["hidden"]
    rows = []
    for n in (1, 2, 4, 8):
        est = estimate_memory(total, block, layers, hidden, tokens, shards=n)
        fused = estimate_memory(total, block, layers, hidden, tokens, shards=n, fused_adamw=True)
        rows.append({"gpus": n, **{f"{k}_gib": v / GIB for k, v in est.as_dict().items()},
                     "total_ckpt_fused_adamw_gib": fused.total("full") / GIB,
                     # the older figures, without autocast's weight copies and AdamW's temporaries
                     "old_total_ckpt_gib": (est.state + est.gathered + est.activations_full) / GIB,
                     "old_total_no_ckpt_gib": (est.state + est.gathered + est.activations_none) / GIB})
    measured = act["per_token_bytes"] / hidden
    return {"params": total, "block_params": block, "layers": layers, "tokens_per_clip": tokens,
            "activation_bytes_per_token_per_block": act["per_token_bytes"],
            "library_bytes_per_token_per_width": ACT_BYTES_PER_TOKEN_PER_WIDTH,
            "measured_bytes_per_token_per_width": measured,
            "activations_no_ckpt_gib": rows[0]["activations_none_gib"],
            "activations_ckpt_gib": rows[0]["activations_full_gib"],
            "quadratic_saved_tensor": act["quadratic_saved"], "rows": rows}


# --------------------------------------------------------------------------- report
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20, help="optimiser steps per speed run (default 20)")
    ap.add_argument("--json", default=str(REPO / "benchmarks" / "results" / "train.json"))
    ap.add_argument("--skip-speed", action="store_true", help="only the computed memory table")
    ap.add_argument("--skip-memory", action="store_true", help="only the measured speed table")
    ap.add_argument("--repeats", type=int, default=3, help="alternating repeats of the on-the-fly pair (median)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    result = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
              "torch": torch.__version__}
    if not args.skip_speed:
        runs = speed(args.steps, args.repeats)
        result["speed"] = runs
        base = runs[0]["steps_per_s"]
        print("\nTiny config, CPU, global batch 4 (measured; one thread per process)")
        print(f"{'run':<20} {'procs':>5} {'steps/s':>8} {'vs 1 proc cached':>17} {'final loss':>10}")
        for r in runs:
            print(f"{r['run']:<20} {r['processes']:>5} {r['steps_per_s']:>8.2f} {r['steps_per_s'] / base:>16.2f}x "
                  f"{r['final_loss']:>10.4f}" + (f"  (median of {', '.join(f'{v:.2f}' for v in r['repeats_steps_per_s'])})"
                                                 if "repeats_steps_per_s" in r else ""))
    if args.skip_memory:
        return _write(result, args.json)
    mem = memory_table()
    result["memory"] = mem
    print("\nOSCAR-2B training memory per GPU, FSDP2, AdamW + EMA, bf16 autocast (COMPUTED, not measured: no GPU "
          "here; oscar_core.train.memory)")
    print(f"parameters {mem['params'] / 1e9:.3f} B; {mem['tokens_per_clip']} tokens per 81-frame 512x288 clip; "
          f"{mem['activation_bytes_per_token_per_block']:.0f} saved bytes/token/block measured now "
          f"({mem['measured_bytes_per_token_per_width']:.1f} per unit of width; the library uses "
          f"{mem['library_bytes_per_token_per_width']:.1f})")
    drift = abs(mem["measured_bytes_per_token_per_width"] / mem["library_bytes_per_token_per_width"] - 1)
    if drift > 0.05:
        print(f"WARNING: the measured activation constant differs from oscar_core.train.memory's by {drift:.0%}")
    print(f"activations per clip: {mem['activations_no_ckpt_gib']:.1f} GiB without checkpointing, "
          f"{mem['activations_ckpt_gib']:.1f} GiB with (a tokens x tokens saved tensor: "
          f"{'yes' if mem['quadratic_saved_tensor'] else 'none'})")
    print(f"{'GPUs':>4} {'state':>6} {'bf16 w':>6} {'AdamW tmp':>9} {'gather':>6} {'total none':>10} "
          f"{'total full':>10} {'full+fused':>10} {'old full':>8}  fits 80 GB (full / none)")
    for r in mem["rows"]:
        fits = lambda g: "yes" if g * GIB < 80e9 * 0.95 else "no"  # noqa: E731 - 5 % for the allocator and CUDA
        print(f"{r['gpus']:>4} {r['state_gib']:>6.1f} {r['autocast_weights_gib']:>6.1f} "
              f"{r['optimizer_temporaries_gib']:>9.1f} {r['gathered_gib']:>6.2f} {r['total_none_gib']:>10.1f} "
              f"{r['total_full_gib']:>10.1f} {r['total_ckpt_fused_adamw_gib']:>10.1f} {r['old_total_ckpt_gib']:>8.1f}  "
              f"{fits(r['total_full_gib'])} / {fits(r['total_none_gib'])}")
    print("GiB per GPU; bf16 w: autocast's cached bf16 weight copies (whole model, an upper bound under FSDP); "
          "AdamW tmp: the foreach step's fp32 temporary (0 with fused=True); old full: the table before these two")
    return _write(result, args.json)


def _write(result: dict, path) -> int:
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
