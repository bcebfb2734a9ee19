"""oscar's Wan VAE (``oscar_core.model.wan_vae.WanVAE``) against diffusers' ``AutoencoderKLWan``, in the same run.

    python benchmarks/wan_vae.py [--repeats 5] [--json benchmarks/measured/wan_vae.json]
    python benchmarks/wan_vae.py --encode-variants-only [--no-compile] [--repeats 5] [--json ...]

``imports``: fresh interpreters from the repository root (OMP_NUM_THREADS=1), alternating row by row each repeat,
median CPU seconds (user + system of the child, ``resource.getrusage``) and wall seconds:

- ``import torch``: the floor under both;
- ``oscar: VideoVAE + load oscar-toy vae/``: what a rollout's VAE path imports and loads now
  (``oscar_core.model.vae.load_vae_folder``);
- ``diffusers: AutoencoderKLWan + load oscar-toy vae/``: the same folder through diffusers' class (oscar's strict
  loader, as ``load_vae_folder`` did before it had its own class).

``compute``: in this process, one torch thread, both classes loaded from ``zoo/assets/oscar-toy/vae`` with their 3-D
convolutions on oneDNN (as ``VideoVAE`` runs them), one 17-frame 64x64 toy chunk (a rendered toyarm episode):
``encode`` (posterior mode) and ``decode`` (of the reference's latents); best thread-CPU and wall milliseconds of
``--repeats``, the classes alternating; ``max_abs_diff`` between their outputs (0.0: bit-identical). oscar's class
runs twice: as it is (its RMS norm from sums of squares where that is bit-identical,
``oscar_core.model._wan_vae_layers.channel_norm_by_sums``) and with its RMS norm through ``F.normalize`` (the
reference's operation, ``oscar WanVAE, F.normalize norm``), so the norm's share shows in the same run.

``encode_variants`` (``--encode-variants-only`` measures it alone and adds it to the ``--json`` file with its own
provenance, the file's other fields as they were): what the paths issue 43 names do to the closed loop's condition
encode on the CPU: oscar's ``WanVAE`` encode of the same toy chunk (one thread, oneDNN 3-D convolutions) as it is,
with its 5-D convolution weights and the input in ``torch.channels_last_3d`` (the RMS norm then takes its
``F.normalize`` path), and with the encoder under ``torch.compile`` (inductor's C++ backend; a compiled graph does not
take the oneDNN route, inductor picks its own convolution); best thread-CPU and wall ms of ``--repeats`` after a
first call, the variants alternating; the first compiled call's wall and CPU seconds (this process and its compile
workers; the inductor cache as the process finds it: ``TORCHINDUCTOR_CACHE_DIR=$(mktemp -d)`` for a cold one);
``max_abs_diff`` against the encode as it is (0.0: bit-identical). ``--no-compile`` leaves the compiled row out.
"""

from __future__ import annotations

import argparse
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

from _provenance import provenance, with_provenance  # noqa: E402
from _wan_norm import f_normalize_rms_norm  # noqa: E402

TOY_VAE = REPO / "zoo" / "assets" / "oscar-toy" / "vae"
LOAD = "load_vae_folder({path!r})"
IMPORT_ROWS = {
    "import torch": "import torch",
    "oscar: VideoVAE + load oscar-toy vae/": (
        f"from oscar_core.model.vae import VideoVAE, load_vae_folder\n{LOAD.format(path=str(TOY_VAE))}"
    ),
    "diffusers: AutoencoderKLWan + load oscar-toy vae/": (
        "from diffusers.models.autoencoders.autoencoder_kl_wan import AutoencoderKLWan\n"
        "from oscar_core.model.weights import build_strict, load_state_dict, read_config\n"
        f"f = {str(TOY_VAE)!r}\n"
        "build_strict(AutoencoderKLWan, read_config(f, ('AutoencoderKLWan',)), load_state_dict(f), f)"
    ),
}


