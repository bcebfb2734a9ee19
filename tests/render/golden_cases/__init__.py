"""Golden-image suites as data, one module per suite; tests/render/test_goldens.py checks them all.

A suite is its cases (case id -> what its ``render`` takes; the golden is ``tests/render/golden/<suite>_<case>.png``),
the one function that renders a case to an (H, W, 3) uint8 RGB image, and pairs of cases (base, nudged) whose images
must differ by more than the tolerance: a moved joint or a changed gripper is caught, so the tolerance is not too loose.

Tolerance: RMS 1.5 on 0-255 over the image for every suite: enough for OpenCV anti-aliasing differences across
builds (and, for the mesh and capsule rasterisers, which have no anti-aliasing, a few flipped silhouette pixels), far
below what a nudge gives. Regenerate a suite (then look at the PNGs before committing) with
``python -m pytest tests/render/test_goldens.py -k <suite> --oscar-regen-golden`` (an embodiment's name also selects
its images in the capsules and mesh suites; ``-k "franka and not robotiq"`` leaves franka_robotiq out).

Importable from every test folder as ``render.golden_cases`` (tests/conftest.py puts tests/ on ``sys.path``), so the
embodiments' own tests check the same configurations (within limits, near a limit).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from oscar_core import Camera, load_camera, render_skeleton_video

TOL = 1.5


@dataclass(frozen=True)
class GoldenSuite:
    """name: prefix of the golden file names; cases: case id -> case; render: case -> image; nudged: (base case,
    nudged case) pairs whose images differ by more than ``tol`` (RMS on 0-255)."""

    name: str
    cases: Mapping[str, Any]
    render: Callable[[Any], np.ndarray]
    nudged: Sequence[tuple[Any, Any]]
    tol: float = TOL


def bundled_camera(embodiment) -> Camera:
    """The embodiment's bundled example camera (a camera value of :func:`grid_suite`)."""
    return load_camera(embodiment.example_camera)


def grid_suite(
    name: str,
    embodiment: Callable[[], Any],
    configs: Mapping[str, Any],
    cameras: Mapping[str, Camera | Callable[[Any], Camera]],
    trajectory: Callable[[Any], Any],
    size: tuple[int, int],
    nudged: Sequence[tuple[tuple[Any, str], tuple[Any, str]]],
) -> GoldenSuite:
    """Every configuration seen by every camera, one skeleton frame each at ``size``: case ``<config>_<camera>`` is
    ``(configs[config], camera)``, and any ``(configuration, camera name)`` renders (the nudged ones too).

    embodiment: builds the embodiment (called once, on the first render); cameras: a Camera, or a function of the
    embodiment that gives one (:func:`bundled_camera`); trajectory: configuration -> one-frame Trajectory."""
    embodiment = functools.cache(embodiment)

    @functools.cache
    def camera(camera_name: str) -> Camera:
        cam = cameras[camera_name]
        return cam if isinstance(cam, Camera) else cam(embodiment())

    def render(case) -> np.ndarray:
        config, camera_name = case
        return render_skeleton_video(embodiment(), trajectory(config), camera(camera_name), size)[0]

    cases = {f"{c}_{cam}": (configs[c], cam) for c in sorted(configs) for cam in sorted(cameras)}
    return GoldenSuite(name, cases, render, tuple(nudged))
