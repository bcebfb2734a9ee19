"""Built-in dataset readers, registered through the same hook an outside plugin uses.

Each entry of :data:`BUILTIN_READERS` is ``"module:Class"``; a reader module
imports its heavy dependencies (h5py, pyarrow, av) inside its methods, so
listing the readers costs nothing and a missing optional dependency fails
only the reader that needs it, with the install command in the message.
"""

from __future__ import annotations

from importlib import import_module

from ...plugin.hookspecs import hookimpl

# one line per built-in reader: "module:Class"
BUILTIN_READERS: list[str] = [
    "oscar_core.data.readers.lerobot:LeRobotReader",
    "oscar_core.data.readers.agibot_world:AgiBotWorldReader",
    "oscar_core.data.readers.droid:DroidRawReader",
    "oscar_core.data.readers.egodex:EgoDexReader",
    "oscar_core.data.readers.epic_vitra:EpicVitraReader",
    "oscar_core.data.readers.interndata_a1:InternDataA1Reader",
    "oscar_core.data.readers.rh20t:RH20TReader",
    "oscar_core.data.readers.npz:NpzReader",
]


@hookimpl
def oscar_register_readers():
    classes = []
    for spec in BUILTIN_READERS:
        module, _, name = spec.partition(":")
        classes.append(getattr(import_module(module), name))
    return classes
