"""Tests that never run: the project's environment has every extra the tests need, and ``--strict-extras``
(``make test``, CI) turns a skip for a missing package of the project's own into a failure."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from _paths import REPO
from _strict_extras import own_requirements, owner_of


def _makefile_extras() -> set[str]:
    found = re.search(r"^EXTRAS := (\S+)$", (REPO / "Makefile").read_text(), re.M)
    return set(found.group(1).split(","))


def test_the_makefile_installs_every_extra_whose_packages_the_tests_import():
    own = own_requirements()
    installed = _makefile_extras()
    imported, missing = set(), []
    for path in sorted((REPO / "tests").rglob("*.py")):
        for module in re.findall(r"importorskip\(\s*[\"']([\w.]+)[\"']", path.read_text()):
            extras = own.get(module.split(".")[0])
            if extras:
                imported.add(module)
                if not set(extras) & installed:
                    missing.append(f"{path.relative_to(REPO)}: {module} (extras {extras})")
    assert {"websockets", "faiss", "smplx"} <= imported  # the scan finds what it should
    assert missing == [], f"Makefile EXTRAS leaves out extras the tests import: {missing}"
    for target in ("test", "test-fast"):
        recipe = re.search(rf"^{target}: install\n\t(.*)$", (REPO / "Makefile").read_text(), re.M).group(1)
        assert "--strict-extras" in recipe, recipe


def test_own_requirements_are_found_by_import_name():
    own = own_requirements()
    assert own["websockets"] == ("policy",) and own["faiss"] == ("data",) and own["cv2"] == ()
    assert owner_of("matplotlib.pyplot", own) == "oscar-wm[plots,dev]"
    assert owner_of("scipy.spatial.transform", own) == "oscar-wm" and owner_of("tomllib", own) is None


CASES = """
import sys
import pytest

def test_own_extra_missing():
    sys.modules["msgpack"] = None  # as if the policy extra were not installed
    pytest.importorskip("msgpack", reason="no msgpack here")

def test_gpu_skip():
    pytest.importorskip("oscar_no_such_cuda_kernels")

def test_explicit_skip_naming_an_extra():
    pytest.skip('rerun is missing (pip install "oscar-wm[viz]")')

def test_network_skip():
    pytest.skip("no network here")
"""


def _run(tmp_path: Path, *flags: str) -> subprocess.CompletedProcess:
    (tmp_path / "test_cases.py").write_text(CASES)
    env = {**os.environ, "PYTHONPATH": str(REPO / "tests")}
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "_strict_extras", "-p", "no:cacheprovider", "-q", "-rfEs", *flags],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_strict_extras_fails_a_skip_for_the_projects_own_extra_and_lists_the_others(tmp_path):
    plain = _run(tmp_path)
    assert plain.returncode == 0 and "4 skipped" in plain.stdout, plain.stdout
    strict = _run(tmp_path, "--strict-extras")
    assert strict.returncode == 1, strict.stdout
    assert "2 failed, 2 skipped" in strict.stdout, strict.stdout
    assert "FAILED test_cases.py::test_own_extra_missing" in strict.stdout
    assert "msgpack is missing, a requirement of oscar-wm[policy]" in strict.stdout
    assert "FAILED test_cases.py::test_explicit_skip_naming_an_extra" in strict.stdout
    skipped = [line for line in strict.stdout.splitlines() if line.startswith("SKIPPED")]
    assert len(skipped) == 2 and "oscar_no_such_cuda_kernels" in skipped[0] + skipped[1]
    assert any("no network here" in line for line in skipped)
