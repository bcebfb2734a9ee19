"""Real datasets from the CLI: a reader's options on the command line (``--reader-option intrinsics=cam.json``) reach
every stage, and an unreadable LeRobot episode table is one rejected row naming the file while the rest goes on."""

import json

import pytest

pytest.importorskip("pyarrow")

from test_reader_lerobot import K, write_droid_v3

from oscar_core.cli import main
from oscar_core.data._episode import load_row
from oscar_core.data.engine import read_stage
from oscar_core.data.reader_options import ReaderOptionError, check_reader_options, parse_reader_options
from oscar_core.data.readers.droid import DroidRawReader
from oscar_core.data.readers.egodex import EgoDexReader
from oscar_core.data.readers.lerobot import LeRobotReader


def _ingest(capsys, *argv):
    rc = main(["data", "ingest", *map(str, argv), "--workers", "1", "--no-progress"])
    out, err = capsys.readouterr()
    return rc, out, err


def test_droid_from_the_hub_ingests_with_intrinsics_from_the_command_line(tmp_path, capsys):
    root = write_droid_v3(tmp_path / "droid")
    rc, out, err = _ingest(capsys, root, "--reader", "lerobot", "--out", tmp_path / "bare")
    assert rc == 0, err
    assert "0 of 2 episodes live" in out  # without intrinsics every DROID episode is rejected, with the reason
    rows = read_stage(str(tmp_path / "bare" / "ingest"))
    assert all("intrinsics of observation.images.exterior_1_left" in r["ingest_reason"] for r in rows)

    cams = tmp_path / "cams.json"
    cams.write_text(json.dumps({"exterior_1_left": list(K)}))
    rc, out, err = _ingest(
        capsys, root, "--reader", "lerobot", "--reader-option", f"intrinsics={cams}", "--out", tmp_path / "run"
    )
    assert rc == 0, err
    assert "2 of 2 episodes live" in out
    rows = read_stage(str(tmp_path / "run" / "ingest"))
    assert [json.loads(r["reader_options"]) for r in rows] == [{"intrinsics": {"exterior_1_left": list(K)}}] * 2
    ep, _ = load_row(rows[1])  # what filter / export workers do: the reader is rebuilt with the stored options
    fx, fy = ep.camera.intrinsics.fx, ep.camera.intrinsics.fy
    assert (fx, fy) == (K[0], K[1]) and ep.n_frames == 10


def test_a_yaml_value_works_as_well_as_a_file(tmp_path, capsys):
    root = write_droid_v3(tmp_path / "droid")
    rc, out, err = _ingest(
        capsys,
        root,
        "--reader",
        "lerobot",
        "--reader-option",
        "intrinsics={exterior_1_left: [" + ", ".join(f"{k:g}" for k in K) + "]}",
        "--out",
        tmp_path / "run",
    )
    assert rc == 0 and "2 of 2 episodes live" in out, err


