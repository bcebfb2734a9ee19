"""What the VLM judges of :mod:`oscar_core.metrics.judge` share: :class:`_BaseJudge` checks and holds the frame and
request settings (``n_frames`` sampled frames, ``max_side`` pixels, JPEG or PNG, the :class:`ChatClient`, the cache
folder), hashes videos by content (memoised per path, mtime and size), samples and fits their frames, and runs the work
on ``concurrency`` threads with an optional progress bar.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from .._util.log import progress_bars_enabled
from .common import MetricInputError
from .judge_client import ChatClient
from .judge_frames import DEFAULT_MAX_SIDE, _content_hash, _fit, _load_frames, sample_frame_indices
from .judge_prompts import DEFAULT_JUDGE_FRAMES

__all__: list[str] = []


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
