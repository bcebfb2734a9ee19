"""Closed-loop policy evaluation: a policy acts on a world's frames, and its actions drive the next frames.

:func:`run_closed_loop` runs every (session, policy) cell of a
:class:`~oscar_core.evaluation.closed_loop_manifest.ClosedLoopManifest` in a *world* — the world model
(:class:`ModelWorld`), or any simulator with the same three members (``first``, ``step``, ``outcome``; the toy
world's is :class:`oscar_core.toyworld.closed_loop.ToySimulator`). Per cell, gymnasium-style:

1. **reset**: the policy's ``reset()`` (if any); the world's first frame; the joint state and gripper from the
   session's ``initial_state``.
2. **observe**: the latest frame resized to the policy's ``image_size`` under its ``image`` key; the joint
   positions and gripper closure integrated from the policy's own commands (the end of the path commanded so
   far) under ``joint_position`` (J,) and ``gripper_position`` (1,); the task under ``prompt``; the session's
   ``extras``. The world generates one view: a ``wrist_image`` key receives a black image of the declared size
   (:data:`VIEWS` says so in every report).
3. **act**: ``infer`` under the policy timeout; the answer checked
   (:func:`~oscar_core.policy.protocol.check_answer`); its first K rows (``replan_every``, default the policy's
   ``actions_per_call``) through the action-space adapter (:class:`~oscar_core.policy.spaces.ActionAdapter`)
   into joint positions at the policy's control rate, appended to the commanded path.
4. **step**: while the commanded path covers the world's next chunk of frames, those frames' joint positions
   are read off the path at the world's frame rate (:func:`~oscar_core.policy.spaces.resample`) and the world
   generates them — the world model from its last generated frame along the condition video (skeleton, mesh
   or capsules, as its card says) of the chunk's poses, seeded per chunk.
5. Repeat until ``horizon`` frames exist or the policy answers ``"done": true``.

A policy fault (exception, timeout, bad answer: :class:`~oscar_core.policy.protocol.PolicyFault`) ends its cell
with the reason; the other cells go on. A fault of the world (model, disk) stops the run.

What is kept per cell, under ``OUT/cells/<session>/<policy>/``: ``video.mkv`` (the generated frames, FFV1
lossless), ``condition.mkv`` (the condition video the world model saw; none for a simulator),
``trajectory.npz`` (the integrated joint path at the world's frame rate, the project's trajectory format, so
``oscar render`` re-renders it), ``calls.json`` (per policy call: the frame index and SHA-256 of the image sent,
the action chunk received, the latency, clipped actions and IK residuals), and ``record.json`` written last,
atomically. The record holds the cell's fingerprint (:func:`oscar_core._util.stage.fingerprint` of the world's
identity — model, sampler, chunk length, size —, the policy's declaration and source, ``replan_every`` and the
bytes of every session input): a re-run reuses a finished cell whose fingerprint and video digest match, reuses
a failed one unless ``retry_failed``, and redoes a changed one, logging what changed.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._util import stage as _stage
from .._util.atomic import sweep_dead_temporaries
from .._util.log import get_logger, progress_bar
from ..metrics.common import MetricInputError
from ..policy.protocol import PolicySpec
from .closed_loop_cell import (
    CellRun,
    ModelWorld,
    OpenCell,
    PolicyPool,
    cell_steps,
    chunk_seed,
    generate_chunks,
    open_cell,
    run_cell,
    run_open_cell,
)
from .closed_loop_judging import judge_and_report, judge_failures, write_json
from .closed_loop_manifest import ClosedLoopManifest, Session, load_closed_loop_manifest
from .closed_loop_report import VIEWS
from .manifest import file_digest

__all__ = [
    "RECORD_VERSION",
    "VIEWS",
    "ClosedLoopResult",
    "CellRun",
    "ModelWorld",
    "run_closed_loop",
    "run_cell",
    "cell_dir",
    "cell_steps",
    "chunk_seed",
    "generate_chunks",
    "judge_failures",
]

RECORD_VERSION = 1
_log = get_logger(__name__)


def cell_dir(out: Path, session: str, policy: str) -> Path:
    return Path(out) / "cells" / session / policy


@dataclass
class ClosedLoopResult:
    """What :func:`run_closed_loop` did: ``records`` (one per cell, session-major), ``report`` (``report.json``),
    ``counts`` and ``paths``."""

    out: Path
    records: list[dict]
    counts: dict
    report: dict
    paths: dict = field(default_factory=dict)


def _read_record(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("v") == RECORD_VERSION else None


def _session_parts(s: Session) -> dict:
    return {
        "task": s.task,
        "embodiment": s.embodiment,
        "horizon": s.horizon,
        "seed": s.seed,
        "extras": s.extras,
        "first_frame": file_digest(s.first_frame),
        "camera": file_digest(s.camera),
        "initial_state": file_digest(s.initial_state),
        "prompt_embeds": file_digest(s.prompt_embeds) if s.prompt_embeds else None,
        "simulator": file_digest(s.simulator) if s.simulator else None,
    }


def _check_run_options(replan_every, chunk_frames, batch_cells, engine, model, policy_timeout) -> None:
    """:class:`MetricInputError` naming the option for a count below 1, an unknown engine, a loaded model with
    Ray (each worker loads its own) or a timeout that is not a positive number of seconds."""
    for name, value in (("replan_every", replan_every), ("chunk_frames", chunk_frames), ("batch_cells", batch_cells)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise MetricInputError(name, "value", "an integer >= 1", repr(value))
    if engine not in ("local", "ray"):
        raise MetricInputError("engine", "value", "local or ray", repr(engine))
    if engine == "ray" and model is not None:
        raise MetricInputError("engine", "model", "a model spec (each Ray worker loads its own)", "a loaded model")
    if policy_timeout is not None and not policy_timeout > 0:
        raise MetricInputError("policy_timeout", "value", "a positive number of seconds", repr(policy_timeout))


def _policy_specs(manifest, policy_sources, replan_every, log) -> list[PolicySpec]:
    """The policies to run: the manifest's, their sources replaced or added by ``policy_sources``; logs each
    policy whose answers must hold more actions than it says it gives."""
    specs = list(manifest.policies)
    for name, src in (policy_sources or {}).items():
        known = [p.name for p in specs]
        if name in known:
            specs[known.index(name)] = dataclasses.replace(specs[known.index(name)], source=src)
        else:
            specs.append(PolicySpec(name=name, source=src))
    for spec in specs:
        if replan_every is not None and replan_every > spec.actions_per_call:
            log(
                f"policy {spec.name}: replan_every {replan_every} > its actions_per_call {spec.actions_per_call}: "
                "its answers must hold at least that many actions"
            )
    return specs


def _check_world_given(simulator, model, model_spec, fps, chunk_frames) -> None:
    """:class:`MetricInputError` without a world (model, model spec or simulator), or for a simulator without both
    ``fps`` and ``chunk_frames``; then :func:`_check_world_context`."""
    if simulator is None and model is None and model_spec is None:
        raise MetricInputError("model", "model", "a world model, a model spec or a simulator", "none")
    if simulator is not None and (fps is None or chunk_frames is None):
        raise MetricInputError(
            "simulator", "fps/chunk_frames", "both given for a simulator world", f"{fps}/{chunk_frames}"
        )
    _check_world_context(simulator, model, model_spec)


def _check_world_context(simulator, model, model_spec) -> None:
    """Refuse a world model whose card's ``context_frames`` is above 1 (:func:`check_one_frame_context`) before any
    cell: a loaded model's card, or the card of a model folder read without its weights. A zoo name or Hub id is
    checked once loaded, when the first cell opens its world and before it runs."""
    from .closed_loop_cell import check_one_frame_context

    if simulator is not None:
        return
    if model is not None:
        check_one_frame_context(getattr(model, "card", None))
        return
    from ..model.world_model import MODEL_FILE, read_card

    folder = Path(str(model_spec))
    if (folder / MODEL_FILE).is_file():
        check_one_frame_context(read_card(folder), f"{folder / MODEL_FILE}: card")


def _embodiments(manifest, plugin_paths) -> dict:
    """Every session's embodiment by name; :class:`MetricInputError` naming the session row for one not installed."""
    from ..plugin.registry import get_embodiment

    embs = {}
    for s in manifest.sessions:
        try:
            embs[s.embodiment] = get_embodiment(s.embodiment, plugin_paths)
        except (KeyError, ValueError, Exception) as exc:  # noqa: BLE001 - named in the error
            raise MetricInputError(
                f"{manifest.path}: sessions[{s.row}]",
                "embodiment",
                "an installed embodiment (oscar embodiments)",
                f"{s.embodiment!r}: {exc}",
            ) from None
    return embs


