"""Checkpoint layouts (oscar, diffusers, native Cosmos), conversion, lock files and Hub failures.

Tiny checkpoints of the real classes are built here in each layout and loaded
through ``oscar_zoo.load`` from folders and from the loopback mock Hub. No
test reaches a real endpoint.
"""

import json
import socket
import threading
import time

import numpy as np
import pytest
import torch
from _models import tiny_world_model
from diffusers import CosmosTransformer3DModel
from safetensors.torch import save_file

import oscar_zoo
from oscar_core.model import CheckpointIntegrityError, CheckpointLayoutError, ModelCard, OscarWorldModel
from oscar_core.model._native import NATIVE_RENAMES, map_native_key, map_native_state
from oscar_core.model.layouts import detect_layout
from oscar_core.model.tiny import TINY_TRANSFORMER_CONFIG, build_tiny_transformer, build_tiny_vae
from oscar_zoo._hub import HubUnreachableError, lock_path, read_lock
from oscar_zoo.testing import MockHub

#: the 2.5 conversion's config keys shapes cannot tell (rope scale (1, 3, 3), no learnable positions)
NATIVE_CFG = {
    **TINY_TRANSFORMER_CONFIG,
    "rope_scale": (1.0, 3.0, 3.0),
    "extra_pos_embed_type": None,
    "max_size": (128, 240, 240),
}


