"""VLM judges of world-model rollouts: per-clip success and pairwise preference.

The OSCAR paper (Sec. "Policy Evaluation", Appendix "VLM success scoring")
scores every rollout with a vision-language model that stands in for a human
RoboArena rater: 32 frames sampled uniformly from the generated video go to
the model in temporal order together with the task instruction, and the model
returns one JSON object with a binary success flag, a partial-progress score
and a one-sentence reason. It also asks the model to compare the rollouts of
two policies from the same session, and fits Bradley–Terry scores to those
preferences. This module does both against **any OpenAI-compatible
chat-completions endpoint** (a local vLLM server, or a hosted API).

Endpoint
--------
``base_url`` (e.g. ``http://127.0.0.1:8000/v1`` or ``https://api.openai.com/v1``;
``/chat/completions`` is appended unless already there), ``model`` and an
optional ``api_key`` (sent as ``Authorization: Bearer``; a local vLLM server
needs none) come from the arguments, else from the environment variables
``OSCAR_JUDGE_BASE_URL``, ``OSCAR_JUDGE_MODEL`` and ``OSCAR_JUDGE_API_KEY``.
The key is never written to results, cache files or error messages.

Frames
------
``n_frames`` (default 32 for the success judge, 16 per rollout for the
pairwise judge) are sampled uniformly over the clip with
``round(linspace(0, T − 1, n))``, so the first and the last frame are always
included (``n = 1`` sends the last frame: the end state decides success). A
clip with fewer than ``n_frames`` frames sends **all** its frames (the
verdict records ``frames_sent`` and ``frames_total``). A frame whose longer
side exceeds ``max_side`` (default 512, so the paper's native 512×288 rollouts
go unchanged) is downscaled with area interpolation, keeping its aspect ratio;
smaller frames are never upscaled. Frames are encoded as JPEG (quality 90) or
PNG and sent as base64 ``data:`` URLs in ``image_url`` content parts.

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

Retries, concurrency, cache
---------------------------
Each request has a timeout (``timeout`` seconds for connecting and for each
read, and for the whole response). HTTP 408, 429 and 5xx answers, timeouts and
connection errors are retried up to ``max_attempts`` requests in all, waiting
``backoff · 2^(k−1)`` seconds (at most ``backoff_max``, ±25 % jitter; a
``Retry-After`` header is honoured up to ``backoff_max``) before retry k. Other
HTTP errors (400, 401, 404, ...) and answers that are not a chat completion
are not retried. A clip whose requests all fail gets status ``"error"`` with
the last error; the run always finishes with one verdict per input.
Up to ``concurrency`` clips (default 4) are judged at once by a thread pool.

With ``cache_dir``, the model's raw answer is stored in one JSON file per
request, ``<cache_dir>/<key>.json``, written atomically; the key is the SHA-256
of the video content (file bytes; for a frame folder its file names and bytes;
for an array its dtype, shape and bytes), the exact prompt texts, the model
name and every sampling setting (frames, max side, image format and quality,
temperature, max tokens, extra body, pairwise layout and order). The base URL
is not part of the key: the same model behind another server shares the cache.
A rerun with the same inputs sends no request (``cached`` is true,
``attempts`` 0); the cached answer is parsed again, so a cached malformed answer
stays malformed — delete its file (``cache_key`` in the verdict) to ask again.
Failed requests are never cached.

Statuses
--------
``"ok"`` — a valid answer; ``"malformed"`` — the model answered but not in the
required form (``raw`` holds the text); ``"error"`` — no answer: the video
could not be read, or every attempt failed, or the server's reply is not an
OpenAI chat completion (``error`` says which; ``raw`` holds the reply body when
there was one).
"""

from __future__ import annotations

import base64
import hashlib
import itertools
import json
import math
import os
import random
import re
import threading
import time
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ._common import MetricInputError

__all__ = [
    "ENV_BASE_URL",
    "ENV_MODEL",
    "ENV_API_KEY",
    "DEFAULT_JUDGE_FRAMES",
    "DEFAULT_PAIRWISE_FRAMES",
    "DEFAULT_MAX_SIDE",
    "PAPER_SUCCESS_PROMPT",
    "SUCCESS_PROMPTS",
    "SUCCESS_SYSTEM_PROMPT",
    "SUCCESS_USER_PROMPT",
    "PAIRWISE_SYSTEM_PROMPT",
    "PAIRWISE_USER_PROMPT",
    "PAIRWISE_SETS_LABELS",
    "PAIRWISE_SIDE_BY_SIDE_NOTE",
    "MalformedAnswer",
    "JudgeRequestError",
    "ChatClient",
    "JudgeClip",
    "JudgePair",
    "SuccessVerdict",
    "PairwiseVerdict",
    "SuccessJudge",
    "PairwiseJudge",
    "sample_frame_indices",
    "parse_success_answer",
    "parse_pairwise_answer",
    "pairs_by_session",
    "success_by_policy",
    "preferences_from_verdicts",
]

ENV_BASE_URL = "OSCAR_JUDGE_BASE_URL"
ENV_MODEL = "OSCAR_JUDGE_MODEL"
ENV_API_KEY = "OSCAR_JUDGE_API_KEY"

#: Frames per rollout for the success judge (the paper's 32).
DEFAULT_JUDGE_FRAMES = 32
#: Frames per rollout for the pairwise judge: two rollouts share one request, so 2 × 16 = 32 images.
DEFAULT_PAIRWISE_FRAMES = 16
#: Longer side, in pixels, above which frames are downscaled (the paper's rollouts are 512×288).
DEFAULT_MAX_SIDE = 512

#: Cache-format version; part of every cache key.
CACHE_VERSION = 1

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
PAIRWISE_SETS_LABELS = ("Attempt A, {n_frames} frames in temporal order:",
                        "Attempt B, {n_frames} frames in temporal order:")
#: Text placed before the images in the "side_by_side" layout. Fields: ``n_frames``.
PAIRWISE_SIDE_BY_SIDE_NOTE = ("{n_frames} images in temporal order follow. Each image shows the same moment of "
                              "both attempts: attempt A on the left, attempt B on the right, split by a grey bar.")

STATUSES = ("ok", "malformed", "error")
_RETRY_HTTP = frozenset({408, 429})
_SEPARATOR_PX = 8


# --------------------------------------------------------------------------- #
# errors
# --------------------------------------------------------------------------- #
class MalformedAnswer(ValueError):
    """The model answered, but not with the JSON object asked for (the message says what is wrong)."""


