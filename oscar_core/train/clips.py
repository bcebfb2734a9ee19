"""Training clips: the on-disk format that the toy world and the data pipeline write and the trainer reads.

This module writes (:class:`ShardWriter`, :class:`ClipSetWriter`) and reads (:class:`ClipSet`) clip sets; the
format's names, the record of one clip and its checks (:class:`ClipRecord`, :class:`Clip`, :class:`ClipFormatError`,
:func:`clip_openness`) live in :mod:`oscar_core.train.clip_format` and are re-exported here.

A **clip set** is a folder of shards::

    CLIPSET/
      oscar_clips.json                  {"format": "oscar-clips", "format_version": 1}
      shard-000000/
        clips.jsonl                     one ClipRecord per line; written last and atomically:
                                        a shard without it is unfinished and is ignored
        <clip id>/rgb.mkv               RGB video (T, H, W, 3): .mkv (FFV1, lossless) or .mp4 (H.264)
        <clip id>/trajectory.npz        the trajectory (docs/formats.md), T frames
        <clip id>/camera.json           the camera (docs/formats.md)
        <clip id>/skeleton.mkv          optional: the skeleton video rendered at the RGB size
        <clip id>/prompt.safetensors    optional: {"prompt_embeds": (L, D)} text embedding
        <clip id>/latents.safetensors   optional: cached VAE latents of fixed windows (below)

A record names everything the trainer needs without opening the videos:
the source dataset (source mixing), the frame count (mixing weights, window
bounds) and the open/close signal (the window prior), so sampling plans are
made from the ``clips.jsonl`` files alone.

The skeleton is rendered on the fly from trajectory + camera + embodiment
unless a stored ``skeleton`` video is given. Cached latents hold, for N
windows of ``window`` frames starting at ``starts``, the normalised VAE
latents of both streams: tensors ``video`` and ``skeleton`` of shape
(N, C, 1 + (window − 1) / 4, H / s, W / s) (s: the VAE's spatial compression, 8 for WAN 2.1) and
``starts`` (N,) int64, with
metadata ``window``, ``vae`` (the VAE's name or hash), ``width``, ``height``.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .._util.atomic import TMP_NAME as _TMP_WITH_PID, atomic_write_bytes, sweep_dead_temporaries, sweep_once, tmp_prefix
from .clip_format import (  # FORMAT_VERSION, REQUIRED_FILES, OPTIONAL_FILES: importable from here as before
    CLIPSET_FILE,
    CLIPSET_FORMAT,
    FORMAT_VERSION,
    OPTIONAL_FILES as OPTIONAL_FILES,
    REQUIRED_FILES as REQUIRED_FILES,
    SHARD_INDEX,
    Clip,
    ClipFormatError,
    ClipRecord,
    _read_marker,
    clip_openness,
)

__all__ = [
    "CLIPSET_FILE",
    "CLIPSET_FORMAT",
    "SHARD_INDEX",
    "Clip",
    "ClipFormatError",
    "ClipRecord",
    "ClipSet",
    "ClipSetWriter",
    "ShardWriter",
    "clip_openness",
    "finished_clipset",
]


class ShardWriter:
    """Writes one shard: clips go into a hidden temporary folder, which becomes the shard on :meth:`close`.

    Use as a context manager; on an exception nothing is left at the shard's
    name. Clip ids must be unique within the shard (the clip set's writer
    checks the whole set).
    """

    def __init__(self, final: Path, video_codec: str = "ffv1"):
        self.final = final
        sweep_once(final.parent)
        self.tmp = Path(tempfile.mkdtemp(prefix=tmp_prefix(final), suffix=".tmp", dir=final.parent))
        self.records: list[ClipRecord] = []
        self.video_codec = video_codec

    def add(self, clip: Clip) -> ClipRecord:
        """Write a clip's files and return its record (``files`` filled in)."""
        from ..camera import save_camera
        from ..kinematics.trajectory import save_trajectory
        from ..media.video import write_video

        rec = clip.record
        if any(r.id == rec.id for r in self.records):
            raise ClipFormatError(self.final, rec.id, "id", "unique within the shard", "a duplicate")
        if clip.rgb is None or clip.trajectory is None or clip.camera is None:
            missing = [k for k in ("rgb", "trajectory", "camera") if getattr(clip, k) is None]
            raise ClipFormatError(self.final, rec.id, missing[0], "given", "None")
        rgb = np.asarray(clip.rgb)
        T = rec.n_frames
        if rgb.ndim != 4 or rgb.shape[0] != T or rgb.shape[1:] != (rec.height, rec.width, 3) or rgb.dtype != np.uint8:
            raise ClipFormatError(
                self.final,
                rec.id,
                "rgb",
                f"uint8 ({T}, {rec.height}, {rec.width}, 3)",
                f"{rgb.dtype} {tuple(rgb.shape)}",
            )
        if len(clip.trajectory) != T:
            raise ClipFormatError(self.final, rec.id, "trajectory", f"{T} frames", f"{len(clip.trajectory)}")
        folder = self.tmp / rec.id
        folder.mkdir()
        ext = ".mkv" if self.video_codec == "ffv1" else ".mp4"
        files = {
            "rgb": f"{rec.id}/rgb{ext}",
            "trajectory": f"{rec.id}/trajectory.npz",
            "camera": f"{rec.id}/camera.json",
        }
        write_video(self.tmp / files["rgb"], rgb, rec.fps, codec=self.video_codec)
        save_trajectory(clip.trajectory, self.tmp / files["trajectory"])
        save_camera(clip.camera, self.tmp / files["camera"])
        if clip.skeleton is not None:
            sk = np.asarray(clip.skeleton)
            if sk.shape != rgb.shape or sk.dtype != np.uint8:
                raise ClipFormatError(
                    self.final, rec.id, "skeleton", f"uint8 {tuple(rgb.shape)}", f"{sk.dtype} {tuple(sk.shape)}"
                )
            files["skeleton"] = f"{rec.id}/skeleton{ext}"
            write_video(self.tmp / files["skeleton"], sk, rec.fps, codec=self.video_codec)
        if clip.prompt_embeds is not None or clip.latents is not None:
            import torch
            from safetensors.torch import save_file

            if clip.prompt_embeds is not None:
                pe = torch.as_tensor(clip.prompt_embeds)
                if pe.ndim != 2:
                    raise ClipFormatError(
                        self.final, rec.id, "prompt_embeds", "shape (L, D)", f"shape {tuple(pe.shape)}"
                    )
                files["prompt_embeds"] = f"{rec.id}/prompt.safetensors"
                save_file({"prompt_embeds": pe.contiguous()}, str(self.tmp / files["prompt_embeds"]))
            if clip.latents is not None:
                files["latents"] = f"{rec.id}/latents.safetensors"
                tensors, meta = _latents_to_file(clip.latents, self.final, rec)
                save_file(tensors, str(self.tmp / files["latents"]), metadata=meta)
        d = json.loads(rec.to_json())
        d["files"] = files
        full = ClipRecord.from_dict(d, f"{self.final}/{SHARD_INDEX}")
        self.records.append(full)
        return full

    def close(self) -> Path:
        """Write the index and move the shard into place (replacing an unfinished one)."""
        data = "".join(r.to_json() + "\n" for r in self.records).encode()
        atomic_write_bytes(self.tmp / SHARD_INDEX, data)
        os.chmod(self.tmp, 0o755)
        if self.final.exists():
            shutil.rmtree(self.final)
        os.replace(self.tmp, self.final)
        return self.final

    def abort(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)

    def __enter__(self) -> ShardWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _latents_to_file(latents: dict, where, rec: ClipRecord):
    import torch

    for k in ("video", "skeleton", "starts", "window", "vae"):
        if k not in latents:
            raise ClipFormatError(where, rec.id, f"latents.{k}", "present", "missing")
    video, skel = torch.as_tensor(latents["video"]), torch.as_tensor(latents["skeleton"])
    starts = torch.as_tensor(latents["starts"], dtype=torch.int64)
    window = int(latents["window"])
    if video.ndim != 5 or skel.shape[0] != video.shape[0] or skel.shape[2:] != video.shape[2:]:
        raise ClipFormatError(
            where,
            rec.id,
            "latents",
            "video and skeleton of shape (N, C, t, h, w) with equal N, t, h, w",
            f"{tuple(video.shape)} and {tuple(skel.shape)}",
        )
    if starts.shape != (video.shape[0],) or (starts < 0).any() or (starts + window > rec.n_frames).any():
        raise ClipFormatError(
            where,
            rec.id,
            "latents.starts",
            f"{video.shape[0]} starts with start + {window} <= {rec.n_frames}",
            starts.tolist(),
        )
    meta = {
        "window": str(window),
        "vae": str(latents["vae"]),
        "width": str(rec.width),
        "height": str(rec.height),
        "condition": str(latents.get("condition") or "skeleton"),
    }  # what the condition stream encodes
    return {"video": video.contiguous(), "skeleton": skel.contiguous(), "starts": starts}, meta


