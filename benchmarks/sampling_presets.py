"""Sampling budgets measured on the trained toy model: quality lost against FLOPs saved.

    python benchmarks/sampling_presets.py --clips CLIPSET --preds PREDS [--json benchmarks/results/sampling_presets.json]

Every preset is rolled out by ``oscar toyworld rollout CLIPSET --model oscar-toy --condition true --limit 45
--guidance 3 --steps N [--guidance-interval LO,HI] --out PREDS/<name>`` (the commands are printed; rollouts
already in PREDS are reused, so the script resumes). For each preset it then reports, on the same held-out
clips and seed:

* motion IoU and PSNR against the ground truth (``oscar toyworld eval``'s per-clip metrics), and their paired
  difference from the 35-step reference with a 95 % bootstrap interval (2,000 resamples of the clips, seed 0);
* the distance to the reference rollout itself (PSNR of the preset's video against the 35-step one);
* model calls per chunk (DiT evaluations, batch items: 2 per guided step, 1 per unguided one) and, computed
  from them, the FLOPs of one chunk of the 2B model at the paper's 81 frames, 512x288 (79.2 TFLOP per batch
  item: 158.4 TFLOP for one guided step, measured by `benchmarks/rollout.py --gpu`'s FLOP count), and the
  frames/s an H200 would give at the compiled throughput measured there (576 TFLOP/s) plus the VAE's 2.1 s per
  chunk: **computed, not measured** on a GPU.

Wall and CPU seconds per rollout on this machine come from the rollout commands' own timing (``--json`` of
the rollout summary), one thread each.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

#: name -> (steps, guidance interval or None); "s35" is the reference (the paper's 35 steps, guidance everywhere)
PRESETS = {
    "s35": (35, None),
    "s20": (20, None),
    "s12": (12, None),
    "s8": (8, None),
    "s12_iv": (12, (0.3, 1.0)),
    "s12_iv_mid": (12, (0.3, 0.9)),
    "s12_iv_low": (12, (0.0, 0.8)),
    "s12_iv_high": (12, (0.8, 1.0)),
    "s8_iv": (8, (0.3, 1.0)),
    "s8_iv_mid": (8, (0.3, 0.9)),
    "s35_cond": (35, "cond"),
}
REFERENCE = "s35"
GUIDANCE = 3.0  # the toy model's table guidance (docs/toyworld.md)
TFLOP_PER_ITEM = 79.2  # 2B, 81 frames, 512x288: one DiT evaluation of batch 1
GPU_TFLOPS = 576.0  # compiled, measured on one H200 (issue 23's table)
VAE_S = 2.1  # VAE encode x2 + decode per chunk on the same GPU
CHUNK_FRAMES = 81


def command(clips: str, preds: Path, name: str) -> list[str]:
    steps, iv = PRESETS[name]
    cmd = [
        sys.executable,
        "-m",
        "oscar_core.cli",
        "toyworld",
        "rollout",
        clips,
        "--model",
        "oscar-toy",
        "--condition",
        "true",
        "--limit",
        "45",
        "--threads",
        "1",
        "--steps",
        str(steps),
        "--guidance",
        "0" if iv == "cond" else str(GUIDANCE),
        "--out",
        str(preds / name),
    ]
    if isinstance(iv, tuple):
        cmd += ["--guidance-interval", f"{iv[0]},{iv[1]}"]
    return cmd


def config_of(name: str):
    from oscar_core.model.sampler import SamplerConfig

    steps, iv = PRESETS[name]
    if iv == "cond":
        return SamplerConfig(steps=steps, guidance=0.0)
    return SamplerConfig(steps=steps, guidance=GUIDANCE, guidance_interval=iv)


def paired_interval(diff: np.ndarray, rng: np.random.Generator, n: int = 2000) -> tuple[float, float]:
    """95 % percentile bootstrap interval of the mean of paired differences (oscar_core.metrics.paired)."""
    from oscar_core.metrics.paired import paired_bootstrap_interval

    return paired_bootstrap_interval(diff, n, rng=rng)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--clips", required=True, help="the toy clip set (oscar toyworld generate ... --seed 0)")
    ap.add_argument("--preds", required=True, help="folder of the presets' rollouts (PREDS/<preset>/)")
    ap.add_argument("--json", default="benchmarks/results/sampling_presets.json")
    args = ap.parse_args()
    preds = Path(args.preds)

    from oscar_core.metrics import psnr
    from oscar_core.metrics.video import load_video
    from oscar_core.model.sampler import model_calls
    from oscar_core.toyworld.evaluate import evaluate_conditions, find_prediction

    for name in PRESETS:  # resumable: a clip already rolled out is skipped by the rollout command
        cmd = command(args.clips, preds, name)
        print("$", " ".join(cmd[1:]), flush=True)
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    table = evaluate_conditions(args.clips, {n: str(preds / n) for n in PRESETS}, split="heldout")
    ids = sorted(set.intersection(*(set(table["clips"][n]) for n in PRESETS)))
    rng = np.random.default_rng(0)
    ref = table["clips"][REFERENCE]
    rows = []
    for name in PRESETS:
        per = table["clips"][name]
        iou = np.array([per[i]["motion_iou"] for i in ids])
        ps = np.array([per[i]["psnr_db"] for i in ids])
        d_iou = iou - np.array([ref[i]["motion_iou"] for i in ids])
        d_ps = ps - np.array([ref[i]["psnr_db"] for i in ids])
        to_ref = [
            float(
                np.mean(
                    np.minimum(
                        psnr(
                            load_video(find_prediction(preds / name, i)),
                            load_video(find_prediction(preds / REFERENCE, i)),
                            n_frames=None,
                        ),
                        100.0,
                    )
                )
            )
            for i in ids
        ]
        calls = model_calls(config_of(name))
        tflop = calls * TFLOP_PER_ITEM
        rows.append(
            {
                "preset": name,
                "steps": PRESETS[name][0],
                "guidance": "none (conditional branch)"
                if PRESETS[name][1] == "cond"
                else ("every step" if PRESETS[name][1] is None else f"sigma in {list(PRESETS[name][1])}"),
                "clips": len(ids),
                "motion_iou": float(iou.mean()),
                "d_motion_iou": float(d_iou.mean()),
                "d_motion_iou_ci95": paired_interval(d_iou, rng),
                "psnr_db": float(ps.mean()),
                "d_psnr_db": float(d_ps.mean()),
                "d_psnr_ci95": paired_interval(d_ps, rng),
                "psnr_to_reference_db": float(np.mean(to_ref)),
                "model_calls_per_chunk": calls,
                "tflop_per_chunk_2b_computed": tflop,
                "h200_frames_per_s_computed": CHUNK_FRAMES / (tflop / GPU_TFLOPS + VAE_S),
            }
        )
    head = (
        f"{'preset':11s} {'steps':>5s} {'guidance':>22s} {'IoU':>6s} {'dIoU [95% CI]':>24s} {'PSNR':>6s} "
        f"{'dPSNR [95% CI]':>24s} {'to ref':>7s} {'calls':>5s} {'TFLOP':>6s} {'fps*':>5s}"
    )
    print(head)
    for r in rows:
        ci, cp = r["d_motion_iou_ci95"], r["d_psnr_ci95"]
        print(
            f"{r['preset']:11s} {r['steps']:5d} {r['guidance']:>22s} {r['motion_iou']:6.3f} "
            f"{r['d_motion_iou']:+7.3f} [{ci[0]:+.3f}, {ci[1]:+.3f}] {r['psnr_db']:6.2f} "
            f"{r['d_psnr_db']:+6.2f} [{cp[0]:+.2f}, {cp[1]:+.2f}]   {r['psnr_to_reference_db']:7.2f} "
            f"{r['model_calls_per_chunk']:5d} {r['tflop_per_chunk_2b_computed']:6.0f} "
            f"{r['h200_frames_per_s_computed']:5.1f}"
        )
    print(
        "* frames/s of the 2B on one H200: computed from the FLOPs (576 TFLOP/s compiled + 2.1 s VAE per "
        "81-frame chunk), not measured"
    )
    floor = None
    if (preds / "shuffled20").is_dir():  # the skeleton-following floor: another clip's skeleton, 20 steps
        shuffled = evaluate_conditions(args.clips, {"shuffled": str(preds / "shuffled20")}, split="heldout")
        floor = float(np.mean([shuffled["clips"]["shuffled"][i]["motion_iou"] for i in ids]))
        print(
            f"floor: a shuffled skeleton (20 steps, guidance everywhere) scores motion IoU {floor:.3f} on these clips"
        )
    out = {
        "machine": platform.platform(),
        "python": sys.version.split()[0],
        "clips": args.clips,
        "reference": REFERENCE,
        "guidance": GUIDANCE,
        "rows": rows,
        "shuffled_skeleton_motion_iou": floor,
    }
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
