"""``--strict-extras``: a test skipped because a package of oscar's own requirements is missing fails instead.

``make test`` (and so CI) passes the flag: the project's environment installs every extra the tests need
(Makefile ``EXTRAS``), so such a skip means a test that never runs. Which packages are the project's own: every
requirement of ``pyproject.toml`` (``[project] dependencies`` and every ``optional-dependencies`` extra), by
import name (:data:`IMPORT_NAMES` where it differs from the distribution's). Caught:

* ``pytest.importorskip(module)`` of such a package (wrapped here, so a module-level call is caught at
  collection, whatever its ``reason``);
* a ``pytest.skip`` whose reason names an install command of an extra (``pip install "oscar-wm[…]"``).

Any other skip — no GPU, no network, a system binary, another Python — stays a skip; ``-rfEs`` (pyproject's
``addopts``) lists every skip and its reason at the end of the run. Loaded by ``tests/conftest.py``; a plain
module, so ``python -m pytest -p _strict_extras`` (with ``tests/`` on ``PYTHONPATH``) loads it elsewhere.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

__all__ = ["IMPORT_NAMES", "own_requirements", "owner_of", "pytest_addoption", "pytest_configure"]

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"
#: Import names of the requirements whose distribution name is not their import name (lower case, '-' as '_').
IMPORT_NAMES = {
    "faiss-cpu": "faiss",
    "scikit-image": "skimage",
    "pillow": "PIL",
    "rerun-sdk": "rerun",
    "rtb-data": "rtbdata",
    "pycollada": "collada",
    "opencv-python-headless": "cv2",
    "pyyaml": "yaml",
}
#: A skip reason that names one of the project's extras' install commands.
_INSTALL_EXTRA = re.compile(r"oscar-wm\[([a-z0-9_,-]+)\]")
_STATE = {"strict": False}


def _name(requirement: str) -> str:
    return re.split(r"[\s\[<>=!~;]", requirement.strip(), maxsplit=1)[0].lower()


def own_requirements(pyproject: Path = PYPROJECT) -> dict[str, tuple[str, ...]]:
    """``{import name: the extras that list it}``, ``()`` for a core dependency."""
    import tomllib

    project = tomllib.loads(Path(pyproject).read_text())["project"]
    own: dict[str, tuple[str, ...]] = {}

    def key(requirement: str) -> str:
        return IMPORT_NAMES.get(_name(requirement), _name(requirement).replace("-", "_"))

    for extra, reqs in project.get("optional-dependencies", {}).items():
        for r in reqs:
            own[key(r)] = own.get(key(r), ()) + (extra,)
    for r in project.get("dependencies", []):
        own[key(r)] = ()
    return own


def owner_of(module: str, own: dict | None = None) -> str | None:
    """Which of the project's requirements provides ``module`` (a dotted import name): ``"oscar-wm"`` (a core
    dependency), ``"oscar-wm[plots,dev]"`` (the extras that list it), or None."""
    own = own_requirements() if own is None else own
    extras = own.get(module.split(".")[0])
    if extras is None:
        return None
    return f"oscar-wm[{','.join(extras)}]" if extras else "oscar-wm"


_importorskip = pytest.importorskip


def _strict_importorskip(modname: str, *args, **kwargs):
    try:
        return _importorskip(modname, *args, **kwargs)
    except pytest.skip.Exception as exc:
        owner = owner_of(modname) if _STATE["strict"] else None
        if owner is None:
            raise
        pytest.fail(
            f"--strict-extras: {modname} is missing, a requirement of {owner} ({exc}); make test installs "
            "every extra the tests need (Makefile EXTRAS)",
            pytrace=False,
        )


def pytest_addoption(parser):
    parser.addoption(
        "--strict-extras",
        action="store_true",
        help="fail, not skip, a test skipped because a package of oscar's own requirements or extras is missing",
    )


def pytest_configure(config):
    _STATE["strict"] = bool(config.getoption("--strict-extras"))
    if _STATE["strict"]:
        pytest.importorskip = _strict_importorskip


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if not (_STATE["strict"] and report.skipped and isinstance(report.longrepr, tuple)):
        return
    reason = str(report.longrepr[2])
    found = _INSTALL_EXTRA.search(reason)
    if found:
        report.outcome = "failed"
        report.longrepr = (
            f"--strict-extras: skipped for a missing extra of the project's own ({found.group(0)}): {reason}"
        )
