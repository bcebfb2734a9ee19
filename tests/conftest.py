"""Fixtures shared by several test modules, and ``tests/`` on ``sys.path`` so that every test folder imports the shared
helpers: ``_paths`` (folders), ``_models`` (tiny world models, training configs), ``_studies`` (a small evaluation
study), ``_datasets`` (raw episodes), ``_browser`` (headless Chromium); and the ``--strict-extras`` option
(``_strict_extras``); the order of the test files on pytest-xdist workers (``_file_order``)."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

# on an xdist worker (make test, make test-fast): the files that hold slow tests first (tests/_file_order.py);
# --strict-extras (make test, CI): a skip for a missing package of oscar's own extras fails (tests/_strict_extras.py)
from _file_order import pytest_collection_modifyitems  # noqa: F401
from _strict_extras import pytest_addoption, pytest_configure, pytest_runtest_makereport  # noqa: F401


@pytest.fixture(scope="module")
def one_thread():
    """One torch thread for a module: the tiny models are latency-bound, and one thread does not oversubscribe a
    shared CPU. Use with ``pytestmark = pytest.mark.usefixtures("one_thread")``."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="session", autouse=True)
def oscar_cache(tmp_path_factory):
    """``$OSCAR_CACHE`` in a temporary folder (unless set): tests never write the user's ~/.cache/oscar (verified
    sha256 records, compile and prompt caches); subprocesses inherit it."""
    import os

    if os.environ.get("OSCAR_CACHE"):
        yield os.environ["OSCAR_CACHE"]
        return
    os.environ["OSCAR_CACHE"] = str(tmp_path_factory.mktemp("oscar-cache"))
    yield os.environ["OSCAR_CACHE"]
    os.environ.pop("OSCAR_CACHE", None)


@pytest.fixture
def refused_port():
    """A loopback TCP port (int) that refuses every connection for the whole test: a socket bound to it that does not
    listen. Held, not closed: a port closed after the OS picked it could be taken by another test worker meanwhile."""
    import socket

    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        yield held.getsockname()[1]


@pytest.fixture(scope="module")
def tiny_model_dir(tmp_path_factory):
    """A tiny world model (seed 0, skeleton scale 0.05, 5-frame chunks at 15 fps) exported in the oscar layout, once
    per test module."""
    from _models import export_tiny_world_model

    return export_tiny_world_model(
        tmp_path_factory.mktemp("m") / "tiny", skeleton_scale=0.05, name="tiny", chunk_frames=5, fps=15.0
    )
