"""A model card carries its recommended sampler settings; every entry point uses them unless told otherwise."""

from __future__ import annotations

import json

import numpy as np
import pytest
from _models import tiny_world_model

import oscar_zoo
from oscar_core.model import ModelCard, ModelInputError, OscarWorldModel, SamplerConfig
from oscar_core.model.sampler import resolve_sampler
from oscar_core.model.tiny import build_tiny_transformer, build_tiny_vae

#: what docs/toyworld.md and docs/evaluation.md measured oscar-toy with
TOY = {"steps": 20, "guidance": 3.0, "guidance_form": "diffusers", "preset": None}


def _captured_sampler(model, monkeypatch, **kwargs) -> SamplerConfig:
    """The SamplerConfig ``model.rollout`` hands to the sampler loop (the loop itself replaced: nothing runs)."""
    import oscar_core.model.rollout as rollout_module

    seen = {}

    def fake(*args, sampler, **rest):
        seen["sampler"] = sampler
        return "done"

    monkeypatch.setattr(rollout_module, "rollout", fake)
    w, h = model.card.width or 32, model.card.height or 32
    first = np.zeros((h, w, 3), np.uint8)
    skeleton = np.zeros((model.card.chunk_frames, h, w, 3), np.uint8)
    import torch

    prompt = torch.zeros(1, 1, model.transformer.text_dim)
    assert model.rollout(first, skeleton, prompt, progress=False, **kwargs) == "done"
    return seen["sampler"]


def test_oscar_toy_with_no_sampler_arguments_uses_its_card(monkeypatch):
    model = oscar_zoo.load("oscar-toy")
    assert model.card.sampler == TOY
    used = _captured_sampler(model, monkeypatch)
    assert (used.steps, used.guidance, used.guidance_form, used.guidance_interval) == (20, 3.0, "diffusers", None)


def test_an_argument_overrides_the_card(monkeypatch):
    model = oscar_zoo.load("oscar-toy")
    used = _captured_sampler(model, monkeypatch, sampler=SamplerConfig(steps=2))
    assert (used.steps, used.guidance) == (2, 6.0)  # a sampler given is used as it is
    choice = resolve_sampler(model.card.sampler, steps=5)
    assert (choice.config.steps, choice.config.guidance) == (5, 3.0)
    assert choice.sources == {
        "steps": "given",
        "guidance": "model card",
        "guidance_form": "model card",
        "preset": "model card",
    }
    assert choice.describe("flag") == (
        "steps 5 (flag), guidance 3 (model card), guidance form diffusers (model card), preset none (model card)"
    )


def test_a_card_without_settings_falls_back_to_the_library_default(monkeypatch):
    model = tiny_world_model(name="tiny", chunk_frames=5, width=32, height=32)
    assert model.card.sampler is None
    used = _captured_sampler(model, monkeypatch)
    assert used == model.sampler_for(SamplerConfig())  # 35 steps, guidance 6, diffusers form, every step
    choice = resolve_sampler(None)
    assert set(choice.sources.values()) == {"library default"} and choice.config == SamplerConfig()


def test_presets_and_steps_by_level():
    """A preset sets steps unless steps are given at the same or a higher level (given > card > default)."""
    fast = resolve_sampler({"preset": "fast"})
    assert fast.config.steps == 12 and fast.sources["steps"] == "preset fast (model card)"
    assert resolve_sampler({"preset": "fast", "steps": 20}).config.steps == 20
    assert resolve_sampler({"steps": 20}, preset="fast").config.steps == 12
    assert resolve_sampler({"preset": "fast"}, steps=7).config.steps == 7
    assert resolve_sampler(None, defaults={"guidance_form": "standard"}).config.guidance_form == "standard"
    assert (
        resolve_sampler({"guidance_form": "diffusers"}, defaults={"guidance_form": "standard"}).config.guidance_form
        == "diffusers"
    )


@pytest.mark.parametrize(
    ("sampler", "message"),
    [
        ({"steps": 0}, "model card sampler.steps: expected an integer >= 1, found 0"),
        ({"guidance": -1}, "model card sampler.guidance: expected a finite number >= 0, found -1"),
        ({"guidance_form": "odd"}, "model card sampler.guidance_form: expected one of"),
        ({"preset": "slow"}, "model card sampler.preset: expected one of ['fast', 'paper'] or null, found 'slow'"),
        (
            {"shift": 3},
            "model card sampler: expected keys among steps, guidance, guidance_form, preset, found ['shift']",
        ),
    ],
)
def test_a_bad_card_setting_is_refused_naming_the_key(sampler, message):
    with pytest.raises(ModelInputError, match=message.replace("[", r"\[").replace("]", r"\]")):
        ModelCard(sampler=sampler)


def test_the_card_round_trips_through_its_file(tmp_path):
    card = ModelCard(name="t", chunk_frames=5, sampler={"steps": 4, "guidance": 1.5})
    model = OscarWorldModel.from_modules(build_tiny_transformer(seed=0), build_tiny_vae(seed=0), card)
    folder = oscar_zoo.export(model, tmp_path / "m")
    assert json.loads((folder / "oscar_model.json").read_text())["card"]["sampler"] == {"steps": 4, "guidance": 1.5}
    assert oscar_zoo.load(str(folder)).card.sampler == {"steps": 4, "guidance": 1.5}


def test_eval_run_reads_the_card_without_loading_weights():
    """``oscar eval run`` needs the settings before its rollout keys: it reads the card from the model's folder."""
    from oscar_core.evaluation.loop import card_sampler_of

    assert card_sampler_of("oscar-toy") == TOY
