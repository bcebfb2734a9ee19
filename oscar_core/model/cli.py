"""The ``oscar rollout`` sub-command (``oscar zoo`` and ``oscar encode-prompt``, which find models by zoo name, are
:mod:`oscar_zoo.cli`'s, on the zoo's floor).

Wire into the main parser with ``add_model_parsers(subparsers)``; each leaf
parser sets ``func`` (returns an exit code) like the other sub-commands.
Heavy imports (torch models, diffusers, huggingface_hub) happen inside the
commands, so ``oscar --help`` stays fast.
"""

from __future__ import annotations

import argparse
import json
import sys

from .._util.arg_types import count, device, interval, number
from .._util.outputs import output_option
from .._util.threads import threads_option
from .presets import SAMPLER_PRESETS
from .rollout_files import RolloutRequest, side_by_side_path

__all__ = [
    "add_model_parsers",
    "cmd_rollout",
    "side_by_side_path",
]

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

_DTYPES = ("float32", "bfloat16", "float16")


def _add_rollout_sampler_options(r) -> None:
    """``oscar rollout``'s sampler options: chunk length, steps, preset, solver, shift, guidance and seed."""
    r.add_argument("--chunk-frames", type=count(1), help="frames per chunk, 4k+1 (default: the model's, e.g. 81)")
    r.add_argument(
        "--steps", type=count(1), help="denoising steps per chunk (default: the model card's, else 35, or the preset's)"
    )
    r.add_argument(
        "--preset",
        choices=sorted(SAMPLER_PRESETS),
        help="sampling budget: paper (35 steps, guidance at every "
        "step) or fast (fewer steps, guidance on part of the noise range; docs/world-model.md); default: "
        "the model card's, else none",
    )
    r.add_argument(
        "--guidance-interval",
        metavar="LO,HI",
        type=interval,
        help="guide only the steps with noise level in [LO, HI]; the others run the conditional branch",
    )
    r.add_argument(
        "--solver",
        choices=("unipc", "euler"),
        help="unipc (2nd order, as Cosmos/diffusers) or euler (default: the checkpoint's scheduler, else unipc)",
    )
    r.add_argument("--shift", type=number(above=0.0), default=5.0, help="flow schedule shift (default 5)")
    r.add_argument(
        "--cond-noise",
        type=number(0.0),
        default=0.0,
        help="conditioning frame fed noised at this level in [0, 1) (default 0: clean; for a model trained with "
        "flow.cond_noise_max)",
    )
    r.add_argument(
        "--guidance",
        type=number(0.0),
        help="skeleton guidance w (default: the model card's, else 6, the "
        "paper's; 0 with --guidance-form diffusers or 1 with standard = conditional branch only)",
    )
    r.add_argument(
        "--guidance-form",
        choices=("diffusers", "standard"),
        help="diffusers (Ho & Salimans, NVIDIA's Cosmos code): v_c + w(v_c - v_u); standard: v_u + "
        "w(v_c - v_u) (default: the model card's, else diffusers)",
    )
    r.add_argument(
        "--action-guidance",
        type=number(0.0),
        help="latent-action models: guidance w over the actions "
        "(unconditional branch: no action tokens; default: none, the conditional branch only)",
    )
    r.add_argument(
        "--two-pass-cfg",
        action="store_true",
        help="run the two guidance branches as two forwards (less memory) instead of one batched forward",
    )
    r.add_argument("--seed", type=count(0), default=0, help="noise seed (same seed, same video)")


def _add_rollout_device_options(r) -> None:
    """``oscar rollout``'s device, precision and memory options (and the output frame rate)."""
    r.add_argument("--fps", type=number(above=0.0), help="output frame rate (default: the trajectory's)")
    r.add_argument("--device", type=device, help="torch device (default: cuda when available, else cpu)")
    threads_option(r)
    r.set_defaults(_resumes=False)  # one video, written whole: Ctrl-C keeps nothing and a rerun starts over
    r.add_argument("--dtype", choices=_DTYPES, help="DiT dtype (default: bfloat16 on CUDA, else float32)")
    from .compile_policy import add_compile_options

    add_compile_options(r)
    r.add_argument("--vae-tiling", action="store_true", help="tile VAE encode/decode (GPU memory)")
    r.add_argument("--vae-slicing", action="store_true", help="VAE one batch element at a time")
    r.add_argument("--offload-vae", action="store_true", help="keep the VAE on the CPU between uses")
    r.add_argument(
        "--offload-text",
        action="store_true",
        help="keep the DiT's text projection on the CPU (the prompt is projected once per chunk)",
    )
    r.add_argument("--offline", action="store_true", help="use only the local Hub cache (like HF_HUB_OFFLINE=1)")
    from .decoder_options import add_decoder_options
    from .encoder_options import add_encoder_option

    add_decoder_options(r)
    add_encoder_option(r)


