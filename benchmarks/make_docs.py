"""Write docs/benchmarks.md from the measured benchmark JSON under benchmarks/measured/.

    python benchmarks/make_docs.py            # rewrite docs/benchmarks.md
    python benchmarks/make_docs.py --check    # exit 1 if docs/benchmarks.md is not what the JSON gives

Every ``benchmarks/measured/*.json`` becomes one section: what the benchmark measures, its provenance (UTC date,
commit, machine, command line; written by ``benchmarks/_provenance.py``) and its results as tables. Results are
rendered from the JSON's own structure (a list of records is a table, a record of numbers a two-column table,
nested records sub-sections), so a new field shows up without a change here, and GPU runs of the same benchmarks
(``*_gpu.json``, ``make bench-gpu``) render the same way. The page holds no number that is not in a JSON file.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
MEASURED = REPO / "benchmarks" / "measured"
PAGE = REPO / "docs" / "benchmarks.md"

#: file stem (without ``_gpu``) -> (title, the script, what it measures). Unknown stems get a plain title.
ABOUT: dict[str, tuple[str, str, str]] = {
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
    "rollout": (
        "World-model rollout",
        "benchmarks/rollout.py",
        "The tiny CPU configuration's denoising step and whole rollout (`tiny`: batched classifier-free "
        "guidance against two passes, in the same run); the 2B model's size, tokens and FLOPs computed from "
        "its configuration (`expected_2b`, `computed_2b`: computed, not measured); with `--gpu` or "
        "`--measure`, each sampling preset measured on the device (`measured`).",
    ),
    "rollout_paper": (
        "World-model rollout, both presets eager (a stopped run)",
        "benchmarks/rollout.py",
        "`make bench-gpu`'s rollout line as it stood, stopped by its time limit while compiling (`complete`: "
        "false): the eager rows of `--preset paper` and `fast`, the VAE's chunk work and the FLOP counts; the "
        "compiled rows are in `rollout_gpu.json`.",
    ),
    "distill_speed": (
        "Teacher, `fast` and the few-step student",
        "benchmarks/distill_speed.py",
        "One 17-frame 64x64 chunk of `oscar-toy` (one thread) for the teacher at `--preset paper`, its card's "
        "sampler and `--preset fast`, and the distilled student at 4, 2 and 1 steps: DiT evaluations counted on "
        "the real transformer (equal to `model_calls`), FLOPs counted by `torch.utils.flop_counter`, median CPU and "
        "wall milliseconds per part (condition render, VAE encodes, DiT, VAE decode); `computed_2b`: the 2B at 81 "
        "frames, 512x288, on one H200 / H100 from those evaluations (computed, not measured); `vae_cut`: decoding "
        "only a chunk's end (toy VAE measured, 2B FLOP ratio counted).",
    ),
    "closed_loop": (
        "Closed-loop policy evaluation",
        "benchmarks/closed_loop.py",
        "Toy sessions x 2 image-based toy policies closed loop in `oscar-toy` (one torch thread), run one cell "
        "at a time and with `--batch-cells N` for each N given, interleaved in the same process: cells per "
        "CPU-minute and per wall-minute, and per closed-loop step (one chunk of one cell) the CPU milliseconds of "
        "the policy's calls, the action adapter (IK), the condition render, the VAE encodes, the DiT, the VAE "
        "decode, the cell's writes, the report and the rest (`cpu_ms_per_step`), beside the wall milliseconds "
        "from the cells' records.",
    ),
    "cli_rollout": (
        "One `oscar rollout` end to end",
        "benchmarks/cli_rollout.py",
        "The real command in a fresh process rolling out one chunk, timed from outside; `fixed_s` = "
        "wall − encode − sample − decode (imports, loading, writing).",
    ),
    "threads": (
        "Torch threads on a busy machine",
        "benchmarks/threads.py",
        "The bundled `oscar-toy` rollout (a fresh `oscar toyworld rollout` process per row) beside background "
        "processes that each keep one core busy, with `--threads 1`, `--threads 2` and the automatic choice "
        "(the cores idle by the 1-minute load average). Median wall seconds from spawn to exit and CPU seconds "
        "of the process; `wall_vs_best` is the row's wall over the best row's (goal for `auto`: at most 1.10).",
    ),
    "train": (
        "Training",
        "benchmarks/train.py",
        "Steps/s of the tiny config on the CPU (cached latents with 1 and 2 processes, and the naive way: "
        "VAE encode and skeleton render in the loop), and the 2B model's training memory per GPU under FSDP2 "
        "(`memory`: computed from its configuration, not measured).",
    ),
    "train_step": (
        "Training step",
        "benchmarks/train.py --step-table",
        "One training step's time and peak memory under activation checkpointing none/full and compile.",
    ),
}


def fmt(value) -> str:
    """A cell: 4 significant digits for floats (whole numbers from 10,000 up), lists joined, text with table pipes
    escaped."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.0f}" if abs(value) >= 1e4 else f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        return ", ".join(fmt(v) for v in value)
    if value is None:
        return "–"
    return str(value).replace("|", "\\|").replace("\n", " ")


def empty(value) -> bool:
    """Nothing measured: left out of the page (a ``None`` inside a table's row is shown as "–")."""
    return value is None or (isinstance(value, (list, tuple, dict)) and len(value) == 0)


