"""Reading ``.npy`` files that hold pickled dicts (RH20T, VITRA) without running code from them.

RH20T's ``transformed/*.npy`` and ``calib/*/*.npy`` and VITRA's per-episode
``*.npy`` are written with ``np.save(path, some_dict)``: an object array
whose payload is a pickle. ``np.load(..., allow_pickle=True)`` would let the
file import and call anything. :func:`load_npy` parses the ``.npy`` header
itself and unpickles the payload with an unpickler whose ``find_class``
resolves only numpy's array/scalar/dtype reconstructors and
``collections.OrderedDict``; dicts, lists, tuples, strings and numbers need
no globals. Any other global raises :class:`NpyPickleError` naming the file
and the refused global, before anything from the file is imported or run.
Plain numeric ``.npy`` files load with ``allow_pickle=False``.
"""

from __future__ import annotations

import collections
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import InputFileError

__all__ = ["NpyPickleError", "load_npy", "ALLOWED_GLOBALS"]


class NpyPickleError(InputFileError):
    """A ``.npy`` file that is unreadable or whose pickle names a global outside the allow-list."""


_RECONSTRUCT = np.ndarray.__reduce__(np.zeros(1))[0]
_SCALAR = np.float64(0.0).__reduce__()[0]
_NUMPY_MODULES = ("numpy.core.multiarray", "numpy._core.multiarray")

#: (module, name) → object: everything the unpickler may resolve
ALLOWED_GLOBALS: dict[tuple[str, str], Any] = {
    **{(m, "_reconstruct"): _RECONSTRUCT for m in _NUMPY_MODULES},
    **{(m, "scalar"): _SCALAR for m in _NUMPY_MODULES},
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
    ("collections", "OrderedDict"): collections.OrderedDict,
}


class _Refused(Exception):
    def __init__(self, what: str):
        self.what = what


class _RestrictedUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if (module, name) in ALLOWED_GLOBALS:
            return ALLOWED_GLOBALS[(module, name)]
        raise _Refused(f"{module}.{name}")

    def persistent_load(self, pid):
        raise _Refused(f"persistent id {pid!r}")


def load_npy(path: str | Path) -> Any:
    """The content of a ``.npy`` file: a numeric array, or the object a pickled ``.npy`` holds.

    A 0-d object array (``np.save(path, a_dict)``) is returned as its item
    (the dict), as ``np.load(...).item()`` would. Raises
    :class:`NpyPickleError` naming the file for a missing or malformed file or
    a refused global.
    """
    path = Path(path)
    if not path.is_file():
        raise NpyPickleError(path, "<file>", "a .npy file", "no such file")
    fmt = np.lib.format
    try:
        with open(path, "rb") as f:
            version = fmt.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = fmt.read_array_header_1_0(f)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = fmt.read_array_header_2_0(f)
            else:
                raise ValueError(f"unsupported .npy version {version}")
            if not dtype.hasobject:
                f.seek(0)
                return np.load(f, allow_pickle=False)
            obj = _RestrictedUnpickler(f, encoding="latin1").load()
    except _Refused as e:
        raise NpyPickleError(
            path,
            "pickle global",
            "only numpy arrays, dicts, lists and numbers (oscar_core.data.readers._npy.ALLOWED_GLOBALS)",
            f"{e.what}, which was refused (nothing from the file was imported or run)",
        ) from None
    except Exception as e:  # noqa: BLE001 - truncated or corrupt file
        raise NpyPickleError(path, "<file>", "a readable .npy file", f"{type(e).__name__}: {e}") from None
    if isinstance(obj, np.ndarray) and obj.dtype.hasobject and obj.shape == ():
        return obj.item()
    return obj