class JudgeRequestError(RuntimeError):
    """No usable chat completion after all attempts (or a non-retryable failure).

    ``attempts``: requests sent; ``attempt_errors``: one short description per
    failed request; ``raw``: the last reply body, if any; ``retryable``: whether
    the last failure was of a retryable kind.
    """

    def __init__(self, message: str, *, attempts: int, attempt_errors: Sequence[str] = (), raw: str | None = None,
                 retryable: bool = False):
        super().__init__(message)
        self.attempts = attempts
        self.attempt_errors = tuple(attempt_errors)
        self.raw = raw
        self.retryable = retryable


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
        raise MalformedAnswer("expected one JSON object (optionally inside a ```json fence) and nothing else, "
                              f"found text starting {s[:40]!r}")
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
        raise MalformedAnswer(f"'winner': expected \"A\", \"B\" or \"tie\", found {winner!r}")
    return {"winner": winner, "reason": _reason(obj)}


# --------------------------------------------------------------------------- #
# the HTTP client
# --------------------------------------------------------------------------- #
def _resolve(value, env: str, what: str, required: bool) -> str | None:
    if value is None or value == "":
        value = os.environ.get(env) or None
    if value is None and required:
        flag = {"base URL": "--base-url / base_url=", "model name": "--model / model="}.get(what, "argument")
        raise MetricInputError(env, what, f"a {what} ({flag}, or the environment variable {env})", "none set")
    return value


def _chat_url(base_url: str) -> str:
    url = base_url.strip().rstrip("/")
    if not re.match(r"\Ahttps?://[^/\s]+", url):
        raise MetricInputError("base_url", "url", "an http:// or https:// URL such as http://127.0.0.1:8000/v1",
                               repr(base_url))
    return url if url.endswith("/chat/completions") else url + "/chat/completions"


def _retry_after(headers) -> float | None:
    if headers is None:
        return None
    value = headers.get("Retry-After")
    try:
        return max(0.0, float(value)) if value is not None else None
    except ValueError:
        return None


def _message_text(body: dict):
    """``choices[0].message.content`` of a chat completion as text, or raise ValueError naming the problem."""
    if not isinstance(body, dict):
        raise ValueError(f"expected a JSON object, found {type(body).__name__}")
    if "error" in body and "choices" not in body:
        err = body["error"]
        msg = err.get("message") if isinstance(err, dict) else err
        raise ValueError(f"the server returned an error object: {str(msg)[:300]}")
    choices = body.get("choices")
    if not isinstance(choices, list) or not choices:
        raise ValueError(f"expected a non-empty 'choices' list, found keys {sorted(body)[:10]}")
    first = choices[0]
    message = first.get("message") if isinstance(first, dict) else None
    if not isinstance(message, dict):
        raise ValueError("expected 'choices[0].message' to be an object")
    content = message.get("content")
    if content is None:
        return None  # the model produced no text (e.g. cut off while reasoning, or a refusal)
    if isinstance(content, str):
        return content
    if isinstance(content, list):  # content parts
        texts = [p.get("text") for p in content if isinstance(p, dict) and p.get("type") in ("text", "output_text")]
        if all(isinstance(t, str) for t in texts):
            return "".join(texts)
    raise ValueError(f"expected 'choices[0].message.content' to be text, found {type(content).__name__}")


def _openai():
    """The ``openai`` package, or an ImportError naming the install command (checked only here)."""
    try:
        import openai
    except ImportError:
        raise ImportError("oscar's VLM judges use the OpenAI Python SDK, which is not installed; install it with: "
                          'pip install "oscar-wm[judge]"') from None
    return openai


