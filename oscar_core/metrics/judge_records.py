"""What goes into and comes out of oscar's VLM judges: clips, pairs, verdicts and their summaries.

Statuses
--------
``"ok"`` — a valid answer; ``"malformed"`` — the model answered but not in the
required form (``raw`` holds the text); ``"error"`` — no answer: the video
could not be read, or every attempt failed, or the server's reply is not an
OpenAI chat completion (``error`` says which; ``raw`` holds the reply body when
there was one).
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .common import MetricInputError

__all__ = [
    "JudgeClip",
    "JudgePair",
    "SuccessVerdict",
    "PairwiseVerdict",
    "pairs_by_session",
    "success_by_policy",
    "preferences_from_verdicts",
]


# --------------------------------------------------------------------------- #
# inputs
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class JudgeClip:
    """One rollout to judge.

    ``name``: unique id (e.g. ``"81a85b7c/pi0_fast"``); ``video``: a path (video
    file, ``.npy`` or PNG-frame folder) or a (T, H, W, 3) array (uint8, or float
    in [0, 1]); ``instruction``: the task as a rater would read it (not the
    world model's caption); ``policy``: the policy that produced the rollout
    (default: ``name``); ``session``: the episode / scene it belongs to (pairs
    are formed within a session).
    """

    name: str
    video: object
    instruction: str
    policy: str | None = None
    session: str | None = None
    #: free-form facts about the clip for programmatic judges (e.g. a target position); not sent to a VLM
    info: Mapping | None = field(default=None, compare=False)

    @property
    def policy_name(self) -> str:
        return self.policy if self.policy is not None else self.name


@dataclass(frozen=True)
class JudgePair:
    """Two rollouts of the same task to compare; ``a`` and ``b`` are the real sides (not the shown order)."""

    a: JudgeClip
    b: JudgeClip
    name: str | None = None

    @property
    def id(self) -> str:
        return self.name if self.name is not None else f"{self.a.name} vs {self.b.name}"


def _check_clip(clip, source: str) -> JudgeClip:
    if not isinstance(clip, JudgeClip):
        raise MetricInputError(source, "type", "a JudgeClip", type(clip).__name__)
    if not isinstance(clip.name, str) or not clip.name:
        raise MetricInputError(source, "name", "a non-empty clip name", repr(clip.name))
    if not isinstance(clip.instruction, str) or not clip.instruction.strip():
        raise MetricInputError(
            f"{source} ({clip.name})", "instruction", "a non-empty task instruction", repr(clip.instruction)
        )
    for key in ("policy", "session"):
        value = getattr(clip, key)
        if value is not None and (not isinstance(value, str) or not value):
            raise MetricInputError(f"{source} ({clip.name})", key, "a non-empty string or None", repr(value))
    video = clip.video
    if isinstance(video, (str, os.PathLike)):
        if not Path(video).exists():
            raise MetricInputError(
                video, "video", f"an existing video file or frame folder (clip {clip.name!r})", "no such file or folder"
            )
    elif isinstance(video, np.ndarray) or (hasattr(video, "detach") and hasattr(video, "cpu")):
        shape = tuple(video.shape)
        if len(shape) != 4 or shape[-1] != 3 or shape[0] < 1:
            raise MetricInputError(
                f"{source} ({clip.name})", "video", "(T, H, W, 3) frames with T >= 1", f"shape {shape}"
            )
    else:
        raise MetricInputError(
            f"{source} ({clip.name})", "video", "a path or a (T, H, W, 3) array", type(video).__name__
        )
    return clip


def _check_unique(names: Sequence[str], source: str, what: str) -> None:
    seen, dup = set(), []
    for n in names:
        if n in seen:
            dup.append(n)
        seen.add(n)
    if dup:
        raise MetricInputError(source, what, "unique names", f"duplicates {sorted(set(dup))[:10]}")


def pairs_by_session(clips: Iterable[JudgeClip]) -> list[JudgePair]:
    """Every pair of rollouts by different policies within a session — the paper's protocol.

    Clips are grouped by ``session`` (clips without one, by their
    instruction); within a group every two clips of different policies form a
    pair, in input order (7 policies → 21 pairs per session; the paper's 65
    sessions give 1 365). Clips of one group must share their instruction.
    """
    clips = [_check_clip(c, f"clips[{k}]") for k, c in enumerate(clips)]
    groups: dict[tuple, list[JudgeClip]] = {}
    for c in clips:
        key = ("session", c.session) if c.session is not None else ("instruction", c.instruction.strip())
        groups.setdefault(key, []).append(c)
    pairs = []
    for (_kind, value), members in groups.items():
        for a, b in itertools.combinations(members, 2):
            if a.instruction.strip() != b.instruction.strip():
                where = f"session {value!r}" if _kind == "session" else f"clips {a.name!r}, {b.name!r}"
                raise MetricInputError(
                    where,
                    "instruction",
                    f"the same instruction for every clip ({a.name}: {a.instruction!r})",
                    f"{b.name}: {b.instruction!r}",
                )
            if a.policy_name != b.policy_name:
                pairs.append(JudgePair(a, b))
    return pairs


# --------------------------------------------------------------------------- #
# verdicts
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class SuccessVerdict:
    """The success judge's result for one clip.

    ``status``: "ok", "malformed" or "error" (module docstring); ``binary`` (0/1),
    ``partial`` (0–100) and ``reason`` are set only when ``status == "ok"``;
    ``raw``: the model's answer text (or the reply body of a non-chat reply);
    ``error``: what went wrong; ``attempts``: HTTP requests sent for this clip
    (0 when ``cached``; retries = attempts − 1); ``attempt_errors``: one entry per
    failed request; ``frames_total`` / ``frames_sent``: frames in the clip / sent.
    """

    clip: str
    policy: str
    session: str | None
    instruction: str
    status: str
    binary: int | None = None
    partial: int | None = None
    reason: str | None = None
    raw: str | None = None
    error: str | None = None
    attempts: int = 0
    cached: bool = False
    attempt_errors: tuple[str, ...] = ()
    frames_total: int | None = None
    frames_sent: int | None = None
    cache_key: str | None = None
    model: str | None = None
    #: token usage of the request that produced the answer (from the response; also kept for cached answers)
    usage: dict | None = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def to_dict(self) -> dict:
        return {
            "clip": self.clip,
            "policy": self.policy,
            "session": self.session,
            "instruction": self.instruction,
            "status": self.status,
            "binary": self.binary,
            "partial": self.partial,
            "reason": self.reason,
            "raw": self.raw,
            "error": self.error,
            "attempts": self.attempts,
            "cached": self.cached,
            "attempt_errors": list(self.attempt_errors),
            "frames_total": self.frames_total,
            "frames_sent": self.frames_sent,
            "cache_key": self.cache_key,
            "model": self.model,
            "usage": self.usage,
        }


@dataclass(frozen=True)
class PairwiseVerdict:
    """The pairwise judge's result for one :class:`JudgePair`.

    ``a`` / ``b``: the real policies (as in the pair); ``shown_first``: the
    policy shown as "A" (``swapped`` is true when that is ``b``);
    ``model_winner``: the model's literal "A" / "B" / "tie"; ``winner``: mapped
    back to the real sides, "a" / "b" / "tie" (``winner_policy`` names it, None
    for a tie). Other fields as in :class:`SuccessVerdict`.
    """

    pair: str
    a: str
    b: str
    clip_a: str
    clip_b: str
    instruction: str
    swapped: bool
    status: str
    model_winner: str | None = None
    winner: str | None = None
    reason: str | None = None
    raw: str | None = None
    error: str | None = None
    attempts: int = 0
    cached: bool = False
    attempt_errors: tuple[str, ...] = ()
    frames_sent: tuple[int, int] | None = None
    cache_key: str | None = None
    model: str | None = None
    usage: dict | None = None
    #: both_orders: the verdicts of the two presentations (shown as is, then swapped) and whether they agreed
    orders: tuple | None = None
    orders_agree: bool | None = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def shown_first(self) -> str:
        return self.b if self.swapped else self.a

    @property
    def winner_policy(self) -> str | None:
        return {"a": self.a, "b": self.b}.get(self.winner)

    def preference(self):
        """This verdict as a :class:`~oscar_core.metrics.policy.Preference`, or None unless ``ok``."""
        from .policy import Preference

        if not self.ok:
            return None
        return Preference(self.a, self.b, {"a": 2, "tie": 1, "b": 0}[self.winner], where=self.pair)

    def to_dict(self) -> dict:
        return {
            "pair": self.pair,
            "a": self.a,
            "b": self.b,
            "clip_a": self.clip_a,
            "clip_b": self.clip_b,
            "instruction": self.instruction,
            "swapped": self.swapped,
            "shown_first": self.shown_first,
            "status": self.status,
            "model_winner": self.model_winner,
            "winner": self.winner,
            "winner_policy": self.winner_policy,
            "reason": self.reason,
            "raw": self.raw,
            "error": self.error,
            "attempts": self.attempts,
            "cached": self.cached,
            "attempt_errors": list(self.attempt_errors),
            "frames_sent": list(self.frames_sent) if self.frames_sent else None,
            "cache_key": self.cache_key,
            "model": self.model,
            "usage": self.usage,
            "orders_agree": self.orders_agree,
            "orders": [o.to_dict() for o in self.orders] if self.orders else None,
        }


def success_by_policy(verdicts: Iterable[SuccessVerdict]) -> dict[str, dict]:
    """Per-policy summary of success verdicts, in first-appearance order.

    ``{policy: {"success_rate", "episodes", "mean_partial", "judged", "not_judged"}}``:
    only "ok" verdicts count (``episodes`` lists their binary verdicts);
    ``not_judged`` counts the malformed and failed ones, which are left out —
    never counted as failures. ``success_rate`` / ``mean_partial`` are None for
    a policy without any "ok" verdict. The entries are in the format
    ``oscar eval policies --wm`` reads.
    """
    out: dict[str, dict] = {}
    for v in verdicts:
        row = out.setdefault(v.policy, {"episodes": [], "partials": [], "not_judged": 0})
        if v.ok:
            row["episodes"].append(v.binary)
            row["partials"].append(v.partial)
        else:
            row["not_judged"] += 1
    summary = {}
    for policy, row in out.items():
        eps, parts = row["episodes"], row["partials"]
        summary[policy] = {
            "success_rate": float(np.mean(eps)) if eps else None,
            "episodes": eps,
            "mean_partial": float(np.mean(parts)) if parts else None,
            "judged": len(eps),
            "not_judged": row["not_judged"],
        }
    return summary


def preferences_from_verdicts(verdicts: Iterable[PairwiseVerdict]) -> list:
    """The :class:`~oscar_core.metrics.policy.Preference` s of the "ok" pairwise verdicts (others are skipped),
    ready for :func:`~oscar_core.metrics.policy.fit_bradley_terry`."""
    return [p for p in (v.preference() for v in verdicts) if p is not None]
