"""Write docs/benchmarks.md from the measured benchmark JSON under benchmarks/measured/.

    python benchmarks/make_docs.py            # rewrite docs/benchmarks.md (also: make docs)
    python benchmarks/make_docs.py --check    # exit 1 if docs/benchmarks.md is not what the JSON gives

The page opens with a headline table (``HEADLINES``: one figure per row with its value, unit, whether it was measured
or computed, the machine, the date and a link to its section), then one section per benchmark. A benchmark's runs
(``rollout.json`` on the CPU, ``rollout_gpu.json`` from ``make bench-gpu``, ...) stand side by side in its tables:
one column per run for settings and single figures, and in a table of records one row per record (matched across runs
by its leading text fields) with a field's value per run beside each other where the runs differ. Every value comes
from a JSON file; the JSON stays the record (its provenance, written by ``benchmarks/_provenance.py``, gives each
run's date, commit, machine and command). A headline that names a value its file does not hold is an error (exit 2).
"""

import argparse
import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
MEASURED = REPO / "benchmarks" / "measured"
PAGE = REPO / "docs" / "benchmarks.md"

#: benchmark (file stem without ``_gpu``) -> (title, the script, what it measures), in page order. Unknown benchmarks
#: follow with a plain title.
ABOUT: dict[str, tuple[str, str, str]] = {
    "rollout": (
        "World-model rollout",
        "benchmarks/rollout.py",
        "The tiny CPU configuration's denoising step and whole rollout (`tiny`: batched classifier-free "
        "guidance against two passes, in the same run); the 2B model's size, tokens and FLOPs computed from "
        "its configuration (`expected_2b`, `computed_2b`: computed, not measured); with `--gpu` or "
        "`--measure`, each sampling preset measured on the device (`measured`).",
    ),
    "action_following": (
        "Action following, the quick set",
        "benchmarks/action_following.py",
        "`oscar toyworld action-following --model oscar-toy --quick` as a user runs it (a fresh process, one torch "
        "thread): 9 counterfactual toy sets x 6 variants, 97 frames = 6 chunks, 10 sampler steps. Decision accuracy "
        "and the pairwise rate with 95 % bootstrap intervals over sets, per-variant verdict agreement and ball end "
        "error (ball radii), per-chunk PSNR and ball error, and the wall and CPU seconds of the whole command "
        "(set generation included) with the load average before and after (docs/action-following.md).",
    ),
    "cli_rollout": (
        "One `oscar rollout` end to end",
        "benchmarks/cli_rollout.py",
        "The real command in a fresh process rolling out one chunk, timed from outside; `fixed_s` = "
        "wall − encode − sample − decode (imports, loading, writing).",
    ),
    "startup": (
        "Start-up: `oscar` commands and a toy rollout's imports",
        "benchmarks/startup.py",
        "Fresh processes timed from outside (median CPU and wall seconds, modules held at exit, and which of "
        "diffusers, transformers and torch._dynamo they held): `oscar --help`, `oscar rollout --help`, `oscar zoo "
        "list`, and what `oscar rollout` of `oscar-toy` imports before reading weights (oscar's own DiT, VAE and "
        "UniPC), beside three floors: `import torch`, `import torch, torch._dynamo` and diffusers' DiT and VAE "
        "classes imported from their own modules with no oscar code (what the toy row cost while its models were "
        "diffusers' classes: they bring torch._dynamo, transformers and scipy); `by_package`: the toy row's import "
        "time per top-level package from one "
        "`python -X importtime` process (self times, the importer's wall clock); `before` rows: an older commit "
        "measured in the same run, alternating with this one.",
    ),
    "wan_vae": (
        "The Wan VAE: oscar's own class against diffusers'",
        "benchmarks/wan_vae.py",
        "Import and load of the VAE path in fresh processes (oscar's `load_vae_folder` of the oscar-toy `vae/`, "
        "diffusers' `AutoencoderKLWan` on the same folder, `import torch` as the floor; median CPU and wall "
        "seconds), and one 17-frame 64x64 toy chunk encoded and decoded by both classes in one process on one "
        "thread with oneDNN convolutions (best CPU and wall ms, the classes alternating; `max_abs_diff` 0 = "
        "bit-identical); `encode_variants`: oscar's encode of the same chunk as it is, channels-last and under "
        "`torch.compile` (first call = the compile), `max_abs_diff` against the encode as it is (added by "
        "`--encode-variants-only` with its own provenance).",
    ),
    "cosmos_dit": (
        "The Cosmos DiT: oscar's own class against diffusers'",
        "benchmarks/cosmos_dit.py",
        "Import and load of the DiT path in fresh processes (oscar's `OscarTransformer3DModel.load_strict` of the "
        "oscar-toy `transformer/`, diffusers' `CosmosTransformer3DModel` with the same weights less PE_s, "
        "`import torch` as the floor; median CPU and wall seconds), and one guided step's DiT call of a toy chunk "
        "(batch 2, 5 x 16 x 16 latent) by both classes in one process on one thread (best CPU and wall ms, the "
        "classes alternating; `max_abs_diff` 0 = bit-identical).",
    ),
    "distill_speed": (
        "Teacher, `fast` and the few-step student",
        "benchmarks/distill_speed.py",
        "One 17-frame 64x64 chunk of `oscar-toy` (one thread) for the teacher at `--preset paper`, its card's "
        "sampler and `--preset fast`, and the distilled student at 4, 2 and 1 steps: DiT evaluations counted on "
        "the real transformer (equal to `model_calls`), FLOPs counted by `torch.utils.flop_counter`, median CPU and "
        "wall milliseconds per part (condition render, VAE encodes, DiT, VAE decode); `computed_2b`: the 2B at 81 "
        "frames, 512x288, on one H200 / H100 from those evaluations (computed, not measured); `vae_cut`: decoding "
        "only a chunk's end (toy VAE measured, 2B FLOP ratio counted); `closed_loop_2b`: the 2B closed-loop step with "
        "a 4-step sampler (seed and condition encodes every chunk, the full or the tiny decoder), FLOPs counted, "
        "seconds computed from each card's measured VAE seconds by FLOP share (computed, not measured; added by "
        "`--closed-loop-2b-only` with its own provenance).",
    ),
    "closed_loop": (
        "Closed-loop policy evaluation",
        "benchmarks/closed_loop.py",
        "Toy sessions x 2 image-based toy policies closed loop (one torch thread) in `oscar-toy` at 10 steps with "
        "the full decoder (teacher), in `oscar-toy-fast` (the 4-step student) with the full decoder, and in the "
        "student with the bundled tiny decoder; each run one cell at a time and with `--batch-cells N` for each N "
        "given, interleaved in the same process: cells per CPU-minute and per wall-minute, per closed-loop step "
        "(one chunk of one cell) the CPU milliseconds of the policy's calls, the action adapter (IK), the "
        "condition render, the VAE encodes, the DiT, the VAE decode, the cell's writes, the report and the rest "
        "(`cpu_ms_per_step`), beside the wall milliseconds from the cells' records, and the latency a policy sees "
        "per chunk (`policy_visible`: wall and CPU ms of each world step, request to frames); the student run "
        "also probes the VAE on one generated chunk (`vae_probe`, docs/closed-loop.md).",
    ),
    "tiny_decoder": (
        "The toy tiny decoder against the full VAE decoder",
        "benchmarks/tiny_decoder.py",
        "`oscar-toy`'s bundled tiny decoder (`tiny_decoder.safetensors`, `oscar toyworld train-tiny-decoder`) and "
        "its full VAE decoder, one torch thread, in one run: CPU and wall milliseconds per 17-frame 64x64 chunk "
        "(best of N at batch 1, and per chunk in the batched decodes of the verdict part); PSNR and motion IoU of "
        "the tiny decode against the full decode (and of both against the true frames) on held-out windows of "
        "toy clips; and the toy judge's verdict (`ball_moved`) on both decoders' videos of the same latents of "
        "counterfactual sets rolled out by `oscar-toy` (docs/world-model.md).",
    ),
    "tiny_encoder": (
        "The toy tiny condition encoder against the full VAE encoder",
        "benchmarks/tiny_encoder.py",
        "`oscar-toy`'s bundled tiny condition encoder (`tiny_encoder.safetensors`, `oscar toyworld "
        "train-tiny-encoder`) and its full VAE encoder, one torch thread, in one run: CPU and wall milliseconds of a "
        "17-frame 64x64 condition encode and a 1-frame seed encode (best of N, interleaved); the relative RMS error "
        "of the tiny encoder's normalised latents against the full encoder's on held-out conditions (and on RGB first "
        "frames); PSNR of rollouts by `oscar-toy-fast` and `oscar-toy` with the tiny-encoded conditions against the "
        "full-encoded ones on the same seeds, beside two seeds' spread and both against the true frames; and each "
        "encoder's FLOP rate on this CPU at the WAN 2.1 shapes (docs/world-model.md).",
    ),
    "render": (
        "Skeleton rendering",
        "benchmarks/render.py",
        "Per-frame cost of each stage of a skeleton video (FK, projection, rasterisation, H.264) on one CPU "
        "thread for 81-frame example trajectories, against the naive way in the same run (yourdfpy FK, "
        "`cv2.projectPoints` and drawing per frame). Microseconds (`_us`) and frames per second (`_fps`).",
    ),
    "render_scale": (
        "Rendering at dataset scale",
        "benchmarks/render_scale.py",
        "Everything run as a user would, in subprocesses, with wall time beside CPU time (user + "
        "system, children included): start-up of `oscar` commands, episodes/s of `oscar render "
        "--manifest` with 1 and 2 workers against one process per episode and the Python API in one "
        "process, and the x264 presets (CPU seconds, size, PSNR against the rendered frames).",
    ),
    "train": (
        "Training",
        "benchmarks/train.py",
        "Steps/s of the tiny config on the CPU (cached latents with 1 and 2 processes, and the naive way: "
        "VAE encode and skeleton render in the loop), the 2B model's training memory per GPU under FSDP2 "
        "(`memory`: computed from its configuration, not measured) and, with `--step-table` on a GPU, one 2B "
        "training step's time and peak memory under activation checkpointing none/full and compile (`step_table`).",
    ),
    "threads": (
        "Torch threads on a busy machine",
        "benchmarks/threads.py",
        "The bundled `oscar-toy` rollout (a fresh `oscar toyworld rollout` process per row) beside background "
        "processes that each keep one core busy, with `--threads 1`, `--threads 2` and the automatic choice "
        "(the cores idle by the 1-minute load average). Median wall seconds from spawn to exit and CPU seconds "
        "of the process; `wall_vs_best` is the row's wall over the best row's (goal for `auto`: at most 1.10).",
    ),
}

