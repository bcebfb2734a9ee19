"""The order in which pytest-xdist workers take the test files: the files that hold a test marked slow first, each
file's tests kept together, otherwise the collection order.

The Makefile's test targets hand out whole files in collection order (``--dist loadfile --no-loadscope-reorder``).
Sorted so, the long files start at once and the short ones fill in around them: the workers finish together instead
of one of them running a long test alone at the end. Every worker sorts the same collection the same way (xdist
checks that the workers agree); a run in one process keeps the collection order. Loaded by ``tests/conftest.py``; a
plain module, so ``python -m pytest -p _file_order`` (with ``tests/`` on ``PYTHONPATH``) loads it elsewhere.
"""

from __future__ import annotations

__all__ = ["pytest_collection_modifyitems"]


def pytest_collection_modifyitems(config, items) -> None:
    if not hasattr(config, "workerinput"):  # only an xdist worker has it
        return
    slow_files = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.path not in slow_files)  # stable: a slow file's tests (False) before the rest
