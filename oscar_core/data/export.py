"""``export``: live episodes into a training clip set (``oscar_core.train.clips``, docs/formats.md "Training clips").

One export shard (``part-NNNNNN``) becomes one clip-set shard
(``shard-part-NNNNNN``); the clip set's own rule (a shard exists once its
``clips.jsonl`` does) and the stage's completion records agree, so a killed
export resumes shard by shard. Each clip is the whole episode: RGB frames
(resized to ``size`` when given, the camera rescaled the same way), the
trajectory, the camera, the open/close signal, the caption (or none) and the
dataset's task text. The skeleton is rendered on the fly by the trainer by
default; ``render_skeleton`` stores it (``oscar_core.render.skeleton_video.render_skeleton_video``).
The clip set may be a local folder or an fsspec URL (``s3://…``; the trainer
reads a local copy).
Clip ids are the episode id with ``/`` and other characters outside
``[A-Za-z0-9._-]`` replaced by ``-``, plus 8 hex digits of its hash (unique).
"""

from __future__ import annotations

import hashlib
import json
import re
import tempfile
from dataclasses import dataclass

import numpy as np

from . import _fs
from ._episode import EPISODE_ERRORS, camera_at_video_size, load_row, reason_of
from .manifest import is_alive

__all__ = ["ExportStage", "clip_id"]


def clip_id(episode_id: str) -> str:
    """A clip id for an episode id: letters, digits, ``._-`` only, unique by a hash suffix."""
    base = re.sub(r"[^A-Za-z0-9._-]+", "-", episode_id).strip("-._")[:180] or "episode"
    return f"{base}-{hashlib.sha1(episode_id.encode()).hexdigest()[:8]}"


@dataclass(frozen=True)
class ExportStage:
    """Sharded stage writing clip-set shards under ``out`` (a local folder or an fsspec URL).

    For a URL each shard is written to a local temporary folder, then copied
    to ``out/shard-…/`` with its index (``clips.jsonl``) last, so the shard
    exists for a reader only once all its files are there.
    """

    out: str
    size: tuple[int, int] | None = None
    render_skeleton: bool = False
    video_codec: str = "ffv1"
    plugin_paths: tuple[str, ...] = ()
    name: str = "export"

    def __call__(self, rows: list[dict], shard: str = "") -> list[dict]:
        name = f"shard-{shard or 'x'}"
        if _fs.is_local(self.out):
            return self._write(rows, _fs.local_path(self.out), name)
        with tempfile.TemporaryDirectory(prefix="oscar-export-") as tmp:
            out = self._write(rows, tmp, name)
            _put_clip_set(tmp, self.out, name)
        return out

    def _write(self, rows: list[dict], root: str, name: str) -> list[dict]:
        from ..train.clips import ClipSetWriter

        writer = ClipSetWriter(root, video_codec=self.video_codec)
        out = []
        with writer.shard(name) as sw:
            for r in rows:
                if not is_alive(r):
                    out.append(r)
                    continue
                o = dict(
                    r, export_status="ok", export_reason=None, export_value=None, export_clip=None, export_shard=None
                )
                try:
                    clip = self._clip(r)
                except EPISODE_ERRORS as exc:
                    o.update(export_status="rejected", export_reason=f"unreadable: {reason_of(exc)}")
                else:
                    # outside the episode's try: a failed write (a full disk) fails the stage, never the episode
                    rec = sw.add(clip)
                    o.update(export_clip=rec.id, export_shard=name, export_value=float(rec.n_frames))
                out.append(o)
        return out

    def _clip(self, row: dict):
        from ..render.skeleton_video import fit_image, render_skeleton_video
        from ..train.clips import Clip, ClipRecord, clip_openness

        ep, emb = load_row(row, self.plugin_paths)
        traj = emb.check_trajectory(ep.trajectory)
        rgb = ep.video.read()
        H, W = rgb.shape[1:3]
        cam = camera_at_video_size(ep.camera, W, H)
        if self.size is not None and (W, H) != tuple(self.size):
            W, H = self.size
            rgb = np.stack([fit_image(f, W, H, "crop") for f in rgb])
            cam = cam.resized(W, H, mode="crop")
        skeleton = render_skeleton_video(emb, traj, cam, (W, H)) if self.render_skeleton else None
        op = clip_openness(emb, traj)
        rec = ClipRecord(
            id=clip_id(row["id"]),
            source=row["source"],
            embodiment=row["embodiment"],
            n_frames=len(traj),
            fps=float(traj.fps),
            width=int(W),
            height=int(H),
            openness=tuple(map(tuple, op.tolist())),
            files={},
            caption=row.get("caption"),
            task=row.get("task"),
            meta={"episode": row["id"], "frames": [0, len(traj)], "camera": row.get("camera")},
        )
        return Clip(rec, rgb=rgb, trajectory=traj, camera=cam, skeleton=skeleton)


def _put_clip_set(local_root: str, url: str, shard: str) -> None:
    """Copy one finished clip-set shard (and the clip set's marker, when ``url`` has none yet) to ``url``."""
    from ..train.clips import CLIPSET_FILE, CLIPSET_FORMAT, SHARD_INDEX

    marker = _fs.join(url, CLIPSET_FILE)
    if _fs.exists(marker):
        try:
            fmt = json.loads(_fs.read_bytes(marker)).get("format")
        except (ValueError, AttributeError):
            fmt = "unreadable JSON"
        if fmt != CLIPSET_FORMAT:
            raise ValueError(f"{marker}: expected a clip set marker (format {CLIPSET_FORMAT!r}), found {fmt!r}")
    else:
        with open(f"{local_root}/{CLIPSET_FILE}", "rb") as f:
            _fs.write_bytes_atomic(marker, f.read())
    _fs.put_tree(f"{local_root}/{shard}", _fs.join(url, shard), last=(SHARD_INDEX,))
