"""The chat-completions client of oscar's VLM judges: endpoint, retries, backoff, budget and the answer cache.

Endpoint
--------
``base_url`` (e.g. ``http://127.0.0.1:8000/v1`` or ``https://api.openai.com/v1``;
``/chat/completions`` is appended unless already there), ``model`` and an
optional ``api_key`` (sent as ``Authorization: Bearer``; a local vLLM server
needs none) come from the arguments, else from the environment variables
``OSCAR_JUDGE_BASE_URL``, ``OSCAR_JUDGE_MODEL`` and ``OSCAR_JUDGE_API_KEY``.
The key is never written to results, cache files or error messages.

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
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import random
import re
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from ..errors import OscarError
from .common import MetricInputError

__all__ = [
    "ENV_BASE_URL",
    "ENV_MODEL",
    "ENV_API_KEY",
    "CACHE_VERSION",
    "JudgeRequestError",
    "JudgeEndpointUnreachable",
    "ChatClient",
]

ENV_BASE_URL = "OSCAR_JUDGE_BASE_URL"
ENV_MODEL = "OSCAR_JUDGE_MODEL"
ENV_API_KEY = "OSCAR_JUDGE_API_KEY"

#: Cache-format version; part of every cache key.
CACHE_VERSION = 1
_RETRY_HTTP = frozenset({408, 429})


class JudgeEndpointUnreachable(OscarError, RuntimeError):
    """The endpoint refused every connection and never answered: a fault of the whole run, not of one clip.

    Raised by :meth:`ChatClient.complete` once ``max_attempts`` connections in a row have failed before any
    HTTP response came back; judges let it through (it is not a per-clip verdict), so ``oscar eval`` stops at
    once with a non-zero exit instead of spending every clip's retries on a server that is not there.
    """


class JudgeRequestError(RuntimeError):
    """No usable chat completion after all attempts (or a non-retryable failure).

    ``attempts``: requests sent; ``attempt_errors``: one short description per
    failed request; ``raw``: the last reply body, if any; ``retryable``: whether
    the last failure was of a retryable kind.
    """

    def __init__(
        self,
        message: str,
        *,
        attempts: int,
        attempt_errors: Sequence[str] = (),
        raw: str | None = None,
        retryable: bool = False,
    ):
        super().__init__(message)
        self.attempts = attempts
        self.attempt_errors = tuple(attempt_errors)
        self.raw = raw
        self.retryable = retryable


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
        raise MetricInputError(
            "base_url", "url", "an http:// or https:// URL such as http://127.0.0.1:8000/v1", repr(base_url)
        )
    return url if url.endswith("/chat/completions") else url + "/chat/completions"


def _retry_after(headers, now: float | None = None) -> float | None:
    """Seconds to wait from a ``Retry-After`` header: delay-seconds or an HTTP date (RFC 9110 §10.2.3).

    ``now``: the current time as a Unix timestamp (default: the clock). A date in the past waits 0 s;
    a missing or unreadable header gives None.
    """
    if headers is None:
        return None
    value = headers.get("Retry-After")
    if value is None:
        return None
    try:
        seconds = float(value)
    except ValueError:
        from email.utils import parsedate_to_datetime

        try:
            when = parsedate_to_datetime(value.strip())
        except (TypeError, ValueError, IndexError):
            return None
        if when is None:
            return None
        if when.tzinfo is None:  # HTTP dates are GMT; a date without a zone is read as such
            import datetime

            when = when.replace(tzinfo=datetime.timezone.utc)
        seconds = when.timestamp() - (time.time() if now is None else now)
    return max(0.0, seconds) if math.isfinite(seconds) else None


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
        raise ImportError(
            "oscar's VLM judges use the OpenAI Python SDK, which is not installed; install it with: "
            'pip install "oscar-wm[judge]"'
        ) from None
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

    def __init__(
        self,
        base_url: str | None = None,
        model: str | None = None,
        api_key: str | None = None,
        *,
        timeout: float = 120.0,
        max_attempts: int = 5,
        backoff: float = 1.0,
        backoff_max: float = 30.0,
        temperature: float | None = None,
        max_tokens: int | None = None,
        extra_body: Mapping | None = None,
        token_field: str = "max_completion_tokens",
        max_timeout_retries: int = 1,
        max_requests: int | None = None,
    ):
        self.base_url = _resolve(base_url, ENV_BASE_URL, "base URL", True)
        self.url = _chat_url(self.base_url)
        self.model = _resolve(model, ENV_MODEL, "model name", True)
        self._api_key = _resolve(api_key, ENV_API_KEY, "API key", False)
        for name, value, positive in (
            ("timeout", timeout, True),
            ("backoff", backoff, False),
            ("backoff_max", backoff_max, False),
        ):
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or not math.isfinite(value)
                or value < 0
                or (positive and value == 0)
            ):
                raise MetricInputError(
                    name, "value", "a number of seconds " + ("> 0" if positive else ">= 0"), repr(value)
                )
        for name, value, low in (("max_attempts", max_attempts, 1), ("max_timeout_retries", max_timeout_retries, 0)):
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise MetricInputError(name, "value", f"an integer >= {low}", repr(value))
        if max_requests is not None and (
            isinstance(max_requests, bool) or not isinstance(max_requests, int) or max_requests < 0
        ):
            raise MetricInputError("max_requests", "value", "an integer >= 0 or None", repr(max_requests))
        if max_tokens is not None and (
            isinstance(max_tokens, bool) or not isinstance(max_tokens, int) or max_tokens < 1
        ):
            raise MetricInputError("max_tokens", "value", "an integer >= 1 or None", repr(max_tokens))
        if token_field not in ("max_completion_tokens", "max_tokens"):
            raise MetricInputError("token_field", "value", '"max_completion_tokens" or "max_tokens"', repr(token_field))
        if extra_body is not None and not isinstance(extra_body, Mapping):
            raise MetricInputError("extra_body", "type", "a JSON object (mapping)", type(extra_body).__name__)
        reserved = sorted({"model", "messages"} & set(extra_body or {}))
        if reserved:
            raise MetricInputError("extra_body", "keys", "request fields other than 'model' and 'messages'", reserved)
        self.timeout, self.max_attempts = float(timeout), max_attempts
        self.backoff, self.backoff_max = float(backoff), float(backoff_max)
        self.temperature, self.max_tokens, self.token_field = temperature, max_tokens, token_field
        self.max_timeout_retries, self.max_requests = max_timeout_retries, max_requests
        self.extra_body = dict(extra_body or {})
        openai = _openai()
        sdk_base = self.url[: -len("/chat/completions")]
        self._sdk = openai.OpenAI(
            base_url=sdk_base, api_key=self._api_key or "no-key", timeout=self.timeout, max_retries=0
        )
        self._no_auth = None if self._api_key else {"Authorization": openai.Omit()}
        self._rng = random.Random()
        self._lock = threading.Lock()
        self.requests_sent = 0
        self.responses = 0  # HTTP responses of any status: the endpoint is there
        self._refused_in_a_row = 0
        self._unreachable: str | None = None
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

    def _answered(self) -> None:
        with self._lock:
            self.responses += 1
            self._refused_in_a_row = 0

    def _refused(self, cause: str) -> None:
        """Count a failed connection; after ``max_attempts`` in a row with no response ever, the endpoint is
        unreachable for the whole run (every later request fails at once)."""
        with self._lock:
            self._refused_in_a_row += 1
            if self.responses == 0 and self._refused_in_a_row >= self.max_attempts and self._unreachable is None:
                self._unreachable = (
                    f"the judge endpoint {self.url} refused all {self._refused_in_a_row} connections and never "
                    f"answered ({cause}); nothing was judged. Start the server, or point --judge-base-url / "
                    f"${ENV_BASE_URL} at a running one, then run the same command again"
                )
        if self._unreachable is not None:
            raise JudgeEndpointUnreachable(self._unreachable)

    def _send(self, messages: list) -> str:
        """One HTTP request through the SDK; returns the reply body's text (SDK exceptions propagate)."""
        raw = self._sdk.chat.completions.with_raw_response.create(
            model=self.model, messages=messages, extra_body=self.sampling() or None, extra_headers=self._no_auth
        )
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
            if self._unreachable is not None:
                raise JudgeEndpointUnreachable(self._unreachable)
            if not self._take_request():
                msg = f"request budget of {self.max_requests} requests spent (max_requests); not sent"
                errors.append(msg)
                raise JudgeRequestError(msg, attempts=attempt, attempt_errors=errors, retryable=False)
            attempt += 1
            retry_after = None
            try:
                text = self._send(messages)
            except openai.APIStatusError as exc:
                self._answered()
                try:
                    raw = self._redact(exc.response.text[:4000])
                except Exception:  # noqa: BLE001 - the body is informational only
                    raw = None
                code = exc.status_code
                retryable = code in _RETRY_HTTP or 500 <= code <= 599
                errors.append(f"HTTP {code}" + (f": {raw[:200]}" if raw else ""))
                retry_after = _retry_after(exc.response.headers)
            except openai.APITimeoutError:
                self._answered()  # connected: the server is there, only slow
                timeouts += 1
                errors.append(f"timeout: no complete response within {self.timeout:g} s")
                retryable = timeouts <= self.max_timeout_retries
                raw = None
                if not retryable:
                    raise JudgeRequestError(
                        f"request to {self.url} timed out {timeouts} time(s); not retried beyond "
                        f"max_timeout_retries={self.max_timeout_retries} (a timed-out request may still be billed)",
                        attempts=attempt,
                        attempt_errors=errors,
                        retryable=True,
                    ) from None
            except openai.APIConnectionError as exc:
                cause = exc.__cause__ or exc
                errors.append(f"connection: {type(cause).__name__}: {cause}")
                retryable = True
                raw = None
                self._refused(f"{type(cause).__name__}: {cause}")
            else:
                self._answered()
                text = self._redact(text)
                try:
                    body = json.loads(text)
                    content = _message_text(body)
                except (json.JSONDecodeError, ValueError) as exc:
                    msg = f"not an OpenAI chat completion from {self.url}: " + (
                        "the body is not JSON" if isinstance(exc, json.JSONDecodeError) else str(exc)
                    )
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
                raise JudgeRequestError(
                    f"request to {self.url} {what}: {errors[-1]}",
                    attempts=attempt,
                    attempt_errors=errors,
                    raw=raw,
                    retryable=retryable,
                )
            time.sleep(self._delay(attempt, retry_after))


def _usage(body: dict) -> dict | None:
    """``usage`` of a chat completion as ``{prompt_tokens, completion_tokens, total_tokens}`` (ints), or None."""
    u = body.get("usage") if isinstance(body, dict) else None
    if not isinstance(u, dict):
        return None
    out = {
        k: int(u[k])
        for k in ("prompt_tokens", "completion_tokens", "total_tokens")
        if isinstance(u.get(k), int) and not isinstance(u.get(k), bool)
    }
    return out or None


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
    from .._util.atomic import atomic_write_bytes

    atomic_write_bytes(cache_dir / f"{key}.json", (json.dumps(entry, indent=1, ensure_ascii=False) + "\n").encode())
