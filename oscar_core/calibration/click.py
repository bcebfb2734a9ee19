"""A local web page on which a person clicks the embodiment's skeleton points on a few video frames.

:func:`collect_points` serves, on loopback only (``127.0.0.1``), a page that shows
``frames`` of a video one at a time with the embodiment's skeleton point names
(``Embodiment.skeleton.links``); the person clicks each point where it is (or
skips it), then presses Save. The page posts the clicks, which are checked as a
points file (:func:`oscar_core.calibration.points.parse_points`: the embodiment's
names, frames of the session, pixels inside the image) and written atomically to
``out`` in the format ``oscar calibrate --points`` reads (docs/formats.md,
"Calibration points"); then the server stops and the points are returned.

Pixels: the page maps a click at CSS position (x, y) from the image's corner, on an
image shown w x h for a W x H frame, to u = x W / w - 0.5, v = y H / h - 0.5 (pixel
centres at integer coordinates, as the points file); a browser that reports whole
CSS pixels has x taken at that CSS pixel's centre, so a click on an image shown at
its natural size is at most half a pixel off per axis.

The server is the standard library's ``http.server``. Every request must carry the
session's random token (a query parameter, and the ``X-Oscar-Token`` header for the
post, which a page from another origin cannot send without a preflight the server
never grants), so another local page cannot read the frames or write the file.
"""

from __future__ import annotations

import json
import secrets
import threading
from collections.abc import Callable, Sequence
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import numpy as np

from .._util.log import get_logger
from .points import PixelPoints, PointsFileError, parse_points, save_points

__all__ = ["ClickSession", "choose_frames", "collect_points", "MAX_POST_BYTES"]

_log = get_logger(__name__)

#: the largest points post accepted, bytes (a few thousand clicks take well under this)
MAX_POST_BYTES = 4 << 20
_TEMPLATE = Path(__file__).resolve().parent.parent / "templates" / "calibrate_click.html.j2"


def choose_frames(n_frames: int, count: int) -> list[int]:
    """``count`` frame indices spread uniformly over ``n_frames`` (first and last included), distinct, sorted."""
    if n_frames < 1 or count < 1:
        raise ValueError(f"choose_frames: expected n_frames >= 1 and count >= 1, found {n_frames}, {count}")
    return sorted({int(round(x)) for x in np.linspace(0, n_frames - 1, min(count, n_frames))})


class ClickSession:
    """What the page shows and accepts: ``rgb`` (F, H, W, 3) uint8, the frames ``frames`` (F indices into the
    trajectory, in order), the embodiment's ``names``; ``out`` the points file to write."""

    def __init__(self, embodiment: str, names: Sequence[str], frames: Sequence[int], rgb: np.ndarray, out):
        self.embodiment, self.names, self.frames = embodiment, tuple(names), [int(f) for f in frames]
        if len(rgb) != len(self.frames):
            raise ValueError(f"ClickSession: expected {len(self.frames)} images, found {len(rgb)}")
        self.rgb, self.out = rgb, Path(out)
        self.token = secrets.token_urlsafe(16)
        self.result: PixelPoints | None = None
        self.done = threading.Event()

    @property
    def size(self) -> tuple[int, int]:
        return int(self.rgb.shape[2]), int(self.rgb.shape[1])

    def page(self) -> bytes:
        import jinja2

        env = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined)
        return env.from_string(_TEMPLATE.read_text()).render(embodiment=self.embodiment, token=self.token).encode()

    def session_json(self) -> bytes:
        w, h = self.size
        doc = {
            "embodiment": self.embodiment,
            "points": list(self.names),
            "frames": self.frames,
            "width": w,
            "height": h,
        }
        return json.dumps(doc).encode()

    def frame_png(self, frame: int) -> bytes | None:
        import cv2

        if frame not in self.frames:
            return None
        ok, buf = cv2.imencode(".png", self.rgb[self.frames.index(frame)][..., ::-1])
        return buf.tobytes() if ok else None

    def accept(self, body: bytes) -> PixelPoints:
        """Check a posted points document against the session and write it; :class:`PointsFileError` if bad."""
        src = "<posted points>"
        try:
            doc = json.loads(body)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise PointsFileError(src, "<document>", "JSON", f"invalid JSON ({exc})") from None
        pts = parse_points(doc, src)
        if pts.embodiment not in (None, self.embodiment):
            raise PointsFileError(src, "embodiment", repr(self.embodiment), repr(pts.embodiment))
        w, h = self.size
        for i, (f, n, (u, v)) in enumerate(zip(pts.frame, pts.name, pts.uv)):
            if int(f) not in self.frames:
                raise PointsFileError(src, f"points[{i}].frame", f"one of the frames shown {self.frames}", int(f))
            if n not in self.names:
                raise PointsFileError(src, f"points[{i}].point", "one of the embodiment's point names", repr(n))
            if not (-0.5 <= u < w - 0.5 and -0.5 <= v < h - 0.5):
                raise PointsFileError(src, f"points[{i}]", f"a pixel inside the {w}x{h} image", f"({u:.1f}, {v:.1f})")
        if not len(pts):
            raise PointsFileError(src, "points", "at least one clicked point", "none")
        pts = PixelPoints(pts.frame, pts.name, pts.uv, self.embodiment, str(self.out))
        save_points(pts, self.out)
        self.result = pts
        return pts


