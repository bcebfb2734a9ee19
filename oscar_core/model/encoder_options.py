"""Which encoder turns a rollout's condition video into latents: the flag of the commands that take it (``oscar
rollout``, ``oscar eval closed-loop``), its check, and what a run records of the choice.

``--tiny-encoder FILE``: encode every chunk's condition video with that tiny encoder (:mod:`.tiny_encoder`, a
safetensors file) instead of the full VAE encoder; the seed frame stays with the full encoder. Without it: the full
encoder (no model card names a tiny encoder).
"""

from __future__ import annotations

from .decoder_options import check_tiny_weights_file, tiny_file_identity

__all__ = ["add_encoder_option", "encoder_choice", "check_encoder_choice", "encoder_identity"]


def add_encoder_option(parser) -> None:
    """Add ``--tiny-encoder FILE`` to ``parser``."""
    parser.add_argument(
        "--tiny-encoder",
        metavar="FILE",
        help="encode the condition (skeleton) video of every chunk with this tiny encoder (.safetensors; e.g. "
        "oscar-toy's tiny_encoder.safetensors, or a converted taew2_1 for the 2B) instead of the full VAE encoder: "
        "faster, less exact; the seed frame keeps the full encoder (docs/world-model.md)",
    )


def check_encoder_choice(choice, what: str = "--tiny-encoder"):
    """``choice`` (None or False: the full encoder; a path) with a path checked to be a ``.safetensors`` file that
    exists; ModelInputError naming ``what``, the expected and the found otherwise. Returns None or the path."""
    if choice is None or choice is False:
        return None
    return check_tiny_weights_file(choice, what, "tiny-encoder")


def encoder_choice(args):
    """The condition encoder the flag in ``args`` chooses, checked before any model is looked up: None (the full
    encoder) or the ``--tiny-encoder`` path."""
    return check_encoder_choice(getattr(args, "tiny_encoder", None))


def encoder_identity(choice) -> str:
    """What a run records of a condition-encoder choice: ``"full"``, or ``"tiny-sha256:<hex>"`` of the file's
    bytes."""
    if choice is None or choice is False:
        return "full"
    return tiny_file_identity(choice)
