"""Data-pipeline throughput: episodes/s per stage and engine, and dedup candidate search at scale.

    python benchmarks/data.py stages [--episodes 16] [--json benchmarks/results/data_stages.json]
    python benchmarks/data.py dedup [--sizes 10000,100000,1000000] [--brute-max 100000] [--json benchmarks/results/data_dedup.json]

``stages``: synthetic episodes (the toy arm, 81 frames at 128x72, lossless
MKV) through ingest, filter, dedup-embed (a tiny random SigLIP: this measures
the pipeline's own cost — decoding, FK, I/O — not a real SigLIP forward pass)
and export, with the in-process loop (the naive way), the local process pool
and Ray Data (when installed). Episodes/s are end to end, pool start-up
included.

``dedup``: unit embeddings of SigLIP-base width (768) in clusters of near
duplicates plus as many unrelated ones; each size runs in a fresh process so
its peak memory (max RSS) is its own. The pipeline's candidate search
(``oscar_core.data.dedup.candidate_pairs``, default settings, time per phase)
against the exact all-pairs answer (faiss ``IndexFlatIP`` range search) up
to ``--brute-max`` (recall, false pairs, time). Timings on shared machines
swing; compare within a run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))


def _table(head, rows):
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) for i, h in enumerate(head)]

    def line(cells):
        return "  ".join(str(c).rjust(w) for c, w in zip(cells, widths))

    return "\n".join([line(head), "  ".join("-" * w for w in widths), *map(line, rows)])


def bench_stages(n: int, workers: int) -> list[dict]:
    import torch
    import transformers
    from _datasets import write_episode

    from oscar_core.data.dedup import SiglipEmbedder
    from oscar_core.data.run import run_dedup, run_export, run_filter, run_ingest

    tmp = Path(tempfile.mkdtemp(prefix="oscar-data-bench-"))
    for i in range(n):
        write_episode(tmp / "src", f"ep{i:04d}", seed=i)
    torch.manual_seed(0)
    cfg = transformers.SiglipVisionConfig(
        hidden_size=32, intermediate_size=37, num_hidden_layers=2, num_attention_heads=2, image_size=32, patch_size=8
    )
    transformers.SiglipVisionModel(cfg).save_pretrained(tmp / "siglip")
    engines = {
        "in-process (naive)": dict(engine="local", workers=1),
        f"local pool x{workers}": dict(engine="local", workers=workers),
    }
    try:
        import ray  # noqa: F401

        engines[f"ray x{workers}"] = dict(engine="ray", workers=workers)
    except ImportError:
        print("ray not installed: skipping the ray engine")
    results = []
    shard = max(1, n // (2 * workers))
    for label, kw in engines.items():
        run = str(tmp / f"run-{kw['engine']}-{kw['workers']}")
        steps = {
            "ingest": lambda: run_ingest(str(tmp / "src"), "npz", run, shard_size=shard, progress=False, **kw),
            "filter": lambda: run_filter(run, shard_size=shard, progress=False, **kw),
            "dedup (tiny SigLIP)": lambda: run_dedup(
                run, SiglipEmbedder(str(tmp / "siglip")), shard_size=shard, progress=False, **kw
            ),
            "export": lambda: run_export(run, str(tmp / f"clips-{label[:5]}"), shard_size=shard, progress=False, **kw),
        }
        for stage, fn in steps.items():
            t = time.perf_counter()
            fn()
            dt = time.perf_counter() - t
            results.append(
                {
                    "engine": label,
                    "stage": stage,
                    "episodes": n,
                    "seconds": round(dt, 2),
                    "episodes_per_s": round(n / dt, 2),
                }
            )
            print(f"{label:22s} {stage:20s} {n / dt:7.2f} episodes/s", flush=True)
    shutil.rmtree(tmp, ignore_errors=True)
    return results


def synth(n: int, d: int = 768, per: int = 4, unrelated: float = 0.5, spread: float = 0.4, seed: int = 0):
    """(n, d) float32 unit rows: a fraction ``unrelated`` on their own random directions, the rest around
    (1 − unrelated)·n/per shared centres (near-duplicate groups), each row at a random noise level, so many pairs
    sit on both sides of cosine 0.95. Isotropic (the hard case for clustering and projection: real SigLIP
    embeddings concentrate on far fewer directions). Built in chunks to bound memory."""
    import numpy as np

    rng = np.random.default_rng(seed)
    grouped = int(round(n * (1 - unrelated)))
    centres = rng.standard_normal((max(1, grouped // per), d), dtype=np.float32)
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    x = np.empty((n, d), np.float32)
    for s in range(0, n, 65536):
        e = min(n, s + 65536)
        rows = rng.standard_normal((e - s, d), dtype=np.float32)  # the unrelated rows' own directions
        g = np.arange(s, e) < grouped
        rows[g] = centres[rng.integers(0, len(centres), int(g.sum()))]
        rows /= np.linalg.norm(rows, axis=1, keepdims=True)
        rows += (
            rng.uniform(0, spread, (e - s, 1)).astype(np.float32)
            * rng.standard_normal((e - s, d), dtype=np.float32)
            / np.sqrt(d)
        )
        x[s:e] = rows / np.linalg.norm(rows, axis=1, keepdims=True)
    return x


def dedup_one(n: int, brute: bool, brute_queries: int = 0) -> dict:
    """Time, phases and peak memory of the candidate search for n synthetic embeddings (run in its own process);
    with ``brute``, the exact answer by faiss's flat (all pairs) range search, its time, and the recall."""
    from oscar_core.data.dedup import DedupConfig, _exact_pairs, candidate_pairs

    x = synth(n)
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    cfg = DedupConfig()
    phases: dict[str, float] = {}
    t, c = time.perf_counter(), time.process_time()
    pairs = candidate_pairs(
        x, cfg.cosine, nlist=cfg.nlist, nprobe=cfg.nprobe, reduce_dim=cfg.reduce_dim, timings=phases
    )
    dt, cpu = time.perf_counter() - t, time.process_time() - c
    out = {
        "n": n,
        "dim": x.shape[1],
        "method": f"blocked IVF (PCA {cfg.reduce_dim}, 4·sqrt(N) lists, nprobe {cfg.nprobe}) + exact re-check",
        "seconds": round(dt, 2),
        "cpu_seconds": round(cpu, 2),
        "load_avg_1min": round(os.getloadavg()[0], 2),
        "phases_s": {k: round(v, 2) for k, v in phases.items()},
        "pairs": int(len(pairs)),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),
        "embeddings_mb": round(x.nbytes / 2**20),
        "rss_after_synth_mb": round(base),
    }
    if brute:
        t, c = time.perf_counter(), time.process_time()
        ref = _exact_pairs(x, cfg.cosine)  # faiss IndexFlatIP range search: every pair, exact
        out["brute_method"] = "faiss IndexFlatIP range search (all pairs)"
        out["brute_seconds"] = round(time.perf_counter() - t, 2)
        out["brute_cpu_seconds"] = round(time.process_time() - c, 2)
        found = {tuple(p) for p in pairs.tolist()}
        true = {tuple(p) for p in ref.tolist()}
        out["brute_pairs"] = int(len(ref))
        out["recall"] = round(len(found & true) / max(1, len(true)), 6)
        out["false_pairs"] = int(len(found - true))
    elif brute_queries:
        # every true pair touching a random sample of rows, by an exact flat range search of those rows against all:
        # each pair is in the sample with the same probability, so the recall over them estimates the recall
        import faiss
        import numpy as np

        rng = np.random.default_rng(1)
        sample = np.sort(rng.choice(n, min(n, brute_queries), replace=False))
        t, c = time.perf_counter(), time.process_time()
        index = faiss.IndexFlatIP(x.shape[1])
        index.add(x)
        lims, _, ids = index.range_search(x[sample], cfg.cosine)
        rows = np.repeat(sample, np.diff(np.asarray(lims, dtype=np.int64)))
        ids = np.asarray(ids, dtype=np.int64)
        keep = rows != ids
        true = {(min(a, b), max(a, b)) for a, b in zip(rows[keep].tolist(), ids[keep].tolist())}
        out["brute_method"] = f"faiss IndexFlatIP range search of {len(sample)} random rows against all"
        out["brute_seconds"] = round(time.perf_counter() - t, 2)
        out["brute_cpu_seconds"] = round(time.process_time() - c, 2)
        insample = np.zeros(n, bool)
        insample[sample] = True
        found = {tuple(p) for p in pairs[insample[pairs[:, 0]] | insample[pairs[:, 1]]].tolist()}
        out["brute_pairs"] = int(len(true))
        out["recall"] = round(len(found & true) / max(1, len(true)), 6)
        out["false_pairs"] = int(len(found - true))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("part", choices=("stages", "dedup", "dedup-one"))
    ap.add_argument("--episodes", type=int, default=16)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--sizes", default="10000,100000")
    ap.add_argument("--brute-max", type=int, default=10000, help="run the brute-force scan up to this size")
    ap.add_argument(
        "--brute-queries",
        type=int,
        default=1000,
        help="above --brute-max: the exact pairs of this many random rows (estimated recall)",
    )
    ap.add_argument("--json", help="write results here")
    args = ap.parse_args(argv)
    meta = {"machine": platform.platform(), "cpus": os.cpu_count(), "python": platform.python_version()}
    if args.part == "dedup-one":
        n = int(args.sizes)
        print(json.dumps(dedup_one(n, n <= args.brute_max, args.brute_queries)))
        return 0
    if args.part == "stages":
        res = bench_stages(args.episodes, args.workers)
        print()
        print(
            _table(
                ["engine", "stage", "episodes", "seconds", "episodes/s"],
                [[r["engine"], r["stage"], r["episodes"], r["seconds"], r["episodes_per_s"]] for r in res],
            )
        )
    else:
        res = []
        for n in [int(s) for s in args.sizes.split(",")]:
            p = subprocess.run(
                [
                    sys.executable,
                    __file__,
                    "dedup-one",
                    "--sizes",
                    str(n),
                    "--brute-max",
                    str(args.brute_max),
                    "--brute-queries",
                    str(args.brute_queries),
                ],
                capture_output=True,
                text=True,
                check=True,
            )
            r = json.loads(p.stdout.strip().splitlines()[-1])
            res.append(r)
            print(json.dumps(r), flush=True)
        print()
        print(
            _table(
                ["n", "seconds", "CPU s", "phases s", "pairs", "peak RSS MB", "brute s", "brute CPU s", "recall"],
                [
                    [
                        r["n"],
                        r["seconds"],
                        r.get("cpu_seconds", "-"),
                        " ".join(f"{k} {v}" for k, v in r["phases_s"].items()),
                        r["pairs"],
                        r["peak_rss_mb"],
                        r.get("brute_seconds", "-"),
                        r.get("brute_cpu_seconds", "-"),
                        r.get("recall", "-"),
                    ]
                    for r in res
                ],
            )
        )
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({"meta": meta, "results": res}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
