"""`oscar eval weights pull`: pinned downloads from a loopback server, hash failures, trust on first use; the
torchvision-free LPIPS against a second implementation and torchvision's key names."""

import hashlib
import io
import json
import threading
import warnings
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from oscar_core.cli import main as oscar_main
from oscar_core.metrics import lpips as lpips_metric
from oscar_core.metrics.lpips_net import LPIPS, alexnet_features, vgg16_features
from oscar_core.metrics.weights import (
    LOCK_NAME,
    WEIGHTS,
    WeightFile,
    WeightHashError,
    cached_networks,
    pull_weights,
    weight_path,
)

# torchvision's parameter names and shapes (torchvision/models/alexnet.py, vgg.py cfg "D"): a second source
TV_ALEXNET = {
    "features.0.weight": (64, 3, 11, 11),
    "features.0.bias": (64,),
    "features.3.weight": (192, 64, 5, 5),
    "features.3.bias": (192,),
    "features.6.weight": (384, 192, 3, 3),
    "features.6.bias": (384,),
    "features.8.weight": (256, 384, 3, 3),
    "features.8.bias": (256,),
    "features.10.weight": (256, 256, 3, 3),
    "features.10.bias": (256,),
    "classifier.1.weight": (4096, 9216),
    "classifier.1.bias": (4096,),
    "classifier.4.weight": (4096, 4096),
    "classifier.4.bias": (4096,),
    "classifier.6.weight": (1000, 4096),
    "classifier.6.bias": (1000,),
}
_VGG_CONVS = [
    (0, 3, 64),
    (2, 64, 64),
    (5, 64, 128),
    (7, 128, 128),
    (10, 128, 256),
    (12, 256, 256),
    (14, 256, 256),
    (17, 256, 512),
    (19, 512, 512),
    (21, 512, 512),
    (24, 512, 512),
    (26, 512, 512),
    (28, 512, 512),
]
TV_VGG16_FEATURES = {
    k: v
    for i, cin, cout in _VGG_CONVS
    for k, v in ((f"features.{i}.weight", (cout, cin, 3, 3)), (f"features.{i}.bias", (cout,)))
}


def _features_state(shapes, seed=0):
    g = torch.Generator().manual_seed(seed)
    return {k: torch.randn(s, generator=g) * 0.05 for k, s in shapes.items() if k.startswith("features.")}


def _lin_state(channels, seed=1):
    g = torch.Generator().manual_seed(seed)
    return {f"lin{k}.model.1.weight": torch.rand((1, c, 1, 1), generator=g) for k, c in enumerate(channels)}


def _pth(state) -> bytes:
    buf = io.BytesIO()
    torch.save(state, buf)
    return buf.getvalue()


def test_trunks_have_torchvision_names_and_shapes():
    assert {f"features.{k}": tuple(v.shape) for k, v in alexnet_features().state_dict().items()} == {
        k: v for k, v in TV_ALEXNET.items() if k.startswith("features.")
    }
    assert {f"features.{k}": tuple(v.shape) for k, v in vgg16_features().state_dict().items()} == TV_VGG16_FEATURES
    model = LPIPS("alex")
    state = _features_state(TV_ALEXNET)
    # torchvision's full file also has classifier.* (unused by LPIPS): accepted and ignored
    model.load_trunk({**state, "classifier.6.bias": torch.zeros(1000)})
    assert torch.equal(model.features[3].weight, state["features.3.weight"])
    with pytest.raises(Exception, match=r"features\.6\.weight.*expected shape \(384, 192, 3, 3\)"):
        model.load_trunk({**state, "features.6.weight": torch.zeros(384, 192, 5, 5)}, source="alexnet.pth")
    with pytest.raises(Exception, match=r"missing \['features\.10\.bias'\]"):
        model.load_trunk({k: v for k, v in state.items() if k != "features.10.bias"})


