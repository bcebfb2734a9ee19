"""Where ``oscar eval run``'s rollouts happen: in this process, or on Ray actors across GPUs and machines.

Both engines use :func:`roll_out_cells`: a cell's inputs (its first frame at the rollout size, the card's
condition video — skeleton or mesh — and its prompt embedding) are computed, consecutive cells sharing one
frame count, size and prompt shape are rolled out together in batches of up to ``batch_cells``
(:meth:`~oscar_core.model.OscarWorldModel.rollout_batch`: each video equals its one-at-a-time rollout up to
float rounding), and each group is handed back as soon as it is done.

``engine="ray"`` (:func:`roll_out_on_ray`) starts ``workers`` actors (``num_gpus=1`` each on CUDA, else one
CPU each), each loading the model once from the model spec; groups of cells are queued to whichever actor is
free, and the frames come back to this process, which writes every video and record — so the run folder,
the resume rule (a killed run redoes only the cells without a record) and the report are the local engine's,
and the workers need no access to the output folder. It joins a running Ray cluster (``ray.init()`` finds
``RAY_ADDRESS``) or starts a local one.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Iterator, Sequence

import numpy as np

from ..metrics.common import MetricInputError
from ..render.conditions import takes_actions
from .manifest import Cell

__all__ = [
    "cell_inputs",
    "cell_prompt",
    "ray_result",
    "roll_out_cells",
    "roll_out_group",
    "roll_out_on_ray",
    "start_ray_actors",
]


def cell_prompt(cell: Cell):
    """The cell's prompt embedding (1, L, D) from its safetensors file, or None (the model's empty prompt)."""
    if cell.prompt_embeds is None:
        return None
    from safetensors.torch import load_file

    from ..model.weights import check_safetensors

    check_safetensors(cell.prompt_embeds)
    tensors = load_file(str(cell.prompt_embeds))
    if "prompt_embeds" in tensors:
        return tensors["prompt_embeds"]
    if len(tensors) == 1:
        return next(iter(tensors.values()))
    raise MetricInputError(cell.prompt_embeds, "tensors", "a tensor named 'prompt_embeds'", sorted(tensors))


def cell_inputs(model, cell: Cell, size, plugin_paths) -> dict:
    """The cell's rollout inputs: ``first`` (H, W, 3) uint8 at the rollout size, ``video`` (T, H, W, 3) uint8
    condition video (the card's: skeleton, mesh or capsules; None for a latent-action model), ``actions``
    (T − 1, 14) for a latent-action model (else None), ``prompt`` (1, L, D) or None, ``fps``."""
    from ..kinematics.trajectory import load_trajectory
    from ..model.image import read_first_frame
    from ..plugin.registry import get_embodiment
    from ..render.skeleton_video import fit_image

    emb = get_embodiment(cell.embodiment, plugin_paths)
    traj = load_trajectory(cell.trajectory)
    camera = emb.load_camera(cell.camera)
    first = read_first_frame(cell.first_frame, camera, cell.camera)
    card = model.card
    if size is None:
        size = (card.width, card.height) if card.width and card.height else (first.shape[1], first.shape[0])
    # what the card's condition needs: its condition video (skeleton, mesh, capsules) or the trajectory's actions
    if hasattr(model, "rollout_inputs"):  # an OscarWorldModel
        cond = model.rollout_inputs(traj, camera, emb, size, resize_mode="crop", camera_source=str(cell.camera))
    else:  # any model with rollout(first, skeleton, prompt, ...) (evaluation/loop.py): the card's condition video
        from ..render.conditions import condition_video, video_condition_of

        cond = {
            "skeleton": condition_video(
                video_condition_of(card.condition),
                emb,
                traj,
                camera,
                size,
                resize_mode="crop",
                camera_source=str(cell.camera),
                style=getattr(card, "condition_style", None),
            )
        }
    first = fit_image(first, size[0], size[1], "crop")
    return {
        "first": first,
        "video": cond.get("skeleton"),
        "actions": cond.get("actions"),
        "gripper": cond.get("gripper"),
        "prompt": cell_prompt(cell),
        "fps": float(traj.fps),
    }


def _batch_key(inputs: dict) -> tuple:
    """Cells roll out in one batch only with one chunk plan and size and one prompt shape."""
    prompt = inputs["prompt"]
    cond = inputs["video"] if inputs["video"] is not None else inputs["actions"]
    return cond.shape, None if prompt is None else tuple(prompt.shape)


def roll_out_group(model, group: list[dict], *, sampler, chunk_frames, seeds, progress) -> list[np.ndarray]:
    """Roll out a group of inputs (``first``, ``video``, ``prompt``, ``actions``): one ``rollout`` for a group of
    one, else one ``rollout_batch``; (T, H, W, 3) uint8 videos."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "trained at WxH" is reported once in the run's summary instead
        if len(group) == 1:
            g = group[0]
            # a latent-action model's input, or a gripper-signal model's second input
            extra = {k: g[k] for k in ("actions", "gripper") if g.get(k) is not None}
            return [
                model.rollout(
                    g["first"],
                    g["video"],
                    g["prompt"],
                    chunk_frames=chunk_frames,
                    sampler=sampler,
                    seed=seeds[0],
                    progress=progress,
                    keep_chunks=False,
                    **extra,
                ).frames
            ]
        return model.rollout_batch(
            [g["first"] for g in group],
            [g["video"] for g in group],
            [g["prompt"] for g in group],
            chunk_frames=chunk_frames,
            sampler=sampler,
            seeds=seeds,
            progress=progress,
            **({"grippers": [g["gripper"] for g in group]} if group[0].get("gripper") is not None else {}),
        )


def roll_out_cells(
    model, cells: Sequence[Cell], *, size, sampler, chunk_frames, plugin_paths, batch_cells: int, progress: bool = False
) -> Iterator[tuple[list, list]]:
    """Roll ``cells`` out in order; yields ``([(cell, seconds per cell), ...], [(frames, fps), ...])`` per group.

    A group is consecutive cells with one :func:`_batch_key`, at most ``batch_cells`` of them (one for a
    latent-action model); frames are (T, H, W, 3) uint8.
    """
    per_batch = batch_cells if not takes_actions(model.card.condition) else 1
    group: list[Cell] = []
    inputs: list[dict] = []

    def flush():
        t0 = time.perf_counter()
        videos = roll_out_group(
            model, inputs, sampler=sampler, chunk_frames=chunk_frames, seeds=[c.seed for c in group], progress=progress
        )
        seconds = (time.perf_counter() - t0) / len(group)
        return [(c, seconds) for c in group], [(v, inp["fps"]) for v, inp in zip(videos, inputs)]

    for cell in cells:
        inp = cell_inputs(model, cell, size, plugin_paths)
        if group and (len(group) >= per_batch or _batch_key(inp) != _batch_key(inputs[0])):
            yield flush()
            group, inputs = [], []
        group.append(cell)
        inputs.append(inp)
    if group:
        yield flush()


class _RolloutWorker:
    """A Ray actor's state: one model, loaded once; :meth:`roll` rolls a list of cells out."""

    def __init__(
        self,
        model_spec: str,
        revision,
        device: str,
        dtype_name: str | None,
        plugin_paths: tuple,
        compile: str = "auto",
        cells: int = 1,
    ):
        import torch

        import oscar_zoo

        dtype = getattr(torch, dtype_name) if dtype_name else None
        self.model = oscar_zoo.load(model_spec, revision, device=device, dtype=dtype)
        self.model.set_compile(compile, cells=cells)  # compiled once per worker, weighed over its share of cells
        self.plugin_paths = plugin_paths

    def roll(self, cells: list[Cell], options: dict) -> list[tuple[str, np.ndarray, float, float, int]]:
        """[(cell id, frames, fps, seconds per cell, batch size)] of ``cells``, in order."""
        out = []
        for group, videos in roll_out_cells(self.model, cells, plugin_paths=self.plugin_paths, **options):
            out += [(c.id, frames, fps, seconds, len(group)) for (c, seconds), (frames, fps) in zip(group, videos)]
        return out


def start_ray_actors(
    cls, jobs: int, *, workers: int, model_spec, revision, device, dtype, plugin_paths, log, extra: Callable
) -> tuple:
    """Start ``min(workers, jobs, free)`` Ray actors of ``cls`` (``num_gpus=1`` each on CUDA, else one CPU each),
    joining a running cluster (``RAY_ADDRESS``) or starting a local one. Each actor is constructed with
    ``(model_spec, revision, device, dtype name, plugin_paths, *extra(share))`` (share: jobs per actor). Returns ``(ray, actors, n, gpu)``; no free CPU/GPU for even one
    actor is an input error (an actor Ray cannot place would wait forever)."""
    from .._util.optional import require

    ray = require("ray", "ray")
    if not ray.is_initialized():
        ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False, ignore_reinit_error=True)
    gpu = str(device).startswith("cuda")
    resources = {"num_gpus": 1, "num_cpus": 0} if gpu else {"num_cpus": 1}
    kind = "GPU" if gpu else "CPU"
    free = int(ray.available_resources().get(kind, 0))
    if free < 1:
        raise MetricInputError(
            "engine",
            "ray",
            f"a Ray cluster with a free {kind} for each worker",
            f"no free {kind} (cluster: {ray.cluster_resources()})",
        )
    n = min(workers, jobs, free)
    if n < min(workers, jobs):
        log(f"the Ray cluster has {free} free {kind}(s): starting {n} worker(s) instead of {workers}")
    actor_cls = ray.remote(**resources)(cls)
    share = -(-jobs // n)  # jobs per worker
    dtype_name = str(dtype).removeprefix("torch.") if dtype is not None else None
    args = (model_spec, revision, "cuda" if gpu else str(device), dtype_name, tuple(plugin_paths), *extra(share))
    return ray, [actor_cls.remote(*args) for _ in range(n)], n, gpu


def ray_result(ray, ref, model_spec):
    """``ray.get(ref)``; a worker's fault is the run's, raised as an input error naming its cause (not Ray's
    wrapper), or the worker's death (e.g. its model could not load)."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as exc:
        cause = exc.as_instanceof_cause() if hasattr(exc, "as_instanceof_cause") else exc
        raise MetricInputError("engine", "ray", "every worker's cells", f"{type(cause).__name__}: {cause}") from None
    except ray.exceptions.RayActorError as exc:
        raise MetricInputError(
            "engine", "ray", f"a worker that loads {model_spec}", str(exc).strip().splitlines()[-1][:2000]
        ) from None


def roll_out_on_ray(
    pending: list[tuple[int, Cell, str]],
    record: Callable,
    *,
    model_spec: str,
    revision,
    device,
    dtype,
    workers: int,
    size,
    sampler,
    chunk_frames,
    plugin_paths,
    batch_cells: int,
    log: Callable[[str], None],
    compile: str = "auto",
) -> None:
    """Roll the ``pending`` cells ((index, cell, rollout key), manifest order) out on ``workers`` Ray actors and
    call ``record(index, cell, key, frames, fps, seconds, batch)`` for each as its group comes back."""
    ray, actors, n, gpu = start_ray_actors(
        _RolloutWorker,
        len(pending),
        workers=workers,
        model_spec=model_spec,
        revision=revision,
        device=device,
        dtype=dtype,
        plugin_paths=plugin_paths,
        log=log,
        extra=lambda share: (compile, share),
    )
    log(f"rolling {len(pending)} cells out on {n} Ray worker(s) ({'one GPU' if gpu else 'one CPU'} each)")
    options = dict(size=size, sampler=sampler, chunk_frames=chunk_frames, batch_cells=batch_cells)
    queue = [pending[i : i + batch_cells] for i in range(0, len(pending), batch_cells)]
    by_id = {c.id: (k, c, key) for k, c, key in pending}
    in_flight: dict = {}

    def submit(actor) -> None:
        if queue:
            chunk = queue.pop(0)
            in_flight[actor.roll.remote([c for _, c, _ in chunk], options)] = actor

    try:
        for actor in actors:
            submit(actor)
        while in_flight:
            (ref,), _ = ray.wait(list(in_flight), num_returns=1)
            actor = in_flight.pop(ref)
            results = ray_result(ray, ref, model_spec)
            submit(actor)
            for cell_id, frames, fps, seconds, batch in results:
                k, cell, key = by_id[cell_id]
                record(k, cell, key, frames, fps, seconds, batch)
    finally:
        for actor in actors:
            ray.kill(actor)
