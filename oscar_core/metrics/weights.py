"""The standard networks of the video metrics: pinned URLs, sha256, a cache, ``oscar eval weights pull``.

| name | file | from | pin |
|---|---|---|---|
| ``i3d`` | ``i3d_torchscript.pt`` (FVD) | StyleGAN-V ``src/metrics/frechet_video_distance.py`` | trust on first use |
| ``inception`` | ``inception-2015-12-05.pt`` (FID) | StyleGAN2-ADA / StyleGAN-V ``metric_utils`` | trust on first use |
| ``lpips-alex`` | ``lpips/weights/v0.1/alex.pth`` | richzhang/PerceptualSimilarity @ 082bb24 | full sha256 |
| ``lpips-vgg`` | ``lpips/weights/v0.1/vgg.pth`` | richzhang/PerceptualSimilarity @ 082bb24 | full sha256 |
| ``alexnet`` | ``alexnet-owt-7be5be79.pth`` (LPIPS trunk) | torchvision's model URL | sha256 prefix 7be5be79 |
| ``vgg16`` | ``vgg16-397923af.pth`` (LPIPS trunk) | torchvision's model URL | sha256 prefix 397923af |

Where the hashes come from: the two LPIPS linear-layer files are in the public
PerceptualSimilarity repository; their sha256 were computed here from the git
objects at commit 082bb24f84c091ea94de2867d34c4544f68e0963, and the URL names
that commit, so the bytes cannot change. torchvision names its files with the
first 8 hex digits of their sha256 (``torch.hub``'s ``check_hash`` convention),
so those files are pinned to that prefix. For the two TorchScript detectors no
public source states a sha256 (the references download them unverified), so
none is invented: the first download's sha256 is recorded in the cache's lock
file ``weights.lock.json`` (trust on first use) and every later use must
match it. A full pin or a lock entry that does not match is an error naming
the file, the expected and the found hash; the bad download is deleted.

The cache is ``$OSCAR_WEIGHTS_CACHE``, else ``$XDG_CACHE_HOME/oscar/weights``
(``~/.cache/oscar/weights``). Downloads go to a temporary file that is renamed
into place only after its hash is accepted. :func:`weight_path` re-checks the
hash every time a file is used — before ``torch.jit.load`` (which may run
code from the archive) or ``torch.load(weights_only=True)``.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from .._util.atomic import atomic_write_bytes
from .common import MetricInputError

__all__ = [
    "WeightFile",
    "WEIGHTS",
    "WeightHashError",
    "weights_cache_dir",
    "pull_weights",
    "weight_path",
    "cached_networks",
    "LOCK_NAME",
    "GROUPS",
]

LOCK_NAME = "weights.lock.json"
_LPIPS_COMMIT = "082bb24f84c091ea94de2867d34c4544f68e0963"


@dataclass(frozen=True)
class WeightFile:
    """One downloadable file: ``sha256`` (full pin), ``sha256_prefix`` (leading hex digits) or neither (TOFU)."""

    name: str
    url: str
    filename: str
    kind: str  # "torchscript" or "state_dict"
    source: str
    sha256: str | None = None
    sha256_prefix: str | None = None

    @property
    def pin(self) -> str:
        if self.sha256:
            return "sha256"
        return "sha256 prefix" if self.sha256_prefix else "trust on first use"


WEIGHTS: dict[str, WeightFile] = {
    w.name: w
    for w in (
        WeightFile(
            "i3d",
            "https://www.dropbox.com/s/ge9e5ujwgetktms/i3d_torchscript.pt?dl=1",
            "i3d_torchscript.pt",
            "torchscript",
            "StyleGAN-V src/metrics/frechet_video_distance.py (universome/stylegan-v@3fecd69)",
        ),
        WeightFile(
            "inception",
            "https://nvlabs-fi-cdn.nvidia.com/stylegan2-ada-pytorch/pretrained/metrics/inception-2015-12-05.pt",
            "inception-2015-12-05.pt",
            "torchscript",
            "StyleGAN2-ADA metrics/frechet_inception_distance.py (TorchScript of the TF 2015-12-05 Inception)",
        ),
        WeightFile(
            "lpips-alex",
            f"https://raw.githubusercontent.com/richzhang/PerceptualSimilarity/{_LPIPS_COMMIT}/"
            "lpips/weights/v0.1/alex.pth",
            "lpips_v0.1_alex.pth",
            "state_dict",
            f"richzhang/PerceptualSimilarity@{_LPIPS_COMMIT[:7]} lpips/weights/v0.1/alex.pth (6009 bytes)",
            sha256="df73285e35b22355a2df87cdb6b70b343713b667eddbda73e1977e0c860835c0",
        ),
        WeightFile(
            "lpips-vgg",
            f"https://raw.githubusercontent.com/richzhang/PerceptualSimilarity/{_LPIPS_COMMIT}/"
            "lpips/weights/v0.1/vgg.pth",
            "lpips_v0.1_vgg.pth",
            "state_dict",
            f"richzhang/PerceptualSimilarity@{_LPIPS_COMMIT[:7]} lpips/weights/v0.1/vgg.pth (7289 bytes)",
            sha256="a78928a0af1e5f0fcb1f3b9e8f8c3a2a5a3de244d830ad5c1feddc79b8432868",
        ),
        WeightFile(
            "alexnet",
            "https://download.pytorch.org/models/alexnet-owt-7be5be79.pth",
            "alexnet-owt-7be5be79.pth",
            "state_dict",
            "torchvision AlexNet_Weights.IMAGENET1K_V1 (LPIPS's trunk)",
            sha256_prefix="7be5be79",
        ),
        WeightFile(
            "vgg16",
            "https://download.pytorch.org/models/vgg16-397923af.pth",
            "vgg16-397923af.pth",
            "state_dict",
            "torchvision VGG16_Weights.IMAGENET1K_V1 (LPIPS's VGG trunk)",
            sha256_prefix="397923af",
        ),
    )
}

#: What ``oscar eval weights pull`` fetches by default (LPIPS-VGG on request).
GROUPS = {"default": ("i3d", "inception", "lpips-alex", "alexnet"), "all": tuple(WEIGHTS)}


class WeightHashError(MetricInputError):
    """A downloaded or cached weight file does not have the pinned (or recorded) sha256."""


def weights_cache_dir(cache_dir=None) -> Path:
    if cache_dir is not None:
        return Path(cache_dir)
    env = os.environ.get("OSCAR_WEIGHTS_CACHE")
    if env:
        return Path(env)
    root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "oscar" / "weights"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _read_lock(cache: Path) -> dict:
    path = cache / LOCK_NAME
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except ValueError as exc:
        raise MetricInputError(path, "JSON", "the weights lock file written by oscar", str(exc)) from None
    return data if isinstance(data, dict) else {}


def _write_lock(cache: Path, lock: dict) -> None:
    atomic_write_bytes(cache / LOCK_NAME, (json.dumps(lock, indent=2, sort_keys=True) + "\n").encode())


def _check(w: WeightFile, digest: str, lock: dict, where) -> str:
    """Raise WeightHashError unless ``digest`` is acceptable; returns how it was accepted."""
    if w.sha256:
        if digest != w.sha256:
            raise WeightHashError(where, "sha256", f"{w.sha256} (pinned: {w.source})", digest)
        return "pinned sha256"
    if w.sha256_prefix and not digest.startswith(w.sha256_prefix):
        raise WeightHashError(where, "sha256", f"a hash starting {w.sha256_prefix} (torchvision's file name)", digest)
    entry = lock.get(w.name)
    if entry is not None:
        if entry.get("url") == w.url and entry.get("sha256") != digest:
            raise WeightHashError(
                where, "sha256", f"{entry.get('sha256')} (recorded in {LOCK_NAME} on {entry.get('recorded')})", digest
            )
        if entry.get("url") == w.url:
            return "matches the lock file"
    return "trust on first use"


def _download(url: str, dest: Path, timeout: float, progress: Callable[[str], None] | None) -> None:
    request = urllib.request.Request(url, headers={"User-Agent": "oscar-weights/1"})
    try:
        with urllib.request.urlopen(request, timeout=timeout) as response, open(dest, "wb") as f:
            shutil.copyfileobj(response, f, length=1 << 20)
    except urllib.error.HTTPError as exc:
        raise MetricInputError(url, "download", "HTTP 200", f"HTTP {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, OSError, TimeoutError) as exc:
        reason = getattr(exc, "reason", exc)
        raise MetricInputError(url, "download", "a reachable URL", f"{type(reason).__name__}: {reason}") from None


def pull_weights(
    names: Iterable[str] = GROUPS["default"],
    *,
    cache_dir=None,
    force: bool = False,
    table: Mapping[str, WeightFile] | None = None,
    timeout: float = 300.0,
    log: Callable[[str], None] | None = None,
) -> dict[str, dict]:
    """Download (or verify, if cached) the named files; returns ``{name: {"path", "sha256", "status", "pin"}}``.

    ``table`` replaces :data:`WEIGHTS` (tests serve fixture files from 127.0.0.1).
    A file already in the cache is re-hashed and checked instead of downloaded
    (``force`` downloads again). Raises :class:`WeightHashError` on a mismatch.
    """
    table = WEIGHTS if table is None else table
    log = log or (lambda m: None)
    cache = weights_cache_dir(cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    lock = _read_lock(cache)
    out = {}
    for name in names:
        if name not in table:
            raise MetricInputError("weights", "name", f"one of {sorted(table)} (or 'all')", repr(name))
        w = table[name]
        path = cache / w.filename
        if path.is_file() and not force:
            digest = _sha256(path)
            how = _check(w, digest, lock, path)
            status = "cached"
        else:
            log(f"downloading {w.name} from {w.url}")
            fd, tmp = tempfile.mkstemp(prefix=f".{w.filename}.", suffix=".part", dir=cache)
            os.close(fd)
            tmp = Path(tmp)
            try:
                _download(w.url, tmp, timeout, log)
                digest = _sha256(tmp)
                how = _check(w, digest, lock, w.url)
                os.replace(tmp, path)
            finally:
                tmp.unlink(missing_ok=True)
            status = "downloaded"
        if how == "trust on first use":
            lock[w.name] = {
                "url": w.url,
                "sha256": digest,
                "size": path.stat().st_size,
                "recorded": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                "how": "trust on first use",
            }
            _write_lock(cache, lock)
            log(f"{w.name}: no published sha256; recorded {digest} in {cache / LOCK_NAME} (trust on first use)")
        out[name] = {
            "path": str(path),
            "sha256": digest,
            "status": status,
            "check": how,
            "pin": w.pin,
            "url": w.url,
            "source": w.source,
        }
    return out


def weight_path(name: str, *, cache_dir=None, table: Mapping[str, WeightFile] | None = None) -> Path | None:
    """The verified cached file of ``name``, or None if it is not in the cache (run ``oscar eval weights pull``).

    The file is re-hashed and must match its pin or its lock entry (a file with
    neither — never pulled through oscar — is refused).
    """
    found = _verified(name, cache_dir, table)
    return None if found is None else found[0]


def _verified(name: str, cache_dir, table) -> tuple[Path, str] | None:
    """(path, sha256) of a cached file that matches its pin or lock entry; None if not cached."""
    table = WEIGHTS if table is None else table
    if name not in table:
        return None
    w = table[name]
    cache = weights_cache_dir(cache_dir)
    path = cache / w.filename
    if not path.is_file():
        return None
    lock = _read_lock(cache)
    digest = _sha256(path)
    how = _check(w, digest, lock, path)
    if how == "trust on first use":
        raise WeightHashError(
            path,
            "sha256",
            f"an entry in {cache / LOCK_NAME} (pull it with oscar eval weights pull)",
            "a file oscar did not download",
        )
    return path, digest


def cached_networks(*, cache_dir=None, device="cpu", table: Mapping[str, WeightFile] | None = None) -> dict:
    """The metric networks available in the cache, ready to call: ``{"lpips", "i3d", "inception"}`` (subset).

    LPIPS (AlexNet) needs both ``alexnet`` and ``lpips-alex``. The TorchScript
    detectors are loaded from the very bytes whose sha256 was checked, with
    the reference call arguments (``I3D_CALL_KWARGS``, ``INCEPTION_CALL_KWARGS``).
    """
    from .video import I3D_CALL_KWARGS, INCEPTION_CALL_KWARGS, load_torchscript

    out: dict = {}
    for key, kwargs in (("i3d", I3D_CALL_KWARGS), ("inception", INCEPTION_CALL_KWARGS)):
        found = _verified(key, cache_dir, table)
        if found is not None:
            out[key] = load_torchscript(found[0], device=device, sha256=found[1], **kwargs)
    trunk = weight_path("alexnet", cache_dir=cache_dir, table=table)
    lin = weight_path("lpips-alex", cache_dir=cache_dir, table=table)
    if trunk is not None and lin is not None:
        from .lpips_net import LPIPS

        out["lpips"] = LPIPS.from_files("alex", trunk, lin).to(device)
    return out


def _is_hex(s: str | None, n: int | None = None) -> bool:
    return s is not None and re.fullmatch(r"[0-9a-f]+", s) is not None and (n is None or len(s) == n)
