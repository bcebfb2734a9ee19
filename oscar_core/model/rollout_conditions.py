"""What a world model's rollout is conditioned on, given its card: the condition video a trajectory renders to, the
gripper openness a card with a gripper signal takes, and a latent-action model's actions padded to the chunk plan.

:class:`~oscar_core.model.world_model.OscarWorldModel` calls these with its own card, transformer and VAE; they hold
no state of their own.
"""

from __future__ import annotations

import numpy as np

from ..render.conditions import takes_actions
from .card import ModelCard
from .errors import ModelInputError
from .gripper_signal import gripper_input


def action_plan(
    card: ModelCard, transformer, vae, skeleton, actions, chunk: int
) -> tuple[np.ndarray | None, int | None]:
    """A rollout's actions checked against the card and padded to the chunk plan.

    skeleton: the condition video passed to the rollout, or None; actions: (T − 1, 14) latent actions or None;
    chunk: frames per chunk. Returns (None, None) for a video-conditioned card (which must not be given actions),
    else (the actions held to cover every chunk, (T', 14) with T' ≥ T − 1; the frame count T). Raises
    ``ModelInputError`` when a latent-action model is given a skeleton or no actions, or a chunk length other than
    the window it was trained on (``transformer.config.action_frames`` + 1).
    """
    if not takes_actions(card.condition):
        if actions is not None:
            raise ModelInputError(
                f"rollout: model {card.name or ''} is conditioned on "
                f"{card.condition!r}: expected a skeleton video, found actions"
            )
        return None, None
    if actions is None or skeleton is not None:
        raise ModelInputError(
            f"rollout: model {card.name or ''} is a latent-action model: expected "
            "actions (T - 1, 14) and skeleton=None (rollout_trajectory builds them), found "
            f"{'a skeleton video' if skeleton is not None else 'no actions'}"
        )
    from .latent_action import hold_actions
    from .rollout import chunk_plan

    trained = int(getattr(transformer.config, "action_frames", chunk - 1)) + 1
    if chunk != trained:
        raise ModelInputError(
            f"chunk_frames: a latent-action model takes the window it was trained on "
            f"({trained} frames: its actions are (chunk_frames - 1, 14) = "
            f"({trained - 1}, 14)), found {chunk}"
        )
    actions = np.asarray(actions)
    total = len(actions) + 1
    starts = chunk_plan(total, chunk, vae.temporal)
    return hold_actions(actions, max(starts[-1] + chunk - 1, len(actions))), total


def condition_inputs(
    card: ModelCard,
    trajectory,
    camera,
    embodiment,
    size: tuple[int, int] | None = None,
    *,
    resize_mode: str = "crop",
    camera_source: str = "<camera>",
) -> dict:
    """What a model with this card is conditioned on along a trajectory: ``{"skeleton": ...}`` or
    ``{"skeleton": None, "actions": ...}``, plus ``gripper`` for a card with ``gripper_signal``.

    skeleton: (T, H, W, 3) uint8 condition video (the card's skeleton, mesh or capsules) rendered at ``size``
    (width, height) pixels (None: the card's size, else the camera's); actions: (T − 1, 14) float64
    ``latent_actions(embodiment, trajectory)`` (latent-action models); gripper: (T, G) float64 openness in [0, 1]
    (1 = open) of the trajectory's grippers.
    """
    if takes_actions(card.condition):
        from .latent_action import latent_actions

        return {"skeleton": None, "actions": latent_actions(embodiment, trajectory)}
    from ..render.conditions import condition_video, video_condition_of

    if size is None and card.width and card.height:
        size = (card.width, card.height)
    name = video_condition_of(card.condition)
    skeleton = condition_video(
        name,
        embodiment,
        trajectory,
        camera,
        size,
        resize_mode=resize_mode,
        camera_source=camera_source,
        style=card.condition_style,
    )
    return {"skeleton": skeleton, **gripper_input(card, embodiment, trajectory)}