class ClipSetWriter:
    """Creates (or reopens) a clip set and hands out shard writers; finished shards are skipped on re-runs."""

    def __init__(self, root, video_codec: str = "ffv1"):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        marker = self.root / CLIPSET_FILE
        if marker.exists():
            _read_marker(marker)
        else:
            atomic_write_bytes(
                marker, json.dumps({"format": CLIPSET_FORMAT, "format_version": FORMAT_VERSION}).encode()
            )
        if video_codec not in ("ffv1", "h264"):
            raise ValueError(f"video_codec: expected 'ffv1' or 'h264', found {video_codec!r}")
        self.video_codec = video_codec

    def shard_done(self, name: str) -> bool:
        """True when shard ``name`` is complete (its index exists)."""
        return (self.root / name / SHARD_INDEX).is_file()

    def shard(self, name: str) -> ShardWriter:
        if not re.match(r"^shard-[A-Za-z0-9._-]+$", name):
            raise ValueError(f"shard name: expected 'shard-<letters, digits, ._->', found {name!r}")
        return ShardWriter(self.root / name, self.video_codec)

    def remove_stale(self) -> list[Path]:
        """Delete the temporary shard folders of killed writers (their pid no longer runs) and those without a pid
        in their name (an older oscar's); returns what was removed. A live writer's temporary, in this or another
        process, is left alone."""
        removed = sweep_dead_temporaries(self.root)
        for p in self.root.glob(".shard-*.tmp"):
            if p.is_dir() and not _TMP_WITH_PID.match(p.name):
                shutil.rmtree(p, ignore_errors=True)
                removed.append(p)
        return removed


