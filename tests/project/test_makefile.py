"""The two set-up commands install into the project's virtual environment, never into the python3 that runs make.

``make -n`` prints what a target would run without running it: from a checkout with no environment yet, ``make
demo`` and ``make test`` create ``VENV`` first, and every pip install and every python command afterwards is
``VENV``'s own; CI (.ci/run) calls the same targets.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
import tomllib
from _paths import REPO

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")


def dry_run(target: str, venv: Path, *settings: str) -> list[str]:
    # a clean environment: under `make test` this make is a sub-make, which would print its directory and inherit flags
    env = {k: v for k, v in os.environ.items() if k not in ("MAKELEVEL", "MAKEFLAGS", "MFLAGS")}
    proc = subprocess.run(
        ["make", "--no-print-directory", "-n", target, f"VENV={venv}", *settings],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    return [line for line in proc.stdout.splitlines() if line.strip() and not line.startswith("#")]


def outside_the_venv(lines: list[str], venv: Path) -> list[str]:
    """Commands that install or run Python with anything but ``venv``'s interpreter (creating the venv aside)."""
    py = f"{venv}/bin/python"
    bad = []
    for line in lines:
        first = line.split()[0]
        if "pip" in line and not line.startswith(py):
            bad.append(line)
        elif (
            first.startswith(("python", "/usr/bin/python"))
            and " -m venv " not in line
            and "sys.version_info" not in line
        ):
            bad.append(line)
    return bad


@pytest.mark.parametrize("target", ["demo", "test", "test-fast", "lint"])
def test_set_up_commands_create_and_use_the_project_venv(tmp_path, target):
    venv = tmp_path / "venv"
    lines = dry_run(target, venv)
    assert any(line.startswith("python3 -m venv " + str(venv)) for line in lines), lines
    assert any(line.startswith(f"{venv}/bin/python -m pip install") for line in lines)
    assert outside_the_venv(lines, venv) == []
    own = re.sub(r"^OMP_NUM_THREADS=\S+ ", "", lines[-1])  # the test targets set torch's threads first
    assert own.startswith(f"{venv}/bin/python -m ")  # the target's own command, in the venv


def test_the_check_notices_an_install_into_the_system_python(tmp_path):
    venv = tmp_path / "venv"
    assert outside_the_venv(
        ["python3 -m pip install -e .", f"{venv}/bin/python -m pip install x", "python3 -m pytest -q"], venv
    ) == ["python3 -m pip install -e .", "python3 -m pytest -q"]


def test_ci_calls_the_readmes_commands():
    ci = (REPO / ".ci" / "run").read_text()
    assert "make test\n" in ci and "make lint\n" in ci and "make test-install\n" in ci
    # the demo runs once, in the install test, from the installed wheel (`make demo`'s command there)
    assert "make demo" not in ci
    install = (REPO / "tests" / "project" / "test_install_venv.py").read_text()
    assert '"oscar_core.cli", "demo"' in install


@pytest.mark.parametrize("target", ["test", "test-fast"])
def test_both_test_targets_run_in_parallel_with_xdist_from_the_dev_extra(tmp_path, target):
    """CI's ``make test`` and ``make test-fast`` share one worker setting: a pytest-xdist worker per core, whole files
    at a time in the order tests/conftest.py sorts them; ``TEST_WORKERS=0`` runs them in make's own process."""
    venv = tmp_path / "venv"
    command = dry_run(target, venv)[-1]
    # one torch thread per worker unless the caller's OMP_NUM_THREADS says otherwise (a worker per core already)
    assert command.startswith(f"OMP_NUM_THREADS=${{OMP_NUM_THREADS:-1}} {venv}/bin/python -m pytest -q --strict-extras")
    assert command.endswith(" -n auto --dist loadfile --no-loadscope-reorder"), command
    serial = dry_run(target, venv, "TEST_WORKERS=0")[-1]
    assert serial.startswith(f"{venv}/bin/python -m pytest") and "OMP_NUM_THREADS" not in serial  # torch's default
    assert serial.endswith(" -n 0 --dist loadfile --no-loadscope-reorder")
    assert ('-m "not slow' in command) == (target == "test-fast")  # make test runs the slow tests too
    dev = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]["dev"]
    assert any(req.startswith("pytest-xdist") for req in dev)