class ChatClient:
    """An OpenAI-compatible chat-completions client (the OpenAI Python SDK) with oscar's retry and cost rules.

    ``base_url`` / ``model`` / ``api_key`` default to ``$OSCAR_JUDGE_BASE_URL``,
    ``$OSCAR_JUDGE_MODEL`` / ``$OSCAR_JUDGE_API_KEY`` (no key: no
    ``Authorization`` header, as a local vLLM server wants). ``temperature``
    and ``max_tokens`` are sent only when set (reasoning models such as GPT-5
    reject a temperature); ``max_tokens`` goes out as ``max_completion_tokens``
    (what OpenAI's newer models require; vLLM accepts it) unless
    ``token_field="max_tokens"``. ``extra_body`` is merged into every request
    body (e.g. ``{"reasoning_effort": "high"}``).

    The SDK's own retries are off; ``complete`` retries 408, 429, 5xx and
    connection errors up to ``max_attempts`` requests, honouring ``Retry-After``
    (up to ``backoff_max``), but a **timed-out** request — the expensive kind:
    the server may still be working on it, and bill it — is retried at most
    ``max_timeout_retries`` times (default 1). ``max_requests`` caps the HTTP
    requests this client sends in all (a budget shared by every clip and
    thread; once spent, requests fail at once with "request budget ... spent").
    Thread-safe.
    """

    def __init__(self, base_url: str | None = None, model: str | None = None, api_key: str | None = None, *,
                 timeout: float = 120.0, max_attempts: int = 5, backoff: float = 1.0, backoff_max: float = 30.0,
                 temperature: float | None = None, max_tokens: int | None = None,
                 extra_body: Mapping | None = None, token_field: str = "max_completion_tokens",
                 max_timeout_retries: int = 1, max_requests: int | None = None):
        self.base_url = _resolve(base_url, ENV_BASE_URL, "base URL", True)
        self.url = _chat_url(self.base_url)
        self.model = _resolve(model, ENV_MODEL, "model name", True)
        self._api_key = _resolve(api_key, ENV_API_KEY, "API key", False)
        for name, value, positive in (("timeout", timeout, True), ("backoff", backoff, False),
                                      ("backoff_max", backoff_max, False)):
            if (isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value)
                    or value < 0 or (positive and value == 0)):
                raise MetricInputError(name, "value", "a number of seconds " + ("> 0" if positive else ">= 0"),
                                       repr(value))
        for name, value, low in (("max_attempts", max_attempts, 1), ("max_timeout_retries", max_timeout_retries, 0)):
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise MetricInputError(name, "value", f"an integer >= {low}", repr(value))
        if max_requests is not None and (isinstance(max_requests, bool) or not isinstance(max_requests, int)
                                         or max_requests < 0):
            raise MetricInputError("max_requests", "value", "an integer >= 0 or None", repr(max_requests))
        if max_tokens is not None and (isinstance(max_tokens, bool) or not isinstance(max_tokens, int)
                                       or max_tokens < 1):
            raise MetricInputError("max_tokens", "value", "an integer >= 1 or None", repr(max_tokens))
        if token_field not in ("max_completion_tokens", "max_tokens"):
            raise MetricInputError("token_field", "value", '"max_completion_tokens" or "max_tokens"', repr(token_field))
        if extra_body is not None and not isinstance(extra_body, Mapping):
            raise MetricInputError("extra_body", "type", "a JSON object (mapping)", type(extra_body).__name__)
        reserved = sorted({"model", "messages"} & set(extra_body or {}))
        if reserved:
            raise MetricInputError("extra_body", "keys", "request fields other than 'model' and 'messages'",
                                   reserved)
        self.timeout, self.max_attempts = float(timeout), max_attempts
        self.backoff, self.backoff_max = float(backoff), float(backoff_max)
        self.temperature, self.max_tokens, self.token_field = temperature, max_tokens, token_field
        self.max_timeout_retries, self.max_requests = max_timeout_retries, max_requests
        self.extra_body = dict(extra_body or {})
        openai = _openai()
        sdk_base = self.url[: -len("/chat/completions")]
        self._sdk = openai.OpenAI(base_url=sdk_base, api_key=self._api_key or "no-key", timeout=self.timeout,
                                  max_retries=0)
        self._no_auth = None if self._api_key else {"Authorization": openai.Omit()}
        self._rng = random.Random()
        self._lock = threading.Lock()
        self.requests_sent = 0
        self.usage = {"prompt_tokens": 0, "completion_tokens": 0, "total_tokens": 0}

    def __repr__(self) -> str:  # never shows the key
        return f"ChatClient(url={self.url!r}, model={self.model!r}, key={'set' if self._api_key else 'none'})"

    def sampling(self) -> dict:
        """The request fields besides ``model`` and ``messages`` (part of every cache key)."""
        out = {}
        if self.temperature is not None:
            out["temperature"] = self.temperature
        if self.max_tokens is not None:
            out[self.token_field] = self.max_tokens
        out.update(self.extra_body)
        return out

    def _delay(self, attempt: int, retry_after: float | None) -> float:
        with self._lock:
            jitter = 1.0 + 0.25 * (2.0 * self._rng.random() - 1.0)
        delay = min(self.backoff_max, self.backoff * 2.0 ** (attempt - 1)) * jitter
        if retry_after is not None:
            delay = max(delay, min(retry_after, self.backoff_max))
        return delay

    def _redact(self, text: str) -> str:
        """``text`` with the API key masked (a server may echo it in an error message)."""
        return text.replace(self._api_key, "***") if self._api_key and len(self._api_key) >= 4 else text

    def _take_request(self) -> bool:
        with self._lock:
            if self.max_requests is not None and self.requests_sent >= self.max_requests:
                return False
            self.requests_sent += 1
            return True

    def _send(self, messages: list) -> str:
        """One HTTP request through the SDK; returns the reply body's text (SDK exceptions propagate)."""
        raw = self._sdk.chat.completions.with_raw_response.create(
            model=self.model, messages=messages, extra_body=self.sampling() or None, extra_headers=self._no_auth)
        return raw.http_response.text

    def complete(self, messages: list) -> tuple[str | None, int, tuple[str, ...], dict | None]:
        """Send one chat request; returns ``(answer text or None, attempts, attempt_errors, usage or None)``.

        Raises :class:`JudgeRequestError` when no chat completion was obtained.
        """
        openai = _openai()
        errors: list[str] = []
        attempt = timeouts = 0
        raw = None
        while True:
            if not self._take_request():
                msg = f"request budget of {self.max_requests} requests spent (max_requests); not sent"
                errors.append(msg)
                raise JudgeRequestError(msg, attempts=attempt, attempt_errors=errors, retryable=False)
            attempt += 1
            retry_after = None
            try:
                text = self._send(messages)
            except openai.APIStatusError as exc:
                try:
                    raw = self._redact(exc.response.text[:4000])
                except Exception:  # noqa: BLE001 - the body is informational only
                    raw = None
                code = exc.status_code
                retryable = code in _RETRY_HTTP or 500 <= code <= 599
                errors.append(f"HTTP {code}" + (f": {raw[:200]}" if raw else ""))
                retry_after = _retry_after(exc.response.headers)
            except openai.APITimeoutError:
                timeouts += 1
                errors.append(f"timeout: no complete response within {self.timeout:g} s")
                retryable = timeouts <= self.max_timeout_retries
                raw = None
                if not retryable:
                    raise JudgeRequestError(
                        f"request to {self.url} timed out {timeouts} time(s); not retried beyond "
                        f"max_timeout_retries={self.max_timeout_retries} (a timed-out request may still be billed)",
                        attempts=attempt, attempt_errors=errors, retryable=True) from None
            except openai.APIConnectionError as exc:
                cause = exc.__cause__ or exc
                errors.append(f"connection: {type(cause).__name__}: {cause}")
                retryable = True
                raw = None
            else:
                text = self._redact(text)
                try:
                    body = json.loads(text)
                    content = _message_text(body)
                except (json.JSONDecodeError, ValueError) as exc:
                    msg = (f"not an OpenAI chat completion from {self.url}: "
                           + ("the body is not JSON" if isinstance(exc, json.JSONDecodeError) else str(exc)))
                    errors.append(msg)
                    raise JudgeRequestError(msg, attempts=attempt, attempt_errors=errors, raw=text[:4000]) from None
                usage = _usage(body)
                if usage:
                    with self._lock:
                        for k in self.usage:
                            self.usage[k] += usage.get(k, 0)
                return content, attempt, tuple(errors), usage
            if not retryable or attempt >= self.max_attempts:
                what = "failed" if not retryable else f"failed after {attempt} attempts"
                raise JudgeRequestError(f"request to {self.url} {what}: {errors[-1]}", attempts=attempt,
                                        attempt_errors=errors, raw=raw, retryable=retryable)
            time.sleep(self._delay(attempt, retry_after))