#: file stem -> (benchmark, the run's column label) where the default (stem without ``_gpu``; "CPU" or "GPU") is wrong
RUNS: dict[str, tuple[str, str]] = {
    "rollout_paper_gpu": ("rollout", "GPU, stopped run"),
    "train_step_gpu": ("train", "GPU"),
    "closed_loop": ("closed_loop", "CPU, teacher"),
    "closed_loop_student": ("closed_loop", "CPU, student"),
    "closed_loop_student_tiny": ("closed_loop", "CPU, student + tiny decoder"),
    "closed_loop_student_tiny_beside_enc": ("closed_loop", "CPU, student + tiny decoder (beside the next run)"),
    "closed_loop_student_tiny_enc": ("closed_loop", "CPU, student + tiny decoder + tiny condition encoder"),
    **{
        f"closed_loop_2b_{sampler}_{decoder}_gpu": ("closed_loop", f"GPU, 2B {sampler}, {words}")
        for sampler in ("teacher", "fast", "4step")
        for decoder, words in (("full", "full VAE"), ("tiny", "tiny decoder"))
    },
    "closed_loop_2b_4step_tinyboth_gpu": ("closed_loop", "GPU, 2B 4step, tiny decoder + tiny condition encoder"),
}


@dataclass(frozen=True)
class Headline:
    """One row of the headline table: ``path`` reads the value in ``benchmarks/measured/<file>`` (dotted keys;
    ``[k=v,k2=v2]`` picks the record of a list whose fields match); the value is multiplied by ``scale``;
    ``kind``: "measured" or "computed"; ``machine``: what the figure is for, where that is not the machine that
    wrote the file (a computed figure); ``provenance``: the path of a section's own provenance block (a section a
    later run added to the file), whose date the row gives instead of the file's."""

    figure: str
    file: str
    path: str
    unit: str
    kind: str = "measured"
    scale: float = 1.0
    machine: str | None = None
    provenance: str | None = None