def finished_clipset(root) -> ClipSet | None:
    """The clip set at ``root`` if it holds a finished shard, else None (no set there, or nothing finished yet)."""
    if not (Path(root) / CLIPSET_FILE).is_file():
        return None
    clips = ClipSet(root)
    return clips if clips.records else None


class ClipSet:
    """Reads a clip set: every finished shard's records, and clips on demand.

    root: the clip-set folder. Unfinished shards (no index) are ignored.
    Duplicate clip ids across shards are an error naming both shards.
    """

    def __init__(self, root):
        self.root = Path(root)
        marker = self.root / CLIPSET_FILE
        if not marker.is_file():
            raise ClipFormatError(self.root, None, CLIPSET_FILE, "a clip-set marker file", "missing (not a clip set)")
        _read_marker(marker)
        self.records: list[ClipRecord] = []
        self.shard_of: dict[str, Path] = {}
        for shard in sorted(p for p in self.root.glob("shard-*") if p.is_dir()):
            index = shard / SHARD_INDEX
            if not index.is_file():
                continue
            for lineno, line in enumerate(index.read_text().splitlines(), 1):
                if not line.strip():
                    continue
                where = f"{index}:{lineno}"
                try:
                    d = json.loads(line)
                except json.JSONDecodeError as exc:
                    raise ClipFormatError(
                        where, None, "<line>", "one JSON object", f"invalid JSON ({exc.msg})"
                    ) from None
                rec = ClipRecord.from_dict(d, where)
                if rec.id in self.shard_of:
                    raise ClipFormatError(
                        where, rec.id, "id", "unique in the clip set", f"also in {self.shard_of[rec.id].name}"
                    )
                self.shard_of[rec.id] = shard
                self.records.append(rec)
        self._by_id = {r.id: r for r in self.records}

    def __len__(self) -> int:
        return len(self.records)

    def __iter__(self) -> Iterator[ClipRecord]:
        return iter(self.records)

    def record(self, clip_id: str) -> ClipRecord:
        try:
            return self._by_id[clip_id]
        except KeyError:
            raise KeyError(f"{self.root}: no clip {clip_id!r}") from None

    def path(self, rec: ClipRecord, role: str) -> Path:
        """Absolute path of one of a clip's files."""
        if role not in rec.files:
            raise ClipFormatError(self.shard_of[rec.id], rec.id, f"files.{role}", "present", "missing")
        return self.shard_of[rec.id] / rec.files[role]

    def read_trajectory(self, rec: ClipRecord):
        """Check that every file of a clip exists and return its trajectory, which must have ``n_frames`` frames."""
        from ..errors import InputFileError
        from ..kinematics.trajectory import load_trajectory

        shard = self.shard_of[rec.id]
        for role, rel in rec.files.items():
            if not (shard / rel).exists():
                raise ClipFormatError(shard, rec.id, f"files.{role}", f"a file at {rel}", "no such file")
        try:
            traj = load_trajectory(shard / rec.files["trajectory"])
        except InputFileError as exc:
            raise ClipFormatError(shard, rec.id, exc.field, exc.expected, exc.found) from None
        if len(traj) != rec.n_frames:
            raise ClipFormatError(
                shard, rec.id, "trajectory", f"{rec.n_frames} frames (n_frames)", f"{len(traj)} frames"
            )
        return traj

    def skeleton_video(self, rec: ClipRecord, clip: Clip, registry) -> np.ndarray:
        """(T, H, W, 3) uint8 skeleton video of a loaded ``clip``: its stored one, else rendered at the clip's size
        from its trajectory and camera through ``registry``'s embodiment."""
        if clip.skeleton is not None:
            return clip.skeleton
        from ..render.skeleton_video import render_skeleton_video

        return render_skeleton_video(
            registry.get(rec.embodiment),
            clip.trajectory,
            clip.camera,
            (rec.width, rec.height),
            camera_source=str(self.path(rec, "camera")),
        )

    def condition_video(
        self, rec: ClipRecord, clip: Clip, registry, condition: str = "skeleton", style: dict | None = None
    ) -> np.ndarray:
        """(T, H, W, 3) uint8 condition video ``condition`` (:mod:`oscar_core.render.conditions`) of a loaded ``clip``:
        for the skeleton in the default look :meth:`skeleton_video` (its stored one, else rendered), else rendered
        at the clip's size from its trajectory and camera through ``registry``'s embodiment, in ``style`` (a
        ``condition_style`` mapping; None: the default look)."""
        if condition == "skeleton" and not style:
            return self.skeleton_video(rec, clip, registry)
        from ..render.conditions import condition_video

        return condition_video(
            condition,
            registry.get(rec.embodiment),
            clip.trajectory,
            clip.camera,
            (rec.width, rec.height),
            camera_source=str(self.path(rec, "camera")),
            style=style,
        )

    def load(
        self,
        rec: ClipRecord | str,
        *,
        start: int = 0,
        frames: int | None = None,
        video: bool = True,
        skeleton: bool = True,
        registry=None,
    ) -> Clip:
        """Read a clip, or the window ``[start, start + frames)`` of it, and check it against its record.

        Checks: every file present; the video's frame size is the record's; the
        trajectory (and the stored skeleton) have ``n_frames`` frames; the
        window lies inside the clip. ``registry``: an embodiment registry used to
        read the camera with the embodiment's defaults (None: plain camera file).
        Returns a :class:`Clip` whose arrays cover the window only.
        """
        from ..camera import load_camera
        from ..errors import InputFileError
        from ..media.video import read_video

        if isinstance(rec, str):
            rec = self.record(rec)
        shard = self.shard_of[rec.id]
        n = rec.n_frames - start if frames is None else int(frames)
        if start < 0 or n < 1 or start + n > rec.n_frames:
            raise ClipFormatError(
                shard,
                rec.id,
                "n_frames",
                f"at least {start + max(n, 1)} frames for the window [{start}, {start + n})",
                rec.n_frames,
            )
        traj = self.read_trajectory(rec)
        try:
            if registry is not None:
                camera = registry.get(rec.embodiment).load_camera(shard / rec.files["camera"])
            else:
                camera = load_camera(shard / rec.files["camera"])
        except InputFileError as exc:
            raise ClipFormatError(shard, rec.id, exc.field, exc.expected, exc.found) from None
        if camera.num_frames is not None and camera.num_frames != rec.n_frames:  # one extrinsic per frame
            raise ClipFormatError(
                shard, rec.id, "camera", f"{rec.n_frames} per-frame extrinsics (n_frames)", f"{camera.num_frames}"
            )
        clip = Clip(
            rec,
            trajectory=traj.time_slice(start, start + n) if (start, n) != (0, rec.n_frames) else traj,
            camera=camera.time_slice(start, start + n),
        )

        def read_window(role: str) -> np.ndarray:
            try:
                v = read_video(shard / rec.files[role], max_frames=start + n)
            except (ValueError, FileNotFoundError) as exc:
                raise ClipFormatError(shard, rec.id, f"files.{role}", "a readable video", str(exc)) from None
            if v.shape[1:3] != (rec.height, rec.width):
                raise ClipFormatError(
                    shard, rec.id, role, f"frames of {rec.width}x{rec.height}", f"{v.shape[2]}x{v.shape[1]}"
                )
            if len(v) < start + n:
                raise ClipFormatError(shard, rec.id, role, f"{rec.n_frames} frames (n_frames)", f"{len(v)} frames")
            return v[start : start + n]

        if video:
            clip.rgb = read_window("rgb")
        if skeleton and "skeleton" in rec.files:
            clip.skeleton = read_window("skeleton")
        if "prompt_embeds" in rec.files or "latents" in rec.files:
            from safetensors import safe_open

            if "prompt_embeds" in rec.files:
                with safe_open(str(shard / rec.files["prompt_embeds"]), "pt") as f:
                    if "prompt_embeds" not in f.keys():
                        raise ClipFormatError(
                            shard, rec.id, "prompt_embeds", "a tensor 'prompt_embeds'", sorted(f.keys())
                        )
                    clip.prompt_embeds = f.get_tensor("prompt_embeds")
            if "latents" in rec.files:
                with safe_open(str(shard / rec.files["latents"]), "pt") as f:
                    keys = set(f.keys())
                    if not {"video", "skeleton", "starts"} <= keys:
                        raise ClipFormatError(shard, rec.id, "latents", "tensors video, skeleton, starts", sorted(keys))
                    meta = f.metadata() or {}
                    clip.latents = {k: f.get_tensor(k) for k in ("video", "skeleton", "starts")}
                    clip.latents.update({k: meta.get(k) for k in ("window", "vae", "width", "height")})
                    clip.latents["condition"] = meta.get("condition", "skeleton")  # older files: skeleton
        return clip
