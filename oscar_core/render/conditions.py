"""The conditions a world model can take, by name, in one registry: adding a condition touches this file only.

Video conditions are drawn by a :class:`~oscar_core.render.renderer.ConditionRenderer` and go through the VAE
and the DiT's PE_s in the same way (the model's "skeleton" stream carries whichever condition video its card
names):

- ``skeleton``: the paper's 2D kinematic skeleton (:mod:`oscar_core.render.skeleton_stream`);
- ``mesh``: each link's URDF visual geometry (:mod:`oscar_core.render.mesh`);
- ``capsules``: shaded capsules along the skeleton's edges with fingers that open and close
  (:mod:`oscar_core.render.capsules`): a mesh condition for any kinematic tree, with or without visual
  geometry, and the toy world's own robot body.

The others are no video: ``latent_action`` (the paper's latent-action baseline: per-frame actions from the
trajectory, :mod:`oscar_core.model.latent_action`) and ``none`` (image and text only).

Every consumer of a condition (``oscar render``, the batch renderer, the trainer, rollouts, ``oscar eval run``,
the model card) looks it up here.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from ..errors import OscarError

__all__ = [
    "ConditionName",
    "VideoConditionName",
    "Condition",
    "REGISTRY",
    "CONDITIONS",
    "MODEL_CONDITIONS",
    "DEFAULT_CONDITION",
    "condition",
    "takes_actions",
    "is_video_condition",
    "check_condition",
    "chunk_renderer",
    "video_renderer",
    "renderer",
    "condition_video",
    "condition_style",
    "parse_condition_style",
    "style_for",
    "condition_key",
    "video_condition_of",
]

#: every condition a model card or a training config may name
ConditionName = Literal["skeleton", "mesh", "capsules", "latent_action", "none"]
#: the conditions given as a video
VideoConditionName = Literal["skeleton", "mesh", "capsules"]


@dataclass(frozen=True)
class Condition:
    """One condition. renderer: ``"module:NAME"`` of its :class:`~oscar_core.render.renderer.ConditionRenderer`
    (imported on first use), None for a condition that is no video; actions: the model is conditioned on
    per-frame actions computed from the trajectory instead of a video."""

    name: str
    renderer: str | None = None
    actions: bool = False

    @property
    def is_video(self) -> bool:
        return self.renderer is not None


REGISTRY: dict[str, Condition] = {
    c.name: c
    for c in (
        Condition("skeleton", "oscar_core.render.skeleton_stream:SKELETON"),
        Condition("mesh", "oscar_core.render.mesh:MESH"),
        Condition("capsules", "oscar_core.render.capsules:CAPSULES"),
        Condition("latent_action", actions=True),
        Condition("none"),
    )
}

#: the video conditions (``oscar render --condition``, the latent cache, the batch renderer), in registry order
CONDITIONS: tuple[str, ...] = tuple(n for n, c in REGISTRY.items() if c.is_video)
#: every condition a model may be trained with
MODEL_CONDITIONS: tuple[str, ...] = tuple(REGISTRY)
DEFAULT_CONDITION = "skeleton"


def condition(name: str, source: str = "condition") -> Condition:
    """The registry entry of ``name``; an :class:`OscarError` naming ``source`` and the choices if there is none."""
    try:
        return REGISTRY[name]
    except (KeyError, TypeError):
        raise OscarError(f"{source}: expected one of {', '.join(MODEL_CONDITIONS)}, found {name!r}") from None


def takes_actions(name: str) -> bool:
    """Whether a model of condition ``name`` is conditioned on per-frame actions (``latent_action``) rather than
    a condition video."""
    return condition(name).actions


def is_video_condition(name: str) -> bool:
    """Whether ``name`` is a condition given as a video (rendered, through the VAE and PE_s)."""
    entry = REGISTRY.get(name)
    return entry is not None and entry.is_video


def check_condition(name, source: str = "condition") -> str:
    """``name`` if it is a video condition, else an :class:`OscarError` naming ``source`` and the choices."""
    if not is_video_condition(name):
        raise OscarError(f"{source}: expected one of {', '.join(CONDITIONS)}, found {name!r}")
    return name


def video_condition_of(card_condition: str) -> str:
    """The condition video a model whose card says ``card_condition`` is rolled out with: that condition
    when it is a video condition, else the skeleton (models without a video condition ignore it)."""
    return card_condition if is_video_condition(card_condition) else DEFAULT_CONDITION


def renderer(name: str):
    """The :class:`~oscar_core.render.renderer.ConditionRenderer` of video condition ``name``."""
    module, attr = REGISTRY[check_condition(name)].renderer.split(":")
    return getattr(importlib.import_module(module), attr)


def chunk_renderer(name: str) -> Callable:
    """The streaming renderer of condition ``name``: ``f(embodiment, traj, camera, size, *, resize_mode,
    device, camera_source, chunk_frames, strict, stats)`` yielding (n, H, W, 3) uint8 chunks."""
    return renderer(name).iter_chunks


def video_renderer(name: str) -> Callable:
    """The whole-video renderer of condition ``name``:
    ``f(embodiment, traj, camera, size, ...)`` → (T, H, W, 3) uint8."""
    return renderer(name).render_video


def condition_style(style, source: str = "condition_style"):
    """The :class:`~oscar_core.render.raster.SkeletonStyle` of a card's or a config's ``condition_style`` (a mapping
    of style fields, e.g. ``{"gripper_radius_open": 27}``, sizes in pixels at 288 px of height; None: the default
    look, returned as None); an :class:`OscarError` names ``source``'s key, what was expected and what was found."""
    from .raster import SkeletonStyle

    if style is None or isinstance(style, SkeletonStyle):
        return style
    try:
        return SkeletonStyle.from_overrides(style, source)
    except ValueError as e:
        raise OscarError(str(e)) from None


