"""`oscar eval video` and `oscar eval policies` through add_eval_parser (no dependence on the main CLI wiring)."""

import argparse
import json
import sys

import numpy as np
import pytest
import torch

from oscar_core.metrics import MetricInputError, add_eval_parser, fit_bradley_terry, psnr, spearman_rho, ssim

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit.script` is deprecated:DeprecationWarning")


def run(capsys, *argv):
    parser = argparse.ArgumentParser(prog="oscar")
    add_eval_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["eval", *map(str, argv)])
    code = args.func(args)
    out, err = capsys.readouterr()
    return code, out, err


def _pair(seed, frames=6, size=(16, 20)):
    rng = np.random.default_rng(seed)
    gt = rng.integers(0, 256, (frames, *size, 3), dtype=np.uint8)
    pred = np.clip(gt.astype(int) + rng.integers(-20, 21, gt.shape), 0, 255).astype(np.uint8)
    return pred, gt


def test_eval_video_folders_with_embodiment_subfolders(tmp_path, capsys):
    arrays = {}
    for k, name in enumerate(["franka/ep0", "franka/ep1", "kuka/ep0"]):
        pred, gt = _pair(k)
        arrays[name] = (pred, gt)
        for root, arr in (("pred", pred), ("gt", gt)):
            (tmp_path / root / name).parent.mkdir(parents=True, exist_ok=True)
            np.save(tmp_path / root / f"{name}.npy", arr)
    code, out, _ = run(
        capsys, "video", tmp_path / "pred", tmp_path / "gt", "--frames", 5, "--json", "--out", tmp_path / "res.json"
    )
    assert code == 0
    data = json.loads(out)
    assert data == json.loads((tmp_path / "res.json").read_text())
    rows = {c["name"]: c for c in data["clips"]}
    assert set(rows) == set(arrays) and rows["kuka/ep0"]["embodiment"] == "kuka"
    pred, gt = arrays["franka/ep1"]
    assert rows["franka/ep1"]["psnr"] == pytest.approx(psnr(pred, gt, n_frames=5).mean())
    assert rows["franka/ep1"]["ssim"] == pytest.approx(ssim(pred, gt, n_frames=5).mean())
    assert data["per_embodiment"]["franka"]["clips"] == 2
    code, out, _ = run(capsys, "video", tmp_path / "pred", tmp_path / "gt", "--frames", 5)
    assert "[mean] franka (2)" in out and "[mean over clips] (3)" in out


def test_eval_video_single_mkv_pair_with_networks(tmp_path, capsys, monkeypatch):
    av = pytest.importorskip("av")
    pred, gt = _pair(7, frames=4, size=(16, 16))
    for name, arr in (("pred.mkv", pred), ("gt.mkv", gt)):  # FFV1 in RGB is lossless
        with av.open(str(tmp_path / name), "w") as c:
            s = c.add_stream("ffv1", rate=10)
            s.width, s.height, s.pix_fmt = 16, 16, "bgr0"
            for f in arr:
                for packet in s.encode(av.VideoFrame.from_ndarray(f, format="rgb24")):
                    c.mux(packet)
            for packet in s.encode():
                c.mux(packet)

    class L1(torch.nn.Module):
        def forward(self, x, y):
            return (x - y).abs().mean(dim=(1, 2, 3))

    torch.jit.script(L1()).save(str(tmp_path / "l1.pt"))
    (tmp_path / "my_vae.py").write_text("def encoder():\n    return lambda x: x[:, :, :, ::2, ::2]\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    code, out, _ = run(
        capsys,
        "video",
        tmp_path / "pred.mkv",
        tmp_path / "gt.mkv",
        "--frames",
        0,
        "--json",
        "--lpips",
        tmp_path / "l1.pt",
        "--vae",
        "my_vae:encoder",
    )
    assert code == 0
    row = json.loads(out)["clips"][0]
    assert row["name"] == "pred" and row["frames"] == 4 and row["embodiment"] is None
    assert row["psnr"] == pytest.approx(psnr(pred, gt, n_frames=None).mean(), abs=1e-9)
    assert row["lpips"] == pytest.approx(np.mean(np.abs(pred / 127.5 - gt / 127.5)), rel=1e-4)
    assert row["latent_l2"] > 0 and row["tlpips"] >= 0


def test_eval_video_errors(tmp_path, capsys):
    (tmp_path / "pred").mkdir()
    (tmp_path / "gt").mkdir()
    np.save(tmp_path / "pred" / "a.npy", np.zeros((2, 12, 12, 3), np.uint8))
    with pytest.raises(MetricInputError, match=r"gt: field 'clips': expected a ground truth .* found none for \['a'\]"):
        run(capsys, "video", tmp_path / "pred", tmp_path / "gt")
    with pytest.raises(MetricInputError, match="no such file or folder"):
        run(capsys, "video", tmp_path / "nope.mp4", tmp_path / "gt")
    np.save(tmp_path / "gt" / "a.npy", np.zeros((2, 12, 12, 3), np.uint8))
    with pytest.raises(MetricInputError, match="a: pred: field 'frames': expected at least 49 frames"):
        run(capsys, "video", tmp_path / "pred", tmp_path / "gt")
    with pytest.raises(MetricInputError, match="module:attr"):
        run(capsys, "video", tmp_path / "pred", tmp_path / "gt", "--frames", 2, "--lpips", "not-a-spec")


def _policy_files(tmp_path, prefs=True):
    real = {
        "pi0_fast": {"success_rate": 0.6, "score": 1650},
        "pg_flow": {"success_rate": 0.5, "score": 1560},
        "pg_bin": {"episodes": [1, 0, 0, 0, 0], "score": 1400},
    }
    wm = {"pi0_fast": 0.55, "pg_flow": {"success_rate": 0.3}, "pg_bin": 0.25}
    (tmp_path / "real.json").write_text(json.dumps(real))
    (tmp_path / "wm.json").write_text(json.dumps(wm))

    def pref(a, b, winner):
        return {"a": a, "b": b, "winner": winner}

    lines = (
        [pref("pi0_fast", "pg_flow", "a")] * 3
        + [pref("pg_flow", "pi0_fast", "a")]
        + [pref("pg_flow", "pg_bin", "a")] * 3
        + [pref("pg_bin", "pg_flow", "tie")]
        + [pref("pg_bin", "pi0_fast", "b")] * 2
        + [pref("pg_bin", "pi0_fast", "a")]
    )
    (tmp_path / "prefs.jsonl").write_text("\n".join(json.dumps(x) for x in lines) + "\n\n")
    return real, wm, lines


def test_eval_policies_json_and_table(tmp_path, capsys):
    real, wm, lines = _policy_files(tmp_path)
    code, out, _ = run(capsys, "policies", "--real", tmp_path / "real.json", "--wm", tmp_path / "wm.json", "--json")
    assert code == 0
    data = json.loads(out)
    assert data["ranked_by"] == {"real": "score", "wm": "success_rate"}
    assert data["metrics"]["sisr_delta_pp"] == pytest.approx(100 * (0.05 + 0.2 + 0.05) / 3)
    code, out, _ = run(
        capsys,
        "policies",
        "--real",
        tmp_path / "real.json",
        "--wm",
        tmp_path / "wm.json",
        "--preferences",
        tmp_path / "prefs.jsonl",
        "--json",
        "--out",
        tmp_path / "out.json",
    )
    data = json.loads(out)
    assert data == json.loads((tmp_path / "out.json").read_text())
    assert data["ranked_by"]["wm"] == "bradley_terry_elo"
    bt = fit_bradley_terry([(x["a"], x["b"], x["winner"]) for x in lines], policies=list(real))
    assert [b["policy"] for b in data["bradley_terry"]["board"]] == bt.ranking()
    real_elo = {k: v["score"] for k, v in real.items()}
    assert data["metrics"]["spearman_rho"] == pytest.approx(spearman_rho(real_elo, bt.scores("elo")))
    code, out, _ = run(
        capsys,
        "policies",
        "--real",
        tmp_path / "real.json",
        "--wm",
        tmp_path / "wm.json",
        "--preferences",
        tmp_path / "prefs.jsonl",
    )
    assert "Bradley-Terry" in out and "MMRV" in out and "wm=bradley_terry_elo" in out


def test_eval_policies_errors(tmp_path, capsys):
    _policy_files(tmp_path)
    with open(tmp_path / "prefs.jsonl", "a") as f:
        f.write(json.dumps({"a": "pi0_fast", "b": "octo", "winner": "a"}) + "\n")
    with pytest.raises(MetricInputError, match=r"prefs.jsonl:13: field 'b': expected one of the policies .* 'octo'"):
        run(
            capsys,
            "policies",
            "--real",
            tmp_path / "real.json",
            "--wm",
            tmp_path / "wm.json",
            "--preferences",
            tmp_path / "prefs.jsonl",
        )
    (tmp_path / "wm.json").write_text(json.dumps({"pi0_fast": 0.5, "pg_flow": 0.5}))
    with pytest.raises(MetricInputError, match=r"missing \['pg_bin'\]"):
        run(capsys, "policies", "--real", tmp_path / "real.json", "--wm", tmp_path / "wm.json")
    (tmp_path / "wm.json").write_text(json.dumps({"pi0_fast": 55, "pg_flow": 0.5, "pg_bin": 0.1}))
    with pytest.raises(MetricInputError, match=r"wm.json: field 'pi0_fast.success_rate': expected a fraction"):
        run(capsys, "policies", "--real", tmp_path / "real.json", "--wm", tmp_path / "wm.json")
    (tmp_path / "wm.json").write_text("{not json")
    with pytest.raises(MetricInputError, match=r"wm.json: field 'line 1': expected valid JSON"):
        run(capsys, "policies", "--real", tmp_path / "real.json", "--wm", tmp_path / "wm.json")


def test_help_shows_examples(capsys):
    parser = argparse.ArgumentParser(prog="oscar")
    add_eval_parser(parser.add_subparsers(dest="command"))
    for sub in ("video", "policies"):
        with pytest.raises(SystemExit):
            parser.parse_args(["eval", sub, "--help"])
        assert "examples:" in capsys.readouterr().out
    assert sys.modules["oscar_core.metrics.cli"]
