"""What a one-chunk ``oscar rollout`` costs end to end, through the real CLI, and where the fixed cost goes.

    python benchmarks/cli_rollout.py --size tiny [--repeats 3] [--compile-modes]
    python benchmarks/cli_rollout.py --model oscar-toy
    python benchmarks/cli_rollout.py --size 2b --device cuda --compile-modes      # on a GPU

Measured: each row is a fresh ``python -m oscar_core.cli rollout ... --json`` process rolling out exactly one
chunk (the model's ``chunk_frames``, at its training size) of an embodiment's bundled example trajectory, with a
precomputed prompt embedding (``--prompt-embeds``) so nothing is downloaded or encoded. The script times the
process from outside (wall seconds from spawn to exit, and the CPU seconds it and its children used, from
``resource.getrusage(RUSAGE_CHILDREN)``) and reads the CLI's own breakdown (``timings`` in its JSON):
``startup`` (interpreter start and the ``oscar`` command's imports), ``import`` (the rollout's imports),
``load`` (reading the weights onto the device), ``render`` (the condition video), ``text`` (the prompt
embedding), ``compile`` (torch.compile's set-up; the compile itself is in the first chunk's sample),
``encode`` / ``sample`` / ``decode`` (the model), ``write`` (what writing the videos added) and
``exit`` (outside wall − the CLI's wall: tearing the process down). The **fixed cost** is everything but
encode + sample + decode.

Modes: ``never`` (eager) always; with ``--compile-modes`` also ``always`` with a cold compile cache (a fresh
``$OSCAR_CACHE`` per repeat), ``always`` with that cache warm (the same folder again) and ``auto`` (the
library's choice). ``--baseline-env VAR=VALUE`` adds a ``never`` row run with those variables, alternating with
the plain one repeat by repeat: ``OSCAR_FULL_EXIT=1`` and ``OSCAR_VERIFY=full`` give the interpreter's full
shutdown and the hashing of every weight file on every load, as before they were cut. Inputs are built into ``--work`` (a temporary folder by default): a random-weights model
(``--size tiny``: oscar_core.model.tiny; ``--size 2b``: the Cosmos-Predict2.5-2B DiT config and the default WAN
2.1 VAE, in bf16 on the device) saved with ``OscarWorldModel.save_pretrained``, or ``--model NAME_OR_FOLDER``.

The machine is recorded (processor, CPU count, torch version, and on CUDA ``torch.cuda.get_device_name()``
from a probe process) in the JSON, default ``benchmarks/results/cli_rollout.json``. A failed rollout
process stops the benchmark with a non-zero exit naming the mode and the process's error.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PARTS = ("startup", "import", "load", "render", "text", "compile", "write", "exit")
MODEL_PARTS = ("encode", "sample", "decode")
SIZES = ("tiny", "2b")


class BenchmarkError(RuntimeError):
    """A rollout process failed or reported something the benchmark cannot use."""


# ----------------------------------------------------------------------------- inputs
def build_model(size: str, folder: Path, device: str) -> Path:
    """A random-weights model folder of ``size`` ('tiny' or '2b') written with ``save_pretrained``."""
    import torch

    from oscar_core.model import ModelCard, OscarWorldModel
    from oscar_core.model.tiny import build_random_2b, build_tiny_transformer, build_tiny_vae

    if (folder / "oscar_model.json").is_file():
        return folder
    if size == "tiny":
        card = ModelCard(name="bench-tiny", chunk_frames=17, width=64, height=64, fps=15.0)
        model = OscarWorldModel.from_modules(
            build_tiny_transformer(seed=0, skeleton_scale=0.05), build_tiny_vae(seed=0), card
        )
    elif size == "2b":
        dtype = torch.bfloat16  # the released checkpoint's dtype (about 4 GB of DiT weights)
        transformer, vae = build_random_2b(device, dtype)
        card = ModelCard(name="bench-2b", chunk_frames=81, width=512, height=288, fps=15.0)
        model = OscarWorldModel.from_modules(transformer, vae, card, device=device, dtype=dtype)
    else:
        raise BenchmarkError(f"--size: expected one of {SIZES}, found {size!r}")
    return model.save_pretrained(folder)


def _text_dim(model_folder: Path) -> int:
    """Channels of the prompt embedding the model takes (its cross-attention projection's input)."""
    cfg = json.loads((model_folder / "transformer" / "config.json").read_text())
    if cfg.get("use_crossattn_projection"):
        return int(cfg["crossattn_proj_in_channels"])
    return int(cfg["text_embed_dim"])


def build_inputs(
    work: Path,
    model: str,
    embodiment: str,
    tokens: int,
    chunk_frames: int | None = None,
    frame_size: tuple[int, int] | None = None,
) -> dict:
    """First frame, one-chunk trajectory, camera and prompt embedding for ``model`` (a name or folder).

    Returns the paths and the chunk's frame count, width and height: the model card's unless ``chunk_frames``
    or ``frame_size`` (width, height) are given (then the rollout is asked for them).
    """
    import cv2
    import numpy as np
    import torch
    from safetensors.torch import save_file

    import oscar_zoo
    from oscar_core.kinematics.trajectory import load_trajectory, save_trajectory
    from oscar_core.model.world_model import read_card
    from oscar_core.plugin.registry import get_embodiment

    folder = Path(oscar_zoo.pull(model, local_files_only=True))  # a folder, a bundled or a cached model
    card = read_card(folder)
    emb = get_embodiment(embodiment)
    if emb.example_trajectory is None or emb.example_camera is None:
        raise BenchmarkError(
            f"--embodiment {embodiment}: expected an embodiment with a bundled example "
            "trajectory and camera, found none"
        )
    traj = load_trajectory(emb.example_trajectory)
    frames = chunk_frames or card.chunk_frames
    if len(traj) < frames:
        raise BenchmarkError(
            f"{emb.example_trajectory}: expected at least one chunk of {frames} frames, found {len(traj)}"
        )
    traj = traj.time_slice(0, frames)
    if card.fps and traj.timestamps is None:
        traj = traj.replace(fps=card.fps)  # the model's frame rate: no resampling warning in the rollout
    camera = emb.load_camera(emb.example_camera)
    work.mkdir(parents=True, exist_ok=True)
    inputs = {
        "model": str(folder),
        "frames": frames,
        "embodiment": embodiment,
        "chunk_frames": chunk_frames,
        "frame_size": list(frame_size) if frame_size else None,
        "trajectory": str(save_trajectory(traj, work / "trajectory.npz")),
        "camera": str(emb.example_camera),
        "first_frame": str(work / "first.png"),
        "prompt_embeds": str(work / "prompt_embeds.safetensors"),
    }
    width, height = frame_size or (card.width or camera.intrinsics.width, card.height or camera.intrinsics.height)
    inputs["size"] = [width, height]
    img = np.random.default_rng(0).integers(
        0, 256, (camera.intrinsics.height, camera.intrinsics.width, 3), dtype=np.uint8
    )
    cv2.imwrite(inputs["first_frame"], img)
    g = torch.Generator().manual_seed(0)
    save_file({"prompt_embeds": torch.randn(1, tokens, _text_dim(folder), generator=g)}, inputs["prompt_embeds"])
    return inputs


# ----------------------------------------------------------------------------- one process
def rollout_command(inputs: dict, out: Path, mode: str, device: str, steps: int | None, extra: tuple = ()) -> list[str]:
    """The ``oscar rollout`` command line of one row (``python -m oscar_core.cli``, the installed CLI)."""
    cmd = [
        sys.executable,
        "-m",
        "oscar_core.cli",
        "rollout",
        "--model",
        inputs["model"],
        "--embodiment",
        inputs["embodiment"],
        "--first-frame",
        inputs["first_frame"],
        "--trajectory",
        inputs["trajectory"],
        "--camera",
        inputs["camera"],
        "--prompt-embeds",
        inputs["prompt_embeds"],
        "--out",
        str(out),
        "--compile",
        mode,
        "--device",
        device,
        "--no-progress",
        "--json",
        "--offline",
    ]
    if steps is not None:
        cmd += ["--steps", str(steps)]
    if inputs.get("chunk_frames"):
        cmd += ["--chunk-frames", str(inputs["chunk_frames"])]
    if inputs.get("frame_size"):
        cmd += ["--size", "{}x{}".format(*inputs["frame_size"])]
    return cmd + list(extra)


def run_row(
    cmd: list[str], cache: Path, label: str, timeout: float | None = None, extra_env: dict | None = None
) -> dict:
    """Run one rollout process with ``$OSCAR_CACHE`` = ``cache``; its wall and CPU seconds and its JSON.

    Raises BenchmarkError naming ``label``, the exit code and the end of stderr when the process fails or
    prints no JSON summary.
    """
    env = {**os.environ, "OSCAR_CACHE": str(cache), "HF_HUB_OFFLINE": "1", **(extra_env or {})}
    env.pop("TORCHINDUCTOR_CACHE_DIR", None)  # the compile cache follows $OSCAR_CACHE, as for a user
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=REPO, check=False, timeout=timeout)
    except subprocess.TimeoutExpired as exc:
        raise BenchmarkError(
            f"{label}: the rollout process ran past --timeout {timeout:g} s and was killed:\n"
            f"{' '.join(cmd)}\n{(exc.stderr or b'')[-3000:]!r}"
        ) from None
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode:
        raise BenchmarkError(
            f"{label}: the rollout process exited with {proc.returncode}:\n{' '.join(cmd)}\n{proc.stderr[-3000:]}"
        )
    try:
        summary = json.loads(proc.stdout[proc.stdout.index("{") :])
    except ValueError:
        raise BenchmarkError(
            f"{label}: expected the rollout's JSON summary on stdout, found {proc.stdout[-500:]!r}"
        ) from None
    t = summary.get("timings", {})
    missing = [k for k in ("import", "load", "render", "text", "compile", "write", "wall", *MODEL_PARTS) if k not in t]
    if missing:
        raise BenchmarkError(f"{label}: the rollout's JSON 'timings': expected {missing}, found {sorted(t)}")
    parts = {k: float(t.get(k, 0.0)) for k in PARTS if k != "exit"}
    parts["exit"] = max(wall - float(t["wall"]), 0.0)
    model = {k: float(t[k]) for k in MODEL_PARTS}
    return {
        "wall_s": wall,
        "cli_wall_s": float(t["wall"]),
        "cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
        "parts": parts,
        "model": model,
        "fixed_s": wall - sum(model.values()),
        "frames": int(summary["frames"]),
        "chunks": int(summary["chunks"]),
        "size": summary["size"],
        "compile": summary.get("compile"),
        "dtype": summary.get("dtype"),
        "device": summary.get("device"),
        "device_name": summary.get("device_name"),
    }


