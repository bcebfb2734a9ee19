"""Camera calibration from the robot itself: a fixed camera's pose (and intrinsics) from clicked or detected
skeleton points (:mod:`~oscar_core.calibration.pnp`), and a score of how well a calibration lines the rendered
robot up with a video (:mod:`~oscar_core.calibration.score`). docs/calibration.md.

Names are re-exported here flat; submodules load on first use.
"""

from __future__ import annotations

from .._util.lazy import lazy_exports

_EXPORTS = {
    "PixelPoints": "points",
    "PointsFileError": "points",
    "load_points": "points",
    "save_points": "points",
    "calibrate": "pnp",
    "CalibrationResult": "pnp",
    "Correspondences": "pnp",
    "build_correspondences": "pnp",
    "check_geometry": "pnp",
    "skeleton_points": "pnp",
    "rotation_error_deg": "pnp",
    "position_error_mm": "pnp",
    "calibration_score": "score",
    "ScoreConfig": "score",
    "CalibrationScore": "score",
    "perturb_camera": "score",
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
