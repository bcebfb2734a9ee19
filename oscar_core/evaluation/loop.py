"""The policy-evaluation loop: manifest → rollouts → verdicts → fidelity report.

:func:`run_evaluation` does, for a :class:`~oscar_core.evaluation.manifest.Manifest`:

1. **Rollouts.** Every cell is rolled out with the world model from its first
   frame along the skeleton video of its trajectory (rendered from the
   embodiment plugin and the camera, fitted to the rollout size like
   ``oscar rollout`` does) and written losslessly to
   ``OUT/rollouts/<session>/<policy>.mkv``. A record
   ``OUT/cells/<session>/<policy>.json`` is written atomically after the video;
   its ``rollout_key`` is the SHA-256 of everything that determines the video
   (the model's identity, sampler settings, chunk length, size, seed, and the
   bytes of the first frame, trajectory, camera and prompt embedding). A
   re-run skips every cell whose record has the same key and whose video still
   has the recorded SHA-256 — so a killed run resumes where it stopped, and a
   changed input redoes exactly the cells it affects.
2. **Success verdicts** from a judge (``judge_many``): a VLM
   (:class:`~oscar_core.metrics.judge.SuccessJudge`) or a function of the
   video (:class:`~oscar_core.metrics.programmatic.ProgrammaticJudge`). An
   ``ok`` verdict is stored in the cell's record with the judge's description
   and reused while both match; malformed and failed verdicts are not stored,
   so a re-run asks again.
3. **Pairwise preferences** within each session (``compare_many`` of the
   pairwise judge, if any) and their Bradley–Terry–Davidson scores.
4. **Fidelity** against the real results where the manifest has them (MMRV in
   both forms, Spearman ρ, Pearson r, SISR_Δ: :func:`~oscar_core.metrics.policy.compare_policies`),
   and the report folder (:mod:`oscar_core.evaluation.report`).

The world model is anything with ``rollout(first_frame, skeleton, prompt_embeds,
*, chunk_frames, sampler, seed, progress, keep_chunks)`` returning an object
with ``frames`` (T, H, W, 3) uint8 and a ``card`` (``width``, ``height``,
``chunk_frames``, ``fps``) — :class:`~oscar_core.model.OscarWorldModel`, loaded
by :func:`oscar_zoo.load` from a zoo name, a Hub id or a folder. It is loaded
only when some cell needs a rollout.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._util import stage as _stage
from .._util.atomic import atomic_write_bytes, sweep_dead_temporaries
from .._util.log import get_logger, progress_bar
from .._util.stage import EngineName
from ..metrics.common import MetricInputError
from .manifest import Cell, Manifest, file_digest, load_manifest

__all__ = [
    "RECORD_VERSION",
    "EvaluationResult",
    "EvaluationSettings",
    "run_evaluation",
    "card_sampler_of",
    "model_identity",
    "rollout_key",
    "record_path",
    "video_path",
]

RECORD_VERSION = 1
_log = get_logger(__name__)
VIDEO_SUFFIX = ".mkv"  # FFV1, lossless: judges and metrics see exactly the generated pixels


@dataclass
class EvaluationResult:
    """What :func:`run_evaluation` did and found.

    ``records``: one per cell (manifest order); ``counts``: rollouts done /
    reused, verdicts done / reused; ``report``: the JSON written to
    ``OUT/report.json``; ``paths``: the files written.
    """

    out: Path
    records: list[dict]
    counts: dict
    report: dict
    paths: dict = field(default_factory=dict)


def record_path(out: Path, cell: Cell) -> Path:
    return Path(out) / "cells" / cell.session / f"{cell.policy}.json"


def video_path(out: Path, cell: Cell) -> Path:
    return Path(out) / "rollouts" / cell.session / f"{cell.policy}{VIDEO_SUFFIX}"


model_identity = _stage.model_identity  # shared with toyworld rollouts (one definition, in the bottom layer)


def rollout_key(cell: Cell, *, model_id: str, sampler: dict, chunk_frames, size, fps) -> str:
    """SHA-256 of everything that determines a cell's rollout (module docstring, step 1)."""
    fields = {
        "v": RECORD_VERSION,
        "model": model_id,
        "sampler": sampler,
        "chunk_frames": chunk_frames,
        "size": list(size) if size else None,
        "fps": fps,
        "seed": cell.seed,
        "embodiment": cell.embodiment,
        "first_frame": file_digest(cell.first_frame),
        "trajectory": file_digest(cell.trajectory),
        "camera": file_digest(cell.camera),
        "prompt_embeds": file_digest(cell.prompt_embeds) if cell.prompt_embeds else None,
    }
    return hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()