def plan(compile_modes: bool, baseline_env: dict | None = None) -> list[list[tuple[str, str, str, dict]]]:
    """Groups of rows in run order, each row (label, --compile value, cache kind, extra environment); the rows of
    a group alternate repeat by repeat (same conditions on a shared machine). Cache kind 'fresh': a new
    $OSCAR_CACHE per repeat; 'warm': the one the last 'fresh' run filled. ``baseline_env``: a 'never' row run with those variables beside the plain one."""
    never = [("never", "never", "shared", {})]
    if baseline_env:
        desc = " ".join(f"{k}={v}" for k, v in baseline_env.items())
        never = [(f"never, {desc}", "never", "shared-baseline", dict(baseline_env))] + never
    groups = [never]
    if compile_modes:
        groups += [
            [("always, cold cache", "always", "fresh", {})],
            [("always, warm cache", "always", "warm", {})],
            [("auto", "auto", "shared", {})],
        ]
    return groups


def summarise(label: str, mode: str, runs: list[dict], frames: int) -> dict:
    """Medians (and the best wall) over the repeats of one mode; frames/s count the frames after the first."""
    med = statistics.median
    new = frames - 1
    wall = med(r["wall_s"] for r in runs)
    sample = med(r["model"]["sample"] for r in runs)
    return {
        "mode": label,
        "compile": mode,
        "repeats": len(runs),
        "wall_s": wall,
        "best_wall_s": min(r["wall_s"] for r in runs),
        "cpu_s": med(r["cpu_s"] for r in runs),
        "fixed_s": med(r["fixed_s"] for r in runs),
        "parts": {k: med(r["parts"][k] for r in runs) for k in PARTS},
        "sample_s": sample,
        "vae_s": med(r["model"]["encode"] + r["model"]["decode"] for r in runs),
        "frames": frames,
        "new_frames": new,
        "frames_per_s_wall": new / wall,
        "frames_per_s_sample": new / sample if sample > 0 else None,
        "compile_reason": runs[-1]["compile"],
        "runs": runs,
    }