def _reference_lpips(x, y, state, lins, taps):
    """A second implementation, functional and written from the paper's definition."""
    shift = torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1)
    scale = torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1)
    a, b = (x - shift) / scale, (y - shift) / scale
    convs = {0: (4, 2), 3: (1, 2), 6: (1, 1), 8: (1, 1), 10: (1, 1)}  # index -> (stride, padding)
    total, k = 0, 0
    for i in range(12):
        if i in convs:
            w, bias = state[f"features.{i}.weight"], state[f"features.{i}.bias"]
            a = F.conv2d(a, w, bias, stride=convs[i][0], padding=convs[i][1])
            b = F.conv2d(b, w, bias, stride=convs[i][0], padding=convs[i][1])
        elif i in (2, 5):
            a, b = F.max_pool2d(a, 3, 2), F.max_pool2d(b, 3, 2)
        else:
            a, b = a.clamp(min=0), b.clamp(min=0)
        if i in taps:
            na = a / (a.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            nb = b / (b.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            total = total + ((na - nb) ** 2 * lins[f"lin{k}.model.1.weight"].view(1, -1, 1, 1)).sum(1).mean((1, 2))
            k += 1
    return total


def test_lpips_matches_a_second_implementation():
    state, lins = _features_state(TV_ALEXNET, seed=3), _lin_state((64, 192, 384, 256, 256), seed=4)
    net = LPIPS("alex")
    net.load_trunk(state)
    net.load_linear(lins)
    g = torch.Generator().manual_seed(5)
    x, y = torch.rand((2, 3, 64, 96), generator=g) * 2 - 1, torch.rand((2, 3, 64, 96), generator=g) * 2 - 1
    out = net(x, y)
    assert out.shape == (2, 1, 1, 1)
    ref = _reference_lpips(x, y, state, lins, (1, 4, 7, 9, 11))
    torch.testing.assert_close(out.view(-1), ref, rtol=1e-5, atol=1e-7)
    assert float(net(x, x).abs().max()) == 0.0 and torch.allclose(net(y, x), out)
    # through the metric: frames (T, H, W, 3) uint8
    frames = (np.random.default_rng(0).random((3, 64, 96, 3)) * 255).astype(np.uint8)
    assert lpips_metric(frames, frames, net, n_frames=None).tolist() == [0.0, 0.0, 0.0]


class Server:
    """Serves ``files`` {path: bytes} on 127.0.0.1 and records the requests."""

    def __init__(self, files):
        self.files, self.requests = dict(files), []
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *a):
                pass

            def do_GET(self):
                server.requests.append(self.path)
                data = server.files.get(self.path)
                if data is None:
                    self.send_response(404)
                    self.end_headers()
                    return
                self.send_response(200)
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()


class TinyI3D(torch.nn.Module):
    def forward(self, x, rescale: bool = False, resize: bool = False, return_features: bool = False):
        return x.float().mean(dim=(2, 3, 4))


@pytest.fixture
def served(tmp_path):
    ts = io.BytesIO()
    torch.jit.save(torch.jit.script(TinyI3D()), ts)
    files = {
        "/i3d.pt": ts.getvalue(),
        "/lin.pth": _pth(_lin_state((64, 192, 384, 256, 256))),
        "/alexnet-owt.pth": _pth(_features_state(TV_ALEXNET)),
    }
    srv = Server(files)
    sha = {k: hashlib.sha256(v).hexdigest() for k, v in files.items()}
    table = {
        "i3d": WeightFile("i3d", srv.url + "/i3d.pt", "i3d_torchscript.pt", "torchscript", "test"),
        "lpips-alex": WeightFile(
            "lpips-alex", srv.url + "/lin.pth", "lin.pth", "state_dict", "test", sha256=sha["/lin.pth"]
        ),
        "alexnet": WeightFile(
            "alexnet",
            srv.url + "/alexnet-owt.pth",
            "alexnet.pth",
            "state_dict",
            "test",
            sha256_prefix=sha["/alexnet-owt.pth"][:8],
        ),
    }
    yield srv, table, sha, tmp_path / "cache"
    srv.close()


def test_pull_verifies_caches_and_records_first_use(served):
    srv, table, sha, cache = served
    res = pull_weights(["i3d", "lpips-alex", "alexnet"], cache_dir=cache, table=table)
    assert {k: (v["status"], v["check"]) for k, v in res.items()} == {
        "i3d": ("downloaded", "trust on first use"),
        "lpips-alex": ("downloaded", "pinned sha256"),
        "alexnet": ("downloaded", "trust on first use"),
    }  # a prefix pin is checked, then the full hash recorded
    lock = json.loads((cache / LOCK_NAME).read_text())
    assert lock["i3d"]["sha256"] == sha["/i3d.pt"] and lock["alexnet"]["sha256"] == sha["/alexnet-owt.pth"]
    assert "lpips-alex" not in lock  # fully pinned: nothing to record
    again = pull_weights(["i3d", "lpips-alex", "alexnet"], cache_dir=cache, table=table)
    assert {v["status"] for v in again.values()} == {"cached"} and len(srv.requests) == 3
    assert again["i3d"]["check"] == "matches the lock file"
    # the networks the video metrics use by default, hash-checked on every use
    nets = cached_networks(cache_dir=cache, table=table)
    assert sorted(nets) == ["i3d", "lpips"] and isinstance(nets["lpips"], LPIPS)
    # the upstream file changes: a forced re-download no longer matches what was recorded
    srv.files["/i3d.pt"] = srv.files["/i3d.pt"] + b"\0"
    with pytest.raises(WeightHashError, match=rf"i3d.pt: field 'sha256': expected {sha['/i3d.pt']} \(recorded in"):
        pull_weights(["i3d"], cache_dir=cache, table=table, force=True)
    assert not list(cache.glob(".*.part"))
    # a cached file changed on disk is refused before torch.jit.load could run it
    (cache / "i3d_torchscript.pt").write_bytes(b"not what was recorded")
    with pytest.raises(WeightHashError, match="recorded in weights.lock.json"):
        weight_path("i3d", cache_dir=cache, table=table)


def test_hash_failures_and_http_errors(served):
    srv, table, sha, cache = served
    srv.files["/lin.pth"] = b"tampered"
    with pytest.raises(WeightHashError) as exc:
        pull_weights(["lpips-alex"], cache_dir=cache, table=table)
    msg = str(exc.value)
    assert msg.startswith(f"{srv.url}/lin.pth: field 'sha256': expected {sha['/lin.pth']}")
    assert hashlib.sha256(b"tampered").hexdigest() in msg
    assert not (cache / "lin.pth").exists() and not list(cache.glob(".*"))  # nothing half-written stays
    srv.files["/alexnet-owt.pth"] = b"other bytes"
    with pytest.raises(WeightHashError, match=f"a hash starting {sha['/alexnet-owt.pth'][:8]}"):
        pull_weights(["alexnet"], cache_dir=cache, table=table)
    del srv.files["/i3d.pt"]
    with pytest.raises(Exception, match=r"i3d.pt: field 'download': expected HTTP 200, found HTTP 404"):
        pull_weights(["i3d"], cache_dir=cache, table=table)
    # a file put in the cache by hand (never pulled) is not trusted
    cache.mkdir(exist_ok=True)
    (cache / "i3d_torchscript.pt").write_bytes(b"x")
    with pytest.raises(WeightHashError, match="a file oscar did not download"):
        weight_path("i3d", cache_dir=cache, table=table)
    with pytest.raises(Exception, match="one of"):
        pull_weights(["nope"], cache_dir=cache, table=table)


def test_the_pinned_table():
    for w in WEIGHTS.values():
        assert w.url.startswith("https://"), w
        assert w.sha256 is None or (len(w.sha256) == 64 and int(w.sha256, 16) >= 0)
        assert w.sha256_prefix is None or w.sha256_prefix in w.filename  # torchvision names files by the prefix
    assert WEIGHTS["lpips-alex"].sha256 and WEIGHTS["lpips-alex"].url.count("082bb24f84c091ea94de2867d34c4544f68e0963")
    assert WEIGHTS["i3d"].pin == WEIGHTS["inception"].pin == "trust on first use"  # no published hash


def test_eval_video_uses_the_cached_networks(served, tmp_path, monkeypatch, capsys):
    srv, table, sha, cache = served
    pull_weights(["lpips-alex", "alexnet"], cache_dir=cache, table=table)
    import oscar_core.metrics.weights as weights

    monkeypatch.setattr(weights, "WEIGHTS", table)
    monkeypatch.setenv("OSCAR_WEIGHTS_CACHE", str(cache))
    rng = np.random.default_rng(0)
    pred, gt = tmp_path / "pred.npy", tmp_path / "gt.npy"
    np.save(pred, rng.integers(0, 256, (4, 64, 64, 3), dtype=np.uint8))
    np.save(gt, rng.integers(0, 256, (4, 64, 64, 3), dtype=np.uint8))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        assert oscar_main(["eval", "video", str(pred), str(gt), "--frames", "0", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["networks_from_cache"] == ["lpips"] and data["aggregate"]["lpips"] > 0
    assert oscar_main(["eval", "video", str(pred), str(gt), "--frames", "0", "--json", "--no-cached-networks"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["networks_from_cache"] == [] and "lpips" not in data["aggregate"]


def test_cached_detectors_are_loaded_from_the_checked_bytes(served):
    srv, table, sha, cache = served
    pull_weights(["i3d"], cache_dir=cache, table=table)
    nets = cached_networks(cache_dir=cache, table=table)
    x = torch.arange(2 * 3 * 2 * 4 * 4, dtype=torch.uint8).view(2, 3, 2, 4, 4)
    assert torch.equal(nets["i3d"](x), x.float().mean(dim=(2, 3, 4)))  # called like StyleGAN-V calls it
    from oscar_core.metrics.video import load_torchscript

    with pytest.raises(Exception, match="field 'sha256': expected 0000"):
        load_torchscript(cache / "i3d_torchscript.pt", sha256="0" * 64)
