"""Golden images of every embodiment and render condition, one parametrised test over the suites of
tests/render/golden_cases/ (the configurations, cameras and nudges live there, with how each suite was chosen).

Regenerate a suite (then look at the PNGs before committing) with
``python -m pytest tests/render/test_goldens.py -k kuka --oscar-regen-golden``.
"""

import pytest
from render.golden_cases import agibot_g1, capsules, franka, franka_robotiq, hsr, kuka, mano, mesh, toyarm

from oscar_core.testing import compare_images

SUITES = [m.SUITE for m in (agibot_g1, capsules, franka, franka_robotiq, hsr, kuka, mano, mesh, toyarm)]


@pytest.mark.parametrize("suite, case", [pytest.param(s, c, id=f"{s.name}-{c}") for s in SUITES for c in s.cases])
def test_golden_image(golden, suite, case):
    golden.check(suite.render(suite.cases[case]), f"{suite.name}_{case}.png", tol=suite.tol)


@pytest.mark.parametrize("suite", SUITES, ids=lambda s: s.name)
def test_tolerance_detects_a_small_change(suite):
    """Each nudge (a joint moved by ~0.02 rad, a gripper change, a hand moved 4 mm) exceeds the tolerance."""
    assert suite.nudged
    for base, nudged in suite.nudged:
        assert compare_images(suite.render(nudged), suite.render(base)) > suite.tol
