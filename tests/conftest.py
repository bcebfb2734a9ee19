"""Fixtures shared by several test modules."""

import pytest


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