#: the page's first table: what a person comes for, one screen. A row whose file is absent is left out.
HEADLINES: tuple[Headline, ...] = (
    Headline(
        "2B rollout, `--preset fast`, compiled: 81-frame chunk at 512x288",
        "rollout_gpu.json",
        "measured.presets[preset=fast,variant=compiled].frames_per_s",
        "frames/s",
    ),
    Headline(
        "… the same, seconds per chunk (encode + sample + decode)",
        "rollout_gpu.json",
        "measured.presets[preset=fast,variant=compiled].seconds_per_chunk",
        "s",
    ),
    Headline(
        "2B rollout, `--preset paper` (35 steps, guided), eager",
        "rollout_paper_gpu.json",
        "measured.presets[preset=paper,variant=eager].frames_per_s",
        "frames/s",
    ),
    Headline(
        "2B denoising step, guided (2 evaluations), compiled",
        "rollout_gpu.json",
        "measured.steps.guided_compiled.median_ms",
        "ms",
    ),
    Headline(
        "2B distilled student at 1 step, on one H200",
        "distill_speed_gpu.json",
        "rows[row=student, 1 step].computed_2b.h200.frames_per_s",
        "frames/s",
        kind="computed",
        machine="one H200 (from FLOPs and its measured throughput)",
    ),
    Headline(
        "2B closed-loop step, 4-step sampler, full VAE, on one H200",
        "distill_speed.json",
        "closed_loop_2b.rows[step=full VAE].h200_frames_per_s",
        "frames/s",
        kind="computed",
        machine="one H200 (from FLOPs and its measured throughput)",
        provenance="closed_loop_2b.provenance",
    ),
    Headline(
        "… with the tiny decoder (target ≥ 60)",
        "distill_speed.json",
        "closed_loop_2b.rows[step=tiny decoder].h200_frames_per_s",
        "frames/s",
        kind="computed",
        machine="one H200 (from FLOPs and its measured throughput)",
        provenance="closed_loop_2b.provenance",
    ),
    Headline(
        "… the VAE's share of that step (target ≤ 40)",
        "distill_speed.json",
        "closed_loop_2b.rows[step=tiny decoder].h200_vae_share",
        "%",
        kind="computed",
        scale=100.0,
        machine="one H200 (from FLOPs and its measured throughput)",
        provenance="closed_loop_2b.provenance",
    ),
    Headline(
        "… with the tiny decoder and the tiny condition encoder (tiny parts at the VAE's FLOP rate, assumed)",
        "distill_speed.json",
        "closed_loop_2b.rows[step=tiny decoder + tiny condition encoder].h200_frames_per_s",
        "frames/s",
        kind="computed",
        machine="one H200 (from FLOPs and its measured throughput)",
        provenance="closed_loop_2b.provenance",
    ),
    Headline(
        "… the VAE's share of that step (target ≤ 40)",
        "distill_speed.json",
        "closed_loop_2b.rows[step=tiny decoder + tiny condition encoder].h200_vae_share",
        "%",
        kind="computed",
        scale=100.0,
        machine="one H200 (from FLOPs and its measured throughput)",
        provenance="closed_loop_2b.provenance",
    ),
    Headline(
        "`oscar rollout` of one `oscar-toy` chunk (17 frames 64x64), whole command",
        "cli_rollout.json",
        "rows[mode=never].cpu_s",
        "CPU s",
    ),
    Headline("`oscar --help`", "startup.json", "rows[checkout=this,what=oscar --help].cpu_s", "CPU s"),
    Headline(
        "A toy rollout's imports (torch, oscar's DiT, VAE and UniPC)",
        "startup.json",
        "rows[checkout=this,what=toy rollout imports].cpu_s",
        "CPU s",
    ),
    Headline(
        "`oscar-toy` chunk, distilled student at 1 step (one thread)",
        "distill_speed.json",
        "rows[row=student, 1 step].toy_cpu_ms_per_chunk",
        "CPU ms",
    ),
    Headline(
        "`oscar-toy` chunk, teacher at `--preset paper` (one thread)",
        "distill_speed.json",
        "rows[row=teacher, --preset paper].toy_cpu_ms_per_chunk",
        "CPU ms",
    ),
    Headline(
        "Closed-loop evaluation, `oscar-toy`, 4 cells batched",
        "closed_loop.json",
        "rows[batch_cells=4].cells_per_cpu_minute",
        "cells/CPU-min",
    ),
    Headline(
        "Closed-loop step, 4-step student + tiny decoder, one cell at a time (one thread)",
        "closed_loop_student_tiny.json",
        "rows[batch_cells=1].cpu_ms_per_step.total",
        "CPU ms",
    ),
    Headline(
        "… the latency a policy sees per chunk",
        "closed_loop_student_tiny.json",
        "rows[batch_cells=1].policy_visible.cpu_ms_per_chunk",
        "CPU ms",
    ),
    Headline(
        "Closed-loop step, 4-step student + tiny decoder + tiny condition encoder, one cell at a time (one thread)",
        "closed_loop_student_tiny_enc.json",
        "rows[batch_cells=1].cpu_ms_per_step.total",
        "CPU ms",
    ),
    Headline(
        "… the latency a policy sees per chunk",
        "closed_loop_student_tiny_enc.json",
        "rows[batch_cells=1].policy_visible.cpu_ms_per_chunk",
        "CPU ms",
    ),
    Headline(
        "Skeleton video, franka 512x288, FK to pixels (one thread)",
        "render.json",
        "rows[embodiment=franka,size=512x288].median_pipeline_fps",
        "frames/s",
    ),
    Headline(
        "… the same with H.264 encoding",
        "render.json",
        "rows[embodiment=franka,size=512x288].pipeline_with_h264_fps",
        "frames/s",
    ),
    Headline(
        "Tiny model training, cached latents, 1 process", "train.json", "speed[run=cached-1proc].steps_per_s", "steps/s"
    ),
    Headline(
        "2B training step, full activation checkpointing",
        "train_step_gpu.json",
        "step_table.variants[variant=full].median_step_s",
        "s",
    ),
    Headline(
        "… its peak memory",
        "train_step_gpu.json",
        "step_table.variants[variant=full].peak_bytes",
        "GiB",
        scale=2.0**-30,
    ),
    Headline(
        "2B training memory per GPU, 8 GPUs FSDP2, full checkpointing",
        "train.json",
        "memory.rows[gpus=8].total_full_gib",
        "GiB",
        kind="computed",
        machine="any GPU (from the 2B configuration)",
    ),
)

