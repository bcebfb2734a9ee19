"""A procedural world small enough to train the whole OSCAR pipeline on a CPU.

* :mod:`~oscar_core.toyworld.motion` — random reach / pick-and-place motions inside URDF limits, the carry rule;
* :mod:`~oscar_core.toyworld.hand` — human-hand episodes (the ``mano`` plugin's keypoints), the hand's ball rules;
* :mod:`~oscar_core.toyworld.scene` — floor, backdrop, lighting, colours, cameras that see the robot;
* :mod:`~oscar_core.toyworld.raster` — z-buffered shaded capsules and spheres;
* :mod:`~oscar_core.toyworld.episode` — one episode: motion + scene + camera → RGB frames + ground truth;
* :mod:`~oscar_core.toyworld.generate` — clip sets, deterministic per seed, resumable by shard;
* :mod:`~oscar_core.toyworld.vae_train` — the toy ``AutoencoderKLWan``;
* :mod:`~oscar_core.toyworld.locate`, :mod:`~oscar_core.toyworld.evaluate` — the table;
* :mod:`~oscar_core.toyworld.cli` — ``oscar toyworld``.

Names are re-exported here flat; submodules load on first use. See docs/toyworld.md.
"""

from __future__ import annotations

from .._util.lazy import lazy_exports

_EXPORTS = {
    "ToyWorldError": "motion",
    "check_supported": "motion",
    "sample_motion": "motion",
    "carry_object": "motion",
    "Motion": "motion",
    "joint_limits": "motion",
    "miss_start": "motion",
    "is_hand": "motion",
    "sample_hand_motion": "hand",
    "hand_carry": "hand",
    "hand_closed": "hand",
    "push_object": "hand",
    "Scene": "scene",
    "sample_scene": "scene",
    "sample_camera": "scene",
    "OBJECT_RGB": "scene",
    "EE_RGB": "scene",
    "Episode": "episode",
    "make_episode": "episode",
    "plan_episode": "episode",
    "render_world": "episode",
    "episode_rng": "episode",
    "miss_rng": "episode",
    "GenerateConfig": "generate",
    "generate_clipset": "generate",
    "VAETrainConfig": "vae_train",
    "train_vae": "vae_train",
    "load_toy_vae": "vae_train",
    "write_reconstructions": "vae_train",
    "position_errors": "locate",
    "EE_TARGET": "locate",
    "OBJECT_TARGET": "locate",
    "evaluate_conditions": "evaluate",
    "evaluate_clip": "evaluate",
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
