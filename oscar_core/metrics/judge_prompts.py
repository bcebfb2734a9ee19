"""Prompts of oscar's VLM judges and the strict parsing of their answers.

Prompts
-------
The prompt texts are module constants (:data:`SUCCESS_SYSTEM_PROMPT`,
:data:`SUCCESS_USER_PROMPT`, :data:`PAIRWISE_SYSTEM_PROMPT`,
:data:`PAIRWISE_USER_PROMPT`, ...); they follow the paper's recipe (the model
sees only the instruction and the frames, not the caption that conditioned the
world model) in our own words. ``docs/evaluation.md`` explains each choice.

Answers are parsed strictly
---------------------------
The answer must be exactly one JSON object — alone, or alone inside one
Markdown code fence (```` ```json ... ``` ````) — with exactly the keys asked
for: ``binary`` the integer 0 or 1, ``partial`` an integer in [0, 100],
``reason`` a non-empty string (pairwise: ``winner`` exactly ``"A"``, ``"B"``
or ``"tie"`` and ``reason``). Anything else (prose around the object, extra or
missing keys, ``true`` for 1, ``"80"`` or ``80.5`` for a score, duplicate
keys, NaN) makes the verdict ``"malformed"``: it keeps the raw text and an
explanation, and its scores stay ``None`` — a score is never guessed. A
malformed answer is not re-asked.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence

__all__ = [
    "DEFAULT_JUDGE_FRAMES",
    "DEFAULT_PAIRWISE_FRAMES",
    "PAPER_SUCCESS_PROMPT",
    "SUCCESS_PROMPTS",
    "SUCCESS_SYSTEM_PROMPT",
    "SUCCESS_USER_PROMPT",
    "PAIRWISE_SYSTEM_PROMPT",
    "PAIRWISE_USER_PROMPT",
    "PAIRWISE_SETS_LABELS",
    "PAIRWISE_SIDE_BY_SIDE_NOTE",
    "STATUSES",
    "MalformedAnswer",
    "parse_success_answer",
    "parse_pairwise_answer",
]

#: Frames per rollout for the success judge (the paper's 32).
DEFAULT_JUDGE_FRAMES = 32
#: Frames per rollout for the pairwise judge: two rollouts share one request, so 2 × 16 = 32 images.
DEFAULT_PAIRWISE_FRAMES = 16

# --------------------------------------------------------------------------- #
# prompts
# --------------------------------------------------------------------------- #
#: The paper's success prompt, word for word (OSCAR Appendix "VLM success scoring", the box "Prompt for the VLM
#: success evaluator"; paragraphs as in the LaTeX source). Sent as the text of one user message, with the task
#: in place of ``{instruction}``; the frames follow it as images ("Frames in temporal order: <32 images>").
#: No system message. Filled with ``str.replace`` (the JSON braces are literal).
PAPER_SUCCESS_PROMPT = """\
You are evaluating whether a robot manipulation rollout successfully completes a described task. You see frames \
sampled uniformly across the rollout duration.

Output one JSON object only, no prose:

{"binary": 0 or 1, "partial": 0-100, "reason": "<one short sentence>"}

- binary = 1 only if the task is fully completed as described

- partial: 0 = no progress, 100 = fully complete, intermediate = partial progress

Task: {instruction}

Frames in temporal order:"""

#: ``SuccessJudge(prompt=...)`` choices: the paper's (default) and oscar's earlier, more detailed wording.
SUCCESS_PROMPTS = ("paper", "oscar")

# oscar's own, more detailed wording (``prompt="oscar"``; docs/evaluation.md explains each choice)
SUCCESS_SYSTEM_PROMPT = """\
You grade videos of a robot carrying out a manipulation instruction. You get \
the instruction and still frames taken at even time intervals from one \
attempt, from its first to its last moment. Judge only what the frames show: \
give no credit for what might happen after the last frame, and treat a \
result you cannot see as not achieved.

Reply with exactly one JSON object and no other text:
{"binary": 0 or 1, "partial": integer from 0 to 100, "reason": "one short sentence"}

- binary: 1 only if the instruction is fully carried out by the end of the \
attempt, else 0.
- partial: how much of the instruction was achieved: 0 means no progress, 100 \
means fully done, values in between mean partial progress (for example, the \
object was grasped but not put in place).
- reason: one short sentence on the visual evidence for your grade."""

#: User text of the success judge; the frames follow it as images. Fields: ``instruction``, ``n_frames``.
SUCCESS_USER_PROMPT = "Instruction: {instruction}\n\nThe {n_frames} frames of the attempt follow, in temporal order."

PAIRWISE_SYSTEM_PROMPT = """\
You compare two videos of a robot attempting the same manipulation \
instruction from the same starting scene. Each attempt, called A or B, is \
shown as still frames taken at even time intervals, from its first to its \
last moment. Decide which attempt carries out the instruction better. \
Finishing the task beats not finishing it. If both finish or both fail, \
prefer the attempt that got further, acted more precisely and made fewer \
mistakes such as dropping, knocking over or pushing away objects. The letters \
and the order of presentation say nothing about quality. Answer "tie" only \
if you cannot tell the two attempts apart in quality.

