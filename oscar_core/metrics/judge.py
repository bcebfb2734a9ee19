"""VLM judges of rollouts: success per rollout and pairwise preferences within a session.

One module on purpose: both judges share the settings, video hashing, frame sampling and worker loop of
``_BaseJudge`` (their HTTP client is judge_client.py); it passed 600 lines only when the tree was formatted.

The OSCAR paper (Sec. "Policy Evaluation", Appendix "VLM success scoring")
scores every rollout with a vision-language model that stands in for a human
RoboArena rater: 32 frames sampled uniformly from the generated video go to
the model in temporal order together with the task instruction, and the model
returns one JSON object with a binary success flag, a partial-progress score
and a one-sentence reason. It also asks the model to compare the rollouts of
two policies from the same session, and fits Bradley–Terry scores to those
preferences. This module does both against **any OpenAI-compatible
chat-completions endpoint** (a local vLLM server, or a hosted API).

The parts live in their own modules, each documenting its rules:
:mod:`~oscar_core.metrics.judge_prompts` (prompts and strict answer parsing),
:mod:`~oscar_core.metrics.judge_frames` (frame sampling and encoding),
:mod:`~oscar_core.metrics.judge_client` (endpoint, retries, budget, cache) and
:mod:`~oscar_core.metrics.judge_records` (clips, pairs, verdicts, statuses).
This module holds the two judges on top and re-exports every public name, so
``from oscar_core.metrics.judge import ...`` keeps working.
"""

from __future__ import annotations

import hashlib
import os
import threading
import time
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import replace
from pathlib import Path

import numpy as np

from .._util.log import progress_bars_enabled
from .common import MetricInputError
from .judge_client import (
    CACHE_VERSION,
    ENV_API_KEY,
    ENV_BASE_URL,
    ENV_MODEL,
    ChatClient,
    JudgeEndpointUnreachable,
    JudgeRequestError,
    _cache_read,
    _cache_write,
    _key,
)
from .judge_frames import (
    DEFAULT_MAX_SIDE,
    _content_hash,
    _encode_image,
    _fit,
    _image_part,
    _load_frames,
    _side_by_side,
    sample_frame_indices,
)
from .judge_prompts import (
    DEFAULT_JUDGE_FRAMES,
    DEFAULT_PAIRWISE_FRAMES,
    PAIRWISE_SETS_LABELS,
    PAIRWISE_SIDE_BY_SIDE_NOTE,
    PAIRWISE_SYSTEM_PROMPT,
    PAIRWISE_USER_PROMPT,
    PAPER_SUCCESS_PROMPT,
    SUCCESS_PROMPTS,
    SUCCESS_SYSTEM_PROMPT,
    SUCCESS_USER_PROMPT,
    MalformedAnswer,
    parse_pairwise_answer,
    parse_success_answer,
)
from .judge_records import (
    JudgeClip,
    JudgePair,
    PairwiseVerdict,
    SuccessVerdict,
    _check_clip,
    _check_unique,
    pairs_by_session,
    preferences_from_verdicts,
    success_by_policy,
)

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
    "JudgeEndpointUnreachable",
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


# --------------------------------------------------------------------------- #
# the judges
# --------------------------------------------------------------------------- #
def _progress(n: int, enabled: bool, desc: str):
    if not (enabled and progress_bars_enabled()):
        return None
    from tqdm import tqdm

    return tqdm(total=n, desc=desc, unit="clip")