def _handler(session: ClickSession):
    class Handler(BaseHTTPRequestHandler):
        def log_message(self, fmt, *args):  # the oscar logger, not stderr
            _log.debug("click page: " + fmt, *args)

        def _send(self, code: int, body: bytes, kind: str) -> None:
            self.send_response(code)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def _json(self, code: int, doc: dict) -> None:
            self._send(code, json.dumps(doc).encode(), "application/json")

        def do_GET(self):
            url = urlsplit(self.path)
            token = parse_qs(url.query).get("token", [""])[0]
            if url.path == "/":
                if not secrets.compare_digest(token, session.token):
                    return self._json(403, {"error": "wrong or missing token"})
                return self._send(200, session.page(), "text/html; charset=utf-8")
            if not secrets.compare_digest(token, session.token):
                return self._json(403, {"error": "wrong or missing token"})
            if url.path == "/session.json":
                return self._send(200, session.session_json(), "application/json")
            if url.path.startswith("/frame/") and url.path.endswith(".png"):
                stem = url.path[len("/frame/") : -len(".png")]
                png = session.frame_png(int(stem)) if stem.isdigit() else None
                if png is not None:
                    return self._send(200, png, "image/png")
            self._json(404, {"error": f"no such page {url.path}"})

        def do_POST(self):
            if urlsplit(self.path).path != "/points":
                return self._json(404, {"error": "no such page"})
            if not secrets.compare_digest(self.headers.get("X-Oscar-Token", ""), session.token):
                return self._json(403, {"error": "wrong or missing token"})
            n = int(self.headers.get("Content-Length") or 0)
            if n > MAX_POST_BYTES:
                return self._json(413, {"error": f"at most {MAX_POST_BYTES} bytes"})
            try:
                pts = session.accept(self.rfile.read(n))
            except PointsFileError as exc:
                return self._json(400, {"error": str(exc)})
            self._json(200, {"points": len(pts), "path": str(session.out)})
            session.done.set()

    return Handler


def collect_points(
    session: ClickSession,
    *,
    port: int = 0,
    on_ready: Callable[[str], None] | None = None,
    timeout_s: float | None = None,
) -> PixelPoints:
    """Serve ``session``'s page on ``127.0.0.1:port`` (0: a free port) until the points are saved; return them.

    on_ready(url) is called once the server listens (the URL holds the token). timeout_s: give up after
    this many seconds (TimeoutError); None waits for as long as it takes.
    """
    server = ThreadingHTTPServer(("127.0.0.1", int(port)), _handler(session))
    server.daemon_threads = True
    thread = threading.Thread(target=server.serve_forever, name="oscar-click-page", daemon=True)
    thread.start()
    url = f"http://127.0.0.1:{server.server_address[1]}/?token={session.token}"
    _log.info("click page at %s", url)
    try:
        if on_ready is not None:
            on_ready(url)
        if not session.done.wait(timeout_s):
            raise TimeoutError(f"click page: no points saved within {timeout_s:g} s")
    finally:
        server.shutdown()
        server.server_close()
    assert session.result is not None
    return session.result


def click_points_on_video(
    embodiment,
    n_frames: int,
    video,
    out,
    *,
    count: int = 4,
    port: int = 0,
    on_ready: Callable[[str], None] | None = None,
    timeout_s: float | None = None,
) -> PixelPoints:
    """Read ``count`` frames spread over the first ``n_frames`` (the trajectory's length) of ``video`` and
    :func:`collect_points` on them for ``embodiment``; the points are written to ``out``.

    The video must hold at least ``n_frames`` frames (frame t is trajectory frame t).
    """
    from ..errors import InputFileError
    from ..media.video import read_video, video_info

    frames = choose_frames(n_frames, count)
    have = int(video_info(video)["frames"])
    if have < n_frames:
        raise InputFileError(video, "frames", f"at least {n_frames} frames (the trajectory's length)", f"{have} frames")
    rgb = read_video(video, max_frames=frames[-1] + 1)[frames]
    session = ClickSession(embodiment.name, embodiment.skeleton.links, frames, rgb, out)
    return collect_points(session, port=port, on_ready=on_ready, timeout_s=timeout_s)
