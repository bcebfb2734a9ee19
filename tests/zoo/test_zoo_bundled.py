"""Checkpoints shipped inside the package (``CheckpointSpec.bundled``): offline, hash-pinned, no revisions."""

import dataclasses

import numpy as np
import pytest
from _models import tiny_world_model

import oscar_zoo
from oscar_core.model import CheckpointIntegrityError, SamplerConfig
from oscar_core.toyworld.package import file_hashes
from oscar_zoo import UnknownModelError
from oscar_zoo._table import CheckpointSpec, FileSpec


@pytest.fixture(autouse=True)
def offline(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")  # closed port: a Hub call fails at once
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "empty-cache"))
    monkeypatch.setenv("OSCAR_ZOO_REGISTRY", str(tmp_path / "zoo.json"))


@pytest.fixture
def bundled(tmp_path, monkeypatch):
    folder = tmp_path / "assets" / "tiny-bundled"
    model = tiny_world_model(skeleton_scale=0.05, name="tiny-bundled", chunk_frames=5)
    model.save_pretrained(folder)
    spec = CheckpointSpec(
        name="tiny-bundled",
        repo_id="",
        revision=None,
        kind="oscar",
        license="Apache-2.0",
        paper=None,
        chunk_frames=5,
        files=tuple(FileSpec(p, h) for p, h in file_hashes(folder).items()),
        bundled=str(folder),
    )  # absolute: the package folder is not joined to it
    from oscar_zoo import _fetch

    monkeypatch.setattr(_fetch, "list_models", lambda: (spec,))
    return spec, folder, model


def test_bundled_model_loads_offline_and_equals_the_saved_one(bundled):
    spec, folder, model = bundled
    loaded = oscar_zoo.load("tiny-bundled")
    assert loaded.card.name == "tiny-bundled"
    rng = np.random.default_rng(0)
    first, skel = rng.integers(0, 256, (16, 32, 3), np.uint8), rng.integers(0, 256, (5, 16, 32, 3), np.uint8)
    a = loaded.rollout(first, skel, sampler=SamplerConfig(steps=2), progress=False).frames
    b = model.rollout(first, skel, sampler=SamplerConfig(steps=2), progress=False).frames
    np.testing.assert_array_equal(a, b)
    assert oscar_zoo.pull("tiny-bundled") == folder.resolve()


def test_a_changed_file_fails_its_pinned_hash(bundled):
    spec, folder, _ = bundled
    cfg = folder / "transformer" / "config.json"
    cfg.write_text(cfg.read_text() + "\n")  # same JSON, other bytes
    with pytest.raises(CheckpointIntegrityError, match="sha256"):
        oscar_zoo.load("tiny-bundled")


def test_no_revision_and_a_missing_folder_is_named(bundled, monkeypatch, tmp_path):
    spec, folder, _ = bundled
    with pytest.raises(UnknownModelError, match="no revision"):
        oscar_zoo.load("tiny-bundled", revision="main")
    gone = dataclasses.replace(spec, bundled=str(tmp_path / "nowhere"))
    from oscar_zoo import _fetch

    monkeypatch.setattr(_fetch, "list_models", lambda: (gone,))
    with pytest.raises(Exception, match="reinstall oscar-wm"):
        oscar_zoo.load("tiny-bundled")