def is_scalar(value) -> bool:
    return (
        value is None
        or isinstance(value, (str, int, float, bool))
        or (isinstance(value, (list, tuple)) and all(isinstance(v, (str, int, float, bool)) for v in value))
    )


def flatten(record: dict, prefix: str = "") -> dict:
    """``{"a": {"b": 1}}`` -> ``{"a.b": 1}`` (scalars and lists of scalars kept; deeper lists of records shown as a
    count)."""
    out = {}
    for key, value in record.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, name + "."))
        elif is_scalar(value):
            out[name] = value
        else:
            out[name] = f"{len(value)} records"
    return out


def table(rows: list[dict]) -> list[str]:
    flat = [flatten(r) for r in rows]
    columns: list[str] = []
    for r in flat:
        columns += [c for c in r if c not in columns]
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(r.get(c)) for c in columns) + " |" for r in flat]
    return lines


def section(name: str, value, depth: int) -> list[str]:
    """Markdown for one JSON value under the heading ``name`` (``depth`` = heading level)."""
    head = "#" * min(depth, 6) + f" `{name}`"
    if value is None or value == [] or value == {}:
        return []
    if is_scalar(value):
        return [f"- `{name}`: {fmt(value)}"]
    if isinstance(value, list) and all(isinstance(v, dict) for v in value):
        return [head, "", *table(value), ""]
    if isinstance(value, dict):
        scalars = {k: v for k, v in value.items() if is_scalar(v) and not empty(v)}
        nested = {k: v for k, v in value.items() if not is_scalar(v) and not empty(v)}
        out = [head, ""]
        if scalars:
            out += ["| field | value |", "|---|---|", *[f"| {k} | {fmt(v)} |" for k, v in scalars.items()], ""]
        for key, sub in nested.items():
            out += section(key, sub, depth + 1)
        return out if len(out) > 2 else []
    return [head, "", "```", json.dumps(value), "```", ""]


def provenance_lines(prov: dict | None) -> list[str]:
    if not prov:
        return ["*Provenance: not recorded in this file.*", ""]
    m = prov.get("machine") or {}
    where = ", ".join(f"{k} {fmt(v)}" for k, v in m.items())
    return [
        f"- **date** {prov.get('date', '?')} · **commit** `{prov.get('commit', '?')}`",
        f"- **machine** {where}",
        f"- **command** `{prov.get('command', '?')}`",
        "",
    ]


def render_file(path: Path) -> list[str]:
    data = json.loads(path.read_text())
    stem = path.stem
    key = stem[:-4] if stem.endswith("_gpu") else stem
    title, script, about = ABOUT.get(key, (stem.replace("_", " ").capitalize(), "", ""))
    gpu = " (GPU)" if stem.endswith("_gpu") else ""
    out = [
        f"## {title}{gpu}",
        "",
        f"From `benchmarks/measured/{path.name}`" + (f", written by `{script}`." if script else "."),
        "",
    ]
    if about:
        out += [about, ""]
    out += provenance_lines(data.get("provenance") if isinstance(data, dict) else None)
    body = (
        {k: v for k, v in data.items() if k != "provenance" and not empty(v)}
        if isinstance(data, dict)
        else {"results": data}
    )
    scalars = {k: v for k, v in body.items() if is_scalar(v)}
    if scalars:
        out += ["| field | value |", "|---|---|", *[f"| {k} | {fmt(v)} |" for k, v in scalars.items()], ""]
    for k, v in body.items():
        if not is_scalar(v):
            out += section(k, v, 3)
    return out


def render_page(folder: Path = MEASURED) -> str:
    files = sorted(folder.glob("*.json"), key=lambda p: (p.stem.endswith("_gpu"), p.stem))
    lines = [
        "# Benchmarks",
        "",
        "<!-- generated by benchmarks/make_docs.py from benchmarks/measured/*.json: do not edit by hand -->",
        "",
        "What each benchmark in `benchmarks/` measured, with where and when. Re-measure with the command shown "
        "under each section, writing its JSON into `benchmarks/measured/`, then run "
        "`python benchmarks/make_docs.py` (a test fails while this page and the JSON disagree). Timings on a "
        "shared machine swing between runs; compare numbers within one run (each section's machine "
        "line has the 1-minute load average when the result was written).",
        "",
    ]
    lines += ["| section | file | date | commit |", "|---|---|---|---|"]
    for f in files:
        prov = (json.loads(f.read_text()) or {}).get("provenance") or {}
        key = f.stem[:-4] if f.stem.endswith("_gpu") else f.stem
        title = ABOUT.get(key, (f.stem,))[0] + (" (GPU)" if f.stem.endswith("_gpu") else "")
        lines.append(f"| {title} | `{f.name}` | {prov.get('date', '–')} | `{prov.get('commit', '–')}` |")
    lines.append("")
    for f in files:
        lines += render_file(f)
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="exit 1 if the page differs from what the JSON gives")
    args = ap.parse_args(argv)
    text = render_page()
    if args.check:
        if not PAGE.is_file() or PAGE.read_text() != text:
            print(f"{PAGE.relative_to(REPO)} is out of date: run python benchmarks/make_docs.py", file=sys.stderr)
            return 1
        return 0
    sys.path.insert(0, str(REPO))
    from oscar_core._util.atomic import atomic_write_bytes

    print(f"wrote {atomic_write_bytes(PAGE, text.encode())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