@pytest.mark.parametrize(
    "option, message",
    [
        ("intrinsic=cams.json", "reader 'lerobot' has no such option; it takes: intrinsics"),
        ("intrinsics=5", "--reader-option intrinsics (reader 'lerobot'): expected a mapping"),
        ("intrinsics=missing.json", "expected a .json file, found no such file"),
        ("intrinsics", "expected NAME=VALUE"),
    ],
)
def test_a_bad_reader_option_is_refused_before_listing(tmp_path, capsys, monkeypatch, option, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cams.json").write_text("{}")
    listed = []
    monkeypatch.setattr(LeRobotReader, "list_episodes", lambda self, source: listed.append(source) or iter(()))
    rc, _, err = _ingest(capsys, tmp_path, "--reader", "lerobot", "--reader-option", option, "--out", tmp_path / "r")
    assert rc == 2 and message in err, err
    assert listed == [] and not (tmp_path / "r").exists()


def test_option_values_are_type_checked_against_the_constructor(tmp_path):
    assert check_reader_options(DroidRawReader, parse_reader_options(["image_size=[1280, 720]"])) == {
        "image_size": (1280, 720)
    }
    with pytest.raises(
        ReaderOptionError,
        match=r"--reader-option image_size \(reader 'droid_raw'\)\[1\]: expected an "
        r"integer, found str 'x'",
    ):
        check_reader_options(DroidRawReader, {"image_size": [1280, "x"]})
    with pytest.raises(ReaderOptionError, match="expected a list of 2 values"):
        check_reader_options(DroidRawReader, {"image_size": [1, 2, 3]})
    assert check_reader_options(EgoDexReader, parse_reader_options(["min_confidence=1"])) == {"min_confidence": 1.0}
    with pytest.raises(ReaderOptionError, match="expected a finite number, found str 'high'"):
        check_reader_options(EgoDexReader, parse_reader_options(["min_confidence=high"]))
    with pytest.raises(ReaderOptionError, match="given twice"):
        parse_reader_options(["a=1", "a=2"])
    y = tmp_path / "o.yaml"
    y.write_text("exterior_1_left: [1, 2, 3, 4]\n")
    assert parse_reader_options([f"intrinsics={y}"]) == {"intrinsics": {"exterior_1_left": [1, 2, 3, 4]}}
    bad = tmp_path / "bad.json"
    bad.write_text("{nope")
    with pytest.raises(ReaderOptionError, match=r"bad.json: expected JSON, found JSONDecodeError"):
        parse_reader_options([f"intrinsics={bad}"])


def test_an_unreadable_episode_table_names_itself_and_the_rest_goes_on(tmp_path, capsys):
    root = write_droid_v3(tmp_path / "droid")
    broken = root / "meta" / "episodes" / "chunk-000" / "file-001.parquet"
    broken.write_bytes(b"this is not a parquet file at all")
    refs = list(LeRobotReader(intrinsics={"exterior_1_left": K}).list_episodes(str(root)))
    assert [r.episode_id for r in refs] == ["droid/0", "droid/1", "droid/meta/episodes/chunk-000/file-001.parquet"]
    cams = tmp_path / "cams.json"
    cams.write_text(json.dumps({"exterior_1_left": list(K)}))
    rc, out, err = _ingest(
        capsys, root, "--reader", "lerobot", "--reader-option", f"intrinsics={cams}", "--out", tmp_path / "run"
    )
    assert rc == 0, err
    assert "2 of 3 episodes live" in out
    rows = {r["id"]: r for r in read_stage(str(tmp_path / "run" / "ingest"))}
    bad = rows["droid/meta/episodes/chunk-000/file-001.parquet"]
    assert bad["ingest_status"] == "rejected"
    assert (
        str(broken) in bad["ingest_reason"]
        and "a readable LeRobot episode table (meta/episodes)" in bad["ingest_reason"]
    )
    assert "magic bytes" in bad["ingest_reason"].lower() or "parquet" in bad["ingest_reason"].lower()
    assert rows["droid/0"]["ingest_status"] == rows["droid/1"]["ingest_status"] == "ok"


def test_a_broken_line_of_a_v21_episode_list_is_one_rejected_row(tmp_path):
    from test_reader_interndata_a1 import write_task

    from oscar_core.data.readers.interndata_a1 import InternDataA1Reader
    from oscar_core.plugin.reader import EpisodeError

    write_task(tmp_path, lengths=(9, 11, 10))
    ds = tmp_path / "articulation_tasks" / "franka" / "close_the_electriccooker"
    jl = ds / "meta" / "episodes.jsonl"
    lines = jl.read_text().splitlines()
    lines[1] = '{"episode_index": 1, "tasks": ["x"], "len'  # a truncated line
    jl.write_text("\n".join(lines) + "\n")
    reader = InternDataA1Reader()
    refs = list(reader.list_episodes(str(tmp_path)))
    base = "interndata_a1/articulation_tasks/franka/close_the_electriccooker"
    assert [r.episode_id for r in refs] == [f"{base}/0", f"{base}/meta/episodes.jsonl:2", f"{base}/2"]
    with pytest.raises(
        EpisodeError,
        match=r"episodes.jsonl: field '<file>': expected a readable LeRobot episode "
        r"table \(meta/episodes\); .* found line 2: expected \{episode_index",
    ):
        reader.load_episode(refs[1])
    assert reader.load_episode(refs[2]).n_frames == 10


def test_a_plugin_reader_taking_any_keyword_gets_its_options_unchecked_by_name():
    from oscar_core.plugin.reader import Reader

    class Open(Reader):
        name = "open"

        def __init__(self, root: str = ".", **extra):
            self.root, self.extra = root, extra

    assert check_reader_options(Open, {"root": "/d", "anything": [1, 2]}) == {"root": "/d", "anything": [1, 2]}
    with pytest.raises(
        ReaderOptionError, match="--reader-option root \\(reader 'open'\\): expected a string, found int 3"
    ):
        check_reader_options(Open, {"root": 3})
