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

__all__ = ["add_model_parsers", "cmd_rollout", "cmd_zoo_list", "cmd_zoo_pull", "side_by_side_path"]

ROLLOUT_EXAMPLES = """examples:
  oscar rollout --model oscar-2b --embodiment franka --first-frame img.png --trajectory traj.npz \\
      --camera cam.json --prompt "put the cup in the sink" --out video.mp4
  oscar rollout ... --out video.mp4 --side-by-side compare.mp4 --device cuda --dtype bfloat16 --vae-tiling
  oscar rollout ... --prompt-embeds embeds.safetensors --steps 20 --seed 3 --json

The rollout is written to --out; a side-by-side video (rollout | skeleton over
the rollout) to --side-by-side (default: OUT_side.mp4).
"""

ZOO_EXAMPLES = """examples:
  oscar zoo list
  oscar zoo list --json
  oscar zoo pull oscar-2b
  HF_HUB_OFFLINE=1 oscar zoo pull oscar-2b     (check that the cache holds it)
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
    text.add_argument("--prompt", help="task text; its embedding must be in the prompt cache (--prompt-cache)")
    text.add_argument("--prompt-embeds", metavar="FILE", help="precomputed prompt embedding (.safetensors, tensor "
                      "'prompt_embeds' of shape (1, L, D))")
    r.add_argument("--prompt-cache", metavar="DIR", help="prompt-embedding cache (default: $OSCAR_CACHE/prompt_embeds "
                   "or ~/.cache/oscar/prompt_embeds)")
    r.add_argument("--size", help="rollout WIDTHxHEIGHT, multiples of 16 (default: the model's, else the camera's)")
    r.add_argument("--resize", choices=("crop", "stretch"), default="crop",
                   help="how camera and first frame are fitted to --size (default: centre crop)")
    r.add_argument("--chunk-frames", type=int, help="frames per chunk, 4k+1 (default: the model's, e.g. 81)")
    r.add_argument("--steps", type=int, default=35, help="denoising steps per chunk (default 35)")
    r.add_argument("--shift", type=float, default=5.0, help="flow schedule shift (default 5)")
    r.add_argument("--guidance", type=float, default=6.0, help="skeleton guidance w (default 6; 0 with --guidance-form "
                   "diffusers or 1 with standard = conditional only)")
    r.add_argument("--guidance-form", choices=("standard", "diffusers"), default="standard",
                   help="standard: v_u + w(v_c - v_u) (paper); diffusers: v_c + w(v_c - v_u)")
    r.add_argument("--two-pass-cfg", action="store_true", help="run the two guidance branches as two forwards "
                   "(less memory) instead of one batched forward")
    r.add_argument("--seed", type=int, default=0, help="noise seed (same seed, same video)")
    r.add_argument("--fps", type=float, help="output frame rate (default: the trajectory's)")
    r.add_argument("--device", default="cpu", help="torch device (cpu, cuda, cuda:1)")
    r.add_argument("--dtype", choices=_DTYPES, default="float32", help="DiT dtype (bfloat16 on GPUs)")
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
    zp.set_defaults(func=cmd_zoo_pull)


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
        rows.append((s.name, f"{s.repo_id}@{s.revision or 'main (unpinned)'}", s.kind, s.license or "?",
                     ",".join(s.embodiments) or "-", str(s.chunk_frames or "?"),
                     f"{s.width}x{s.height}" if s.width and s.height else "?", f"{s.fps:g}" if s.fps else "?"))
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    for row in rows:
        print("  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip())
    print(f"user registry: {oscar_zoo.registry_path()}", file=sys.stderr)
    return 0


def cmd_zoo_pull(args) -> int:
    import oscar_zoo

    folder = oscar_zoo.pull(args.name, args.revision, force_download=args.force,
                            local_files_only=True if args.offline else None)
    if args.json:
        print(json.dumps({"name": args.name, "folder": str(folder)}))
    else:
        print(f"{args.name}: verified, in {folder}")
    return 0


# --------------------------------------------------------------------------- rollout


def _prompt_embeds(args, model):
    import torch

    from .text import PromptEmbeddingCache

    if args.prompt_embeds:
        from safetensors.torch import load_file

        from ._weights import check_safetensors

        check_safetensors(args.prompt_embeds)
        tensors = load_file(args.prompt_embeds)
        if "prompt_embeds" in tensors:
            return tensors["prompt_embeds"]
        if len(tensors) == 1:
            return next(iter(tensors.values()))
        from ..errors import InputFileError

        raise InputFileError(args.prompt_embeds, "tensors", "a tensor named 'prompt_embeds'", sorted(tensors))
    if args.prompt is None:
        return None
    encoder = model.card.text_encoder_id or "unknown-encoder"
    cache = PromptEmbeddingCache(args.prompt_cache, encoder_id=encoder)
    found = cache.get(args.prompt)
    if found is None:
        from .errors import ModelInputError

        raise ModelInputError(
            f"{cache.root}: prompt {args.prompt!r}: expected a cached embedding made by encoder {encoder!r} "
            f"({cache.path(args.prompt).name}), found none; compute it once with that text encoder and store it "
            f"with oscar_core.model.PromptEmbeddingCache({str(cache.root)!r}, {encoder!r}).put(prompt, embeds), "
            "or pass --prompt-embeds FILE")
    return found.to(torch.float32)


def _rollout_size(args, card, camera) -> tuple[int, int]:
    from ..pipeline import parse_size
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
    import numpy as np
    import torch

    import oscar_zoo

    from ..errors import InputFileError
    from ..pipeline import fit_image, overlay_skeleton, render_skeleton_video
    from ..registry import get_embodiment
    from ..trajectory import load_trajectory
    from ..video import write_video
    from ._image import read_image
    from .sampler import SamplerConfig

    emb = get_embodiment(args.embodiment, getattr(args, "plugin", None) or ())
    traj = load_trajectory(args.trajectory)
    camera = emb.load_camera(args.camera)
    first = read_image(args.first_frame)
    cam_size = (camera.intrinsics.width, camera.intrinsics.height)
    if (first.shape[1], first.shape[0]) != cam_size:
        raise InputFileError(args.first_frame, "image size", f"{cam_size[0]}x{cam_size[1]} (the image size of camera "
                             f"{args.camera})", f"{first.shape[1]}x{first.shape[0]}")
    sampler = SamplerConfig(steps=args.steps, shift=args.shift, guidance=args.guidance,
                            guidance_form=args.guidance_form, batched_cfg=not args.two_pass_cfg)
    dtype = getattr(torch, args.dtype)
    model = oscar_zoo.load(args.model, args.revision, device=args.device, dtype=dtype,
                           offload_vae=args.offload_vae, offload_text=args.offload_text,
                           local_files_only=True if args.offline else None)
    if args.vae_tiling:
        model.enable_vae_tiling()
    if args.vae_slicing:
        model.enable_vae_slicing()
    width, height = _rollout_size(args, model.card, camera)
    skeleton = render_skeleton_video(emb, traj, camera, (width, height), resize_mode=args.resize,
                                     camera_source=args.camera)
    first = fit_image(first, width, height, args.resize)
    prompt = _prompt_embeds(args, model)
    if model.card.fps and abs(model.card.fps - traj.fps) > 1e-6:
        print(f"warning: {args.trajectory} is at {traj.fps:g} fps but the model was trained at {model.card.fps:g} fps; "
              "resample the trajectory for faithful motion speed", file=sys.stderr)
    result = model.rollout(first, skeleton, prompt, chunk_frames=args.chunk_frames, sampler=sampler, seed=args.seed,
                           progress=not args.no_progress, keep_chunks=False)
    fps = args.fps or traj.fps
    out = write_video(args.out, result.frames, fps)
    summary = {"rollout": str(out), "frames": int(len(result.frames)), "size": [width, height], "fps": fps,
               "chunks": len(result.starts), "model": args.model, "seed": args.seed,
               "guidance": {"w": args.guidance, "form": args.guidance_form}}
    if not args.no_side_by_side:
        side = np.concatenate([result.frames, overlay_skeleton(skeleton, result.frames)], axis=2)
        summary["side_by_side"] = str(write_video(args.side_by_side or side_by_side_path(args.out), side, fps))
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        extra = f" and {summary['side_by_side']}" if "side_by_side" in summary else ""
        print(f"wrote {out}{extra}: {summary['frames']} frames, {width}x{height}, {fps:g} fps, "
              f"{summary['chunks']} chunk(s)")
    return 0