def _judge_id(judge) -> str:
    desc = judge.describe() if hasattr(judge, "describe") else {"repr": repr(judge)}
    desc = {
        k: v
        for k, v in desc.items()
        if k not in ("concurrency", "cache_dir", "timeout", "max_attempts", "max_requests", "dry_run")
    }
    return hashlib.sha256(json.dumps(desc, sort_keys=True, default=str).encode()).hexdigest()


def _write_json(path: Path, data) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, (json.dumps(data, indent=2, default=str) + "\n").encode())


def _read_record(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None  # missing or half-written by something else: redo the cell
    return data if isinstance(data, dict) and data.get("v") == RECORD_VERSION else None


class _LazyModel:
    """Loads the world model on first use (a fully resumed run never loads it)."""

    def __init__(self, model, loader: Callable | None):
        self._model, self._loader = model, loader

    def get(self):
        if self._model is None:
            self._model = self._loader()
        return self._model


def _check_embodiments(manifest: Manifest, plugin_paths) -> None:
    from ..errors import OscarError
    from ..plugin.registry import get_embodiment

    for cell in manifest.cells:
        try:
            get_embodiment(cell.embodiment, plugin_paths)
        except (OscarError, KeyError, ValueError) as exc:
            raise MetricInputError(
                f"{manifest.path}: cells[{cell.row}] (session {cell.session!r}, policy {cell.policy!r})",
                "embodiment",
                "an installed embodiment (oscar embodiments)",
                f"{cell.embodiment!r}: {exc}",
            ) from None


@dataclass(frozen=True)
class EvaluationSettings:
    """How :func:`run_evaluation` rolls out, judges and reports (every field has the command's default).

    model_spec: zoo name, Hub id or folder to load (``oscar_zoo.load(model_spec, revision, device=device,
    dtype=dtype)``) when a rollout is needed and no model object is given; dtype None: bfloat16 on CUDA, else
    the checkpoint's. sampler: :class:`~oscar_core.model.SamplerConfig` (None: the model card's recommended
    settings over the library's defaults, :func:`~oscar_core.model.sampler.resolve_sampler`). chunk_frames: frames
    per chunk (None: the model's). batch_cells: roll out up to this many cells in one batch (cells in manifest
    order that share a frame count, size and prompt shape; each cell's video equals its one-at-a-time rollout up
    to float rounding, and its record is written as soon as its batch finishes; latent-action models roll out one
    at a time). engine: ``local`` (this process) or ``ray``: ``workers`` Ray actors (one GPU each on CUDA), each
    loading the model once from ``model_spec`` and rolling out groups of cells; this process writes every video
    and record, so the run folder, the resume rule and the report are the local run's. compile: ``auto``,
    ``always`` or ``never`` (:mod:`oscar_core.model.compile_policy`), weighed over every pending cell (a worker's
    share on Ray); None: a given model's own ``compile_mode``, ``auto`` for a loaded one. plot_formats: the
    report's figure formats; progress: progress bars.
    """

    model_spec: str | None = None
    revision: str | None = None
    sampler: object = None
    chunk_frames: int | None = None
    device: object = "cpu"
    dtype: object = None
    plugin_paths: tuple = ()
    progress: bool = False
    plot_formats: tuple = ("png",)
    batch_cells: int = 1
    engine: EngineName = "local"
    workers: int = 1
    compile: str | None = None

    def check(self, model=None) -> None:
        """Raise :class:`MetricInputError` naming the first bad setting (before any work)."""
        for name in ("batch_cells", "workers"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise MetricInputError(name, "value", "an integer >= 1", repr(value))
        if self.compile is not None:
            from ..model.compile_policy import check_compile_mode

            check_compile_mode(self.compile)
        if self.engine not in ("local", "ray"):
            raise MetricInputError("engine", "value", '"local" or "ray"', repr(self.engine))
        if self.engine == "ray" and self.model_spec is None:
            raise MetricInputError(
                "engine",
                "ray",
                "a model spec (zoo name, Hub id or folder) each worker loads",
                f"a model object ({type(model).__name__})",
            )


@dataclass
class _Run:
    """One evaluation in progress: its inputs, settings and what the phases have found so far."""

    manifest: Manifest
    out: Path
    settings: EvaluationSettings
    log: Callable[[str], None]
    model: _LazyModel
    model_id: str
    sampler: object
    counts: dict

    @property
    def model_name(self) -> str:
        return self.settings.model_spec if self.settings.model_spec is not None else self.model_id


def run_evaluation(
    manifest,
    out,
    *,
    model=None,
    judge=None,
    pairwise_judge=None,
    settings: EvaluationSettings | None = None,
    log: Callable[[str], None] | None = None,
    **fields,
) -> EvaluationResult:
    """Run the loop of the module docstring and write the report folder ``out``: rollouts, success verdicts,
    pairwise preferences, then metrics and the report, one phase each.

    manifest: a path or a loaded :class:`Manifest`. model: a loaded world model, or None to load
    ``settings.model_spec`` when a rollout is needed. judge: success judge (``judge_many``) or None (no
    world-model success rates); pairwise_judge: ``compare_many`` or None. settings: an
    :class:`EvaluationSettings`, or its fields as keywords (``model_spec=..., batch_cells=4``). log: called with
    each progress message (default: the logger at INFO).
    """
    if settings is None:
        settings = EvaluationSettings(**fields)
    elif fields:
        settings = dataclasses.replace(settings, **fields)
    settings.check(model)
    run = _start(manifest, out, model, settings, log)
    records = _rollouts(run)
    clips, verdicts = _success_verdicts(run, records, judge)
    pair_verdicts = _pairwise_preferences(run, clips, verdicts, judge, pairwise_judge)
    return _report(run, records, verdicts, pair_verdicts, judge, pairwise_judge, user_log=log)


def card_sampler_of(spec: str, revision: str | None = None) -> dict | None:
    """The sampler settings model ``spec``'s card recommends (``ModelCard.sampler``), read from its folder (bundled,
    local, or pulled into the Hub cache) without loading weights; None for a folder without an OSCAR card."""
    import oscar_zoo

    from ..model.world_model import MODEL_FILE, read_card

    folder = Path(oscar_zoo.pull(spec, revision))
    return read_card(folder).sampler if (folder / MODEL_FILE).is_file() else None


def _start(manifest, out, model, settings: EvaluationSettings, log) -> _Run:
    """Load and check the manifest, sweep temporaries of killed runs, and set up the (lazy) model."""
    log = log or _log.info
    manifest = manifest if isinstance(manifest, Manifest) else load_manifest(manifest)
    _check_embodiments(manifest, settings.plugin_paths)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    # temporaries of killed runs (videos, cell records, report files), even when every cell is then reused
    for folder in (out, *sorted((out / "cells").glob("*")), *sorted((out / "rollouts").glob("*"))):
        sweep_dead_temporaries(folder)
    spec, revision = settings.model_spec, settings.revision
    if model is None and spec is None:
        raise MetricInputError("model", "model", "a world model or a model spec (zoo name, Hub id or folder)", "none")
    if settings.sampler is not None:
        sampler = settings.sampler
    else:  # the card's recommended settings over the library's defaults
        from ..model.card_sampler import resolve_sampler

        card_sampler = (
            getattr(getattr(model, "card", None), "sampler", None)
            if model is not None
            else card_sampler_of(spec, revision)
        )
        choice = resolve_sampler(card_sampler)
        log(f"sampler: {choice.describe()}")
        sampler = choice.config
    model_id = model_identity(spec, revision) if spec is not None else f"object:{type(model).__name__}"

    def load():
        import oscar_zoo

        log(f"loading world model {spec}")
        return oscar_zoo.load(spec, revision, device=settings.device, dtype=settings.dtype)

    counts = {
        "cells": len(manifest.cells),
        "rollouts_done": 0,
        "rollouts_reused": 0,
        "verdicts_done": 0,
        "verdicts_reused": 0,
        "verdicts_not_ok": 0,
    }
    return _Run(manifest, out, settings, log, _LazyModel(model, load), model_id, sampler, counts)


def _rollouts(run: _Run) -> list[dict]:
    """Phase 1: every cell's rollout, reused when its record and video match, else rolled out and recorded.
    Returns the records in manifest order."""
    manifest, out, st, log, counts = run.manifest, run.out, run.settings, run.log, run.counts
    sampler_fields = dataclasses.asdict(run.sampler)
    size = manifest.size
    done: dict[int, dict] = {}
    # a bar over the cells: rate and ETA of the whole evaluation (reused cells count at once)
    bar = progress_bar(total=len(manifest.cells), desc="eval run: rollouts", unit="cell", enabled=st.progress)
    pending = []  # (index, cell, key) of the cells without a valid rollout
    for k, cell in enumerate(manifest.cells):
        rpath, vpath = record_path(out, cell), video_path(out, cell)
        key = rollout_key(
            cell, model_id=run.model_id, sampler=sampler_fields, chunk_frames=st.chunk_frames, size=size, fps=None
        )
        rec = _read_record(rpath)
        if (
            rec is not None
            and rec.get("rollout_key") == key
            and vpath.is_file()
            and rec.get("video_sha256") == file_digest(vpath)
        ):
            counts["rollouts_reused"] += 1
            done[k] = rec
            bar.update(1)
        else:
            pending.append((k, cell, key))

    def record(k: int, cell: Cell, key: str, frames: np.ndarray, fps: float, seconds: float, batch: int) -> None:
        """Write one rolled-out cell's video, then its record (the record last: a killed run redoes the cell)."""
        from ..media.video import write_video

        rpath, vpath = record_path(out, cell), video_path(out, cell)
        vpath.parent.mkdir(parents=True, exist_ok=True)
        write_video(vpath, frames, fps)
        rec = {
            "v": RECORD_VERSION,
            "cell": cell.id,
            "session": cell.session,
            "policy": cell.policy,
            "row": cell.row,
            "rollout_key": key,
            "model": run.model_name,
            "video": str(vpath.relative_to(out)),
            "video_sha256": file_digest(vpath),
            "frames": int(len(frames)),
            "size": [int(frames.shape[2]), int(frames.shape[1])],
            "fps": fps,
            "seconds": round(seconds, 3),
            "verdict": None,
            "batch": batch,
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        _write_json(rpath, rec)
        counts["rollouts_done"] += 1
        done[k] = rec
        bar.update(1)
        log(
            f"[{k + 1}/{len(manifest.cells)}] rolled out {cell.id}: {rec['frames']} frames in "
            f"{rec['seconds']:.1f} s" + (f" (batch of {batch})" if batch > 1 else "")
        )

    options = dict(
        size=size,
        sampler=run.sampler,
        chunk_frames=st.chunk_frames,
        plugin_paths=tuple(st.plugin_paths),
        batch_cells=st.batch_cells,
    )
    if pending and st.engine == "ray":
        from .rollout_engines import roll_out_on_ray

        roll_out_on_ray(
            pending,
            record,
            model_spec=st.model_spec,
            revision=st.revision,
            device=st.device,
            dtype=st.dtype,
            workers=st.workers,
            log=log,
            compile=st.compile or "auto",
            **options,
        )
    elif pending:
        from .rollout_engines import roll_out_cells

        at = {id(c): (k, key) for k, c, key in pending}
        loaded = run.model.get()
        if hasattr(loaded, "set_compile"):  # compile once for the whole job, weighed over its pending cells
            loaded.set_compile(st.compile or getattr(loaded, "compile_mode", "auto"), cells=len(pending))
        for group, videos in roll_out_cells(loaded, [c for _, c, _ in pending], progress=st.progress, **options):
            for (cell, seconds), (frames, fps) in zip(group, videos):
                k, key = at[id(cell)]
                record(k, cell, key, frames, fps, seconds, len(group))
    bar.close()
    return [done[k] for k in range(len(manifest.cells))]


def _success_verdicts(run: _Run, records: list[dict], judge) -> tuple[list, list]:
    """Phase 2: (the cells as judge clips, one success verdict or None per cell); an ``ok`` verdict stored in a
    cell's record by the same judge is reused, fresh ``ok`` verdicts are stored."""
    from ..metrics.judge import JudgeClip, SuccessVerdict

    manifest, out, counts = run.manifest, run.out, run.counts
    clips = [
        JudgeClip(
            name=c.id, video=out / r["video"], instruction=c.task, policy=c.policy, session=c.session, info=c.info
        )
        for c, r in zip(manifest.cells, records)
    ]
    verdicts: list[SuccessVerdict | None] = [None] * len(clips)
    if judge is None:
        return clips, verdicts
    jid = _judge_id(judge)
    todo = []
    for k, rec in enumerate(records):
        stored = rec.get("verdict")
        if isinstance(stored, dict) and stored.get("judge_id") == jid and stored.get("status") == "ok":
            v = dict(stored["verdict"])
            v["attempt_errors"] = tuple(v.get("attempt_errors") or ())
            verdicts[k] = SuccessVerdict(**v)
            counts["verdicts_reused"] += 1
        else:
            todo.append(k)
    if todo:
        run.log(f"judging {len(todo)} rollouts")
        fresh = judge.judge_many([clips[k] for k in todo], progress=run.settings.progress)
        for k, v in zip(todo, fresh):
            verdicts[k] = v
            counts["verdicts_done"] += 1
            if v.ok:
                records[k]["verdict"] = {"judge_id": jid, "status": "ok", "verdict": v.to_dict()}
                _write_json(record_path(out, manifest.cells[k]), records[k])
            else:
                counts["verdicts_not_ok"] += 1
    counts["verdicts_not_ok"] = sum(1 for v in verdicts if v is not None and not v.ok)
    return clips, verdicts


def _pairwise_preferences(run: _Run, clips: list, verdicts: list, judge, pairwise_judge) -> list:
    """Phase 3: the pairwise judge's verdicts on every pair of cells within a session ([] without one)."""
    from ..metrics.judge import pairs_by_session

    if pairwise_judge is None:
        return []
    pairs = pairs_by_session(clips)
    if not pairs:
        return []
    run.log(f"comparing {len(pairs)} pairs")
    kwargs = {}
    if getattr(pairwise_judge, "kind", None) == "programmatic" and judge is pairwise_judge:
        kwargs["verdicts"] = [v for v in verdicts if v is not None]
    return pairwise_judge.compare_many(pairs, progress=run.settings.progress, **kwargs)


def _report(run: _Run, records, verdicts, pair_verdicts, judge, pairwise_judge, user_log) -> EvaluationResult:
    """Phase 4: the metrics and the report folder."""
    from ..metrics.judge import success_by_policy
    from .report import build_report, write_report

    wm = success_by_policy([v for v in verdicts if v is not None]) if judge is not None else {}
    report = build_report(
        run.manifest,
        records,
        verdicts,
        pair_verdicts,
        wm,
        counts=run.counts,
        model=run.model_name,
        judge=judge.describe() if judge is not None and hasattr(judge, "describe") else None,
        pairwise_judge=(
            pairwise_judge.describe() if pairwise_judge is not None and hasattr(pairwise_judge, "describe") else None
        ),
        sampler=dataclasses.asdict(run.sampler),
    )
    paths = write_report(run.out, report, run.manifest, records, plot_formats=run.settings.plot_formats, log=user_log)
    return EvaluationResult(out=run.out, records=records, counts=run.counts, report=report, paths=paths)
