"""A loopback mock of the Hugging Face Hub, for tests that must never reach the real one.

It answers, on 127.0.0.1, the endpoints ``hf_hub_download``,
``snapshot_download`` and ``list_repo_files`` use:

* ``HEAD|GET /{repo_id}/resolve/{revision}/{path}`` — the file, with the
  headers huggingface_hub requires (``X-Repo-Commit``, ``ETag``,
  ``Content-Length``); 404s carry ``X-Error-Code`` (RepoNotFound,
  RevisionNotFound, EntryNotFound) so the client raises the right error
  at once, without retries;
* ``GET /api/models/{repo_id}/revision/{revision}`` — repo info (sha, siblings);
* ``GET /api/models/{repo_id}/tree/{revision}[/{path}]`` — the file listing.

Usage::

    with MockHub() as hub:
        commit = hub.add_folder("me/tiny", folder)
        oscar_zoo.load("me/tiny", endpoint=hub.url, cache_dir=tmp_path / "hf")

Every request is recorded in ``hub.requests`` (method, path); ``tamper``
changes a served file without touching anything else (corruption tests).
"""

from __future__ import annotations

import hashlib
import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import unquote, urlsplit

__all__ = ["MockHub"]


class MockHub:
    """Serve in-memory repositories over HTTP on 127.0.0.1 (a free port)."""

    def __init__(self):
        self.repos: dict[str, dict] = {}  # repo_id -> {"refs": {name: commit}, "commits": {commit: {path: bytes}}}
        self.requests: list[tuple[str, str]] = []
        self._server: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ content
    def add_files(self, repo_id: str, files: dict[str, bytes], revision: str = "main") -> str:
        """Publish ``files`` as a new commit of ``repo_id`` on branch ``revision``; returns the commit hash."""
        digest = hashlib.sha1(repo_id.encode())
        for path in sorted(files):
            digest.update(path.encode() + b"\0" + hashlib.sha256(files[path]).digest())
        commit = digest.hexdigest()
        repo = self.repos.setdefault(repo_id, {"refs": {}, "commits": {}})
        repo["commits"][commit] = dict(files)
        repo["refs"][revision] = commit
        return commit

    def add_folder(self, repo_id: str, folder, revision: str = "main") -> str:
        """Publish every file under ``folder`` (hidden files skipped)."""
        folder = Path(folder)
        files = {
            p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*"))
            if p.is_file() and not any(part.startswith(".") for part in p.relative_to(folder).parts)
        }
        return self.add_files(repo_id, files, revision)

    def tamper(self, repo_id: str, path: str, data: bytes, revision: str = "main") -> None:
        """Serve ``data`` for ``path`` from now on, keeping the commit hash (a corrupted upload/CDN)."""
        repo = self.repos[repo_id]
        repo["commits"][repo["refs"].get(revision, revision)][path] = data

    def _files(self, repo_id: str, revision: str):
        repo = self.repos.get(repo_id)
        if repo is None:
            return None, None, "RepoNotFound"
        commit = repo["refs"].get(revision, revision if revision in repo["commits"] else None)
        if commit is None:
            return None, None, "RevisionNotFound"
        return commit, repo["commits"][commit], None

    # ------------------------------------------------------------------ server
    @property
    def url(self) -> str:
        if self._server is None:
            raise RuntimeError("MockHub is not running: use it as a context manager or call start()")
        host, port = self._server.server_address[:2]
        return f"http://{host}:{port}"

    def start(self) -> MockHub:
        hub = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args):  # keep test output clean
                pass

            def do_HEAD(self):
                hub._handle(self, head=True)

            def do_GET(self):
                hub._handle(self, head=False)

        self._server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._server.daemon_threads = True
        self._thread = threading.Thread(
            target=self._server.serve_forever, kwargs={"poll_interval": 0.05}, name="oscar-mock-hub", daemon=True
        )
        self._thread.start()
        return self

    def stop(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None

    def __enter__(self) -> MockHub:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------------ routing
    def _handle(self, req: BaseHTTPRequestHandler, head: bool) -> None:
        path = urlsplit(req.path).path
        self.requests.append((req.command, path))
        parts = [unquote(p) for p in path.strip("/").split("/")]
        if len(parts) >= 5 and parts[0] == "api" and parts[1] == "models" and parts[4] in ("revision", "tree"):
            repo_id, kind, revision, sub = (
                f"{parts[2]}/{parts[3]}",
                parts[4],
                parts[5] if len(parts) > 5 else "main",
                "/".join(parts[6:]),
            )
            return self._api(req, head, repo_id, kind, revision, sub)
        if len(parts) >= 5 and parts[2] == "resolve":
            return self._resolve(req, head, f"{parts[0]}/{parts[1]}", parts[3], "/".join(parts[4:]))
        self._send(req, 404, b"", head, {"X-Error-Code": "RepoNotFound"})

    def _resolve(self, req, head, repo_id, revision, file_path):
        commit, files, error = self._files(repo_id, revision)
        if error:
            return self._send(req, 404, error.encode(), head, {"X-Error-Code": error})
        if file_path not in files:
            return self._send(
                req, 404, b"EntryNotFound", head, {"X-Error-Code": "EntryNotFound", "X-Repo-Commit": commit}
            )
        data = files[file_path]
        headers = {
            "X-Repo-Commit": commit,
            "ETag": f'"{hashlib.sha256(data).hexdigest()}"',
            "Content-Type": "application/octet-stream",
            "Accept-Ranges": "bytes",
        }
        start = 0
        rng = req.headers.get("Range", "")
        if rng.startswith("bytes=") and not head:
            start = int(rng[6:].split("-")[0] or 0)
            headers["Content-Range"] = f"bytes {start}-{len(data) - 1}/{len(data)}"
            return self._send(req, 206, data[start:], head, headers)
        self._send(req, 200, data, head, headers)

    def _api(self, req, head, repo_id, kind, revision, sub):
        commit, files, error = self._files(repo_id, revision)
        if error:
            return self._send(req, 404, json.dumps({"error": error}).encode(), head, {"X-Error-Code": error})
        if kind == "revision":
            body = {
                "id": repo_id,
                "modelId": repo_id,
                "sha": commit,
                "private": False,
                "siblings": [{"rfilename": p} for p in sorted(files)],
            }
        else:
            prefix = sub.rstrip("/") + "/" if sub else ""
            body = [
                {"type": "file", "path": p, "size": len(d), "oid": hashlib.sha1(d).hexdigest()}
                for p, d in sorted(files.items())
                if p.startswith(prefix)
            ]
        self._send(req, 200, json.dumps(body).encode(), head, {"Content-Type": "application/json"})

    @staticmethod
    def _send(req, status: int, body: bytes, head: bool, headers: dict) -> None:
        req.send_response(status)
        for key, value in headers.items():
            req.send_header(key, value)
        req.send_header("Content-Length", str(len(body)))
        req.end_headers()
        if not head:
            req.wfile.write(body)
