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
from ..metrics.common import MetricInputError
from ..policy.loading import load_policy
from ..policy.protocol import PolicyFault, PolicySpec, call_policy, check_answer
from ..policy.spaces import ActionAdapter, resample
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
    "chunk_seed",
]

RECORD_VERSION = 1
_log = get_logger(__name__)


def cell_dir(out: Path, session: str, policy: str) -> Path:
    return Path(out) / "cells" / session / policy


def chunk_seed(seed: int, chunk: int) -> int:
    """The noise seed of chunk ``chunk`` of a cell with seed ``seed`` (independent streams per chunk)."""
    return int(np.random.SeedSequence([int(seed), int(chunk)]).generate_state(1)[0])


class ModelWorld:
    """The world model as a world: generates ``chunk`` new frames per :meth:`step` from its last frame.

    model: an :class:`~oscar_core.model.OscarWorldModel` (or anything with ``rollout`` and ``card``);
    first: (H, W, 3) uint8 at the rollout size; camera, emb: the session's; q0, g0: (J,), (G,) the robot's
    state at the first frame; fps: the model's frame rate; chunk_frames: L = 4k+1 (L − 1 new frames per step).
    """

    name = "world-model"

    def __init__(
        self,
        model,
        *,
        first,
        camera,
        camera_source: str,
        emb,
        q0,
        g0,
        fps: float,
        chunk_frames: int,
        size,
        prompt,
        sampler,
        seed: int,
    ):
        self.model, self.first, self.camera, self.camera_source, self.emb = model, first, camera, camera_source, emb
        self.fps, self.chunk_frames, self.chunk = float(fps), int(chunk_frames), int(chunk_frames) - 1
        self.size, self.prompt, self.sampler, self.seed = tuple(size), prompt, sampler, seed
        self.q, self.g = np.asarray(q0, float)[None], np.asarray(g0, float)[None]
        self.last = first
        self.steps = 0
        self.condition: list[np.ndarray] = []

    def _condition(self, q: np.ndarray, g: np.ndarray) -> np.ndarray:
        from ..kinematics.trajectory import Trajectory

        traj = Trajectory(
            self.emb.joint_names, q, self.fps, g, self.emb.gripper_names or None, source="<closed-loop chunk>"
        )
        if hasattr(self.model, "rollout_inputs"):
            return self.model.rollout_inputs(
                traj, self.camera, self.emb, self.size, resize_mode="crop", camera_source=self.camera_source
            )["skeleton"]
        from ..render.conditions import condition_video, video_condition_of

        return condition_video(
            video_condition_of(self.model.card.condition),
            self.emb,
            traj,
            self.camera,
            self.size,
            resize_mode="crop",
            camera_source=self.camera_source,
        )

    def step(self, q: np.ndarray, gripper: np.ndarray) -> np.ndarray:
        """(n, H, W, 3) uint8 new frames for joint positions ``q`` (n, J) and gripper signals (n, G), n = chunk."""
        import warnings

        q_win = np.concatenate([self.q[-1:], q])
        g_win = np.concatenate([self.g[-1:], gripper])
        cond = self._condition(q_win, g_win)
        self.condition += [cond[0]] if not self.condition else []
        self.condition += list(cond[1:])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "trained at WxH": said once in the report instead
            frames = self.model.rollout(
                self.last,
                cond,
                self.prompt,
                chunk_frames=self.chunk_frames,
                sampler=self.sampler,
                seed=chunk_seed(self.seed, self.steps),
                progress=False,
                keep_chunks=False,
            ).frames[1:]
        self.q, self.g = np.concatenate([self.q, q]), np.concatenate([self.g, gripper])
        self.last = frames[-1]
        self.steps += 1
        return frames

    def outcome(self) -> dict:
        return {}


@dataclass
class CellRun:
    """What one cell did. frames: (T, H, W, 3) uint8; q: (T, J); gripper: (T, G) raw signals; calls: one dict
    per policy call; fault: the reason the cell ended early, or None; done_by_policy: the policy said done."""

    frames: np.ndarray
    q: np.ndarray
    gripper: np.ndarray
    calls: list[dict]
    fault: str | None = None
    done_by_policy: bool = False
    clipped: int = 0


def _observation(
    spec: PolicySpec, frame: np.ndarray, q: np.ndarray, closure: float, task: str, extras: dict
) -> tuple[dict, str]:
    """The observation dict under the policy's keys, and the SHA-256 of the image sent."""
    import cv2

    w, h = spec.image_size
    image = frame if frame.shape[:2] == (h, w) else cv2.resize(frame, (w, h), interpolation=cv2.INTER_AREA)
    image = np.ascontiguousarray(image, dtype=np.uint8)
    obs = dict(extras)
    keys = spec.keys
    obs[keys["image"]] = image
    obs[keys["wrist_image"]] = np.zeros_like(image)
    obs[keys["joint_position"]] = np.asarray(q, dtype=np.float64).copy()
    obs[keys["gripper_position"]] = np.array([closure], dtype=np.float64)
    obs[keys["prompt"]] = task
    return obs, hashlib.sha256(image.tobytes()).hexdigest()