def _world_identity(
    simulator, model, model_spec, revision, sampler, fps, chunk_frames, size, tiny_decoder=None, tiny_encoder=None
) -> dict:
    """What every cell's output depends on about the world: the simulator (its identity, fps, chunk frames) or
    the world model (its pinned identity, sampler settings, chunk frames, and a chosen decoder or condition encoder:
    :func:`_decoder_identity`, :func:`_encoder_identity`), and the rollout size."""
    if simulator is not None:
        world_id = {
            "kind": "simulator",
            "name": getattr(simulator, "identity", repr(simulator)),
            "fps": fps,
            "chunk_frames": chunk_frames,
            "size": size,
        }
    else:
        world_id = {
            "kind": "world-model",
            "model": _stage.model_identity(model_spec, revision) if model_spec else f"object:{type(model).__name__}",
            "sampler": dataclasses.asdict(sampler),
            "chunk_frames": chunk_frames,
            "size": size,
        }
    return world_id | _decoder_identity(simulator, tiny_decoder) | _encoder_identity(simulator, tiny_encoder)


def _decoder_identity(simulator, tiny_decoder) -> dict:
    """``{"decoder": ...}`` when a decoder was chosen for a world model (:func:`decoder_identity`), else empty: a run
    that chooses none keeps the keys its cells had before the choice existed."""
    if simulator is not None or tiny_decoder is None:
        return {}
    from ..model.decoder_options import decoder_identity

    return {"decoder": decoder_identity(tiny_decoder)}


