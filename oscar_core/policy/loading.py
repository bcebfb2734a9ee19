"""Where a policy comes from: ``module:attr``, ``path/to/file.py:attr``, an ``oscar.policies`` entry point,
``ws://host:port`` (openpi's websocket protocol, :class:`~oscar_core.policy.remote.WebsocketPolicy`), or
``lerobot:PATH_OR_REPO`` (a LeRobot policy, :class:`~oscar_core.policy.lerobot.LeRobotPolicy`).

A class is instantiated with no arguments, an object with ``infer`` is used as it is, a plain function
``obs -> dict`` is wrapped so it has ``infer``.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
from pathlib import Path

from .._util.user_code import import_attr
from ..errors import OscarError
from .protocol import ENTRY_POINT_GROUP, PolicySpecError

__all__ = ["PolicyLoadError", "load_policy", "resolve_policy_source"]


class PolicyLoadError(OscarError):
    """Policies that cannot be loaded (or connected), found before any work: ``lines`` holds one line per policy;
    the message prints each on a line of its own starting ``error:`` under the CLI (exit 2)."""

    def __init__(self, lines: list[str]):
        self.lines = list(lines)
        super().__init__("\nerror: ".join(self.lines))


def resolve_policy_source(source: str, folder) -> str:
    """``source`` with a relative ``path/to/file.py:attr`` made absolute against ``folder`` (a manifest's folder,
    as its session files are); every other source (``module:attr``, an entry point, ``ws://…``, an absolute
    path) unchanged."""
    target, sep, attr = source.rpartition(":")
    if not sep or not target.endswith(".py") or source.startswith(("ws://", "wss://")) or Path(target).is_absolute():
        return source
    return f"{(Path(folder) / target).resolve()}:{attr}"


class _FunctionPolicy:
    """A plain function ``obs -> {"actions": ...}`` made into a policy."""

    def __init__(self, fn):
        self.fn = fn

    def infer(self, obs: dict) -> dict:
        return self.fn(obs)


def load_policy(source: str, keys=None):
    """A policy object from ``module:attr``, ``path/to/file.py:attr``, an ``oscar.policies`` entry-point name,
    ``ws://host:port`` (a :class:`~oscar_core.policy.remote.WebsocketPolicy`, connected here), or
    ``lerobot:PATH_OR_REPO[?mapping]`` (:func:`~oscar_core.policy.lerobot.load_lerobot_policy`; ``keys``: the
    observation keys the loop sends it, the declaration's).

    A class is instantiated with no arguments; an object with ``infer`` is returned as it is; a function is
    wrapped. Raises :class:`PolicySpecError` naming ``source`` when nothing usable is found.
    """
    if source.startswith(("ws://", "wss://")):
        from .remote import WebsocketPolicy

        return WebsocketPolicy(source)
    if source.startswith("lerobot:"):
        from .lerobot import load_lerobot_policy

        return load_lerobot_policy(source, keys=keys)
    try:
        if ":" in source:
            obj = import_attr(source, "policy")
        else:
            found = [ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP) if ep.name == source]
            if not found:
                names = sorted(ep.name for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP))
                raise PolicySpecError(
                    source,
                    "policy",
                    f"module:attr, file.py:attr or an {ENTRY_POINT_GROUP} entry point (installed: {names or 'none'})",
                    "none of these",
                )
            obj = found[0].load()
    except FileNotFoundError:
        raise PolicySpecError(source, "policy", "an existing Python file", "no such file") from None
    except ValueError as exc:
        raise PolicySpecError(source, "policy", "module:attr or path/to/file.py:attr", str(exc)) from None
    except (ImportError, AttributeError) as exc:
        raise PolicySpecError(source, "policy", "an importable module:attr", f"{type(exc).__name__}: {exc}") from None
    if isinstance(obj, type):
        obj = obj()
    if hasattr(obj, "infer"):
        return obj
    if callable(obj):
        return _FunctionPolicy(obj)
    raise PolicySpecError(
        source, "policy", "an object with infer(obs), a class of one, or a function", type(obj).__name__
    )
