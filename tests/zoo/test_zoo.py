"""The zoo: table, front door, loopback mock Hub, offline cache, hashes, user registry.

No test reaches a real endpoint: HF_ENDPOINT points at a closed local port
unless a test passes the mock hub's URL, and caches/registries live in tmp.
"""

import dataclasses
import json

import numpy as np
import pytest
import torch
from _models import tiny_world_model
from diffusers import CosmosTransformer3DModel

import oscar_zoo
from oscar_core.model import CheckpointIntegrityError, CheckpointLayoutError, SamplerConfig
from oscar_core.model.tiny import TINY_TRANSFORMER_CONFIG, build_tiny_vae
from oscar_core.model.weights import meta_tensors
from oscar_zoo import UnknownModelError
from oscar_zoo.testing import MockHub

COSMOS_REV = "diffusers/base/post-trained"


@pytest.fixture(autouse=True)
def isolated(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")  # closed port: any stray call fails at once
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hf-cache"))
    monkeypatch.setenv("OSCAR_ZOO_REGISTRY", str(tmp_path / "zoo.json"))
    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    monkeypatch.setenv("HF_HUB_DISABLE_TELEMETRY", "1")


@pytest.fixture(scope="module")
def tiny():
    return tiny_world_model(skeleton_scale=0.05, name="tiny", chunk_frames=5, embodiments=("toyarm",))


@pytest.fixture(scope="module")
def exported(tiny, tmp_path_factory):
    return oscar_zoo.export(tiny, tmp_path_factory.mktemp("export") / "tiny")


@pytest.fixture
def hub():
    with MockHub() as h:
        yield h


def _same_weights(a, b):
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


def _rollout(model):
    rng = np.random.default_rng(1)
    first, skel = rng.integers(0, 256, (16, 32, 3), np.uint8), rng.integers(0, 256, (5, 16, 32, 3), np.uint8)
    return model.rollout(first, skel, sampler=SamplerConfig(steps=2), seed=5, progress=False).frames


def _register(hub, exported, name="tiny-ft", repo="me/tiny-ft"):
    commit = hub.add_folder(repo, exported)
    manifest = json.loads((exported / "oscar_manifest.json").read_text())["files"]
    return oscar_zoo.register(name, repo, commit, files={p: m["sha256"] for p, m in manifest.items()}), commit


# --------------------------------------------------------------------------- table


def test_table_is_sorted_frozen_and_honest():
    names = [s.name for s in oscar_zoo.CHECKPOINTS]
    assert names == sorted(names) and {"oscar-2b", "cosmos-predict2.5-2b"} <= set(names)
    spec = {s.name: s for s in oscar_zoo.CHECKPOINTS}
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec["oscar-2b"].revision = "x"
    assert spec["oscar-2b"].repo_id == "zywu2115/OSCAR-2B" and spec["oscar-2b"].revision is None
    # nothing invented: Hub entries pin no hash that could not be verified; a bundled entry pins every file
    assert all(f.sha256 is None for s in oscar_zoo.CHECKPOINTS if not s.bundled for f in s.files)
    assert all(f.sha256 for s in oscar_zoo.CHECKPOINTS if s.bundled for f in s.files)
    base = spec["cosmos-predict2.5-2b"]
    assert (base.repo_id, base.revision, base.kind) == ("nvidia/Cosmos-Predict2.5-2B", COSMOS_REV, "cosmos-base")


def test_unknown_name_lists_the_known_ones():
    with pytest.raises(UnknownModelError, match="cosmos-predict2.5-2b, oscar-2b"):
        oscar_zoo.load("no-such-model")


# --------------------------------------------------------------------------- loading


def test_load_by_name_through_the_mock_hub_same_weights_same_outputs(hub, exported, tiny):
    _register(hub, exported)
    model = oscar_zoo.load("tiny-ft", endpoint=hub.url)
    assert _same_weights(model.transformer, tiny.transformer) and _same_weights(model.vae.vae, tiny.vae.vae)
    assert model.card.embodiments == ("toyarm",) and model.card.chunk_frames == 5
    np.testing.assert_array_equal(_rollout(model), _rollout(tiny))
    assert any(path.endswith("transformer/diffusion_pytorch_model.safetensors") for _, path in hub.requests)


def test_offline_from_the_cache(hub, exported, tiny, monkeypatch):
    _register(hub, exported)
    oscar_zoo.pull("tiny-ft", endpoint=hub.url)
    seen = len(hub.requests)
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    model = oscar_zoo.load("tiny-ft")  # HF_ENDPOINT is the closed port: only the cache can answer
    assert len(hub.requests) == seen
    assert _same_weights(model.transformer, tiny.transformer)


def test_offline_without_cache_says_so(monkeypatch, exported, hub):
    _register(hub, exported)
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    with pytest.raises(CheckpointLayoutError, match="offline"):
        oscar_zoo.load("tiny-ft")


def test_load_a_local_folder(exported, tiny):
    assert _same_weights(oscar_zoo.load(str(exported)).transformer, tiny.transformer)


def test_cosmos_base_by_name_gives_base_plus_zero_pe_s(hub, tmp_path):
    torch.manual_seed(0)
    base = CosmosTransformer3DModel(**TINY_TRANSFORMER_CONFIG).eval()
    base.save_pretrained(tmp_path / "base" / "transformer", max_shard_size="200KB")  # sharded, like the 2B
    build_tiny_vae(seed=3).save_pretrained(tmp_path / "base" / "vae")
    hub.add_folder("nvidia/Cosmos-Predict2.5-2B", tmp_path / "base", revision=COSMOS_REV)
    model = oscar_zoo.load("cosmos-predict2.5-2b", endpoint=hub.url)
    assert meta_tensors(model.transformer) == []
    assert torch.count_nonzero(model.transformer.skeleton_embed.proj.weight) == 0
    state = model.transformer.state_dict()
    assert all(torch.equal(state[k], v) for k, v in base.state_dict().items())
    assert model.card.chunk_frames == 93 and model.card.base == f"nvidia/Cosmos-Predict2.5-2B@{COSMOS_REV}"
    assert any("diffusers%2Fbase%2Fpost-trained" in path for _, path in hub.requests)


# --------------------------------------------------------------------------- bad checkpoints


def test_tampered_file_is_detected_not_loaded(hub, exported):
    _, commit = _register(hub, exported)
    hub.tamper("me/tiny-ft", "transformer/diffusion_pytorch_model.safetensors", b"\x08" + b"\0" * 20)
    with pytest.raises(CheckpointIntegrityError) as err:
        oscar_zoo.load("tiny-ft", endpoint=hub.url)
    message = str(err.value)
    assert "transformer/diffusion_pytorch_model.safetensors: sha256: expected" in message
    assert "oscar zoo pull --force tiny-ft" in message


def test_partial_file_without_known_hash_is_detected(tmp_path, exported):
    import shutil

    folder = tmp_path / "partial"
    shutil.copytree(exported, folder)
    (folder / "oscar_manifest.json").unlink()  # no hash to compare with: the structure check must catch it
    weights = folder / "vae" / "diffusion_pytorch_model.safetensors"
    weights.write_bytes(weights.read_bytes()[:-100])
    with pytest.raises(CheckpointIntegrityError, match="file size: expected"):
        oscar_zoo.load(str(folder))


def test_missing_files_report_expected_and_found(hub):
    hub.add_files("zywu2115/OSCAR-2B", {"README.md": b"# OSCAR", "model.pt": b"pickle"})
    with pytest.raises(CheckpointLayoutError) as err:
        oscar_zoo.load("oscar-2b", endpoint=hub.url)
    message = str(err.value)
    assert "layouts tried — oscar: oscar_model.json, transformer/config.json" in message
    assert "diffusers: transformer/config.json" in message and "cosmos-native: one DiT checkpoint" in message
    assert "found README.md, model.pt" in message and "model.pt but no diffusers vae/" in message
    assert "unverified" in message


def test_missing_weights_in_a_partial_repo(hub, exported):
    files = {p.relative_to(exported).as_posix(): p.read_bytes() for p in exported.rglob("*") if p.is_file()}
    del files["oscar_manifest.json"], files["vae/diffusion_pytorch_model.safetensors"]
    hub.add_files("me/broken", files)
    with pytest.raises(CheckpointLayoutError, match="missing vae/diffusion_pytorch_model.safetensors"):
        oscar_zoo.load("me/broken", endpoint=hub.url)


# --------------------------------------------------------------------------- user registry and push


def test_registry_names_cannot_shadow_the_table():
    with pytest.raises(ValueError, match="not in the built-in table"):
        oscar_zoo.register("oscar-2b", "me/x")
    with pytest.raises(ValueError, match="no '/'"):
        oscar_zoo.register("me/x", "me/x")
    spec = oscar_zoo.register("mine", "me/x", "main", chunk_frames=9)
    assert [s.name for s in oscar_zoo.list_models()] == [
        "cosmos-predict2.5-2b",
        "mine",
        "oscar-2b",
        "oscar-toy",
        "oscar-toy-fast",
    ]
    assert spec.source == str(oscar_zoo.registry_path()) and oscar_zoo.unregister("mine")


def test_push_registers_and_loads_back_by_name(hub, exported, tiny, monkeypatch):
    from huggingface_hub import HfApi

    monkeypatch.setattr(HfApi, "create_repo", lambda self, repo_id, **kw: None)
    monkeypatch.setattr(
        HfApi,
        "upload_folder",
        lambda self, folder_path, repo_id, **kw: type("Commit", (), {"oid": hub.add_folder(repo_id, folder_path)})(),
    )
    spec = oscar_zoo.push(exported, "me/pushed", name="pushed")
    assert spec.pinned and spec.files and all(f.sha256 for f in spec.files)
    model = oscar_zoo.load("pushed", endpoint=hub.url)
    assert _same_weights(model.transformer, tiny.transformer)
