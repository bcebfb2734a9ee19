"""Model cards carry the YAML block the Hub reads (licence, library, base model, pipeline tag, tags)."""

from __future__ import annotations

import json

import yaml
from _models import tiny_world_model
from _paths import REPO

from oscar_core.model.hub_card import hub_license, hub_metadata, with_hub_metadata

BUNDLED = REPO / "zoo" / "assets" / "oscar-toy"


def front_matter(markdown: str) -> tuple[dict, str]:
    assert markdown.startswith("---\n"), markdown[:40]
    end = markdown.index("\n---\n", 4)
    return yaml.safe_load(markdown[4:end]), markdown[end + 5 :]


def test_the_bundled_model_card_has_the_hub_block_of_its_own_card():
    meta, body = front_matter((BUNDLED / "README.md").read_text())
    card = json.loads((BUNDLED / "oscar_model.json").read_text())["card"]
    assert meta == hub_metadata(card, tags=("toy-world",))
    assert meta["license"] == "apache-2.0" and meta["library_name"] == "oscar-wm"
    assert meta["pipeline_tag"] == "image-to-video" and "base_model" not in meta  # trained from scratch
    assert {"oscar", "robotics", "embodiment:toyarm"} <= set(meta["tags"])
    assert body.lstrip().startswith("# oscar-toy")


def test_a_fine_tune_names_its_base_repo_and_other_licences_are_spelled_out():
    meta = hub_metadata(
        {
            "license": "NVIDIA Open Model License",
            "base": "nvidia/Cosmos-Predict2.5-2B@diffusers/base",
            "embodiments": ["franka"],
        }
    )
    assert meta["base_model"] == "nvidia/Cosmos-Predict2.5-2B"
    assert meta["license"] == "other" and meta["license_name"] == "nvidia-open-model-license"
    assert meta["license_link"].startswith("https://www.nvidia.com/")
    assert hub_license(None) == {"license": "unknown"} and hub_license("MIT") == {"license": "mit"}


def test_the_block_is_replaced_not_stacked():
    once = with_hub_metadata("# m\n\ntext\n", {"license": "Apache-2.0"})
    twice = with_hub_metadata(once, {"license": "MIT"})
    meta, body = front_matter(twice)
    assert meta["license"] == "mit" and twice.count("---\n") == 2 and body.strip() == "# m\n\ntext"


def test_the_toy_packager_writes_the_block():
    from oscar_core.toyworld.package import model_card_markdown

    md = model_card_markdown("my-toy", {"license": "Apache-2.0", "embodiments": ["toyarm"], "base": None}, {}, None)
    meta, body = front_matter(md)
    assert meta["library_name"] == "oscar-wm" and "toy-world" in meta["tags"] and body.lstrip().startswith("# my-toy")


def test_an_exported_model_folder_has_a_card_with_the_block(tmp_path):
    import oscar_zoo
    from oscar_core.model.manifest import read_manifest

    model = tiny_world_model(
        name="tiny-ft", embodiments=("franka",), license="MIT", base="nvidia/Cosmos-Predict2.5-2B@main"
    )
    folder = oscar_zoo.export(model, tmp_path / "m")
    meta, body = front_matter((folder / "README.md").read_text())
    assert meta["license"] == "mit" and meta["base_model"] == "nvidia/Cosmos-Predict2.5-2B"
    assert "embodiment:franka" in meta["tags"] and body.lstrip().startswith("# tiny-ft")
    assert "README.md" not in read_manifest(folder)  # documentation: a download fetches the weights' files only
    oscar_zoo.load(str(folder))  # and the folder still loads


def test_the_default_card_names_conditioning_that_changes_the_rollout():
    from oscar_core.model.hub_card import default_model_card

    plain = default_model_card({"name": "m", "chunk_frames": 17})
    assert "context" not in plain and "gripper signal" not in plain
    both = default_model_card({"name": "m", "chunk_frames": 17, "context_frames": 5, "gripper_signal": True})
    assert "last 5 decoded frames (`context_frames`); open-loop rollouts only" in both
    assert "gripper's openness per latent frame (`gripper_signal`)" in both
