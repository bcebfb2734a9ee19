"""Ingest and filter on constructed episodes: each filter rejects its own case with the measured value; bad input is
rejected with its reason and the run goes on."""

import json
from pathlib import Path

import numpy as np
import pytest
from _datasets import SIZE, base_parts, write_episode

from oscar_core.data.engine import read_stage
from oscar_core.data.filters import FilterConfig, decide, measure_action, measure_spikes, measure_visible
from oscar_core.data.run import run_filter, run_ingest
from oscar_core.data.stats import compute_stats, format_table


def build_source(root: Path) -> Path:
    traj, cam = base_parts()
    src = root / "src"
    write_episode(src, "good", seed=1)
    write_episode(src, "pan", seed=2, pan=1.0)
    still = traj.replace(q=np.repeat(traj.q[:1], len(traj), 0), gripper=np.repeat(traj.gripper[:1], len(traj), 0))
    write_episode(src, "still", still, seed=3)
    write_episode(src, "short", traj.time_slice(0, 50), seed=4)
    spike_q = traj.q.copy()
    spike_q[40, 1] += 1.2  # one frame 1.2 rad off: 18 rad/s at 15 fps
    write_episode(src, "spike", traj.replace(q=spike_q), seed=5)
    # the camera looks away: principal point moved so the arm sits off the right edge of the image
    off = cam.resized(*SIZE)
    off_cam = type(off)(
        intrinsics=type(off.intrinsics)(
            fx=off.intrinsics.fx,
            fy=off.intrinsics.fy,
            cx=off.intrinsics.cx + 1.5 * SIZE[0],
            cy=off.intrinsics.cy,
            width=SIZE[0],
            height=SIZE[1],
        ),
        extrinsic=off.extrinsic,
        convention=off.convention,
        direction=off.direction,
        embodiment=off.embodiment,
    )
    write_episode(src, "offframe", traj, off_cam, seed=6)
    # bad input
    bad = write_episode(src, "truncated", seed=7, video="rgb.mp4")
    data = (bad / "rgb.mp4").read_bytes()
    (bad / "rgb.mp4").write_bytes(data[: len(data) // 3])
    nan = write_episode(src, "nan", seed=8)
    with np.load(nan / "trajectory.npz") as z:
        arrays = {k: z[k] for k in z.files}
    arrays["q"][10, 2] = np.nan
    np.savez(nan / "trajectory.npz", **arrays)
    nocam = write_episode(src, "nocamera", seed=9)
    (nocam / "camera.json").unlink()
    mism = write_episode(src, "mismatch", seed=10)
    arrays["q"][10, 2] = 0.0
    arrays["gripper"] = arrays["gripper"][:-5]  # state and gripper action of different lengths
    np.savez(mism / "trajectory.npz", **arrays)
    return src


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("filters")
    src = build_source(root)
    out = str(root / "run")
    run_ingest(str(src), "npz", out, workers=1, shard_size=4, progress=False)
    run_filter(out, workers=1, shard_size=4, progress=False)
    rows = {r["id"].split("/")[1]: r for r in read_stage(str(Path(out) / "filter"))}
    return out, rows


def test_good_episode_passes_with_its_measurements(run):
    _, rows = run
    r = rows["good"]
    assert r["ingest_status"] == "ok" and r["filter_status"] == "ok", r
    assert r["length"] == 81 and r["fps"] == 15.0 and (r["width"], r["height"]) == SIZE
    assert r["filter_camera_motion"] < 0.002
    assert r["filter_visible"] == 1.0 and r["filter_action"] > 0.3


def test_moving_camera_is_rejected_and_measured_in_diagonals_per_second(run):
    r = run[1]["pan"]
    assert r["filter_status"] == "rejected" and r["filter_reason"].startswith("camera_motion: ")
    # the background moves 1 px/frame at 15 fps; the flow runs at the video's own 128 px width
    expected = 1.0 * 15 / np.hypot(*SIZE)
    assert r["filter_value"] == pytest.approx(expected, rel=0.1)


@pytest.mark.parametrize(
    "name, reason", [("still", "action"), ("short", "length"), ("spike", "spike_joint"), ("offframe", "visible")]
)
def test_each_filter_rejects_its_case(run, name, reason):
    r = run[1][name]
    assert r["filter_status"] == "rejected" and r["filter_reason"].split(":")[0] == reason, r["filter_reason"]
    assert r["filter_value"] == r[f"filter_{reason}"]


def test_spike_value_is_the_injected_jump(run):
    # q[40, 1] += 1.2 rad: the step into and out of frame 40 reads about 1.2 rad x 15 fps
    assert run[1]["spike"]["filter_spike_joint"] == pytest.approx(18.0, abs=1.5)


@pytest.mark.parametrize(
    "name, field", [("truncated", "rgb.mp4"), ("nan", "finite values"), ("nocamera", "camera"), ("mismatch", "gripper")]
)
def test_bad_input_is_rejected_with_its_reason_and_the_run_goes_on(run, name, field):
    r = run[1][name]
    assert r["ingest_status"] == "rejected" and r["ingest_reason"].startswith("unreadable: ")
    assert field in r["ingest_reason"]
    assert r["filter_status"] is None  # not measured: carried through unchanged


def test_stats_count_every_rejection_once(run):
    out, rows = run
    st = compute_stats(out)
    total = st["total"]
    assert total["public"] == len(rows) == 10 and total["kept"] == 1
    assert total["rejected"] == {
        "ingest:unreadable": 4,
        "filter:camera_motion": 1,
        "filter:action": 1,
        "filter:length": 1,
        "filter:spike_joint": 1,
        "filter:visible": 1,
    }
    table = format_table(st)
    assert "ingest:unreadable" in table and table.splitlines()[-2].split()[-1] == "1"


def test_thresholds_are_config_values(run, tmp_path):
    cfg = FilterConfig.from_overrides(["min_length=40", "max_camera_motion=1"])
    assert cfg.min_length == 40 and cfg.max_camera_motion == 1.0 and cfg.min_action == FilterConfig().min_action
    with pytest.raises(ValueError, match="min_lenght"):
        FilterConfig.from_overrides(["min_lenght=3"])
    r = run[1]["short"]
    m = {k: r[f"filter_{k}"] for k in ("length", "camera_motion", "action", "visible", "spike_joint", "spike_point")}
    assert decide(m, FilterConfig()) is not None and decide(m, cfg) is None
    assert json.loads((Path(run[0]) / "filter" / "config.json").read_text())["min_length"] == 70


def test_measures_on_closed_forms():
    T = 20
    pts = np.zeros((T, 2, 3))
    pts[:, 1, 0] = np.linspace(0, 0.5, T)  # point 1 travels 0.5 m along x
    assert measure_action(pts) == pytest.approx(0.5)
    pts[5, 0] = np.nan  # a missing keypoint is ignored
    assert measure_action(pts) == pytest.approx(0.5)
    uv = np.array([[[5.0, 5.0], [-1.0, 5.0], [5.0, 10.0], [9.99, 0.0]]])
    assert measure_visible(uv, np.array([[True, True, True, False]]), 10, 10) == 0.25
    q = np.zeros((5, 2))
    q[3, 1] = 0.2
    js, ps = measure_spikes(q, np.zeros((5, 1, 3)), fps=10)
    assert js == pytest.approx(2.0) and ps == 0.0


def test_h5_missing_field_is_rejected_through_a_plugin_reader(tmp_path):
    h5py = pytest.importorskip("h5py")
    plugin = tmp_path / "h5reader.py"
    plugin.write_text('''
from oscar_core.plugin.hookspecs import hookimpl
from oscar_core.plugin.reader import EpisodeError
from oscar_core.data.readers.npz import NpzReader


class H5Reader(NpzReader):
    """npz layout plus a states.h5 that must hold observation/q (as a DROID-like reader checks its fields)."""
    name = "h5toy"

    def load_episode(self, ref, registry=None):
        import h5py
        path = ref.paths["episode"].replace("episode.json", "states.h5")
        with h5py.File(path, "r") as f:
            if "observation/q" not in f:
                raise EpisodeError(ref.episode_id, path, "observation/q", "a (T, J) dataset", "missing")
        return super().load_episode(ref, registry)


@hookimpl
def oscar_register_readers():
    return [H5Reader]
''')
    for name, field in (("ok", "observation/q"), ("broken", "observation/qq")):
        folder = write_episode(tmp_path / "src", name, seed=0)
        with h5py.File(folder / "states.h5", "w") as f:
            f.create_dataset(field, data=np.zeros((3, 4)))
    out = str(tmp_path / "run")
    run_ingest(str(tmp_path / "src"), "h5toy", out, workers=1, progress=False, plugin_paths=(str(plugin),))
    rows = {r["id"]: r for r in read_stage(str(tmp_path / "run" / "ingest"))}
    assert rows["src/ok"]["ingest_status"] == "ok"
    reason = rows["src/broken"]["ingest_reason"]
    assert reason.startswith("unreadable: EpisodeError") and "states.h5: field 'observation/q'" in reason
    assert "expected a (T, J) dataset, found missing" in reason


def test_unknown_embodiment_is_a_rejection_not_a_crash(tmp_path):
    folder = write_episode(tmp_path / "src", "ok", seed=0)
    other = write_episode(tmp_path / "src", "alien", seed=0)
    (other / "episode.json").write_text(json.dumps({"embodiment": "nobody"}))
    run_ingest(str(tmp_path / "src"), "npz", str(tmp_path / "run"), workers=1, progress=False)
    rows = {r["id"]: r for r in read_stage(str(tmp_path / "run" / "ingest"))}
    assert rows["src/ok"]["ingest_status"] == "ok" and folder.is_dir()
    assert rows["src/alien"]["ingest_status"] == "rejected" and "nobody" in rows["src/alien"]["ingest_reason"]
