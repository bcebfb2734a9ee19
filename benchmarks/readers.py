"""Dataset-reader speed on a synthetic LeRobot v3.0 DROID dataset, against the naive way.

    python benchmarks/readers.py [--episodes 200] [--frames 40] [--repeats 3] [--json benchmarks/results/readers.json]

Writes one dataset in the real layout (all episodes in one shared parquet
file and one shared 320x180 H.264 MP4 per camera, as the Hub release packs
them), then times:

* listing: ``LeRobotReader.list_episodes`` (episode table only), episodes/s;
* one episode's state rows: pyarrow with a row filter on ``episode_index``
  (what the reader does) against reading the whole shared file and masking;
* the video check: demuxing the episode's packets (``probe_video``, what
  ``load_episode`` does) against decoding its frames (``VideoSource.read``);
* ``load_episode`` end to end, episodes/s.

Prints a table and writes JSON. Timings on a shared machine swing by up to
3x between runs: compare the ratios within one run.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def timed(fn, repeats: int) -> float:
    """Median seconds of ``repeats`` calls."""
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return statistics.median(out)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=200)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default="benchmarks/results/readers.json")
    args = ap.parse_args(argv)

    import pyarrow.parquet as pq
    import test_reader_lerobot as fixture

    from oscar_core.data.readers._common import probe_video
    from oscar_core.data.readers.lerobot import LeRobotReader

    def frames(n, offset):  # a moving gradient: cheap to encode, every frame different
        y, x = np.mgrid[0:180, 0:320]
        out = np.empty((n, 180, 320, 3), np.uint8)
        for i in range(n):
            out[i] = ((x + 3 * (offset + i)) % 256)[..., None].astype(np.uint8)
            out[i, ..., 1] = (y + offset + i) % 256
        return out

    fixture._frames = frames
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        root = fixture.write_droid_v3(
            Path(tmp) / "droid", cameras=("exterior_1_left",), lengths=(args.frames,) * args.episodes
        )
        build = time.perf_counter() - t0
        reader = LeRobotReader(intrinsics={"exterior_1_left": (260.0, 260.0, 160.0, 90.0)})
        refs = list(reader.list_episodes(str(root)))
        mid = refs[len(refs) // 2]
        data = mid.paths["data"]
        idx = mid.meta["episode_index"]
        cols = [
            "observation.state.joint_position",
            "observation.state.gripper_position",
            "camera_extrinsics.exterior_1_left",
        ]

        def rows_filtered():
            pq.read_table(data, columns=cols + ["episode_index"], filters=[("episode_index", "=", idx)])

        def rows_whole():
            t = pq.read_table(data)
            mask = np.asarray(t.column("episode_index").to_numpy()) == idx
            return [np.asarray(t.column(c).to_pylist(), dtype=object)[mask] for c in cols]

        key = "observation.images.exterior_1_left"
        vpath, start = mid.paths[f"video:{key}"], mid.meta["video_start"][key]

        def video_probe():
            probe_video(mid.episode_id, Path(vpath), args.frames, fixture.FPS, start=start)

        def video_decode():
            probe_video(mid.episode_id, Path(vpath), args.frames, fixture.FPS, start=start).read()

        results = {
            "list_episodes_s": timed(lambda: list(reader.list_episodes(str(root))), args.repeats),
            "rows_filtered_s": timed(rows_filtered, args.repeats),
            "rows_whole_file_s": timed(rows_whole, args.repeats),
            "video_demux_s": timed(video_probe, args.repeats),
            "video_decode_s": timed(video_decode, args.repeats),
            "load_episode_s": timed(lambda: reader.load_episode(mid), args.repeats),
        }
    n = args.episodes
    table = [
        (
            "list_episodes (whole dataset)",
            results["list_episodes_s"],
            f"{n / results['list_episodes_s']:.0f} episodes/s",
        ),
        ("state rows: row filter (reader)", results["rows_filtered_s"], ""),
        (
            "state rows: whole file + mask (naive)",
            results["rows_whole_file_s"],
            f"{results['rows_whole_file_s'] / results['rows_filtered_s']:.1f}x slower",
        ),
        ("video check: demux packets (reader)", results["video_demux_s"], ""),
        (
            "video check: decode frames (naive)",
            results["video_decode_s"],
            f"{results['video_decode_s'] / results['video_demux_s']:.1f}x slower",
        ),
        ("load_episode end to end", results["load_episode_s"], f"{1 / results['load_episode_s']:.1f} episodes/s"),
    ]
    print(
        f"LeRobot v3.0 DROID: {n} episodes x {args.frames} frames in one shared parquet + 320x180 MP4 "
        f"(built in {build:.1f} s); median of {args.repeats}"
    )
    print(f"{'step':42s} {'ms':>9s}  note")
    for name, sec, note in table:
        print(f"{name:42s} {sec * 1e3:9.2f}  {note}")
    out = {
        "episodes": n,
        "frames": args.frames,
        "repeats": args.repeats,
        "python": platform.python_version(),
        "machine": platform.machine(),
        **results,
    }
    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2))
    print(f"wrote {path}")
    return out


if __name__ == "__main__":
    main()
