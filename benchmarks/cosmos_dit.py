"""oscar's Cosmos DiT (``OscarTransformer3DModel`` on ``oscar_core.model.cosmos_dit.CosmosDiT``) against diffusers'
``CosmosTransformer3DModel``, in the same run.

    python benchmarks/cosmos_dit.py [--repeats 5] [--json benchmarks/measured/cosmos_dit.json]

``imports``: fresh interpreters from the repository root (OMP_NUM_THREADS=1), alternating row by row each repeat,
median CPU seconds (user + system of the child, ``resource.getrusage``) and wall seconds:

- ``import torch``: the floor under both;
- ``oscar: OscarTransformer3DModel + load oscar-toy transformer/``: what a rollout's DiT path imports and loads now;
- ``diffusers: CosmosTransformer3DModel + load oscar-toy transformer/``: the same weights (PE_s left out: diffusers'
  class has none) through diffusers' class and oscar's strict loader, as the DiT path ran before.

``compute``: in this process, one torch thread, both classes holding the oscar-toy transformer's weights, one guided
step's DiT call of a toy chunk (batch 2, 16 x 5 x 16 x 16 latent, per-frame timesteps, no skeleton, so both compute
the same function); best thread-CPU and wall milliseconds of ``--repeats``, the classes alternating;
``max_abs_diff`` between their outputs (0.0: bit-identical). oscar's class runs twice: as it is (its rotary tables
kept per grid, device and fps) and with the tables made afresh in every call (``RoPE tables made every call``, as
before they were kept).

``rope``: the rotary tables alone (``RotaryPositions``), made afresh and kept, best thread-CPU ms of ``--repeats``
x 10 calls: the toy grid (5 x 8 x 8 tokens, head 32) and the 2B model's grid for 81 frames at 512 x 288 (21 x 18 x 32
tokens, head 128, its ``rope_scale``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))
sys.path.insert(0, str(REPO))

from _provenance import with_provenance  # noqa: E402

TOY_DIT = REPO / "zoo" / "assets" / "oscar-toy" / "transformer"
IMPORT_ROWS = {
    "import torch": "import torch",
    "oscar: OscarTransformer3DModel + load oscar-toy transformer/": (
        "from oscar_core.model.transformer import OscarTransformer3DModel\n"
        f"OscarTransformer3DModel.load_strict({str(TOY_DIT)!r})"
    ),
    "diffusers: CosmosTransformer3DModel + load oscar-toy transformer/": (
        "import sys\nsys.path.insert(0, 'benchmarks')\nfrom cosmos_dit import load_reference\n"
        f"load_reference({str(TOY_DIT)!r})"
    ),
}


def load_reference(folder):
    """diffusers' ``CosmosTransformer3DModel`` from an oscar transformer folder: its config without
    ``skeleton_channels``, its weights without PE_s (diffusers' class has none), loaded strictly."""
    from diffusers.models.transformers.transformer_cosmos import CosmosTransformer3DModel

    from oscar_core.model.weights import load_state_dict, read_config

    config = read_config(folder, ("OscarTransformer3DModel",))
    settings = {k: v for k, v in config.items() if not k.startswith("_") and k != "skeleton_channels"}
    model = CosmosTransformer3DModel(**settings)
    state = {k: v for k, v in load_state_dict(folder).items() if not k.startswith("skeleton_embed.")}
    model.load_state_dict(state, strict=True)
    return model.eval()


def run_once(code: str) -> tuple[float, float]:
    """(CPU s, wall s) of one fresh interpreter running ``code`` in the repository root."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"}
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"cosmos_dit: {code!r} exited {proc.returncode}: {proc.stderr.strip()[-400:]}")
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), wall


def measure_imports(repeats: int) -> list[dict]:
    """One record per :data:`IMPORT_ROWS` row: median CPU and wall seconds of ``repeats`` fresh processes."""
    runs: dict[str, list[tuple[float, float]]] = {name: [] for name in IMPORT_ROWS}
    for _ in range(repeats):
        for name, code in IMPORT_ROWS.items():
            runs[name].append(run_once(code))
    return [
        {
            "what": name,
            "cpu_s": round(statistics.median(c for c, _ in runs[name]), 3),
            "wall_s": round(statistics.median(w for _, w in runs[name]), 3),
        }
        for name in IMPORT_ROWS
    ]


def _toy_step_inputs() -> dict:
    """Keyword arguments of one guided step's DiT call on an oscar-toy chunk (17 frames of 64 x 64 pixels)."""
    import torch

    g = torch.Generator().manual_seed(0)
    cond = torch.zeros(2, 1, 5, 16, 16)
    cond[:, :, 0] = 1
    return dict(
        hidden_states=torch.randn(2, 16, 5, 16, 16, generator=g),
        timestep=torch.rand(2, 1, 5, 1, 1, generator=g),
        encoder_hidden_states=torch.randn(2, 1, 48, generator=g),
        condition_mask=cond,
        padding_mask=torch.zeros(1, 1, 64, 64),
        fps=10.0,
        return_dict=False,
    )


@contextlib.contextmanager
def rope_made_every_call():
    """Inside: oscar's ``RotaryPositions`` computes its tables afresh in every call (its way before it kept them)."""
    from oscar_core.model._cosmos_layers import RotaryPositions

    forward = RotaryPositions.forward
    RotaryPositions.forward = lambda self, grid, device, fps=None: self.tables(grid, device, fps)
    try:
        yield
    finally:
        RotaryPositions.forward = forward


def measure_rope(repeats: int) -> list[dict]:
    """The rotary tables alone, made and kept, at the toy grid and the 2B grid (module docstring)."""
    import torch

    from oscar_core.model._cosmos_layers import RotaryPositions
    from oscar_core.model.tiny import COSMOS_2B_TRANSFORMER_CONFIG as BIG

    torch.set_num_threads(1)
    cases = {
        "toy, 5 x 8 x 8 tokens": (RotaryPositions(32, (8, 8, 8), (1.0, 1.0, 1.0)), (5, 8, 8)),
        "2B, 21 x 18 x 32 tokens": (
            RotaryPositions(BIG["attention_head_dim"], (128, 120, 120), tuple(BIG["rope_scale"])),
            (21, 18, 32),
        ),
    }
    rows = []
    for name, (rope, grid) in cases.items():
        best = {"made": float("inf"), "kept": float("inf")}
        for _ in range(repeats):
            for how in best:
                with rope_made_every_call() if how == "made" else contextlib.nullcontext():
                    c0 = time.thread_time()
                    for _ in range(10):
                        rope(grid, torch.device("cpu"), 10.0)
                    best[how] = min(best[how], 1e3 * (time.thread_time() - c0) / 10)
        rows.append({"grid": name, "made_cpu_ms": round(best["made"], 3), "kept_cpu_ms": round(best["kept"], 3)})
    return rows


def measure_compute(repeats: int) -> list[dict]:
    """One DiT call by both classes, oscar's with its rotary tables kept and made every call (module docstring);
    one record per row."""
    import torch

    from oscar_core.model._resize import install_torchvision_free_resize
    from oscar_core.model.transformer import OscarTransformer3DModel

    install_torchvision_free_resize()
    torch.set_num_threads(1)
    ours = OscarTransformer3DModel.load_strict(TOY_DIT)
    #: name -> (model, the context its calls run in)
    models = {
        "oscar OscarTransformer3DModel": (ours, contextlib.nullcontext),
        "oscar OscarTransformer3DModel, RoPE tables made every call": (ours, rope_made_every_call),
        "diffusers CosmosTransformer3DModel": (load_reference(TOY_DIT), contextlib.nullcontext),
    }
    kwargs = _toy_step_inputs()
    best: dict[str, list] = {}
    with torch.no_grad():
        want = models["diffusers CosmosTransformer3DModel"][0](**kwargs)[0]
        for _ in range(repeats):  # alternate the rows so a change of load hits all
            for name, (model, context) in models.items():
                with context():
                    t0, c0 = time.perf_counter(), time.thread_time()
                    out = model(**kwargs)[0]
                cpu, wall = 1e3 * (time.thread_time() - c0), 1e3 * (time.perf_counter() - t0)
                rec = best.setdefault(name, [out, cpu, wall])
                rec[1], rec[2] = min(rec[1], cpu), min(rec[2], wall)
    return [
        {
            "dit": name,
            "cpu_ms": round(cpu, 1),
            "wall_ms": round(wall, 1),
            "max_abs_diff": float((out - want).abs().max()),
        }
        for name, (out, cpu, wall) in best.items()
    ]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", type=Path, default=REPO / "benchmarks" / "measured" / "cosmos_dit.json")
    args = ap.parse_args(argv)
    if args.repeats < 1:
        print(f"cosmos_dit: --repeats: expected at least 1, found {args.repeats}", file=sys.stderr)
        return 2
    load = os.getloadavg()[0]
    imports = measure_imports(args.repeats)
    compute = measure_compute(args.repeats)
    rope = measure_rope(args.repeats)
    print(f"{'import (fresh process)':<66} {'CPU s':>7} {'wall s':>7}")
    for r in imports:
        print(f"{r['what']:<66} {r['cpu_s']:>7.2f} {r['wall_s']:>7.2f}")
    print(f"\n{'toy DiT call, batch 2 x 320 tokens, one thread':<60} {'CPU ms':>8} {'wall ms':>8} {'max |diff|':>11}")
    for r in compute:
        print(f"{r['dit']:<60} {r['cpu_ms']:>8.1f} {r['wall_ms']:>8.1f} {r['max_abs_diff']:>11.3g}")
    print(f"\n{'RoPE tables, CPU ms per call':<30} {'made':>8} {'kept':>8}")
    for r in rope:
        print(f"{r['grid']:<30} {r['made_cpu_ms']:>8.3f} {r['kept_cpu_ms']:>8.3f}")
    result = {
        "repeats": args.repeats,
        "load_1min": [load, os.getloadavg()[0]],
        "imports": imports,
        "compute": compute,
        "rope": rope,
    }
    from oscar_core._util.atomic import atomic_write_bytes

    args.json.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(args.json, (json.dumps(with_provenance(result), indent=2) + "\n").encode())
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