def _add_rollout_parser(subparsers, fmt) -> None:
    """Register ``oscar rollout`` and its options on ``subparsers``."""
    r = subparsers.add_parser(
        "rollout",
        help="roll the world model out along a trajectory (skeleton-conditioned)",
        epilog=ROLLOUT_EXAMPLES,
        formatter_class=fmt,
    )
    r.add_argument("--model", required=True, help="zoo name, Hub id owner/name, or folder (see `oscar zoo list`)")
    r.add_argument("--revision", help="Hub revision overriding the zoo's pinned one")
    r.add_argument("--embodiment", required=True, help="embodiment name (see `oscar embodiments`)")
    r.add_argument(
        "--first-frame",
        required=True,
        help="first RGB frame taken by --camera: an image (PNG/JPEG) or a video (MP4/MKV/...: its frame 0)",
    )
    r.add_argument("--trajectory", required=True, help="trajectory .npz (docs/formats.md)")
    r.add_argument("--camera", required=True, help="camera calibration .json (docs/formats.md)")
    output_option(
        r.add_argument("--out", required=True, help="rollout video: .mp4 (H.264), .mkv (lossless) or folder/ (PNGs)"),
        "any",
    )
    r.add_argument("--side-by-side", help="side-by-side video path (default: OUT_side.mp4)")
    r.add_argument("--no-side-by-side", action="store_true", help="do not write the side-by-side video")
    text = r.add_mutually_exclusive_group()
    text.add_argument(
        "--prompt",
        help="task text; embedded with the model's text encoder on the first use, then "
        "read from the prompt cache (--prompt-cache)",
    )
    text.add_argument(
        "--prompt-embeds",
        metavar="FILE",
        help="precomputed prompt embedding (.safetensors, tensor 'prompt_embeds' of shape (1, L, D))",
    )
    output_option(
        r.add_argument(
            "--prompt-cache",
            metavar="DIR",
            help="prompt-embedding cache (default: $OSCAR_CACHE/prompt_embeds or ~/.cache/oscar/prompt_embeds)",
        ),
        "folder",
    )
    r.add_argument(
        "--text-encoder",
        metavar="ID_OR_FOLDER",
        help="text encoder for --prompt (default: the checkpoint's text_encoder_id)",
    )
    r.add_argument("--native-file", help="which native Cosmos checkpoint file, when a folder/repo holds several")
    r.add_argument("--size", help="rollout WIDTHxHEIGHT, multiples of 16 (default: the model's, else the camera's)")
    r.add_argument(
        "--resize",
        choices=("crop", "stretch"),
        default="crop",
        help="how camera and first frame are fitted to --size (default: centre crop)",
    )
    _add_rollout_sampler_options(r)
    _add_rollout_device_options(r)
    r.add_argument("--no-progress", action="store_true", help="no progress bars")
    r.add_argument("--json", action="store_true", help="print a machine-readable summary")
    r.set_defaults(func=cmd_rollout)


def add_model_parsers(subparsers) -> None:
    """Add ``rollout`` to an ``argparse`` sub-parser set (``zoo`` and ``encode-prompt``: :mod:`oscar_zoo.cli`)."""
    _add_rollout_parser(subparsers, argparse.RawDescriptionHelpFormatter)


# --------------------------------------------------------------------------- rollout


def cmd_rollout(args) -> int:
    """``oscar rollout``: the options as a :class:`~oscar_core.model.rollout_files.RolloutRequest`, then
    :func:`~oscar_core.model.rollout_files.run_rollout`, then the summary."""
    startup = _seconds_since_process_start()
    from .decoder_options import decoder_choice
    from .encoder_options import encoder_choice
    from .rollout_files import run_rollout

    request = RolloutRequest(
        model=args.model,
        embodiment=args.embodiment,
        first_frame=args.first_frame,
        trajectory=args.trajectory,
        camera=args.camera,
        out=args.out,
        revision=args.revision,
        side_by_side=args.side_by_side,
        no_side_by_side=args.no_side_by_side,
        prompt=args.prompt,
        prompt_embeds=args.prompt_embeds,
        prompt_cache=args.prompt_cache,
        text_encoder=args.text_encoder,
        native_file=args.native_file,
        size=args.size,
        resize=args.resize,
        chunk_frames=args.chunk_frames,
        steps=args.steps,
        preset=args.preset,
        guidance_interval=args.guidance_interval,
        solver=args.solver,
        shift=args.shift,
        cond_noise=args.cond_noise,
        guidance=args.guidance,
        guidance_form=args.guidance_form,
        action_guidance=getattr(args, "action_guidance", None),
        two_pass_cfg=args.two_pass_cfg,
        seed=args.seed,
        fps=args.fps,
        device=args.device,
        dtype=args.dtype,
        compile=args.compile,
        vae_tiling=args.vae_tiling,
        vae_slicing=args.vae_slicing,
        offload_vae=args.offload_vae,
        offload_text=args.offload_text,
        offline=args.offline,
        tiny_decoder=decoder_choice(args),
        tiny_encoder=encoder_choice(args),
        progress=not args.no_progress,
        plugin_paths=tuple(getattr(args, "plugin", None) or ()),
    )
    result = run_rollout(request, notify=lambda line: print(line, file=sys.stderr), startup=startup, given="flag")
    summary = result.summary
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        width, height = summary["size"]
        extra = f" and {summary['side_by_side']}" if "side_by_side" in summary else ""
        print(
            f"wrote {summary['rollout']}{extra}: {summary['frames']} frames, {width}x{height}, "
            f"{summary['fps']:g} fps, {summary['chunks']} chunk(s)"
        )
        print(
            "seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in result.timings.items()) + f" ({summary['compile']})",
            file=sys.stderr,
        )
    return 0


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