def _encoder_identity(simulator, tiny_encoder) -> dict:
    """``{"condition_encoder": "tiny-sha256:<hex>"}`` when a tiny condition encoder was chosen for a world model
    (:func:`~oscar_core.model.encoder_options.encoder_identity`), else empty: a run with the full encoder keeps the
    keys its cells had before the choice existed."""
    if simulator is not None or tiny_encoder is None or tiny_encoder is False:
        return {}
    from ..model.encoder_options import encoder_identity

    return {"condition_encoder": encoder_identity(tiny_encoder)}


def _plan_cells(out: Path, manifest, specs, world_id: dict, replan_every, retry_failed: bool, counts, bar, log):
    """``(records, pending, reused_failed)``: one record per (session, policy) cell in order — the recorded one
    where its key (a fingerprint of world, session, replan interval and policy) matches and its video is intact, or
    a failed one kept without ``retry_failed``; None for a cell to run —, the cells to run as
    ``(index, session, spec, parts, key, replan_every)`` and the ``session/policy`` names of the failed cells kept.
    Counts reused, failed and retried cells in ``counts``."""
    records: list[dict | None] = []
    pending: list[tuple] = []
    reused_failed: list[str] = []
    for s in manifest.sessions:
        sparts = _session_parts(s)
        for spec in specs:
            folder = cell_dir(out, s.session, spec.name)
            K = int(replan_every or spec.actions_per_call)
            parts = {
                "v": RECORD_VERSION,
                "world": world_id,
                "session": sparts,
                "replan_every": K,
                "policy": {k: v for k, v in spec.to_dict().items() if k != "timeout_s"},
            }
            key = _stage.fingerprint(parts)
            rec = _read_record(folder / "record.json")
            if rec is not None and rec.get("key") == key:
                if (
                    rec["status"] == "ok"
                    and (folder / "video.mkv").is_file()
                    and rec.get("video_sha256") == file_digest(folder / "video.mkv")
                ):
                    counts["reused"] += 1
                    records.append(rec)
                    bar.update(1)
                    continue
                if rec["status"] == "failed" and not retry_failed:
                    counts["reused"] += 1
                    counts["failed"] += 1
                    reused_failed.append(f"{s.session}/{spec.name}")
                    records.append(rec)
                    bar.update(1)
                    continue
                counts["retried"] += rec["status"] == "failed"
            elif rec is not None:
                log(
                    f"{s.session}/{spec.name}: redone, its inputs changed: "
                    + "; ".join(_stage.changes(rec.get("parts"), parts))
                )
            pending.append((len(records), s, spec, parts, key, K))
            records.append(None)
    return records, pending, reused_failed