#: a list of more numbers than this is shown as its count and range; a longer text is cut with "…" (the JSON has it)
LONG_LIST = 8
LONG_TEXT = 160


class HeadlineError(ValueError):
    """A headline names a value its file does not hold."""


def fmt(value) -> str:
    """A cell: 4 significant digits for floats (whole numbers from 10,000 up), short lists joined, long lists of
    numbers as their count and range, text with table pipes escaped."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.0f}" if abs(value) >= 1e4 else f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        numbers = [v for v in value if isinstance(v, (int, float)) and not isinstance(v, bool)]
        if len(value) > LONG_LIST and len(numbers) == len(value):
            return f"{len(value)} values, {fmt(float(min(numbers)))} to {fmt(float(max(numbers)))}"
        return ", ".join(fmt(v) for v in value)
    if value is None:
        return "–"
    text = str(value) if len(str(value)) <= LONG_TEXT else str(value)[: LONG_TEXT - 1] + "…"
    return text.replace("|", "\\|").replace("\n", " ")


def empty(value) -> bool:
    """Nothing measured: left out of the page (a ``None`` inside a table's row is shown as "–")."""
    return value is None or (isinstance(value, (list, tuple, dict)) and len(value) == 0)


def is_scalar(value) -> bool:
    return (
        value is None
        or isinstance(value, (str, int, float, bool))
        or (isinstance(value, (list, tuple)) and all(isinstance(v, (str, int, float, bool)) for v in value))
    )


def is_records(value) -> bool:
    return isinstance(value, list) and len(value) > 0 and all(isinstance(v, dict) for v in value)


def is_parameter_map(value) -> bool:
    """``{"0.2": 2.77, "0.3": 4.16, ...}``: a value per parameter, shown in one cell."""
    if not isinstance(value, dict) or not value or not all(is_scalar(v) for v in value.values()):
        return False
    try:
        [float(k) for k in value]
    except ValueError:
        return False
    return True


def flatten(record: dict, prefix: str = "") -> dict:
    """``{"a": {"b": 1}}`` -> ``{"a.b": 1}``: scalars, lists of scalars and parameter maps (one cell
    ``"0.2: 2.77, 0.3: 4.16"``) kept; lists of records inside a record shown as a count."""
    out = {}
    for key, value in record.items():
        name = f"{prefix}{key}"
        if is_parameter_map(value):
            out[name] = ", ".join(f"{k}: {fmt(v)}" for k, v in value.items())
        elif isinstance(value, dict):
            out.update(flatten(value, name + "."))
        elif is_scalar(value):
            out[name] = value
        else:
            out[name] = f"{len(value)} records"
    return out


def split_values(data: dict, prefix: str = "") -> tuple[dict, dict]:
    """A run's body as (figures: dotted path -> scalar, tables: dotted path -> list of records), in file order;
    empty values left out."""
    figures, tables = {}, {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if empty(value):
            continue
        if is_records(value):
            tables[name] = value
        elif is_parameter_map(value) or is_scalar(value):
            figures.update(flatten({key: value}, prefix))
        elif isinstance(value, dict):
            sub_figures, sub_tables = split_values(value, name + ".")
            figures.update(sub_figures)
            tables.update(sub_tables)
        else:
            figures[name] = fmt(value)
    return figures, tables


def markdown_table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header), *["| " + " | ".join(r) + " |" for r in rows]]


