"""One closed-loop cell: its world (the world model as :class:`ModelWorld`), its loop (:func:`cell_steps`,
:func:`run_cell`) and its policy objects (:class:`PolicyPool`).

The loop and what is kept per cell are described in :mod:`oscar_core.evaluation.closed_loop`, which runs the cells
of a manifest; :mod:`.closed_loop_batch` drives several cells' loops in lock-step and :mod:`.closed_loop_ray` runs
cells on Ray actors, both from the pieces here.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..policy.loading import load_policy
from ..policy.protocol import PolicyFault, PolicySpec, call_policy, check_answer
from .closed_loop_manifest import Session
from .closed_loop_step import CellState

__all__ = [
    "LOAD_FAULT",
    "CellRun",
    "ModelWorld",
    "OpenCell",
    "PolicyPool",
    "cell_steps",
    "check_one_frame_context",
    "chunk_seed",
    "drive",
    "generate_chunks",
    "never_loaded",
    "open_cell",
    "open_world",
    "run_cell",
    "run_open_cell",
]


#: How the reason of a cell whose policy could not be loaded begins (:meth:`PolicyPool.take`).
LOAD_FAULT = "cannot load "


def never_loaded(record: dict) -> bool:
    """The cell failed because its policy could not be loaded (it never acted)."""
    return record.get("status") == "failed" and str(record.get("reason") or "").startswith(LOAD_FAULT)


def check_one_frame_context(card, where: str = "model card") -> None:
    """Raise :class:`~oscar_core.metrics.common.MetricInputError` naming the card's ``context_frames`` unless it is 1:
    the closed loop steps a world model a fixed chunk of new frames at a time from its last frame, and a model with a
    longer context (:mod:`oscar_core.model.chunks`) makes fewer new frames per chunk after its first."""
    n = getattr(card, "context_frames", 1)
    if n != 1:
        from ..metrics.common import MetricInputError

        raise MetricInputError(
            where,
            "context_frames",
            "1 (the closed loop and its environments step a world model from its last frame alone)",
            repr(n),
        )


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
        check_one_frame_context(getattr(model, "card", None))
        self.model, self.first, self.camera, self.camera_source, self.emb = model, first, camera, camera_source, emb
        self.fps, self.chunk_frames, self.chunk = float(fps), int(chunk_frames), int(chunk_frames) - 1
        self.size, self.prompt, self.sampler, self.seed = tuple(size), prompt, sampler, seed
        self.q, self.g = np.asarray(q0, float)[None], np.asarray(g0, float)[None]
        self.last = first
        self.steps = 0
        self.condition: list[np.ndarray] = []
        self.timing = {"render_s": 0.0, "model_s": 0.0}  # seconds spent rendering conditions / in the model

    def _condition(self, q: np.ndarray, g: np.ndarray) -> dict:
        """The model's inputs for a chunk's poses: ``video`` (L, H, W, 3) uint8 and, for a model with a gripper
        signal, ``gripper`` (L, G) openness (else None)."""
        from ..kinematics.trajectory import Trajectory

        traj = Trajectory(
            self.emb.joint_names, q, self.fps, g, self.emb.gripper_names or None, source="<closed-loop chunk>"
        )
        if hasattr(self.model, "rollout_inputs"):
            inputs = self.model.rollout_inputs(
                traj, self.camera, self.emb, self.size, resize_mode="crop", camera_source=self.camera_source
            )
            return {"video": inputs["skeleton"], "gripper": inputs.get("gripper")}
        from ..render.conditions import condition_video, video_condition_of

        video = condition_video(
            video_condition_of(self.model.card.condition),
            self.emb,
            traj,
            self.camera,
            self.size,
            resize_mode="crop",
            camera_source=self.camera_source,
            style=getattr(self.model.card, "condition_style", None),
        )
        return {"video": video, "gripper": None}

    def chunk_inputs(self, q: np.ndarray, gripper: np.ndarray) -> dict:
        """The world model's inputs for the next chunk, for joint positions ``q`` (n, J) and gripper signals
        (n, G), n = chunk: ``first`` (H, W, 3) uint8 the last generated frame, ``video`` (L, H, W, 3) uint8 the
        condition video from the last pose on, ``gripper`` (L, G) openness or None (a model with a gripper
        signal), ``prompt``, ``seed`` (this chunk's, :func:`chunk_seed`)."""
        t0 = time.perf_counter()
        cond = self._condition(np.concatenate([self.q[-1:], q]), np.concatenate([self.g[-1:], gripper]))
        self.timing["render_s"] += time.perf_counter() - t0
        return {"first": self.last, **cond, "prompt": self.prompt, "seed": chunk_seed(self.seed, self.steps)}

    def accept(self, q: np.ndarray, gripper: np.ndarray, inputs: dict, frames: np.ndarray) -> np.ndarray:
        """Take the chunk generated from ``inputs`` (:meth:`chunk_inputs`): frames (L, H, W, 3) uint8, its first
        the seed frame; returns the (n, H, W, 3) new ones."""
        cond = inputs["video"]
        self.condition += [cond[0]] if not self.condition else []
        self.condition += list(cond[1:])
        new = frames[1:]
        self.q, self.g = np.concatenate([self.q, q]), np.concatenate([self.g, gripper])
        self.last = new[-1]
        self.steps += 1
        return new

    def step(self, q: np.ndarray, gripper: np.ndarray) -> np.ndarray:
        """(n, H, W, 3) uint8 new frames for joint positions ``q`` (n, J) and gripper signals (n, G), n = chunk."""
        inputs = self.chunk_inputs(q, gripper)
        t0 = time.perf_counter()
        (frames,) = generate_chunks(self.model, [inputs], chunk_frames=self.chunk_frames, sampler=self.sampler)
        self.timing["model_s"] += time.perf_counter() - t0
        return self.accept(q, gripper, inputs, frames)

    def outcome(self) -> dict:
        return {}


def generate_chunks(model, inputs: list[dict], *, chunk_frames: int, sampler) -> list[np.ndarray]:
    """One chunk for each of ``inputs`` (:meth:`ModelWorld.chunk_inputs`): one ``rollout`` for one input, one
    ``rollout_batch`` for several (each equal to its own rollout up to float rounding; ``eval run``'s
    :func:`~.rollout_engines.roll_out_cells` does the same). Returns (L, H, W, 3) uint8 videos, the seed frame
    first."""
    from .rollout_engines import roll_out_group

    group = [{**i, "actions": None} for i in inputs]
    return roll_out_group(
        model, group, sampler=sampler, chunk_frames=chunk_frames, seeds=[i["seed"] for i in inputs], progress=False
    )


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


def cell_steps(
    first,
    fps: float,
    chunk: int,
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
):
    """One cell (module docstring, steps 1–5) as a generator, for a driver that owns the world.

    first: (H, W, 3) uint8 the world's first frame; fps: the world's frame rate; chunk: new frames per world step.
    Yields ``(q, gripper)``, (chunk, J) joint positions and (chunk, G) gripper signals of the next chunk's frames,
    and expects to be sent that chunk's (chunk, H, W, 3) uint8 frames; returns (``StopIteration.value``) the
    :class:`CellRun`. :func:`run_cell` drives it with one world; the lock-step driver
    (:mod:`.closed_loop_batch`) drives many at once and batches their chunks.
    """
    state = CellState(first, fps, chunk, spec, emb, q0=q0, g0=g0, horizon=horizon)
    K = int(replan_every or spec.actions_per_call)
    timeout = float(timeout_s or spec.timeout_s)
    bounds = state.adapter.bounds()
    calls: list[dict] = []
    fault, done = None, False
    if hasattr(policy, "reset"):
        try:
            policy.reset()
        except Exception as exc:  # noqa: BLE001 - a policy's own fault
            fault = f"reset raised {type(exc).__name__}: {str(exc).strip()[:300]}"
    while fault is None and not done and not state.finished:
        while not state.covered:
            obs, digest = state.observe(task, extras or {})
            record = {"frame": state.frame_index, "image_sha256": digest, "t_s": round(state.times[-1], 6)}
            try:
                answer, seconds = call_policy(policy, obs, timeout)
                record["latency_s"] = round(seconds, 6)
                actions = check_answer(answer, width=state.adapter.width, min_horizon=K, bounds=bounds)
            except PolicyFault as exc:
                record["fault"] = exc.reason
                calls.append(record)
                fault = exc.reason
                break
            t_adapt = time.perf_counter()
            res = state.execute(actions[:K])
            record["adapter_s"] = round(time.perf_counter() - t_adapt, 6)
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
        if done:  # done mid-chunk: hold the last pose to the chunk's end
            state.hold()
        qs, gs = state.chunk_request()
        new = yield qs, gs
        state.accept(qs, gs, new)
    return CellRun(*state.paths(), calls, fault, done, state.clipped)


def run_cell(world, policy, spec: PolicySpec, emb, **loop) -> CellRun:
    """Run one cell in ``world`` (module docstring, steps 1–5) and return what it did; a policy fault ends it with
    a reason. ``loop``: the keyword arguments of :func:`cell_steps` (q0, g0, task, horizon, extras, replan_every,
    timeout_s)."""
    return drive(cell_steps(world.first, world.fps, world.chunk, policy, spec, emb, **loop), world)


def drive(steps, world) -> CellRun:
    """Run a cell's :func:`cell_steps` generator to its end with ``world`` generating every chunk it asks for."""
    try:
        request = next(steps)
        while True:
            request = steps.send(world.step(*request))
    except StopIteration as stop:
        return stop.value


@dataclass
class OpenCell:
    """A cell ready to run: its session, policy declaration and embodiment, fingerprint ``parts`` and ``key``, the
    world, the policy object (or the :class:`PolicyFault` that loading it raised), the robot's first state
    (q0 (J,), g0 (G,)), the executed actions per call ``K`` and when it was opened (``perf_counter``)."""

    session: Session
    spec: PolicySpec
    emb: object
    parts: dict
    key: str
    world: object
    policy: object
    q0: np.ndarray
    g0: np.ndarray
    K: int
    started: float

    def steps(self, timeout):
        """The cell's :func:`cell_steps` generator."""
        s = self.session
        return cell_steps(
            self.world.first,
            self.world.fps,
            self.world.chunk,
            self.policy,
            self.spec,
            self.emb,
            q0=self.q0,
            g0=self.g0,
            task=s.task,
            horizon=s.horizon,
            extras=s.extras,
            replan_every=self.K,
            timeout_s=timeout,
        )


class PolicyPool:
    """Policy objects by policy name, loaded on demand: :meth:`take` one (a loaded one that is free, else a new
    one from its source), :meth:`give` it back after a cell that ended well. A policy whose cell failed is
    dropped (a timed-out call may still run, a connection may be broken), so the next cell loads it afresh.
    One cell runs at a time per object; cells in flight together (``batch_cells``) get one object each."""

    def __init__(self):
        self.free: dict[str, list] = {}

    def take(self, spec: PolicySpec):
        if self.free.get(spec.name):
            return self.free[spec.name].pop()
        try:
            return load_policy(spec.source, keys=spec.keys)
        except Exception as exc:  # noqa: BLE001 - a policy that cannot be loaded fails its cells, not the run
            return PolicyFault(f"{LOAD_FAULT}{spec.source}: {str(exc).strip()[:300]}")

    def preload(self, specs) -> None:
        """Load (or connect) one object of every policy in ``specs`` and keep it for the first cell; raises
        :class:`~oscar_core.policy.loading.PolicyLoadError` with one line per policy that cannot be, so a run
        stops before any model loads or cell runs."""
        from ..policy.loading import PolicyLoadError

        bad = []
        for spec in specs:
            try:
                self.give(spec, load_policy(spec.source))
            except Exception as exc:  # noqa: BLE001 - each named on its line
                text = str(exc).strip()[:300]
                bad.append(
                    f"policy {spec.name!r} cannot be loaded: "
                    + (text if spec.source in text else f"{spec.source}: {text}")
                )
        if bad:
            raise PolicyLoadError(bad)

    def give(self, spec: PolicySpec, policy) -> None:
        if policy is not None and not isinstance(policy, PolicyFault):
            self.free.setdefault(spec.name, []).append(policy)


def open_world(s: Session, emb, *, get_model, simulator, sampler, size, chunk_frames, fps):
    """Read a session's inputs and build its world: returns ``(world, q0, g0)``, the world (the simulator
    factory's, or a :class:`ModelWorld` of ``get_model()``) and the robot's first joint positions (J,) and gripper
    signals (G,) from frame 0 of ``initial_state``. size: (width, height) or None (the card's, else the first
    frame's); chunk_frames, fps: None for the model card's."""
    from ..kinematics.trajectory import load_trajectory
    from ..model.image import read_first_frame
    from ..render.skeleton_video import fit_image

    camera = emb.load_camera(s.camera)
    state = emb.check_trajectory(load_trajectory(s.initial_state))
    q0, g0 = state.q[0], state.gripper[0]
    first = read_first_frame(s.first_frame, camera, str(s.camera))
    if simulator is not None:
        size = size or (first.shape[1], first.shape[0])
        first = fit_image(first, size[0], size[1], "crop")
        return simulator(s, emb, camera, first, size, fps, chunk_frames), q0, g0
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
    return world, q0, g0


def open_cell(
    s: Session,
    spec: PolicySpec,
    emb,
    parts: dict,
    key: str,
    *,
    pool: PolicyPool,
    get_model,
    simulator,
    sampler,
    size,
    chunk_frames,
    fps,
    K: int,
) -> OpenCell:
    """Read a cell's session inputs, build its world (:func:`open_world`) and take its policy object."""
    t0 = time.perf_counter()
    world, q0, g0 = open_world(
        s, emb, get_model=get_model, simulator=simulator, sampler=sampler, size=size, chunk_frames=chunk_frames, fps=fps
    )
    return OpenCell(s, spec, emb, parts, key, world, pool.take(spec), q0, g0, K, t0)


def failed_to_load(cell: OpenCell) -> CellRun:
    first = cell.world.first
    return CellRun(first[None], cell.q0[None], cell.g0[None], [], cell.policy.reason)


def run_open_cell(cell: OpenCell, timeout) -> CellRun:
    """Run an opened cell in its own world, in this thread."""
    if isinstance(cell.policy, PolicyFault):
        return failed_to_load(cell)
    return drive(cell.steps(timeout), cell.world)
