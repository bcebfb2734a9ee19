"""The autoencoder ceiling of the action-following benchmark (``--ceiling``): the VAE's chunk-by-chunk reconstruction
of the true frames equals a rollout whose DiT predicts every chunk's true latent and a hand-rolled reconstruction
(and not one shifted by a frame); the benchmark scores it into the usual report with its mode recorded, loads only
the VAE, and refuses a set without true frames before any model loads."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from _models import export_tiny_world_model, tiny_world_model

from oscar_core.evaluation.action_following import ActionFollowingSettings, run_action_following, score_variant
from oscar_core.evaluation.action_following_ceiling import CEILING
from oscar_core.evaluation.action_following_manifest import load_action_following
from oscar_core.media.video import read_video
from oscar_core.metrics.programmatic import ProgrammaticJudge
from oscar_core.model import SamplerConfig
from oscar_core.model.rollout import reconstruct_rollout
from oscar_core.model.vae import VideoVAE
from oscar_core.toyworld.judge import ball_moved
from oscar_core.toyworld.locate import ball_position

pytestmark = pytest.mark.usefixtures("one_thread")

JUDGE = "oscar_core.toyworld.judge:ball_moved"
CARD = dict(name="tiny-ceiling", chunk_frames=17, width=64, height=64)


@pytest.fixture(scope="module")
def sets(tmp_path_factory):
    """One toyarm set of 33 frames (two 17-frame chunks), 64 x 64, with the simulator's frames."""
    from oscar_core.toyworld.counterfactual import write_counterfactual_sets

    return write_counterfactual_sets(tmp_path_factory.mktemp("af_ceiling_sets"), ["toyarm"], 1, seed=0, frames=33)


@pytest.fixture(scope="module")
def model():
    return tiny_world_model(**CARD)


def _hand_rolled(vae, truth: np.ndarray, offset: int = 0) -> np.ndarray:
    """Chunk k of 17 frames is truth[16k + offset : 16k + offset + 17] (offset 0: the rollout's layout), reconstructed
    by the VAE; chunk 0 kept whole, the first frame of every later chunk dropped; the last frame held past T."""
    T = len(truth)
    padded = np.concatenate([truth, np.repeat(truth[-1:], 17 + offset, axis=0)])
    out = []
    for k, start in enumerate(range(0, T - 1, 16)):
        rec = VideoVAE.to_uint8(vae.reconstruct(VideoVAE.to_pixels(padded[start + offset : start + offset + 17])))[0]
        out.append(rec if k == 0 else rec[1:])
    return np.concatenate(out)[:T]


def _oracle(vae, held: np.ndarray, starts: list[int], calls: list[int]):
    """A stand-in for the sampler that returns the VAE latent of the true frames of the chunk it is called for (the
    n-th call: chunk n of ``starts``), recording the starts in ``calls``."""

    def sample_chunk(transformer, first_latent, skeleton_latent, prompt, sampler, **kw):
        start = starts[len(calls)]
        calls.append(start)
        return vae.encode(VideoVAE.to_pixels(held[start : start + 17]))

    return sample_chunk


@pytest.mark.filterwarnings("ignore:no prompt embedding")
def test_the_reconstruction_is_a_rollout_whose_dit_predicts_each_chunks_true_latent(model, sets, monkeypatch):
    """The ceiling is the rollout's own chunk layout: the world model's rollout, with a DiT that returns the VAE's
    latent of each chunk's true frames, gives bitwise the same video; a hand-rolled reconstruction too, and one
    shifted by a frame does not (the check can see a shift)."""
    import oscar_core.model.rollout as rollout_module

    truth = read_video(load_action_following(sets).sets[0].variants[0].video)  # (33, 64, 64, 3): 2 chunks
    for T in (33, 29):  # 29: the last chunk overruns T (held at the last frame, cut at T)
        video = truth[:T]
        ceiling = reconstruct_rollout(model.vae, video, chunk_frames=17)
        assert ceiling.shape == video.shape and ceiling.dtype == np.uint8
        starts = rollout_module.chunk_plan(T, 17, model.vae.temporal)
        held = np.concatenate([video, np.repeat(video[-1:], starts[-1] + 17 - T, axis=0)])
        calls: list[int] = []
        oracle = _oracle(model.vae, held, starts, calls)
        monkeypatch.setattr(rollout_module, "sample_chunk", oracle)
        rolled = model.rollout(
            video[0], np.zeros_like(video), chunk_frames=17, sampler=SamplerConfig(steps=1), progress=False
        ).frames
        monkeypatch.undo()
        assert calls == starts == [0, 16]
        np.testing.assert_array_equal(ceiling, rolled)
        np.testing.assert_array_equal(ceiling, _hand_rolled(model.vae, video))
        assert not np.array_equal(ceiling, _hand_rolled(model.vae, video, offset=1))