@pytest.fixture(autouse=True)
def isolated(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")  # closed port: any stray call fails at once
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hf-cache"))
    monkeypatch.setenv("OSCAR_ZOO_REGISTRY", str(tmp_path / "zoo.json"))
    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    monkeypatch.setenv("HF_HUB_DISABLE_TELEMETRY", "1")


@pytest.fixture
def hub():
    with MockHub() as h:
        yield h


def _same(a, b):
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


def _to_native(key: str) -> str:
    """diffusers name → native name (the conversion table applied backwards), with the ``net.`` prefix."""
    for old, new in reversed(NATIVE_RENAMES):
        key = key.replace(new, old)
    return "net." + key


def _oscar_dit(seed=0):
    return build_tiny_transformer(
        seed=seed, skeleton_scale=0.05, **{k: NATIVE_CFG[k] for k in ("rope_scale", "extra_pos_embed_type", "max_size")}
    )


def _native_folder(tmp_path, dit, *, skeleton_name="net.skeleton_embedder.proj.1.weight", suffix=".pt", ema_twin=False):
    """A native-Cosmos folder: ``base/post-trained/<id>_ema_bf16<suffix>`` + diffusers ``vae/``."""
    folder = tmp_path / "native"
    state = {}
    for key, value in dit.state_dict().items():
        if key == "skeleton_embed.proj.weight":
            if skeleton_name:
                state[skeleton_name] = value.clone()
            continue
        state[_to_native(key)] = value.clone()
    state["net.accum_iteration"] = torch.tensor(7)  # bookkeeping tensors the conversion drops
    state["net.pos_embedder.seq"] = torch.arange(4.0)
    state["net.blocks.0.self_attn._extra_state"] = torch.zeros(1)
    if ema_twin:  # both copies: the EMA one must win
        state = {
            **{k.replace("net.", "net_ema.", 1): v for k, v in state.items()},
            **{k: torch.randn_like(v.float()).to(v.dtype) for k, v in state.items()},
        }
    path = folder / "base" / "post-trained" / f"81edfebe_ema_bf16{suffix}"
    path.parent.mkdir(parents=True)
    if suffix == ".pt":
        torch.save({"model": state}, path)
    else:
        save_file({k: v.contiguous() for k, v in state.items()}, str(path))
    build_tiny_vae(seed=3).save_pretrained(folder / "vae")
    return folder, path


# --------------------------------------------------------------------------- native key mapping


def test_native_keys_map_like_diffusers_conversion():
    # pairs read off diffusers' scripts/convert_cosmos_to_diffusers.py (Cosmos 2.0 / 2.5 table)
    pairs = {
        "net.blocks.0.self_attn.q_proj.weight": "transformer_blocks.0.attn1.to_q.weight",
        "net.blocks.11.cross_attn.output_proj.weight": "transformer_blocks.11.attn2.to_out.0.weight",
        "net.blocks.3.cross_attn.k_norm.weight": "transformer_blocks.3.attn2.norm_k.weight",
        "net.blocks.2.adaln_modulation_cross_attn.2.weight": "transformer_blocks.2.norm2.linear_2.weight",
        "net.blocks.5.mlp.layer1.weight": "transformer_blocks.5.ff.net.0.proj.weight",
        "net.blocks.5.mlp.layer2.weight": "transformer_blocks.5.ff.net.2.weight",
        "net.x_embedder.proj.1.weight": "patch_embed.proj.weight",
        "net.t_embedder.1.linear_1.weight": "time_embed.t_embedder.linear_1.weight",
        "net.t_embedding_norm.weight": "time_embed.norm.weight",
        "net.final_layer.adaln_modulation.2.weight": "norm_out.linear_2.weight",
        "net.final_layer.linear.weight": "proj_out.weight",
        "net.crossattn_proj.0.weight": "crossattn_proj.0.weight",
    }
    for native, diffusers_name in pairs.items():
        assert map_native_key(native) == diffusers_name
    for dropped in ("net.accum_iteration", "net.pos_embedder.seq", "net.blocks.1.self_attn._extra_state"):
        assert map_native_key(dropped) is None
    with pytest.raises(CheckpointLayoutError, match="both map to"):
        map_native_state(
            {"net.blocks.0.mlp.layer1.weight": torch.zeros(1), "net.blocks.0.ff.net.0.proj.weight": torch.zeros(1)}, "x"
        )


@pytest.mark.parametrize("suffix", [".pt", ".safetensors"])
def test_native_checkpoint_loads_through_the_zoo_with_its_skeleton_embedder(tmp_path, suffix):
    dit = _oscar_dit()
    folder, _ = _native_folder(tmp_path, dit, suffix=suffix)
    report = []
    model = oscar_zoo.load(str(folder), report=report)
    assert _same(model.transformer, dit)
    assert model.transformer.config.rope_scale == (1.0, 3.0, 3.0)
    assert any("net.skeleton_embedder.proj.1.weight -> skeleton_embed.proj.weight" in line for line in report)
    assert any(line.startswith("layout: cosmos-native") for line in report)


def test_native_ema_copy_wins_and_a_base_checkpoint_gets_a_zero_pe_s(tmp_path):
    dit = _oscar_dit()
    folder, _ = _native_folder(tmp_path, dit, skeleton_name=None, ema_twin=True)
    report = []
    model = oscar_zoo.load(str(folder), report=report)
    state = model.transformer.state_dict()
    assert all(torch.equal(state[k], v) for k, v in dit.state_dict().items() if k != "skeleton_embed.proj.weight")
    assert torch.count_nonzero(state["skeleton_embed.proj.weight"]) == 0
    assert any("none found" in line for line in report)


def test_native_config_json_beside_the_file_overrides_what_shapes_cannot_tell(tmp_path):
    dit = build_tiny_transformer(seed=1, skeleton_scale=0.05, extra_pos_embed_type=None, rope_scale=(2.0, 1.0, 1.0))
    folder, path = _native_folder(tmp_path, dit, skeleton_name="net.pose_embedder.weight")
    assert oscar_zoo.load(str(folder)).transformer.config.rope_scale == (1.0, 3.0, 3.0)  # the 2.5 default
    (path.parent / "config.json").write_text(json.dumps({"rope_scale": [2.0, 1.0, 1.0]}))
    model = oscar_zoo.load(str(folder))
    assert model.transformer.config.rope_scale == (2.0, 1.0, 1.0) and _same(model.transformer, dit)


def test_native_checkpoint_through_the_mock_hub_fetches_only_what_it_needs(tmp_path, hub):
    dit = _oscar_dit()
    folder, _ = _native_folder(tmp_path, dit)
    (folder / "README.md").write_text("# native")
    (folder / "tokenizer.pth").write_bytes(b"a pickle nobody loads")
    (folder / "vae" / "other.bin").write_bytes(b"x")
    hub.add_folder("nvidia/native", folder)
    model = oscar_zoo.load("nvidia/native", endpoint=hub.url)
    assert _same(model.transformer, dit)
    fetched = {path.split("/resolve/", 1)[1].split("/", 1)[1] for m, path in hub.requests if "/resolve/" in path}
    assert fetched == {
        "base/post-trained/81edfebe_ema_bf16.pt",
        "vae/config.json",
        "vae/diffusion_pytorch_model.safetensors",
    }


def test_several_native_files_must_be_chosen(tmp_path):
    dit = _oscar_dit()
    folder, path = _native_folder(tmp_path, dit)
    (path.parent / "other_ema_bf16.pt").write_bytes(path.read_bytes())
    with pytest.raises(CheckpointLayoutError, match="several native checkpoints"):
        oscar_zoo.load(str(folder))
    model = oscar_zoo.load(str(folder), native_file="base/post-trained/other_ema_bf16.pt")
    assert _same(model.transformer, dit)


# --------------------------------------------------------------------------- diffusers layout


def test_diffusers_folder_with_scheduler_and_a_renamed_skeleton_embedder(tmp_path):
    dit = build_tiny_transformer(seed=2, skeleton_scale=0.05)
    torch.manual_seed(0)
    base = CosmosTransformer3DModel(**TINY_TRANSFORMER_CONFIG).eval()
    base.load_state_dict({k: v for k, v in dit.state_dict().items() if k != "skeleton_embed.proj.weight"})
    folder = tmp_path / "pipe"
    base.save_pretrained(folder / "transformer")
    # put PE_s into the transformer's safetensors under another plausible name
    weights = folder / "transformer" / "diffusion_pytorch_model.safetensors"
    from safetensors.torch import load_file

    state = load_file(str(weights))
    state["skel_embedder.proj.weight"] = dit.skeleton_embed.proj.weight.detach().clone()
    save_file(state, str(weights))
    build_tiny_vae(seed=3).save_pretrained(folder / "vae")
    (folder / "scheduler").mkdir()
    (folder / "scheduler" / "scheduler_config.json").write_text(
        json.dumps(
            {
                "_class_name": "UniPCMultistepScheduler",
                "use_flow_sigmas": True,
                "prediction_type": "flow_prediction",
                "use_karras_sigmas": True,
                "sigma_max": 200.0,
                "sigma_min": 0.01,
            }
        )
    )
    report = []
    model = oscar_zoo.load(str(folder), report=report)
    assert _same(model.transformer, dit)
    assert any("skel_embedder.proj.weight -> skeleton_embed.proj.weight" in line for line in report)
    from oscar_core.model import SamplerConfig

    sampler = model.sampler_for(SamplerConfig())
    assert sampler.solver == "unipc" and sampler.scheduler_config["use_karras_sigmas"] is True


def test_nothing_matches_lists_files_layouts_and_expectations(tmp_path):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "weights.bin").write_bytes(b"0")
    with pytest.raises(CheckpointLayoutError) as err:
        oscar_zoo.load(str(tmp_path / "x"))
    msg = str(err.value)
    assert "found weights.bin" in msg
    for layout in ("oscar: oscar_model.json", "diffusers: transformer/config.json", "cosmos-native: one DiT"):
        assert layout in msg
    assert (
        detect_layout(["a.pt", "vae/config.json", "vae/diffusion_pytorch_model.safetensors"], "x").kind
        == "cosmos-native"
    )