def run_once(code: str) -> tuple[float, float]:
    """(CPU s, wall s) of one fresh interpreter running ``code`` in the repository root."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"}
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"wan_vae: {code!r} exited {proc.returncode}: {proc.stderr.strip()[-400:]}")
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


def _best(fn, repeats: int) -> tuple[object, float, float]:
    """(last result, best thread-CPU ms, best wall ms) of ``repeats`` calls of ``fn``."""
    cpu, wall, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.thread_time()
        out = fn()
        cpu.append(time.thread_time() - c0)
        wall.append(time.perf_counter() - t0)
    return out, 1e3 * min(cpu), 1e3 * min(wall)


def _toy_chunk():
    """(1, 3, 17, 64, 64) pixels in [-1, 1] of a rendered toyarm episode."""
    from oscar_core.model.vae import VideoVAE
    from oscar_core.plugin.registry import Registry
    from oscar_core.toyworld.episode import episode_rng, make_episode

    ep = make_episode(Registry().get("toyarm"), episode_rng(0, "toyarm", 9), 64, 64, 17, ss=1)
    return VideoVAE.to_pixels(ep.rgb)


def measure_compute(repeats: int) -> list[dict]:
    """Encode and decode of one toy chunk by both classes, oscar's with either RMS norm (module docstring); one record
    per (row, part)."""
    import contextlib

    import torch
    from diffusers.models.autoencoders.autoencoder_kl_wan import AutoencoderKLWan

    from oscar_core.model.cpu_conv import use_onednn_conv3d
    from oscar_core.model.wan_vae import WanVAE
    from oscar_core.model.weights import build_strict, load_state_dict, read_config

    torch.set_num_threads(1)
    reference = build_strict(
        AutoencoderKLWan, read_config(TOY_VAE, ("AutoencoderKLWan",)), load_state_dict(TOY_VAE), TOY_VAE
    )
    ours = WanVAE.from_folder(TOY_VAE)
    #: name -> (model, the context its calls run in)
    models = {
        "oscar WanVAE": (ours, contextlib.nullcontext),
        "oscar WanVAE, F.normalize norm": (ours, f_normalize_rms_norm),
        "diffusers AutoencoderKLWan": (reference, contextlib.nullcontext),
    }
    use_onednn_conv3d(ours), use_onednn_conv3d(reference)
    x = _toy_chunk()
    with torch.no_grad():
        z = reference.encode(x).latent_dist.mode()
        want = {"encode": z, "decode": reference.decode(z).sample}
        parts = {"encode": lambda m: m.encode(x).latent_dist.mode(), "decode": lambda m: m.decode(z).sample}
        best: dict[tuple[str, str], list] = {}
        for _ in range(repeats):  # alternate the classes so a change of load hits both
            for name, (model, context) in models.items():
                for part, fn in parts.items():
                    with context():
                        out, cpu, wall = _best(lambda fn=fn, model=model: fn(model), 1)
                    rec = best.setdefault((name, part), [out, cpu, wall])
                    rec[1], rec[2] = min(rec[1], cpu), min(rec[2], wall)
    return [
        {
            "vae": name,
            "part": part,
            "cpu_ms": round(cpu, 1),
            "wall_ms": round(wall, 1),
            "max_abs_diff": float((out - want[part]).abs().max()),
        }
        for (name, part), (out, cpu, wall) in best.items()
    ]


ENCODE_VARIANTS = ("as it is", "channels-last", "compiled")


def _channels_last(model, on: bool) -> None:
    """The 5-D parameters of ``model`` in ``torch.channels_last_3d`` (``on``) or contiguous again (values unchanged)."""
    import torch

    fmt = torch.channels_last_3d if on else torch.contiguous_format
    for param in model.parameters():
        if param.ndim == 5:
            param.data = param.data.contiguous(memory_format=fmt)


def measure_encode_variants(repeats: int, variants=ENCODE_VARIANTS) -> list[dict]:
    """The toy chunk's encode by oscar's ``WanVAE`` under each of ``variants`` (module docstring): one record each
    with best thread-CPU / wall ms, the first call's seconds, and ``max_abs_diff`` against the encode as it is. The
    model is put back as it was after each variant's calls."""
    import torch

    from oscar_core.model.cpu_conv import use_onednn_conv3d
    from oscar_core.model.wan_vae import WanVAE

    torch.set_num_threads(1)
    model = WanVAE.from_folder(TOY_VAE)
    use_onednn_conv3d(model)
    x = _toy_chunk()
    plain_encoder = model.encoder
    compiled_encoder = None

    def run(variant: str):
        nonlocal compiled_encoder
        inputs = x
        if variant == "channels-last":
            _channels_last(model, True)
            inputs = x.contiguous(memory_format=torch.channels_last_3d)
        elif variant == "compiled":
            if compiled_encoder is None:
                compiled_encoder = torch.compile(plain_encoder, dynamic=False)
            model.encoder = compiled_encoder
        try:
            return model.encode(inputs).latent_dist.mode()
        finally:
            _channels_last(model, False)
            model.encoder = plain_encoder

    records: dict[str, dict] = {}
    with torch.no_grad():
        want = run("as it is")
        for v in variants:  # the first call: the compile itself for the compiled encoder
            c0, k0 = time.process_time(), resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            out = run(v)
            wall = time.perf_counter() - t0
            k1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            children = (k1.ru_utime - k0.ru_utime) + (k1.ru_stime - k0.ru_stime)
            records[v] = {
                "variant": v,
                "first_call_wall_s": round(wall, 2),
                "first_call_cpu_s": round(time.process_time() - c0 + children, 2),
                "max_abs_diff": float((out - want).abs().max()),
                "cpu_ms": float("inf"),
                "wall_ms": float("inf"),
            }
        for _ in range(repeats):  # alternate the variants so a change of load hits them all
            for v in variants:
                out, cpu, wall = _best(lambda v=v: run(v), 1)
                rec = records[v]
                rec["cpu_ms"], rec["wall_ms"] = round(min(rec["cpu_ms"], cpu), 1), round(min(rec["wall_ms"], wall), 1)
                rec["max_abs_diff"] = max(rec["max_abs_diff"], float((out - want).abs().max()))
    base = records[variants[0]]["cpu_ms"]
    for rec in records.values():
        rec["cpu_vs_as_it_is"] = round(rec["cpu_ms"] / base, 3)
    return list(records.values())