def _judge():
    return ProgrammaticJudge(ball_moved, name=JUDGE)


def test_the_ceiling_run_scores_the_reconstruction_in_the_report_format(sets, model, tmp_path, monkeypatch):
    monkeypatch.setattr(type(model), "rollout", lambda *a, **k: pytest.fail("the ceiling rolled the model out"))
    monkeypatch.setattr(type(model), "rollout_batch", lambda *a, **k: pytest.fail("the ceiling rolled out"))
    out = tmp_path / "ceiling"
    settings = ActionFollowingSettings(ceiling=True, resamples=200, seed=5)
    res = run_action_following(sets, out, judge=_judge(), model=model, settings=settings)
    report = json.loads((out / "report.json").read_text())
    assert report["mode"] == CEILING == "ceiling: the VAE's reconstruction of the true frames"
    assert report["sampler"] == "none (no sampling)" and report["seed"] is None
    assert json.loads((out / "fingerprint.json").read_text())["parts"]["mode"] == CEILING
    s = report["scores"]
    assert (
        s["sets"] == 1
        and len(s["chunks"]) == 2
        and set(s["variants"]) == {v["name"] for v in res.records[0]["variants"]}
    )
    summary = (out / "summary.md").read_text()
    assert "autoencoder ceiling" in summary and CEILING in summary and "decision accuracy" in summary
    assert "nan" not in summary.lower()
    # every record is the judge, locator and per-chunk metrics of the hand-rolled reconstruction
    cs = load_action_following(sets).sets[0]
    for v, row in zip(cs.variants, res.records[0]["variants"]):
        truth = read_video(v.video)
        rec = _hand_rolled(model.vae, truth)
        want = score_variant(rec, truth, ball_position, cs.info, 16)
        assert row["chunks"] == want["chunks"] and row["end_error"] == want["end_error"], v.name
        assert row["verdict"] == ball_moved(rec, SimpleNamespace(info=cs.info))["binary"], v.name
        assert row["truth_verdict"] == v.outcome
        assert (out / "videos" / cs.set / f"{v.name}.mp4").is_file()
    # a rollout run in the same folder is refused: the mode is part of the fingerprint
    from oscar_core._util.stage import StageChanged

    with pytest.raises(StageChanged, match="mode"):
        run_action_following(sets, out, judge=_judge(), model=model, settings=ActionFollowingSettings(resamples=200))


