"""``oscar toyworld example``: the three input files of ``oscar rollout`` for one toy-world episode.

The episode is episode :data:`EXAMPLE_INDEX` of an embodiment under a seed,
exactly as ``oscar toyworld generate --seed SEED`` draws it (a held-out
episode: index % 10 == 9), so with seed 0 and toyarm, franka or kuka it is an
episode ``oscar-toy`` never trained on. It writes:

* ``first_frame.png`` — frame 0 the toy world renders for that trajectory and camera, (H, W, 3) RGB;
* ``trajectory.npz`` — the episode's joint trajectory (docs/formats.md), ``frames`` frames at ``fps``;
* ``camera.json`` — the static camera that filmed it (docs/formats.md), ``width`` x ``height`` pixels.

Defaults are ``oscar-toy``'s: 64 x 64 pixels, 17 frames (one chunk), 10 fps.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["EXAMPLE_INDEX", "EXAMPLE_FILES", "write_example"]

#: Which episode of the embodiment the example is (every tenth episode, index % 10 == 9, is held out).
EXAMPLE_INDEX = 9
#: The files written, in order: first frame, trajectory, camera.
EXAMPLE_FILES = ("first_frame.png", "trajectory.npz", "camera.json")


def write_example(
    out,
    embodiment: str = "toyarm",
    *,
    seed: int = 0,
    width: int = 64,
    height: int = 64,
    frames: int = 17,
    fps: float = 10.0,
    supersample: int = 2,
    registry=None,
) -> dict:
    """Write ``out``/first_frame.png, trajectory.npz and camera.json for episode :data:`EXAMPLE_INDEX` of
    ``embodiment`` under ``seed``; returns ``{"files": [paths], "episode": ..., "frames", "size", "fps"}``.

    Every input is checked before anything is drawn: the embodiment must be one the toy world supports
    (:class:`~oscar_core.toyworld.motion.ToyWorldError` otherwise), ``out`` a folder that can be written
    (:class:`~oscar_core.errors.OutputPathError`). Each file is written atomically.
    """
    from .._util.atomic import atomic_write_bytes
    from ..camera import save_camera
    from ..kinematics.trajectory import save_trajectory
    from ..plugin.registry import Registry
    from .episode import episode_rng, plan_episode, render_world
    from .motion import check_supported
    from .policy_eval import _png_bytes

    registry = registry or Registry()
    emb = registry.get(embodiment)
    check_supported(emb)
    if width <= 0 or height <= 0:
        raise ValueError(f"toyworld example: --size: expected a positive WIDTHxHEIGHT, found {width}x{height}")
    if frames < 2:
        raise ValueError(f"toyworld example: --frames: expected at least 2 frames, found {frames}")
    out = Path(out)
    _check_folder(out)
    motion, scene, camera = plan_episode(emb, episode_rng(seed, emb.name, EXAMPLE_INDEX), width, height, frames, fps)
    first = render_world(emb, motion, scene, camera, ss=supersample).rgb[0]
    paths = [out / name for name in EXAMPLE_FILES]
    atomic_write_bytes(paths[0], _png_bytes(np.ascontiguousarray(first)))
    save_trajectory(motion.trajectory, paths[1])
    save_camera(camera, paths[2])
    return {
        "files": [str(p) for p in paths],
        "episode": f"{emb.name} episode {EXAMPLE_INDEX} (seed {seed})",
        "embodiment": emb.name,
        "frames": frames,
        "size": [width, height],
        "fps": fps,
    }


def _check_folder(out: Path) -> None:
    """Make ``out`` (parents included) and check that a file can be created in it, or raise OutputPathError."""
    import os

    from ..errors import OutputPathError

    if out.exists() and not out.is_dir():
        raise OutputPathError(out, "expected a folder, found a file")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(out, exc.strerror or str(exc)) from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise OutputPathError(out, "the folder is not writable")
