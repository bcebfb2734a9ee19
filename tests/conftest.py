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