class _BaseJudge:
    default_frames = DEFAULT_JUDGE_FRAMES

    def __init__(
        self,
        *,
        base_url=None,
        model=None,
        api_key=None,
        n_frames: int | None = None,
        max_side: int | None = DEFAULT_MAX_SIDE,
        image_format: str = "jpeg",
        jpeg_quality: int = 90,
        temperature: float | None = None,
        max_tokens: int | None = None,
        extra_body: Mapping | None = None,
        timeout: float = 120.0,
        max_attempts: int = 5,
        backoff: float = 1.0,
        backoff_max: float = 30.0,
        concurrency: int = 4,
        cache_dir=None,
        client: ChatClient | None = None,
        token_field: str = "max_completion_tokens",
        max_timeout_retries: int = 1,
        max_requests: int | None = None,
    ):
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
        self.client = client or ChatClient(
            base_url,
            model,
            api_key,
            timeout=timeout,
            max_attempts=max_attempts,
            backoff=backoff,
            backoff_max=backoff_max,
            temperature=temperature,
            max_tokens=max_tokens,
            extra_body=extra_body,
            token_field=token_field,
            max_timeout_retries=max_timeout_retries,
            max_requests=max_requests,
        )
        self.n_frames, self.max_side = n_frames, max_side
        self.image_format, self.jpeg_quality = image_format, jpeg_quality
        self.concurrency = concurrency
        self.cache_dir = None if cache_dir is None else Path(cache_dir)
        if self.cache_dir is not None:
            try:
                self.cache_dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise MetricInputError(
                    self.cache_dir, "cache_dir", "a writable folder", exc.strerror or str(exc)
                ) from None
        self._hashes: dict = {}
        self._hash_lock = threading.Lock()

    @property
    def model(self) -> str:
        return self.client.model

    def settings(self) -> dict:
        """Frame and sampling settings (recorded in results; part of every cache key)."""
        return {
            "n_frames": self.n_frames,
            "max_side": self.max_side,
            "image_format": self.image_format,
            "jpeg_quality": self.jpeg_quality if self.image_format == "jpeg" else None,
            "sampling": self.client.sampling(),
        }

    def describe(self) -> dict:
        """JSON-ready description of the judge (no API key)."""
        return {
            "base_url": self.client.base_url,
            "model": self.model,
            **self.settings(),
            "max_attempts": self.client.max_attempts,
            "timeout": self.client.timeout,
            "max_timeout_retries": self.client.max_timeout_retries,
            "max_requests": self.client.max_requests,
            "concurrency": self.concurrency,
            "cache_dir": None if self.cache_dir is None else str(self.cache_dir),
        }

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
        pool = ThreadPoolExecutor(
            max_workers=min(self.concurrency, max(1, len(items))), thread_name_prefix="oscar-judge"
        )
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
            raise MetricInputError(
                "prompt",
                "value",
                '"paper", "oscar" or a template containing {instruction} (and optionally {n_frames})',
                repr(prompt)[:80],
            )
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
            texts = [
                m["content"]
                if isinstance(m["content"], str)
                else "".join(p["text"] for p in m["content"] if p["type"] == "text")
                for m in msgs
            ]
            out.append(
                {
                    "clip": clip.name,
                    "cached": False,
                    "model": self.model,
                    "texts": texts,
                    "images": len(urls),
                    "frames_total": total,
                    "image_size": [int(frames[0].shape[1]), int(frames[0].shape[0])],
                    "image_bytes": sum(len(u) for u in urls),
                    "sampling": self.client.sampling(),
                }
            )
        return out

    def _cache_fields(self, content_hash: str, instruction: str) -> dict:
        # the prompt templates, the instruction, the video content and the settings determine the request
        # exactly (the frame count in the text is min(n_frames, T), a function of the content), so a cache
        # hit needs no decoding
        return {
            "v": CACHE_VERSION,
            "kind": "success",
            "video": content_hash,
            "model": self.model,
            "system": self.system_prompt,
            "user": self.user_prompt,
            "instruction": instruction.strip(),
            "settings": self.settings(),
        }

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
        return SuccessVerdict(
            clip=clip.name,
            policy=clip.policy_name,
            session=clip.session,
            instruction=clip.instruction,
            model=self.model,
            **kw,
        )

    def _judge(self, clip: JudgeClip) -> SuccessVerdict:
        base: dict = {}
        try:
            key = _key(self._cache_fields(self._hash(clip.video), clip.instruction))
            base = {"cache_key": key}
            entry = _cache_read(self.cache_dir, key)
            if entry is not None:
                base.update(
                    frames_total=entry.get("frames_total"),
                    frames_sent=entry.get("frames_sent"),
                    usage=entry.get("usage"),
                )
                return self._from_answer(clip, entry["answer"], base, attempts=0, cached=True, errors=())
            frames, total = self._frames(clip.video, clip.name)
            base.update(frames_total=total, frames_sent=len(frames))
            images = [_encode_image(f, self.image_format, self.jpeg_quality) for f in frames]
            try:
                answer, attempts, errors, usage = self.client.complete(self.messages(clip.instruction, images))
            except JudgeRequestError as exc:
                return self._verdict(
                    clip,
                    status="error",
                    error=str(exc),
                    raw=exc.raw,
                    attempts=exc.attempts,
                    attempt_errors=exc.attempt_errors,
                    **base,
                )
            _cache_write(
                self.cache_dir,
                key,
                {
                    "key": key,
                    "kind": "success",
                    "model": self.model,
                    "clip": clip.name,
                    "instruction": clip.instruction,
                    "frames_total": total,
                    "frames_sent": len(frames),
                    "settings": self.settings(),
                    "answer": answer,
                    "usage": usage,
                    "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                },
            )
            base["usage"] = usage
            return self._from_answer(clip, answer, base, attempts=attempts, cached=False, errors=errors)
        except JudgeEndpointUnreachable:
            raise  # the whole run's fault, not this clip's
        except Exception as exc:  # noqa: BLE001 - one bad clip must not stop the run
            return self._verdict(clip, status="error", error=f"{type(exc).__name__}: {exc}", **base)

    def _from_answer(self, clip, answer, base, *, attempts, cached, errors) -> SuccessVerdict:
        try:
            parsed = parse_success_answer(answer if answer is not None else "")
        except MalformedAnswer as exc:
            msg = "the model returned no text" if answer is None else str(exc)
            return self._verdict(
                clip,
                status="malformed",
                raw=answer,
                error=f"malformed answer: {msg}",
                attempts=attempts,
                cached=cached,
                attempt_errors=tuple(errors),
                **base,
            )
        return self._verdict(
            clip,
            status="ok",
            raw=answer,
            attempts=attempts,
            cached=cached,
            attempt_errors=tuple(errors),
            **parsed,
            **base,
        )


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
            parts += [
                {"type": "text", "text": texts[1]},
                *map(_image_part, first),
                {"type": "text", "text": texts[2]},
                *map(_image_part, second),
            ]
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
            raise MetricInputError(
                f"{source} ({pair.id})", "b", f"a policy other than {pair.a.policy_name!r}", repr(pair.b.policy_name)
            )

    def _verdict(self, pair: JudgePair, swapped: bool, **kw) -> PairwiseVerdict:
        return PairwiseVerdict(
            pair=pair.id,
            a=pair.a.policy_name,
            b=pair.b.policy_name,
            clip_a=pair.a.name,
            clip_b=pair.b.name,
            instruction=pair.a.instruction,
            swapped=swapped,
            model=self.model,
            **kw,
        )

    def _compare(self, pair: JudgePair) -> PairwiseVerdict:
        """One verdict; with ``both_orders`` the pair is asked as is and swapped, then reconciled:
        both valid and agreeing → that winner; both valid and disagreeing (position bias) → a tie; either
        not valid → that order's status (the pair gives no preference)."""
        if not self.both_orders:
            return self._compare_once(pair, self.swapped(pair))
        v1, v2 = self._compare_once(pair, False), self._compare_once(pair, True)
        both = dict(
            orders=(v1, v2),
            attempts=v1.attempts + v2.attempts,
            cached=v1.cached and v2.cached,
            attempt_errors=v1.attempt_errors + v2.attempt_errors,
            swapped=False,
            usage=_sum_usage([v1.usage, v2.usage]),
        )
        bad = next((v for v in (v1, v2) if not v.ok), None)
        if bad is not None:
            return replace(bad, model_winner=None, winner=None, reason=None, **both)
        agree = v1.winner == v2.winner
        reason = (
            v1.reason
            if agree
            else (f"the two orders disagree (as shown: {v1.winner}, swapped: {v2.winner}); counted as a tie")
        )
        return replace(
            v1,
            model_winner=None,
            winner=v1.winner if agree else "tie",
            reason=reason,
            orders_agree=agree,
            raw=None,
            cache_key=None,
            **both,
        )

    def _compare_once(self, pair: JudgePair, swapped: bool) -> PairwiseVerdict:
        first, second = (pair.b, pair.a) if swapped else (pair.a, pair.b)
        base: dict = {}
        try:
            fields = {
                "v": CACHE_VERSION,
                "kind": "pairwise",
                "first": self._hash(first.video),
                "second": self._hash(second.video),
                "model": self.model,
                "system": self.system_prompt,
                "user": [self.user_prompt, *self.set_labels, self.side_by_side_note],
                "instruction": pair.a.instruction.strip(),
                "settings": self.settings(),
            }
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
                return self._verdict(
                    pair,
                    swapped,
                    status="error",
                    error=str(exc),
                    raw=exc.raw,
                    attempts=exc.attempts,
                    attempt_errors=exc.attempt_errors,
                    **base,
                )
            _cache_write(
                self.cache_dir,
                key,
                {
                    "key": key,
                    "kind": "pairwise",
                    "model": self.model,
                    "pair": pair.id,
                    "shown_first": first.name,
                    "shown_second": second.name,
                    "instruction": pair.a.instruction,
                    "frames_sent": list(base["frames_sent"]),
                    "settings": self.settings(),
                    "answer": answer,
                    "usage": usage,
                    "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                },
            )
            base["usage"] = usage
            return self._from_answer(pair, swapped, answer, base, attempts=attempts, cached=False, errors=errors)
        except JudgeEndpointUnreachable:
            raise  # the whole run's fault, not this pair's
        except Exception as exc:  # noqa: BLE001 - one bad pair must not stop the run
            return self._verdict(pair, swapped, status="error", error=f"{type(exc).__name__}: {exc}", **base)

    def _from_answer(self, pair, swapped, answer, base, *, attempts, cached, errors) -> PairwiseVerdict:
        try:
            parsed = parse_pairwise_answer(answer if answer is not None else "")
        except MalformedAnswer as exc:
            msg = "the model returned no text" if answer is None else str(exc)
            return self._verdict(
                pair,
                swapped,
                status="malformed",
                raw=answer,
                error=f"malformed answer: {msg}",
                attempts=attempts,
                cached=cached,
                attempt_errors=tuple(errors),
                **base,
            )
        shown = parsed["winner"]
        if shown == "tie":
            winner = "tie"
        else:
            winner = {"A": "b", "B": "a"}[shown] if swapped else {"A": "a", "B": "b"}[shown]
        return self._verdict(
            pair,
            swapped,
            status="ok",
            model_winner=shown,
            winner=winner,
            reason=parsed["reason"],
            raw=answer,
            attempts=attempts,
            cached=cached,
            attempt_errors=tuple(errors),
            **base,
        )