def test_the_command_loads_only_the_vae(sets, tmp_path, monkeypatch, capsys):
    import oscar_zoo
    from oscar_core.cli import main
    from oscar_core.model.transformer import OscarTransformer3DModel

    folder = export_tiny_world_model(tmp_path / "tiny", **CARD)
    monkeypatch.setattr(oscar_zoo, "load", lambda *a, **k: pytest.fail("the whole model was loaded"))
    monkeypatch.setattr(
        OscarTransformer3DModel, "load_strict", classmethod(lambda *a, **k: pytest.fail("the DiT was read"))
    )
    out = tmp_path / "o"
    args = ["eval", "action-following", str(sets), "--model", str(folder), "--judge", JUDGE, "--out", str(out)]
    assert main(args + ["--ceiling", "--threads", "1", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["mode"] == CEILING and printed["scores"]["sets"] == 1
    assert json.loads((out / "report.json").read_text())["scores"] == printed["scores"]
    assert len(list((out / "videos").rglob("*.mp4"))) == 6


def test_a_set_without_true_frames_is_refused_before_any_model_loads(sets, tmp_path, monkeypatch, capsys):
    import oscar_zoo
    from oscar_core.cli import main

    m = json.loads(sets.read_text())
    m["sets"][0]["variants"][3].pop("video")
    bad = sets.parent / "no_video.json"
    bad.write_text(json.dumps(m))
    monkeypatch.setattr(oscar_zoo, "load", lambda *a, **k: pytest.fail("the model was loaded"))
    monkeypatch.setattr(oscar_zoo, "pull", lambda *a, **k: pytest.fail("the model was looked up"))
    args = ["eval", "action-following", str(bad), "--model", "oscar-toy", "--judge", JUDGE, "--out", str(tmp_path)]
    assert main(args + ["--ceiling"]) == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines() if line.startswith("error:")]
    assert len(err) == 1 and str(bad) in err[0] and "'sets[0].variants[3].video'" in err[0], err
    assert "true frames" in err[0]


def test_the_toy_command_runs_the_ceiling_of_oscar_toy_from_its_vae_alone(sets, tmp_path, monkeypatch, capsys):
    import shutil

    import oscar_zoo
    from oscar_core.cli import main
    from oscar_core.model.transformer import OscarTransformer3DModel

    out = tmp_path / "af"
    shutil.copytree(sets.parent, out / "sets")  # the same sets the command makes (kept: not made again)
    monkeypatch.setattr(oscar_zoo, "load", lambda *a, **k: pytest.fail("the whole model was loaded"))
    monkeypatch.setattr(
        OscarTransformer3DModel, "load_strict", classmethod(lambda *a, **k: pytest.fail("the DiT was read"))
    )
    args = ["toyworld", "action-following", "--model", "oscar-toy", "--sets", "1", "--embodiments", "toyarm"]
    args += ["--chunks", "2", "--seed", "0", "--ceiling", "--out", str(out), "--threads", "1", "--json"]
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["mode"] == CEILING and report["chunk_frames"] == 17 and report["model"] == "oscar-toy"
    s = report["scores"]
    assert s["sets"] == 1 and len(s["chunks"]) == 2 and s["judge_failures"] == 0
    assert all(v["judge_on_truth"] == {"agree": 1, "of": 1} for v in s["variants"].values())


def test_the_ceilings_vae_decodes_as_the_loaded_model_does(tmp_path):
    """The card's tiny decoder decodes the ceiling as it decodes the rollout; False: the full decoder."""
    import torch

    from oscar_core.evaluation.action_following_ceiling import load_ceiling_vae
    from oscar_core.model import ModelCard, OscarWorldModel
    from oscar_core.model.tiny_decoder import TinyDecoderNet

    model = tiny_world_model(chunk_frames=5)
    torch.manual_seed(0)
    model.vae.use_tiny_decoder(TinyDecoderNet(widths=(16, 8, 8, 8)).eval())  # x8 in space, x4 in time
    folder = model.save_pretrained(tmp_path / "m", ModelCard(chunk_frames=5, tiny_decoder="tiny.safetensors"))
    z = torch.randn(1, 16, 2, 4, 8)
    loaded = OscarWorldModel.from_pretrained(folder)
    assert loaded.vae.tiny is not None
    tiny = load_ceiling_vae(str(folder))
    torch.testing.assert_close(tiny.decode(z), loaded.vae.decode(z), rtol=0, atol=0)
    full = load_ceiling_vae(str(folder), tiny_decoder=False)
    assert full.tiny is None
    torch.testing.assert_close(full.decode(z), tiny_world_model(chunk_frames=5).vae.decode(z), rtol=0, atol=0)
    assert not torch.allclose(full.decode(z), tiny.decode(z))
