"""``oscar toyworld train-vae --resume``: a run stopped at a checkpoint and resumed ends with the weights of one that
never stopped, bit for bit; a resume state that does not fit is refused in one line before any training."""

from __future__ import annotations

import json
import shutil

import pytest

from oscar_core.cli import main
from oscar_core.plugin.registry import default_registry
from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
from oscar_core.toyworld.motion import ToyWorldError


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    out = tmp_path_factory.mktemp("vae_resume") / "clips"
    generate_clipset(
        GenerateConfig(("toyarm",), episodes=10, width=16, height=16, frames=5, seed=0, shard_size=10, skeleton=False),
        out,
        default_registry(),
    )
    return out


def _cfg(**kw):
    from oscar_core.toyworld.vae_train import VAETrainConfig

    base = dict(steps=4, batch=1, base_dim=4, eval_every=2, eval_clips=1, ball=5.0, ball_region="union", chroma=1.0)
    return VAETrainConfig(**{**base, **kw})


def _train(clips, out, **kw):
    import torch

    from oscar_core.toyworld.vae_train import train_vae

    n = torch.get_num_threads()
    try:
        return train_vae(clips, out, _cfg(**kw), log=lambda m: None)
    finally:
        torch.set_num_threads(n)


def _weights(folder):
    from safetensors.torch import load_file

    return load_file(folder / "vae" / "diffusion_pytorch_model.safetensors")


def _same(a, b) -> bool:
    import torch

    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("sample_posterior", [False, True])  # True: torch's generator must be restored too
def test_stopped_and_resumed_run_equals_the_unbroken_run(clips, tmp_path, sample_posterior):
    straight = _train(clips, tmp_path / "straight", sample_posterior=sample_posterior)
    first = _train(clips, tmp_path / "broken", stop_at=2, sample_posterior=sample_posterior)
    assert first["steps_done"] == 2 and (tmp_path / "broken" / "resume" / "state.json").is_file()
    assert not _same(_weights(tmp_path / "straight"), _weights(tmp_path / "broken"))
    resumed = _train(clips, tmp_path / "broken", resume=True, sample_posterior=sample_posterior)
    assert resumed["steps_done"] == 4
    assert _same(_weights(tmp_path / "straight"), _weights(tmp_path / "broken"))
    # the card carries on the first run's curve and evaluations
    assert [e["step"] for e in resumed["evals"]] == [e["step"] for e in straight["evals"]] == [0, 2, 4]
    assert [c["step"] for c in resumed["curve"]] == [c["step"] for c in straight["curve"]]
    assert resumed["evals"][-1]["psnr_db"] == straight["evals"][-1]["psnr_db"]
    assert not list((tmp_path / "broken").glob(".*.tmp")) and not list((tmp_path / "broken").glob(".*.old"))


def test_resume_refuses_what_does_not_fit_before_training(clips, tmp_path, monkeypatch):
    import oscar_core.toyworld.vae_train as vt

    _train(clips, tmp_path / "run", stop_at=2)
    trained = []
    monkeypatch.setattr(vt, "_vae_loss", lambda *a, **k: trained.append(1) or (_ for _ in ()).throw(AssertionError))
    with pytest.raises(ToyWorldError, match=r"settings\.lr: expected the resumed run's 0\.001, found 0\.002 given now"):
        _train(clips, tmp_path / "run", resume=True, lr=2e-3)
    with pytest.raises(ToyWorldError, match="--resume: expected resume/state.json"):
        _train(clips, tmp_path / "nothing", resume=True)
    other = tmp_path / "other_clips"
    shutil.copytree(clips, other)
    index = next(other.glob("shard-*/clips.jsonl"))
    index.write_text("".join(index.read_text().splitlines(keepends=True)[1:]))  # one training clip fewer
    with pytest.raises(
        ToyWorldError, match=r"state\.json: clips_digest: expected the digest of the clip set given now"
    ):
        _train(other, tmp_path / "run", resume=True)
    # resume/ from one step, vae/ from another (a crash between the two renames)
    state = tmp_path / "run" / "resume" / "state.json"
    raw = json.loads(state.read_text())
    state.write_text(json.dumps({**raw, "weights_sha256": "0" * 64}))
    with pytest.raises(ToyWorldError, match="weights_sha256: expected the sha256 of .*, found another"):
        _train(clips, tmp_path / "run", resume=True)
    state.write_text(json.dumps({**raw, "format": "something else"}))
    with pytest.raises(ToyWorldError, match="format: expected oscar-toy-vae-resume version 1"):
        _train(clips, tmp_path / "run", resume=True)
    assert trained == []


def test_a_moved_clip_set_still_resumes(clips, tmp_path):
    shutil.copytree(clips, tmp_path / "moved")
    _train(clips, tmp_path / "run", stop_at=2)
    assert _train(tmp_path / "moved", tmp_path / "run", resume=True)["steps_done"] == 4


def test_cli_resume_flag_and_exit_code(clips, tmp_path, capsys):
    base = ["toyworld", "train-vae", str(clips), "--out", str(tmp_path / "run"), "--steps", "2", "--batch", "1"]
    base += ["--base-dim", "4", "--eval-every", "1", "--eval-clips", "1"]
    assert main(base + ["--stop-at", "1"]) == 0
    assert main(base + ["--resume"]) == 0
    card = json.loads((tmp_path / "run" / "vae_card.json").read_text())
    assert card["steps_done"] == 2 and card["settings"]["resume"] is True
    capsys.readouterr()
    assert main(base + ["--resume", "--window", "9"]) == 2
    assert "settings.window: expected the resumed run's 5, found 9 given now" in capsys.readouterr().err


def test_a_save_killed_between_its_renames_resumes_and_leaves_no_temporaries(clips, tmp_path):
    straight = _train(clips, tmp_path / "straight")
    run = tmp_path / "run"
    _train(clips, run, stop_at=2)
    # kill -9 inside the next save: its new weights half-written aside, the old vae/ already renamed away
    (run / "vae").rename(run / ".vae.old")
    (run / ".vae.tmp").mkdir()
    (run / ".vae.tmp" / "diffusion_pytorch_model.safetensors").write_bytes(b"half")
    (run / ".resume.tmp").mkdir()
    assert _train(clips, run, resume=True)["steps_done"] == 4
    assert _same(_weights(tmp_path / "straight"), _weights(run)) and straight["steps_done"] == 4
    assert sorted(p.name for p in run.iterdir() if p.name.startswith(".")) == []
