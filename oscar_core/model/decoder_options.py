"""Which decoder turns a rollout's latents into frames: the flags every command that rolls out shares
(``oscar rollout``, ``oscar eval closed-loop``, ``oscar eval action-following``, ``oscar toyworld
action-following``), their check, and what a run's fingerprint records of the choice.

``--tiny-decoder FILE``: decode with that tiny decoder (:mod:`.tiny_decoder`, a safetensors file) instead of the
full VAE decoder; ``--full-decoder``: the full decoder even where the model card names a tiny one (its
``tiny_decoder`` field). Neither: the card decides (:meth:`~oscar_core.model.world_model.OscarWorldModel.from_pretrained`).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from .errors import ModelInputError

__all__ = ["add_decoder_options", "decoder_choice", "check_decoder_choice", "decoder_identity"]


def add_decoder_options(parser) -> None:
    """Add ``--tiny-decoder FILE`` and ``--full-decoder`` (one or the other) to ``parser``."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--tiny-decoder",
        metavar="FILE",
        help="decode with this tiny decoder (.safetensors; e.g. oscar-toy's tiny_decoder.safetensors, or a "
        "converted taew2_1 for the 2B) instead of the full VAE decoder: faster, less exact (docs/world-model.md)",
    )
    group.add_argument(
        "--full-decoder",
        action="store_true",
        help="decode with the full VAE decoder even where the model card names a tiny decoder",
    )


def check_decoder_choice(choice, what: str = "--tiny-decoder"):
    """``choice`` (None: the card's; False: the full decoder; a path) with a path checked to be a ``.safetensors``
    file that exists; ModelInputError naming ``what``, the expected and the found otherwise. Returns the choice
    (a path as a :class:`~pathlib.Path`)."""
    if choice is None or choice is False:
        return choice
    return check_tiny_weights_file(choice, what, "tiny-decoder")


def check_tiny_weights_file(choice, what: str, kind: str) -> Path:
    """``choice`` as a :class:`~pathlib.Path` to an existing ``.safetensors`` file of ``kind`` (``"tiny-decoder"``,
    ``"tiny-encoder"``) weights; ModelInputError naming ``what``, the expected and the found otherwise."""
    path = Path(choice)
    if path.suffix != ".safetensors":
        raise ModelInputError(f"{what}: expected a .safetensors file of {kind} weights, found {str(path)!r}")
    if not path.is_file():
        raise ModelInputError(f"{what}: expected a {kind} file, found no file {str(path)!r}")
    return path


def tiny_file_identity(path) -> str:
    """``"tiny-sha256:<hex>"`` of the bytes of the tiny decoder's or encoder's file at ``path``."""
    with open(path, "rb") as f:
        return f"tiny-sha256:{hashlib.file_digest(f, 'sha256').hexdigest()}"


def decoder_choice(args):
    """The decoder the flags in ``args`` choose, checked before any model is looked up: None (the card's),
    False (``--full-decoder``) or the ``--tiny-decoder`` path."""
    if getattr(args, "full_decoder", False):
        return False
    return check_decoder_choice(getattr(args, "tiny_decoder", None))


def decoder_identity(choice) -> str | None:
    """What a run's fingerprint records of a decoder choice: None for the card's (the model's identity covers its
    card), ``"full"``, or ``"tiny-sha256:<hex>"`` of the file's bytes."""
    if choice is None:
        return None
    if choice is False:
        return "full"
    return tiny_file_identity(choice)
