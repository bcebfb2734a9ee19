"""A torch module whose constructor's keyword arguments are its config, saved as a diffusers-style folder.

oscar's own models (the Wan VAE, the Cosmos DiT) keep diffusers' folder layout so that folders written by either
library load in both: ``config.json`` (``_class_name`` plus the constructor's arguments) beside
``diffusion_pytorch_model.safetensors``, or, above ``max_shard_size``, numbered shards and their index
(:mod:`.weights` reads both). This base gives a subclass the three things oscar uses of diffusers' ``ConfigMixin`` /
``ModelMixin``:

* ``model.config``: every constructor argument, defaults filled in, read as attributes (``model.config.z_dim``)
  or as a mapping (``dict(model.config)``); read-only.
* ``Cls.from_config(mapping)``: keys starting with ``_`` (``_class_name``, ``_diffusers_version``) are dropped; a
  key the constructor does not take is refused (:class:`~.errors.CheckpointLayoutError`), since silently ignoring a
  setting a newer writer added could change what the model computes.
* ``model.save_pretrained(folder, max_shard_size=...)``: every file written atomically (temporary, then rename).

The subclass sets ``config_class_name`` (the ``_class_name`` written) and takes its settings as keyword arguments
(positional ones are allowed but recorded by name). A subclass whose constructor ends in ``**kwargs`` states only
its own new settings and passes the rest on with ``super().__init__(**kwargs)``: its recorded settings are its
parent's (in the parent's order, defaults as the parent declares them) followed by its own, and ``**kwargs`` takes
nothing else, so an unknown setting is still refused. ``inspect.signature(Cls)`` shows the merged settings.
"""

from __future__ import annotations

import inspect
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

import torch

from .._util.atomic import atomic_output, atomic_write_bytes
from .errors import CheckpointLayoutError, ModelInputError
from .weights import CONFIG_NAME, INDEX_NAME, WEIGHTS_NAME

__all__ = ["ConfiguredModule", "ModelConfig", "parse_shard_size"]

_UNITS = {"B": 1, "KB": 10**3, "MB": 10**6, "GB": 10**9, "TB": 10**12, "KIB": 2**10, "MIB": 2**20, "GIB": 2**30}


class ModelConfig(Mapping):
    """A model's settings, read-only: ``cfg.name`` or ``cfg["name"]``; ``dict(cfg)`` copies them."""

    def __init__(self, values: Mapping[str, Any]):
        object.__setattr__(self, "_values", dict(values))

    def __getitem__(self, key: str) -> Any:
        return self._values[key]

    def __iter__(self):
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __getattr__(self, key: str) -> Any:
        values = self.__dict__.get("_values", {})  # absent while copy/pickle rebuild the object: no recursion
        if key not in values:
            raise AttributeError(f"model config has no setting {key!r}")
        return values[key]

    def __setattr__(self, key: str, value: Any) -> None:
        raise AttributeError(f"model config is read-only (tried to set {key!r})")

    def __repr__(self) -> str:
        return f"ModelConfig({self._values!r})"


def parse_shard_size(size: str | int) -> int:
    """Bytes of a shard size given as bytes or as ``"10GB"`` / ``"200KB"`` / ``"1GiB"`` (decimal units as diffusers')."""
    if isinstance(size, int) and not isinstance(size, bool):
        if size <= 0:
            raise ModelInputError(f"max_shard_size: expected a positive byte count, found {size}")
        return size
    text = str(size).strip().upper().replace(" ", "")
    for unit in sorted(_UNITS, key=len, reverse=True):
        if text.endswith(unit):
            try:
                value = float(text[: -len(unit)])
            except ValueError:
                break
            if value > 0:
                return int(value * _UNITS[unit])
            break
    raise ModelInputError(f"max_shard_size: expected bytes or a size such as '10GB' or '200KB', found {size!r}")


_VARIADIC = (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)


def _recorded_signature(cls: type, init) -> inspect.Signature:
    """The settings ``cls``'s constructor ``init`` records: its own signature, or, when it takes ``**kwargs``, the
    settings of the next constructor in the MRO (what ``super().__init__(**kwargs)`` calls) followed by its own new
    ones; a setting it restates keeps the parent's place and takes its own default. ``*args`` / ``**kwargs`` are
    left out of the result, so binding it refuses an unknown setting."""
    own = inspect.signature(init)
    params = list(own.parameters.values())
    if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params):
        return own
    mine = {p.name: p for p in params[1:] if p.kind not in _VARIADIC}
    parent_init = next(c.__dict__["__init__"] for c in cls.__mro__[1:] if "__init__" in c.__dict__)
    parent = list(inspect.signature(parent_init).parameters.values())[1:]
    merged = [
        p.replace(default=mine[p.name].default, annotation=mine[p.name].annotation) if p.name in mine else p
        for p in parent
        if p.kind not in _VARIADIC
    ]
    merged += [p for name, p in mine.items() if name not in {q.name for q in parent}]
    return own.replace(parameters=[params[0], *merged])


def _bound_config(signature: inspect.Signature, args: tuple, kwargs: dict) -> dict[str, Any]:
    """The constructor's arguments by name, defaults filled in (``self``, ``*args``, ``**kwargs`` left out)."""
    bound = signature.bind(None, *args, **kwargs)
    bound.apply_defaults()
    names = [p.name for p in list(signature.parameters.values())[1:] if p.kind not in _VARIADIC]
    return {name: bound.arguments[name] for name in names}