def _usage(body: dict) -> dict | None:
    """``usage`` of a chat completion as ``{prompt_tokens, completion_tokens, total_tokens}`` (ints), or None."""
    u = body.get("usage") if isinstance(body, dict) else None
    if not isinstance(u, dict):
        return None
    out = {k: int(u[k]) for k in ("prompt_tokens", "completion_tokens", "total_tokens")
           if isinstance(u.get(k), int) and not isinstance(u.get(k), bool)}
    return out or None


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
        raise MetricInputError(f"{source} ({clip.name})", "instruction", "a non-empty task instruction",
                               repr(clip.instruction))
    for key in ("policy", "session"):
        value = getattr(clip, key)
        if value is not None and (not isinstance(value, str) or not value):
            raise MetricInputError(f"{source} ({clip.name})", key, "a non-empty string or None", repr(value))
    video = clip.video
    if isinstance(video, (str, os.PathLike)):
        if not Path(video).exists():
            raise MetricInputError(video, "video", f"an existing video file or frame folder (clip {clip.name!r})",
                                   "no such file or folder")
    elif isinstance(video, np.ndarray) or (hasattr(video, "detach") and hasattr(video, "cpu")):
        shape = tuple(video.shape)
        if len(shape) != 4 or shape[-1] != 3 or shape[0] < 1:
            raise MetricInputError(f"{source} ({clip.name})", "video", "(T, H, W, 3) frames with T >= 1",
                                   f"shape {shape}")
    else:
        raise MetricInputError(f"{source} ({clip.name})", "video", "a path or a (T, H, W, 3) array",
                               type(video).__name__)
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
                raise MetricInputError(where, "instruction",
                                       f"the same instruction for every clip ({a.name}: {a.instruction!r})",
                                       f"{b.name}: {b.instruction!r}")
            if a.policy_name != b.policy_name:
                pairs.append(JudgePair(a, b))
    return pairs


# --------------------------------------------------------------------------- #
# frames
# --------------------------------------------------------------------------- #
def sample_frame_indices(total: int, n: int) -> np.ndarray:
    """Indices of ``n`` frames sampled uniformly from ``total``: ``round(linspace(0, total − 1, n))``.

    The first and last frame are included for n ≥ 2, the indices are distinct
    and increasing; ``n ≥ total`` returns every frame; ``n = 1`` returns the last frame.
    """
    if total < 1:
        raise MetricInputError("video", "frames", "at least 1 frame", f"{total} frames")
    if n < 1:
        raise MetricInputError("n_frames", "value", "an integer >= 1", n)
    if n >= total:
        return np.arange(total)
    if n == 1:
        return np.array([total - 1])
    return np.rint(np.linspace(0, total - 1, n)).astype(np.int64)


def _to_uint8(video) -> np.ndarray:
    if hasattr(video, "detach") and hasattr(video, "cpu"):
        video = video.detach().cpu().numpy()
    video = np.asarray(video)
    if video.dtype == np.uint8:
        return video
    if np.issubdtype(video.dtype, np.floating):
        return np.clip(np.rint(video * 255.0), 0, 255).astype(np.uint8)
    raise MetricInputError("video", "dtype", "uint8, or float in [0, 1]", str(video.dtype))


def _load_frames(video, source: str) -> np.ndarray:
    if isinstance(video, (str, os.PathLike)):
        from .video import load_video

        try:
            arr = load_video(video)
        except MetricInputError:
            raise
        except (OSError, ValueError) as exc:
            raise MetricInputError(video, "video", "a readable video", f"{type(exc).__name__}: {exc}") from None
    else:
        arr = video
    arr = _to_uint8(arr)
    if arr.ndim != 4 or arr.shape[-1] != 3 or len(arr) == 0:
        raise MetricInputError(source, "video", "(T, H, W, 3) RGB frames with T >= 1", f"shape {arr.shape}")
    return arr


def _fit(frame: np.ndarray, max_side: int | None) -> np.ndarray:
    h, w = frame.shape[:2]
    if not max_side or max(h, w) <= max_side:
        return frame
    import cv2

    scale = max_side / max(h, w)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    return cv2.resize(frame, size, interpolation=cv2.INTER_AREA)


def _side_by_side(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    import cv2

    h = left.shape[0]
    if right.shape[0] != h:
        right = cv2.resize(right, (max(1, round(right.shape[1] * h / right.shape[0])), h),
                           interpolation=cv2.INTER_AREA)
    bar = np.full((h, _SEPARATOR_PX, 3), 128, dtype=np.uint8)
    return np.concatenate([left, bar, right], axis=1)


def _encode_image(frame: np.ndarray, image_format: str, quality: int) -> str:
    import cv2

    bgr = np.ascontiguousarray(frame[..., ::-1])
    if image_format == "jpeg":
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
        mime = "image/jpeg"
    else:
        ok, buf = cv2.imencode(".png", bgr)
        mime = "image/png"
    if not ok:
        raise ValueError(f"could not encode a {frame.shape} frame as {image_format}")
    return f"data:{mime};base64,{base64.b64encode(buf.tobytes()).decode('ascii')}"


def _image_part(url: str) -> dict:
    return {"type": "image_url", "image_url": {"url": url}}


# --------------------------------------------------------------------------- #
# content hashes and the cache
# --------------------------------------------------------------------------- #
def _hash_file(h, path: Path) -> None:
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)


def _content_hash(video) -> str:
    h = hashlib.sha256()
    if isinstance(video, (str, os.PathLike)):
        p = Path(video)
        if p.is_dir():
            h.update(b"frames-folder\0")
            for f in sorted(x for x in p.iterdir() if x.is_file()):
                h.update(f.name.encode() + b"\0")
                _hash_file(h, f)
        else:
            h.update(b"file\0")
            _hash_file(h, p)
    else:
        arr = np.ascontiguousarray(_to_uint8(video))
        h.update(f"array\0{arr.dtype.str}\0{arr.shape}\0".encode())
        h.update(arr.tobytes())
    return h.hexdigest()


def _key(fields: dict) -> str:
    return hashlib.sha256(json.dumps(fields, sort_keys=True, ensure_ascii=False).encode()).hexdigest()


def _cache_read(cache_dir: Path | None, key: str) -> dict | None:
    if cache_dir is None:
        return None
    path = cache_dir / f"{key}.json"
    try:
        entry = json.loads(path.read_text())
    except (OSError, ValueError):
        return None  # missing or unreadable: treat as a miss (it will be rewritten)
    if not isinstance(entry, dict) or entry.get("key") != key or "answer" not in entry:
        return None
    return entry


