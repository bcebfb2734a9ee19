"""Programmatic judges: success and preference computed by a function of the video.

A judge is anything with the two methods the evaluation loop calls:

* ``judge_many(clips) -> list[SuccessVerdict]`` — one verdict per
  :class:`~oscar_core.metrics.judge.JudgeClip`, in input order;
* ``compare_many(pairs) -> list[PairwiseVerdict]`` — one verdict per
  :class:`~oscar_core.metrics.judge.JudgePair` (optional: a judge without it
  gives no preferences);

and ``describe() -> dict`` (JSON-ready; it identifies the judge in results
and resume records, so it must change whenever the verdicts could). The VLM
judges (:class:`~oscar_core.metrics.judge.SuccessJudge`,
:class:`~oscar_core.metrics.judge.PairwiseJudge`) and
:class:`ProgrammaticJudge` all fit.

:class:`ProgrammaticJudge` wraps a plain function::

    def cube_in_bin(video, clip):
        # video: (T, H, W, 3) uint8 RGB, the whole rollout; clip.info: the manifest cell's "info"
        x, y = locate_cube(video[-1])
        inside = in_box((x, y), clip.info["bin_box"])
        return {"binary": int(inside), "partial": 100 if inside else 0, "reason": f"cube at ({x}, {y})"}

    judge = ProgrammaticJudge(cube_in_bin, name="toy-cube-in-bin", version="1")

The function's answer obeys the VLM answer's rules (``binary`` the integer 0
or 1, ``partial`` an integer in [0, 100], ``reason`` a non-empty string; a
tuple ``(binary, partial, reason)`` is accepted too): anything else makes the
verdict ``"malformed"``, an exception makes it ``"error"`` — one bad clip
never stops a run. Pairwise preferences default to comparing the two clips'
``(binary, partial)``: the higher one wins, equal ones tie; ``compare=`` takes
a function ``(video_a, video_b, pair) -> "a" | "b" | "tie"`` instead.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence

import numpy as np

from .common import MetricInputError
from .judge import JudgeClip, JudgePair, PairwiseVerdict, SuccessVerdict, _check_clip, _check_unique, _load_frames

__all__ = ["ProgrammaticJudge", "check_verdict_fields"]


def check_verdict_fields(answer) -> dict:
    """A programmatic answer as ``{"binary", "partial", "reason"}``, or ValueError saying what is wrong."""
    if isinstance(answer, tuple) and len(answer) == 3:
        answer = dict(zip(("binary", "partial", "reason"), answer))
    if not isinstance(answer, Mapping):
        raise ValueError(f"expected a mapping with binary, partial, reason, found {type(answer).__name__}")
    keys = sorted(answer)
    if keys != ["binary", "partial", "reason"]:
        raise ValueError(f"expected exactly the keys ['binary', 'partial', 'reason'], found {keys}")
    binary, partial, reason = answer["binary"], answer["partial"], answer["reason"]
    if isinstance(binary, (bool, np.bool_)) or not isinstance(binary, (int, np.integer)) or binary not in (0, 1):
        raise ValueError(f"'binary': expected the integer 0 or 1, found {binary!r}")
    if isinstance(partial, (bool, np.bool_)) or not isinstance(partial, (int, np.integer)) or not 0 <= partial <= 100:
        raise ValueError(f"'partial': expected an integer in [0, 100], found {partial!r}")
    if not isinstance(reason, str) or not reason.strip():
        raise ValueError(f"'reason': expected a non-empty string, found {reason!r}")
    return {"binary": int(binary), "partial": int(partial), "reason": reason.strip()}


class ProgrammaticJudge:
    """Success verdicts (and preferences) from a function of the video; see the module docstring.

    fn: ``(video (T, H, W, 3) uint8, clip: JudgeClip) -> {"binary", "partial", "reason"}``.
    name: identifies the judge in results (default: the function's qualified name).
    version: bump it when the function changes, so stored verdicts are not reused.
    compare: optional ``(video_a, video_b, pair) -> "a" | "b" | "tie"``.
    """

    kind = "programmatic"

    def __init__(self, fn: Callable, *, name: str | None = None, version: str = "1", compare: Callable | None = None):
        if not callable(fn):
            raise MetricInputError("fn", "type", "a function (video, clip) -> verdict", type(fn).__name__)
        if compare is not None and not callable(compare):
            raise MetricInputError(
                "compare", "type", "a function (video_a, video_b, pair) -> 'a'|'b'|'tie'", type(compare).__name__
            )
        self.fn, self.compare_fn = fn, compare
        self.name = name or f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', repr(fn))}"
        self.version = str(version)
        self.model = f"programmatic:{self.name}"

    def describe(self) -> dict:
        return {
            "kind": self.kind,
            "name": self.name,
            "version": self.version,
            "compare": None if self.compare_fn is None else getattr(self.compare_fn, "__qualname__", "custom"),
        }

    # ------------------------------------------------------------------ success
    def judge(self, clip: JudgeClip) -> SuccessVerdict:
        """One verdict; never raises for a problem of this clip."""
        _check_clip(clip, "clip")
        return self._judge(clip)

    def judge_many(self, clips: Iterable[JudgeClip], *, progress: bool = False) -> list[SuccessVerdict]:
        """One verdict per clip, in input order (``progress`` is accepted for interface parity)."""
        clips = [_check_clip(c, f"clips[{k}]") for k, c in enumerate(clips)]
        _check_unique([c.name for c in clips], "clips", "name")
        return [self._judge(c) for c in clips]

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
        try:
            video = _load_frames(clip.video, clip.name)
            answer = self.fn(video, clip)
        except Exception as exc:  # noqa: BLE001 - one bad clip must not stop the run
            return self._verdict(clip, status="error", error=f"{type(exc).__name__}: {exc}")
        try:
            fields = check_verdict_fields(answer)
        except ValueError as exc:
            return self._verdict(
                clip,
                status="malformed",
                raw=repr(answer)[:2000],
                error=f"malformed answer: {exc}",
                frames_total=len(video),
            )
        return self._verdict(clip, status="ok", frames_total=len(video), frames_sent=len(video), **fields)

    # ------------------------------------------------------------------ pairwise
    def compare_many(
        self, pairs: Iterable[JudgePair], *, progress: bool = False, verdicts: Sequence[SuccessVerdict] | None = None
    ) -> list[PairwiseVerdict]:
        """One preference per pair, in input order.

        Default rule: the clip with the higher ``(binary, partial)`` wins, equal
        ones tie; a pair with a clip whose success verdict is not ``ok`` gets
        that verdict's status. ``verdicts`` (optional): success verdicts already
        computed for these clips (by clip name), so the function is not run twice.
        """
        pairs = list(pairs)
        for k, p in enumerate(pairs):
            if not isinstance(p, JudgePair):
                raise MetricInputError(f"pairs[{k}]", "type", "a JudgePair", type(p).__name__)
        _check_unique([p.id for p in pairs], "pairs", "id")
        known = {v.clip: v for v in (verdicts or ())}
        out = []
        for pair in pairs:
            base = dict(
                pair=pair.id,
                a=pair.a.policy_name,
                b=pair.b.policy_name,
                clip_a=pair.a.name,
                clip_b=pair.b.name,
                instruction=pair.a.instruction,
                swapped=False,
                model=self.model,
            )
            if self.compare_fn is not None:
                try:
                    winner = self.compare_fn(
                        _load_frames(pair.a.video, pair.a.name), _load_frames(pair.b.video, pair.b.name), pair
                    )
                except Exception as exc:  # noqa: BLE001
                    out.append(PairwiseVerdict(status="error", error=f"{type(exc).__name__}: {exc}", **base))
                    continue
                if winner not in ("a", "b", "tie"):
                    out.append(
                        PairwiseVerdict(
                            status="malformed",
                            raw=repr(winner)[:200],
                            error=f"malformed answer: expected 'a', 'b' or 'tie', found {winner!r}",
                            **base,
                        )
                    )
                    continue
                out.append(
                    PairwiseVerdict(
                        status="ok", winner=winner, model_winner=winner, reason="programmatic comparison", **base
                    )
                )
                continue
            va = known.get(pair.a.name) or self._judge(pair.a)
            vb = known.get(pair.b.name) or self._judge(pair.b)
            known[pair.a.name], known[pair.b.name] = va, vb
            bad = next((v for v in (va, vb) if not v.ok), None)
            if bad is not None:
                out.append(PairwiseVerdict(status=bad.status, error=f"{bad.clip}: {bad.error}", **base))
                continue
            sa, sb = (va.binary, va.partial), (vb.binary, vb.partial)
            winner = "a" if sa > sb else "b" if sb > sa else "tie"
            out.append(
                PairwiseVerdict(
                    status="ok", winner=winner, model_winner=winner, reason=f"(binary, partial) {sa} vs {sb}", **base
                )
            )
        return out