# ----------------------------------------------------------------------------- the table
def print_table(rows: list[dict], title: str) -> None:
    print(f"\n{title}")
    wide = max(20, *(len(r["mode"]) for r in rows))
    head = (
        f"{'mode':<{wide}} {'wall s med/best':>15} {'CPU s':>6} {'fixed s':>7}  "
        + " ".join(f"{k:>7}" for k in PARTS)
        + f" {'sample':>7} {'VAE':>6} {'fr/s wall':>9} {'fr/s sample':>11}"
    )
    print(head)
    for r in rows:
        fs = r["frames_per_s_sample"]
        print(
            f"{r['mode']:<{wide}} {r['wall_s']:>7.2f}/{r['best_wall_s']:<7.2f} {r['cpu_s']:>6.1f} {r['fixed_s']:>7.2f}  "
            + " ".join(f"{r['parts'][k]:>7.2f}" for k in PARTS)
            + f" {r['sample_s']:>7.2f} {r['vae_s']:>6.2f} {r['frames_per_s_wall']:>9.2f} "
            + (f"{fs:>11.2f}" if fs else f"{'-':>11}")
        )


def machine(device: str) -> dict:
    """Processor, CPU count, torch version and (on CUDA) the GPU's name, from a probe process."""
    probe = (
        "import json, torch; d = {'torch': torch.__version__}\n"
        "if torch.cuda.is_available(): d['gpu'] = torch.cuda.get_device_name()\nprint(json.dumps(d))"
    )
    out = {
        "processor": platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
    }
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=False)
    if proc.returncode == 0:
        out.update(json.loads(proc.stdout))
    if not device.startswith("cuda"):
        out.pop("gpu", None)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example: python benchmarks/cli_rollout.py --size 2b --device cuda --compile-modes",
    )
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--size", choices=SIZES, help="build a random-weights model of this size (default tiny)")
    src.add_argument("--model", help="a zoo name or model folder instead (e.g. oscar-toy)")
    ap.add_argument("--device", default="cpu", help="--device of the rollout (default cpu)")
    ap.add_argument("--repeats", type=int, default=3, help="processes per mode (default 3)")
    ap.add_argument(
        "--compile-modes",
        action="store_true",
        help="also --compile always (cold cache, then warm) and auto; default: never only",
    )
    ap.add_argument("--steps", type=int, help="denoising steps (default: the CLI's)")
    ap.add_argument("--chunk-frames", type=int, help="frames of the one chunk (default: the model's chunk_frames)")
    ap.add_argument("--frame-size", metavar="WxH", help="rollout size (default: the model's training size)")
    ap.add_argument("--embodiment", default="toyarm", help="embodiment whose example trajectory is used")
    ap.add_argument("--tokens", type=int, default=None, help="prompt tokens (default 512 for 2b, else 8)")
    ap.add_argument(
        "--baseline-env",
        action="append",
        metavar="VAR=VALUE",
        help="also a 'never' row run with this variable set, alternating with the plain one (repeatable), "
        "e.g. OSCAR_FULL_EXIT=1 and OSCAR_VERIFY=full: the shutdown and hashing of before",
    )
    ap.add_argument("--timeout", type=float, default=3600.0, help="seconds one rollout process may take (3600)")
    ap.add_argument("--work", help="folder for the model and inputs (default: a temporary one, removed after)")
    ap.add_argument("--json", default=str(REPO / "benchmarks" / "results" / "cli_rollout.json"))
    ap.add_argument(
        "--rollout-arg",
        action="append",
        default=[],
        metavar="ARG",
        help="one more argument for every rollout (repeatable), e.g. --rollout-arg=--dtype=float32",
    )
    args = ap.parse_args(argv)
    if args.repeats < 1:
        ap.error(f"--repeats: expected at least 1, found {args.repeats}")
    for kv in args.baseline_env or ():
        if "=" not in kv or not kv.split("=", 1)[0]:
            ap.error(f"--baseline-env: expected VAR=VALUE, found {kv!r}")
    size = args.size or (None if args.model else "tiny")
    keep = args.work is not None
    work = Path(args.work) if keep else Path(tempfile.mkdtemp(prefix="oscar-cli-rollout-"))
    try:
        return _run(args, size, work)
    except BenchmarkError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    finally:
        if not keep:
            shutil.rmtree(work, ignore_errors=True)


