"""A file argument that is not what it should be: the error names the file, the format expected and what was
found (a zip archive, an image, binary data, a folder), never a codec error; one line and exit 2 on the CLI."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
from _paths import REPO

from oscar_core._util.inputs import describe_content, read_text_file
from oscar_core.cli import main
from oscar_core.errors import InputFileError

FRANKA = REPO / "embodiments" / "franka" / "assets"
PNG = b"\x89PNG\r\n\x1a\n" + bytes(range(200, 256))


@pytest.fixture
def files(tmp_path):
    npz = tmp_path / "traj.npz"
    np.savez(npz, q=np.zeros((2, 1)))
    (tmp_path / "latin1.json").write_bytes('{"name": "caf\xe9"}'.encode("latin-1"))
    (tmp_path / "img.png").write_bytes(PNG)
    (tmp_path / "empty.json").write_bytes(b"")
    (tmp_path / "late.json").write_bytes(b"{" + b" " * 100 + b"\xff}")
    (tmp_path / "folder").mkdir()
    return tmp_path


def test_describe_content_names_what_a_file_holds(files):
    assert zipfile.is_zipfile(files / "traj.npz")
    assert describe_content(files / "traj.npz") == "a zip archive (an .npz or .zip file?)"
    assert describe_content(files / "img.png") == "a PNG image"
    assert describe_content(files / "latin1.json") == "binary data (byte 0xe9 at position 13 is not utf-8 text)"
    assert describe_content(files / "empty.json") == "an empty file"
    assert describe_content(files / "folder") == "a folder"
    assert describe_content(files / "missing") == "no such file"
    assert describe_content(FRANKA / "example_camera.json") == "JSON text"


def test_read_text_file_errors_name_file_format_and_finding(files):
    for name, found in [
        ("traj.npz", "a zip archive"),
        ("img.png", "a PNG image"),
        ("folder", "a folder"),
        ("missing", "no such file"),
        ("late.json", "byte 0xff at position 101 is not utf-8"),
    ]:
        with pytest.raises(InputFileError) as e:
            read_text_file(files / name, "camera calibration JSON")
        msg = str(e.value)
        assert msg.startswith(str(files / name)) and "expected camera calibration JSON" in msg and found in msg, msg
        assert "codec" not in msg


def _one_line(capsys, argv):
    assert main(argv) == 2, argv
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err and "codec" not in err, err
    return err


@pytest.mark.parametrize(
    "argv_of, needle",
    [
        # --camera traj.npz (render and rollout): the utf-8 codec error
        (
            lambda f: [
                "render",
                "--embodiment",
                "franka",
                "--trajectory",
                str(FRANKA / "example_trajectory.npz"),
                "--camera",
                str(f / "traj.npz"),
                "--out",
                str(f / "o.mp4"),
            ],
            "traj.npz: field '<file>': expected camera calibration JSON (utf-8 text; docs/formats.md), found a zip archive",
        ),
        (
            lambda f: [
                "render",
                "--embodiment",
                "franka",
                "--trajectory",
                str(FRANKA / "example_trajectory.npz"),
                "--camera",
                str(f / "latin1.json"),
                "--out",
                str(f / "o.mp4"),
            ],
            "latin1.json: field '<file>': expected camera calibration JSON (utf-8 text; docs/formats.md), found binary data",
        ),
        # a trajectory that is a camera file, or an image
        (
            lambda f: [
                "render",
                "--embodiment",
                "franka",
                "--trajectory",
                str(FRANKA / "example_camera.json"),
                "--camera",
                str(FRANKA / "example_camera.json"),
                "--out",
                str(f / "o.mp4"),
            ],
            "example_camera.json: field '<file>': expected a NumPy .npz archive (np.savez), found JSON text",
        ),
        (
            lambda f: [
                "render",
                "--embodiment",
                "franka",
                "--trajectory",
                str(f / "img.png"),
                "--camera",
                str(FRANKA / "example_camera.json"),
                "--out",
                str(f / "o.mp4"),
            ],
            "img.png: field '<file>': expected a NumPy .npz archive (np.savez), found a PNG image",
        ),
        # a render manifest, an evaluation manifest and a training config that are binary
        (
            lambda f: ["render", "--manifest", str(f / "traj.npz")],
            "traj.npz: field '<file>': expected a render manifest (.jsonl or .csv, utf-8 text; docs/formats.md), found a zip",
        ),
        (
            lambda f: ["eval", "run", str(f / "img.png"), "--model", "oscar-toy", "--out", str(f / "ev")],
            "img.png: field 'file': expected an evaluation manifest JSON file (utf-8 text; docs/evaluation.md), found a PNG",
        ),
        (
            lambda f: ["train", str(f / "traj.npz")],
            "traj.npz: field '<file>': expected a training config (YAML, utf-8 text), found a zip archive",
        ),
        (
            lambda f: [
                "eval",
                "benchmark",
                "run",
                str(f / "latin1.json"),
                "--model",
                "oscar-toy",
                "--out",
                str(f / "b"),
            ],
            "latin1.json: field '<file>': expected a benchmark set file (JSON written by oscar eval benchmark build), "
            "found binary data",
        ),
        (
            lambda f: ["eval", "policies", "--real", str(f / "traj.npz"), "--wm", str(f / "traj.npz")],
            "traj.npz: field 'file': expected a JSON file (utf-8 text), found a zip archive",
        ),
    ],
)
def test_cli_file_arguments(files, capsys, argv_of, needle):
    assert needle in _one_line(capsys, argv_of(files))


def test_first_frame_that_is_not_an_image_says_what_it_is(files):
    from oscar_core.model.image import read_image

    with pytest.raises(
        InputFileError,
        match=r"traj.npz: field 'image': expected a readable image \(PNG, JPEG\) or "
        r"video .*, found a zip archive",
    ):
        read_image(files / "traj.npz")
    with pytest.raises(InputFileError, match=r"folder: field 'image': expected a file: an image .*found a folder"):
        read_image(files / "folder")
    (files / "cam.json").write_text(json.dumps({"not": "an image"}))
    with pytest.raises(InputFileError, match="found JSON text"):
        read_image(files / "cam.json")
