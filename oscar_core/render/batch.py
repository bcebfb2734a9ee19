"""Render many episodes: one episode spec → one video file, mapped over a worker pool.

The episode specs and their readers (:class:`EpisodeSpec`, :func:`read_manifest`, :func:`specs_from_folder`) live in
:mod:`oscar_core.render.batch_specs` and are re-exported here.

The data pipeline and ``oscar render --manifest`` / ``--trajectories`` use this::

    from oscar_core.render.batch import EpisodeSpec, RenderOptions, render_episode, render_many

    render_episode(EpisodeSpec("franka", "t.npz", "cam.json", "out/t.mp4", size=(512, 288)))
    results = render_many(specs, RenderOptions(preset="veryfast"), workers=2, progress=True)

Each episode streams (FK, projection, rasterisation and encoding in chunks), so
memory does not grow with its length; each worker process loads the plugins
once and keeps the embodiments it has used. A failing episode is recorded in
its :class:`EpisodeResult` and the others go on.

Resuming: with ``resume=True``, after each rendered episode a record
``.<output name>.oscar-render.json`` is written beside the output with the episode's fingerprint — the sha256 of
its trajectory and camera files, its embodiment, size, fps, resize,
format and condition (skeleton, mesh or capsules) and its style when one is given, the encoder settings (preset, crf, yuv), strictness, FK device kind,
plugin paths and a format version (threads and chunk size are left out: they
do not change the frames). ``render_many(resume=True)`` (``oscar render``
batches by default; ``--no-resume`` redoes everything) skips an episode whose
output exists and whose record matches, and renders it again otherwise.
Worker processes come from a fork server (never a plain fork after threads
exist) and exit when the process that made the pool dies. As with spawn
(macOS, Windows, CUDA FK), each worker imports the calling script again as
``__mp_main__``: a script calling ``render_many(workers > 1)`` keeps its
top-level work under ``if __name__ == "__main__":``; an unguarded call raises
``MainGuardError`` naming the line before any work (``oscar_core._util.main_guard``).

A manifest (``read_manifest``) is JSONL or CSV; see docs/formats.md.
"""

from __future__ import annotations

import json
import os
import time
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

from .._util import stage as _stage
from ..errors import OscarError, OutputPathError
from .batch_specs import (  # MANIFEST_FIELDS, REQUIRED_FIELDS: importable from here as before
    MANIFEST_FIELDS as MANIFEST_FIELDS,
    REQUIRED_FIELDS as REQUIRED_FIELDS,
    EpisodeSpec,
    read_manifest,
    specs_from_folder,
)

__all__ = [
    "EpisodeResult",
    "EpisodeSpec",
    "RenderOptions",
    "read_manifest",
    "render_episode",
    "render_many",
    "specs_from_folder",
    "summarise",
]


@dataclass(frozen=True)
class RenderOptions:
    """How every episode is rendered and encoded.

    preset: x264 preset; crf: H.264 quality; yuv: "opencv" or "swscale" (see
    :class:`oscar_core.media.video.VideoWriter`); threads: encoder threads per episode
    (None: 1 with several workers, else automatic); strict: frames where the camera
    sees nothing of the robot are an error; chunk_frames: frames per streamed chunk;
    device: torch device for FK ("cpu" uses NumPy); plugin_paths: one-file plugins;
    condition: the condition video of episodes that do not name one ("skeleton", "mesh" or "capsules");
    condition_style: how a skeleton is drawn, a mapping of :class:`~oscar_core.render.raster.SkeletonStyle` fields
    (a model card's ``condition_style``; None: the standard look); an episode of another condition is refused.
    """

    preset: str | None = None
    crf: int = 18
    yuv: str | None = None
    threads: int | None = None
    strict: bool = False
    chunk_frames: int | None = None
    device: str = "cpu"
    plugin_paths: tuple[str, ...] = ()
    condition: str = "skeleton"
    condition_style: dict | None = None


@dataclass
class EpisodeResult:
    """What became of one episode: ``ok`` with ``out`` written, or ``error`` (a sentence)."""

    index: int
    spec: EpisodeSpec
    ok: bool
    out: str | None = None
    frames: int = 0
    width: int | None = None
    height: int | None = None
    fps: float | None = None
    seconds: float = 0.0
    error: str | None = None
    warnings: list[str] = field(default_factory=list)
    empty_frames: list[int] = field(default_factory=list)
    skipped: bool = False  # resumed: the output and its record matched this episode's fingerprint; not rendered again

    def to_dict(self) -> dict:
        d = asdict(self)
        d["spec"] = asdict(self.spec)
        d["seconds"] = round(self.seconds, 4)
        return d


# ------------------------------------------------------------------ one episode

_REGISTRIES: dict[tuple[str, ...], object] = {}


