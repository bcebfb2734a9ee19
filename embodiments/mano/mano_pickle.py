"""Reading the official MANO model files without chumpy and without running their code.

``MANO_RIGHT.pkl`` / ``MANO_LEFT.pkl`` are Python 2 pickles of a dict of
numpy arrays, one ``scipy.sparse.csc_matrix`` (``J_regressor``) and
``chumpy.ch.Ch`` objects (``shapedirs``, possibly others). A plain
``pickle.load`` would import chumpy (which no longer installs) and, like any
pickle, would run whatever callable the file names. :func:`load_mano_pickle`
uses a :class:`pickle.Unpickler` whose ``find_class`` returns objects only
from a short allow-list:

* numpy's array and scalar reconstructors, ``numpy.ndarray`` and
  ``numpy.dtype`` (object dtypes are refused);
* the builtin ``set`` (chumpy keeps its dirty flags in one), ``object`` and
  ``copyreg._reconstructor`` (used by protocol 0/1 pickles; it only builds
  the inert placeholders below), and ``_codecs.encode`` limited to latin-1
  (how protocol-2 pickles written by Python 3 store bytes);
* ``scipy.sparse`` CSC/CSR matrices and every ``chumpy.*`` class, which become
  inert placeholders that only record their pickled state.

After loading, a chumpy placeholder becomes ``numpy.asarray(state["x"])``
(a plain ``Ch`` keeps its value in ``x``; a derived chumpy expression has no
``x`` and is refused), and a sparse placeholder becomes a fresh
``scipy.sparse`` matrix built from its ``data``/``indices``/``indptr``/shape.
Any other global in the file raises :class:`MANOModelError` naming the file
and the refused global; nothing outside the list is ever imported or called.
"""

from __future__ import annotations

import io
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from oscar_core.errors import InputFileError

__all__ = ["MANOModelError", "load_mano_pickle", "loads_mano_pickle", "REQUIRED_KEYS", "ALLOWED_GLOBALS"]

#: Fields smplx.MANO reads from the model dict.
REQUIRED_KEYS = (
    "v_template",
    "f",
    "J_regressor",
    "kintree_table",
    "weights",
    "posedirs",
    "shapedirs",
    "hands_components",
    "hands_mean",
)


class MANOModelError(InputFileError):
    """A MANO model file that is missing, malformed, or names a global outside the allow-list."""


# ---- placeholders ------------------------------------------------------------------


class _Placeholder:
    """Records what the pickle hands it and does nothing else."""

    _qualname = "?"
    _args: tuple = ()
    _state = None  # NEWOBJ creates instances without calling __init__

    def __init__(self, *args, **kwargs):
        self._args, self._state = args, None

    def __setstate__(self, state):
        self._state = state


class _ChumpyPlaceholder(_Placeholder):
    pass


class _SparsePlaceholder(_Placeholder):
    _format = "csc"


_PLACEHOLDERS: dict[tuple[str, str], type] = {}


def _placeholder(base: type, module: str, name: str, **attrs) -> type:
    key = (module, name)
    if key not in _PLACEHOLDERS:
        _PLACEHOLDERS[key] = type(f"_{name}Placeholder", (base,), {"_qualname": f"{module}.{name}", **attrs})
    return _PLACEHOLDERS[key]


# ---- allowed callables -------------------------------------------------------------

_RECONSTRUCT = np.ndarray.__reduce__(np.zeros(1))[0]  # numpy's _reconstruct, wherever this numpy keeps it
_SCALAR = np.float64(0.0).__reduce__()[0]  # numpy's scalar reconstructor


class _Refused(Exception):
    def __init__(self, what: str):
        self.what = what


def _dtype(spec, align=False, copy=False):
    dt = np.dtype(spec, bool(align), bool(copy))
    if dt.hasobject:
        raise _Refused(f"numpy.dtype({spec!r}) (object arrays could hold arbitrary objects)")
    return dt


def _latin1_encode(text, encoding="latin1", *rest):
    if not isinstance(text, str) or str(encoding).lower().replace("-", "") != "latin1" or rest:
        raise _Refused(
            f"_codecs.encode with {type(text).__name__}, {encoding!r} (only latin-1 text → bytes is allowed)"
        )
    return text.encode("latin1")


def _reconstructor(cls, base, state=None):
    if isinstance(cls, type) and issubclass(cls, _Placeholder) and base is object:
        obj = cls()
        if state is not None:
            obj.__setstate__(state)
        return obj
    raise _Refused(
        f"copyreg._reconstructor({getattr(cls, '__name__', cls)!r}, ...) (only for chumpy/scipy placeholders)"
    )


_NUMPY_MODULES = ("numpy.core.multiarray", "numpy._core.multiarray")
_SPARSE_MODULES = (
    "scipy.sparse",
    "scipy.sparse.csc",
    "scipy.sparse._csc",
    "scipy.sparse.csr",
    "scipy.sparse._csr",
    "scipy.sparse.compressed",
    "scipy.sparse._compressed",
)

#: (module, name) pairs the unpickler resolves (chumpy.* and scipy sparse matrices become placeholders).
ALLOWED_GLOBALS: dict[tuple[str, str], Any] = {
    **{(m, "_reconstruct"): _RECONSTRUCT for m in _NUMPY_MODULES},
    **{(m, "scalar"): _SCALAR for m in _NUMPY_MODULES},
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): _dtype,
    ("builtins", "set"): set,
    ("builtins", "object"): object,
    ("copyreg", "_reconstructor"): _reconstructor,
    ("_codecs", "encode"): _latin1_encode,
}
_PY2_MODULES = {"__builtin__": "builtins", "copy_reg": "copyreg"}


