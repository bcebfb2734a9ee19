"""``oscar data``: the data pipeline's sub-commands (registered with one line in ``oscar_core.cli``)."""

from __future__ import annotations

import argparse
import json
import sys

from .._util.arg_types import count, device, number
from .._util.outputs import output_option

__all__ = ["add_data_parser"]

EXAMPLE = """\
examples:
  oscar data sample-dataset data/sample        (a small LeRobot v3.0 dataset, made here: no download)
  oscar data ingest data/sample --reader lerobot --out runs/sample
  oscar data dedup runs/sample --embedder trajectory   (no SigLIP weights)
  oscar data ingest /data/mydataset --reader npz --out runs/r1
  oscar data ingest /data/droid_1.0.1 --reader lerobot --reader-option intrinsics=droid_cams.json --out runs/droid
  oscar data filter runs/r1 --set min_length=70 --set max_camera_motion=0.02
  oscar data dedup runs/r1 --siglip google/siglip-base-patch16-224
  oscar data caption runs/r1 --endpoint http://localhost:8000/v1 --model Qwen/Qwen3-VL-30B-A3B-Instruct --budget 1000
  oscar data export runs/r1 --out clips/r1
  oscar data stats runs/r1 --plot runs/r1/stats.png   (also writes runs/r1/stats.html)
every stage: --engine local|ray, --workers N, --shard-size N; re-running a stage finishes it without redoing work.
"""


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--engine",
        choices=("local", "ray"),
        default="local",
        help='local: a process pool (default); ray: Ray Data (pip install "oscar-wm[ray]")',
    )
    p.add_argument(
        "--workers",
        type=count(1),
        default=None,
        help="worker processes / Ray CPUs, one torch thread each (default: the cores idle now; 1: in-process)",
    )
    p.add_argument(
        "--shard-size", type=count(1), default=32, help="episodes per shard, the unit of resumption (default 32)"
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def _kw(args) -> dict:
    return {
        "engine": args.engine,
        "workers": args.workers,
        "shard_size": args.shard_size,
        "progress": not args.no_progress,
        "plugin_paths": tuple(args.plugin or ()),
    }


def _run_log(run: str, stage: str):
    """``RUN/logs/data-<stage>-<UTC>.log`` for a local run folder (``oscar_core._util.log.run_log``); nothing for a URL."""
    import contextlib

    from .._util.log import run_log

    if "://" in str(run) and not str(run).startswith("file://"):
        return contextlib.nullcontext()
    return run_log(str(run).removeprefix("file://"), f"data-{stage}")


def _report(run, what: str) -> None:
    from .._util.log import log_result

    log_result(
        f"{len(run.processed)} shards done now, {len(run.skipped)} already done, {len(run.incomplete)} unfinished"
    )
    print(
        f"{what}: {len(run.processed)} shards done now, {len(run.skipped)} already done"
        + (f", {len(run.incomplete)} unfinished (run again)" if run.incomplete else "")
    )
    if run.rows:
        from .manifest import is_alive

        alive = sum(is_alive(r) for r in run.rows)
        print(f"{what}: {alive} of {len(run.rows)} episodes live -> {run.stage_url}")


def cmd_ingest(args) -> int:
    from .reader_options import parse_reader_options
    from .run import run_ingest

    options = parse_reader_options(args.reader_option)
    with _run_log(args.out, "ingest"):
        res = run_ingest(args.source, args.reader, args.out, reader_options=options, **_kw(args))
        _report(res, "ingest")
    return 0


def cmd_filter(args) -> int:
    from .filters import FilterConfig
    from .run import run_filter

    with _run_log(args.run, "filter"):
        res = run_filter(args.run, FilterConfig.from_overrides(args.set), **_kw(args))
        _report(res, "filter")
    return 0


def cmd_dedup(args) -> int:
    from .dedup import DedupConfig, SiglipEmbedder, TrajectoryEmbedder
    from .run import run_dedup

    if args.embedder == "siglip" and not args.siglip:
        raise ValueError(
            "oscar data dedup: --siglip: expected a SigLIP model (Hub id or folder) with --embedder siglip, "
            "found none (or use --embedder trajectory, which needs no weights)"
        )
    embedder = SiglipEmbedder(args.siglip, args.device) if args.embedder == "siglip" else TrajectoryEmbedder()
    cfg = DedupConfig(cosine=args.cosine, rms_alpha=args.rms_alpha, rms_floor=args.rms_floor, nprobe=args.nprobe)
    with _run_log(args.run, "dedup"):
        res, summary = run_dedup(args.run, embedder, cfg, **_kw(args))
        _report(res, "dedup")
    print("dedup: " + ", ".join(f"{k} {v}" for k, v in summary.items()))
    return 0


def cmd_caption(args) -> int:
    from .caption import CaptionConfig
    from .run import run_caption

    cfg = CaptionConfig(
        base_url=args.endpoint,
        model=args.model,
        fps=args.fps,
        long_fps=args.long_fps,
        max_frames=args.max_frames,
        budget=args.budget,
        max_retries=args.retries,
        api_key_env=args.api_key_env,
    )
    with _run_log(args.run, "caption"):
        res = run_caption(args.run, cfg, **_kw(args))
        _report(res, "caption")
    return 0 if not res.incomplete else 3


def cmd_export(args) -> int:
    from ..render.skeleton_video import parse_size
    from .run import run_export

    size = parse_size(args.size) if args.size else None
    with _run_log(args.run, "export"):
        res = run_export(
            args.run, args.out, size=size, render_skeleton=args.render_skeleton, video_codec=args.codec, **_kw(args)
        )
        _report(res, "export")
    return 0


def cmd_stats(args) -> int:
    from . import _fs
    from .stats import compute_stats, format_table, plot_stats, stats_json

    st = compute_stats(args.run)
    text = stats_json(st)
    _fs.write_bytes_atomic(_fs.join(args.run, "stats.json"), text.encode())
    if args.plot:
        plot_stats(st, args.plot)
    page = None
    if not args.no_html:
        from .html import write_stats_html

        page = write_stats_html(st, args.run, plugin_paths=tuple(args.plugin or ()))
    sys.stdout.write(text + "\n" if args.json else format_table(st))
    if page is not None and not args.json:
        sys.stdout.write(f"wrote {page}\n")
    return 0


def cmd_sample_dataset(args) -> int:
    from .sample import write_sample_dataset

    summary = write_sample_dataset(args.out, frames=args.frames, seed=args.seed)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(
            f"{summary['dataset']}: {summary['episodes']} episodes, {summary['frames']} frames, LeRobot v3.0 "
            f"(DROID columns, one shared MP4); ingest it with --reader {summary['reader']}"
        )
    return 0


def _add_data_sample_dataset_parser(ds, fmt) -> None:
    """Register ``oscar data sample-dataset`` and its options on ``ds``."""
    p = ds.add_parser(
        "sample-dataset",
        help="write a small LeRobot v3.0 dataset (7 episodes, one shared MP4) to try the pipeline offline",
        epilog=EXAMPLE,
        formatter_class=fmt,
    )
    output_option(p.add_argument("out", help="a new folder"), "folder")
    p.add_argument("--frames", type=int, default=80, help="frames per episode (default 80)")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--json", action="store_true", help="print the summary (with each episode's expected fate) as JSON")
    p.set_defaults(func=cmd_sample_dataset)


def _add_data_ingest_parser(ds, fmt) -> None:
    """Register ``oscar data ingest`` and its options on ``ds``."""
    p = ds.add_parser(
        "ingest",
        help="list a dataset's episodes into a manifest and probe each one",
        epilog=EXAMPLE,
        formatter_class=fmt,
    )
    p.add_argument("source", help="dataset folder or fsspec URL")
    p.add_argument("--reader", required=True, help="dataset reader name (npz, lerobot, droid, …)")
    p.add_argument(
        "--reader-option",
        action="append",
        metavar="NAME=VALUE",
        help="a reader's constructor option (docs/datasets.md), e.g. intrinsics=cam.json for DROID from "
        "the Hub; VALUE is YAML or a .json/.yaml file; repeatable",
    )
    output_option(p.add_argument("--out", required=True, help="run folder or fsspec URL"), "folder")
    _common(p)
    p.set_defaults(func=cmd_ingest)


def _add_data_filter_parser(ds, fmt) -> None:
    """Register ``oscar data filter`` and its options on ``ds``."""
    p = ds.add_parser(
        "filter",
        help="length, static camera, meaningful action, visible skeleton, joint spikes "
        "(and, when asked, the calibration score)",
        epilog=EXAMPLE,
        formatter_class=fmt,
    )
    output_option(p.add_argument("run", help="run folder"), "folder")
    p.add_argument(
        "--set",
        action="append",
        metavar="NAME=VALUE",
        help="override a threshold (FilterConfig field: min_length, max_camera_motion, min_action, "
        "min_visible, max_joint_speed, max_point_speed, min_calibration_score (0: off), …); "
        "repeatable",
    )
    _common(p)
    p.set_defaults(func=cmd_filter)


def _add_data_dedup_parser(ds, fmt) -> None:
    """Register ``oscar data dedup`` and its options on ``ds``."""
    p = ds.add_parser(
        "dedup",
        help="SigLIP (or motion) candidates (cosine > 0.95) verified by trajectory RMS, one kept per group",
        epilog=EXAMPLE,
        formatter_class=fmt,
    )
    output_option(p.add_argument("run", help="run folder"), "folder")
    p.add_argument(
        "--embedder",
        choices=("siglip", "trajectory"),
        default="siglip",
        help="siglip: SigLIP picture embeddings find candidates (the paper; needs --siglip); trajectory: "
        "the skeleton's motion does, no weights to download",
    )
    p.add_argument("--siglip", help="SigLIP vision model: Hub id or local folder (with --embedder siglip)")
    p.add_argument("--device", type=device, default="cpu", help="torch device for SigLIP")
    p.add_argument(
        "--cosine", type=number(-1.0, 1.0), default=0.95, help="visual candidate threshold (default 0.95, the paper's)"
    )
    p.add_argument(
        "--rms-alpha", type=number(0.0), default=0.25, help="duplicate when RMS < alpha x smaller motion scale"
    )
    p.add_argument("--rms-floor", type=number(0.0), default=0.01, help="... or below this many metres (default 0.01)")
    p.add_argument("--nprobe", type=count(1), default=16, help="k-means clusters searched per episode (default 16)")
    _common(p)
    p.set_defaults(func=cmd_dedup)


def _add_data_caption_parser(ds, fmt) -> None:
    """Register ``oscar data caption`` and its options on ``ds``."""
    p = ds.add_parser(
        "caption",
        help="captions from an OpenAI-compatible VLM endpoint (cached, retried, budgeted)",
        epilog=EXAMPLE,
        formatter_class=fmt,
    )
    output_option(p.add_argument("run", help="run folder"), "folder")
    p.add_argument("--endpoint", required=True, help="base URL, e.g. http://localhost:8000/v1")
    p.add_argument("--model", required=True, help="model name the endpoint serves")
    p.add_argument("--budget", type=count(0), default=None, help="at most this many episodes sent this run")
    p.add_argument("--fps", type=number(above=0.0), default=15.0, help="frames per second of episode sent (default 15)")
    p.add_argument("--long-fps", type=number(above=0.0), default=2.0, help="for DROID / long episodes (default 2)")
    p.add_argument("--max-frames", type=count(1), default=256, help="frames per request at most (default 256)")
    p.add_argument("--retries", type=count(0), default=4, help="retries per request (default 4)")
    p.add_argument("--api-key-env", default="OPENAI_API_KEY", help="environment variable with the API key")
    _common(p)
    p.set_defaults(func=cmd_caption)


def _add_data_export_parser(ds, fmt) -> None:
    """Register ``oscar data export`` and its options on ``ds``."""
    p = ds.add_parser(
        "export",
        help="live episodes as training clips (docs/formats.md, Training clips)",
        epilog=EXAMPLE,
        formatter_class=fmt,
    )
    output_option(p.add_argument("run", help="run folder"), "folder")
    output_option(p.add_argument("--out", required=True, help="clip set folder or fsspec URL"), "folder")
    p.add_argument("--size", help="WIDTHxHEIGHT to resize to (default: the video's)")
    p.add_argument(
        "--render-skeleton",
        action="store_true",
        help="store the skeleton video (default: the trainer renders it on the fly)",
    )
    p.add_argument(
        "--codec", choices=("ffv1", "h264"), default="ffv1", help="clip video codec (default ffv1, lossless)"
    )
    _common(p)
    p.set_defaults(func=cmd_export)


def _add_data_stats_parser(ds, fmt) -> None:
    """Register ``oscar data stats`` and its options on ``ds``."""
    p = ds.add_parser(
        "stats",
        help="the paper's Table 1 for a run: public vs kept, rejections per filter",
        epilog=EXAMPLE,
        formatter_class=fmt,
    )
    output_option(p.add_argument("run", help="run folder"), "folder")
    p.add_argument("--json", action="store_true", help="print JSON (always written to RUN/stats.json)")
    output_option(
        p.add_argument("--plot", metavar="PATH", help="also save a bar chart (.png/.pdf/.svg; needs oscar-wm[plots])"),
        "file",
    )
    p.add_argument(
        "--no-html",
        action="store_true",
        help="do not write RUN/stats.html (the funnel with thumbnails of rejected episodes per reason)",
    )
    p.set_defaults(func=cmd_stats)


def add_data_parser(sub) -> None:
    """Register ``oscar data <stage>`` on the top-level sub-parser collection."""
    fmt = argparse.RawDescriptionHelpFormatter
    d = sub.add_parser(
        "data", help="data pipeline: ingest, filter, dedup, caption, export, stats", epilog=EXAMPLE, formatter_class=fmt
    )
    ds = d.add_subparsers(dest="data_command", required=True)
    _add_data_sample_dataset_parser(ds, fmt)
    _add_data_ingest_parser(ds, fmt)
    _add_data_filter_parser(ds, fmt)
    _add_data_dedup_parser(ds, fmt)
    _add_data_caption_parser(ds, fmt)
    _add_data_export_parser(ds, fmt)
    _add_data_stats_parser(ds, fmt)