Reply with exactly one JSON object and no other text:
{"winner": "A" or "B" or "tie", "reason": "one short sentence"}"""

#: User text of the pairwise judge. Fields: ``instruction``, ``n_frames``.
PAIRWISE_USER_PROMPT = "Instruction: {instruction}"
#: Labels placed before each frame set in the "sets" layout. Fields: ``n_frames``.
PAIRWISE_SETS_LABELS = (
    "Attempt A, {n_frames} frames in temporal order:",
    "Attempt B, {n_frames} frames in temporal order:",
)
#: Text placed before the images in the "side_by_side" layout. Fields: ``n_frames``.
PAIRWISE_SIDE_BY_SIDE_NOTE = (
    "{n_frames} images in temporal order follow. Each image shows the same moment of "
    "both attempts: attempt A on the left, attempt B on the right, split by a grey bar."
)

STATUSES = ("ok", "malformed", "error")


class MalformedAnswer(ValueError):
    """The model answered, but not with the JSON object asked for (the message says what is wrong)."""


# --------------------------------------------------------------------------- #
# strict answer parsing
# --------------------------------------------------------------------------- #
_FENCE = re.compile(r"\A```[ \t]*(?:json)?[ \t]*\r?\n(.*?)\r?\n?[ \t]*```\Z", re.S | re.I)


def _no_duplicates(pairs):
    keys = [k for k, _ in pairs]
    dup = sorted({k for k in keys if keys.count(k) > 1})
    if dup:
        raise MalformedAnswer(f"duplicate keys {dup}")
    return dict(pairs)


def _reject_constant(name):
    raise MalformedAnswer(f"{name} is not a JSON number")


def _json_object(text) -> dict:
    if not isinstance(text, str):
        raise MalformedAnswer(f"expected the answer as text, found {type(text).__name__}")
    s = text.strip()
    if not s:
        raise MalformedAnswer("empty answer")
    m = _FENCE.match(s)
    if m:
        s = m.group(1).strip()
    if not s.startswith("{"):
        raise MalformedAnswer(
            "expected one JSON object (optionally inside a ```json fence) and nothing else, "
            f"found text starting {s[:40]!r}"
        )
    try:
        obj = json.loads(s, object_pairs_hook=_no_duplicates, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise MalformedAnswer(f"not one valid JSON object: {exc.msg} at character {exc.pos}") from None
    if not isinstance(obj, dict):
        raise MalformedAnswer(f"expected a JSON object, found {type(obj).__name__}")
    return obj


def _check_keys(obj: dict, expected: Sequence[str]) -> None:
    missing = [k for k in expected if k not in obj]
    extra = sorted(k for k in obj if k not in expected)
    if missing or extra:
        found = "; ".join(p for p in (f"missing {missing}" if missing else "", f"extra {extra}" if extra else "") if p)
        raise MalformedAnswer(f"expected exactly the keys {list(expected)}, found {found}")


def _reason(obj: dict) -> str:
    reason = obj["reason"]
    if not isinstance(reason, str) or not reason.strip():
        raise MalformedAnswer(f"'reason': expected a non-empty string, found {reason!r}")
    return reason.strip()


def parse_success_answer(text: str) -> dict:
    """Strictly parse a success-judge answer into ``{"binary": int, "partial": int, "reason": str}``.

    Raises :class:`MalformedAnswer` for anything but exactly one JSON object
    (alone or alone in a code fence) with exactly the keys ``binary`` (the
    integer 0 or 1), ``partial`` (an integer in [0, 100]) and ``reason`` (a
    non-empty string).
    """
    obj = _json_object(text)
    _check_keys(obj, ("binary", "partial", "reason"))
    binary, partial = obj["binary"], obj["partial"]
    if type(binary) is not int or binary not in (0, 1):
        raise MalformedAnswer(f"'binary': expected the integer 0 or 1, found {binary!r}")
    if type(partial) is not int or not 0 <= partial <= 100:
        raise MalformedAnswer(f"'partial': expected an integer in [0, 100], found {partial!r}")
    return {"binary": binary, "partial": partial, "reason": _reason(obj)}


def parse_pairwise_answer(text: str) -> dict:
    """Strictly parse a pairwise answer into ``{"winner": "A" | "B" | "tie", "reason": str}``.

    Same rules as :func:`parse_success_answer`; ``winner`` must be exactly
    ``"A"``, ``"B"`` or ``"tie"``.
    """
    obj = _json_object(text)
    _check_keys(obj, ("winner", "reason"))
    winner = obj["winner"]
    if winner not in ("A", "B", "tie") or not isinstance(winner, str):
        raise MalformedAnswer(f'\'winner\': expected "A", "B" or "tie", found {winner!r}')
    return {"winner": winner, "reason": _reason(obj)}