# --------------------------------------------------------------------------- convert


def test_convert_native_to_oscar_layout_and_cli(tmp_path, capsys):
    from oscar_core.cli import main

    dit = _oscar_dit()
    folder, _ = _native_folder(tmp_path, dit)
    assert main(["zoo", "convert", str(folder), str(tmp_path / "out"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["layout"] == "cosmos-native" and any("skeleton_embedder" in line for line in out["report"])
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "README.md",
        "oscar_manifest.json",
        "oscar_model.json",
        "transformer",
        "vae",
    ]
    assert not list((tmp_path / "out").rglob("*.pt")) and not list((tmp_path / "out").rglob("*.bin"))
    back = oscar_zoo.load(str(tmp_path / "out"))
    assert _same(back.transformer, dit)


# --------------------------------------------------------------------------- lock files


def _exported(tmp_path):
    tiny = tiny_world_model(skeleton_scale=0.05, name="tiny", chunk_frames=5)
    return oscar_zoo.export(tiny, tmp_path / "export"), tiny


def test_pull_writes_a_lock_and_a_moved_branch_still_loads_the_locked_commit(tmp_path, hub):
    folder, tiny = _exported(tmp_path)
    commit = hub.add_folder("me/tiny", folder)
    oscar_zoo.pull("me/tiny", endpoint=hub.url)
    lock = read_lock("me/tiny", "main")
    assert lock.commit == commit and lock.layout == "oscar"
    assert set(lock.files) >= {"oscar_model.json", "transformer/diffusion_pytorch_model.safetensors"}
    assert all(len(h) == 64 for h in lock.files.values())
    # the branch moves to other weights; load keeps to the locked commit
    other = OscarWorldModel.from_modules(
        build_tiny_transformer(seed=9, skeleton_scale=0.05),
        build_tiny_vae(seed=0),
        ModelCard(name="tiny", chunk_frames=5),
    )
    hub.add_folder("me/tiny", oscar_zoo.export(other, tmp_path / "other"))
    assert _same(oscar_zoo.load("me/tiny", endpoint=hub.url).transformer, tiny.transformer)
    # a new pull moves the lock
    oscar_zoo.pull("me/tiny", endpoint=hub.url)
    assert read_lock("me/tiny", "main").commit != commit
    assert _same(oscar_zoo.load("me/tiny", endpoint=hub.url).transformer, other.transformer)


def test_a_file_changed_in_the_cache_fails_the_lock(tmp_path, hub, monkeypatch):
    folder, _ = _exported(tmp_path)
    hub.add_folder("me/tiny", folder)
    root = oscar_zoo.pull("me/tiny", endpoint=hub.url)
    card = (root / "oscar_model.json").resolve()
    data = json.loads(card.read_text())
    data["card"]["chunk_frames"] = 9
    card.write_text(json.dumps(data))
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    with pytest.raises(CheckpointIntegrityError, match=r"oscar_model.json: sha256: expected [0-9a-f]{64} \(lock file"):
        oscar_zoo.load("me/tiny")
    assert lock_path("me/tiny", "main").is_file()


# --------------------------------------------------------------------------- unreachable / offline Hub


class _Hanging:
    """A loopback server that accepts connections and never answers."""

    def __enter__(self):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.conns = []
        self.stop = False
        threading.Thread(target=self._accept, daemon=True).start()
        return f"http://127.0.0.1:{self.sock.getsockname()[1]}"

    def _accept(self):
        while not self.stop:
            try:
                conn, _ = self.sock.accept()
                self.conns.append(conn)
            except OSError:
                return

    def __exit__(self, *exc):
        self.stop = True
        for c in self.conns:
            c.close()
        self.sock.close()


def test_refused_hub_fails_at_once_with_the_offline_hint(refused_port):
    t0 = time.monotonic()
    with pytest.raises(
        HubUnreachableError,
        match=r"cannot reach the Hub \(http://127.0.0.1:\d+: .*\); set "
        r"HF_HUB_OFFLINE=1 to use the cache",
    ):
        oscar_zoo.pull("oscar-2b", endpoint=f"http://127.0.0.1:{refused_port}")
    assert time.monotonic() - t0 < 5


def test_hanging_hub_fails_within_the_timeout(monkeypatch):
    monkeypatch.setenv("OSCAR_HUB_TIMEOUT", "1")
    with _Hanging() as url:
        t0 = time.monotonic()
        with pytest.raises(HubUnreachableError, match=r"no answer within 1 s\); set HF_HUB_OFFLINE=1"):
            oscar_zoo.load("cosmos-predict2.5-2b", endpoint=url)
        assert time.monotonic() - t0 < 5


def test_offline_reads_the_cache_with_no_request_and_never_a_layout_complaint(tmp_path, hub, monkeypatch):
    folder, tiny = _exported(tmp_path)
    hub.add_folder("me/tiny", folder)
    oscar_zoo.pull("me/tiny", endpoint=hub.url)
    requests = list(hub.requests)
    assert len(requests) == len(set(requests))  # no request made twice
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    assert _same(oscar_zoo.load("me/tiny", endpoint=hub.url).transformer, tiny.transformer)
    assert hub.requests == requests
    with pytest.raises(CheckpointLayoutError, match="nothing in the local cache") as err:
        oscar_zoo.load("me/other", endpoint=hub.url)
    assert "layout:" not in str(err.value)


@pytest.mark.slow
def test_cli_reports_an_unreachable_hub_in_seconds(tmp_path, refused_port):
    import subprocess
    import sys

    env = {
        "HF_HUB_CACHE": str(tmp_path / "c"),
        "HF_ENDPOINT": f"http://127.0.0.1:{refused_port}",
        "PATH": "/usr/bin:/bin",
        "OSCAR_ZOO_REGISTRY": str(tmp_path / "r.json"),
        "HOME": str(tmp_path),
    }
    proc = subprocess.run(
        [sys.executable, "-m", "oscar_core.cli", "zoo", "pull", "oscar-2b"],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )  # the time bound is tested in-process
    assert proc.returncode != 0
    assert "cannot reach the Hub" in proc.stderr and "HF_HUB_OFFLINE=1" in proc.stderr
    assert "layout" not in proc.stderr and "Traceback" not in proc.stderr
    np.testing.assert_equal(proc.stdout, "")