def _cache_write(cache_dir: Path | None, key: str, entry: dict) -> None:
    if cache_dir is None:
        return
    from .._atomic import atomic_write_bytes

    atomic_write_bytes(cache_dir / f"{key}.json", (json.dumps(entry, indent=1, ensure_ascii=False) + "\n").encode())


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
        return {"clip": self.clip, "policy": self.policy, "session": self.session, "instruction": self.instruction,
                "status": self.status, "binary": self.binary, "partial": self.partial, "reason": self.reason,
                "raw": self.raw, "error": self.error, "attempts": self.attempts, "cached": self.cached,
                "attempt_errors": list(self.attempt_errors), "frames_total": self.frames_total,
                "frames_sent": self.frames_sent, "cache_key": self.cache_key, "model": self.model, "usage": self.usage}


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
        return {"pair": self.pair, "a": self.a, "b": self.b, "clip_a": self.clip_a, "clip_b": self.clip_b,
                "instruction": self.instruction, "swapped": self.swapped, "shown_first": self.shown_first,
                "status": self.status, "model_winner": self.model_winner, "winner": self.winner,
                "winner_policy": self.winner_policy, "reason": self.reason, "raw": self.raw, "error": self.error,
                "attempts": self.attempts, "cached": self.cached, "attempt_errors": list(self.attempt_errors),
                "frames_sent": list(self.frames_sent) if self.frames_sent else None, "cache_key": self.cache_key,
                "model": self.model, "usage": self.usage, "orders_agree": self.orders_agree,
                "orders": [o.to_dict() for o in self.orders] if self.orders else None}


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
        summary[policy] = {"success_rate": float(np.mean(eps)) if eps else None, "episodes": eps,
                           "mean_partial": float(np.mean(parts)) if parts else None, "judged": len(eps),
                           "not_judged": row["not_judged"]}
    return summary


def preferences_from_verdicts(verdicts: Iterable[PairwiseVerdict]) -> list:
    """The :class:`~oscar_core.metrics.policy.Preference` s of the "ok" pairwise verdicts (others are skipped),
    ready for :func:`~oscar_core.metrics.policy.fit_bradley_terry`."""
    return [p for p in (v.preference() for v in verdicts) if p is not None]


# --------------------------------------------------------------------------- #
# the judges
# --------------------------------------------------------------------------- #
def _progress(n: int, enabled: bool, desc: str):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=n, desc=desc, unit="clip")


class _BaseJudge:
    default_frames = DEFAULT_JUDGE_FRAMES

    def __init__(self, *, base_url=None, model=None, api_key=None, n_frames: int | None = None,
                 max_side: int | None = DEFAULT_MAX_SIDE, image_format: str = "jpeg", jpeg_quality: int = 90,
                 temperature: float | None = None, max_tokens: int | None = None, extra_body: Mapping | None = None,
                 timeout: float = 120.0, max_attempts: int = 5, backoff: float = 1.0, backoff_max: float = 30.0,
                 concurrency: int = 4, cache_dir=None, client: ChatClient | None = None,
                 token_field: str = "max_completion_tokens", max_timeout_retries: int = 1,
                 max_requests: int | None = None):
        n_frames = self.default_frames if n_frames is None else n_frames
        if isinstance(n_frames, bool) or not isinstance(n_frames, int) or n_frames < 1:
            raise MetricInputError("n_frames", "value", "an integer >= 1", repr(n_frames))
        if max_side is not None and (isinstance(max_side, bool) or not isinstance(max_side, int) or max_side < 16):
            raise MetricInputError("max_side", "value", "an integer >= 16 (pixels) or None", repr(max_side))
        image_format = str(image_format).lower().replace("jpg", "jpeg")
        if image_format not in ("jpeg", "png"):
            raise MetricInputError("image_format", "value", '"jpeg" or "png"', repr(image_format))
        if isinstance(jpeg_quality, bool) or not isinstance(jpeg_quality, int) or not 1 <= jpeg_quality <= 100:
            raise MetricInputError("jpeg_quality", "value", "an integer in [1, 100]", repr(jpeg_quality))
        if isinstance(concurrency, bool) or not isinstance(concurrency, int) or concurrency < 1:
            raise MetricInputError("concurrency", "value", "an integer >= 1", repr(concurrency))
        self.client = client or ChatClient(base_url, model, api_key, timeout=timeout, max_attempts=max_attempts,
                                           backoff=backoff, backoff_max=backoff_max, temperature=temperature,
                                           max_tokens=max_tokens, extra_body=extra_body, token_field=token_field,
                                           max_timeout_retries=max_timeout_retries, max_requests=max_requests)
        self.n_frames, self.max_side = n_frames, max_side
        self.image_format, self.jpeg_quality = image_format, jpeg_quality
        self.concurrency = concurrency
        self.cache_dir = None if cache_dir is None else Path(cache_dir)
        if self.cache_dir is not None:
            try:
                self.cache_dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise MetricInputError(self.cache_dir, "cache_dir", "a writable folder",
                                       exc.strerror or str(exc)) from None
        self._hashes: dict = {}
        self._hash_lock = threading.Lock()

    @property
    def model(self) -> str:
        return self.client.model

    def settings(self) -> dict:
        """Frame and sampling settings (recorded in results; part of every cache key)."""
        return {"n_frames": self.n_frames, "max_side": self.max_side, "image_format": self.image_format,
                "jpeg_quality": self.jpeg_quality if self.image_format == "jpeg" else None,
                "sampling": self.client.sampling()}

    def describe(self) -> dict:
        """JSON-ready description of the judge (no API key)."""
        return {"base_url": self.client.base_url, "model": self.model, **self.settings(),
                "max_attempts": self.client.max_attempts, "timeout": self.client.timeout,
                "max_timeout_retries": self.client.max_timeout_retries, "max_requests": self.client.max_requests,
                "concurrency": self.concurrency, "cache_dir": None if self.cache_dir is None else str(self.cache_dir)}

    def _hash(self, video) -> str:
        if not isinstance(video, (str, os.PathLike)):
            return _content_hash(video)
        p = Path(video)
        try:
            st = p.stat()
            memo = (str(p.resolve()), st.st_mtime_ns, st.st_size)
        except OSError:
            memo = None
        with self._hash_lock:
            if memo is not None and memo in self._hashes:
                return self._hashes[memo]
        value = _content_hash(video)
        if memo is not None:
            with self._hash_lock:
                self._hashes[memo] = value
        return value

    def _frames(self, video, source: str) -> tuple[list[np.ndarray], int]:
        arr = _load_frames(video, source)
        idx = sample_frame_indices(len(arr), self.n_frames)
        return [_fit(arr[i], self.max_side) for i in idx], len(arr)

    def _run(self, items: Sequence, work, desc: str, progress: bool) -> list:
        results: list = [None] * len(items)
        bar = _progress(len(items), progress, desc)
        pool = ThreadPoolExecutor(max_workers=min(self.concurrency, max(1, len(items))),
                                  thread_name_prefix="oscar-judge")
        try:
            futures = {pool.submit(work, item): k for k, item in enumerate(items)}
            for fut in as_completed(futures):
                results[futures[fut]] = fut.result()  # work() never raises for a per-item problem
                if bar is not None:
                    bar.update(1)
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)  # e.g. Ctrl-C: drop the queued items
            raise
        finally:
            if bar is not None:
                bar.close()
        pool.shutdown()
        return results


