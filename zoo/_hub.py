"""Talking to the Hub once, with a short timeout, and pinning what a pull saw in a lock file.

* :func:`probe` makes the one request that resolves a revision: ``GET
  {endpoint}/api/models/{repo}/revision/{revision}`` gives the commit and the
  file listing, so the layout is decided before any download and no request
  is repeated. Connection refused, a timeout (``OSCAR_HUB_TIMEOUT`` seconds,
  default 10, counted from the process's start when the request is made
  during start-up, :func:`request_timeout`; nothing else talks to the
  network first, :func:`_headers`) or a server error raise
  :class:`HubUnreachableError` at once —
  "cannot reach the Hub (…); set HF_HUB_OFFLINE=1 to use the cache" — with
  no retry loop.
* Offline (``HF_HUB_OFFLINE=1`` or ``local_files_only``), :func:`cached_commit`
  reads the commit from the lock file or the cache's ``refs/``, and nothing
  touches the network.
* A lock file per (repo, revision) lives beside the cache
  (``{HF_HUB_CACHE}/oscar-locks/models--owner--name/<revision>.json``): the
  resolved commit and the sha256 of every file a pull fetched. A later load
  uses that commit (a moved branch does not change what loads) and verifies
  every file against it.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import quote

from oscar_core._util.atomic import atomic_write_bytes
from oscar_core.errors import OscarError
from oscar_core.model.errors import CheckpointLayoutError

__all__ = [
    "HubUnreachableError",
    "HubInfo",
    "probe",
    "hub_timeout",
    "cache_root",
    "cached_commit",
    "Lock",
    "read_lock",
    "write_lock",
    "lock_path",
    "is_commit",
]

_COMMIT = re.compile(r"^[0-9a-f]{40}$")


class HubUnreachableError(OscarError, ConnectionError):
    """The Hub endpoint did not answer (refused, timed out, server error)."""


def is_commit(revision: str | None) -> bool:
    return bool(revision) and bool(_COMMIT.match(revision))


def hub_timeout(timeout: float | None = None) -> float:
    """Seconds to wait for the Hub: ``timeout``, else ``OSCAR_HUB_TIMEOUT``, else 10."""
    if timeout is not None:
        return float(timeout)
    return float(os.environ.get("OSCAR_HUB_TIMEOUT") or 10.0)


MIN_REQUEST_SECONDS = 2.0  # the least a request is given, however late in start-up it is made


def process_age() -> float | None:
    """Seconds since this process started (interpreter start-up included; Linux ``/proc``), or None."""
    try:
        start_ticks = int(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])
        uptime = float(Path("/proc/uptime").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    return max(0.0, uptime - start_ticks / os.sysconf("SC_CLK_TCK"))


def request_timeout(seconds: float) -> float:
    """The timeout of a Hub request, so that a command that goes to the Hub during its start-up fails within
    ``seconds`` of its start: ``seconds`` minus the process's age while it is younger than ``seconds`` (at least
    :data:`MIN_REQUEST_SECONDS`), else ``seconds``."""
    age = process_age()
    if age is None or age >= seconds:
        return seconds
    return min(seconds, max(seconds - age, MIN_REQUEST_SECONDS))


def cache_root(cache_dir=None) -> Path:
    """The Hub cache folder: ``cache_dir``, else ``HF_HUB_CACHE`` now, else huggingface_hub's default."""
    if cache_dir is not None:
        return Path(cache_dir)
    if os.environ.get("HF_HUB_CACHE"):
        return Path(os.environ["HF_HUB_CACHE"])
    from huggingface_hub import constants

    return Path(constants.HF_HUB_CACHE)


@dataclass(frozen=True)
class HubInfo:
    """What the Hub said about ``repo_id`` at ``revision``: its commit and files."""

    repo_id: str
    revision: str
    commit: str
    files: tuple[str, ...]


