"""openpi's websocket protocol on loopback: a real server process, the real client, the same cell results."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("websockets")
pytest.importorskip("msgpack")

from oscar_core.evaluation.closed_loop import run_closed_loop
from oscar_core.media.video import read_video
from oscar_core.policy.loading import PolicyLoadError
from oscar_core.policy.remote import pack, unpack
from oscar_core.toyworld.closed_loop import toy_simulator, write_closed_loop_sessions

FAILING = """
import numpy as np

class FailsOnSecondCall:
    def __init__(self):
        self.n = 0
    def infer(self, obs):
        self.n += 1
        if self.n > 1:
            raise ValueError("weights not found")
        return {"actions": np.zeros((8, 5))}

class DiesOnSecondCall(FailsOnSecondCall):
    def infer(self, obs):
        if self.n >= 1:
            import os
            os._exit(1)  # the server process dies mid-episode
        return super().infer(obs)
"""


@contextlib.contextmanager
def _serve(target: str):
    """A real server process for ``target`` on a free loopback port; yields its ws:// address."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "oscar_core.policy.serve", target, "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    line = proc.stdout.readline()
    if not line.startswith("listening on "):
        proc.kill()
        raise AssertionError(f"server did not start: {line!r} {proc.stderr.read()}")
    try:
        yield line.split()[-1]
    finally:
        proc.kill()
        proc.wait()


def test_openpi_array_encoding_round_trips():
    obs = {
        "observation/exterior_image_1_left": np.arange(12, dtype=np.uint8).reshape(2, 2, 3),
        "observation/joint_position": np.linspace(0, 1, 7),
        "prompt": "pick",
        "n": np.float32(2.5),
    }
    back = unpack(pack(obs))
    assert back["prompt"] == "pick" and back["n"] == np.float32(2.5) and back["n"].dtype == np.float32
    np.testing.assert_array_equal(back["observation/exterior_image_1_left"], obs["observation/exterior_image_1_left"])
    assert back["observation/joint_position"].dtype == np.float64
    raw = __import__("msgpack").unpackb(pack({"a": np.zeros(2, np.float32)}))  # openpi's layout on the wire
    assert set(raw["a"]) == {b"__ndarray__", b"data", b"dtype", b"shape"} and raw["a"][b"dtype"] == "<f4"


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("remote")
    return write_closed_loop_sessions(root / "s", ["toyarm"], 2, seed=5, horizon=33, policies=["exact"])


def test_served_policy_gives_the_same_cells_as_in_process(sessions, tmp_path):
    local = run_closed_loop(sessions, tmp_path / "local", simulator=toy_simulator, fps=10.0, chunk_frames=17)
    with _serve("oscar_core.toyworld.image_policies:ExactPolicy") as uri:
        remote = run_closed_loop(
            sessions,
            tmp_path / "remote",
            simulator=toy_simulator,
            fps=10.0,
            chunk_frames=17,
            policy_sources={"exact": uri},
        )
    assert remote.counts["failed"] == 0 and local.counts["failed"] == 0
    for a, b in zip(local.records, remote.records):
        assert a["outcome"] == b["outcome"]
        np.testing.assert_array_equal(
            read_video(tmp_path / "local" / a["video"]), read_video(tmp_path / "remote" / b["video"])
        )
        ca = json.loads((tmp_path / "local" / a["dir"] / "calls.json").read_text())["calls"]
        cb = json.loads((tmp_path / "remote" / b["dir"] / "calls.json").read_text())["calls"]
        assert [c["actions"] for c in ca] == [c["actions"] for c in cb]
        assert [c["image_sha256"] for c in ca] == [c["image_sha256"] for c in cb]


def test_server_error_refusal_and_death_fail_the_cell(sessions, tmp_path, refused_port):
    (tmp_path / "failing.py").write_text(FAILING)
    data = json.loads(sessions.read_text())
    data["policies"][0]["action_space"] = "joint_position"
    m = sessions.parent / "joint.json"
    m.write_text(json.dumps(data))
    with _serve(f"{tmp_path / 'failing.py'}:FailsOnSecondCall") as uri:
        res = run_closed_loop(
            m, tmp_path / "err", simulator=toy_simulator, fps=10.0, chunk_frames=17, policy_sources={"exact": uri}
        )
    assert [r["reason"] for r in res.records] == [
        "infer raised RuntimeError: policy server error: ValueError: weights not found"
    ] * 2
    with _serve(f"{tmp_path / 'failing.py'}:DiesOnSecondCall") as uri:
        res = run_closed_loop(
            m, tmp_path / "died", simulator=toy_simulator, fps=10.0, chunk_frames=17, policy_sources={"exact": uri}
        )
    first, second = (r["reason"] for r in res.records)
    assert first.startswith("infer raised ConnectionClosed"), first  # the connection dropped mid-episode
    assert second.startswith("cannot load ws://"), second  # nobody listens any more
    port = refused_port  # nobody listens from the start: the run stops before any cell, one line naming the policy
    with pytest.raises(PolicyLoadError, match=rf"^policy 'exact' cannot be loaded: ws://127.0.0.1:{port}: ") as err:
        run_closed_loop(
            m,
            tmp_path / "refused",
            simulator=toy_simulator,
            fps=10.0,
            chunk_frames=17,
            policy_sources={"exact": f"ws://127.0.0.1:{port}"},
        )
    assert len(err.value.lines) == 1 and not (tmp_path / "refused" / "cells").exists()


@pytest.mark.parametrize(
    "target, found",
    [
        ("oscar_core.toyworld.image_polices:ExactPolicy", "No module named 'oscar_core.toyworld.image_polices'"),
        ("oscar_core.toyworld.image_policies:Exact", "has no attribute 'Exact'"),
        ("no_such_file.py:Policy", "no such file"),
    ],
)
def test_serve_a_typo_is_one_line_and_exit_2(target, found):
    proc = subprocess.run(
        [sys.executable, "-m", "oscar_core.policy.serve", target, "--port", "0"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith(f"error: {target}: field 'policy'"), proc.stderr
    assert found in proc.stderr
