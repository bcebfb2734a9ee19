"""pytest plugin (entry point ``pytest11: oscar_golden``): the ``golden`` fixture.

Options: ``--oscar-regen-golden`` rewrites golden images instead of comparing
(the only way they are regenerated); ``--oscar-golden-results DIR`` is where
actual/expected/diff images go on failure (default ``golden-results/`` under
the rootdir). Goldens live in a ``golden/`` folder beside the test file.
Imports nothing heavy at pytest start-up.

The module may be loaded twice over: by its entry point (name ``oscar_golden``)
and by ``-p oscar_core.testing.pytest_plugin`` or a ``pytest_plugins`` list
(name = module path).  pluggy refuses one module under two names, so whichever
name loads it first blocks the other one, and the second load is skipped.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ENTRY_POINT_NAME = "oscar_golden"


def _block_other_name(pluginmanager) -> None:
    """Block the alias this module was not registered under, so it is not loaded twice."""
    this = sys.modules[__name__]
    registered_as = pluginmanager.get_name(this)
    for alias in (ENTRY_POINT_NAME, __name__):
        if alias != registered_as and not pluginmanager.is_blocked(alias) and pluginmanager.get_plugin(alias) is None:
            pluginmanager.set_blocked(alias)


def pytest_addoption(parser, pluginmanager):
    # Called (historic hook) as soon as this module is registered, before the
    # entry points are loaded, so blocking the alias here is in time.
    _block_other_name(pluginmanager)
    group = parser.getgroup("oscar", "oscar golden images")
    group.addoption(
        "--oscar-regen-golden",
        action="store_true",
        default=False,
        help="write golden images instead of comparing against them",
    )
    group.addoption(
        "--oscar-golden-results",
        default=None,
        metavar="DIR",
        help="folder for actual/expected/diff images of failed comparisons (default: <rootdir>/golden-results)",
    )


class GoldenChecker:
    """Compare images with PNGs in ``<test file's folder>/golden/``."""

    def __init__(self, folder: Path, results: Path, regenerate: bool):
        self.folder, self.results, self.regenerate = folder, results, regenerate

    def check(self, image, name: str, *, tol: float) -> None:
        """image: (H, W, 3) uint8 RGB; name: PNG file name; tol: max RMS on 0-255 (0 = exact)."""
        from .golden import assert_matches_golden

        assert_matches_golden(image, self.folder / name, tol=tol, results_dir=self.results, regenerate=self.regenerate)


@pytest.fixture
def golden(request) -> GoldenChecker:
    config = request.config
    results = config.getoption("--oscar-golden-results") or Path(str(config.rootpath)) / "golden-results"
    return GoldenChecker(
        Path(str(request.path)).parent / "golden", Path(results), bool(config.getoption("--oscar-regen-golden"))
    )
