"""``caption``: captions from an OpenAI-compatible vision-language endpoint, cached, retried, within a request budget.

The paper captions every kept episode with Qwen3-VL-30B-A3B-Instruct served by
vLLM, with the system prompt of its appendix (:data:`SYSTEM_PROMPT`), from
frames sampled at 15 fps — 1–2 fps for DROID, whose episodes are about 5x
longer. Here: any endpoint that speaks the OpenAI chat-completions API
(``vllm serve Qwen/Qwen3-VL-30B-A3B-Instruct`` gives one at
``http://HOST:8000/v1``); the frames go as JPEG ``image_url`` parts of one
user message, in time order.

* Frames: ``fps`` (15) per second of episode; ``long_fps`` (2) for sources in
  ``long_sources`` (``droid``) or episodes longer than ``long_seconds``; at most
  ``max_frames``, resized to ``frame_width`` pixels wide.
* Cache: one JSON file per episode under ``RUN/caption/cache/``, keyed by the
  model, the prompt, the episode id, the frame indices, the frame width, JPEG
  quality, token limit and the cache format (:meth:`CaptionConfig.key_fields`);
  a re-run asks nothing it has asked before, and a changed setting never
  reuses an answer to another request.
* Retries: the OpenAI SDK's own (``max_retries`` with exponential back-off on
  connection errors, 408/409/429 and 5xx, honouring ``Retry-After``).
* Budget: at most ``budget`` episodes are sent per run (cached ones are free);
  the rest are ``deferred``: their shards stay unfinished and the next run
  captions them. An episode that still fails after the retries is ``failed``
  (its shard also stays unfinished).
* Endpoint down: before the first request of a run, :func:`check_endpoint`
  must get an answer within 10 s (``timeout`` if shorter); a refused
  connection or silence fails the whole stage with :class:`EndpointUnreachable`
  naming ``--endpoint``, and nothing is recorded.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
from dataclasses import asdict, dataclass, field

import numpy as np

from .._util.optional import require
from ..errors import OscarError
from . import _fs
from ._caption_prompt import SYSTEM_PROMPT
from ._episode import EPISODE_ERRORS, load_row, reason_of
from .manifest import is_alive

CACHE_FORMAT = 2  # 2: the key also holds jpeg_quality and max_tokens (1 had neither: such entries are not reused)

__all__ = [
    "SYSTEM_PROMPT",
    "CaptionConfig",
    "CaptionStage",
    "frame_indices",
    "cache_key",
    "plan_budget",
    "EndpointUnreachable",
    "check_endpoint",
]

USER_TEXT = "Describe this video."


class EmptyAnswer(RuntimeError):
    """The endpoint answered without a caption (counted as a failed request)."""


@dataclass(frozen=True)
class CaptionConfig:
    """Endpoint and sampling settings of ``oscar data caption``."""

    base_url: str  # e.g. http://localhost:8000/v1 (vLLM's OpenAI-compatible server)
    model: str  # e.g. Qwen/Qwen3-VL-30B-A3B-Instruct (the paper's)
    api_key_env: str = "OPENAI_API_KEY"  # environment variable holding the key ("EMPTY" when unset, as vLLM accepts)
    fps: float = 15.0  # frames per second of episode sent (paper)
    long_fps: float = 2.0  # for long episodes (paper: 1-2 fps for DROID)
    long_sources: tuple[str, ...] = ("droid",)  # sources always sampled at long_fps
    long_seconds: float = 60.0  # episodes longer than this use long_fps too
    max_frames: int = 256  # upper bound on frames per request (uniformly thinned)
    frame_width: int = 448  # pixels; frames are resized to this width (aspect kept)
    jpeg_quality: int = 90
    max_tokens: int = 300  # the prompt asks for 80-100 words
    max_retries: int = 4  # SDK retries per request
    timeout: float = 180.0  # seconds per request
    budget: int | None = None  # episodes sent per run (None: no limit)

    def key_fields(self) -> dict:
        """What a caption depends on (the cache key's fields besides episode, frames and prompt; the stage's
        fingerprint settings): model, frame sampling, frame size and JPEG quality, the answer's token limit, and
        the cache format. Not the endpoint URL, retries, timeout or budget (they change how, not what, is asked)."""
        return {
            "cache_format": CACHE_FORMAT,
            **{
                k: v
                for k, v in asdict(self).items()
                if k
                in (
                    "model",
                    "fps",
                    "long_fps",
                    "long_sources",
                    "long_seconds",
                    "max_frames",
                    "frame_width",
                    "jpeg_quality",
                    "max_tokens",
                )
            },
        }


class EndpointUnreachable(OscarError, ConnectionError):
    """The captioning endpoint refuses connections or never answers: the whole stage fails, nothing is recorded."""


def check_endpoint(base_url: str, seconds: float = 10.0) -> None:
    """:class:`EndpointUnreachable` unless ``GET {base_url}/models`` gets any HTTP answer within ``seconds`` in all.

    Any status counts as an answer (a server without ``/models`` still
    answers); a refused connection, a DNS failure or silence do not. Run
    before the first request, so a down endpoint fails the stage in seconds
    instead of every episode after its retries.
    """
    import threading

    import httpx

    url = base_url.rstrip("/") + "/models"
    got: dict = {}

    def get() -> None:
        try:
            got["status"] = httpx.get(url, timeout=seconds).status_code
        except Exception as exc:  # noqa: BLE001 - reported below
            got["error"] = f"{type(exc).__name__}: {exc}"

    t = threading.Thread(target=get, daemon=True, name="oscar-endpoint-check")
    t.start()
    t.join(seconds)
    if t.is_alive() or "error" in got:
        cause = f"no answer within {seconds:g} s" if t.is_alive() else got["error"][:200]
        raise EndpointUnreachable(
            f"--endpoint {base_url}: cannot reach the captioning endpoint ({cause}); start "
            "the server or fix --endpoint, then run the same command again (nothing was "
            "recorded; cached captions are kept)"
        )


def frame_indices(n_frames: int, fps: float, source: str, cfg: CaptionConfig) -> np.ndarray:
    """Episode frame numbers to send: every ``fps / rate`` frames (rate: cfg.fps or cfg.long_fps), at most max_frames."""
    long = source.split("_")[0] in cfg.long_sources or source in cfg.long_sources or n_frames / fps > cfg.long_seconds
    rate = min(cfg.long_fps if long else cfg.fps, fps)
    idx = np.unique(np.round(np.arange(0, n_frames, fps / rate)).astype(int).clip(0, n_frames - 1))
    if len(idx) > cfg.max_frames:
        idx = idx[np.unique(np.linspace(0, len(idx) - 1, cfg.max_frames).round().astype(int))]
    return idx


def cache_key(row: dict, idx: np.ndarray, cfg: CaptionConfig) -> str:
    blob = json.dumps(
        {
            "id": row["id"],
            "frames": idx.tolist(),
            "prompt": hashlib.sha256(SYSTEM_PROMPT.encode()).hexdigest(),
            **cfg.key_fields(),
        },
        sort_keys=True,
    )
    return hashlib.sha256(blob.encode()).hexdigest()


def _cache_url(cache: str, key: str) -> str:
    return _fs.join(cache, key[:2], f"{key}.json")


def plan_budget(rows: list[dict], cfg: CaptionConfig, cache: str) -> frozenset[str]:
    """Ids of the live, uncached episodes allowed a request this run (the first ``budget`` in id order)."""
    want = []
    for r in rows:
        if not is_alive(r):
            continue
        idx = frame_indices(int(r["length"]), float(r["fps"]), r["source"], cfg)
        if not _fs.exists(_cache_url(cache, cache_key(r, idx, cfg))):
            want.append(r["id"])
    return frozenset(want if cfg.budget is None else want[: max(0, cfg.budget)])


def _jpeg_url(frame: np.ndarray, width: int, quality: int) -> str:
    import cv2

    h, w = frame.shape[:2]
    if w > width:
        frame = cv2.resize(frame, (width, max(2, round(h * width / w))), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", frame[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover
        raise ValueError("JPEG encoding failed")
    return "data:image/jpeg;base64," + base64.b64encode(buf.tobytes()).decode()


@dataclass(frozen=True)
class CaptionStage:
    """Sharded stage: ``caption`` and ``caption_*`` columns per live row."""

    config: CaptionConfig
    cache: str
    allowed: frozenset[str] = field(default_factory=frozenset)
    plugin_paths: tuple[str, ...] = ()
    name: str = "caption"

    @staticmethod
    def shard_complete(rows: list[dict]) -> bool:
        return not any(r.get("caption_status") in ("deferred", "failed") for r in rows)

    def __call__(self, rows: list[dict], shard: str = "") -> list[dict]:
        client = None
        out = []
        for r in rows:
            if not is_alive(r):
                out.append(r)
                continue
            o = dict(r, caption_status="ok", caption_reason=None, caption_value=None, caption=None)
            idx = frame_indices(int(r["length"]), float(r["fps"]), r["source"], self.config)
            url = _cache_url(self.cache, cache_key(r, idx, self.config))
            o["caption_value"] = float(len(idx))
            if _fs.exists(url):
                o["caption"] = json.loads(_fs.read_bytes(url))["caption"]
            elif r["id"] not in self.allowed:
                o.update(caption_status="deferred", caption_reason="deferred: request budget spent")
            else:
                if client is None:
                    client = self._client()
                try:
                    text = self._request(client, r, idx)
                except EmptyAnswer as exc:
                    o.update(caption_status="failed", caption_reason=f"failed: {exc}")
                except EPISODE_ERRORS as exc:
                    o.update(caption_status="rejected", caption_reason=f"unreadable: {reason_of(exc)}")
                except Exception as exc:  # the endpoint failed after the SDK's retries: try again next run
                    if type(exc).__module__.split(".")[0] != "openai":
                        raise
                    o.update(caption_status="failed", caption_reason=f"failed: {reason_of(exc)}")
                else:
                    o["caption"] = text
                    _fs.write_bytes_atomic(
                        url,
                        json.dumps(
                            {"id": r["id"], "caption": text, "model": self.config.model, "frames": idx.tolist()}
                        ).encode(),
                    )
            out.append(o)
        return out

    def _client(self):
        openai = require("openai", "data")
        return openai.OpenAI(
            base_url=self.config.base_url,
            api_key=os.environ.get(self.config.api_key_env) or "EMPTY",
            max_retries=self.config.max_retries,
            timeout=self.config.timeout,
        )

    def _request(self, client, row: dict, idx: np.ndarray) -> str:
        ep, _ = load_row(row, self.plugin_paths)
        frames = ep.video.read(idx)
        cfg = self.config
        content = [{"type": "text", "text": USER_TEXT}]
        content += [
            {"type": "image_url", "image_url": {"url": _jpeg_url(f, cfg.frame_width, cfg.jpeg_quality)}} for f in frames
        ]
        resp = client.chat.completions.create(
            model=cfg.model,
            max_tokens=cfg.max_tokens,
            messages=[{"role": "system", "content": SYSTEM_PROMPT}, {"role": "user", "content": content}],
        )
        text = (resp.choices[0].message.content or "").strip() if resp.choices else ""
        if not text:
            raise EmptyAnswer(f"{cfg.base_url}: expected a caption for {row['id']!r}, found an empty answer")
        return text