def _jsonable(value: Any) -> Any:
    if isinstance(value, tuple | list):
        return [_jsonable(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    return value


def _shards(state: dict[str, torch.Tensor], limit: int) -> list[list[str]]:
    """Tensor names grouped in order into shards of at most ``limit`` bytes (a bigger tensor gets its own)."""
    groups: list[list[str]] = [[]]
    size = 0
    for name, tensor in state.items():
        nbytes = tensor.numel() * tensor.element_size()
        if groups[-1] and size + nbytes > limit:
            groups.append([])
            size = 0
        groups[-1].append(name)
        size += nbytes
    return groups


def _version() -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("diffusers")
    except PackageNotFoundError:
        return None


class ConfiguredModule(torch.nn.Module):
    """``torch.nn.Module`` whose constructor's arguments are recorded as :attr:`config` (see the module docstring)."""

    config_class_name: ClassVar[str] = ""
    config: ModelConfig

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "__init__" not in cls.__dict__:
            return
        init = cls.__dict__["__init__"]
        signature = _recorded_signature(cls, init)
        merged = signature != inspect.signature(init)

        def recording_init(self, *args, **kw):
            if not hasattr(self, "_config_recording"):  # the outermost constructor records (a subclass's wins)
                object.__setattr__(self, "_config_recording", True)
                torch.nn.Module.__init__(self)
                self.config = ModelConfig(_bound_config(signature, args, kw))
            if merged:  # positional settings passed by name, so the parent's reach it through **kwargs
                bound = signature.bind(None, *args, **kw).arguments
                args, kw = (), {k: v for k, v in list(bound.items())[1:]}
            init(self, *args, **kw)

        recording_init.__doc__, recording_init.__name__ = init.__doc__, "__init__"
        recording_init.__signature__ = signature  # type: ignore[attr-defined]
        cls.__init__ = recording_init  # type: ignore[method-assign]

    def __init__(self) -> None:
        if not hasattr(self, "_config_recording"):
            super().__init__()
            self.config = ModelConfig({})

    def __setattr__(self, key: str, value: Any) -> None:
        if key == "config":  # a plain attribute, never a submodule or buffer
            object.__setattr__(self, key, value)
        else:
            super().__setattr__(key, value)

    @classmethod
    def config_keys(cls) -> list[str]:
        """The settings the constructor takes, in order."""
        params = list(inspect.signature(cls.__init__).parameters.values())[1:]
        return [p.name for p in params if p.kind not in _VARIADIC]

    @classmethod
    def from_config(cls, config: Mapping[str, Any], source: str | Path = CONFIG_NAME):
        """Build the model from a config mapping (e.g. a parsed config.json; ``source`` names it in errors)."""
        settings = {k: v for k, v in dict(config).items() if not str(k).startswith("_")}
        unknown = sorted(set(settings) - set(cls.config_keys()))
        if unknown:
            raise CheckpointLayoutError(
                source,
                ", ".join(unknown),
                f"only settings {cls.__name__} takes ({', '.join(cls.config_keys())})",
                f"{len(unknown)} other setting(s)",
                "a newer library may have written them; oscar refuses rather than ignore what they change",
            )
        return cls(**settings)

    def save_pretrained(self, folder, safe_serialization: bool = True, max_shard_size: str | int = "10GB") -> Path:
        """Write ``folder/config.json`` and the safetensors weights (sharded above ``max_shard_size``); returns folder.

        Only safetensors are written (``safe_serialization=False`` is refused: oscar never writes pickles).
        Weight files of an earlier save with another sharding are removed after the new ones are in place.
        """
        from safetensors.torch import save_file

        if not safe_serialization:
            raise ModelInputError("save_pretrained: safe_serialization=False is not offered; weights are safetensors")
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        state = {k: v.detach().to("cpu").contiguous() for k, v in self.state_dict().items()}
        groups = _shards(state, parse_shard_size(max_shard_size))
        names = (
            [WEIGHTS_NAME]
            if len(groups) == 1
            else [
                WEIGHTS_NAME.replace(".safetensors", f"-{i + 1:05d}-of-{len(groups):05d}.safetensors")
                for i in range(len(groups))
            ]
        )
        for name, group in zip(names, groups, strict=True):
            with atomic_output(folder / name) as tmp:
                save_file({k: state[k].clone() for k in group}, str(tmp), metadata={"format": "pt"})
        stale = {WEIGHTS_NAME, INDEX_NAME} | {p.name for p in folder.glob(WEIGHTS_NAME.replace(".safetensors", "-*"))}
        if len(groups) > 1:
            weight_map = {k: name for name, group in zip(names, groups, strict=True) for k in group}
            total = sum(t.numel() * t.element_size() for t in state.values())
            index = {"metadata": {"total_size": total}, "weight_map": weight_map}
            atomic_write_bytes(folder / INDEX_NAME, (json.dumps(index, indent=2) + "\n").encode())
            stale -= {INDEX_NAME}
        for name in sorted(stale - set(names)):
            (folder / name).unlink(missing_ok=True)
        config: dict[str, Any] = {"_class_name": self.config_class_name or type(self).__name__}
        version = _version()
        if version:
            config["_diffusers_version"] = version
        config.update({k: _jsonable(v) for k, v in self.config.items()})
        atomic_write_bytes(folder / CONFIG_NAME, (json.dumps(config, indent=2, sort_keys=True) + "\n").encode())
        return folder
