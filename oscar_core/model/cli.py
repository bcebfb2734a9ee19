"""The ``oscar rollout`` and ``oscar zoo`` sub-commands.

Wire into the main parser with ``add_model_parsers(subparsers)``; each leaf
parser sets ``func`` (returns an exit code) like the other sub-commands.
Heavy imports (torch models, diffusers, huggingface_hub) happen inside the
commands, so ``oscar --help`` stays fast.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .._util.arg_types import count, default_device, device, interval, number
from .presets import SAMPLER_PRESETS

__all__ = ["add_model_parsers", "cmd_rollout", "cmd_zoo_list", "cmd_zoo_pull", "cmd_zoo_convert", "cmd_encode_prompt",
           "side_by_side_path"]

ROLLOUT_EXAMPLES = """examples:
  oscar rollout --model oscar-2b --embodiment franka --first-frame img.png --trajectory traj.npz \\
      --camera cam.json --prompt "put the cup in the sink" --out video.mp4
  oscar rollout ... --out video.mp4 --side-by-side compare.mp4 --device cuda --dtype bfloat16 --vae-tiling
  oscar rollout ... --prompt-embeds embeds.safetensors --steps 20 --seed 3 --json
  oscar rollout ... --solver euler --guidance 1      (first-order sampler, conditional branch only)
  oscar rollout ... --compile always     (compile the DiT even for a short rollout; --no-compile: never)

