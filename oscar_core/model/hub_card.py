"""The YAML metadata block the Hugging Face Hub reads at the top of a model card (``README.md``).

:func:`hub_metadata` turns an oscar :class:`~oscar_core.model.ModelCard`
dictionary into the block (the Hub's model-card fields, see
https://huggingface.co/docs/hub/model-cards): ``license`` (the Hub's licence
id, or ``other`` with ``license_name``/``license_link``), ``library_name``
(``oscar-wm``, the distribution that loads it), ``base_model`` (the Hub repo a
fine-tune started from, when the card names one), ``pipeline_tag``
(``image-to-video``: a first frame and a skeleton video in, a video out) and
``tags`` (oscar, the embodiments, …). Plain Python and PyYAML: no torch.
"""

from __future__ import annotations

import yaml

__all__ = ["LIBRARY_NAME", "PIPELINE_TAG", "hub_metadata", "hub_license", "with_hub_metadata", "default_model_card"]

LIBRARY_NAME = "oscar-wm"
PIPELINE_TAG = "image-to-video"
#: SPDX id → the Hub's licence id (lower case; https://huggingface.co/docs/hub/repositories-licenses).
_HUB_LICENSES = {
    "apache-2.0": "apache-2.0",
    "mit": "mit",
    "cc-by-4.0": "cc-by-4.0",
    "cc-by-nc-4.0": "cc-by-nc-4.0",
    "bsd-3-clause": "bsd-3-clause",
    "openrail": "openrail",
}
_NVIDIA_OPEN = "https://www.nvidia.com/en-us/agreements/enterprise-software/nvidia-open-model-license/"


def hub_license(license: str | None) -> dict:
    """The licence fields for ``license`` (SPDX id or a licence's name): ``{"license": ...}`` plus, for a
    licence the Hub has no id for, ``license_name`` (a slug) and ``license_link`` where known."""
    if not license:
        return {"license": "unknown"}
    key = license.strip().lower()
    if key in _HUB_LICENSES:
        return {"license": _HUB_LICENSES[key]}
    slug = "-".join("".join(c if c.isalnum() else " " for c in key).split())
    out = {"license": "other", "license_name": slug}
    if "nvidia open model" in key:
        out["license_link"] = _NVIDIA_OPEN
    return out


def hub_metadata(card: dict, *, tags=()) -> dict:
    """The metadata fields of the module docstring for a model card dictionary (``ModelCard.to_dict()``)."""
    meta = {**hub_license(card.get("license")), "library_name": LIBRARY_NAME}
    base = card.get("base")
    if base:
        meta["base_model"] = str(base).split("@", 1)[0]  # "owner/name@revision" → the repo id the Hub links
    meta["pipeline_tag"] = PIPELINE_TAG
    all_tags = [
        "oscar",
        "world-model",
        "robotics",
        "video-generation",
        "skeleton-conditioned",
        *tags,
        *[f"embodiment:{e}" for e in card.get("embodiments") or ()],
    ]
    meta["tags"] = list(dict.fromkeys(all_tags))  # in order, no repeats
    return meta


def with_hub_metadata(markdown: str, card: dict, *, tags=()) -> str:
    """``markdown`` with the ``---`` YAML block of :func:`hub_metadata` in front (a block already there is replaced)."""
    body = markdown
    if body.startswith("---\n"):
        end = body.find("\n---\n", 4)
        if end != -1:
            body = body[end + len("\n---\n") :].lstrip("\n")
    block = yaml.safe_dump(hub_metadata(card, tags=tags), sort_keys=False, allow_unicode=True)
    return f"---\n{block}---\n\n{body}"


def _conditioning_lines(card: dict) -> list[str]:
    """Bullets for the card's conditioning options that change how it must be rolled out (none for the defaults)."""
    lines = []
    if card.get("gripper_signal"):
        lines.append("- gripper signal: the DiT also takes the gripper's openness per latent frame (`gripper_signal`)")
    ctx = int(card.get("context_frames") or 1)
    if ctx > 1:
        lines.append(
            f"- context: each chunk after the first continues from the previous chunk's last {ctx} decoded frames "
            "(`context_frames`); open-loop rollouts only (the closed loop and the Gymnasium envs refuse it)"
        )
    return lines


def default_model_card(card: dict) -> str:
    """The ``README.md`` an exported model folder gets when it has none (``OscarWorldModel.save_pretrained``):
    the metadata block, what the folder is and how to load it. Replace it with a real card before sharing."""
    name = card.get("name") or "oscar-model"
    emb = ", ".join(card.get("embodiments") or []) or "not recorded"
    size = f"{card.get('width')}x{card.get('height')}" if card.get("width") else "not recorded"
    lines = [
        f"# {name}",
        "",
        "An OSCAR skeleton-conditioned video world model in oscar's folder layout (`oscar-wm` on the package index).",
        "",
        f"- embodiments: {emb}",
        f"- chunk: {card.get('chunk_frames')} frames at {size}, {card.get('fps')} fps",
        f"- condition: {card.get('condition', 'skeleton')}; base: {card.get('base') or 'none recorded'}",
        *_conditioning_lines(card),
        f"- licence: {card.get('license') or 'not recorded'}",
        "",
        "```python",
        "import oscar_zoo",
        "",
        'model = oscar_zoo.load("<this folder or its Hub repo>")',
        "```",
        "",
        "This card was written by `save_pretrained`; say how the model was trained and what it was measured to "
        "do before sharing it.",
        "",
    ]
    return with_hub_metadata("\n".join(lines), card)
