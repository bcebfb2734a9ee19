"""Finding embodiment plugins: entry points, one-file plugins, and the registry.

Built-in embodiments and outside plugins are found the same way: every module
named in the ``oscar`` entry-point group is imported and registered with a
pluggy ``PluginManager``, then its ``oscar_register_embodiments`` hook is
called. A plugin that fails to import, raises in its hook or breaks the
contract is recorded as a :class:`PluginFailure` naming its distribution;
the other plugins still load.

Environment variables:

``OSCAR_PLUGINS``
    ``os.pathsep``-separated ``.py`` files (or folders of them) loaded as
    one-file plugins, like ``--plugin PATH`` on the command line.
``OSCAR_DISABLE_PLUGIN_AUTOLOAD``
    ``1`` to skip entry points (only path plugins load).
``OSCAR_BLOCK_PLUGINS``
    comma-separated entry-point or distribution names not to load.
"""

from __future__ import annotations

import importlib
import importlib.metadata as md
import importlib.util
import os
import sys
import warnings
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import pluggy

from ..errors import PluginError
from . import hookspecs
from .embodiment import Embodiment

__all__ = [
    "ENTRY_POINT_GROUP",
    "EmbodimentEntry",
    "PluginFailure",
    "Registry",
    "default_registry",
    "get_embodiment",
    "PluginLoadWarning",
]

ENTRY_POINT_GROUP = "oscar"
ENV_PLUGINS = "OSCAR_PLUGINS"
ENV_DISABLE_AUTOLOAD = "OSCAR_DISABLE_PLUGIN_AUTOLOAD"
ENV_BLOCK = "OSCAR_BLOCK_PLUGINS"


class PluginLoadWarning(UserWarning):
    """A plugin failed to load; the others are unaffected."""


@dataclass(frozen=True)
class EmbodimentEntry:
    """Where a registered class (an embodiment, or a dataset reader) came from."""

    name: str
    cls: type
    plugin: str  # entry-point name or file path
    distribution: str  # distribution name, or "file:<path>" for path plugins
    version: str


@dataclass(frozen=True)
class PluginFailure:
    """A plugin that could not be used, and why."""

    plugin: str
    distribution: str
    error: str

    def __str__(self) -> str:
        return f"plugin {self.plugin!r} from {self.distribution}: {self.error}"


def _truthy(value: str | None) -> bool:
    return (value or "").strip().lower() in ("1", "true", "yes", "on")


def _expand_paths(paths: Iterable[str | Path]) -> list[Path]:
    out = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            out += sorted(x for x in p.glob("*.py") if not x.name.startswith("_"))
        else:
            out.append(p)
    return out


