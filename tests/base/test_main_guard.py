"""A worker pool started from a script's unguarded top level fails at once with a clear error.

The scripts run in a subprocess with a timeout: before the check, the same
unguarded script ran its top level once per worker and returned every episode
as failed with ``BrokenProcessPool``.
"""

from __future__ import annotations

import os
import runpy
import subprocess
import sys
import textwrap

import pytest
from _paths import TOYARM_ASSETS

from oscar_core._util.main_guard import MainGuardError, check_main_guard, guarded

RENDER = """
from pathlib import Path
import sys
from oscar_core import load_trajectory, save_trajectory
from oscar_core.render.batch import EpisodeSpec, RenderOptions, render_many

A = Path({assets!r})
out = Path(sys.argv[1])
print("top level", flush=True)
specs = []
for k in range(3):
    p = out / f"t{{k}}.npz"
    if not p.exists():
        save_trajectory(load_trajectory(A / "example_trajectory.npz").time_slice(0, 6), p)
    specs.append(EpisodeSpec("toyarm", str(p), str(A / "example_camera.json"), str(out / f"t{{k}}.mp4"), size=(64, 36)))


def main():
    res = render_many(specs, RenderOptions(), workers=2)
    print("ok", sum(r.ok for r in res), flush=True)


{call}
"""


def _script(tmp_path, text: str) -> subprocess.CompletedProcess:
    path = tmp_path / "user_script.py"
    path.write_text(textwrap.dedent(text))
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run(
        [sys.executable, str(path), str(tmp_path)],
        check=False,
        capture_output=True,
        text=True,
        env=env,
        timeout=240,
        cwd=tmp_path,
    )


def test_render_many_from_an_unguarded_script_fails_fast_naming_the_line(tmp_path):
    proc = _script(tmp_path, RENDER.format(assets=str(TOYARM_ASSETS), call="main()"))
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "MainGuardError: render_many(workers=2)" in proc.stderr
    assert f"{tmp_path / 'user_script.py'}, line" in proc.stderr and 'if __name__ == "__main__":' in proc.stderr
    assert proc.stdout.count("top level") == 1  # no worker ran the script again
    assert not list(tmp_path.glob("*.mp4")) and "BrokenProcessPool" not in proc.stderr


def test_the_same_script_with_the_guard_renders(tmp_path):
    proc = _script(tmp_path, RENDER.format(assets=str(TOYARM_ASSETS), call='if __name__ == "__main__":\n    main()'))
    assert proc.returncode == 0, proc.stderr
    assert "ok 3" in proc.stdout and len(list(tmp_path.glob("*.mp4"))) == 3


def test_run_sharded_from_an_unguarded_script_fails_fast(tmp_path):
    text = """
    import sys
    from oscar_core.data.engine import run_sharded

    def stage(rows, shard):
        return [dict(r, n=len(r["id"])) for r in rows]

    rows = [{"id": f"e{i}"} for i in range(4)]
    run = run_sharded(stage, rows, sys.argv[1] + "/stage", shard_size=1, workers=2, progress=False)
    print("processed", len(run.processed))
    """
    proc = _script(tmp_path, text)
    assert proc.returncode == 1 and "MainGuardError: run_sharded(workers=2)" in proc.stderr, proc.stderr
    assert not (tmp_path / "stage" / "completions").exists() or not list((tmp_path / "stage" / "completions").iterdir())
    body = text.split("rows = ")[1]
    guarded_text = (
        text.split("rows = ")[0] + 'if __name__ == "__main__":\n        rows = ' + body.replace("\n    ", "\n        ")
    )
    proc = _script(tmp_path, guarded_text)
    assert proc.returncode == 0 and "processed 4" in proc.stdout, proc.stderr


def test_a_script_read_from_standard_input_is_refused_before_the_workers_die(tmp_path):
    """Workers look for a file named ``<stdin>``: even a guarded script cannot start a pool from there."""
    text = RENDER.format(assets=str(TOYARM_ASSETS), call='if __name__ == "__main__":\n    main()')
    proc = subprocess.run(
        [sys.executable, "-", str(tmp_path)],
        input=text,
        check=False,
        capture_output=True,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        timeout=240,
        cwd=tmp_path,
    )
    assert proc.returncode == 1 and "MainGuardError" in proc.stderr and "standard input" in proc.stderr, proc.stderr
    assert "BrokenProcessPool" not in proc.stderr and not list(tmp_path.glob("*.mp4"))


def test_a_worker_running_the_script_again_refuses_too(tmp_path):
    """The worker side: the script's top level executing as ``__mp_main__`` (how workers import it)."""
    path = tmp_path / "again.py"
    path.write_text("from oscar_core._util.main_guard import check_main_guard\n\ncheck_main_guard('pool(workers=2)')\n")
    with pytest.raises(MainGuardError, match=r"again\.py, line 3"):
        runpy.run_path(str(path), run_name="__mp_main__")
    runpy.run_path(str(path), run_name="not_a_worker")  # another module's top level: nothing to say


def test_no_script_nothing_to_check():
    check_main_guard("pool(workers=2)")  # under pytest: the runner's main module is guarded or a package


@pytest.mark.parametrize(
    ("source", "line", "expected"),
    [
        ("x = 1\ncall()\n", 2, False),
        ('if __name__ == "__main__":\n    call()\n', 2, True),
        ("if '__main__' == __name__:\n    call()\n", 2, True),
        ('if __name__ == "__main__" and ok:\n    call()\n', 2, True),
        ('if __name__ != "__main__":\n    pass\nelse:\n    call()\n', 4, True),
        ('if __name__ != "__main__":\n    call()\n', 2, False),
        ('if __name__ == "__main__":\n    pass\nelse:\n    call()\n', 4, False),
        ('if __name__ == "__main__":\n    with ctx:\n        for i in x:\n            call()\n', 4, True),
        (
            'with ctx:\n    if __name__ == "__main__":\n        try:\n            call()\n        finally:\n            pass\n',
            4,
            True,
        ),
        ("with ctx:\n    call(\n        1,\n    )\n", 3, False),
        ("if ready:\n    call()\n", 2, False),
        ("def f(\n", 1, None),
    ],
)
def test_guard_detection_from_source(source, line, expected):
    assert guarded(source, line) is expected
