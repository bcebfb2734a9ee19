"""Closed-loop simulators are plugins found through the entry point group ``oscar.simulators``
(oscar_core.evaluation.simulators): the toy world registers its own in pyproject.toml, so the closed loop's command
never imports the toy world; an unknown name, two distributions claiming one name and a broken entry point are
one-line errors naming what was expected and what was found."""

from __future__ import annotations

import importlib
from types import SimpleNamespace

import pytest
from _paths import REPO

from oscar_core.evaluation import simulators
from oscar_core.metrics.common import MetricInputError
from oscar_core.toyworld.closed_loop import toy_simulator


def test_the_toy_world_registers_its_simulator_in_pyproject():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    group = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["entry-points"][simulators.GROUP]
    module, attr = group["toy"].split(":")
    assert getattr(importlib.import_module(module), attr) is toy_simulator


def test_the_installed_toy_simulator_is_the_toy_worlds():
    # installed metadata: an editable checkout registers the group once `pip install -e .` ran after it was added
    assert simulators.load_simulator("toy") is toy_simulator


def _ep(name, value, dist=None, loads=None):
    def load():
        if isinstance(loads, BaseException):
            raise loads
        return loads

    return SimpleNamespace(name=name, value=value, dist=dist, load=load)


def test_lookup_by_name_and_its_errors(monkeypatch):
    def factory(*args):
        return None

    dist_a, dist_b = SimpleNamespace(name="oscar-wm", version="0.1.0"), SimpleNamespace(name="my-sim", version="2.0")
    eps = [_ep("toy", "a.b:toy", dist_a, factory), _ep("toy", "a.b:toy", dist_a, factory)]  # seen twice: one
    monkeypatch.setattr(simulators.md, "entry_points", lambda group: eps if group == simulators.GROUP else [])
    assert simulators.load_simulator("toy") is factory
    with pytest.raises(MetricInputError, match=r"--simulator: .*oscar.simulators: toy;.*found 'mujoco'"):
        simulators.load_simulator("mujoco")
    eps.append(_ep("toy", "my_sim:toy", dist_b, factory))
    with pytest.raises(MetricInputError, match=r"a.b:toy \(oscar-wm 0.1.0\) and my_sim:toy \(my-sim 2.0\)"):
        simulators.load_simulator("toy")
    eps[:] = [_ep("broken", "gone:x", dist_b, ImportError("No module named 'gone'")), _ep("odd", "m:x", None, 3)]
    with pytest.raises(MetricInputError, match=r"an importable simulator \(gone:x\), found ImportError"):
        simulators.load_simulator("broken")
    with pytest.raises(MetricInputError, match="a simulator factory .a callable., found int"):
        simulators.load_simulator("odd")
    eps.clear()
    with pytest.raises(MetricInputError, match=r"oscar.simulators: none; an editable checkout needs `pip install"):
        simulators.load_simulator("toy")
