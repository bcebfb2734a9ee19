"""The pairwise VLM judge: :class:`PairwiseJudge` asks a model which of two rollouts of the same task is better (the
paper's pairwise preferences), showing each pair in an order drawn from SHA-256(seed, pair id), optionally in both
orders, as two sets of frames or side by side; its verdicts feed the Bradley–Terry scores. Re-exported by
:mod:`oscar_core.metrics.judge`.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Iterable, Sequence
from dataclasses import replace

from .common import MetricInputError
from .judge_base import _BaseJudge
from .judge_client import CACHE_VERSION, JudgeEndpointUnreachable, JudgeRequestError, _cache_read, _cache_write, _key
from .judge_frames import _encode_image, _image_part, _side_by_side, sample_frame_indices
from .judge_prompts import (
    DEFAULT_PAIRWISE_FRAMES,
    PAIRWISE_SETS_LABELS,
    PAIRWISE_SIDE_BY_SIDE_NOTE,
    PAIRWISE_SYSTEM_PROMPT,
    PAIRWISE_USER_PROMPT,
    MalformedAnswer,
    parse_pairwise_answer,
)
from .judge_records import JudgePair, PairwiseVerdict, _check_clip, _check_unique

__all__ = ["PairwiseJudge"]


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