def record_keys(records: list[dict]) -> list[str]:
    """The fields that name a record: the leading text fields of the first record, or its first field."""
    first = flatten(records[0])
    keys = []
    for name, value in first.items():
        if not isinstance(value, str):
            break
        keys.append(name)
    return keys or list(first)[:1]


def keyed(records: list[dict], keys: list[str]) -> dict[tuple, dict]:
    """Flattened records by their key fields' values (a repeated key gets its occurrence number)."""
    out: dict[tuple, dict] = {}
    for r in records:
        flat = flatten(r)
        key = tuple(fmt(flat.get(k)) for k in keys)
        n = 1
        while key + ((n,) if n > 1 else ()) in out:
            n += 1
        out[key + ((n,) if n > 1 else ())] = flat
    return out


def side_by_side_records(labels: list[str], lists: list[list[dict] | None]) -> list[str]:
    """One table of the runs' records: a row per record (matched across runs by ``record_keys``), the key fields,
    then each field once where every run that has the record agrees, else one column per run."""
    present = [(label, rs) for label, rs in zip(labels, lists) if rs]
    keys = record_keys(present[0][1])
    by_run = [(label, keyed(rs, keys)) for label, rs in present]
    row_keys: list[tuple] = []
    fields: list[str] = []
    for _, recs in by_run:
        row_keys += [k for k in recs if k not in row_keys]
        for flat in recs.values():
            fields += [f for f in flat if f not in fields and f not in keys]
    columns: list[tuple[str, str | None]] = []  # (field, run label or None: the same in every run)
    for f in fields:
        same = (
            all(len({fmt(recs[k].get(f)) for _, recs in by_run if k in recs}) == 1 for k in row_keys)
            or len(by_run) == 1
        )
        columns += [(f, None)] if same else [(f, label) for label, _ in by_run]
    header = keys + [f if label is None else f"{f} ({label})" for f, label in columns]
    rows = []
    for k in row_keys:
        first = next(recs[k] for _, recs in by_run if k in recs)
        cells = [fmt(first.get(name)) for name in keys]
        for f, label in columns:
            source = first if label is None else dict(by_run)[label].get(k, {})
            cells.append(fmt(source.get(f)))
        rows.append(cells)
    return markdown_table(header, rows)


