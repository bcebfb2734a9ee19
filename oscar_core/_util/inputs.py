"""Read an input file so that its errors name the file, the format expected and what was found.

``--camera traj.npz`` should say "expected camera calibration JSON (utf-8 text), found a zip archive (an
.npz?)", not "'utf-8' codec can't decode byte 0xe9 in position 17". :func:`read_text_file` reads a text
file (JSON, YAML, CSV, JSONL) and raises the caller's :class:`~oscar_core.errors.InputFileError` subclass
for a missing file, a folder, or bytes that are not utf-8 text; :func:`describe_content` names what a file
holds from its first bytes (the "found" part of such errors).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputFileError

__all__ = ["describe_content", "read_text_file"]

# (magic bytes at offset 0, what they are); checked in order
_MAGIC = (
    (b"PK\x03\x04", "a zip archive (an .npz or .zip file?)"),
    (b"\x93NUMPY", "a NumPy .npy array"),
    (b"\x89PNG\r\n\x1a\n", "a PNG image"),
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"GIF8", "a GIF image"),
    (b"\x1aE\xdf\xa3", "a Matroska/WebM video (.mkv)"),
    (b"\x1f\x8b", "gzip-compressed data"),
    (b"%PDF", "a PDF document"),
    (b"\x80", "a Python pickle"),
)


def describe_content(path, head: bytes | None = None) -> str:
    """What the file at ``path`` holds, from its first bytes (``head``: those bytes, if already read)."""
    p = Path(path)
    if not p.exists():
        return "no such file"
    if p.is_dir():
        return "a folder"
    if head is None:
        try:
            with open(p, "rb") as fh:
                head = fh.read(64)
        except OSError as exc:
            return f"a file that cannot be read ({exc.strerror or exc})"
    if not head:
        return "an empty file"
    if head[4:8] == b"ftyp":
        return "an MP4/MOV video"
    if head.startswith(b"RIFF") and head[8:12] == b"WEBP":
        return "a WebP image"
    for magic, what in _MAGIC:
        if head.startswith(magic):
            return what
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as exc:
        if not (len(head) == 64 and exc.start >= 61):  # not just a multi-byte character cut by the 64-byte window
            return f"binary data (byte 0x{head[exc.start]:02x} at position {exc.start} is not utf-8 text)"
    return "JSON text" if head.lstrip()[:1] in (b"{", b"[") else "text"


def read_text_file(path, expected: str, *, error: type[Exception] = InputFileError, field: str = "<file>") -> str:
    """The utf-8 text of ``path``; ``error(path, field, expected, found)`` (an InputFileError-like class) when it
    is missing, a folder, unreadable or not utf-8 text (``found`` says what it is: :func:`describe_content`).
    ``expected`` names the format, e.g. "camera calibration JSON (utf-8 text)"."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise error(p, field, expected, "no such file") from None
    except IsADirectoryError:
        raise error(p, field, expected, "a folder") from None
    except OSError as exc:
        raise error(p, field, expected, f"a file that cannot be read ({exc.strerror or exc})") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        what = describe_content(p, raw[:64])
        if what in ("text", "JSON text"):  # the bad byte is past the first 64
            what = f"binary data (byte 0x{raw[exc.start]:02x} at position {exc.start} is not utf-8 text)"
        raise error(p, field, expected, what) from None