def _run_cells(
    pending,
    records,
    counts,
    bar,
    out,
    embs,
    pool,
    world_options,
    ray_options,
    *,
    engine,
    batch_cells,
    policy_timeout,
    log,
):
    """Runs the pending cells: on Ray actors, in lock-step batches of ``batch_cells`` or one at a time. Each cell's
    written record goes into ``records`` at its index, counted in ``counts`` (done, failed) and on ``bar``."""

    def finish(index: int, rec: dict) -> None:
        counts["done"] += 1
        counts["failed"] += rec["status"] == "failed"
        records[index] = rec
        bar.update(1)

    def open_job(job) -> OpenCell:
        _, s, spec, parts, key, K = job
        return open_cell(s, spec, embs[s.embodiment], parts, key, pool=pool, K=K, **world_options)

    def write(cell: OpenCell, run: CellRun) -> dict:
        return _write_cell(out, cell, run, pool=pool, log=log)

    if engine == "ray" and pending:
        from .closed_loop_ray import run_on_ray

        run_on_ray(
            pending,
            finish,
            write,
            batch_cells=batch_cells,
            timeout=policy_timeout,
            world_options={k: v for k, v in world_options.items() if k not in ("get_model", "simulator")},
            log=log,
            **ray_options,
        )
    elif batch_cells > 1 and pending:
        from .closed_loop_batch import run_lock_step

        log(f"running {len(pending)} cells in lock-step, up to {batch_cells} at once")
        run_lock_step(pending, open_job, finish, batch_cells=batch_cells, write=write, timeout=policy_timeout)
    else:
        for job in pending:
            cell = open_job(job)
            finish(job[0], write(cell, run_open_cell(cell, policy_timeout)))


def _model_loader(model, model_spec, revision, device, dtype, log, tiny_decoder=None, tiny_encoder=None) -> Callable:
    """A function returning the world model: ``model``, or ``model_spec`` loaded (``oscar_zoo.load``, with
    ``tiny_decoder`` and ``tiny_encoder``) on its first call only, so a run whose every cell is reused loads nothing."""
    loaded = {"model": model}

    def get_model():
        if loaded["model"] is None:
            import oscar_zoo

            log(f"loading world model {model_spec}")
            loaded["model"] = oscar_zoo.load(
                model_spec, revision, device=device, dtype=dtype, tiny_decoder=tiny_decoder, tiny_encoder=tiny_encoder
            )
        return loaded["model"]

    return get_model


