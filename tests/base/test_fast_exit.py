"""oscar_core._util.fast_exit: the `oscar` process ends without module teardown but keeps what shutdown must do."""

import json
import subprocess
import sys

import pytest

SNIPPET = r"""
import atexit, sys, threading, time
from pathlib import Path
out = Path(sys.argv[1])
atexit.register(lambda: (out / "atexit").write_text("ran"))
def late():
    time.sleep(0.3)
    (out / "thread").write_text("finished")
threading.Thread(target=late).start()               # non-daemon: shutdown waits for it
from concurrent.futures import ThreadPoolExecutor
pool = ThreadPoolExecutor(2)                         # left open: its idle workers are stopped, not waited for
pool.submit(time.sleep, 0.01).result()
sys.stdout.write("unflushed stdout")                # no newline, block-buffered into a pipe
sys.stderr.write("unflushed stderr")
from oscar_core._util.fast_exit import exit_process
exit_process(3)
print("never reached")
"""


@pytest.mark.parametrize("full", ["", "1"])
def test_exit_keeps_code_threads_atexit_and_output(tmp_path, full):
    env = {"PATH": "/usr/bin:/bin", "OSCAR_FULL_EXIT": full}
    proc = subprocess.run(
        [sys.executable, "-c", SNIPPET, str(tmp_path)], capture_output=True, text=True, env=env, check=False, timeout=60
    )
    assert proc.returncode == 3, proc.stderr
    assert proc.stdout == "unflushed stdout" and proc.stderr.startswith("unflushed stderr")
    assert (tmp_path / "thread").read_text() == "finished"
    assert (tmp_path / "atexit").read_text() == "ran"


def test_the_command_line_exits_with_the_commands_code(tmp_path):
    ok = subprocess.run(
        [sys.executable, "-m", "oscar_core.cli", "embodiments", "--json"], capture_output=True, check=False, text=True
    )
    assert ok.returncode == 0, ok.stderr
    assert "toyarm" in {e["name"] for e in json.loads(ok.stdout)["embodiments"]}  # the whole JSON came out
    bad = subprocess.run(
        [
            sys.executable,
            "-m",
            "oscar_core.cli",
            "render",
            "--embodiment",
            "toyarm",
            "--trajectory",
            str(tmp_path / "missing.npz"),
            "--camera",
            str(tmp_path / "c.json"),
            "--out",
            str(tmp_path / "v.mp4"),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert bad.returncode == 2 and "missing.npz" in bad.stderr
