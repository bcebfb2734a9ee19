"""VLM judges of rollouts: success per rollout and pairwise preferences within a session.

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
The judges sit on top: what both share (settings, video hashing, frame
sampling, worker loop) in :mod:`~oscar_core.metrics.judge_base`, the pairwise
judge in :mod:`~oscar_core.metrics.judge_pairwise`, and the success judge
here. This module re-exports every public name, so
``from oscar_core.metrics.judge import ...`` keeps working.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence

from .common import MetricInputError
from .judge_base import _BaseJudge
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
from .judge_frames import (  # _load_frames: importable from here as before
    DEFAULT_MAX_SIDE,
    _encode_image,
    _image_part,
    _load_frames as _load_frames,
    sample_frame_indices,
)
from .judge_pairwise import PairwiseJudge
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
