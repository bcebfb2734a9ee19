"""Speed of the teacher, ``--preset fast`` and the distilled few-step student: evaluations, FLOPs, seconds per chunk.

    python benchmarks/distill_speed.py [--student FOLDER] [--repeats 5] [--device cpu|cuda] [--dtype float32|bfloat16]
                                       [--json benchmarks/results/distill_speed.json]
    python benchmarks/distill_speed.py --closed-loop-2b-only --json benchmarks/measured/distill_speed.json

Rows: the teacher (the bundled ``oscar-toy``) at ``--preset paper`` (35 UniPC steps, guidance every step), at its
card's sampler (20 steps, guidance 3) and at ``--preset fast`` (12 steps, guidance at σ ≤ 0.8); the student
(``--student``: an oscar model folder of a distilled student, e.g. ``oscar train`` with a ``distill:`` section)
at its card's steps and at 2 and 1 Euler steps, guidance folded in (one branch). Without ``--student`` the
student rows sample the teacher's weights with the student's sampler (4/2/1 Euler steps, no guidance): the
same architecture, so the same work; the JSON says which weights ran.

For one 17-frame 64x64 chunk of a toyarm episode (``oscar toyworld`` episode 0, seed 0), on ``--device`` with
``torch.set_num_threads(--threads)``:

* ``dit_evaluations``: DiT evaluations per chunk COUNTED on the real model (batch items of every forward of the
  transformer, seen by a forward pre-hook) and checked equal to ``oscar_core.model.sampler.model_calls``;
* FLOPs per chunk counted by ``torch.utils.flop_counter.FlopCounterMode`` (DiT sampling, VAE encodes, VAE decode);
* CPU seconds (``time.process_time``) and wall seconds per chunk, median of ``--repeats`` after one warm-up, split
  into the condition render (skeleton video of the chunk's trajectory), the VAE encode of the first frame, the VAE
  encode of the condition video, the DiT sampling and the VAE decode of the chunk.

The 2B model at the paper's size (81 frames, 512x288) is COMPUTED, not measured: DiT evaluations x the FLOPs of
one evaluation of batch 1 (``flops.step_conditional`` of ``benchmarks/measured/rollout_gpu.json``: torch's FLOP
counter on the real 2B, bf16, one H100), over a stated throughput, plus the VAE's seconds per chunk:

* H200: 576 TFLOP/s, the compiled DiT's throughput and ≈ 2.1 s of VAE (encode x2 + decode) per chunk measured on
  one H200 (the compiled 2B guided step took 0.275 s for 158.4 TFLOP) in the measurement quoted in
  docs/world-model.md, which this repository does not hold as JSON;
* H100 (assumed): the H200's figures scaled by the two cards' published dense BF16 peaks (989.4 TFLOP/s each for
  the SXM parts, so the same 576 TFLOP/s and 2.1 s);
* H100 eager (measured parts): the eager conditional step and the VAE encode + decode seconds that
  ``benchmarks/measured/rollout_gpu.json`` measured on one H100.

Frames/s counts 80 new frames per 81-frame chunk (a later chunk's first frame is the previous chunk's last).

The VAE's share, and what cuts it (``vae_cut``): WAN's causal decoder turns latent frames into pixels one at a time,
each step reading a cache of the previous step's features in every causal convolution, so a single pixel frame of
a chunk cannot be decoded exactly without decoding every latent frame before it (nor "every 8th frame"). What a
closed loop can do instead is decode only the chunk's end as if it began there: the last latent frame alone (one
pixel frame) or the last two or three (the last frame with one or two latent frames of causal context). They are
measured on the toy VAE (milliseconds, and the PSNR of the last frame against the full decode's), and their FLOP
ratio to the full decode is counted at the 2B size on the meta device (WAN 2.1 VAE, 21 latent frames of 64x36),
giving the 2B chunk's computed seconds with that decode.

The 2B closed-loop step (``closed_loop_2b``, computed): what ``oscar eval closed-loop`` asks of the 2B per chunk with a
4-step sampler without guidance (4 DiT evaluations): the VAE encode of the seed frame (1 frame: the session's first
frame in a cell's first chunk, the last generated frame after that, so nothing to cache past chunk 0), the full VAE
encode of the chunk's 81-frame condition video (every chunk; nothing of it is cached), and the decode, by the full
WAN 2.1 decoder or by the tiny decoder (``oscar_core.model.tiny_decoder.TinyDecoderNet`` at ``taew2_1``'s widths), and
the condition encode by the full encoder or by the tiny encoder (``oscar_core.model.tiny_encoder.TinyEncoderNet`` at
``taew2_1``'s width, the condition padded at its end to 84 frames; the seed frame stays with the full encoder, as
``--tiny-encoder`` does).
Every part's FLOPs are counted at the 2B's shapes on the meta device. No record splits the H200's measured 2.1 s of
VAE into encode and decode, so each VAE part gets the share of a card's VAE seconds that its FLOPs have of the VAE's
(the decode: 0.624 by FLOPs, against 0.620 measured on one H100, eager); the tiny decoder and the tiny encoder are
ASSUMED to run at the FLOP rate the full VAE ran at on that card (H200: 162.5 TFLOP in 2.1 s, 77 TFLOP/s), not
measured. Rows: the full VAE, the tiny decoder, the tiny decoder with the tiny condition encoder, and the tiny decoder
with no condition encode at all (the most any caching of the condition could save); per card the seconds, frames/s, the VAE's share and whether the targets (>= 60 frames/s, VAE <= 40 %)
are met, and the largest condition encode (seconds, share of today's) with which the tiny-decoder step would meet
both. ``--closed-loop-2b-only`` counts and computes these rows alone (seconds, no model run) and adds them to the
``--json`` file, whose measured fields stay as they were; the section keeps its own provenance.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from contextlib import contextmanager
from pathlib import Path

for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import provenance, with_provenance  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
GPU_JSON = REPO / "benchmarks" / "measured" / "rollout_gpu.json"

#: (row name, which model, resolve_sampler options): the card's sampler under these options
ROWS = (
    ("teacher, --preset paper", "teacher", {"preset": "paper"}),
    ("teacher, card", "teacher", {}),
    ("teacher, --preset fast", "teacher", {"preset": "fast"}),
    ("student, card", "student", {}),
    ("student, 2 steps", "student", {"steps": 2}),
    ("student, 1 step", "student", {"steps": 1}),
)
#: the student's sampler when no student folder is given (what ``oscar train``'s distill export writes)
STUDENT_CARD_SAMPLER = {"steps": 4, "guidance": None, "guidance_form": "diffusers", "preset": None}
PARTS = ("render", "encode_first", "encode_condition", "dit", "decode")
VAE_PARTS = ("encode_first", "encode_condition", "decode")

H200_TFLOPS = 576.0  # compiled 2B DiT on one H200 (158.4 TFLOP in 0.275 s); docs/world-model.md
H200_VAE_S = 2.1  # VAE encode x2 + decode of one 81-frame 512x288 chunk, same H200 measurement
PEAK_BF16 = {"H100 SXM": 989.4, "H200": 989.4}  # dense BF16 tensor-core peaks (NVIDIA datasheets), TFLOP/s
NEW_FRAMES = 80  # new frames per 81-frame chunk of the 2B
GOAL_FPS = 25.0
#: the 2B closed-loop step's targets: frames/s computed on one H200 and the VAE's largest share of the step
CLOSED_LOOP_TARGETS = {"frames_per_s": 60.0, "vae_share": 0.40}
CLOSED_LOOP_EVALUATIONS = 4  # a 4-step sampler without guidance: one DiT evaluation per step
TINY_BOTH_ROW = "tiny decoder + tiny condition encoder"  # the closed-loop row with both tiny parts
#: decodes of a chunk's end alone: (name, latent frames from the end)
END_DECODES = (("last latent frame", 1), ("last 2 latent frames", 2), ("last 3 latent frames", 3))


# --------------------------------------------------------------------------- counting


@contextmanager
def counting_evaluations(transformer):
    """Count DiT evaluations while the block runs: yields a dict whose ``"items"`` is the batch items of every
    forward of ``transformer`` (a guided step of batch 1 in one forward of batch 2 is 2) and ``"forwards"`` the
    calls."""
    seen = {"items": 0, "forwards": 0}

    def hook(module, args, kwargs):
        x = kwargs.get("hidden_states", args[0] if args else None)
        seen["items"] += int(x.shape[0])
        seen["forwards"] += 1

    handle = transformer.register_forward_pre_hook(hook, with_kwargs=True)
    try:
        yield seen
    finally:
        handle.remove()


def chunk_inputs(frames: int, width: int, height: int, seed: int = 0) -> dict:
    """The inputs of one chunk: a toyarm episode of the toy world (``frames`` frames at ``width`` x ``height``)."""
    from oscar_core.plugin.registry import get_embodiment
    from oscar_core.toyworld.episode import episode_rng, make_episode

    emb = get_embodiment("toyarm")
    ep = make_episode(emb, episode_rng(seed, "toyarm", 0), width, height, frames)
    return {"emb": emb, "trajectory": ep.trajectory, "camera": ep.camera, "first": ep.rgb[0]}


def chunk_parts(model, inputs: dict, sampler, seed: int = 0):
    """One chunk, part by part: ``{part: zero-argument callable}`` in :data:`PARTS` order, each taking its input
    from the one before (the render's video feeds the condition encode, the sample feeds the decode)."""
    from oscar_core.model.sampler import sample_chunk
    from oscar_core.model.vae import VideoVAE
    from oscar_core.render.skeleton_video import render_skeleton_video

    vae, state = model.vae, {}
    prompt = model.prompt_embeds(None)
    device = model.device

    def render():
        state["skeleton"] = render_skeleton_video(inputs["emb"], inputs["trajectory"], inputs["camera"])

    def encode_first():
        state["first"] = vae.encode(VideoVAE.to_pixels(inputs["first"][None]))

    def encode_condition():
        state["condition"] = vae.encode(VideoVAE.to_pixels(state["skeleton"]))

    def dit():
        if "uncond" not in state:  # a rollout encodes the black video once per chunk size, not per chunk
            black = model.card.unconditional_skeleton == "black_video"
            state["uncond"] = vae.encode(VideoVAE.to_pixels(np.zeros_like(state["skeleton"]))) if black else None
        g = torch.Generator().manual_seed(seed)
        state["latent"] = sample_chunk(
            model.transformer,
            state["first"],
            state["condition"],
            prompt.to(device),
            sampler,
            g,
            uncond_skeleton=state["uncond"],
        )

    def decode():
        state["video"] = vae.decode(state["latent"])

    return dict(zip(PARTS, (render, encode_first, encode_condition, dit, decode))), state


def count_dit_evaluations(model, sampler, inputs: dict) -> dict:
    """Run one chunk and count its DiT evaluations on the real transformer: ``{"items", "forwards"}``."""
    parts, _ = chunk_parts(model, inputs, sampler)
    for name in PARTS[:3]:
        parts[name]()
    with counting_evaluations(model.transformer) as seen:
        parts["dit"]()
    return dict(seen)


def flops_of(fn) -> int:
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter, torch.no_grad():
        fn()
    return int(counter.get_total_flops())


# --------------------------------------------------------------------------- timing


def _sync(device) -> None:
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize()


def time_parts(parts: dict, repeats: int, device) -> dict:
    """Median wall and CPU seconds of each part over ``repeats`` chunks, after one warm-up chunk."""
    for fn in parts.values():
        fn()
    _sync(device)
    wall = {p: [] for p in parts}
    cpu = {p: [] for p in parts}
    for _ in range(repeats):
        for name, fn in parts.items():
            t0, c0 = time.perf_counter(), time.process_time()
            with torch.no_grad():
                fn()
            _sync(device)
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
    return {
        "wall_s": {p: statistics.median(v) for p, v in wall.items()},
        "cpu_s": {p: statistics.median(v) for p, v in cpu.items()},
    }


def psnr_db(a: torch.Tensor, b: torch.Tensor) -> float:
    """PSNR of two [-1, 1] images (peak-to-peak 2)."""
    mse = float(((a.float() - b.float()) ** 2).mean())
    return float("inf") if mse == 0 else 10.0 * np.log10(4.0 / mse)


def toy_vae_cut(model, latent: torch.Tensor, full_video: torch.Tensor, repeats: int, device) -> list[dict]:
    """Decode of the whole chunk against the chunk's end alone (:data:`END_DECODES`), on the toy VAE: one record per
    decode with its milliseconds, FLOPs and the PSNR of its last pixel frame against the whole decode's."""
    vae = model.vae
    variants = {"whole chunk": latent, **{name: latent[:, :, -k:] for name, k in END_DECODES}}
    out = []
    for name, z in variants.items():
        timing = time_parts({name: lambda z=z: vae.decode(z)}, repeats, device)
        video = vae.decode(z)
        out.append(
            {
                "decode": name,
                "latent_frames": int(z.shape[2]),
                "pixel_frames": int(video.shape[2]),
                "cpu_ms": 1e3 * timing["cpu_s"][name],
                "wall_ms": 1e3 * timing["wall_s"][name],
                "mflop": flops_of(lambda z=z: vae.decode(z)) / 1e6,
                "last_frame_psnr_db": min(psnr_db(video[:, :, -1], full_video[:, :, -1]), 100.0),
            }
        )
    for row in out:
        row["cpu_vs_whole"] = row["cpu_ms"] / out[0]["cpu_ms"]
        row["mflop_vs_whole"] = row["mflop"] / out[0]["mflop"]
    return out


def vae_decode_flops_2b(frames: int = 81, width: int = 512, height: int = 288) -> dict:
    """FLOPs of the WAN 2.1 VAE's decode of a whole 2B chunk and of its last 1 / 2 latent frames (meta device)."""
    from oscar_core.model.wan_vae import WanVAE

    with torch.device("meta"):
        vae = WanVAE()  # its defaults (diffusers' AutoencoderKLWan's) are the WAN 2.1 VAE's configuration
    t = (frames - 1) // 4 + 1
    out = {}
    for name, k in (("whole chunk", t), *END_DECODES):
        z = torch.zeros(1, 16, k, height // 8, width // 8, device="meta")
        out[name] = flops_of(lambda z=z: vae.decode(z))
    return out


# --------------------------------------------------------------------------- the 2B, computed


def paper_eager_row() -> tuple[dict, Path]:
    """The ``--preset paper`` eager chunk measured on the GPU, and its file: ``rollout_gpu.json`` when its run measured
    that preset, else ``rollout_paper_gpu.json`` (the run that did, when the last ``rollout_gpu.json`` measured
    ``fast`` alone). ValueError naming both files when neither holds it."""
    for path in (GPU_JSON, GPU_JSON.with_name("rollout_paper_gpu.json")):
        if path.is_file():
            rows = json.loads(path.read_text()).get("measured", {}).get("presets", [])
            hits = [r for r in rows if r.get("preset") == "paper" and r.get("variant", "eager") == "eager"]
            if hits:
                return hits[0], path
    raise ValueError(
        f"{GPU_JSON} and rollout_paper_gpu.json beside it: expected a measured.presets record of the paper preset, "
        "eager (benchmarks/rollout.py --gpu), found none"
    )


def gpu_reference() -> dict:
    """The 2B figures this benchmark computes from: FLOPs of one evaluation and the H100's eager measurement
    (``benchmarks/measured/rollout_gpu.json``), the H200 throughput and VAE seconds (constants above)."""
    m = json.loads(GPU_JSON.read_text())["measured"]
    paper, paper_file = paper_eager_row()
    eval_flops = m["flops"]["step_conditional"]
    h100_step = m["steps"]["conditional_eager"]["median_ms"] / 1e3
    encode, decode = paper["seconds_parts"]["encode"], paper["seconds_parts"]["decode"]
    scale = PEAK_BF16["H100 SXM"] / PEAK_BF16["H200"]
    return {
        "tflop_per_evaluation": eval_flops / 1e12,
        "tflop_vae_per_chunk": m["flops"]["vae_per_chunk"] / 1e12,
        "source_flops": f"{GPU_JSON.relative_to(REPO)}: measured.flops (torch's FLOP counter, {m['device']}, bf16)",
        "throughputs": {
            "h200": {"tflops": H200_TFLOPS, "vae_s": H200_VAE_S, "decode_share_of_vae": decode / (encode + decode)},
            "h100": {
                "tflops": H200_TFLOPS * scale,
                "vae_s": H200_VAE_S * scale,
                "decode_share_of_vae": decode / (encode + decode),
            },
            "h100_eager": {
                "tflops": eval_flops / 1e12 / h100_step,
                "vae_s": encode + decode,
                "decode_share_of_vae": decode / (encode + decode),
            },
        },
        "notes": {
            "h200": "computed: 576 TFLOP/s compiled and 2.1 s VAE per chunk, measured on one H200 (docs/world-model.md)",
            "h100": "computed, assumed: the H200 figures x H100/H200 dense BF16 peak (989.4/989.4 TFLOP/s)",
            "h100_eager": f"computed from {GPU_JSON.relative_to(REPO)}: eager conditional step "
            f"{h100_step:.3f} s; from {paper_file.relative_to(REPO)}: VAE encode {encode:.2f} s + decode "
            f"{decode:.2f} s of the paper preset, eager (one H100)",
            "decode_share_of_vae": "the decode's share of the VAE seconds, from the H100 eager measurement",
        },
    }


def computed_2b(evaluations: int, ref: dict, decode_ratio: float = 1.0) -> dict:
    """Seconds per chunk, frames/s and the VAE's share of the 2B on each card (computed); ``decode_ratio``: the
    decode's FLOPs relative to the whole chunk's (1: the whole chunk decoded)."""
    tflop = evaluations * ref["tflop_per_evaluation"]
    out = {"tflop_dit_per_chunk": tflop}
    for card, t in ref["throughputs"].items():
        dit = tflop / t["tflops"]
        vae = t["vae_s"] * (1.0 - t["decode_share_of_vae"] * (1.0 - decode_ratio))
        out[card] = {
            "seconds_per_chunk": dit + vae,
            "frames_per_s": NEW_FRAMES / (dit + vae),
            "vae_share": vae / (dit + vae),
        }
    return out


# --------------------------------------------------------------------------- the 2B closed-loop step, computed


def closed_loop_flops_2b(frames: int = 81, width: int = 512, height: int = 288) -> dict:
    """FLOPs of the VAE's work in one closed-loop step of the 2B, counted on the meta device: ``encode_seed`` (one
    frame), ``encode_condition`` (the chunk's ``frames``-frame condition video), ``decode`` (the WAN 2.1 decoder, the
    chunk's (frames - 1) / 4 + 1 latent frames), ``tiny_decode`` (the tiny decoder at ``taew2_1``'s widths, the same
    latents) and ``tiny_encode_condition`` (the tiny encoder at ``taew2_1``'s width, the same condition video)."""
    from oscar_core.model.tiny_decoder import TinyDecoderNet
    from oscar_core.model.tiny_encoder import TinyEncoderNet
    from oscar_core.model.wan_vae import WanVAE

    with torch.device("meta"):
        vae = WanVAE()  # its defaults (diffusers' AutoencoderKLWan's) are the WAN 2.1 VAE's configuration
        tiny = TinyDecoderNet()  # taew2_1's widths, the module oscar loads taew2_1 into
        tiny_encoder = TinyEncoderNet()  # taew2_1's width, the module oscar loads taew2_1's encoder into
    t = (frames - 1) // 4 + 1
    z = torch.zeros(1, 16, t, height // 8, width // 8, device="meta")
    return {
        "encode_seed": flops_of(lambda: vae.encode(torch.zeros(1, 3, 1, height, width, device="meta"))),
        "encode_condition": flops_of(lambda: vae.encode(torch.zeros(1, 3, frames, height, width, device="meta"))),
        "decode": flops_of(lambda: vae.decode(z)),
        "tiny_decode": flops_of(lambda: tiny(z.permute(0, 2, 1, 3, 4))),  # TinyDecoderNet takes (N, T', z, h, w)
        # TinyEncoderNet takes (N, T, 3, H, W) and pads T at its end to a multiple of 4
        "tiny_encode_condition": flops_of(
            lambda: tiny_encoder(torch.zeros(1, frames, 3, height, width, device="meta"))
        ),
    }


def _step_seconds(dit_s: float, vae_s: float) -> dict:
    total = dit_s + vae_s
    return {
        "seconds_per_chunk": total,
        "vae_seconds": vae_s,
        "frames_per_s": NEW_FRAMES / total,
        "vae_share": vae_s / total,
        "meets_targets": bool(
            NEW_FRAMES / total >= CLOSED_LOOP_TARGETS["frames_per_s"]
            and vae_s / total <= CLOSED_LOOP_TARGETS["vae_share"]
        ),
    }


def closed_loop_2b(ref: dict, flops: dict, evaluations: int = CLOSED_LOOP_EVALUATIONS) -> dict:
    """The 2B closed-loop step computed on each card of ``ref`` (:func:`gpu_reference`) from ``flops``
    (:func:`closed_loop_flops_2b`): each VAE part's seconds are its FLOP share of the card's VAE seconds (the card's
    VAE FLOP rate), the DiT's are ``evaluations`` x the FLOPs of one over the card's throughput. Returns
    ``vae_split`` (the FLOPs and the split), ``rows`` (full VAE; tiny decoder; tiny decoder and tiny condition encoder;
    tiny decoder without a condition encode)
    and ``condition_encode_budget`` (per card, the largest condition encode with which the tiny-decoder step meets
    :data:`CLOSED_LOOP_TARGETS`, and the slowest FLOP rate at which the tiny encoder stays within it)."""
    tf = {k: v / 1e12 for k, v in flops.items()}
    vae_tflop = tf["encode_seed"] + tf["encode_condition"] + tf["decode"]
    tiny_dec, full_enc, tiny_enc = "tiny decoder (taew2_1 widths)", "WAN 2.1 encoder", "tiny encoder (taew2_1 width)"
    variants = (
        ("full VAE", "WAN 2.1 decoder", full_enc, tf["encode_condition"], tf["decode"]),
        ("tiny decoder", tiny_dec, full_enc, tf["encode_condition"], tf["tiny_decode"]),
        (TINY_BOTH_ROW, tiny_dec, tiny_enc, tf["tiny_encode_condition"], tf["tiny_decode"]),
        ("tiny decoder, no condition encode (bound)", tiny_dec, "none", 0.0, tf["tiny_decode"]),
    )
    rows = []
    for name, decoder, condition_encoder, encode_condition, decode in variants:
        row = {
            "step": name,
            "decoder": decoder,
            "condition_encoder": condition_encoder,
            "dit_evaluations": evaluations,
            "tflop_dit": evaluations * ref["tflop_per_evaluation"],
            "tflop_encode_seed": tf["encode_seed"],
            "tflop_encode_condition": encode_condition,
            "tflop_decode": decode,
        }
        for card, t in ref["throughputs"].items():
            rate = vae_tflop / t["vae_s"]  # TFLOP/s: the card's VAE seconds over the VAE's FLOPs
            dit = row["tflop_dit"] / t["tflops"]
            vae = (tf["encode_seed"] + encode_condition + decode) / rate
            row.update({f"{card}_{k}": v for k, v in _step_seconds(dit, vae).items()})
        rows.append(row)
    budget = {}
    for card, t in ref["throughputs"].items():
        rate = vae_tflop / t["vae_s"]
        dit = evaluations * ref["tflop_per_evaluation"] / t["tflops"]
        # VAE / (DiT + VAE) <= share  <=>  VAE <= DiT * share / (1 - share); 80 / (DiT + VAE) >= fps
        vae_max = min(
            dit * CLOSED_LOOP_TARGETS["vae_share"] / (1.0 - CLOSED_LOOP_TARGETS["vae_share"]),
            NEW_FRAMES / CLOSED_LOOP_TARGETS["frames_per_s"] - dit,
        )
        encode_max = vae_max - (tf["encode_seed"] + tf["tiny_decode"]) / rate
        budget[card] = {
            "condition_encode_s_max": encode_max,
            "condition_encode_now_s": tf["encode_condition"] / rate,
            "fraction_of_now": encode_max / (tf["encode_condition"] / rate),
            "tiny_encode_condition_s": tf["tiny_encode_condition"] / rate,
            # the slowest the tiny encoder may run (TFLOP/s) with the tiny decoder at the VAE's rate
            "tiny_encoder_min_tflops": tf["tiny_encode_condition"] / encode_max,
            "vae_tflops": rate,
        }
    return {
        "targets": dict(CLOSED_LOOP_TARGETS),
        "vae_split": {
            "tflop_encode_seed": tf["encode_seed"],
            "tflop_encode_condition": tf["encode_condition"],
            "tflop_decode": tf["decode"],
            "tflop_vae_counted": vae_tflop,
            "tflop_vae_reference": ref["tflop_vae_per_chunk"],
            "tflop_tiny_decode": tf["tiny_decode"],
            "tiny_decode_vs_decode": tf["tiny_decode"] / tf["decode"],
            "tflop_tiny_encode_condition": tf["tiny_encode_condition"],
            "tiny_encode_vs_encode_condition": tf["tiny_encode_condition"] / tf["encode_condition"],
            "decode_share_by_flops": tf["decode"] / vae_tflop,
            "decode_share_measured_h100_eager": ref["throughputs"]["h100_eager"]["decode_share_of_vae"]
            if "h100_eager" in ref["throughputs"]
            else None,
            "seed_encode_share_of_vae": tf["encode_seed"] / vae_tflop,
            "note": "no record splits the H200's 2.1 s of VAE into encode and decode: each VAE part is given its FLOP "
            "share of a card's VAE seconds; the tiny decoder and the tiny encoder are assumed to run at the FLOP rate "
            "the full VAE ran at on that card (not measured)",
        },
        "rows": rows,
        "condition_encode_budget": budget,
    }


def print_closed_loop(cl: dict) -> None:
    """The 2B closed-loop rows on each card (computed), and the condition encode the targets leave room for."""
    split, cards = cl["vae_split"], list(cl["condition_encode_budget"])
    measured = split["decode_share_measured_h100_eager"]
    print(
        f"\n2B closed-loop step, {cl['rows'][0]['dit_evaluations']} DiT evaluations, computed: each VAE part its FLOP "
        f"share of the card's VAE seconds (decode {split['decode_share_by_flops']:.3f} by FLOPs"
        + (f", {measured:.3f} measured on one H100" if measured is not None else "")
        + f"); tiny decoder {split['tflop_tiny_decode']:.2f} TFLOP = {100 * split['tiny_decode_vs_decode']:.1f} % of "
        f"the decode's; tiny condition encoder {split['tflop_tiny_encode_condition']:.2f} TFLOP = "
        f"{100 * split['tiny_encode_vs_encode_condition']:.1f} % of the condition encode's; both assumed at the VAE's "
        "FLOP rate"
    )
    print(f"  {'step':42s} {'TFLOP enc':>9s} {'dec':>7s}" + "".join(f" {c + ' s, fps, VAE%':>24s}" for c in cards))
    for r in cl["rows"]:
        print(
            f"  {r['step']:42s} {r['tflop_encode_seed'] + r['tflop_encode_condition']:9.2f} {r['tflop_decode']:7.2f}"
            + "".join(
                f" {r[c + '_seconds_per_chunk']:8.3f} {r[c + '_frames_per_s']:7.1f} {100 * r[c + '_vae_share']:7.1f}"
                for c in cards
            )
        )
    t = cl["targets"]
    for card, b in cl["condition_encode_budget"].items():
        print(
            f"  {card}: >= {t['frames_per_s']:g} frames/s with the VAE <= {100 * t['vae_share']:g} % needs the tiny "
            f"decoder and a condition encode of at most {b['condition_encode_s_max']:.3f} s, "
            f"{100 * b['fraction_of_now']:.0f} % of today's {b['condition_encode_now_s']:.3f} s; the tiny encoder's "
            f"{b['tiny_encode_condition_s']:.3f} s fits while it runs at >= {b['tiny_encoder_min_tflops']:.1f} TFLOP/s "
            f"({100 * b['tiny_encoder_min_tflops'] / b['vae_tflops']:.0f} % of the VAE's {b['vae_tflops']:.0f})"
        )


def add_closed_loop_2b(path: Path) -> dict:
    """Count, compute and add ``closed_loop_2b`` (with its own provenance) to the benchmark JSON at ``path``, every
    other field as it was, from the file's own ``reference_2b`` (the figures its ``computed_2b`` rows used); written
    atomically. Returns the section."""
    from oscar_core._util.atomic import atomic_write_bytes

    data = json.loads(path.read_text())
    ref = data.get("reference_2b") or gpu_reference()  # the reference the file's computed_2b rows were computed from
    cl = closed_loop_2b(ref, closed_loop_flops_2b())
    data["closed_loop_2b"] = {"provenance": provenance(), **cl}
    atomic_write_bytes(path, (json.dumps(data, indent=2) + "\n").encode())
    return cl


# --------------------------------------------------------------------------- main


def load_models(args, device, dtype):
    import oscar_zoo

    teacher = oscar_zoo.load("oscar-toy", device=device, dtype=dtype)
    if args.student:
        return teacher, oscar_zoo.load(args.student, device=device, dtype=dtype), str(args.student)
    student = oscar_zoo.load("oscar-toy", device=device, dtype=dtype)
    from dataclasses import replace

    student.card = replace(student.card, sampler=dict(STUDENT_CARD_SAMPLER))
    student.scheduler_config = {"_class_name": "FlowMatchEulerDiscreteScheduler", "shift": 5.0}
    return teacher, student, "oscar-toy's weights with the student's sampler (same architecture, same work)"


def measure_row(name: str, model, options: dict, inputs: dict, args, device) -> dict:
    from oscar_core.model.sampler import model_calls

    sampler = model.sampler_for(model.recommended_sampler(**options))
    seen = count_dit_evaluations(model, sampler, inputs)
    declared = model_calls(sampler)
    if seen["items"] != declared:
        raise AssertionError(f"{name}: counted {seen['items']} DiT evaluations per chunk, model_calls says {declared}")
    parts, state = chunk_parts(model, inputs, sampler)
    flops = {p: flops_of(fn) for p, fn in parts.items()}  # the render runs numpy and cv2: no torch FLOPs
    timing = time_parts(parts, args.repeats, device)
    wall, cpu = timing["wall_s"], timing["cpu_s"]
    return {
        "row": name,
        "solver": sampler.resolved_solver,
        "steps": sampler.steps,
        "guidance": sampler.guidance,
        "guidance_interval": list(sampler.guidance_interval) if sampler.guidance_interval else None,
        "dit_evaluations": seen["items"],
        "dit_forwards": seen["forwards"],
        "model_calls": declared,
        "toy_mflop_dit_per_chunk": flops["dit"] / 1e6,
        "toy_mflop_vae_per_chunk": sum(flops[p] for p in VAE_PARTS) / 1e6,
        "toy_wall_ms": {p: 1e3 * wall[p] for p in PARTS},
        "toy_cpu_ms": {p: 1e3 * cpu[p] for p in PARTS},
        "toy_wall_ms_per_chunk": 1e3 * sum(wall.values()),
        "toy_cpu_ms_per_chunk": 1e3 * sum(cpu.values()),
        "toy_vae_share_of_cpu": sum(cpu[p] for p in VAE_PARTS) / sum(cpu.values()),
        "toy_vae_share_of_wall": sum(wall[p] for p in VAE_PARTS) / sum(wall.values()),
        "_state": state,
    }


def print_table(rows: list[dict], cut: dict) -> None:
    print(
        f"{'row':24s} {'evals':>5s} {'toy MFLOP':>10s} {'CPU ms (wall)':>13s} {'render':>7s} {'enc':>6s} {'DiT':>7s} "
        f"{'dec':>6s} {'VAE%':>5s} {'2B TFLOP':>8s} {'H200 fps*':>9s} {'H100 fps*':>9s} {'eager*':>6s} {'VAE% H200*':>10s}"
    )
    for r in rows:
        w, c = r["toy_cpu_ms"], r["computed_2b"]
        print(
            f"{r['row']:24s} {r['dit_evaluations']:5d} {r['toy_mflop_dit_per_chunk'] + r['toy_mflop_vae_per_chunk']:10.0f} "
            f"{r['toy_cpu_ms_per_chunk']:6.0f} ({r['toy_wall_ms_per_chunk']:5.0f}) {w['render']:7.1f} "
            f"{w['encode_first'] + w['encode_condition']:6.1f} {w['dit']:7.1f} {w['decode']:6.1f} "
            f"{100 * r['toy_vae_share_of_cpu']:5.1f} {c['tflop_dit_per_chunk']:8.0f} {c['h200']['frames_per_s']:9.1f} "
            f"{c['h100']['frames_per_s']:9.1f} {c['h100_eager']['frames_per_s']:6.1f} {100 * c['h200']['vae_share']:10.1f}"
        )
    print("toy: one chunk, median CPU ms per part (render, VAE encodes, DiT, VAE decode) and the VAE's share of them")
    print("* computed for the 2B at 81 frames, 512x288 (80 new frames per chunk), VAE included; not measured")
    print("\nDecode of a chunk's end only (toy VAE measured; 2B: FLOPs counted on the meta device, seconds computed):")
    for toy, big in zip(cut["toy_measured"], cut["student_2b_computed"]):
        print(
            f"  {toy['decode']:22s} toy {toy['cpu_ms']:6.1f} CPU ms ({toy['cpu_vs_whole']:.2f} of the whole), last "
            f"frame {toy['last_frame_psnr_db']:5.1f} dB vs the whole decode's | 2B decode x{big['flop_ratio']:.3f} "
            f"FLOPs: student {big['h200_frames_per_s']:.1f} frames/s on an H200*, VAE {100 * big['h200_vae_share']:.0f} %"
        )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--student", help="oscar model folder of a distilled student (default: see the module docstring)")
    ap.add_argument("--repeats", type=int, default=5, help="timed chunks per row, after one warm-up (median)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    ap.add_argument("--device", default="cpu", help="cpu or cuda (the toy model; the 2B rows are computed)")
    ap.add_argument("--dtype", default="float32", choices=("float32", "bfloat16"))
    ap.add_argument("--json", default="benchmarks/results/distill_speed.json")
    ap.add_argument(
        "--closed-loop-2b-only",
        action="store_true",
        help="count and compute the 2B closed-loop rows only and add them to the existing --json file (its other "
        "fields unchanged; no model runs)",
    )
    args = ap.parse_args(argv)
    if args.closed_loop_2b_only:
        path = Path(args.json)
        try:
            rows = json.loads(path.read_text()).get("rows") if path.is_file() else None
        except ValueError:
            rows = None
        if not rows:
            ap.error(f"--closed-loop-2b-only: {path}: expected a JSON file written by this benchmark, found none")
        print_closed_loop(add_closed_loop_2b(path))
        print(f"wrote {path}")
        return 0
    if args.repeats < 1 or args.threads < 1:
        ap.error(f"--repeats and --threads: expected integers >= 1, found {args.repeats} and {args.threads}")
    if args.student and not (Path(args.student) / "oscar_model.json").is_file():
        ap.error(f"--student {args.student}: expected an oscar model folder (oscar_model.json), found none")
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        ap.error(f"--device {args.device}: CUDA is not available here")
    torch.set_num_threads(args.threads)
    device, dtype = torch.device(args.device), getattr(torch, args.dtype)
    teacher, student, student_weights = load_models(args, device, dtype)
    models = {"teacher": teacher, "student": student}
    card = teacher.card
    inputs = chunk_inputs(card.chunk_frames, card.width, card.height)
    ref = gpu_reference()
    rows = []
    for name, which, options in ROWS:
        row = measure_row(name, models[which], options, inputs, args, device)
        row["computed_2b"] = computed_2b(row["dit_evaluations"], ref)
        rows.append(row)
        print(
            f"measured {name}: {row['dit_evaluations']} DiT evaluations, {row['toy_cpu_ms_per_chunk']:.0f} CPU ms",
            flush=True,
        )
    state = rows[3]["_state"]  # the student at its card's steps
    flops2b = vae_decode_flops_2b()
    computed = []
    for name, flops in flops2b.items():
        ratio = flops / flops2b["whole chunk"]
        c = computed_2b(rows[3]["dit_evaluations"], ref, decode_ratio=ratio)
        computed.append(
            {
                "decode": name,
                "tflop_decode": flops / 1e12,
                "flop_ratio": ratio,
                **{f"{card}_{k}": v for card in ref["throughputs"] for k, v in c[card].items()},
            }
        )
    cut = {
        "toy_measured": toy_vae_cut(student, state["latent"], state["video"], args.repeats, device),
        "student_2b_computed": computed,
    }
    for r in rows:
        r.pop("_state")
    print_table(rows, cut)
    closed_loop = closed_loop_2b(ref, closed_loop_flops_2b())
    print_closed_loop(closed_loop)
    out = with_provenance(
        {
            "settings": {
                "device": str(device),
                "dtype": args.dtype,
                "threads": args.threads,
                "repeats": args.repeats,
                "chunk": f"{card.chunk_frames} frames, {card.width}x{card.height}, toyarm episode 0, seed 0",
                "teacher": "oscar-toy",
                "student": student_weights,
                "new_frames_per_2b_chunk": NEW_FRAMES,
                "goal_frames_per_s_computed": GOAL_FPS,
            },
            "reference_2b": ref,
            "rows": rows,
            "vae_cut": cut,
            "closed_loop_2b": closed_loop,
        },
        device=str(device),
    )
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(out, indent=2) + "\n")
    tmp.replace(path)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