def _registry(plugin_paths: Sequence[str]):
    """One :class:`~oscar_core.plugin.registry.Registry` per process and plugin set (embodiments are cached in it)."""
    key = tuple(plugin_paths)
    if key not in _REGISTRIES:
        from ..plugin.registry import Registry

        _REGISTRIES[key] = Registry(plugin_paths=key, warn=False)
    return _REGISTRIES[key]


def render_episode(
    spec: EpisodeSpec, options: RenderOptions = RenderOptions(), *, registry=None, index: int = 0
) -> EpisodeResult:
    """Render ``spec`` to ``spec.out``, streaming; raises on any error (see :func:`render_many`).

    The output path, suffix and (for H.264) even size are checked before any
    rendering. Warnings (joint limits, an empty view) are caught and returned in
    the result, not printed. Returns an :class:`EpisodeResult` with ``ok=True``.
    """
    from ..kinematics.trajectory import load_trajectory
    from ..media.video import DEFAULT_PRESET, DEFAULT_YUV, VideoWriter, check_output
    from .conditions import check_condition, chunk_renderer, style_for
    from .renderer import DEFAULT_CHUNK_FRAMES, RenderStats

    t0 = time.perf_counter()
    condition = check_condition(spec.condition or options.condition, "condition")
    style = style_for(condition, options.condition_style)
    check_output(spec.out, format=spec.format)  # suffix and folder, before reading anything
    iter_chunks = chunk_renderer(condition)
    registry = registry if registry is not None else _registry(options.plugin_paths)
    emb = registry.get(spec.embodiment)
    traj = load_trajectory(spec.trajectory)
    cam = emb.load_camera(spec.camera)
    size = tuple(spec.size) if spec.size else (cam.intrinsics.width, cam.intrinsics.height)
    stats = RenderStats()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        writer = VideoWriter(
            spec.out,
            spec.fps or traj.fps,
            format=spec.format,
            crf=options.crf,
            preset=options.preset or DEFAULT_PRESET,
            yuv=options.yuv or DEFAULT_YUV,
            threads=0 if options.threads is None else options.threads,
            size=size,
        )
        with writer:
            for chunk in iter_chunks(
                emb,
                traj,
                cam,
                size,
                style=style,
                resize_mode=spec.resize,
                device=options.device,
                camera_source=str(spec.camera),
                strict=options.strict,
                stats=stats,
                chunk_frames=options.chunk_frames or DEFAULT_CHUNK_FRAMES,
            ):
                writer.write(chunk)
    seen, messages = set(), []
    for w in caught:
        text = f"{w.category.__name__}: {w.message}"
        if text not in seen:
            seen.add(text)
            messages.append(text)
    return EpisodeResult(
        index,
        spec,
        True,
        str(writer.path),
        writer.frames,
        size[0],
        size[1],
        spec.fps or traj.fps,
        time.perf_counter() - t0,
        None,
        messages,
        stats.empty_frames,
    )


def _safe_render(index: int, spec: EpisodeSpec, options: RenderOptions, registry=None) -> EpisodeResult:
    t0 = time.perf_counter()
    try:
        return render_episode(spec, options, registry=registry, index=index)
    except Exception as exc:  # noqa: BLE001 - one episode's failure, whatever it is, is recorded, not fatal
        text = str(exc) if isinstance(exc, OscarError) else f"{type(exc).__name__}: {exc}"
        return EpisodeResult(index, spec, False, seconds=time.perf_counter() - t0, error=text)


def _init_worker() -> None:
    from .._util.interrupt import worker_ignores_interrupt

    worker_ignores_interrupt()  # Ctrl-C: the parent stops the pool
    try:
        import cv2

        cv2.setNumThreads(1)
    except ImportError:  # pragma: no cover - cv2 is a dependency
        pass


# -------------------------------------------------------------------- resume


def record_path(spec: EpisodeSpec) -> Path:
    """The completion record of ``spec``'s output: ``.<name>.oscar-render.json`` beside it."""
    out = Path(spec.out.rstrip("/" + os.sep))
    return out.with_name(f".{out.name}.oscar-render.json")


def _file_sha256(path: str) -> str | None:
    import hashlib

    try:
        with open(path, "rb") as f:
            return hashlib.file_digest(f, "sha256").hexdigest()
    except OSError:
        return None


