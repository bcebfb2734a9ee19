"""tests/_file_order.py: on pytest-xdist workers the test files that hold a slow test run first, each file's tests
together; a run in one process keeps the collection order."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from _paths import REPO

# file: its tests, "!" marking a slow one; d's module-level mark makes every test of it slow
FILES = {"a": ["a1", "a2"], "b": ["b1", "!b2"], "c": ["c1"], "d": ["d1"]}


def _ran(tmp_path: Path, *flags: str) -> list[str]:
    """The tests of FILES in the order they ran (each appends its name to ran.txt), pytest run with ``flags``."""
    for name, tests in FILES.items():
        text = "import pytest\n" + ("pytestmark = pytest.mark.slow\n" if name == "d" else "")
        for test in tests:
            mark = "@pytest.mark.slow\n" if test.startswith("!") else ""
            text += f"\n{mark}def test_{test.strip('!')}():\n    open('ran.txt', 'a').write('{test.strip('!')} ')\n"
        (tmp_path / f"test_{name}.py").write_text(text)
    (tmp_path / "pytest.ini").write_text("[pytest]\nmarkers =\n    slow: slow\n")
    (tmp_path / "ran.txt").unlink(missing_ok=True)
    env = {**os.environ, "PYTHONPATH": str(REPO / "tests")}
    cmd = [sys.executable, "-m", "pytest", "-p", "_file_order", "-p", "no:cacheprovider", "-q", *flags]
    run = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    return (tmp_path / "ran.txt").read_text().split()


def test_an_xdist_worker_runs_the_files_with_slow_tests_first_each_file_together(tmp_path):
    # one worker takes whole files in the order it sorted them (xdist's controller keeps it): it runs them so
    got = _ran(tmp_path, "-n", "1", "--dist", "loadfile", "--no-loadscope-reorder")
    assert got == ["b1", "b2", "d1", "a1", "a2", "c1"]


def test_one_process_keeps_the_collection_order(tmp_path):
    assert _ran(tmp_path) == ["a1", "a2", "b1", "b2", "c1", "d1"]
    assert _ran(tmp_path, "-n", "0", "--dist", "loadfile", "--no-loadscope-reorder") == [
        "a1",
        "a2",
        "b1",
        "b2",
        "c1",
        "d1",
    ]
