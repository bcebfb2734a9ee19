"""benchmarks/startup.py: ``-X importtime``'s report summed per top-level package (self times, each module once)."""

import importlib.util

import pytest
from _paths import REPO

# a report as ``python -X importtime`` writes it (children before their parent, indented by depth)
REPORT = """\
import time: self [us] | cumulative | imported package
import time:    100000 |     100000 |     torch._C
import time:    200000 |     200000 |       sympy.core
import time:     50000 |     250000 |     sympy
import time:    150000 |     500000 |   torch._dynamo
import time:    100000 |     600000 | torch
import time:     25000 |      25000 |   diffusers.utils
import time:     75000 |     100000 | diffusers
import time:      5000 |       5000 | oscar_core
1234
"""


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_startup", REPO / "benchmarks" / "startup.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_self_times_are_summed_per_top_level_package(bench):
    rows = {r["package"]: r for r in bench.by_package(REPORT)}
    # torch: torch._C + torch._dynamo + torch itself, not torch's cumulative 0.6 s (that holds sympy's 0.25)
    assert rows["torch"] == {"package": "torch", "self_s": 0.35, "share": 0.496, "modules": 3}
    assert rows["sympy"] == {"package": "sympy", "self_s": 0.25, "share": 0.355, "modules": 2}
    assert rows["diffusers"]["self_s"] == 0.1 and rows["oscar_core"]["self_s"] == 0.005
    assert list(rows) == ["torch", "sympy", "diffusers", "oscar_core"]  # largest first
    assert sum(r["share"] for r in rows.values()) == pytest.approx(1.0, abs=0.002)


def test_packages_past_the_top_are_summed_as_other(bench):
    rows = bench.by_package(REPORT, top=2)
    assert [r["package"] for r in rows] == ["torch", "sympy", "other"]
    assert rows[-1] == {"package": "other", "self_s": 0.105, "share": 0.149, "modules": 3}


def test_each_process_reports_its_module_count_and_the_heavy_imports_it_holds(bench):
    # a stand-in module named like a submodule of diffusers: counted as diffusers, without importing it
    code = "import types\nsys.modules['diffusers.utils'] = types.ModuleType('diffusers.utils')"
    _, _, modules, heavy = bench.run_once(code, REPO)
    assert heavy == ["diffusers"] and modules > 10
    assert bench.run_once("pass", REPO)[3] == []