class SuccessJudge(_BaseJudge):
    """Asks a VLM whether each rollout completed its instruction (the paper's "VLM success scoring").

    Keyword arguments (all optional): ``base_url``, ``model``, ``api_key``
    (else ``$OSCAR_JUDGE_*``); ``n_frames`` (32), ``max_side`` (512 px; None =
    native size), ``image_format`` ("jpeg" or "png"), ``jpeg_quality`` (90);
    ``temperature``, ``max_tokens``, ``extra_body`` (request fields, see
    :class:`ChatClient`); ``timeout`` (120 s), ``max_attempts`` (5),
    ``backoff`` (1 s), ``backoff_max`` (30 s); ``concurrency`` (4);
    ``cache_dir`` (None = no cache); ``client``: a ready :class:`ChatClient`
    instead of the endpoint arguments.

    >>> judge = SuccessJudge(base_url="http://127.0.0.1:8000/v1", model="Qwen/Qwen2.5-VL-7B-Instruct",
    ...                      cache_dir=".judge_cache")                                    # doctest: +SKIP
    >>> verdicts = judge.judge_many([JudgeClip("s1/pi0", "s1/pi0.mp4", "put the cup in the bowl")])  # doctest: +SKIP
    """

    def __init__(self, *, prompt: str = "paper", **kwargs):
        super().__init__(**kwargs)
        if prompt == "paper":
            self.system_prompt, self.user_prompt = None, PAPER_SUCCESS_PROMPT
        elif prompt == "oscar":
            self.system_prompt, self.user_prompt = SUCCESS_SYSTEM_PROMPT, SUCCESS_USER_PROMPT
        elif isinstance(prompt, str) and "{instruction}" in prompt:
            self.system_prompt, self.user_prompt = None, prompt
        else:
            raise MetricInputError("prompt", "value", '"paper", "oscar" or a template containing {instruction} '
                                   "(and optionally {n_frames})", repr(prompt)[:80])
        self.prompt = prompt if prompt in SUCCESS_PROMPTS else "custom"

    def settings(self) -> dict:
        return {**super().settings(), "prompt": self.prompt}

    def messages(self, instruction: str, images: Sequence[str]) -> list:
        """The chat messages for one clip: (system prompt,) then the user text followed by the images.

        Templates are filled with ``str.replace`` of ``{instruction}`` and ``{n_frames}``.
        """
        user = self.user_prompt.replace("{instruction}", instruction.strip()).replace("{n_frames}", str(len(images)))
        msgs = [] if self.system_prompt is None else [{"role": "system", "content": self.system_prompt}]
        return msgs + [{"role": "user", "content": [{"type": "text", "text": user}, *map(_image_part, images)]}]

    def plan(self, clips: Iterable[JudgeClip]) -> list[dict]:
        """What :meth:`judge_many` would send, without sending anything (``--dry-run``).

        One entry per clip: ``cached`` (True: the answer is in the cache, no
        request), the text parts, and the images (count, width × height,
        encoded bytes) of the request.
        """
        clips = [_check_clip(c, f"clips[{k}]") for k, c in enumerate(clips)]
        _check_unique([c.name for c in clips], "clips", "name")
        out = []
        for clip in clips:
            key = _key(self._cache_fields(self._hash(clip.video), clip.instruction))
            if _cache_read(self.cache_dir, key) is not None:
                out.append({"clip": clip.name, "cached": True, "cache_key": key})
                continue
            frames, total = self._frames(clip.video, clip.name)
            urls = [_encode_image(f, self.image_format, self.jpeg_quality) for f in frames]
            msgs = self.messages(clip.instruction, urls)
            texts = [m["content"] if isinstance(m["content"], str) else
                     "".join(p["text"] for p in m["content"] if p["type"] == "text") for m in msgs]
            out.append({"clip": clip.name, "cached": False, "model": self.model, "texts": texts,
                        "images": len(urls), "frames_total": total,
                        "image_size": [int(frames[0].shape[1]), int(frames[0].shape[0])],
                        "image_bytes": sum(len(u) for u in urls), "sampling": self.client.sampling()})
        return out

    def _cache_fields(self, content_hash: str, instruction: str) -> dict:
        # the prompt templates, the instruction, the video content and the settings determine the request
        # exactly (the frame count in the text is min(n_frames, T), a function of the content), so a cache
        # hit needs no decoding
        return {"v": CACHE_VERSION, "kind": "success", "video": content_hash, "model": self.model,
                "system": self.system_prompt, "user": self.user_prompt, "instruction": instruction.strip(),
                "settings": self.settings()}

    def judge(self, clip: JudgeClip) -> SuccessVerdict:
        """Judge one clip; never raises for a per-clip problem (it becomes an "error" verdict)."""
        _check_clip(clip, "clip")
        return self._judge(clip)

    def judge_many(self, clips: Iterable[JudgeClip], *, progress: bool = False) -> list[SuccessVerdict]:
        """Judge every clip (``concurrency`` at a time); one verdict per clip, in input order.

        Raises :class:`MetricInputError` before any request for bad input: a
        duplicate clip name, an empty instruction, a missing video path.
        """
        clips = [_check_clip(c, f"clips[{k}]") for k, c in enumerate(clips)]
        _check_unique([c.name for c in clips], "clips", "name")
        return self._run(clips, self._judge, "judging", progress)

    def _verdict(self, clip: JudgeClip, **kw) -> SuccessVerdict:
        return SuccessVerdict(clip=clip.name, policy=clip.policy_name, session=clip.session,
                              instruction=clip.instruction, model=self.model, **kw)

    def _judge(self, clip: JudgeClip) -> SuccessVerdict:
        base: dict = {}
        try:
            key = _key(self._cache_fields(self._hash(clip.video), clip.instruction))
            base = {"cache_key": key}
            entry = _cache_read(self.cache_dir, key)
            if entry is not None:
                base.update(frames_total=entry.get("frames_total"), frames_sent=entry.get("frames_sent"),
                            usage=entry.get("usage"))
                return self._from_answer(clip, entry["answer"], base, attempts=0, cached=True, errors=())
            frames, total = self._frames(clip.video, clip.name)
            base.update(frames_total=total, frames_sent=len(frames))
            images = [_encode_image(f, self.image_format, self.jpeg_quality) for f in frames]
            try:
                answer, attempts, errors, usage = self.client.complete(self.messages(clip.instruction, images))
            except JudgeRequestError as exc:
                return self._verdict(clip, status="error", error=str(exc), raw=exc.raw, attempts=exc.attempts,
                                     attempt_errors=exc.attempt_errors, **base)
            _cache_write(self.cache_dir, key, {"key": key, "kind": "success", "model": self.model,
                                               "clip": clip.name, "instruction": clip.instruction,
                                               "frames_total": total, "frames_sent": len(frames),
                                               "settings": self.settings(), "answer": answer, "usage": usage,
                                               "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")})
            base["usage"] = usage
            return self._from_answer(clip, answer, base, attempts=attempts, cached=False, errors=errors)
        except Exception as exc:  # noqa: BLE001 - one bad clip must not stop the run
            return self._verdict(clip, status="error", error=f"{type(exc).__name__}: {exc}", **base)

    def _from_answer(self, clip, answer, base, *, attempts, cached, errors) -> SuccessVerdict:
        try:
            parsed = parse_success_answer(answer if answer is not None else "")
        except MalformedAnswer as exc:
            msg = "the model returned no text" if answer is None else str(exc)
            return self._verdict(clip, status="malformed", raw=answer, error=f"malformed answer: {msg}",
                                 attempts=attempts, cached=cached, attempt_errors=tuple(errors), **base)
        return self._verdict(clip, status="ok", raw=answer, attempts=attempts, cached=cached,
                             attempt_errors=tuple(errors), **parsed, **base)


