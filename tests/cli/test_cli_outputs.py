"""Every sub-command that writes checks its outputs before any work: one line on stderr, exit 2, no traceback.

The sub-commands and their output options are found by walking the ``oscar`` parser (a new command with an
``--out`` is covered without editing this file). Tests run as root here, and root ignores permission bits,
so the unwritable target is a path under a regular file (``afile/out``: no process can create it) and, where
the machine has one, a folder of a read-only file system (``/proc``).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import pytest
from _paths import REPO

from oscar_core._util.outputs import check_writable, output_kind
from oscar_core.cli import build_parser, main
from oscar_core.errors import OutputPathError

# option names that say "this is written": each must be marked with output_option (so the check runs)
OUTPUT_NAMES = ("--out", "--plot", "--html")


def _leaves(parser, path=()):
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, parser
        return
    seen = set()
    for action in subs:
        for name, child in action.choices.items():
            if id(child) not in seen:
                seen.add(id(child))
                yield from _leaves(child, path + (name,))


def _looks_like_output(action) -> bool:
    return any(o in OUTPUT_NAMES or o.endswith("-out") for o in action.option_strings) or (
        not action.option_strings and action.dest in ("out", "dst")
    )


def _argv(path, parser, target_action, target: str) -> list[str]:
    """``oscar PATH ...`` with every required argument filled with a placeholder and ``target_action`` = target."""
    positionals, options = [], []
    for a in parser._actions:
        if a is target_action:
            if a.option_strings:
                options += [a.option_strings[0], target]
            else:
                positionals.append(target)
        elif not a.option_strings and not isinstance(a, argparse._SubParsersAction):
            if a.nargs not in ("?", "*"):
                positionals.append(a.choices[0] if a.choices else "placeholder")
        elif a.required:
            options += [a.option_strings[0], str(next(iter(a.choices))) if a.choices else "1"]
    return [*path, *positionals, *options]


CASES = [(path, parser, a) for path, parser in _leaves(build_parser()) for a in parser._actions if output_kind(a)]


def test_every_option_named_like_an_output_is_checked():
    unmarked = [
        f"oscar {' '.join(path)} {a.option_strings or a.dest}"
        for path, parser in _leaves(build_parser())
        for a in parser._actions
        if _looks_like_output(a) and not output_kind(a)
    ]
    assert unmarked == []
    assert len(CASES) >= 30  # every writer of the CLI (render, eval, data, train, toyworld, zoo, demo, ...)
    covered = {path for path, _, _ in CASES}
    for must in [
        ("eval", "run"),
        ("data", "ingest"),
        ("train",),
        ("render",),
        ("rollout",),
        ("demo",),
        ("eval", "benchmark", "build"),
        ("toyworld", "eval"),
        ("data", "filter"),
    ]:
        assert must in covered, must


@pytest.mark.parametrize(
    "path,parser,action", CASES, ids=[f"{' '.join(p)}:{(a.option_strings or [a.dest])[0]}" for p, _, a in CASES]
)
def test_an_unwritable_output_is_one_line_and_exit_2(path, parser, action, tmp_path, capsys):
    (tmp_path / "afile").write_text("a regular file, not a folder")
    target = str(tmp_path / "afile" / "out") + ("/" if output_kind(action) == "folder" else "")
    argv = _argv(path, parser, action, target)
    assert main(argv) == 2, argv
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert err.count("\n") == 1 and err.startswith("error: "), err
    assert "afile" in err and "cannot write output" in err, err


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="no /proc (a read-only file system) here")
@pytest.mark.parametrize(
    "argv",
    [
        ["eval", "run", "m.json", "--model", "oscar-toy", "--out", "/proc/oscar-ev"],
        ["data", "ingest", "src", "--reader", "npz", "--out", "/proc/oscar-run"],
        ["toyworld", "generate", "--embodiments", "toyarm", "--episodes", "1", "--out", "/proc/oscar-clips"],
    ],
)
def test_a_folder_that_refuses_writes_is_caught_even_for_root(argv, capsys):
    """/proc refuses new files to every user: the check creates a file for real, it does not read mode bits."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "folder /proc is not writable" in err and "Traceback" not in err


def test_train_checks_its_run_dir_from_set_or_the_config(tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    config = str(REPO / "configs" / "train" / "tiny-cpu.yaml")
    assert main(["train", config, "--set", f"run_dir={tmp_path / 'afile' / 'run'}"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "afile" in err and "cannot write output" in err
    assert main(["train", "--resume", str(tmp_path / "afile")]) == 2
    assert "expected a folder" in capsys.readouterr().err


def test_read_only_folder_by_mode_bits(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("this user (root) writes into a mode-0500 folder")
        with pytest.raises(OutputPathError, match="not writable"):
            check_writable(ro / "ev", "folder")
    finally:
        ro.chmod(0o700)


def test_check_writable_kinds(tmp_path):
    (tmp_path / "f.json").write_text("{}")
    assert check_writable(tmp_path / "new" / "deeper" / "x.json") == tmp_path / "new" / "deeper" / "x.json"
    assert check_writable(tmp_path / "f.json", "file") == tmp_path / "f.json"  # an existing file is replaced
    with pytest.raises(OutputPathError, match="it is a file, expected a folder"):
        check_writable(tmp_path / "f.json", "folder")
    with pytest.raises(OutputPathError, match="it is a folder, expected a file"):
        check_writable(tmp_path, "file")
    assert check_writable(tmp_path, "any") == tmp_path and check_writable(tmp_path / "f.json", "any")  # either
    assert check_writable("s3://bucket/run", "folder") is None  # URLs: the writer's own check
    assert not any(p.name.startswith(".oscar-write-check") for p in tmp_path.iterdir())  # the probe is removed