def print_encode_variants(rows: list[dict]) -> None:
    print(
        f"\n{'toy chunk encode, oscar WanVAE, one thread':<44} {'CPU ms':>8} {'wall ms':>8} {'x':>6} {'max |diff|':>11}"
    )
    for r in rows:
        print(
            f"{r['variant']:<44} {r['cpu_ms']:>8.1f} {r['wall_ms']:>8.1f} {r['cpu_vs_as_it_is']:>6.2f} "
            f"{r['max_abs_diff']:>11.3g}   first call {r['first_call_wall_s']:.1f} s wall, {r['first_call_cpu_s']:.1f} s CPU"
        )


def add_encode_variants(path: Path, repeats: int, variants) -> list[dict]:
    """Measure :func:`measure_encode_variants` and add it as ``encode_variants`` (with its own provenance) to the
    JSON at ``path``, its other fields as they were; written atomically."""
    from oscar_core._util.atomic import atomic_write_bytes

    data = json.loads(path.read_text())
    rows = measure_encode_variants(repeats, variants)
    data["encode_variants"] = {"provenance": provenance(), "repeats": repeats, "rows": rows}
    atomic_write_bytes(path, (json.dumps(data, indent=2) + "\n").encode())
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", type=Path, default=REPO / "benchmarks" / "measured" / "wan_vae.json")
    ap.add_argument(
        "--encode-variants-only",
        action="store_true",
        help="measure the encode as it is, channels-last and compiled only, and add it to the existing --json file",
    )
    ap.add_argument("--no-compile", action="store_true", help="--encode-variants-only without the compiled encoder")
    args = ap.parse_args(argv)
    if args.repeats < 1:
        print(f"wan_vae: --repeats: expected at least 1, found {args.repeats}", file=sys.stderr)
        return 2
    if args.encode_variants_only:
        if not args.json.is_file():
            print(f"wan_vae: --json {args.json}: expected a file this benchmark wrote, found none", file=sys.stderr)
            return 2
        variants = tuple(v for v in ENCODE_VARIANTS if not (args.no_compile and v == "compiled"))
        print_encode_variants(add_encode_variants(args.json, args.repeats, variants))
        print(f"\nwrote {args.json}")
        return 0
    load = os.getloadavg()[0]
    imports = measure_imports(args.repeats)
    compute = measure_compute(args.repeats)
    print(f"{'import (fresh process)':<52} {'CPU s':>7} {'wall s':>7}")
    for r in imports:
        print(f"{r['what']:<52} {r['cpu_s']:>7.2f} {r['wall_s']:>7.2f}")
    print(f"\n{'toy chunk, 17 x 64 x 64, one thread':<48} {'CPU ms':>8} {'wall ms':>8} {'max |diff|':>11}")
    for r in compute:
        print(f"{r['vae'] + ' ' + r['part']:<48} {r['cpu_ms']:>8.1f} {r['wall_ms']:>8.1f} {r['max_abs_diff']:>11.3g}")
    result = {"repeats": args.repeats, "load_1min": [load, os.getloadavg()[0]], "imports": imports, "compute": compute}
    from oscar_core._util.atomic import atomic_write_bytes

    args.json.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(args.json, (json.dumps(with_provenance(result), indent=2) + "\n").encode())
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