def _closure_to_signal(emb, closure: np.ndarray) -> np.ndarray:
    """(n,) closure → (n, G) raw gripper signals (every gripper follows the one command)."""
    from ..kinematics.workspace import openness_to_signal

    openness = np.repeat((1.0 - np.asarray(closure, float))[:, None], len(emb.grippers), axis=1)
    return openness_to_signal(emb, openness)


def _signal_to_closure(emb, signal: np.ndarray) -> float:
    if not len(emb.grippers):
        return 0.0
    return float(1.0 - emb.gripper_openness(np.asarray(signal, float)[None, :])[0, 0])


def run_cell(
    world,
    policy,
    spec: PolicySpec,
    emb,
    *,
    q0,
    g0,
    task: str,
    horizon: int,
    extras: dict | None = None,
    replan_every: int | None = None,
    timeout_s: float | None = None,
) -> CellRun:
    """Run one cell (module docstring, steps 1–5) and return what it did; a policy fault ends it with a reason."""
    adapter = ActionAdapter(emb, spec.action_space, spec.gripper, spec.control_hz)
    K = int(replan_every or spec.actions_per_call)
    timeout = float(timeout_s or spec.timeout_s)
    fps, n = world.fps, world.chunk
    frames = [world.first]
    q_frames = [np.asarray(q0, float)]
    g_frames = [np.asarray(g0, float)]
    times, knots_q = [0.0], [np.asarray(q0, float)]
    knots_c = [_signal_to_closure(emb, g0)]
    calls: list[dict] = []
    clipped = 0
    fault, done = None, False
    if hasattr(policy, "reset"):
        try:
            policy.reset()
        except Exception as exc:  # noqa: BLE001 - a policy's own fault
            fault = f"reset raised {type(exc).__name__}: {str(exc).strip()[:300]}"
    while fault is None and not done and len(frames) < horizon:
        end_t = (len(frames) - 1 + n) / fps  # the next chunk's last frame
        while times[-1] < end_t - 1e-9:
            obs, digest = _observation(spec, frames[-1], knots_q[-1], knots_c[-1], task, extras or {})
            record = {"frame": len(frames) - 1, "image_sha256": digest, "t_s": round(times[-1], 6)}
            try:
                answer, seconds = call_policy(policy, obs, timeout)
                record["latency_s"] = round(seconds, 6)
                actions = check_answer(answer, width=adapter.width, min_horizon=K, bounds=adapter.bounds())
            except PolicyFault as exc:
                record["fault"] = exc.reason
                calls.append(record)
                fault = exc.reason
                break
            res = adapter.apply(actions[:K], knots_q[-1])
            t0 = times[-1]
            times += [t0 + (i + 1) / spec.control_hz for i in range(K)]
            knots_q += list(res.q)
            knots_c += list(res.closure)
            clipped += res.clipped
            record.update(
                actions=actions.tolist(),
                executed=K,
                clipped=res.clipped,
                ik_position_error_m=[None if np.isnan(v) else float(v) for v in res.ik_position_error],
                ik_rotation_error_rad=[None if np.isnan(v) else float(v) for v in res.ik_rotation_error],
            )
            calls.append(record)
            if isinstance(answer, dict) and answer.get("done") is True:
                done = True
                break
        if fault is not None:
            break
        if done and times[-1] < end_t - 1e-9:  # done mid-chunk: hold the last pose to the chunk's end
            times.append(end_t)
            knots_q.append(knots_q[-1])
            knots_c.append(knots_c[-1])
        at = (len(frames) + np.arange(n)) / fps
        qs, cs = resample(np.array(times), np.array(knots_q), np.array(knots_c), at)
        gs = _closure_to_signal(emb, cs)
        new = world.step(qs, gs)
        frames += list(new)
        q_frames += list(qs)
        g_frames += list(gs)
    T = min(len(frames), horizon)
    return CellRun(np.stack(frames[:T]), np.stack(q_frames[:T]), np.stack(g_frames[:T]), calls, fault, done, clipped)


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


def _write_json(path: Path, data) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, (json.dumps(data, indent=1, default=str) + "\n").encode())


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