class _RestrictedUnpickler(pickle.Unpickler):
    def __init__(self, file, source: str):
        super().__init__(file, encoding="latin1")
        self.source = source

    def find_class(self, module: str, name: str):
        module = _PY2_MODULES.get(module, module)
        if (module, name) in ALLOWED_GLOBALS:
            return ALLOWED_GLOBALS[(module, name)]
        if module == "chumpy" or module.startswith("chumpy."):
            return _placeholder(_ChumpyPlaceholder, module, name)
        if module in _SPARSE_MODULES and name in ("csc_matrix", "csr_matrix"):
            return _placeholder(_SparsePlaceholder, module, name, _format=name[:3])
        raise _Refused(f"{module}.{name}")

    def persistent_load(self, pid):
        raise _Refused(f"persistent id {pid!r}")


# ---- after loading ------------------------------------------------------------------


def _convert(obj, source: str, where: str):
    if isinstance(obj, _ChumpyPlaceholder):
        state = obj._state if isinstance(obj._state, dict) else {}
        if "x" not in state:
            raise MANOModelError(
                source,
                where,
                "a chumpy array that stores its value ('x' in its pickled state)",
                f"a {obj._qualname} without one (a derived chumpy expression, which cannot be read without chumpy)",
            )
        return np.asarray(_convert(state["x"], source, where))
    if isinstance(obj, _SparsePlaceholder):
        import scipy.sparse as sp

        state = obj._state if isinstance(obj._state, dict) else {}
        shape = state.get("_shape", state.get("shape"))
        try:
            parts = tuple(np.asarray(_convert(state[k], source, where)) for k in ("data", "indices", "indptr"))
            make = sp.csc_matrix if obj._format == "csc" else sp.csr_matrix
            return make(parts, shape=tuple(int(s) for s in shape))
        except (KeyError, TypeError, ValueError) as exc:
            raise MANOModelError(
                source,
                where,
                f"a {obj._format.upper()} sparse matrix (data, indices, indptr, shape)",
                f"{type(exc).__name__}: {exc}",
            ) from None
    if isinstance(obj, _Placeholder):  # pragma: no cover - only the two kinds above exist
        raise MANOModelError(source, where, "plain data", obj._qualname)
    if isinstance(obj, dict):
        return {k: _convert(v, source, f"{where}[{k!r}]" if where != "<pickle>" else str(k)) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_convert(v, source, f"{where}[{i}]") for i, v in enumerate(obj))
    if isinstance(obj, np.ndarray) and obj.dtype.hasobject:
        raise MANOModelError(source, where, "a numeric array", "an object array")
    return obj


def loads_mano_pickle(data: bytes, source: str = "<MANO model>") -> dict:
    """Like :func:`load_mano_pickle`, from bytes."""
    try:
        raw = _RestrictedUnpickler(io.BytesIO(data), source).load()
    except _Refused as exc:
        raise MANOModelError(
            source,
            "pickle global",
            "only the numpy / scipy.sparse / chumpy classes a MANO model file uses "
            "(oscar_embodiments.mano.mano_pickle.ALLOWED_GLOBALS)",
            f"{exc.what}, which was refused (nothing from the file was imported or run)",
        ) from None
    except MANOModelError:
        raise
    except Exception as exc:  # noqa: BLE001 - truncated or corrupt data, wrong argument types for an allowed callable
        raise MANOModelError(source, "<file>", "a MANO model pickle", f"{type(exc).__name__}: {exc}") from None
    if not isinstance(raw, dict):
        raise MANOModelError(source, "<file>", "a pickled dict of model arrays", type(raw).__name__)
    model = _convert(raw, source, "<pickle>")
    missing = [k for k in REQUIRED_KEYS if k not in model]
    if missing:
        raise MANOModelError(source, missing[0], f"the MANO model fields {list(REQUIRED_KEYS)}", f"missing {missing}")
    _check_shapes(model, source)
    return model


def load_mano_pickle(path) -> dict:
    """Read ``MANO_RIGHT.pkl`` / ``MANO_LEFT.pkl`` into a dict of numpy arrays (``J_regressor``
    stays a scipy sparse matrix), without chumpy and without executing code from the file.

    Raises :class:`MANOModelError` (naming the file) for a missing file, a refused global,
    a chumpy expression without a stored value, or fields of inconsistent shapes.
    """
    path = Path(path)
    if not path.is_file():
        raise MANOModelError(
            str(path), "<file>", "the MANO model file (licensed separately, see the mano README)", "no such file"
        )
    return loads_mano_pickle(path.read_bytes(), str(path))


def _check_shapes(m: dict, source: str) -> None:
    def shape(k):
        return tuple(getattr(m[k], "shape", np.shape(m[k])))

    V = shape("v_template")[0] if len(shape("v_template")) == 2 else -1
    J = shape("kintree_table")[1] if len(shape("kintree_table")) == 2 else -1
    want = {
        "v_template": (V, 3),
        "f": (shape("f")[0] if shape("f") else -1, 3),
        "J_regressor": (J, V),
        "kintree_table": (2, J),
        "weights": (V, J),
        "shapedirs": (V, 3, shape("shapedirs")[-1] if shape("shapedirs") else -1),
        "posedirs": (V, 3, 9 * (J - 1)),
        "hands_mean": (3 * (J - 1),),
        "hands_components": (shape("hands_components")[0] if shape("hands_components") else -1, 3 * (J - 1)),
    }
    for k, s in want.items():
        if V < 1 or J < 2 or shape(k) != s:
            raise MANOModelError(
                source, k, f"shape {s} (V = vertices of v_template, J = joints of kintree_table)", f"shape {shape(k)}"
            )
