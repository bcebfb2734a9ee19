"""docs/closed-loop.md opens with a minimal policy class that must run as written: taken from the page, run in the
toy simulator in-process through `oscar eval closed-loop --policy`, then served over openpi's websocket protocol
by `python -m oscar_core.policy.serve`, with the same cells both ways."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from oscar_core.cli import main
from oscar_core.media.video import read_video
from oscar_core.toyworld.closed_loop import write_closed_loop_sessions

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py

DOC = Path(__file__).resolve().parents[2] / "docs" / "closed-loop.md"


def _policy_source() -> str:
    """The first python block after the page's "A policy of your own" heading."""
    text = DOC.read_text()
    section = text[text.index("## A policy of your own") :]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def _cells(out: Path) -> dict:
    report = json.loads((out / "report.json").read_text())
    return {(c["session"], c["policy"]): c for c in report["cells"]}


def test_the_pages_policy_runs_as_written_in_process_and_served(tmp_path, capsys):
    pytest.importorskip("websockets")
    (tmp_path / "my_policy.py").write_text(_policy_source())
    manifest = write_closed_loop_sessions(
        tmp_path / "toy_cl", ["toyarm"], 1, seed=0, horizon=33, policies=["never_closes"]
    )
    base = ["eval", "closed-loop", str(manifest), "--simulator", "toy", "--no-progress"]
    local = tmp_path / "cl_mine"
    assert main([*base, "--policy", f"mine={tmp_path / 'my_policy.py'}:SwayPolicy", "--out", str(local)]) == 0
    proc = subprocess.Popen(
        [sys.executable, "-m", "oscar_core.policy.serve", f"{tmp_path / 'my_policy.py'}:SwayPolicy", "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline()
        assert line.startswith("listening on "), (line, proc.stderr.read())
        served = tmp_path / "cl_mine_ws"
        assert main([*base, "--policy", f"mine={line.split()[-1]}", "--out", str(served)]) == 0
    finally:
        proc.kill()
        proc.wait()
    capsys.readouterr()
    a, b = _cells(local), _cells(served)
    key = ("toyarm-0000", "mine")
    assert a[key]["status"] == b[key]["status"] == "ok"
    ca = json.loads((local / a[key]["dir"] / "calls.json").read_text())["calls"]
    cb = json.loads((served / b[key]["dir"] / "calls.json").read_text())["calls"]
    assert len(ca) == len(cb) >= 2 and [c["actions"] for c in ca] == [c["actions"] for c in cb]
    # the policy did what its comments say: the first joint sways, the gripper closes a little more each call
    executed = np.array([row for c in ca for row in c["actions"][: c["executed"]]], dtype=float)
    assert np.ptp(executed[:, 0]) > 0 and np.all(np.diff(executed[:, -1]) >= 0) and executed[-1, -1] > 0
    np.testing.assert_array_equal(read_video(local / a[key]["video"]), read_video(served / b[key]["video"]))
