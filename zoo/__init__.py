"""oscar_zoo: named OSCAR checkpoints and one front door to load them.

    import oscar_zoo
    oscar_zoo.list_models()                      # the table + your registered models
    model = oscar_zoo.load("oscar-2b", device="cuda", dtype=torch.bfloat16)
    model = oscar_zoo.load("me/my-oscar")        # any Hub repo in oscar's layout
    model = oscar_zoo.load("./exported")         # a local folder
    base = oscar_zoo.load("cosmos-predict2.5-2b")  # Cosmos base + zero PE_s, to fine-tune

    oscar_zoo.export(model, "./my-ft")           # safetensors + card + sha256 manifest
    oscar_zoo.push("./my-ft", "me/my-ft", name="my-ft")   # upload + register by name
    oscar_zoo.load("my-ft")                      # loads back, hashes checked

Works offline from the Hub cache with ``HF_HUB_OFFLINE=1`` (or
``local_files_only=True``). ``oscar_zoo.testing.MockHub`` serves checkpoints
over loopback for tests.
"""

from __future__ import annotations

from ._fetch import UnknownModelError, list_models, resolve
from ._load import convert, export, load, pull, push
from ._registry import register, registry_path, unregister, user_models
from ._table import CHECKPOINTS, COSMOS_TEXT_ENCODER_ID, CheckpointSpec, FileSpec

__all__ = [
    "CHECKPOINTS",
    "COSMOS_TEXT_ENCODER_ID",
    "CheckpointSpec",
    "FileSpec",
    "UnknownModelError",
    "convert",
    "export",
    "list_models",
    "load",
    "pull",
    "push",
    "register",
    "registry_path",
    "resolve",
    "unregister",
    "user_models",
]