def _run(args, size: str | None, work: Path) -> int:
    t0 = time.perf_counter()
    model = str(build_model(size, work / f"model-{size}", args.device)) if size else args.model
    tokens = args.tokens or (512 if size == "2b" else 8)
    frame_size = tuple(int(v) for v in args.frame_size.lower().split("x")) if args.frame_size else None
    inputs = build_inputs(work / "inputs", model, args.embodiment, tokens, args.chunk_frames, frame_size)
    setup_s = time.perf_counter() - t0
    baseline = dict(kv.split("=", 1) for kv in args.baseline_env) if args.baseline_env else None
    rows = []
    for group in plan(args.compile_modes, baseline):
        runs: dict[str, list] = {label: [] for label, *_ in group}
        for k in range(args.repeats):
            for label, mode, cache_kind, extra_env in group:
                cache = work / {"fresh": f"cache-cold-{k}", "warm": f"cache-cold-{args.repeats - 1}"}.get(
                    cache_kind, f"cache-{cache_kind}"
                )  # warm: the cache the last cold run filled
                out = work / "out" / f"{mode}-{cache_kind}-{k}.mkv"
                out.parent.mkdir(parents=True, exist_ok=True)
                cmd = rollout_command(inputs, out, mode, args.device, args.steps, tuple(args.rollout_arg))
                run = run_row(cmd, cache, f"{label} (repeat {k + 1})", args.timeout, extra_env)
                if run["frames"] != inputs["frames"] or run["chunks"] != 1:
                    raise BenchmarkError(
                        f"{label}: expected one chunk of {inputs['frames']} frames, found "
                        f"{run['frames']} frames in {run['chunks']} chunk(s)"
                    )
                runs[label].append(run)
        rows += [summarise(label, mode, runs[label], inputs["frames"]) for label, mode, *_ in group]
    info = machine(args.device)
    where = info.get("gpu") or f"{info['cpus']} CPUs ({info['processor']})"
    w, h = inputs["size"]
    print_table(
        rows,
        f"oscar rollout, one {inputs['frames']}-frame {w}x{h} chunk of {model if not size else size}, "
        f"--device {args.device}, median of {args.repeats} process(es) per mode, on {where} "
        f"(seconds; fixed = wall - encode - sample - decode)",
    )
    result = {
        "benchmark": "cli_rollout",
        "model": args.model or f"random {size}",
        "size": size,
        "device": args.device,
        "machine": info,
        "steps": args.steps,
        "repeats": args.repeats,
        "frames": inputs["frames"],
        "width": w,
        "height": h,
        "embodiment": args.embodiment,
        "env": {k: os.environ[k] for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS") if k in os.environ},
        "setup_s": setup_s,
        "rows": rows,
    }
    sys.path.insert(0, str(Path(__file__).resolve().parent))  # benchmarks/: also when a test loads this file
    from _provenance import with_provenance

    from oscar_core._util.atomic import atomic_write_bytes

    result = with_provenance(result, gpu=info.get("gpu"))
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    print(f"\nwrote {atomic_write_bytes(args.json, (json.dumps(result, indent=2) + chr(10)).encode())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
