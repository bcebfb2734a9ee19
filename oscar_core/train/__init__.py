"""Training the world model: the clip format, window and source samplers, the rectified-flow loop, checkpoints.

Public names are re-exported flat and load on first use (the loop imports
diffusers and torch.distributed; ``import oscar_core.train`` does not).
See docs/training.md.
"""

from __future__ import annotations

from .._util.deprecation import Deprecated
from .._util.lazy import lazy_exports

_EXPORTS = {
    "ClipSet": "clips",
    "ClipSetWriter": "clips",
    "ClipRecord": "clips",
    "Clip": "clips",
    "ClipFormatError": "clips",
    "clip_openness": "clips",
    "TrainConfig": "config",
    "TrainConfigError": "config",
    "load_config": "config",
    "config_from_dict": "config",
    "train": "loop",
    "TrainResult": "loop",
    "export_run": "export",
    "sample_sigmas": "flow",
    "flow_inputs": "flow",
    "flow_loss": "flow",
    "StepPlanner": "sampling",
    "mixing_weights": "sampling",
    "window_prior": "sampling",
    "write_toy_clipset": "synthetic",
}

#: names this package exported in 0.1.0 that moved (CHANGELOG.md, "Deprecated")
_DEPRECATED = {
    name: Deprecated("oscar_core.model.latent_action", name, f"oscar_core.model.{name}", "0.2.0", "0.3.0")
    for name in ("LatentActionTransformer", "latent_actions")
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, _DEPRECATED)