class Registry:
    """Loaded plugins and the embodiments they register.

    plugin_paths: one-file plugins to load besides the entry points (added to
    those in ``OSCAR_PLUGINS``). autoload: load entry points (default: unless
    ``OSCAR_DISABLE_PLUGIN_AUTOLOAD`` is set). blocked: names of entry points
    or distributions to skip (added to ``OSCAR_BLOCK_PLUGINS``).
    """

    def __init__(
        self,
        plugin_paths: Iterable[str | Path] = (),
        autoload: bool | None = None,
        blocked: Iterable[str] = (),
        warn: bool = True,
    ):
        self.pm = pluggy.PluginManager(hookspecs.PROJECT_NAME)
        self.pm.add_hookspecs(hookspecs)
        self.entries: dict[str, EmbodimentEntry] = {}
        self.reader_entries: dict[str, EmbodimentEntry] = {}  # dataset readers (oscar_register_readers)
        self.failures: list[PluginFailure] = []
        self._instances: dict[str, Embodiment] = {}
        self._loaded_paths: set[Path] = set()
        self._warn = warn
        env_block = [b.strip() for b in os.environ.get(ENV_BLOCK, "").split(",") if b.strip()]
        self.blocked = set(blocked) | set(env_block)
        if autoload is None:
            autoload = not _truthy(os.environ.get(ENV_DISABLE_AUTOLOAD))
        if autoload:
            self._load_entry_points()
        env_paths = [p for p in os.environ.get(ENV_PLUGINS, "").split(os.pathsep) if p.strip()]
        for path in _expand_paths(list(env_paths) + list(plugin_paths)):
            self.load_plugin_file(path)

    # ---- loading ---------------------------------------------------------
    def _fail(self, plugin: str, distribution: str, error: str) -> None:
        failure = PluginFailure(plugin, distribution, error)
        self.failures.append(failure)
        if self._warn:
            warnings.warn(str(failure), PluginLoadWarning, stacklevel=3)

    def _load_entry_points(self) -> None:
        eps = sorted(
            md.entry_points(group=ENTRY_POINT_GROUP), key=lambda ep: ((ep.dist.name if ep.dist else ""), ep.name)
        )
        seen = set()
        for ep in eps:
            dist = ep.dist.name if ep.dist else "<unknown distribution>"
            version = ep.dist.version if ep.dist else ""
            if (ep.name, ep.value) in seen:  # the same distribution visible twice on sys.path
                continue
            seen.add((ep.name, ep.value))
            if ep.name in self.blocked or dist in self.blocked:
                continue
            try:
                module = ep.load()
            except BaseException as exc:  # an import may raise anything, even SystemExit
                if isinstance(exc, KeyboardInterrupt):
                    raise
                self._fail(
                    ep.name, f"{dist} {version}".strip(), f"import of {ep.value!r} failed: {type(exc).__name__}: {exc}"
                )
                continue
            self._register_module(module, ep.name, dist, version)

    def load_plugin_file(self, path: str | Path) -> None:
        """Load a one-file plugin (a ``.py`` module with hookimpls) from ``path``."""
        path = Path(path).resolve()
        label = f"file:{path}"
        if path in self._loaded_paths:
            return
        self._loaded_paths.add(path)
        if not path.is_file() or path.suffix != ".py":
            self._fail(str(path), label, "expected an existing .py file")
            return
        mod_name = f"oscar_plugin_{path.stem}_{abs(hash(str(path))) & 0xFFFFFF:x}"
        try:
            spec = importlib.util.spec_from_file_location(mod_name, path)
            module = importlib.util.module_from_spec(spec)
            sys.modules[mod_name] = module
            spec.loader.exec_module(module)
        except BaseException as exc:
            if isinstance(exc, KeyboardInterrupt):
                raise
            sys.modules.pop(mod_name, None)
            self._fail(str(path), label, f"import failed: {type(exc).__name__}: {exc}")
            return
        self._register_module(module, str(path), label, "")

    def _register_module(self, module, plugin: str, dist: str, version: str) -> None:
        who = f"{dist} {version}".strip()
        try:
            self.pm.register(module, name=f"{dist}:{plugin}")
        except (ValueError, pluggy.PluginValidationError) as exc:  # already registered, or bad hookimpl signature
            self._fail(plugin, who, str(exc).replace("\n", " "))
            return
        unknown = [
            n
            for n in dir(module)
            if n.startswith("oscar_") and callable(getattr(module, n)) and not hasattr(self.pm.hook, n)
        ]
        if unknown:
            self._fail(
                plugin,
                who,
                f"unknown hooks {unknown}; known: {[h for h in dir(self.pm.hook) if h.startswith('oscar_')]}",
            )
        from .reader import Reader

        for hook, base, entries, kind in (
            ("oscar_register_embodiments", Embodiment, self.entries, "embodiment"),
            ("oscar_register_readers", Reader, self.reader_entries, "reader"),
        ):
            for cls in self._hook_classes(module, hook, base, plugin, who):
                self._add_class(cls, plugin, dist, version, entries, kind)

    def _hook_classes(self, module, hook: str, base: type, plugin: str, who: str) -> list[type]:
        """The classes ``module``'s implementation of registration hook ``hook`` returns; failures are recorded."""
        classes = []
        for impl in [i for i in getattr(self.pm.hook, hook).get_hookimpls() if i.plugin is module]:
            try:
                returned = impl.function()
            except Exception as exc:  # noqa: BLE001 - a broken plugin is reported; the others keep working
                self._fail(plugin, who, f"{hook} raised {type(exc).__name__}: {exc}")
                continue
            if returned is None:
                continue
            if isinstance(returned, type) or not isinstance(returned, (list, tuple)):
                self._fail(
                    plugin,
                    who,
                    f"{hook} must return a list of {base.__name__} classes, returned {type(returned).__name__}",
                )
                continue
            classes.extend(returned)
        return classes

    def _add_class(
        self, cls, plugin: str, dist: str, version: str, entries: dict | None = None, kind: str = "embodiment"
    ) -> None:
        """Check one registered class (an embodiment, or with ``kind="reader"`` a dataset reader) and keep it."""
        from .reader import Reader

        who = f"{dist} {version}".strip()
        entries = self.entries if entries is None else entries
        base = Embodiment if kind == "embodiment" else Reader
        if not (isinstance(cls, type) and issubclass(cls, base)):
            article = "an" if base.__name__[0] in "AEIOU" else "a"
            self._fail(plugin, who, f"expected {article} {base.__name__} subclass, found {cls!r}")
            return
        problems = cls.class_problems()
        if problems:
            contract = "the contract" if kind == "embodiment" else "the reader contract"
            self._fail(plugin, who, f"{cls.__qualname__} breaks {contract}: " + "; ".join(problems))
            return
        prior = entries.get(cls.name)
        if prior is not None:
            self._fail(
                plugin,
                who,
                f"{kind} name {cls.name!r} is already registered by {prior.distribution} {prior.version}".rstrip()
                + f" (plugin {prior.plugin!r}); "
                f"{who} registers it again ({cls.__module__}.{cls.__qualname__})",
            )
            return
        entries[cls.name] = EmbodimentEntry(cls.name, cls, plugin, dist, version)

    # ---- use -------------------------------------------------------------
    def reader_names(self) -> list[str]:
        return sorted(self.reader_entries)

    def get_reader(self, name: str, options: dict | None = None):
        """A new instance of the dataset reader ``name``; options: its constructor's keywords (checked by the caller)."""
        if name not in self.reader_entries:
            raise PluginError(
                f"unknown dataset reader {name!r}; registered: {', '.join(self.reader_names()) or 'none'}"
            )
        entry = self.reader_entries[name]
        try:
            return entry.cls(**(options or {}))
        except Exception as exc:
            raise PluginError(
                f"reader {name!r} from {entry.distribution} {entry.version}".rstrip() + f" could not be created: {exc}"
            ) from exc

    def names(self) -> list[str]:
        return sorted(self.entries)

    def get(self, name: str) -> Embodiment:
        """The embodiment ``name``, instantiated once (its files load now)."""
        if name not in self.entries:
            broken = [f for f in self.failures]
            hint = ("; plugins that failed to load: " + "; ".join(map(str, broken))) if broken else ""
            raise PluginError(f"unknown embodiment {name!r}; registered: {', '.join(self.names()) or 'none'}{hint}")
        if name not in self._instances:
            entry = self.entries[name]
            try:
                self._instances[name] = entry.cls()
            except Exception as exc:
                raise PluginError(
                    f"embodiment {name!r} from {entry.distribution} {entry.version}".rstrip()
                    + f" could not be loaded: {exc}"
                ) from exc
        return self._instances[name]


_DEFAULT: Registry | None = None


def default_registry(plugin_paths: Iterable[str | Path] = ()) -> Registry:
    """The process-wide registry (built on first use); extra paths load into it."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = Registry()
    for p in _expand_paths(plugin_paths):
        _DEFAULT.load_plugin_file(p)
    return _DEFAULT


def get_embodiment(name: str, plugin_paths: Iterable[str | Path] = ()) -> Embodiment:
    """Shortcut: ``default_registry(plugin_paths).get(name)``."""
    return default_registry(plugin_paths).get(name)