def run_closed_loop(
    manifest,
    out,
    *,
    model=None,
    model_spec: str | None = None,
    revision: str | None = None,
    simulator: Callable | None = None,
    judge=None,
    sampler=None,
    chunk_frames: int | None = None,
    fps: float | None = None,
    replan_every: int | None = None,
    policy_timeout: float | None = None,
    retry_failed: bool = False,
    policy_sources: dict | None = None,
    device="cpu",
    dtype=None,
    plugin_paths=(),
    progress: bool = False,
    log: Callable[[str], None] | None = None,
) -> ClosedLoopResult:
    """Run every cell of ``manifest`` (a path or a loaded manifest) closed loop and write ``out``.

    The world: the world model ``model`` (loaded) or ``model_spec`` (``oscar_zoo.load``; loaded only if some cell
    must run); or ``simulator``, a factory ``(session, emb, camera, first, size, fps, chunk_frames) -> world``
    (then ``fps`` and ``chunk_frames`` are required). judge: a success judge (``judge_many``) run on every
    finished cell's video, or None. replan_every: actions executed per call for every policy (default: each
    policy's ``actions_per_call``); policy_timeout: seconds per call for every policy (default: each policy's
    ``timeout_s``); retry_failed: redo cells recorded as failed; policy_sources: ``{name: source}`` replacing
    the manifest's sources. Returns :class:`ClosedLoopResult`; writes ``OUT/report.json`` and
    ``OUT/summary.md``.
    """
    from ..model.sampler import SamplerConfig
    from ..plugin.registry import get_embodiment

    log = log or _log.info
    manifest = manifest if isinstance(manifest, ClosedLoopManifest) else load_closed_loop_manifest(manifest)
    for name, value in (("replan_every", replan_every), ("chunk_frames", chunk_frames)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise MetricInputError(name, "value", "an integer >= 1", repr(value))
    if policy_timeout is not None and not policy_timeout > 0:
        raise MetricInputError("policy_timeout", "value", "a positive number of seconds", repr(policy_timeout))
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
    if simulator is None and model is None and model_spec is None:
        raise MetricInputError("model", "model", "a world model, a model spec or a simulator", "none")
    if simulator is not None and (fps is None or chunk_frames is None):
        raise MetricInputError(
            "simulator", "fps/chunk_frames", "both given for a simulator world", f"{fps}/{chunk_frames}"
        )
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
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for folder in (out, *sorted(out.glob("cells/*/*"))):
        sweep_dead_temporaries(folder)
    sampler = sampler or SamplerConfig()
    loaded = {"model": model}

    def get_model():
        if loaded["model"] is None:
            import oscar_zoo

            log(f"loading world model {model_spec}")
            loaded["model"] = oscar_zoo.load(model_spec, revision, device=device, dtype=dtype)
        return loaded["model"]

    if simulator is not None:
        world_id = {
            "kind": "simulator",
            "name": getattr(simulator, "identity", repr(simulator)),
            "fps": fps,
            "chunk_frames": chunk_frames,
            "size": manifest.size,
        }
    else:
        world_id = {
            "kind": "world-model",
            "model": _stage.model_identity(model_spec, revision) if model_spec else f"object:{type(model).__name__}",
            "sampler": dataclasses.asdict(sampler),
            "chunk_frames": chunk_frames,
            "size": manifest.size,
        }
    counts = {"cells": len(manifest.sessions) * len(specs), "done": 0, "reused": 0, "failed": 0, "retried": 0}
    records: list[dict] = []
    policies: dict[str, object] = {}
    bar = progress_bar(total=counts["cells"], desc="closed loop", unit="cell", enabled=progress)
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
                    records.append(rec)
                    bar.update(1)
                    continue
                counts["retried"] += rec["status"] == "failed"
            elif rec is not None:
                log(
                    f"{s.session}/{spec.name}: redone, its inputs changed: "
                    + "; ".join(_stage.changes(rec.get("parts"), parts))
                )
            rec = _run_and_write(
                out,
                s,
                spec,
                embs[s.embodiment],
                parts,
                key,
                policies=policies,
                get_model=get_model,
                simulator=simulator,
                sampler=sampler,
                size=manifest.size,
                chunk_frames=chunk_frames,
                fps=fps,
                K=K,
                timeout=policy_timeout,
                log=log,
            )
            counts["done"] += 1
            counts["failed"] += rec["status"] == "failed"
            records.append(rec)
            bar.update(1)
    bar.close()
    if judge is not None:
        _judge(out, manifest, records, judge, progress, log)
    from .closed_loop_report import build_closed_loop_report, write_closed_loop_report

    report = build_closed_loop_report(manifest, specs, records, counts, world_id, judge)
    paths = write_closed_loop_report(out, report)
    return ClosedLoopResult(out, records, counts, report, paths)


def _judge(out: Path, manifest: ClosedLoopManifest, records: list[dict], judge, progress: bool, log) -> None:
    """Judge every finished cell's video; a valid verdict is stored in its record and reused while the judge's
    description matches (as ``eval run`` does)."""
    from ..metrics.judge import JudgeClip
    from .loop import _judge_id

    jid = _judge_id(judge)
    by_name = {s.session: s for s in manifest.sessions}
    todo = [
        r
        for r in records
        if r["status"] == "ok" and not (isinstance(r.get("verdict"), dict) and r["verdict"].get("judge_id") == jid)
    ]
    if not todo:
        return
    log(f"judging {len(todo)} closed-loop videos")
    clips = [
        JudgeClip(
            name=f"{r['session']}/{r['policy']}",
            video=out / r["video"],
            instruction=by_name[r["session"]].task,
            policy=r["policy"],
            session=r["session"],
            info=by_name[r["session"]].info,
        )
        for r in todo
    ]
    for r, v in zip(todo, judge.judge_many(clips, progress=progress)):
        if v.ok:
            r["verdict"] = {"judge_id": jid, "binary": v.binary, "partial": v.partial, "reason": v.reason}
            _write_json(out / r["dir"] / "record.json", r)
        else:
            r["verdict"] = {"judge_id": None, "binary": None, "status": v.status, "error": v.error}


def _run_and_write(
    out: Path,
    s: Session,
    spec: PolicySpec,
    emb,
    parts: dict,
    key: str,
    *,
    policies: dict,
    get_model,
    simulator,
    sampler,
    size,
    chunk_frames,
    fps,
    K: int,
    timeout,
    log,
) -> dict:
    """Run one cell and write its files, the record last."""
    from ..kinematics.trajectory import Trajectory, load_trajectory, save_trajectory
    from ..media.video import write_video
    from ..model.image import read_first_frame
    from ..render.skeleton_video import fit_image

    folder = cell_dir(out, s.session, spec.name)
    folder.mkdir(parents=True, exist_ok=True)
    camera = emb.load_camera(s.camera)
    state = emb.check_trajectory(load_trajectory(s.initial_state))
    q0, g0 = state.q[0], state.gripper[0]
    first = read_first_frame(s.first_frame, camera, str(s.camera))
    t0 = time.perf_counter()
    if simulator is not None:
        size = size or (first.shape[1], first.shape[0])
        first = fit_image(first, size[0], size[1], "crop")
        world = simulator(s, emb, camera, first, size, fps, chunk_frames)
    else:
        from .rollout_engines import cell_prompt

        model = get_model()
        card = model.card
        size = size or ((card.width, card.height) if card.width and card.height else (first.shape[1], first.shape[0]))
        first = fit_image(first, size[0], size[1], "crop")
        world = ModelWorld(
            model,
            first=first,
            camera=camera,
            camera_source=str(s.camera),
            emb=emb,
            q0=q0,
            g0=g0,
            fps=float(card.fps or fps or 10.0),
            chunk_frames=int(chunk_frames or card.chunk_frames),
            size=size,
            prompt=cell_prompt(s),
            sampler=sampler,
            seed=s.seed,
        )
    fault = None
    if spec.name not in policies:
        try:
            policies[spec.name] = load_policy(spec.source)
        except Exception as exc:  # noqa: BLE001 - a policy that cannot be loaded fails its cells, not the run
            policies[spec.name] = PolicyFault(f"cannot load {spec.source}: {str(exc).strip()[:300]}")
    policy = policies[spec.name]
    if isinstance(policy, PolicyFault):
        run = CellRun(first[None], q0[None], g0[None], [], policy.reason)
    else:
        run = run_cell(
            world,
            policy,
            spec,
            emb,
            q0=q0,
            g0=g0,
            task=s.task,
            horizon=s.horizon,
            extras=s.extras,
            replan_every=K,
            timeout_s=timeout,
        )
    seconds = time.perf_counter() - t0
    fault = run.fault
    if fault is not None:  # a timed-out call may still run, a remote connection may be broken: load it afresh
        policies.pop(spec.name, None)
    rel = folder.relative_to(out)
    _write_json(folder / "calls.json", {"policy": spec.name, "session": s.session, "calls": run.calls})
    latencies = [c["latency_s"] for c in run.calls if "latency_s" in c]
    rec = {
        "v": RECORD_VERSION,
        "session": s.session,
        "policy": spec.name,
        "key": key,
        "parts": parts,
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
    _write_json(folder / "record.json", rec)
    return rec


def _max_ik(calls: list[dict]) -> float | None:
    vals = [v for c in calls for v in (c.get("ik_position_error_m") or []) if v is not None]
    return float(max(vals)) if vals else None
