"""The action-following benchmark: does a world model's outcome change exactly when one decision of the arm does?

:func:`run_action_following` takes a manifest of counterfactual sets (:mod:`.action_following_manifest`: one first
frame, one trajectory, variants that change one decision, the true outcome of each), and for every set

1. rolls every variant out through the model's public path — ``model.rollout_inputs(trajectory, camera,
   embodiment, size)`` and then ``model.rollout(first, inputs["skeleton"], prompt, **every other key of the
   inputs)`` — so any model type works (skeleton, mesh, latent actions, or a condition added later as another key);
   when the inputs hold the condition video alone and the model has ``rollout_batch``, the variants of a set go in
   one batch (each video equal to its own rollout up to float rounding). Every variant of a set uses the same
   noise seed, so the variants differ only by their decision;
2. judges each video (``--judge module:attr``: the verdict, 0/1) and, with true frames, judges those too (the
   judge's own error on this set);
3. with a ``locator`` (``module:attr``: frames (T, H, W, 3) uint8 → (T, 2) pixels, NaN where not found; the toy
   world's is :func:`oscar_core.toyworld.locate.ball_position`) and true frames: the object's end error (last
   frame) and per chunk of the rollout PSNR and the object error, in ball radii (pixels / ``info.ball_radius_px``;
   pixels when the set's ``info`` has no radius). A chunk's frames are ``[1 + (L − 1)(k − 1), (L − 1)k]``; a frame
   where the truth shows the object and the model does not counts as the image diagonal (losing the object is never
   better than misplacing it);
4. writes ``records/<set>.json`` atomically (a killed run resumes: a finished set is kept), and the model's videos
   under ``videos/<set>/<variant>.mp4`` (``.mkv``, lossless, for an odd width or height).

With ``settings.ceiling`` (:mod:`.action_following_ceiling`) step 1 is the autoencoder ceiling instead: each
variant's video is the model's VAE reconstruction of its true frames, chunk by chunk as the rollout decodes them;
only the VAE is loaded, every variant must have true frames, and steps 2–4 are the same.

Then :func:`~.action_following_scores.score_records` makes the scores, written as ``report.json`` and
``summary.md``. The folder's ``fingerprint.json`` holds what the records depend on (the manifest's bytes, the
model, the sampler, the seed, the chunk length, the judge and its version, the locator; a ceiling run adds its
``mode``): a re-run under other settings is refused (:class:`~oscar_core._util.stage.StageChanged`), never mixed.

Checked before any model loads (:func:`check_sets`), each a :class:`~oscar_core.metrics.common.MetricInputError`
naming the manifest and the field: the judge can read every set's ``info`` (it is run on a still video of the
first frame: a judge that raises there cannot judge the set), every set is a whole number of the model's chunks,
and the first frame and the true videos are the model's size and the trajectory's length.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .._util.log import get_logger
from ..metrics.common import MetricInputError
from .action_following_ceiling import CEILING, ROLLOUT, check_true_videos
from .action_following_manifest import ActionFollowingManifest, CounterfactualSet, load_action_following
from .action_following_measure import distance_unit, score_variant
from .action_following_scores import format_summary, paired_scores, score_records

__all__ = [
    "ActionFollowingSettings",
    "ActionFollowingResult",
    "check_sets",
    "load_locator",
    "roll_out_variants",
    "score_variant",
    "run_action_following",
    "check_encoder_mode",
    "REPORT_VERSION",
]

_log = get_logger(__name__)
REPORT_VERSION = 1


@dataclass(frozen=True)
class ActionFollowingSettings:
    """How the benchmark runs. model_spec / revision: what ``oscar_zoo.load`` loads when no model object is given;
    sampler: a :class:`~oscar_core.model.SamplerConfig` (None: the card's); seed: the noise seed of every variant;
    chunk_frames: None = the card's; device, dtype: where the model runs; plugin_paths: extra embodiment plugins;
    resamples, bootstrap_seed: the intervals' bootstrap; progress: progress bars; tiny_decoder: the decoder of the
    model loaded from ``model_spec`` (None: its card's; False: the full decoder; a tiny decoder's file), recorded
    in the run's fingerprint when given; ceiling: score the model's VAE reconstruction of each variant's true frames
    instead of its rollout (:mod:`.action_following_ceiling`; no sampler, no noise seed, only the VAE loaded, its
    decoder chosen as ``tiny_decoder`` says); tiny_encoder: a tiny encoder's file that encodes every chunk's condition
    video instead of the full encoder (None: the full one), recorded in the fingerprint when given; refused with
    ``ceiling``, which encodes no condition."""

    model_spec: str | None = None
    revision: str | None = None
    sampler: object = None
    seed: int = 0
    chunk_frames: int | None = None
    device: str = "cpu"
    dtype: object = None
    plugin_paths: tuple = ()
    resamples: int = 2000
    bootstrap_seed: int = 0
    progress: bool = False
    tiny_decoder: object = None
    ceiling: bool = False
    tiny_encoder: object = None

    def __post_init__(self):
        check_encoder_mode(self.tiny_encoder, self.ceiling)


def check_encoder_mode(tiny_encoder, ceiling: bool, what: str = "tiny_encoder") -> None:
    """Refuse a tiny condition encoder for a ceiling run, which reconstructs the true frames and encodes no
    condition video (ModelInputError naming ``what``)."""
    if ceiling and tiny_encoder not in (None, False):
        from ..model.errors import ModelInputError

        raise ModelInputError(
            f"{what}: expected none with the ceiling (it reconstructs the true frames and encodes no condition "
            f"video), found {tiny_encoder}"
        )


@dataclass
class ActionFollowingResult:
    report: dict
    records: list[dict]
    paths: dict


def load_locator(spec: str | None):
    """The locator function of ``module:attr`` (or ``file.py:attr``), or None."""
    if spec is None:
        return None
    from .._util.user_code import import_attr

    try:
        fn = import_attr(spec, "locator")
    except (ValueError, FileNotFoundError, ImportError, AttributeError) as exc:
        raise MetricInputError(spec, "locator", "an importable module:attr", f"{type(exc).__name__}: {exc}") from None
    if not callable(fn):
        raise MetricInputError(spec, "locator", "a function (frames) -> (T, 2) pixels", type(fn).__name__)
    return fn


def _set_inputs(s: CounterfactualSet, plugin_paths):
    from ..model.image import read_first_frame
    from ..plugin.registry import get_embodiment

    emb = get_embodiment(s.embodiment, plugin_paths)
    camera = emb.load_camera(s.camera)
    first = read_first_frame(s.first_frame, camera, str(s.camera))
    return emb, camera, first


def _judge_one(judge, video: np.ndarray, s: CounterfactualSet, name: str):
    from ..metrics.judge_records import JudgeClip

    clip = JudgeClip(f"{s.set}/{name}", video, s.task or "the task", policy=name, session=s.set, info=s.info)
    return judge.judge_many([clip])[0]


def check_sets(manifest: ActionFollowingManifest, judge, card, chunk_frames: int | None, plugin_paths=()) -> None:
    """The checks made before any model loads (module docstring); ``card``: the model's card (chunk length and
    size; None: no size check), ``chunk_frames``: overrides the card's."""
    from ..media.video import video_info

    L = int(chunk_frames or getattr(card, "chunk_frames", 0) or 0)
    size = (getattr(card, "width", None), getattr(card, "height", None))
    context = getattr(card, "context_frames", 1)
    if context != 1 and L >= 2:
        from ..model.chunks import check_context_frames
        from ..model.errors import ModelInputError

        try:
            check_context_frames(context, L)
        except ModelInputError:
            raise MetricInputError(
                "model card",
                "context_frames",
                f"4k+1 frames covering fewer latent frames than the {L}-frame chunk's {(L - 1) // 4 + 1}",
                repr(context),
            ) from None
    for s in manifest.sets:
        where = f"sets[{s.row}]"
        T = s.frames
        if L >= 2 and ((T - 1) % (L - 1) or T < L):
            raise MetricInputError(
                manifest.path,
                f"{where}.trajectory",
                f"1 + n x {L - 1} frames (a whole number of the model's {L}-frame chunks)",
                f"{T} frames",
            )
        emb, camera, first = _set_inputs(s, plugin_paths)
        h, w = first.shape[:2]
        if size[0] and size[1] and (w, h) != tuple(size):
            raise MetricInputError(
                manifest.path, f"{where}.first_frame", f"{size[0]}x{size[1]} (the model's size)", f"{w}x{h}"
            )
        for j, v in enumerate(s.variants):
            if v.video is None:
                continue
            vi = video_info(v.video)
            if (vi["width"], vi["height"]) != (w, h) or vi["frames"] != T:
                raise MetricInputError(
                    manifest.path,
                    f"{where}.variants[{j}].video",
                    f"{T} frames of {w}x{h} (the trajectory's length, the first frame's size)",
                    f"{vi['frames']} frames of {vi['width']}x{vi['height']}",
                )
        if judge is not None:
            verdict = _judge_one(judge, np.stack([first, first]), s, "<check>")
            if verdict.status == "error":
                raise MetricInputError(
                    manifest.path,
                    f"{where}.info",
                    "what the judge reads (it failed on a still first frame)",
                    verdict.error,
                )


