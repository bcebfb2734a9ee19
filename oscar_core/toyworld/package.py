"""Turn a trained toy-world run into the shipped ``oscar-toy`` folder: weights, card, empty prompt, model card.

``package_toy_model(EXPORT, OUT, ...)`` copies the exported model folder
(``oscar train`` writes RUN_DIR/export), names it, records that it was
trained with the zero prompt (so rollouts without a prompt use exactly what
training used, and say nothing), and writes ``README.md``: what it was
trained on and how, the measured table, the licence. The zoo's table pins
the sha256 of every file it ships (``file_hashes``).
"""

from __future__ import annotations

import hashlib
import shutil
import tempfile
from pathlib import Path

from ..model.hub_card import with_hub_metadata

__all__ = ["package_toy_model", "file_hashes", "model_card_markdown"]


def file_hashes(folder) -> dict[str, str]:
    """{relative path: sha256} of every file under ``folder`` (sorted)."""
    folder = Path(folder)
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            out[p.relative_to(folder).as_posix()] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def model_card_markdown(name: str, card: dict, training: dict, table: dict | None) -> str:
    """The README.md of a shipped toy model (markdown, with the Hub's YAML metadata block on top:
    :func:`oscar_core.model.hub_card.with_hub_metadata`)."""
    lines = [
        f"# {name}",
        "",
        "A small OSCAR world model trained on oscar's procedural toy world (docs/toyworld.md) on a 2-core CPU.",
        "It is the toy-scale test of the paper's central claim, that the skeleton video drives the generated "
        "video; the table below says how far this checkpoint gets. It is not a model of real robots or real "
        "scenes.",
        "",
        "## Model",
        "",
        f"- DiT: `OscarTransformer3DModel`, {training.get('transformer_parameters', '?')} parameters; "
        f"VAE: `AutoencoderKLWan` (4x time, 4x space), {training.get('vae_parameters', '?')} parameters.",
        f"- Chunk: {card.get('chunk_frames')} frames at {card.get('width')}x{card.get('height')}, "
        f"{card.get('fps')} fps; unconditional skeleton: {card.get('unconditional_skeleton')}; "
        "prompt: the zero embedding (trained without text).",
        f"- Trained on: {', '.join(card.get('embodiments', []))} (held out: "
        f"{', '.join(training.get('heldout_embodiments', [])) or 'none'}).",
        "",
        "## Training",
        "",
    ]
    for k, v in training.items():
        if k not in ("transformer_parameters", "vae_parameters", "heldout_embodiments"):
            lines.append(f"- {k}: {v}")
    if table:
        lines += ["", "## Measured (held-out episodes)", "", table.get("markdown", "").rstrip()]
    lines += [
        "",
        "## Licence",
        "",
        f"{card.get('license') or 'Apache-2.0'} (the weights, like the code of oscar-wm).",
        "",
    ]
    return with_hub_metadata("\n".join(lines), card, tags=("toy-world",))


def package_toy_model(
    export,
    out,
    *,
    name: str = "oscar-toy",
    license: str = "Apache-2.0",
    training: dict | None = None,
    table: dict | None = None,
) -> dict[str, str]:
    """Write the shipped folder ``out`` from the exported run ``export``; returns its file hashes."""
    from dataclasses import replace

    import torch

    from ..model.world_model import OscarWorldModel

    export, out = Path(export), Path(out)
    model = OscarWorldModel.from_pretrained(export)
    card = replace(model.card, name=name, license=license, text_encoder_id=None)
    model.empty_prompt = torch.zeros(1, 1, model.transformer.text_dim)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        model.save_pretrained(tmp, card)
        (tmp / "README.md").write_text(model_card_markdown(name, card.to_dict(), training or {}, table))
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return file_hashes(out)
