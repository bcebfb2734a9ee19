"""From clip sets to model-ready batches: select usable clips, then load, render and encode windows.

:class:`TrainData` opens the clip sets of a config, keeps the clips of the
wanted sources that can give a window (bad clips raise, or are skipped and
counted when the config says so), and turns plan items into tensors:

* video latent z_0: the cached latent of the window (``latents.safetensors``)
  or the VAE encoding of the RGB window, fitted to the training size;
* skeleton latent: cached, or the VAE encoding of the stored skeleton video,
  or of the skeleton rendered on the fly from trajectory + camera; a dropped
  skeleton is zeros (``zero_latent``) or the latent of a black video
  (``black_video``);
* prompt embedding (L, D): the clip's, else zeros (1, D); a batch is padded
  with zero tokens to its longest prompt;
* latent actions (window − 1, 14) for the latent-action baseline.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import torch

from ..render.conditions import condition_key, is_video_condition, takes_actions
from .clips import ClipFormatError, ClipRecord, ClipSet
from .config import TrainConfig
from .sampling import PlanItem, StepPlanner

__all__ = ["TrainData", "Batch", "UsableClip"]

#: bytes of focus masks (one bool per latent cell) a run keeps between draws of the same window: the toy world's
#: whole cache is a few MB of them; a 2B run's windows (21 x 36 x 64 cells) keep the first ~5,000 windows drawn
FOCUS_MEMO_BYTES = 256 * 2**20


@dataclass
class UsableClip:
    """A clip the trainer may draw: its set, record, and (cached mode) allowed window starts and the
    condition video its cached condition latents encode ("skeleton" for files written before it was recorded)."""

    clipset: ClipSet
    record: ClipRecord
    starts: np.ndarray | None = None
    cached_condition: str | None = None


@dataclass
class Batch:
    """One micro-batch. z0: (B, C, T', h, w); skeleton: (B, C_s, T', h, w) or None; text: (B, L, D);
    actions: (B, window − 1, 14) or None; focus: (B, 1, T', h, w) in {0, 1}, the latent cells of the focus mask
    (``data.focus_mask``), or None."""

    z0: torch.Tensor
    skeleton: torch.Tensor | None
    text: torch.Tensor
    actions: torch.Tensor | None
    focus: torch.Tensor | None = None


class TrainData:
    """The usable clips of a config and the means to load them.

    config: the run's config; vae: a ``VideoVAE`` (None when every clip has
    cached latents and the black-video latent is not needed); text_dim: the
    DiT's prompt dimension; registry: embodiment registry (default: installed plugins).
    """

    def __init__(self, config: TrainConfig, vae=None, text_dim: int = 1024, registry=None):
        from ..plugin.registry import Registry

        self.config, self.vae, self.text_dim = config, vae, int(text_dim)
        self.registry = registry if registry is not None else Registry()
        d = config.data
        self.window, self.size = d.window, (d.width, d.height)
        # spatial compression of cached latents: the VAE's when one is given (the toy world's is 4), else WAN's 8
        self.spatial = int(getattr(vae, "spatial", 8)) if vae is not None else 8
        # the focus mask's function (oscar_core.train.focus), imported before any clip is read; None = no focus
        self.focus_mask = None
        if d.focus_mask is not None and config.flow.focus_weight:
            from .focus import load_focus_mask

            self.focus_mask = load_focus_mask(d.focus_mask)
        # the focus cells of each window already seen, (clip, start) -> (1, T', h, w) bool; a window's mask is a
        # function of its frames alone, so a cached-latent run decodes each window's video once, not every draw
        self._focus_memo: dict[tuple[int, int], torch.Tensor] = {}
        self._focus_memo_bytes = 0
        self.skipped: list[dict] = []
        self.clips: list[UsableClip] = []
        for root in d.clips:
            cs = ClipSet(root)
            for rec in cs:
                if d.sources is not None and rec.source not in d.sources:
                    continue
                try:
                    self.clips.append(self._check(cs, rec))
                except ClipFormatError as exc:
                    if not d.skip_bad_clips:
                        raise
                    self.skipped.append({"clip": rec.id, "shard": str(cs.shard_of[rec.id]), "reason": str(exc)})
        if not self.clips:
            raise ClipFormatError(
                ", ".join(map(str, d.clips)),
                None,
                "clips",
                f"at least one usable clip (sources {d.sources or 'any'}, >= {self.window} frames)",
                f"none ({len(self.skipped)} skipped)",
            )
        self.cached = self._choose_cached()
        if not self.cached:
            for c in self.clips:
                c.starts = None
        self._black: torch.Tensor | None = None
        self._embodiments: dict = {}
        # load_item may run in worker threads (oscar_core.train.loader): the VAE (one causal-conv cache on the
        # module) encodes one video at a time, and the caches below are filled once
        self._vae_lock = threading.Lock()
        self._cache_lock = threading.Lock()

    # ------------------------------------------------------------------ checks
    def _check(self, cs: ClipSet, rec: ClipRecord) -> UsableClip:
        shard = cs.shard_of[rec.id]
        if rec.n_frames < self.window:
            raise ClipFormatError(
                shard, rec.id, "n_frames", f"at least the window's {self.window} frames", rec.n_frames
            )
        if rec.embodiment not in self.registry.names():
            raise ClipFormatError(
                shard, rec.id, "embodiment", f"an installed embodiment {self.registry.names()}", repr(rec.embodiment)
            )
        starts = cached_condition = None
        if "latents" in rec.files:
            starts, cached_condition = self._cached_starts(cs, rec)
        if self.config.data.check_files:
            self._check_files(cs, rec)
        return UsableClip(cs, rec, starts, cached_condition)

    def _cached_starts(self, cs: ClipSet, rec: ClipRecord) -> tuple[np.ndarray | None, str | None]:
        """(window starts, condition of the cached condition latents) of a clip's latents file; starts None when
        its window or latent size is not the training's."""
        from safetensors import safe_open

        path = cs.path(rec, "latents")
        if not path.is_file():
            raise ClipFormatError(
                cs.shard_of[rec.id], rec.id, "files.latents", f"a file at {rec.files['latents']}", "no such file"
            )
        with safe_open(str(path), "pt") as f:
            meta = f.metadata() or {}
            if int(meta.get("window", -1)) != self.window:
                return None, None
            video = f.get_slice("video").get_shape()
            if video[-2:] != [self.size[1] // self.spatial, self.size[0] // self.spatial]:
                return None, None
            return f.get_tensor("starts").numpy().astype(np.int64), meta.get("condition", "skeleton")

    def _check_files(self, cs: ClipSet, rec: ClipRecord) -> None:
        from ..media.video import video_info

        shard = cs.shard_of[rec.id]
        cs.read_trajectory(rec)  # every file present, the trajectory n_frames long
        for role in ("rgb", "skeleton"):
            if role in rec.files:
                try:
                    info = video_info(shard / rec.files[role])
                except Exception as exc:  # noqa: BLE001 - any decoder failure is a bad file
                    raise ClipFormatError(shard, rec.id, f"files.{role}", "a readable video", str(exc)) from None
                if info["frames"] != rec.n_frames:
                    raise ClipFormatError(
                        shard,
                        rec.id,
                        role,
                        f"{rec.n_frames} frames (n_frames, the trajectory's)",
                        f"{info['frames']} frames",
                    )
                if (info["width"], info["height"]) != (rec.width, rec.height):
                    raise ClipFormatError(
                        shard, rec.id, role, f"frames of {rec.width}x{rec.height}", f"{info['width']}x{info['height']}"
                    )

    def _choose_cached(self) -> bool:
        mode = self.config.data.latents
        have = all(c.starts is not None and len(c.starts) for c in self.clips)
        if mode == "cached" and not have:
            bad = next(c for c in self.clips if c.starts is None or not len(c.starts))
            raise ClipFormatError(
                bad.clipset.shard_of[bad.record.id],
                bad.record.id,
                "latents",
                f"cached latents of {self.window}-frame windows at "
                f"{self.size[0] // self.spatial}x{self.size[1] // self.spatial} (data.latents: cached)",
                "none" if "latents" not in bad.record.files else "another window or size",
            )
        return mode == "cached" or (mode == "auto" and have)

    # ------------------------------------------------------------------ planning
    def planner(self) -> StepPlanner:
        c, d, f = self.config, self.config.data, self.config.flow
        clips = [(u.record.source, u.record.n_frames, u.record.openness_array, u.starts) for u in self.clips]
        return StepPlanner(
            clips,
            self.window,
            seed=c.seed,
            temperature=d.mixing_temperature,
            weights=d.source_weights,
            ramp=d.prior_ramp,
            uniform=d.prior_uniform,
            dropout=d.skeleton_dropout if is_video_condition(c.condition) else 0.0,
            shift=f.shift,
            logit_mean=f.logit_mean,
            logit_std=f.logit_std,
        )

    # ------------------------------------------------------------------ loading
    def embodiment(self, name: str):
        with self._cache_lock:
            if name not in self._embodiments:
                self._embodiments[name] = self.registry.get(name)
            return self._embodiments[name]

    def _encode(self, frames: np.ndarray, what: str) -> torch.Tensor:
        """(C, T', h, w) VAE latent of (T, H, W, 3) uint8 frames; one encode at a time (thread-safe)."""
        vae = self._need_vae(what)
        pixels = vae.to_pixels(frames)
        with self._vae_lock:
            return vae.encode(pixels)[0]

    def _need_vae(self, what: str):
        if self.vae is None:
            raise ClipFormatError("<config>", None, "model.vae", f"a VAE ({what})", "none")
        return self.vae

    def black_latent(self) -> torch.Tensor:
        """(C, T', h, w) VAE latent of an all-black window at the training size (computed once)."""
        with self._cache_lock:
            if self._black is None:
                w, h = self.size
                black = np.zeros((self.window, h, w, 3), dtype=np.uint8)
                self._black = self._encode(black, "the black-video unconditional latent")
            return self._black

    def load_item(self, item: PlanItem, condition: str) -> dict:
        """Tensors of one plan item: z0 (C, T', h, w), skeleton (C_s, T', h, w) or None, text (L, D), actions."""
        from ..render.skeleton_video import fit_image, render_skeleton_video

        u = self.clips[item.clip]
        rec, cs = u.record, u.clipset
        w, h = self.size
        want_skeleton = is_video_condition(condition) and not item.drop
        # stored skeleton videos are skeletons, and cached condition latents encode the condition they record:
        # another condition video (mesh, capsules), or one of another look (condition_style), is rendered and
        # encoded here
        stored = condition_key(condition, self.config.condition_style) == (
            u.cached_condition if self.cached else "skeleton"
        )
        out: dict = {"skeleton": None, "actions": None}
        need_traj = (
            want_skeleton and (not stored or (not self.cached and "skeleton" not in rec.files))
        ) or takes_actions(condition)
        focus_known = (item.clip, item.start) in self._focus_memo
        clip = cs.load(
            rec,
            start=item.start,
            frames=self.window,
            video=not self.cached or (self.focus_mask is not None and not focus_known),
            skeleton=want_skeleton and stored and not self.cached,
            registry=self.registry if need_traj else None,
        )
        if self.cached:
            lat = clip.latents
            row = int(np.nonzero(lat["starts"].numpy() == item.start)[0][0])
            out["z0"] = lat["video"][row].float()
            if want_skeleton and stored:
                out["skeleton"] = lat["skeleton"][row].float()
        else:
            self._need_vae("on-the-fly encoding")
            rgb = np.stack([fit_image(f, w, h, "crop") for f in clip.rgb])
            out["z0"] = self._encode(rgb, "on-the-fly encoding")
            if want_skeleton and stored:
                if clip.skeleton is not None:
                    skel = np.stack([fit_image(f, w, h, "crop") for f in clip.skeleton])
                else:
                    skel = render_skeleton_video(
                        self.embodiment(rec.embodiment),
                        clip.trajectory,
                        clip.camera,
                        (w, h),
                        resize_mode="crop",
                        camera_source=str(cs.path(rec, "camera")),
                    )
                out["skeleton"] = self._encode(skel, "on-the-fly encoding")
        if want_skeleton and not stored:
            from ..render.conditions import condition_video

            video = condition_video(
                condition,
                self.embodiment(rec.embodiment),
                clip.trajectory,
                clip.camera,
                (w, h),
                resize_mode="crop",
                camera_source=str(cs.path(rec, "camera")),
                style=self.config.condition_style,
            )
            out["skeleton"] = self._encode(video, f"the {condition} condition video")
        if is_video_condition(condition) and item.drop:
            out["skeleton"] = (
                self.black_latent()
                if self.config.data.unconditional_skeleton == "black_video"
                else torch.zeros_like(out["z0"])
            )
        if is_video_condition(condition) and self.config.model.gripper_signal:
            out["skeleton"] = self._with_gripper(out["skeleton"], rec, item)
        if self.focus_mask is not None:
            out["focus"] = self._window_focus(item, clip, out["z0"], rec)
        if clip.prompt_embeds is not None:
            pe = clip.prompt_embeds.float()
            if pe.shape[-1] != self.text_dim:
                raise ClipFormatError(
                    cs.shard_of[rec.id],
                    rec.id,
                    "prompt_embeds",
                    f"(L, {self.text_dim}) (the DiT's text dimension)",
                    f"{tuple(pe.shape)}",
                )
            out["text"] = pe
        else:
            out["text"] = torch.zeros(1, self.text_dim)
        if takes_actions(condition):
            from ..model.latent_action import latent_actions

            out["actions"] = torch.from_numpy(latent_actions(self.embodiment(rec.embodiment), clip.trajectory)).float()
        return out

    def _window_focus(self, item: PlanItem, clip, z0: torch.Tensor, rec) -> torch.Tensor:
        """(1, T', h, w) float32: the window's focus cells, from the memo or computed from its frames and kept (up to
        :data:`FOCUS_MEMO_BYTES` of masks; beyond, computed on every draw)."""
        key = (item.clip, item.start)
        cells = self._focus_memo.get(key)
        if cells is None:
            cells = self._focus(clip.rgb, z0, rec).bool()
            if self._focus_memo_bytes + cells.numel() <= FOCUS_MEMO_BYTES:
                self._focus_memo[key] = cells
                self._focus_memo_bytes += cells.numel()
        return cells.float()

    def _focus(self, rgb: np.ndarray, z0: torch.Tensor, rec) -> torch.Tensor:
        """(1, T', h, w): the latent cells of z0 that ``data.focus_mask`` marks in the window's frames (fitted to the
        training size as the frames the latents encode)."""
        from ..render.skeleton_video import fit_image
        from .focus import latent_focus
        from .models import VAE_TEMPORAL

        w, h = self.size
        frames = np.stack([fit_image(f, w, h, "crop") for f in rgb])
        mask = np.asarray(self.focus_mask(frames))
        if mask.shape != frames.shape[:3]:
            raise ValueError(
                f"data.focus_mask {self.config.data.focus_mask}: expected a (T, H, W) mask of {rec.id}'s window "
                f"{frames.shape[:3]}, found {mask.shape}"
            )
        return latent_focus(mask, tuple(z0.shape[1:]), VAE_TEMPORAL)

    def _with_gripper(self, condition: torch.Tensor, rec, item: PlanItem) -> torch.Tensor:
        """(C + C_g, T', h, w): the window's gripper features (:mod:`oscar_core.model.gripper_signal`) appended to
        its condition latent (C, T', h, w); zeros for a dropped condition, as the sampler's unconditional branch."""
        from ..model.gripper_signal import gripper_features, with_gripper_channels
        from .models import VAE_TEMPORAL

        frames = (condition.shape[1] - 1) * VAE_TEMPORAL + 1
        if frames != self.window:
            raise ValueError(
                f"gripper signal: expected condition latents of {self.window}-frame windows "
                f"({(self.window - 1) // VAE_TEMPORAL + 1} latent frames), found {condition.shape[1]}"
            )
        feats = torch.from_numpy(
            gripper_features(rec.openness_array[item.start : item.start + self.window], VAE_TEMPORAL)
        )
        if item.drop:
            feats = torch.zeros_like(feats)
        return with_gripper_channels(condition[None], feats[None])[0]

    def has_window(self, clip: int, start: int) -> bool:
        """Whether clip ``clip`` (an index into :attr:`clips`) has a training window at frame ``start``: a cached
        window start (cached latents), else any start whose window fits in the clip."""
        u = self.clips[clip]
        if start < 0:
            return False
        if self.cached:
            return u.starts is not None and bool((u.starts == start).any())
        return start + self.window <= u.record.n_frames

    def batch(self, items: list[PlanItem], condition: str) -> Batch:
        """Stack the items of one micro-batch (prompts zero-padded to the longest)."""
        loaded = [self.load_item(it, condition) for it in items]
        L = max(x["text"].shape[0] for x in loaded)
        text = torch.stack(
            [torch.cat([x["text"], x["text"].new_zeros(L - x["text"].shape[0], self.text_dim)]) for x in loaded]
        )
        skel = torch.stack([x["skeleton"] for x in loaded]) if is_video_condition(condition) else None
        acts = torch.stack([x["actions"] for x in loaded]) if takes_actions(condition) else None
        focus = torch.stack([x["focus"] for x in loaded]) if self.focus_mask is not None else None
        return Batch(torch.stack([x["z0"] for x in loaded]), skel, text, acts, focus)

    def summary(self) -> dict:
        sources: dict[str, int] = {}
        for u in self.clips:
            sources[u.record.source] = sources.get(u.record.source, 0) + 1
        embedded = sum("prompt_embeds" in u.record.files for u in self.clips)
        captioned = sum("prompt_embeds" not in u.record.files and bool(u.record.caption) for u in self.clips)
        # a clip without a stored prompt embedding trains on a zero text embedding (its caption is not encoded here)
        prompts = {
            "embedded": embedded,
            "caption_only_zero_text": captioned,
            "none_zero_text": len(self.clips) - embedded - captioned,
        }
        return {
            "clips": len(self.clips),
            "skipped_clips": len(self.skipped),
            "sources": sources,
            "latents": "cached" if self.cached else "on_the_fly",
            "prompts": prompts,
        }