def machine_words(prov: dict) -> str:
    """``NVIDIA H100 80GB HBM3`` for a GPU run, ``2 CPUs, load 5`` for a CPU run (the 1-minute load average)."""
    m = prov.get("machine") or {}
    if m.get("gpu"):
        return str(m["gpu"])
    load = f", load {fmt(m['load_average'])}" if m.get("load_average") is not None else ""
    return f"{m.get('cpus', '?')} CPUs{load}" if m else "–"


def slug(title: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation but ``-`` and ``_`` dropped, spaces as ``-``."""
    return re.sub(r"[^\w\- ]", "", title.lower()).replace(" ", "-")


@dataclass(frozen=True)
class Run:
    """One measured file: ``label`` heads its column in its benchmark's tables."""

    path: Path
    benchmark: str
    label: str
    data: dict

    @property
    def provenance(self) -> dict:
        return self.data.get("provenance") or {}

    @property
    def body(self) -> dict:
        return {k: v for k, v in self.data.items() if k != "provenance"}


def load_runs(folder: Path) -> dict[str, list[Run]]:
    """The JSON files of ``folder`` grouped by benchmark (``ABOUT``'s order, then by name), CPU runs first."""
    runs: dict[str, list[Run]] = {}
    for path in sorted(folder.glob("*.json"), key=lambda p: (p.stem.endswith("_gpu"), p.stem)):
        stem = path.stem
        default = (stem.removesuffix("_gpu"), "GPU" if stem.endswith("_gpu") else "CPU")
        benchmark, label = RUNS.get(stem, default)
        data = json.loads(path.read_text())
        runs.setdefault(benchmark, []).append(
            Run(path, benchmark, label, data if isinstance(data, dict) else {"results": data})
        )
    order = list(ABOUT)
    return dict(sorted(runs.items(), key=lambda kv: (order.index(kv[0]) if kv[0] in order else len(order), kv[0])))


def title_of(benchmark: str) -> str:
    return ABOUT[benchmark][0] if benchmark in ABOUT else benchmark.replace("_", " ").capitalize()


def runs_table(runs: list[Run]) -> list[str]:
    """Where and when each run was measured (and its note, where its provenance has one)."""
    rows = []
    for r in runs:
        p = r.provenance
        rows.append(
            [
                r.label,
                f"[`{r.path.name}`](../benchmarks/measured/{r.path.name})",
                fmt(p.get("date")),
                f"`{p['commit']}`" if p.get("commit") else "–",
                machine_words(p) if p else "not recorded",
                f"`{p['command']}`" if p.get("command") else "–",
            ]
        )
    out = markdown_table(["run", "file", "date", "commit", "machine", "command"], rows) + [""]
    out += [f"- {r.label}: {r.provenance['note']}" for r in runs if r.provenance.get("note")]
    return out + ([""] if out[-1] != "" else [])


def figures_tables(labels: list[str], figures: list[dict]) -> list[str]:
    """The runs' single figures: one run as ``| figure | value |``; several as ``| figure | run | run |`` for the
    figures where they differ, then one table of those every run has with the same value."""
    names: list[str] = []
    for f in figures:
        names += [n for n in f if n not in names]
    if not names:
        return []
    if len(figures) == 1:
        return markdown_table(["figure", "value"], [[n, fmt(figures[0][n])] for n in names]) + [""]
    shared = [n for n in names if all(n in f for f in figures) and len({fmt(f[n]) for f in figures}) == 1]
    differ = [n for n in names if n not in shared]
    out = []
    if differ:
        out += markdown_table(["figure", *labels], [[n, *[fmt(f.get(n)) for f in figures]] for n in differ]) + [""]
    if shared:
        out += markdown_table(["figure", "every run"], [[n, fmt(figures[0][n])] for n in shared]) + [""]
    return out


def section(benchmark: str, runs: list[Run]) -> list[str]:
    """``## title``, what it measures, its runs, then its figures and its tables with the runs side by side."""
    script, about = ABOUT.get(benchmark, ("", "", ""))[1:]
    out = [f"## {title_of(benchmark)}", ""]
    if about:
        out += [about + (f" Written by `{script}`." if script else ""), ""]
    out += runs_table(runs)
    labels = [r.label for r in runs]
    split = [split_values(r.body) for r in runs]
    out += figures_tables(labels, [figures for figures, _ in split])
    tables: list[str] = []
    for _, found in split:
        tables += [t for t in found if t not in tables]
    for t in tables:
        out += [f"### `{t}`", "", *side_by_side_records(labels, [found.get(t) for _, found in split]), ""]
    return out


def read_path(data, path: str):
    """The value at ``path`` in ``data``: dotted keys (a key with a dot in it, ``fps.0.5``, is read whole),
    ``name[k=v,k2=v2]`` the one record of the list ``name`` whose fields show as those values; KeyError naming the
    step that is missing."""
    steps = re.findall(r"[^.\[]+(?:\[[^\]]*\])?", path)
    while steps:
        # the longest run of steps that is one key: "0.5" in {"0.2": .., "0.5": ..}
        n = next((n for n in range(len(steps), 0, -1) if isinstance(data, dict) and ".".join(steps[:n]) in data), 1)
        step, steps = ".".join(steps[:n]), steps[n:]
        name, _, match = step.partition("[")
        if not isinstance(data, dict) or name not in data:
            raise KeyError(f"no field '{name}'")
        data = data[name]
        if match:
            wanted = dict(pair.split("=", 1) for pair in re.split(r",(?=[^,=]+=)", match.rstrip("]")))
            hits = [r for r in data or [] if all(fmt(r.get(k)) == v for k, v in wanted.items())]
            if len(hits) != 1:
                raise KeyError(f"{len(hits)} records of '{name}' match [{match}")
            data = hits[0]
    return data


def headline_rows(runs: dict[str, list[Run]]) -> list[list[str]]:
    by_file = {r.path.name: r for group in runs.values() for r in group}
    rows = []
    for h in HEADLINES:
        run = by_file.get(h.file)
        if run is None:
            continue
        try:
            value = read_path(run.data, h.path)
        except KeyError as e:
            raise HeadlineError(f"{run.path}: headline '{h.figure}' reads {h.path}: {e.args[0]}") from None
        try:
            prov = read_path(run.data, h.provenance) if h.provenance else run.provenance
        except KeyError as e:
            raise HeadlineError(
                f"{run.path}: headline '{h.figure}' reads its provenance at {h.provenance}: {e.args[0]}"
            ) from None
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise HeadlineError(f"{run.path}: headline '{h.figure}' reads {h.path}: expected a number, found {value!r}")
        title = title_of(run.benchmark)
        rows.append(
            [
                h.figure,
                fmt(float(value) * h.scale),
                h.unit,
                h.kind,
                h.machine or machine_words(prov),
                str(prov.get("date", "–"))[:10],
                f"[{title}](#{slug(title)}) · [`{h.file}`](../benchmarks/measured/{h.file})",
            ]
        )
    return rows


def render_page(folder: Path = MEASURED) -> str:
    """The whole page for the JSON files in ``folder``; HeadlineError when a headline's value is not in its file."""
    runs = load_runs(folder)
    lines = [
        "# Benchmarks",
        "",
        "<!-- generated by benchmarks/make_docs.py from benchmarks/measured/*.json: do not edit by hand -->",
        "",
        "What the benchmarks in `benchmarks/` measured, with where and when. The JSON in `benchmarks/measured/` is "
        "the record; re-measure with the command shown under a section, writing its JSON there, then run "
        "`make docs` (a test fails while this page and the JSON disagree). Timings on a shared machine swing "
        "between runs: compare numbers within one run (the machine column gives the 1-minute load average when "
        "the result was written). *Computed* figures come from FLOP counts and configurations, not from a run.",
        "",
        *markdown_table(
            ["figure", "value", "unit", "kind", "machine", "date", "section · record"], headline_rows(runs)
        ),
        "",
        "Benchmarks: " + " · ".join(f"[{title_of(b)}](#{slug(title_of(b))})" for b in runs),
        "",
    ]
    for benchmark, group in runs.items():
        lines += section(benchmark, group)
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="exit 1 if the page differs from what the JSON gives")
    args = ap.parse_args(argv)
    try:
        text = render_page(MEASURED)
    except HeadlineError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.check:
        if not PAGE.is_file() or PAGE.read_text() != text:
            print(f"{PAGE} is out of date: run make docs", file=sys.stderr)
            return 1
        return 0
    sys.path.insert(0, str(REPO))
    from oscar_core._util.atomic import atomic_write_bytes

    print(f"wrote {atomic_write_bytes(PAGE, text.encode())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
