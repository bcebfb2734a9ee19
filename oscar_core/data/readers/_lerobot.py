"""The LeRobot dataset layouts (v3.0 and v2.1) read with pyarrow, without the lerobot package.

Field names from LeRobot's dataset code (``lerobot/datasets/utils.py``,
``lerobot_dataset.py``; v3.0 and v2.1 are documented in its
``docs/source/lerobot-dataset-v3.mdx`` and the v2.1 → v3.0 converter):

``meta/info.json``
    ``codebase_version`` (``"v3.0"`` / ``"v2.1"``), ``fps``, ``robot_type``,
    ``features`` ({key: {dtype, shape, names}}; cameras have dtype
    ``"video"`` and shape [height, width, channels]), ``data_path``,
    ``video_path`` (format templates), ``chunks_size``.
v3.0: ``meta/episodes/chunk-XXX/file-YYY.parquet``
    one row per episode: ``episode_index``, ``tasks`` (list of text),
    ``length``, ``data/chunk_index``, ``data/file_index``,
    ``dataset_from_index``, ``dataset_to_index``, and per camera
    ``videos/<key>/chunk_index``, ``videos/<key>/file_index``,
    ``videos/<key>/from_timestamp``, ``videos/<key>/to_timestamp`` (seconds in
    the shared MP4 that holds several episodes).
    Frames: ``data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet``
    with an ``episode_index`` column; videos:
    ``videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4``.
v2.1: ``meta/episodes.jsonl``
    one JSON line per episode: ``episode_index``, ``tasks``, ``length``;
    frames ``data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet``,
    videos ``videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4``
    (``episode_chunk = episode_index // chunks_size``), each episode its own file.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...plugin.reader import EpisodeError
from ._common import require

__all__ = ["LeRobotLayout", "EpisodeRow", "unreadable_table"]

V3_DATA = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
V3_VIDEO = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
V21_DATA = "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"
V21_VIDEO = "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"


@dataclass(frozen=True)
class EpisodeRow:
    """One episode as the metadata describes it (no frame data read).

    data: path of the parquet file holding its frames; videos: camera key →
    (path, start seconds); length: frames; tasks: task texts.
    """

    index: int
    length: int
    tasks: tuple[str, ...]
    data: str
    videos: dict[str, tuple[str, float]]
    # set on a row that stands for an unreadable episode table (``data`` is then that table's path; ``index``
    # the line of a v2.1 episodes.jsonl, -1 for a whole v3.0 table): its episodes cannot be listed, so it
    # becomes one rejected manifest row and the other tables (lines) go on
    error: str | None = None

    @property
    def error_id(self) -> str:
        """The manifest id suffix of an error row, relative to the dataset: ``meta/…parquet`` or ``…jsonl:LINE``."""
        return "" if self.index < 0 else f":{self.index}"


def unreadable_table(ref) -> None:
    """Raise the :class:`EpisodeError` of a ref listed for an unreadable episode table (else nothing)."""
    reason = (ref.meta or {}).get("unreadable_table")
    if reason:
        raise EpisodeError(
            ref.episode_id,
            ref.paths.get("states", "?"),
            "<file>",
            "a readable LeRobot episode table (meta/episodes); its episodes were not listed",
            reason,
        )


class LeRobotLayout:
    """A LeRobot dataset folder: its info.json and episode table.

    root: the dataset folder (holding ``meta/``); reader: name for messages.
    """

    def __init__(self, root: Path, reader: str):
        self.root, self.reader = Path(root), reader
        info_path = self.root / "meta" / "info.json"
        if not info_path.is_file():
            raise ValueError(f"{info_path}: expected a LeRobot dataset's meta/info.json, found no such file")
        try:
            self.info = json.loads(info_path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise ValueError(f"{info_path}: expected JSON, found {type(e).__name__}: {e}") from None
        self.info_path = info_path
        self.version = str(self.info.get("codebase_version", ""))
        if not (self.version.startswith("v3") or self.version.startswith("v2")):
            raise ValueError(
                f"{info_path}: field 'codebase_version': expected 'v3.0' or 'v2.1', found {self.version!r}"
            )
        self.features: dict[str, dict] = dict(self.info.get("features") or {})
        try:
            self.fps = float(self.info["fps"])
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"{info_path}: field 'fps': expected a number, found {self.info.get('fps')!r}") from None

    @property
    def video_keys(self) -> list[str]:
        return [k for k, f in self.features.items() if isinstance(f, dict) and f.get("dtype") == "video"]

    def image_size(self, key: str) -> tuple[int, int] | None:
        """(width, height) of camera ``key`` from its feature shape (``[h, w, c]`` or names)."""
        f = self.features.get(key) or {}
        shape, names = list(f.get("shape") or []), list(f.get("names") or [])
        if len(shape) == 3:
            if names[:2] == ["height", "width"] or not names:
                return int(shape[1]), int(shape[0])
            if names[1:] == ["height", "width"]:
                return int(shape[2]), int(shape[1])
        return None

    # ------------------------------------------------------------------ episodes

    def episodes(self) -> Iterator[EpisodeRow]:
        """The episode table, from metadata only."""
        if self.version.startswith("v3"):
            yield from self._episodes_v3()
        else:
            yield from self._episodes_v21()

    def _episodes_v3(self) -> Iterator[EpisodeRow]:
        pq = require("pyarrow.parquet", self.reader)
        files = sorted((self.root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
        if not files:
            raise ValueError(
                f"{self.root / 'meta' / 'episodes'}: expected chunk-XXX/file-YYY.parquet episode tables "
                f"(LeRobot v3.0), found none"
            )
        data_tpl = self.info.get("data_path") or V3_DATA
        video_tpl = self.info.get("video_path") or V3_VIDEO
        keys = self.video_keys
        for path in files:
            try:
                schema = pq.read_schema(path)
            except Exception as e:  # noqa: BLE001 - ArrowInvalid / OSError ("Parquet magic bytes not found") name no file
                yield EpisodeRow(-1, 0, (), str(path), {}, error=f"{type(e).__name__}: {e}")
                continue
            want = ["episode_index", "length", "tasks", "data/chunk_index", "data/file_index"]
            for k in keys:
                want += [f"videos/{k}/{c}" for c in ("chunk_index", "file_index", "from_timestamp")]
            missing = [c for c in want if c not in schema.names]
            if missing:
                raise ValueError(
                    f"{path}: field '{missing[0]}': expected the LeRobot v3.0 episode columns {want}, "
                    f"found missing {missing}"
                )
            try:
                table = pq.read_table(path, columns=want).to_pydict()
            except Exception as e:  # noqa: BLE001 - a table whose footer reads but whose pages do not
                yield EpisodeRow(-1, 0, (), str(path), {}, error=f"{type(e).__name__}: {e}")
                continue
            for i in range(len(table["episode_index"])):
                row = {c: table[c][i] for c in want}
                data = self.root / data_tpl.format(
                    chunk_index=int(row["data/chunk_index"]), file_index=int(row["data/file_index"])
                )
                videos = {}
                for k in keys:
                    vpath = self.root / video_tpl.format(
                        video_key=k,
                        chunk_index=int(row[f"videos/{k}/chunk_index"]),
                        file_index=int(row[f"videos/{k}/file_index"]),
                    )
                    videos[k] = (str(vpath), float(row[f"videos/{k}/from_timestamp"]))
                yield EpisodeRow(
                    int(row["episode_index"]), int(row["length"]), tuple(row["tasks"] or ()), str(data), videos
                )

    def _episodes_v21(self) -> Iterator[EpisodeRow]:
        path = self.root / "meta" / "episodes.jsonl"
        if not path.is_file():
            raise ValueError(f"{path}: expected the LeRobot v2.1 episode list, found no such file")
        data_tpl = self.info.get("data_path") or V21_DATA
        video_tpl = self.info.get("video_path") or V21_VIDEO
        chunks = int(self.info.get("chunks_size") or 1000)
        with open(path) as f:
            for n, line in enumerate(f, 1):
                if not line.strip():
                    continue
                try:
                    row = json.loads(line)
                    index, length = int(row["episode_index"]), int(row["length"])
                except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
                    # one rejected row for this line (index: the line number); the other lines go on
                    yield EpisodeRow(
                        n,
                        0,
                        (),
                        str(path),
                        {},
                        error=f"line {n}: expected {{episode_index, tasks, length}}, found {type(e).__name__}: {e}",
                    )
                    continue
                chunk = index // chunks
                data = self.root / data_tpl.format(episode_chunk=chunk, episode_index=index)
                videos = {
                    k: (str(self.root / video_tpl.format(episode_chunk=chunk, video_key=k, episode_index=index)), 0.0)
                    for k in self.video_keys
                }
                yield EpisodeRow(index, length, tuple(row.get("tasks") or ()), str(data), videos)

    # ------------------------------------------------------------------ frames

    def frames(
        self, episode_id: str, data_path: str, index: int, columns: list[str], length: int | None = None
    ) -> dict[str, np.ndarray]:
        """The columns of one episode's rows, in frame order: column → (T, ...) array.

        length: the episode table's ``length`` (checked when given).
        Raises :class:`EpisodeError` for a missing file or column, or a row count
        that disagrees with ``length``.
        """
        pq = require("pyarrow.parquet", self.reader)
        path = Path(data_path)
        if not path.is_file():
            raise EpisodeError(episode_id, path, "<file>", "the episode's parquet file", "no such file")
        try:
            names = pq.read_schema(path).names
        except Exception as e:  # noqa: BLE001 - pyarrow raises ArrowInvalid / OSError for a broken file
            raise EpisodeError(episode_id, path, "<file>", "a parquet file", f"{type(e).__name__}: {e}") from None
        for c in columns:
            if c not in names:
                raise EpisodeError(episode_id, path, c, f"a column {c!r}", f"missing (columns: {names})")
        read = list(dict.fromkeys(columns + [c for c in ("episode_index", "frame_index") if c in names]))
        filters = [("episode_index", "=", int(index))] if "episode_index" in names else None
        try:
            table = pq.read_table(path, columns=read, filters=filters)
        except Exception as e:  # noqa: BLE001 - as above: named as a broken parquet file
            raise EpisodeError(episode_id, path, "<file>", "a parquet file", f"{type(e).__name__}: {e}") from None
        if table.num_rows == 0 or (length is not None and table.num_rows != int(length)):
            raise EpisodeError(
                episode_id,
                path,
                "episode_index",
                f"{length if length is not None else 'at least one'} rows of episode {index} "
                "(the episode table's length)",
                f"{table.num_rows} rows",
            )
        out = {}
        order = None
        if "frame_index" in table.column_names:
            order = np.argsort(np.asarray(table.column("frame_index").to_numpy()), kind="stable")
        for c in columns:
            col = table.column(c).to_pylist()
            try:
                a = np.asarray(col, dtype=np.float64)
            except (TypeError, ValueError):
                raise EpisodeError(
                    episode_id, path, c, "numbers (one row of equal length per frame)", "ragged or non-numeric cells"
                ) from None
            out[c] = a if order is None else a[order]
        return out