def _sum_usage(usages) -> dict | None:
    usages = [u for u in usages if u]
    if not usages:
        return None
    return {k: sum(u.get(k, 0) for u in usages) for k in ("prompt_tokens", "completion_tokens", "total_tokens")}


def _swap(seed, pair_id: str) -> bool:
    """Whether ``pair_id`` shows ``b`` first: one bit of SHA-256(seed, pair id) — stable under reordering."""
    return bool(hashlib.sha256(f"{seed}\0{pair_id}".encode()).digest()[0] & 1)


class PairwiseJudge(_BaseJudge):
    """Asks a VLM which of two rollouts of the same task is better (the paper's pairwise preferences).

    Arguments as :class:`SuccessJudge` (``n_frames`` defaults to 16 *per
    rollout*), plus ``seed`` and ``layout``:

    * ``seed`` — which rollout is shown first ("A") is drawn per pair from
      SHA-256(seed, pair id), so about half of the pairs are shown swapped,
      the choice does not depend on the order or number of pairs, and a rerun
      with the same seed asks the same questions (and hits the cache). The
      model's "A"/"B" is mapped back to the real ``a``/``b`` of the pair.
    * ``layout`` — ``"sets"`` (default): all frames of A, then all of B, each
      set after a text label; ``"side_by_side"``: one image per time step with
      A on the left and B on the right, split by an 8-px grey bar (each half
      fitted to ``max_side`` first, B scaled to A's height). Two rollouts of
      different lengths are each sampled to ``n_frames`` (or all their
      frames); side by side, both are cut to the shorter count.
    """

    default_frames = DEFAULT_PAIRWISE_FRAMES
    system_prompt = PAIRWISE_SYSTEM_PROMPT
    user_prompt = PAIRWISE_USER_PROMPT
    set_labels = PAIRWISE_SETS_LABELS
    side_by_side_note = PAIRWISE_SIDE_BY_SIDE_NOTE

    def __init__(self, *, seed: int = 0, layout: str = "sets", both_orders: bool = False, **kwargs):
        super().__init__(**kwargs)
        if layout not in ("sets", "side_by_side"):
            raise MetricInputError("layout", "value", '"sets" or "side_by_side"', repr(layout))
        self.seed, self.layout, self.both_orders = seed, layout, bool(both_orders)

    def settings(self) -> dict:
        return {**super().settings(), "layout": self.layout}

    def describe(self) -> dict:
        return {**super().describe(), "seed": self.seed, "both_orders": self.both_orders}

    def swapped(self, pair: JudgePair) -> bool:
        """True if ``pair.b`` is shown as "A" (see ``seed``)."""
        return _swap(self.seed, pair.id)

    def _texts(self, instruction: str, n_first: int, n_second: int) -> list[str]:
        texts = [self.user_prompt.format(instruction=instruction.strip(), n_frames=n_first)]
        if self.layout == "sets":
            texts += [self.set_labels[0].format(n_frames=n_first), self.set_labels[1].format(n_frames=n_second)]
        else:
            texts.append(self.side_by_side_note.format(n_frames=n_first))
        return texts

    def messages(self, instruction: str, first: Sequence[str], second: Sequence[str] = ()) -> list:
        """Chat messages: ``first`` / ``second`` are the image URLs shown as A / B ("sets"), or ``first`` the
        composite images ("side_by_side")."""
        texts = self._texts(instruction, len(first), len(second))
        parts = [{"type": "text", "text": texts[0]}]
        if self.layout == "sets":
            parts += [{"type": "text", "text": texts[1]}, *map(_image_part, first),
                      {"type": "text", "text": texts[2]}, *map(_image_part, second)]
        else:
            parts += [{"type": "text", "text": texts[1]}, *map(_image_part, first)]
        return [{"role": "system", "content": self.system_prompt}, {"role": "user", "content": parts}]

    def compare(self, pair: JudgePair) -> PairwiseVerdict:
        """Judge one pair; never raises for a per-pair problem."""
        self._check_pair(pair, "pair")
        return self._compare(pair)

    def compare_many(self, pairs: Iterable[JudgePair], *, progress: bool = False) -> list[PairwiseVerdict]:
        """Judge every pair (``concurrency`` at a time); one verdict per pair, in input order.

        Raises :class:`MetricInputError` before any request for bad input
        (duplicate pair ids, same policy on both sides, empty instruction, missing video).
        """
        pairs = list(pairs)
        for k, p in enumerate(pairs):
            self._check_pair(p, f"pairs[{k}]")
        _check_unique([p.id for p in pairs], "pairs", "id")
        return self._run(pairs, self._compare, "comparing", progress)

    @staticmethod
    def _check_pair(pair, source: str) -> None:
        if not isinstance(pair, JudgePair):
            raise MetricInputError(source, "type", "a JudgePair", type(pair).__name__)
        _check_clip(pair.a, f"{source}.a")
        _check_clip(pair.b, f"{source}.b")
        if pair.a.policy_name == pair.b.policy_name:
            raise MetricInputError(f"{source} ({pair.id})", "b", f"a policy other than {pair.a.policy_name!r}",
                                   repr(pair.b.policy_name))

    def _verdict(self, pair: JudgePair, swapped: bool, **kw) -> PairwiseVerdict:
        return PairwiseVerdict(pair=pair.id, a=pair.a.policy_name, b=pair.b.policy_name, clip_a=pair.a.name,
                               clip_b=pair.b.name, instruction=pair.a.instruction, swapped=swapped,
                               model=self.model, **kw)

    def _compare(self, pair: JudgePair) -> PairwiseVerdict:
        """One verdict; with ``both_orders`` the pair is asked as is and swapped, then reconciled:
        both valid and agreeing → that winner; both valid and disagreeing (position bias) → a tie; either
        not valid → that order's status (the pair gives no preference)."""
        if not self.both_orders:
            return self._compare_once(pair, self.swapped(pair))
        v1, v2 = self._compare_once(pair, False), self._compare_once(pair, True)
        both = dict(orders=(v1, v2), attempts=v1.attempts + v2.attempts, cached=v1.cached and v2.cached,
                    attempt_errors=v1.attempt_errors + v2.attempt_errors, swapped=False,
                    usage=_sum_usage([v1.usage, v2.usage]))
        bad = next((v for v in (v1, v2) if not v.ok), None)
        if bad is not None:
            return replace(bad, model_winner=None, winner=None, reason=None, **both)
        agree = v1.winner == v2.winner
        reason = v1.reason if agree else (f"the two orders disagree (as shown: {v1.winner}, swapped: {v2.winner}); "
                                          "counted as a tie")
        return replace(v1, model_winner=None, winner=v1.winner if agree else "tie", reason=reason,
                       orders_agree=agree, raw=None, cache_key=None, **both)

    def _compare_once(self, pair: JudgePair, swapped: bool) -> PairwiseVerdict:
        first, second = (pair.b, pair.a) if swapped else (pair.a, pair.b)
        base: dict = {}
        try:
            fields = {"v": CACHE_VERSION, "kind": "pairwise", "first": self._hash(first.video),
                      "second": self._hash(second.video), "model": self.model, "system": self.system_prompt,
                      "user": [self.user_prompt, *self.set_labels, self.side_by_side_note],
                      "instruction": pair.a.instruction.strip(), "settings": self.settings()}
            key = _key(fields)
            base = {"cache_key": key}
            entry = _cache_read(self.cache_dir, key)
            if entry is not None:
                sent = entry.get("frames_sent")
                base["frames_sent"] = tuple(sent) if isinstance(sent, list) else None
                base["usage"] = entry.get("usage")
                return self._from_answer(pair, swapped, entry["answer"], base, attempts=0, cached=True, errors=())
            f1, _ = self._frames(first.video, first.name)
            f2, _ = self._frames(second.video, second.name)
            if self.layout == "side_by_side":
                n = min(len(f1), len(f2))
                i1, i2 = sample_frame_indices(len(f1), n), sample_frame_indices(len(f2), n)
                f1 = [_side_by_side(f1[i], f2[j]) for i, j in zip(i1, i2)]
                f2 = []
                base["frames_sent"] = (n, n)
            else:
                base["frames_sent"] = (len(f1), len(f2))
            urls1 = [_encode_image(f, self.image_format, self.jpeg_quality) for f in f1]
            urls2 = [_encode_image(f, self.image_format, self.jpeg_quality) for f in f2]
            try:
                answer, attempts, errors, usage = self.client.complete(self.messages(pair.a.instruction, urls1, urls2))
            except JudgeRequestError as exc:
                return self._verdict(pair, swapped, status="error", error=str(exc), raw=exc.raw,
                                     attempts=exc.attempts, attempt_errors=exc.attempt_errors, **base)
            _cache_write(self.cache_dir, key, {"key": key, "kind": "pairwise", "model": self.model, "pair": pair.id,
                                               "shown_first": first.name, "shown_second": second.name,
                                               "instruction": pair.a.instruction,
                                               "frames_sent": list(base["frames_sent"]),
                                               "settings": self.settings(), "answer": answer, "usage": usage,
                                               "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")})
            base["usage"] = usage
            return self._from_answer(pair, swapped, answer, base, attempts=attempts, cached=False, errors=errors)
        except Exception as exc:  # noqa: BLE001 - one bad pair must not stop the run
            return self._verdict(pair, swapped, status="error", error=f"{type(exc).__name__}: {exc}", **base)

    def _from_answer(self, pair, swapped, answer, base, *, attempts, cached, errors) -> PairwiseVerdict:
        try:
            parsed = parse_pairwise_answer(answer if answer is not None else "")
        except MalformedAnswer as exc:
            msg = "the model returned no text" if answer is None else str(exc)
            return self._verdict(pair, swapped, status="malformed", raw=answer, error=f"malformed answer: {msg}",
                                 attempts=attempts, cached=cached, attempt_errors=tuple(errors), **base)
        shown = parsed["winner"]
        if shown == "tie":
            winner = "tie"
        else:
            winner = {"A": "b", "B": "a"}[shown] if swapped else {"A": "a", "B": "b"}[shown]
        return self._verdict(pair, swapped, status="ok", model_winner=shown, winner=winner, reason=parsed["reason"],
                             raw=answer, attempts=attempts, cached=cached, attempt_errors=tuple(errors), **base)
