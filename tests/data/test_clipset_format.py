"""A clip set of another format version is refused by name, before a stage adds to it or records anything.

Each test writes a set with today's code and rewrites its ``oscar_clips.json`` to format version 1 (what a set of
an older oscar carries: such a set may lack the ``fingerprint.json`` that its stage's re-runs are checked against).
"""

from __future__ import annotations

import json

import pytest

from oscar_core.cli import main
from oscar_core.plugin.registry import Registry
from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
from oscar_core.train.clips import CLIPSET_FILE, FORMAT_VERSION, ClipFormatError, ClipSet

BASE = GenerateConfig(("toyarm",), 2, width=32, height=32, frames=9, shard_size=2)
EXPECTED = (
    f"field 'format_version': expected {FORMAT_VERSION} (a set of another format is made again with the "
    "command that made it), found 1"
)


@pytest.fixture(scope="module")
def reg():
    return Registry()


def _make_old(out) -> None:
    """Turn the set at ``out`` into one of format version 1 without a fingerprint."""
    (out / CLIPSET_FILE).write_text(json.dumps({"format": "oscar-clips", "format_version": 1}))
    (out / "fingerprint.json").unlink()


@pytest.fixture
def old_set(tmp_path, reg):
    out = tmp_path / "set"
    assert generate_clipset(BASE, out, reg)["episodes_written"] == 2
    _make_old(out)
    return out


def test_the_format_version_is_2():
    assert FORMAT_VERSION == 2


def test_generate_into_an_old_set_is_refused_naming_the_version_found_and_expected(old_set, reg):
    with pytest.raises(ClipFormatError) as err:
        generate_clipset(BASE, old_set, reg)
    assert str(err.value) == f"{old_set / CLIPSET_FILE}: {EXPECTED}"
    assert not (old_set / "fingerprint.json").exists()  # nothing recorded for a refused run
    with pytest.raises(ClipFormatError, match="expected 2 .*found 1"):
        ClipSet(old_set)  # reading it is refused alike


def test_the_command_exits_2_naming_the_field(old_set, capsys):
    args = [
        "toyworld",
        "generate",
        "--embodiments",
        "toyarm",
        "--episodes",
        "2",
        "--size",
        "32x32",
        "--frames",
        "9",
        "--shard-size",
        "2",
        "--out",
        str(old_set),
        "--no-progress",
    ]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert EXPECTED in err and "Traceback" not in err


def test_train_cache_latents_exits_2_on_an_old_cache(tmp_path, reg, capsys):
    import oscar_zoo

    src = tmp_path / "src"
    generate_clipset(BASE, src, reg)
    vae = str(oscar_zoo.pull("oscar-toy", local_files_only=True))
    out = tmp_path / "lat"
    args = ["train", "--cache-latents", str(src), "--vae", vae, "--window", "5", "--out", str(out), "--no-progress"]
    assert main(args) == 0 and (out / "fingerprint.json").is_file()
    _make_old(out)
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err
    assert EXPECTED in err and "Traceback" not in err
    assert not (out / "fingerprint.json").exists()