def _rollout_one(model, first, inputs: dict, prompt, options: dict) -> np.ndarray:
    rest = {k: v for k, v in inputs.items() if k != "skeleton"}
    if rest.get("actions", 0) is None:  # a skeleton model's dict may say "no actions" explicitly
        rest.pop("actions")
    res = model.rollout(first, inputs.get("skeleton"), prompt, progress=False, **options, **rest)
    return np.asarray(getattr(res, "frames", res))


def roll_out_variants(
    model, first, inputs: list[dict], prompt, *, sampler, seed: int, chunk_frames
) -> list[np.ndarray]:
    """(T, H, W, 3) uint8 videos of one set's variants: one ``rollout_batch`` when every input is the condition video
    alone (its other keys None) and the model has one, else one ``rollout`` per variant with every key of its inputs
    (module docstring); all with noise ``seed``."""
    import warnings

    options = {"sampler": sampler, "seed": seed}
    if chunk_frames:
        options["chunk_frames"] = chunk_frames
    video_only = all(
        inp.get("skeleton") is not None and all(v is None for k, v in inp.items() if k != "skeleton") for inp in inputs
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "trained at WxH": the size was checked before the model loaded
        if video_only and len(inputs) > 1 and hasattr(model, "rollout_batch"):
            out = model.rollout_batch(
                [first] * len(inputs),
                [inp["skeleton"] for inp in inputs],
                prompt,
                sampler=sampler,
                seeds=[seed] * len(inputs),
                **({"chunk_frames": chunk_frames} if chunk_frames else {}),
            )
            return [np.asarray(v) for v in out]
        return [_rollout_one(model, first, inp, prompt, options) for inp in inputs]


def _fingerprint_parts(manifest, settings, model_identity, sampler, chunk, judge, locator_spec) -> dict:
    from .._util import stage as _stage

    describe = judge.describe() if hasattr(judge, "describe") else {"name": type(judge).__name__}
    parts = {
        "stage": "eval-action-following",
        "format": _stage.FORMAT_VERSION,
        "report_version": REPORT_VERSION,
        "manifest_sha256": hashlib.sha256(Path(manifest.path).read_bytes()).hexdigest(),
        "model": model_identity,
        "sampler": asdict(sampler)
        if sampler is not None and hasattr(sampler, "__dataclass_fields__")
        else str(sampler),
        "seed": settings.seed,
        "chunk_frames": chunk,
        "judge": describe,
        "locator": locator_spec,
        **_decoder_part(settings.tiny_decoder),
        **_encoder_part(settings.tiny_encoder),
    }
    if settings.ceiling:  # only here: the folders of rollout runs keep their fingerprints
        parts.update(mode=CEILING, sampler=None, seed=None)
    return parts


def _decoder_part(tiny_decoder) -> dict:
    """``{"decoder": ...}`` when a decoder was chosen, else empty (a run that chooses none keeps its fingerprint)."""
    if tiny_decoder is None:
        return {}
    from ..model.decoder_options import decoder_identity

    return {"decoder": decoder_identity(tiny_decoder)}


def _encoder_part(tiny_encoder) -> dict:
    """``{"encoder": ...}`` when a tiny condition encoder was chosen, else empty (fingerprints made before the
    option are unchanged)."""
    if tiny_encoder is None or tiny_encoder is False:
        return {}
    from ..model.encoder_options import encoder_identity

    return {"encoder": encoder_identity(tiny_encoder)}


def _record_path(out: Path, sid: str) -> Path:
    return out / "records" / f"{sid.replace('/', '_')}.json"


def _paired_report(paired, manifest) -> dict | None:
    """The report.json of the run ``paired`` (a folder) to compare with, checked to be on the same sets (the
    manifest's sha256); None without ``paired``."""
    if paired is None:
        return None
    other_path = Path(paired) / "report.json"
    if not other_path.is_file():
        raise MetricInputError(other_path, "<file>", "the report.json of another action-following run", "no such file")
    other = json.loads(other_path.read_text())
    mine = hashlib.sha256(Path(manifest.path).read_bytes()).hexdigest()
    if other.get("manifest_sha256") != mine:
        raise MetricInputError(
            other_path,
            "manifest_sha256",
            f"a run on the same sets as this one ({manifest.path}, sha256 {mine[:12]}…)",
            f"{str(other.get('manifest_sha256'))[:12]}… ({other.get('manifest')})",
        )
    return other


def _card_and_sampler(model, settings):
    """``(card, sampler)``: the model card (the loaded model's, else read for ``settings.model_spec`` without
    loading weights) and the sampler settings (``settings.sampler``, else the card's recommendation)."""
    card = getattr(model, "card", None)
    if model is None:
        if settings.model_spec is None:
            raise MetricInputError("model", "model", "a world model or a model spec (zoo name or folder)", "none")
        card = _read_card(settings.model_spec, settings.revision)
    sampler = settings.sampler
    if settings.ceiling:
        return card, None  # no sampling
    if sampler is None:
        from ..model.card_sampler import resolve_sampler

        sampler = resolve_sampler(getattr(card, "sampler", None)).config
    return card, sampler


def _recorded_sets(out: Path, manifest):
    """``(records, todo)``: the records already written under ``out`` (set → record) and the sets still to run."""
    records, todo = {}, []
    for s in manifest.sets:
        p = _record_path(out, s.set)
        if p.is_file():
            records[s.set] = json.loads(p.read_text())
        else:
            todo.append(s)
    return records, todo


def _load_model(settings: ActionFollowingSettings):
    """What the run needs of ``settings.model_spec``: its VAE alone for the ceiling
    (:func:`~.action_following_ceiling.load_ceiling_vae`), else the whole world model (``oscar_zoo.load``); both
    on ``settings.device`` in ``settings.dtype``, decoding with ``settings.tiny_decoder``'s choice."""
    if settings.ceiling:
        from .action_following_ceiling import load_ceiling_vae

        return load_ceiling_vae(
            settings.model_spec,
            settings.revision,
            device=settings.device,
            dtype=settings.dtype,
            tiny_decoder=settings.tiny_decoder,
        )
    import oscar_zoo

    return oscar_zoo.load(
        settings.model_spec,
        settings.revision,
        device=settings.device,
        dtype=settings.dtype,
        tiny_decoder=settings.tiny_decoder,
        tiny_encoder=settings.tiny_encoder,
    )


def run_action_following(
    manifest,
    out,
    *,
    judge,
    model=None,
    settings: ActionFollowingSettings | None = None,
    locator: str | None = None,
    paired: str | Path | None = None,
    log=None,
) -> ActionFollowingResult:
    """Run the benchmark (module docstring) into ``out``; returns the report, the per-set records and the paths.

    manifest: a path or a loaded :class:`~.action_following_manifest.ActionFollowingManifest`; judge: an object with
    ``judge_many`` (:func:`oscar_core.evaluation.cli.load_judge`); model: a loaded model (else
    ``settings.model_spec`` is loaded after the checks); locator: ``module:attr`` (default: the manifest's);
    paired: another run's folder on the same manifest: the report adds this run minus it, paired by set.
    """
    from .._util import stage as _stage
    from .._util.atomic import atomic_write_bytes
    from .._util.log import progress_bar

    log = log or _log.info
    settings = settings or ActionFollowingSettings()
    if not isinstance(manifest, ActionFollowingManifest):
        manifest = load_action_following(manifest, settings.plugin_paths)
    locator_spec = locator or manifest.locator
    locate_fn = load_locator(locator_spec)
    other = _paired_report(paired, manifest)
    if settings.ceiling:
        check_true_videos(manifest)
    card, sampler = _card_and_sampler(model, settings)
    chunk = int(settings.chunk_frames or getattr(card, "chunk_frames", 0) or 17)
    check_sets(manifest, judge, card, chunk, settings.plugin_paths)
    out = Path(out)
    identity = (
        _stage.model_identity(settings.model_spec, settings.revision)
        if model is None
        else getattr(model, "identity", None) or getattr(card, "name", None) or type(model).__name__
    )
    parts = _fingerprint_parts(manifest, settings, identity, sampler, chunk, judge, locator_spec)
    _stage.check_stage(out, parts, redo="use another --out for these settings, or delete the folder to redo it")
    (out / "records").mkdir(parents=True, exist_ok=True)
    records, todo = _recorded_sets(out, manifest)
    log(f"action following: {len(manifest.sets)} sets, {len(records)} already done, {len(todo)} to roll out")
    t0, c0 = time.perf_counter(), time.process_time()
    if todo and model is None:
        model = _load_model(settings)
    bar = progress_bar(total=len(todo), desc="action-following sets", unit="set", enabled=settings.progress)
    for s in todo:
        rec = _run_set(model, s, judge, locate_fn, sampler, settings, chunk, out)
        atomic_write_bytes(_record_path(out, s.set), (json.dumps(rec, indent=1) + "\n").encode())
        records[s.set] = rec
        bar.update(1)
        log(
            f"{s.set}: {sum(v['verdict'] == v['outcome'] for v in rec['variants'])} of {len(rec['variants'])} verdicts = truth"
        )
    bar.close()
    ordered = [records[s.set] for s in manifest.sets]
    kw = {"resamples": settings.resamples, "seed": settings.bootstrap_seed}
    report = {
        "format": "oscar-action-following-report",
        "version": REPORT_VERSION,
        "manifest": str(manifest.path),
        "manifest_sha256": parts["manifest_sha256"],
        "model": settings.model_spec if settings.model_spec else identity,
        "mode": CEILING if settings.ceiling else ROLLOUT,
        "judge": getattr(judge, "name", type(judge).__name__),
        "sampler": "none (no sampling)" if settings.ceiling else _describe_sampler(sampler),
        "seed": None if settings.ceiling else settings.seed,
        "chunk_frames": chunk,
        "locator": locator_spec,
        "unit": distance_unit(manifest.sets[0].info)[1],
        "scores": score_records(ordered, **kw),
        "timing": {
            "wall_s": round(time.perf_counter() - t0, 2),
            "cpu_s": round(time.process_time() - c0, 2),
            "sets_run": len(todo),
            "sets_reused": len(manifest.sets) - len(todo),
        },
    }
    if other is not None:
        report["paired"] = {"against": str(paired), **paired_scores(ordered, other.get("records", []), **kw)}
    report["records"] = ordered
    paths = {"report": str(out / "report.json"), "summary": str(out / "summary.md")}
    atomic_write_bytes(out / "report.json", (json.dumps(report, indent=1) + "\n").encode())
    atomic_write_bytes(out / "summary.md", format_summary(report).encode())
    return ActionFollowingResult(report, ordered, paths)


def _describe_sampler(sampler) -> str:
    if sampler is None:
        return "the model's"
    g = getattr(sampler, "guidance", None)
    return f"{getattr(sampler, 'steps', '?')} steps, guidance {g} ({getattr(sampler, 'guidance_form', '?')})"


def _read_card(spec: str, revision):
    import oscar_zoo

    from ..model.world_model import MODEL_FILE, read_card

    folder = Path(oscar_zoo.pull(spec, revision))
    if not (folder / MODEL_FILE).is_file():
        return None
    return read_card(folder)


def _prompt(s: CounterfactualSet):
    if s.prompt_embeds is None:
        return None
    from types import SimpleNamespace

    from .rollout_engines import cell_prompt

    return cell_prompt(SimpleNamespace(prompt_embeds=s.prompt_embeds))  # eval run's rule for the file


def _roll_out_set(model, s: CounterfactualSet, sampler, settings) -> list[np.ndarray]:
    """The model's (T, H, W, 3) uint8 rollout of every variant of ``s`` from its first frame (module docstring)."""
    emb, camera, first = _set_inputs(s, settings.plugin_paths)
    h, w = first.shape[:2]
    if hasattr(model, "rollout_inputs"):
        inputs = [
            model.rollout_inputs(v.trajectory, camera, emb, (w, h), resize_mode="crop", camera_source=str(s.camera))
            for v in s.variants
        ]
    else:  # any model with rollout(first, skeleton, prompt, ...): the card's condition video
        from ..render.conditions import condition_video, video_condition_of

        inputs = [
            {
                "skeleton": condition_video(
                    video_condition_of(model.card.condition), emb, v.trajectory, camera, (w, h), resize_mode="crop"
                )
            }
            for v in s.variants
        ]
    return roll_out_variants(
        model, first, inputs, _prompt(s), sampler=sampler, seed=settings.seed, chunk_frames=settings.chunk_frames
    )


def _run_set(model, s: CounterfactualSet, judge, locate_fn, sampler, settings, chunk: int, out: Path) -> dict:
    from ..media.video import read_video, write_video

    t0, c0 = time.perf_counter(), time.process_time()
    truths = [read_video(v.video) if v.video is not None else None for v in s.variants]
    if settings.ceiling:
        from .action_following_ceiling import reconstruct_variants, vae_of

        videos = reconstruct_variants(
            vae_of(model), truths, chunk, getattr(getattr(model, "card", None), "context_frames", 1)
        )
    else:
        videos = _roll_out_set(model, s, sampler, settings)
    rows = []
    for v, video, truth in zip(s.variants, videos, truths):
        video = np.asarray(video)
        vd = out / "videos" / s.set.replace("/", "_")
        vd.mkdir(parents=True, exist_ok=True)
        ext = "mp4" if video.shape[1] % 2 == 0 and video.shape[2] % 2 == 0 else "mkv"  # H.264 needs even sizes
        write_video(vd / f"{v.name}.{ext}", video, float(v.trajectory.fps))
        verdict = _judge_one(judge, video, s, v.name)
        truth_verdict = _judge_one(judge, truth, s, v.name + "/truth") if truth is not None else None
        row = {
            "name": v.name,
            "outcome": v.outcome,
            "verdict": verdict.binary if verdict.status == "ok" else None,
            "reason": verdict.reason if verdict.status == "ok" else verdict.error,
            "truth_verdict": truth_verdict.binary
            if truth_verdict is not None and truth_verdict.status == "ok"
            else None,
            **score_variant(video, truth, locate_fn, s.info, chunk - 1),
        }
        rows.append(row)
    return {
        "set": s.set,
        "embodiment": s.embodiment,
        "variants": rows,
        "wall_s": round(time.perf_counter() - t0, 3),
        "cpu_s": round(time.process_time() - c0, 3),
    }
