"""oscar_core.model._verified: a weight file's sha256 is remembered while the file is unchanged, and only then."""

import hashlib
import os

import pytest
from _models import tiny_world_model

import oscar_zoo
from oscar_core.model import _verified
from oscar_core.model.errors import CheckpointIntegrityError


@pytest.fixture(autouse=True)
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("OSCAR_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("OSCAR_VERIFY", raising=False)
    return tmp_path / "cache" / "verified"


def _count_hashes(monkeypatch):
    calls = []
    real = _verified.sha256_file

    def counting(path):
        calls.append(path)
        return real(path)

    monkeypatch.setattr(_verified, "sha256_file", counting)
    return calls


def test_remembered_while_unchanged_and_rehashed_after_any_write(tmp_path, monkeypatch, cache):
    f = tmp_path / "w.bin"
    f.write_bytes(b"a" * 1000)
    calls = _count_hashes(monkeypatch)
    assert _verified.file_sha256(f) == hashlib.sha256(b"a" * 1000).hexdigest() and len(calls) == 1
    assert len(list(cache.glob("*.json"))) == 1
    assert _verified.file_sha256(f) == hashlib.sha256(b"a" * 1000).hexdigest() and len(calls) == 1  # remembered
    # same size, modification time set back: the write still changed ctime, so it is hashed again
    st = os.stat(f)
    f.write_bytes(b"b" * 1000)
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert os.stat(f).st_mtime_ns == st.st_mtime_ns and os.stat(f).st_size == st.st_size
    assert _verified.file_sha256(f) == hashlib.sha256(b"b" * 1000).hexdigest() and len(calls) == 2
    monkeypatch.setenv("OSCAR_VERIFY", "full")  # always hash
    assert _verified.file_sha256(f) == hashlib.sha256(b"b" * 1000).hexdigest() and len(calls) == 3


def test_a_garbled_record_is_ignored(tmp_path, monkeypatch, cache):
    f = tmp_path / "w.bin"
    f.write_bytes(b"xyz")
    _verified.file_sha256(f)
    [record] = cache.glob("*.json")
    record.write_text("{not json")
    calls = _count_hashes(monkeypatch)
    assert _verified.file_sha256(f) == hashlib.sha256(b"xyz").hexdigest() and len(calls) == 1


def test_a_changed_weight_file_is_still_refused_on_the_next_load(tmp_path, monkeypatch):
    model = tiny_world_model(name="t", chunk_frames=17)
    folder = oscar_zoo.export(model, tmp_path / "m")
    calls = _count_hashes(monkeypatch)
    oscar_zoo.load(folder)
    first = len(calls)
    assert first >= 4  # configs, card, both weight files (the manifest lists them all)
    oscar_zoo.load(folder)
    assert len(calls) == first  # nothing read twice while unchanged
    weights = folder / "transformer" / "diffusion_pytorch_model.safetensors"
    st = os.stat(weights)
    data = bytearray(weights.read_bytes())
    data[-1] ^= 0xFF  # one flipped bit in the last tensor: same size, same structure
    weights.write_bytes(bytes(data))
    os.utime(weights, ns=(st.st_atime_ns, st.st_mtime_ns))
    with pytest.raises(CheckpointIntegrityError, match="sha256"):
        oscar_zoo.load(folder)
