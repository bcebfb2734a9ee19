"""Roll a world model out from files: the Python function behind ``oscar rollout``.

:func:`run_rollout` takes a :class:`RolloutRequest` (the same fields as the
command's options: a model by zoo name, Hub id or folder; an embodiment; a
first frame, trajectory and camera file; where to write the video) and returns
a :class:`RolloutFilesResult` with what it wrote and its summary (the
``--json`` output of the command). Everything is checked before the weights
load: the output paths, the rollout size, the memory the condition video needs.

Example::

    from oscar_core.model.rollout_files import RolloutRequest, run_rollout

    result = run_rollout(RolloutRequest(model="oscar-toy", embodiment="toyarm", first_frame="f0.png",
                                        trajectory="t.npz", camera="c.json", out="rollout.mp4"))
    print(result.out, result.summary["frames"])

Messages a person should see while it runs (what the text embedding is, a frame-rate mismatch, how the model
was loaded) go to ``notify`` (default: the ``oscar`` logger at WARNING for warnings, INFO otherwise).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from .._util.log import get_logger

__all__ = ["RolloutRequest", "RolloutFilesResult", "run_rollout", "side_by_side_path"]

_log = get_logger(__name__)


def side_by_side_path(out) -> Path:
    """Default side-by-side path: ``video.mp4`` → ``video_side.mp4`` (a folder ``frames/`` → ``frames_side/``)."""
    out = Path(out)
    return out.with_name(f"{out.stem}_side{out.suffix}") if out.suffix else out.with_name(f"{out.name}_side")


@dataclass(frozen=True)
class RolloutRequest:
    """One rollout from files; every field is the ``oscar rollout`` option of the same name.

    model: zoo name, Hub id ``owner/name`` or folder; embodiment: an installed embodiment's name;
    first_frame: RGB image (PNG/JPEG) taken by ``camera``; trajectory: ``.npz``; camera: calibration ``.json``;
    out: ``.mp4`` (H.264), ``.mkv`` (lossless) or ``folder/`` (PNGs). side_by_side: the side-by-side video
    (None: :func:`side_by_side_path`; ``no_side_by_side``: none). size: ``"WIDTHxHEIGHT"``, multiples of 16 (None:
    the model's, else the camera's). Sampler: ``steps``, ``guidance`` w, ``guidance_form`` and ``preset``
    (None: the model card's recommendation, else the library's 35 steps, guidance 6, diffusers form, no preset:
    :func:`~oscar_core.model.sampler.resolve_sampler`), ``guidance_interval`` (lo, hi), ``solver``, ``shift``, ``cond_noise``,
    ``action_guidance`` (latent-action models), ``two_pass_cfg``. fps: output frame rate (None: the
    trajectory's). device / dtype: None chooses (CUDA when available; bfloat16 on CUDA, else float32).
    plugin_paths: plugin files or folders to load besides the installed ones.
    """

    model: str
    embodiment: str
    first_frame: str
    trajectory: str
    camera: str
    out: str
    revision: str | None = None
    side_by_side: str | None = None
    no_side_by_side: bool = False
    prompt: str | None = None
    prompt_embeds: str | None = None
    prompt_cache: str | None = None
    text_encoder: str | None = None
    native_file: str | None = None
    size: str | None = None
    resize: Literal["crop", "stretch"] = "crop"
    chunk_frames: int | None = None
    steps: int | None = None
    preset: str | None = None
    guidance_interval: tuple[float, float] | None = None
    solver: str | None = None
    shift: float = 5.0
    cond_noise: float = 0.0
    guidance: float | None = None
    guidance_form: Literal["diffusers", "standard"] | None = None
    action_guidance: float | None = None
    two_pass_cfg: bool = False
    seed: int = 0
    fps: float | None = None
    device: str | None = None
    dtype: str | None = None
    compile: str = "auto"
    vae_tiling: bool = False
    vae_slicing: bool = False
    offload_vae: bool = False
    offload_text: bool = False
    offline: bool = False
    tiny_decoder: object = None  # None: the card's decoder; False: the full decoder; a path: that tiny decoder
    tiny_encoder: object = None  # None: the full condition encoder; a path: that tiny encoder for the condition
    progress: bool = True
    plugin_paths: tuple[str, ...] = ()


@dataclass
class RolloutFilesResult:
    """What :func:`run_rollout` wrote: ``out`` (the rollout), ``side_by_side`` (or None), and ``summary`` (frames,
    size, fps, chunks, model, seed, text, sampler, steps, guidance, condition, compile, dtype, device, timings in
    seconds: the ``oscar rollout --json`` object)."""

    out: Path
    side_by_side: Path | None
    summary: dict = field(default_factory=dict)
    #: seconds per phase (startup, import, load, render, text, compile, encode, sample, decode, write, wall), unrounded
    timings: dict = field(default_factory=dict)


def _notify_log(message: str) -> None:
    (_log.warning if message.startswith("warning: ") else _log.info)(message)


def _sampler_options(r: RolloutRequest) -> dict:
    """The request's sampler options as :func:`~oscar_core.model.card_sampler.resolve_sampler` takes them."""
    return dict(
        steps=r.steps,
        preset=r.preset,
        guidance_interval=r.guidance_interval,
        shift=r.shift,
        cond_noise=r.cond_noise,
        guidance=r.guidance,
        guidance_form=r.guidance_form,
        batched_cfg=not r.two_pass_cfg,
        solver=r.solver,
        action_guidance=r.action_guidance,
    )


def _check_outputs(r: RolloutRequest, n_frames: int) -> str | Path | None:
    """Checks the output paths and that the condition video of ``n_frames`` frames at ``--size`` fits in memory,
    before any weights load (gigabytes for the 2B: a typo costs a second, not minutes). Returns the side-by-side
    path (None with ``no_side_by_side``)."""
    from ..media.video import check_output
    from ..render.skeleton_video import parse_size

    size = parse_size(r.size) if r.size else None
    check_output(r.out, size=size)
    if size is not None:  # the skeleton video of the whole trajectory is held in memory
        from .._util.memory import check_fits

        check_fits(
            (n_frames, size[1], size[0], 3),
            1,
            "the skeleton video (T, H, W, 3) uint8 at --size",
            "use a smaller --size",
        )
    side_path = None if r.no_side_by_side else (r.side_by_side or side_by_side_path(r.out))
    if side_path is not None:
        check_output(side_path)
    return side_path


def _load_model(r: RolloutRequest, device, dtype, say: Callable[[str], None], timings: dict):
    """The world model of ``r.model`` on ``device`` in ``dtype``, with the request's compile and VAE memory
    settings; adds diffusers' import to ``timings["import"]`` and sets ``timings["load"]`` (seconds)."""
    import oscar_zoo

    report: list[str] = []
    t0 = time.perf_counter()
    if _loads_without_network(r):  # online, diffusers' import waits until the Hub has answered (OSCAR_HUB_TIMEOUT)
        from .world_model import OscarWorldModel  # noqa: F401 - diffusers (~3 s on a CPU): counted as import
    timings["import"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    model = oscar_zoo.load(
        r.model,
        r.revision,
        device=device,
        dtype=dtype,
        offload_vae=r.offload_vae,
        offload_text=r.offload_text,
        local_files_only=True if r.offline else None,
        native_file=r.native_file,
        report=report,
        tiny_decoder=r.tiny_decoder,
        tiny_encoder=r.tiny_encoder,
    )
    timings["load"] = time.perf_counter() - t0
    for line in report:
        say(line)
    model.set_compile(r.compile)
    if r.vae_tiling:
        model.enable_vae_tiling()
    if r.vae_slicing:
        model.enable_vae_slicing()
    return model


def _condition_and_first_frame(r: RolloutRequest, model, emb, traj, camera, first, size: tuple[int, int]):
    """``(condition, first)`` at the rollout ``size`` (width, height): the card's condition video (the skeleton, or
    the mesh / capsules for a model trained on those), (T, H, W, 3) uint8, and the first frame fitted to it."""
    from ..render.conditions import condition_video, video_condition_of
    from ..render.skeleton_video import fit_image

    condition = condition_video(
        video_condition_of(model.card.condition),
        emb,
        traj,
        camera,
        size,
        resize_mode=r.resize,
        camera_source=r.camera,
        style=model.card.condition_style,
    )
    return condition, fit_image(first, size[0], size[1], r.resize)


def _per_frame_inputs(model, emb, traj, camera, latent_action: bool):
    """``(actions, gripper)``: the latent actions of a latent-action model (else None) and, for a model that takes
    the gripper's openness beside its condition video, the trajectory's openness per frame (else None)."""
    from .gripper_signal import gripper_input

    actions = model.rollout_inputs(traj, camera, emb)["actions"] if latent_action else None
    return actions, gripper_input(model.card, emb, traj).get("gripper")


def _rollout_summary(
    r: RolloutRequest,
    model,
    choice,
    out,
    count: int,
    size,
    fps: float,
    n_chunks: int,
    text_source,
    device,
    timings: dict,
) -> dict:
    """The ``oscar rollout --json`` object: what was written (``count`` frames of ``size`` (width, height) at
    ``fps``), the sampler and where its settings came from, the model's condition, dtype and device, and
    ``timings`` in seconds (rounded to ms)."""
    import torch

    sampler = choice.config
    summary = {
        "rollout": str(out),
        "frames": count,
        "size": list(size),
        "fps": fps,
        "chunks": n_chunks,
        "model": r.model,
        "seed": r.seed,
        "text": text_source,
        "sampler": model.sampler_for(sampler).resolved_solver,
        "steps": sampler.steps,
        "unconditional_skeleton": model.card.unconditional_skeleton,
        "guidance": {"w": sampler.guidance, "form": sampler.guidance_form},
        "preset": choice.preset,
        "sampler_sources": dict(choice.sources),
        "condition": model.card.condition,
        "decoder": "full" if model.vae.tiny is None else "tiny",
        "condition_encoder": "full" if model.vae.tiny_encoder is None else "tiny",
        "compile": model.compile_reason,
        "dtype": str(next(model.transformer.parameters()).dtype),
        "device": str(device),
        "timings": {k: round(v, 3) for k, v in timings.items()},
    }
    if str(device).startswith("cuda"):  # which GPU the timings were measured on
        summary["device_name"] = torch.cuda.get_device_name(torch.device(device))
    return summary


def run_rollout(
    request: RolloutRequest,
    *,
    notify: Callable[[str], None] | None = None,
    startup: float | None = None,
    given: str = "request",
) -> RolloutFilesResult:
    """Roll ``request.model`` out along ``request.trajectory`` from ``request.first_frame`` and write the videos.

    Steps: read the inputs (embodiment, trajectory, camera, first frame) and the sampler options, check the
    outputs and the memory the condition video needs, load the model (``oscar_zoo.load``), render the card's
    condition video at the rollout size, embed the prompt, roll out chunk by chunk while writing ``out`` (and
    the side-by-side: rollout | condition over rollout) as chunks arrive. notify: called with each message a
    person should see (default: logged), among them the sampler settings used and where each came from
    (``given``: what to call the request's own values, e.g. "flag"; the model card; the library default).
    startup: seconds the process spent before this call (counted in the summary's timings). Raises an :class:`~oscar_core.errors.OscarError` naming the file or option for bad
    input, before any weights load.
    """
    t_start = time.perf_counter()
    say = notify or _notify_log
    import numpy as np
    import torch

    from .._util.devices import default_device
    from ..kinematics.trajectory import load_trajectory
    from ..plugin.registry import get_embodiment
    from ..render.conditions import takes_actions
    from .card_sampler import resolve_sampler
    from .decoder_options import check_decoder_choice
    from .encoder_options import check_encoder_choice
    from .image import read_first_frame
    from .rollout import RolloutResult

    r = request
    timings = {"startup": startup} if startup is not None else {}
    timings["import"] = time.perf_counter() - t_start
    emb = get_embodiment(r.embodiment, r.plugin_paths or ())
    traj = load_trajectory(r.trajectory)
    camera = emb.load_camera(r.camera)
    first = read_first_frame(r.first_frame, camera, r.camera)
    resolve_sampler(None, **_sampler_options(r))  # the given options checked before any weights load
    check_decoder_choice(r.tiny_decoder)
    check_encoder_choice(r.tiny_encoder)
    side_path = _check_outputs(r, len(traj))
    device = r.device or default_device()
    dtype = getattr(torch, r.dtype or ("bfloat16" if str(device).startswith("cuda") else "float32"))
    model = _load_model(r, device, dtype, say, timings)
    choice = resolve_sampler(model.card.sampler, **_sampler_options(r))
    say(f"sampler: {choice.describe(given)}")
    width, height = rollout_size(r, model.card, camera)
    t0 = time.perf_counter()
    skeleton, first = _condition_and_first_frame(r, model, emb, traj, camera, first, (width, height))
    timings["render"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    prompt, text_source = prompt_embeds_for(r, model, device)
    timings["text"] = time.perf_counter() - t0
    say(f"text: {text_source}")
    if prompt is None and model.empty_prompt is None:
        prompt = torch.zeros(1, 1, model.transformer.text_dim)
    if model.card.fps and abs(model.card.fps - traj.fps) > 1e-6:
        say(
            f"warning: {r.trajectory} is at {traj.fps:g} fps but the model was trained at {model.card.fps:g} fps; "
            "resample the trajectory for faithful motion speed"
        )
    fps = r.fps or traj.fps
    result = RolloutResult(frames=np.empty(0, np.uint8))
    latent_action = takes_actions(model.card.condition)
    t0 = time.perf_counter()
    actions, gripper = _per_frame_inputs(model, emb, traj, camera, latent_action)
    timings["render"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    chunks = model.iter_rollout(
        first,
        None if latent_action else skeleton,
        prompt,
        chunk_frames=r.chunk_frames,
        sampler=choice.config,
        seed=r.seed,
        progress=r.progress,
        result=result,
        actions=actions,
        gripper=gripper,
    )
    # torch.compile's set-up when the policy compiles (mostly inductor's imports, ~1.5 s on a CPU; 0 eager); the
    # compile itself runs inside the first chunk's sample
    timings["compile"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    out, side_out, count = _write_streams(chunks, skeleton, r.out, side_path, fps)
    streamed = time.perf_counter() - t0
    timings.update({k: result.timings.get(k, 0.0) for k in ("encode", "sample", "decode")})
    timings["write"] = max(streamed - sum(result.timings.values()), 0.0)  # what streaming added beyond the model
    timings["wall"] = time.perf_counter() - t_start + (startup or 0.0)
    summary = _rollout_summary(
        r, model, choice, out, count, (width, height), fps, len(result.starts), text_source, device, timings
    )
    if latent_action:
        summary["guidance"] = {"action_w": choice.config.action_guidance, "form": choice.config.guidance_form}
    if side_out is not None:
        summary["side_by_side"] = str(side_out)
    return RolloutFilesResult(Path(str(out)), None if side_out is None else Path(str(side_out)), summary, timings)


def rollout_size(args, card, camera) -> tuple[int, int]:
    """(width, height) of the rollout: ``args.size``, else the card's training size, else the camera's; both
    multiples of 16 (VAE x DiT patch)."""
    from ..render.skeleton_video import parse_size
    from .errors import ModelInputError

    if args.size:
        size, origin = parse_size(args.size), "--size"
    elif card.width and card.height:
        size, origin = (card.width, card.height), "the model's training size"
    else:
        size, origin = (camera.intrinsics.width, camera.intrinsics.height), f"the camera's image size ({args.camera})"
    if size[0] % 16 or size[1] % 16:
        raise ModelInputError(
            f"rollout size: expected width and height divisible by 16 (VAE x DiT patch), found "
            f"{size[0]}x{size[1]} from {origin}; pass --size, e.g. "
            f"{size[0] // 16 * 16}x{size[1] // 16 * 16}"
        )
    return size


def _loads_without_network(args) -> bool:
    """Whether ``args.model`` loads from disk only: a folder, a model bundled with oscar, or ``--offline``."""
    import oscar_zoo

    if args.offline:
        return True
    try:
        resolved = oscar_zoo.resolve(args.model, args.revision)
    except oscar_zoo.UnknownModelError:
        return False  # the load reports it
    return resolved.folder is not None or bool(resolved.spec is not None and resolved.spec.bundled)


def text_encoder(encoder_id: str, device, dtype, offline: bool):
    import torch

    from .text_encoder import TextEncoder

    dt = getattr(torch, dtype) if dtype else None
    return TextEncoder.from_hub(encoder_id, device=device, dtype=dt, local_files_only=True if offline else None)


def prompt_embeds_for(args, model, device) -> tuple:
    """(embedding or None, where it came from) for a :class:`RolloutRequest` (``args``) — never a silent zero
    embedding."""
    import torch

    from .text import PromptEmbeddingCache

    if args.prompt_embeds:
        from safetensors.torch import load_file

        from .weights import check_safetensors

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
            return None, (
                "ZERO text embedding: no --prompt and the checkpoint names no text encoder "
                "(text_encoder_id) and ships no empty-prompt embedding"
            )
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
            "--text-encoder ID_OR_FOLDER, or --prompt-embeds FILE"
        )
    text = text_encoder(encoder, device, None, args.offline)
    embeds, _ = text.cached(prompt, args.prompt_cache)
    return embeds.to(torch.float32), f"{what}, computed with {text.encoder_id} and cached"


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
                    skel = skeleton[start : start + len(block)]
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
