"""The toy world's Gymnasium ids, registered whenever gymnasium is imported, before or after ``import oscar_core``.

Importing gymnasium costs about 0.1 s beside numpy's 0.15 s, and ``import oscar_core`` imports neither (it takes
about 10 ms), so registration waits for gymnasium: :func:`install` registers at once when gymnasium is already
imported, and otherwise puts a finder first on ``sys.meta_path`` that, on gymnasium's own import, wraps its loader
so the ids are registered right after the package has run (the finder then removes itself). The ids name their
factories by string (``oscar_core.envs.toy:make_toy_env``), so registering imports nothing of oscar's.
"""

from __future__ import annotations

import sys

__all__ = ["TOY_IDS", "install", "register_toy_ids"]

#: Registered id → keyword arguments of :func:`oscar_core.envs.toy.make_toy_env`.
TOY_IDS: dict[str, dict] = {
    "oscar/ToySim-v0": {"world": "simulator"},
    "oscar/ToyWorldModel-v0": {"world": "model"},
}


def register_toy_ids(gymnasium) -> None:
    """Register :data:`TOY_IDS` with ``gymnasium`` (the imported module); ids already there are left alone."""
    for env_id, kwargs in TOY_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                env_id,
                entry_point="oscar_core.envs.toy:make_toy_env",
                vector_entry_point="oscar_core.envs.toy:make_toy_vector_env",
                kwargs=dict(kwargs),
            )


class _RegisteringLoader:  # a loader by protocol (importlib.abc alone costs 9 ms to import)
    """gymnasium's own loader, registering the ids once the package has executed."""

    def __init__(self, loader):
        self.loader = loader

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module):
        self.loader.exec_module(module)
        register_toy_ids(module)

    def __getattr__(self, name):  # get_resource_reader, is_package, get_source, ...: the real loader's
        return getattr(self.loader, name)


class _GymnasiumFinder:  # a meta path finder by protocol
    """Finds nothing itself; on ``import gymnasium`` it wraps the spec the path finder gives."""

    def find_spec(self, name, path=None, target=None):
        if name != "gymnasium":
            return None
        import importlib.machinery  # here, not at the top: it costs ~10 ms to import

        if self in sys.meta_path:
            sys.meta_path.remove(self)
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is not None and spec.loader is not None:
            spec.loader = _RegisteringLoader(spec.loader)
        return spec


def install() -> None:
    """Register the ids now if gymnasium is imported, else when it is (module docstring)."""
    gymnasium = sys.modules.get("gymnasium")
    if gymnasium is not None and hasattr(gymnasium, "register"):
        register_toy_ids(gymnasium)
    elif not any(isinstance(f, _GymnasiumFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _GymnasiumFinder())