def _prepared_out(out) -> Path:
    """The output folder, made, with the temporaries a killed run left in it and its cell folders swept."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for folder in (out, *sorted(out.glob("cells/*/*"))):
        sweep_dead_temporaries(folder)
    return out


def _preloaded_policies(pending, reused_failed: list[str]) -> PolicyPool:
    """Warns about the failed cells kept as they are, then loads (or connects) every policy with a cell to run,
    before any model loads or cell runs; returns the pool holding them."""
    if reused_failed:
        _log.warning(
            "reused %d failed cell(s) of an earlier run as they are (%s); --retry-failed redoes them",
            len(reused_failed),
            ", ".join(reused_failed[:5]) + (", …" if len(reused_failed) > 5 else ""),
        )
    pool = PolicyPool()
    pool.preload(list({job[2].name: job[2] for job in pending}.values()))
    return pool


def run_closed_loop(
    manifest,
    out,
    *,
    model=None,
    model_spec: str | None = None,
    revision: str | None = None,
    simulator: Callable | None = None,
    judge=None,
    pairwise_judge=None,
    sampler=None,
    chunk_frames: int | None = None,
    fps: float | None = None,
    replan_every: int | None = None,
    policy_timeout: float | None = None,
    retry_failed: bool = False,
    policy_sources: dict | None = None,
    batch_cells: int = 1,
    engine: str = "local",
    workers: int = 1,
    device="cpu",
    dtype=None,
    tiny_decoder=None,
    tiny_encoder=None,
    plugin_paths=(),
    progress: bool = False,
    plot_formats=("png",),
    log: Callable[[str], None] | None = None,
) -> ClosedLoopResult:
    """Run every cell of ``manifest`` (a path or a loaded manifest) closed loop and write ``out``.

    The world: the world model ``model`` (loaded) or ``model_spec`` (``oscar_zoo.load``; loaded only if some cell
    must run; its decoder ``tiny_decoder``, :mod:`oscar_core.model.decoder_options`, None: its card's; its condition encoder
    ``tiny_encoder``, :mod:`oscar_core.model.encoder_options`, None: the full encoder); or ``simulator``, a factory ``(session, emb, camera, first, size, fps, chunk_frames) -> world``
    (then ``fps`` and ``chunk_frames`` are required). judge: a success judge (``judge_many``) run on every
    finished cell's video, or None; pairwise_judge: ``compare_many`` on every two finished cells of a session
    (preferences and their Bradley–Terry fit in the report), or None. replan_every: actions executed per call for every policy (default: each
    policy's ``actions_per_call``); policy_timeout: seconds per call for every policy (default: each policy's
    ``timeout_s``); retry_failed: redo cells recorded as failed; policy_sources: ``{name: source}`` replacing
    the manifest's sources; batch_cells: cells advanced in lock-step, their chunks generated in one batched
    world-model call (:mod:`.closed_loop_batch`; 1: one cell at a time); engine: ``"local"`` (this process) or
    ``"ray"`` (``workers`` Ray actors, one world each, :mod:`.closed_loop_ray`; this process writes every file).
    Returns :class:`ClosedLoopResult`; writes ``OUT/report.json``, ``OUT/summary.md`` and ``OUT/report.html``
    (:mod:`.closed_loop_report`).
    """
    from ..model.sampler import SamplerConfig

    log = log or _log.info
    manifest = manifest if isinstance(manifest, ClosedLoopManifest) else load_closed_loop_manifest(manifest)
    _check_run_options(replan_every, chunk_frames, batch_cells, engine, model, policy_timeout)
    specs = _policy_specs(manifest, policy_sources, replan_every, log)
    _check_world_given(simulator, model, model_spec, fps, chunk_frames)
    embs = _embodiments(manifest, plugin_paths)
    out = _prepared_out(out)
    sampler = sampler or SamplerConfig()
    get_model = _model_loader(model, model_spec, revision, device, dtype, log, tiny_decoder, tiny_encoder)
    world_id = _world_identity(  # in every cell's fingerprint
        simulator, model, model_spec, revision, sampler, fps, chunk_frames, manifest.size, tiny_decoder, tiny_encoder
    )
    counts = {"cells": len(manifest.sessions) * len(specs), "done": 0, "reused": 0, "failed": 0, "retried": 0}
    bar = progress_bar(total=counts["cells"], desc="closed loop", unit="cell", enabled=progress)
    records, pending, reused_failed = _plan_cells(
        out, manifest, specs, world_id, replan_every, retry_failed, counts, bar, log
    )

    pool = _preloaded_policies(pending, reused_failed)
    world_options = dict(
        get_model=get_model,
        simulator=simulator,
        sampler=sampler,
        size=manifest.size,
        chunk_frames=chunk_frames,
        fps=fps,
    )

    ray_options = dict(model_spec=model_spec, revision=revision, simulator=simulator, device=device, dtype=dtype)
    ray_options.update(tiny_decoder=tiny_decoder, tiny_encoder=tiny_encoder, workers=workers, plugin_paths=plugin_paths)
    run = dict(engine=engine, batch_cells=batch_cells, policy_timeout=policy_timeout, log=log)
    _run_cells(pending, records, counts, bar, out, embs, pool, world_options, ray_options, **run)
    bar.close()
    report, paths = judge_and_report(
        out,
        manifest,
        specs,
        records,
        counts,
        world_id,
        judge,
        pairwise_judge,
        progress,
        plot_formats,
        log,
        reused_failed,
    )
    return ClosedLoopResult(out, records, counts, report, paths)


def _write_cell(out: Path, cell: OpenCell, run: CellRun, *, pool: PolicyPool, log) -> dict:
    """Write a finished cell's files (video, condition, trajectory, calls), the record last, atomically; returns
    the record. The policy object goes back to ``pool`` unless the cell failed."""
    from ..kinematics.trajectory import Trajectory, save_trajectory
    from ..media.video import write_video

    s, spec, emb, world = cell.session, cell.spec, cell.emb, cell.world
    folder = cell_dir(out, s.session, spec.name)
    folder.mkdir(parents=True, exist_ok=True)
    seconds = time.perf_counter() - cell.started
    fault = run.fault
    if fault is None:
        pool.give(spec, cell.policy)
    rel = folder.relative_to(out)
    write_json(folder / "calls.json", {"policy": spec.name, "session": s.session, "calls": run.calls})
    latencies = [c["latency_s"] for c in run.calls if "latency_s" in c]
    rec = {
        "v": RECORD_VERSION,
        "session": s.session,
        "policy": spec.name,
        "key": cell.key,
        "parts": cell.parts,
        "dir": str(rel),
        "status": "failed" if fault else "ok",
        "reason": fault,
        "world": world.name,
        "frames": int(len(run.frames)),
        "calls": len(run.calls),
        "clipped_actions": run.clipped,
        "done_by_policy": run.done_by_policy,
        "seconds": round(seconds, 3),
        "latency_s": {
            "mean": float(np.mean(latencies)) if latencies else None,
            "max": float(np.max(latencies)) if latencies else None,
        },
        "ik_max_position_error_m": _max_ik(run.calls),
        "timing_s": {
            "policy": round(float(sum(latencies)), 6),
            "adapter": round(float(sum(c.get("adapter_s", 0.0) for c in run.calls)), 6),
            **{k.removesuffix("_s"): round(v, 6) for k, v in (getattr(world, "timing", None) or {}).items()},
        },
        "outcome": None,
        "verdict": None,
        "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    if fault is None:
        write_video(folder / "video.mkv", run.frames, world.fps)
        cond = getattr(world, "condition", None)
        if cond:
            write_video(folder / "condition.mkv", np.stack(cond[: len(run.frames)]), world.fps)
            rec["condition"] = str(rel / "condition.mkv")
        save_trajectory(
            Trajectory(
                emb.joint_names,
                run.q,
                world.fps,
                run.gripper,
                emb.gripper_names or None,
                source=f"<closed loop {s.session}/{spec.name}>",
            ),
            folder / "trajectory.npz",
        )
        rec.update(
            video=str(rel / "video.mkv"),
            video_sha256=file_digest(folder / "video.mkv"),
            trajectory=str(rel / "trajectory.npz"),
            outcome=world.outcome() or None,
        )
        log(f"{s.session}/{spec.name}: {rec['frames']} frames, {rec['calls']} policy calls in {seconds:.1f} s")
    else:
        log(f"{s.session}/{spec.name}: FAILED: {fault}")
    write_json(folder / "record.json", rec)
    return rec


def _max_ik(calls: list[dict]) -> float | None:
    vals = [v for c in calls for v in (c.get("ik_position_error_m") or []) if v is not None]
    return float(max(vals)) if vals else None