def episode_parts(spec: EpisodeSpec, options: RenderOptions) -> dict:
    """What ``spec``'s output depends on (its fingerprint parts; see the module docstring)."""
    return {
        "format_version": _stage.FORMAT_VERSION,
        "embodiment": spec.embodiment,
        "trajectory": _file_sha256(spec.trajectory),
        "camera": _file_sha256(spec.camera),
        "size": list(spec.size) if spec.size else None,
        "fps": spec.fps,
        "resize": spec.resize,
        "format": spec.format,
        "condition": spec.condition or options.condition,
        "preset": options.preset,
        "crf": options.crf,
        "yuv": options.yuv,
        "strict": options.strict,
        "device": str(options.device).split(":")[0],
        "plugin_paths": list(options.plugin_paths),
        # only when given, so records written before the option keep matching
        **({"condition_style": options.condition_style} if options.condition_style else {}),
    }


def _resumed(index: int, spec: EpisodeSpec, parts: dict) -> EpisodeResult | None:
    """The recorded result when ``spec``'s output exists and its record has this fingerprint, else None."""
    rec = record_path(spec)
    if not rec.is_file() or not Path(spec.out.rstrip("/" + os.sep)).exists():
        return None
    try:
        got = json.loads(rec.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(got, dict) or got.get("fingerprint") != _stage.fingerprint(parts):
        return None
    return EpisodeResult(
        index,
        spec,
        True,
        got.get("out"),
        int(got.get("frames", 0)),
        got.get("width"),
        got.get("height"),
        got.get("fps"),
        0.0,
        skipped=True,
    )


def _write_record(r: EpisodeResult, parts: dict) -> None:
    from .._util.atomic import atomic_write_bytes

    body = {
        "fingerprint": _stage.fingerprint(parts),
        "parts": parts,
        "out": r.out,
        "frames": r.frames,
        "width": r.width,
        "height": r.height,
        "fps": r.fps,
    }
    try:
        atomic_write_bytes(record_path(r.spec), json.dumps(body, indent=1).encode())
    except OSError:  # pragma: no cover - the video itself was written; a missing record only costs a re-render
        pass


# -------------------------------------------------------------------- many


def _prepare_outputs(specs: Sequence[EpisodeSpec]) -> None:
    """Before any rendering: distinct outputs, folders above them made (never through a file),
    and every output's suffix checked. (Whether each target may be replaced is
    checked per episode: that failure is the episode's alone.)"""
    from ..media.video import output_codec

    seen: dict[str, int] = {}
    for i, s in enumerate(specs):
        key = os.path.abspath(s.out.rstrip("/" + os.sep))
        if key in seen:
            raise OutputPathError(s.out, f"episode {i} writes the same output as episode {seen[key]}")
        seen[key] = i
        parent = Path(s.out.rstrip("/" + os.sep)).parent
        for p in (parent, *parent.parents):
            if p.exists():
                if not p.is_dir():
                    raise OutputPathError(s.out, f"{p} is a file, not a folder")
                break
        output_codec(s.out, format=s.format)
    for s in specs:  # only once every output passed
        parent = Path(s.out.rstrip("/" + os.sep)).parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputPathError(s.out, f"cannot make folder {parent}: {exc.strerror or exc}") from None


def _render_in_pool(specs, options: RenderOptions, todo: list[int], workers: int, done) -> None:
    """Renders the episodes ``todo`` (indices into ``specs``) in a pool of at most ``workers`` processes, handing
    each result to ``done`` as it completes; a worker that dies fails its episode only, Ctrl-C stops the pool."""
    from concurrent.futures import ProcessPoolExecutor, as_completed

    ctx = _pool_context(specs, options)
    with ProcessPoolExecutor(
        max_workers=min(workers, len(todo)),
        mp_context=ctx,
        initializer=_stage.worker_initializer,
        initargs=(os.getpid(), _init_worker),
    ) as pool:
        try:
            futures = {pool.submit(_safe_render, i, specs[i], options): i for i in todo}
            for fut in as_completed(futures):
                try:
                    done(fut.result())
                except Exception as exc:  # noqa: BLE001 - e.g. a worker killed by the OS (out of memory)
                    i = futures[fut]
                    done(EpisodeResult(i, specs[i], False, error=f"worker process failed: {type(exc).__name__}: {exc}"))
        except KeyboardInterrupt:  # stop now rather than render the rest of the queue first
            from .._util.interrupt import stop_pool

            stop_pool(pool)
            raise


def render_many(
    specs: Iterable[EpisodeSpec],
    options: RenderOptions = RenderOptions(),
    *,
    workers: int = 1,
    progress: bool | None = False,
    on_result: Callable[[EpisodeResult], None] | None = None,
    registry=None,
    resume: bool = False,
) -> list[EpisodeResult]:
    """Render every spec; returns one :class:`EpisodeResult` per spec, in input order.

    workers: processes (1: in this process, reusing ``registry`` if given).
    Several workers start once each (from a fork server with the renderer's
    modules imported; each loads the plugins once) and render many episodes
    each; each encoder then uses one thread unless ``options.threads`` says
    otherwise.
    progress: a progress bar on stderr (None: only when stderr is a terminal).
    on_result: called with each result as it completes (any order).
    Errors of one episode (bad input, unwritable output, a strict empty view)
    are recorded in its result; the others go on. Problems with the batch as a
    whole (two episodes writing the same output, an output under a file) raise
    :class:`OutputPathError` before anything is rendered, and so does a bad ``options.condition_style``
    (:class:`OscarError`).
    resume: skip an episode whose output and record match its fingerprint
    (its result has ``skipped=True``) and write each rendered episode's
    record (without ``resume`` no record is read or written).

    With workers > 1, a script must make this call under
    ``if __name__ == "__main__":``: every worker imports the script again
    (fork server and spawn), so a call at its top level would run once more
    in each worker. Such a call raises
    :class:`~oscar_core._util.main_guard.MainGuardError` (a RuntimeError naming
    the script and the line) before anything is rendered.
    """
    workers = max(1, int(workers))
    if workers > 1:
        from .._util.main_guard import check_main_guard

        check_main_guard(f"render_many(workers={workers})")
    specs = list(specs)
    if options.condition_style is not None:  # a bad style is the batch's fault, not each episode's
        from .conditions import condition_style

        condition_style(options.condition_style)
    _prepare_outputs(specs)
    if workers > 1 and options.threads is None:
        from dataclasses import replace

        options = replace(options, threads=1)
    results: list[EpisodeResult | None] = [None] * len(specs)
    from tqdm import tqdm

    bar = None

    parts = [episode_parts(s, options) for s in specs]

    def done(r: EpisodeResult) -> None:
        results[r.index] = r
        if resume and r.ok and not r.skipped:
            _write_record(r, parts[r.index])
        bar.update(1)
        if not r.ok:
            bar.set_postfix_str(f"{sum(1 for x in results if x is not None and not x.ok)} failed")
        if on_result is not None:
            on_result(r)

    def new_bar():
        return tqdm(
            total=len(specs), desc="rendering", unit="episode", disable=None if progress is None else not progress
        )

    todo = []
    for i, s in enumerate(specs):
        r = _resumed(i, s, parts[i]) if resume else None
        if r is None:
            todo.append(i)
        else:
            results[i] = r
    try:
        bar = new_bar()
        for r in results:
            if r is not None:
                bar.update(1)
                if on_result is not None:
                    on_result(r)
        if workers == 1 or len(todo) <= 1:
            if registry is None and todo:
                registry = _registry(options.plugin_paths)
            for i in todo:
                done(_safe_render(i, specs[i], options, registry))
        else:
            _render_in_pool(specs, options, todo, workers, done)
    finally:
        if bar is not None:
            bar.close()
    return [r for r in results if r is not None]


# modules a render worker needs: imported once by the fork server, inherited by every worker it forks
_PRELOAD = [
    "numpy",
    "av",
    "cv2",
    "oscar_core.render.batch",
    "oscar_core.plugin.registry",
    "oscar_core.render.skeleton_stream",
    "oscar_core.kinematics.trajectory",
    "oscar_core.media.video",
]


def _pool_context(specs: Sequence[EpisodeSpec], options: RenderOptions):
    """A fork server with the renderer's imports preloaded (spawn where there is none, and for CUDA FK).

    A plain ``fork`` after this process has threads (tqdm's monitor, torch's
    or OpenCV's pools) can copy a held lock into the child and hang it
    forever — it did, in a second pool made in the same process; a fork
    server is a clean single-threaded process, so pools can be made again and
    again. Each worker loads the plugins and embodiments it uses once (and,
    for ``--condition mesh``, reads and simplifies their meshes once).
    """
    import multiprocessing as mp

    if str(options.device).split(":")[0] != "cpu":
        return mp.get_context("spawn")
    return _stage.pool_context(_PRELOAD)


def summarise(results: Sequence[EpisodeResult], seconds: float) -> dict:
    """Counts, frames and rates of a batch; ``seconds`` is its wall time. ``ok`` includes the episodes skipped as
    unchanged (``skipped``); ``frames`` and the rates count only episodes rendered now."""
    ok = [r for r in results if r.ok]
    frames = sum(r.frames for r in ok if not r.skipped)  # frames rendered now: rates never count skipped work
    return {
        "episodes": len(results),
        "ok": len(ok),
        "failed": len(results) - len(ok),
        "skipped": sum(1 for r in ok if r.skipped),
        "frames": frames,
        "seconds": round(seconds, 3),
        "episodes_per_second": round(sum(1 for r in ok if not r.skipped) / seconds, 3) if seconds > 0 else None,
        "frames_per_second": round(frames / seconds, 1) if seconds > 0 else None,
        "warnings": sum(len(r.warnings) for r in results),
    }
