"""Deprecated public names: a public name that is removed or renamed keeps working for one minor version, and each
use warns with :class:`OscarDeprecationWarning`, naming its replacement and the version that removes it.

A package lists its deprecated names beside its lazy exports (:func:`oscar_core._util.lazy.lazy_exports`'s
``deprecated``); a deprecated method is a function that calls :func:`warn_deprecated` and then its replacement.
Every deprecated name is listed in CHANGELOG.md under "Deprecated" with the same replacement.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

__all__ = ["Deprecated", "OscarDeprecationWarning", "deprecation_message", "warn_deprecated"]


class OscarDeprecationWarning(DeprecationWarning):
    """A public name of oscar that is going away. The message names its replacement and the version removing it.
    Python shows a DeprecationWarning raised from a user's ``__main__`` (and under pytest); to see every one:
    ``python -W default::DeprecationWarning``."""


class Deprecated(NamedTuple):
    """A deprecated module-level name: where its value now lives and what to write instead."""

    module: str  # the module holding the value, absolute (``oscar_core.model.latent_action``)
    attribute: str  # the value's name there
    replacement: str  # what to write instead, as a user would (e.g. "oscar_core.model.LatentActionTransformer")
    since: str  # the version that deprecated it
    removed_in: str  # the version that removes it (one minor version later)


def deprecation_message(old: str, replacement: str, since: str, removed_in: str) -> str:
    """``"<old> is deprecated since <since> and will be removed in <removed_in>: use <replacement>"``."""
    return f"{old} is deprecated since oscar {since} and will be removed in {removed_in}: use {replacement}"


def warn_deprecated(old: str, replacement: str, since: str, removed_in: str, stacklevel: int = 3) -> None:
    """Warn (:class:`OscarDeprecationWarning`) that ``old`` is deprecated in favour of ``replacement``;
    ``stacklevel`` 3 points at the caller of the function that calls this."""
    warnings.warn(deprecation_message(old, replacement, since, removed_in), OscarDeprecationWarning, stacklevel)