def parse_condition_style(text: str | None, source: str = "--condition-style"):
    """The JSON text of a ``--condition-style`` flag decoded (None: not given), for every command that takes the flag
    (``oscar train --cache-latents``, ``oscar render``); an :class:`OscarError` naming ``source`` when it is no JSON.
    Its fields are checked once, by the library call the command makes (:func:`style_for`, before any work)."""
    import json

    if text is None:
        return None
    try:
        return json.loads(text)
    except ValueError as e:
        raise OscarError(f"{source}: expected a JSON mapping of style fields, found {text!r} ({e})") from None


def style_for(name: str, style, source: str = "condition_style"):
    """:func:`condition_style` of ``style`` for condition video ``name``: a style draws the skeleton only, so a
    style given with another condition (mesh, capsules: their looks are their own) is an :class:`OscarError`
    naming ``source``."""
    if style is not None and name != DEFAULT_CONDITION:
        raise OscarError(
            f"{source}: expected the skeleton condition (a style draws the skeleton), found condition {name!r}"
        )
    return condition_style(style, source)


def condition_key(name: str, style=None) -> str:
    """What a cached condition latent encodes, as one string: the condition ``name``, followed by its style's
    fields (sorted JSON) when ``style`` (a mapping) changes the look."""
    import json

    return name if not style else f"{name} {json.dumps(style, sort_keys=True)}"


def condition_video(
    name: str,
    embodiment,
    trajectory,
    camera,
    size,
    *,
    resize_mode: str = "crop",
    camera_source: str = "<camera>",
    style=None,
):
    """(T, H, W, 3) uint8 condition video ``name`` of ``trajectory`` seen by ``camera`` at ``size`` (width, height),
    drawn in ``style`` (a ``condition_style`` mapping, a ``SkeletonStyle``, or None: the default look)."""
    return video_renderer(name)(
        embodiment,
        trajectory,
        camera,
        size,
        resize_mode=resize_mode,
        camera_source=camera_source,
        style=condition_style(style),
    )