def probe(
    repo_id: str, revision: str, *, endpoint: str | None = None, token=None, timeout: float | None = None
) -> HubInfo:
    """Resolve ``revision`` of ``repo_id`` with one request; see the module docstring for the errors."""
    import httpx
    from huggingface_hub import constants

    base = (endpoint or os.environ.get("HF_ENDPOINT") or constants.ENDPOINT).rstrip("/")
    url = f"{base}/api/models/{repo_id}/revision/{quote(revision, safe='')}"
    seconds = hub_timeout(timeout)
    try:
        response = httpx.get(url, headers=_headers(token), timeout=request_timeout(seconds), follow_redirects=True)
    except httpx.TimeoutException:
        raise HubUnreachableError(
            f"cannot reach the Hub ({base}: no answer within {seconds:g} s); set HF_HUB_OFFLINE=1 to use the cache"
        ) from None
    except httpx.HTTPError as exc:
        raise HubUnreachableError(
            f"cannot reach the Hub ({base}: {type(exc).__name__}: {exc}); set HF_HUB_OFFLINE=1 to use the cache"
        ) from None
    code = response.headers.get("X-Error-Code", "")
    label = f"{repo_id}@{revision}"
    if response.status_code == 404 and code == "RevisionNotFound":
        raise CheckpointLayoutError(
            label, "revision", f"a branch, tag or commit of {repo_id}", f"no revision {revision!r}"
        )
    if response.status_code in (401, 403, 404):
        raise CheckpointLayoutError(
            label,
            "repository",
            f"an accessible Hub repository {repo_id}",
            f"HTTP {response.status_code} {code or ''}".strip(),
            f"check the id, your token and the endpoint ({base})",
        )
    if response.status_code >= 400:
        raise HubUnreachableError(
            f"cannot reach the Hub ({base}: HTTP {response.status_code}); set HF_HUB_OFFLINE=1 to use the cache"
        )
    try:
        data = response.json()
        commit = data["sha"]
        files = tuple(sorted(s["rfilename"] for s in data.get("siblings", [])))
    except (ValueError, KeyError, TypeError):
        raise CheckpointLayoutError(
            url, "repo info", "a JSON object with 'sha' and 'siblings'", response.text[:120]
        ) from None
    return HubInfo(repo_id, revision, commit, files)


def _headers(token) -> dict[str, str]:
    """The probe's HTTP headers: a user agent and the token (``token``; None: ``HF_TOKEN`` or the saved login).

    Not ``huggingface_hub.utils.build_hf_headers``: its user agent fetches an
    agent registry from the Hub first (a 3 s timeout of its own, repeated on
    every run while the Hub is unreachable), which made a probe that gives up
    after 10 s fail only after 13 s and more.
    """
    from huggingface_hub import get_token

    from oscar_core import __version__

    tok = None if token is False else (token if isinstance(token, str) else get_token())
    headers = {"user-agent": f"oscar/{__version__}"}
    if tok:
        headers["authorization"] = f"Bearer {tok}"
    return headers


def _repo_folder(cache_dir, repo_id: str) -> Path:
    return cache_root(cache_dir) / f"models--{repo_id.replace('/', '--')}"


def cached_commit(repo_id: str, revision: str, cache_dir=None) -> str | None:
    """The commit ``revision`` pointed to when it was last downloaded (the cache's ``refs/``), or None."""
    if is_commit(revision):
        return revision
    ref = _repo_folder(cache_dir, repo_id) / "refs" / revision
    return ref.read_text().strip() if ref.is_file() else None


def snapshot_folder(repo_id: str, commit: str, cache_dir=None) -> Path:
    return _repo_folder(cache_dir, repo_id) / "snapshots" / commit


@dataclass
class Lock:
    """A pull's record: repo, revision, the commit it resolved to, its layout, and {file: sha256}."""

    repo_id: str
    revision: str
    commit: str
    layout: str
    files: dict[str, str] = field(default_factory=dict)


def lock_path(repo_id: str, revision: str, cache_dir=None) -> Path:
    return (
        cache_root(cache_dir)
        / "oscar-locks"
        / f"models--{repo_id.replace('/', '--')}"
        / f"{quote(revision, safe='')}.json"
    )


def read_lock(repo_id: str, revision: str, cache_dir=None) -> Lock | None:
    path = lock_path(repo_id, revision, cache_dir)
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
        lock = Lock(data["repo_id"], data["revision"], data["commit"], data["layout"], dict(data["files"]))
    except (ValueError, KeyError, TypeError):
        raise CheckpointLayoutError(
            path,
            "lock file",
            "JSON with repo_id, revision, commit, layout, files",
            "an unreadable file",
            "delete it and run `oscar zoo pull` again",
        ) from None
    if lock.repo_id != repo_id or lock.revision != revision:
        raise CheckpointLayoutError(path, "lock file", f"{repo_id}@{revision}", f"{lock.repo_id}@{lock.revision}")
    return lock


def write_lock(lock: Lock, cache_dir=None) -> Path:
    path = lock_path(lock.repo_id, lock.revision, cache_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": "oscar-zoo-lock",
        "version": 1,
        "repo_id": lock.repo_id,
        "revision": lock.revision,
        "commit": lock.commit,
        "layout": lock.layout,
        "files": dict(sorted(lock.files.items())),
    }
    atomic_write_bytes(path, (json.dumps(payload, indent=2) + "\n").encode())
    return path