The rollout is written to --out; a side-by-side video (rollout | skeleton over
the rollout) to --side-by-side (default: OUT_side.mp4). A latent-action model
(an exported `condition: latent_action` run) takes the same arguments and is
fed the trajectory's end-effector actions instead of the skeleton.
"""

ZOO_EXAMPLES = """examples:
  oscar zoo list
  oscar zoo list --json
  oscar zoo pull oscar-2b
  HF_HUB_OFFLINE=1 oscar zoo pull oscar-2b     (check that the cache holds it)
  oscar zoo convert ./cosmos-native-folder ./oscar-folder     (any layout -> oscar's, safetensors)
"""

ENCODE_EXAMPLES = """examples:
  oscar encode-prompt "put the cup in the sink" --model oscar-2b
  oscar encode-prompt "" --model cosmos-predict2.5-2b            (the empty-prompt embedding)
  oscar encode-prompt "wave" --encoder ./cosmos-pipeline-folder --out wave.safetensors --json

The embedding (1, 512, 100352 for Cosmos-Reason1) goes into the prompt cache
keyed by prompt and encoder revision; `oscar rollout --prompt` reads it there.
"""

_DTYPES = ("float32", "bfloat16", "float16")


def side_by_side_path(out) -> Path:
    """Default side-by-side path: ``video.mp4`` → ``video_side.mp4`` (a folder ``frames/`` → ``frames_side/``)."""
    out = Path(out)
    return out.with_name(f"{out.stem}_side{out.suffix}") if out.suffix else out.with_name(f"{out.name}_side")


def add_model_parsers(subparsers) -> None:
    """Add ``rollout`` and ``zoo {list,pull}`` to an ``argparse`` sub-parser set."""
    fmt = argparse.RawDescriptionHelpFormatter
    r = subparsers.add_parser("rollout", help="roll the world model out along a trajectory (skeleton-conditioned)",
                              epilog=ROLLOUT_EXAMPLES, formatter_class=fmt)
    r.add_argument("--model", required=True, help="zoo name, Hub id owner/name, or folder (see `oscar zoo list`)")
    r.add_argument("--revision", help="Hub revision overriding the zoo's pinned one")
    r.add_argument("--embodiment", required=True, help="embodiment name (see `oscar embodiments`)")
    r.add_argument("--first-frame", required=True, help="first RGB frame (PNG/JPEG) taken by --camera")
    r.add_argument("--trajectory", required=True, help="trajectory .npz (docs/formats.md)")
    r.add_argument("--camera", required=True, help="camera calibration .json (docs/formats.md)")
    r.add_argument("--out", required=True, help="rollout video: .mp4 (H.264), .mkv (lossless) or folder/ (PNGs)")
    r.add_argument("--side-by-side", help="side-by-side video path (default: OUT_side.mp4)")
    r.add_argument("--no-side-by-side", action="store_true", help="do not write the side-by-side video")
    text = r.add_mutually_exclusive_group()
    text.add_argument("--prompt", help="task text; embedded with the model's text encoder on the first use, then "
                      "read from the prompt cache (--prompt-cache)")
    text.add_argument("--prompt-embeds", metavar="FILE", help="precomputed prompt embedding (.safetensors, tensor "
                      "'prompt_embeds' of shape (1, L, D))")
    r.add_argument("--prompt-cache", metavar="DIR", help="prompt-embedding cache (default: $OSCAR_CACHE/prompt_embeds "
                   "or ~/.cache/oscar/prompt_embeds)")
    r.add_argument("--text-encoder", metavar="ID_OR_FOLDER", help="text encoder for --prompt (default: the "
                   "checkpoint's text_encoder_id)")
    r.add_argument("--native-file", help="which native Cosmos checkpoint file, when a folder/repo holds several")
    r.add_argument("--size", help="rollout WIDTHxHEIGHT, multiples of 16 (default: the model's, else the camera's)")
    r.add_argument("--resize", choices=("crop", "stretch"), default="crop",
                   help="how camera and first frame are fitted to --size (default: centre crop)")
    r.add_argument("--chunk-frames", type=count(1), help="frames per chunk, 4k+1 (default: the model's, e.g. 81)")
    r.add_argument("--steps", type=count(1), help="denoising steps per chunk (default 35, or the preset's)")
    r.add_argument("--preset", choices=sorted(SAMPLER_PRESETS), help="sampling budget: paper (35 steps, guidance at every "
                   "step) or fast (fewer steps, guidance on part of the noise range; docs/world-model.md)")
    r.add_argument("--guidance-interval", metavar="LO,HI", type=interval,
                   help="guide only the steps with noise level in [LO, HI]; the others run the conditional branch")
    r.add_argument("--solver", choices=("unipc", "euler"), help="unipc (2nd order, as Cosmos/diffusers) or euler "
                   "(default: the checkpoint's scheduler, else unipc)")
    r.add_argument("--shift", type=number(above=0.0), default=5.0, help="flow schedule shift (default 5)")
    r.add_argument("--guidance", type=number(0.0), default=6.0, help="skeleton guidance w (default 6, the paper's; 0 with "
                   "--guidance-form diffusers or 1 with standard = conditional branch only)")
    r.add_argument("--guidance-form", choices=("diffusers", "standard"), default="diffusers",
                   help="diffusers (default; Ho & Salimans, NVIDIA's Cosmos code): v_c + w(v_c - v_u); "
                   "standard: v_u + w(v_c - v_u)")
    r.add_argument("--action-guidance", type=number(0.0), help="latent-action models: guidance w over the actions "
                   "(unconditional branch: no action tokens; default: none, the conditional branch only)")
    r.add_argument("--two-pass-cfg", action="store_true", help="run the two guidance branches as two forwards "
                   "(less memory) instead of one batched forward")
    r.add_argument("--seed", type=count(0), default=0, help="noise seed (same seed, same video)")
    r.add_argument("--fps", type=number(above=0.0), help="output frame rate (default: the trajectory's)")
    r.add_argument("--device", type=device, help="torch device (default: cuda when available, else cpu)")
    r.add_argument("--dtype", choices=_DTYPES, help="DiT dtype (default: bfloat16 on CUDA, else float32)")
    from .compile_policy import add_compile_options

    add_compile_options(r)
    r.add_argument("--vae-tiling", action="store_true", help="tile VAE encode/decode (GPU memory)")
    r.add_argument("--vae-slicing", action="store_true", help="VAE one batch element at a time")
    r.add_argument("--offload-vae", action="store_true", help="keep the VAE on the CPU between uses")
    r.add_argument("--offload-text", action="store_true", help="keep the DiT's text projection on the CPU "
                   "(the prompt is projected once per chunk)")
    r.add_argument("--offline", action="store_true", help="use only the local Hub cache (like HF_HUB_OFFLINE=1)")
    r.add_argument("--no-progress", action="store_true", help="no progress bars")
    r.add_argument("--json", action="store_true", help="print a machine-readable summary")
    r.set_defaults(func=cmd_rollout)

    z = subparsers.add_parser("zoo", help="named world-model checkpoints: list, pull", epilog=ZOO_EXAMPLES,
                              formatter_class=fmt)
    zsub = z.add_subparsers(dest="zoo_command", required=True)
    zl = zsub.add_parser("list", help="the zoo table and your registered models", epilog=ZOO_EXAMPLES, formatter_class=fmt)
    zl.add_argument("--json", action="store_true", help="machine-readable output")
    zl.set_defaults(func=cmd_zoo_list)
    zp = zsub.add_parser("pull", help="download and verify a checkpoint into the Hub cache", epilog=ZOO_EXAMPLES,
                         formatter_class=fmt)
    zp.add_argument("name", help="zoo name, Hub id owner/name, or folder")
    zp.add_argument("--revision", help="Hub revision overriding the pinned one")
    zp.add_argument("--force", action="store_true", help="download again even if cached (after a corruption)")
    zp.add_argument("--offline", action="store_true", help="only check the local cache")
    zp.add_argument("--json", action="store_true", help="machine-readable output")
    zp.add_argument("--native-file", help="which native Cosmos checkpoint file, when the repo holds several")
    zp.set_defaults(func=cmd_zoo_pull)
    zc = zsub.add_parser("convert", help="write any checkpoint layout (oscar, diffusers, native Cosmos) as oscar's "
                         "(safetensors)", epilog=ZOO_EXAMPLES, formatter_class=fmt)
    zc.add_argument("src", help="zoo name, Hub id owner/name, or folder, in any supported layout")
    zc.add_argument("dst", help="output folder (oscar layout)")
    zc.add_argument("--revision", help="Hub revision")
    zc.add_argument("--native-file", help="which native Cosmos checkpoint file, when SRC holds several")
    zc.add_argument("--offline", action="store_true", help="only the local cache")
    zc.add_argument("--json", action="store_true", help="machine-readable output")
    zc.set_defaults(func=cmd_zoo_convert)

    e = subparsers.add_parser("encode-prompt", help="compute (and cache) the text embedding of a prompt",
                              epilog=ENCODE_EXAMPLES, formatter_class=fmt)
    e.add_argument("prompt", help='the prompt text ("" for the empty prompt)')
    e.add_argument("--model", help="zoo name / Hub id whose text_encoder_id to use (default: cosmos-predict2.5-2b's)")
    e.add_argument("--encoder", metavar="ID_OR_FOLDER", help="text encoder: 'owner/name@revision:text_encoder' or a "
                   "diffusers pipeline folder (text_encoder/ + tokenizer/)")
    e.add_argument("--out", help="also write the embedding here (.safetensors, tensor 'prompt_embeds')")
    e.add_argument("--prompt-cache", metavar="DIR", help="prompt-embedding cache folder")
    e.add_argument("--device", type=device, help="torch device (default: cuda when available, else cpu)")
    e.add_argument("--dtype", choices=_DTYPES, help="encoder dtype (default: the checkpoint's)")
    e.add_argument("--offline", action="store_true", help="only the local Hub cache")
    e.add_argument("--json", action="store_true", help="machine-readable output")
    e.set_defaults(func=cmd_encode_prompt)


# --------------------------------------------------------------------------- zoo


def cmd_zoo_list(args) -> int:
    import oscar_zoo

    specs = oscar_zoo.list_models()
    if args.json:
        print(json.dumps({"models": [s.row() for s in specs], "registry": str(oscar_zoo.registry_path())}, indent=2))
        return 0
    header = ("name", "repo@revision", "kind", "license", "embodiments", "frames", "size", "fps")
    rows = [header]
    for s in specs:
        where = "bundled with oscar-wm" if s.bundled else f"{s.repo_id}@{s.revision or 'main (unpinned)'}"
        rows.append((s.name, where, s.kind, s.license or "?",
                     ",".join(s.embodiments) or "-", str(s.chunk_frames or "?"),
                     f"{s.width}x{s.height}" if s.width and s.height else "?", f"{s.fps:g}" if s.fps else "?"))
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    for row in rows:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip())
    print(f"user registry: {oscar_zoo.registry_path()}", file=sys.stderr)
    return 0


def cmd_zoo_pull(args) -> int:
    import oscar_zoo
    from oscar_zoo._hub import lock_path

    folder = oscar_zoo.pull(args.name, args.revision, force_download=args.force,
                            local_files_only=True if args.offline else None, native_file=args.native_file)
    resolved = oscar_zoo.resolve(args.name, args.revision)
    lock = lock_path(resolved.spec.repo_id, resolved.revision) if resolved.spec is not None else None
    lock = lock if lock is not None and lock.is_file() else None
    if args.json:
        print(json.dumps({"name": args.name, "folder": str(folder), "lock": str(lock) if lock else None}))
    else:
        print(f"{args.name}: verified, in {folder}" + (f" (pinned in {lock})" if lock else ""))
    return 0


def cmd_zoo_convert(args) -> int:
    import oscar_zoo
    from oscar_zoo._fetch import fetch, resolve

    report: list[str] = []
    got = fetch(resolve(args.src, args.revision), local_files_only=True if args.offline else None,
                native_file=args.native_file)
    out = oscar_zoo.convert(got.folder, args.dst, native_file=args.native_file, report=report)
    if args.json:
        print(json.dumps({"src": args.src, "dst": str(out), "layout": got.layout.kind, "report": report}, indent=2))
    else:
        for line in report:
            print(line, file=sys.stderr)
        print(f"{args.src} ({got.layout.kind}) -> {out} (oscar layout, safetensors)")
    return 0


# --------------------------------------------------------------------------- text


def _encoder_id_for(model: str | None) -> str:
    import oscar_zoo

    if model:
        spec = oscar_zoo.resolve(model).spec
        if spec is not None and spec.text_encoder_id:
            return spec.text_encoder_id
        from .errors import ModelInputError

        raise ModelInputError(f"model {model!r}: expected a zoo entry with a text_encoder_id, found none; pass "
                              "--encoder ID_OR_FOLDER")
    return oscar_zoo.COSMOS_TEXT_ENCODER_ID


def _text_encoder(encoder_id: str, device, dtype, offline: bool):
    import torch

    from .text_encoder import TextEncoder

    dt = getattr(torch, dtype) if dtype else None
    return TextEncoder.from_hub(encoder_id, device=device, dtype=dt, local_files_only=True if offline else None)


def cmd_encode_prompt(args) -> int:
    from .text import PromptEmbeddingCache

    encoder_id = args.encoder or _encoder_id_for(args.model)
    cache = PromptEmbeddingCache(args.prompt_cache, encoder_id=encoder_id)
    embeds = cache.get(args.prompt)
    cached = embeds is not None
    if not cached:
        encoder = _text_encoder(encoder_id, args.device or default_device(), args.dtype, args.offline)
        cache = PromptEmbeddingCache(args.prompt_cache, encoder_id=encoder.encoder_id)
        embeds, cached = encoder.cached(args.prompt, args.prompt_cache)
    summary = {"prompt": args.prompt, "encoder_id": cache.encoder_id, "shape": list(embeds.shape),
               "cache_file": str(cache.path(args.prompt)), "was_cached": cached}
    if args.out:
        from safetensors.torch import save_file

        from .._util.atomic import atomic_output

        with atomic_output(args.out) as tmp:
            save_file({"prompt_embeds": embeds.contiguous()}, str(tmp),
                      metadata={"prompt": args.prompt, "encoder_id": cache.encoder_id})
        summary["out"] = str(args.out)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        how = "from the cache" if cached else "computed and cached"
        print(f"{args.prompt!r}: {tuple(embeds.shape)} {how} in {summary['cache_file']}")
    return 0


# --------------------------------------------------------------------------- rollout


def _prompt_embeds(args, model, device) -> tuple:
    """(embedding or None, where it came from) for ``oscar rollout`` — never a silent zero embedding."""
    import torch

    from .text import PromptEmbeddingCache

    if args.prompt_embeds:
        from safetensors.torch import load_file

        from ._weights import check_safetensors

        check_safetensors(args.prompt_embeds)
        tensors = load_file(args.prompt_embeds)
        if "prompt_embeds" in tensors:
            return tensors["prompt_embeds"], f"--prompt-embeds {args.prompt_embeds}"
        if len(tensors) == 1:
            return next(iter(tensors.values())), f"--prompt-embeds {args.prompt_embeds}"
        from ..errors import InputFileError

        raise InputFileError(args.prompt_embeds, "tensors", "a tensor named 'prompt_embeds'", sorted(tensors))
    encoder = args.text_encoder or model.card.text_encoder_id
    if args.prompt is None:
        if model.empty_prompt is not None:
            return None, "empty-prompt embedding stored in the checkpoint (no --prompt)"
        if not encoder:
            return None, ("ZERO text embedding: no --prompt and the checkpoint names no text encoder "
                          "(text_encoder_id) and ships no empty-prompt embedding")
    prompt = "" if args.prompt is None else args.prompt
    what = "empty-prompt embedding (no --prompt)" if args.prompt is None else f"prompt {prompt!r}"
    cache = PromptEmbeddingCache(args.prompt_cache, encoder_id=encoder or "unknown-encoder")
    found = cache.get(prompt)
    if found is not None:
        return found.to(torch.float32), f"{what}, cached ({cache.path(prompt)})"
    if not encoder:
        from .errors import ModelInputError

        raise ModelInputError(
            f"{cache.root}: prompt {prompt!r}: expected a cached embedding made by encoder 'unknown-encoder' "
            f"({cache.path(prompt).name}), found none, and the checkpoint names no text encoder; pass "
            "--text-encoder ID_OR_FOLDER, or --prompt-embeds FILE")
    text = _text_encoder(encoder, device, None, args.offline)
    embeds, _ = text.cached(prompt, args.prompt_cache)
    return embeds.to(torch.float32), f"{what}, computed with {text.encoder_id} and cached"


def _rollout_size(args, card, camera) -> tuple[int, int]:
    from ..render.skeleton_video import parse_size
    from .errors import ModelInputError

    if args.size:
        size, origin = parse_size(args.size), "--size"
    elif card.width and card.height:
        size, origin = (card.width, card.height), "the model's training size"
    else:
        size, origin = (camera.intrinsics.width, camera.intrinsics.height), f"the camera's image size ({args.camera})"
    if size[0] % 16 or size[1] % 16:
        raise ModelInputError(f"rollout size: expected width and height divisible by 16 (VAE x DiT patch), found "
                              f"{size[0]}x{size[1]} from {origin}; pass --size, e.g. "
                              f"{size[0] // 16 * 16}x{size[1] // 16 * 16}")
    return size


def cmd_rollout(args) -> int:
    import time

    t_start = time.perf_counter()
    startup = _seconds_since_process_start()
    import numpy as np
    import torch

    import oscar_zoo

    from ..kinematics.trajectory import load_trajectory
    from ..plugin.registry import get_embodiment
    from ..render.conditions import condition_video, video_condition_of
    from ..render.skeleton_video import fit_image
    from ._image import read_first_frame
    from .sampler import sampler_from_options

    timings = {"startup": startup} if startup is not None else {}
    timings["import"] = time.perf_counter() - t_start
    emb = get_embodiment(args.embodiment, getattr(args, "plugin", None) or ())
    traj = load_trajectory(args.trajectory)
    camera = emb.load_camera(args.camera)
    first = read_first_frame(args.first_frame, camera, args.camera)
    sampler = sampler_from_options(steps=args.steps, preset=args.preset, guidance_interval=args.guidance_interval,
                                   shift=args.shift, guidance=args.guidance, guidance_form=args.guidance_form,
                                   batched_cfg=not args.two_pass_cfg, solver=args.solver,
                                   action_guidance=getattr(args, "action_guidance", None))
    # the outputs are checked before any weights load (gigabytes for the 2B): a typo costs a second, not minutes
    from ..media.video import check_output
    from ..render.skeleton_video import parse_size

    size = parse_size(args.size) if args.size else None
    check_output(args.out, size=size)
    if size is not None:  # the skeleton video of the whole trajectory is held in memory
        from .._util.memory import check_fits

        check_fits((len(traj), size[1], size[0], 3), 1, "the skeleton video (T, H, W, 3) uint8 at --size",
                   "use a smaller --size")
    side_path = None if args.no_side_by_side else (args.side_by_side or side_by_side_path(args.out))
    if side_path is not None:
        check_output(side_path)
    device = args.device or default_device()
    dtype = getattr(torch, args.dtype or ("bfloat16" if str(device).startswith("cuda") else "float32"))
    report: list[str] = []
    t0 = time.perf_counter()
    if _loads_without_network(args):  # online, diffusers' import waits until the Hub has answered (OSCAR_HUB_TIMEOUT)
        from .world_model import OscarWorldModel  # noqa: F401 - diffusers (~3 s on a CPU): counted as import
    timings["import"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    model = oscar_zoo.load(args.model, args.revision, device=device, dtype=dtype,
                           offload_vae=args.offload_vae, offload_text=args.offload_text,
                           local_files_only=True if args.offline else None, native_file=args.native_file,
                           report=report)
    timings["load"] = time.perf_counter() - t0
    for line in report:
        print(line, file=sys.stderr)
    model.set_compile(args.compile)
    if args.vae_tiling:
        model.enable_vae_tiling()
    if args.vae_slicing:
        model.enable_vae_slicing()
    width, height = _rollout_size(args, model.card, camera)
    # the card's condition video (the skeleton, or the mesh / capsules for a model trained on those)
    t0 = time.perf_counter()
    skeleton = condition_video(video_condition_of(model.card.condition), emb, traj, camera,
                               (width, height), resize_mode=args.resize, camera_source=args.camera)
    first = fit_image(first, width, height, args.resize)
    timings["render"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    prompt, text_source = _prompt_embeds(args, model, device)
    timings["text"] = time.perf_counter() - t0
    print(f"text: {text_source}", file=sys.stderr)
    if prompt is None and model.empty_prompt is None:
        prompt = torch.zeros(1, 1, model.transformer.text_dim)
    if model.card.fps and abs(model.card.fps - traj.fps) > 1e-6:
        print(f"warning: {args.trajectory} is at {traj.fps:g} fps but the model was trained at {model.card.fps:g} fps; "
              "resample the trajectory for faithful motion speed", file=sys.stderr)
    from .rollout import RolloutResult

    fps = args.fps or traj.fps
    result = RolloutResult(frames=np.empty(0, np.uint8))
    latent_action = model.card.condition == "latent_action"
    t0 = time.perf_counter()
    actions = model.rollout_inputs(traj, camera, emb)["actions"] if latent_action else None
    timings["render"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    chunks = model.iter_rollout(first, None if latent_action else skeleton, prompt, chunk_frames=args.chunk_frames,
                                sampler=sampler, seed=args.seed, progress=not args.no_progress, result=result,
                                actions=actions)
    # torch.compile's set-up when the policy compiles (mostly inductor's imports, ~1.5 s on a CPU; 0 eager); the
    # compile itself runs inside the first chunk's sample
    timings["compile"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    out, side_out, count = _write_streams(chunks, skeleton, args.out, side_path, fps)
    streamed = time.perf_counter() - t0
    timings.update({k: result.timings.get(k, 0.0) for k in ("encode", "sample", "decode")})
    timings["write"] = max(streamed - sum(result.timings.values()), 0.0)  # what streaming added beyond the model
    timings["wall"] = time.perf_counter() - t_start + (startup or 0.0)
    summary = {"rollout": str(out), "frames": count, "size": [width, height], "fps": fps,
               "chunks": len(result.starts), "model": args.model, "seed": args.seed, "text": text_source,
               "sampler": model.sampler_for(sampler).resolved_solver, "steps": args.steps,
               "unconditional_skeleton": model.card.unconditional_skeleton,
               "guidance": {"w": args.guidance, "form": args.guidance_form}, "condition": model.card.condition,
               "compile": model.compile_reason, "dtype": str(next(model.transformer.parameters()).dtype),
               "device": str(device), "timings": {k: round(v, 3) for k, v in timings.items()}}
    if str(device).startswith("cuda"):  # which GPU the timings were measured on
        summary["device_name"] = torch.cuda.get_device_name(torch.device(device))
    if latent_action:
        summary["guidance"] = {"action_w": sampler.action_guidance, "form": args.guidance_form}
    if side_out is not None:
        summary["side_by_side"] = str(side_out)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        extra = f" and {summary['side_by_side']}" if "side_by_side" in summary else ""
        print(f"wrote {out}{extra}: {summary['frames']} frames, {width}x{height}, {fps:g} fps, "
              f"{summary['chunks']} chunk(s)")
        print("seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in timings.items()) + f" ({model.compile_reason})",
              file=sys.stderr)
    return 0


def _loads_without_network(args) -> bool:
    """Whether ``--model`` loads from disk only: a folder, a model bundled with oscar, or ``--offline``."""
    import oscar_zoo

    if args.offline:
        return True
    try:
        resolved = oscar_zoo.resolve(args.model, args.revision)
    except oscar_zoo.UnknownModelError:
        return False  # the load reports it
    return resolved.folder is not None or bool(resolved.spec is not None and resolved.spec.bundled)


def _seconds_since_process_start() -> float | None:
    """Seconds since this process started (Linux ``/proc``; None elsewhere): the interpreter's start, the
    ``oscar`` command's own imports and argument parsing, before a sub-command runs. 10 ms resolution."""
    import os

    try:
        with open("/proc/self/stat") as fh:
            start_ticks = int(fh.read().rsplit(")", 1)[1].split()[19])  # field 22: starttime, in clock ticks
        with open("/proc/uptime") as fh:
            uptime = float(fh.read().split()[0])
        return max(uptime - start_ticks / os.sysconf("SC_CLK_TCK"), 0.0)
    except (OSError, ValueError, IndexError):
        return None


def _write_streams(chunks, skeleton, out, side_path, fps):
    """Write the rollout (and its side-by-side) while chunks arrive; returns (out, side or None, frames)."""
    import queue
    import threading

    import numpy as np

    from ..media.video import write_video
    from ..render.skeleton_video import overlay_skeleton

    done = object()
    side_q: queue.Queue = queue.Queue(maxsize=4)
    state = {"count": 0, "error": None, "side": None}

    def frames():
        state["started"] = True
        try:
            for block in chunks:
                start = state["count"]
                state["count"] += len(block)
                if side_path is not None:
                    skel = skeleton[start:start + len(block)]
                    side_q.put(np.concatenate([block, overlay_skeleton(skel, block)], axis=2))
                yield from block
        finally:
            side_q.put(done)

    def side_frames():
        while (item := side_q.get()) is not done:
            yield from item
        state["side_done"] = True

    def write_side():
        try:
            state["side"] = write_video(side_path, side_frames(), fps)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the main thread
            state["error"] = exc
            while not state.get("side_done") and side_q.get() is not done:  # keep the producer from blocking
                pass

    thread = None
    if side_path is not None:
        thread = threading.Thread(target=write_side, name="oscar-side-by-side", daemon=True)
        thread.start()
    gen = frames()
    try:
        written = write_video(out, gen, fps)
    finally:
        gen.close()
        if not state.get("started"):
            side_q.put(done)
        if thread is not None:
            thread.join()
    if state["error"] is not None:
        raise state["error"]
    return written, state["side"], state["count"]
