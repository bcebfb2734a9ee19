"""Interfaces, not size splits: no private name crosses a package of oscar_core, and the camera modules form one line.

Read from the source with ``ast`` as tests/project/test_layers.py does, but counting every import, ``if TYPE_CHECKING:``
ones included (a type-only import still ties two modules together). Each checker is run on a made-up package too,
so a broken checker cannot pass silently.
"""

from __future__ import annotations

import ast
from pathlib import Path

from _paths import REPO

CORE = REPO / "oscar_core"

#: the package-wide helpers (``oscar_core._util``) are shared by every package: its modules' public names are
#: the interface, so the folder's leading underscore alone does not make an import private
SHARED_PRIVATE_PACKAGES = {"_util"}

#: private names that still cross a package, each with its reason (keep this empty where possible)
ALLOWED_PRIVATE: dict[tuple[str, str], str] = {}

#: the camera modules bottom to top; a module may import only those before it (the same step: neither)
CAMERA_CHAIN: list[tuple[str, ...]] = [
    ("geometry",),
    ("extrinsics", "intrinsics"),
    ("projection",),
    ("pinhole",),
    ("file",),
    ("__init__",),
]


def _module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(root: Path) -> list[tuple[str, str, str]]:
    """(importing module, imported module, imported name or "") for every import of the package at ``root`` that
    names a module of that package (relative imports resolved)."""
    top = root.name
    out = []
    for path in sorted(root.rglob("*.py")):
        mod = _module_name(root, path)
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                out += [(mod, a.name, "") for a in node.names if a.name.split(".")[0] == top]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if target.split(".")[0] == top:
                    out += [(mod, target, a.name) for a in node.names]
    return out


def _package(module: str) -> str:
    """oscar_core.render.mesh -> oscar_core.render; a top-level module is its own package."""
    return ".".join(module.split(".")[:2])


def _private(part: str) -> bool:
    return part.startswith("_") and not part.startswith("__")


def private_crossings(found: list[tuple[str, str, str]]) -> list[str]:
    """Imports of a private name (``_x``), or from a private module, of another package."""
    bad = []
    for mod, target, name in found:
        if _package(mod) == _package(target):
            continue
        parts = [p for p in target.split(".")[1:] if p not in SHARED_PRIVATE_PACKAGES]
        if _private(name) or any(_private(p) for p in parts):
            bad.append(f"{mod} imports {target}{'.' + name if name else ''}")
    return sorted(bad)


def chain_violations(found: list[tuple[str, str, str]], package: str, chain: list[tuple[str, ...]]) -> list[str]:
    """Imports between modules of ``package`` that are not strictly down ``chain``, and private names they share."""
    step = {name: i for i, names in enumerate(chain) for name in names}
    bad = []
    for mod, target, name in found:
        if _package(mod) != package or not target.startswith(package):
            continue
        src = mod[len(package) + 1 :] or "__init__"
        dst = target[len(package) + 1 :]
        if not dst and name in step:  # from . import geometry
            dst, name = name, ""
        dst = dst or "__init__"
        if src not in step or dst not in step:
            bad.append(f"{mod}: module not in the chain ({src if src not in step else dst})")
        elif step[dst] >= step[src]:
            bad.append(f"{mod} imports {target} (not below it)")
        elif _private(name):
            bad.append(f"{mod} imports the private name {name} of {target}")
    return sorted(bad)


def test_no_private_name_crosses_a_package():
    bad = [b for b in private_crossings(imports(CORE)) if tuple(b.split(" imports ")) not in ALLOWED_PRIVATE]
    assert bad == [], "\n".join(bad)


def test_the_camera_modules_form_one_line():
    assert {p.stem for p in (CORE / "camera").glob("*.py")} == {n for names in CAMERA_CHAIN for n in names}
    assert chain_violations(imports(CORE), "oscar_core.camera", CAMERA_CHAIN) == []


def test_the_checkers_find_what_they_must(tmp_path):
    pkg = tmp_path / "pkg"
    for rel, text in {
        "__init__.py": "",
        "a/__init__.py": "",
        "b/__init__.py": "",
        "_util/__init__.py": "",
        "_util/h.py": "x = 1\n",
        "a/low.py": "_secret = 1\nshared = 2\n",
        "a/_private.py": "y = 1\n",
        "a/high.py": "from typing import TYPE_CHECKING\nfrom .low import _secret\nif TYPE_CHECKING:\n"
        "    from . import top\n",
        "a/top.py": "from .high import x\n",
        "b/user.py": "from ..a.low import _secret, shared\nfrom ..a import _private\nimport pkg.a._private\n"
        "from .._util.h import x\nfrom pkg.a.low import shared as _alias\n",
    }.items():
        (pkg / rel).parent.mkdir(parents=True, exist_ok=True)
        (pkg / rel).write_text(text)
    found = imports(pkg)
    assert private_crossings(found) == [
        "pkg.b.user imports pkg.a._private",
        "pkg.b.user imports pkg.a._private",
        "pkg.b.user imports pkg.a.low._secret",
    ]
    chain = [("low",), ("high",), ("top",), ("__init__",)]
    assert chain_violations(found, "pkg.a", chain) == [
        "pkg.a.high imports pkg.a (not below it)",  # the TYPE_CHECKING import of top counts (from . import top)
        "pkg.a.high imports the private name _secret of pkg.a.low",
    ]


# ------------------------------------------------------------------ conditions and renderers
def test_every_condition_comes_from_the_registry_and_every_video_condition_has_a_renderer():
    from typing import get_args

    from oscar_core.render import conditions as c
    from oscar_core.render.renderer import ChunkedRenderer, ConditionRenderer

    assert c.MODEL_CONDITIONS == tuple(c.REGISTRY) == get_args(c.ConditionName)
    assert c.CONDITIONS == ("skeleton", "mesh", "capsules") == get_args(c.VideoConditionName)
    assert [n for n in c.REGISTRY if c.takes_actions(n)] == ["latent_action"]
    for name in c.CONDITIONS:
        r = c.renderer(name)
        assert isinstance(r, ChunkedRenderer) and r.name == name
        for method in ("prepare", "render_range", "iter_chunks", "render_video"):
            assert callable(getattr(r, method)) and method in dir(ConditionRenderer)
    from oscar_core.model.world_model import CONDITIONS as CARD_CONDITIONS
    from oscar_core.train.config import CONDITIONS as TRAIN_CONDITIONS

    assert CARD_CONDITIONS == TRAIN_CONDITIONS == c.MODEL_CONDITIONS


def test_a_new_condition_is_one_registry_entry(monkeypatch):
    """A fourth video condition: its renderer plus one entry; every lookup by name finds it."""
    import sys
    import types

    import numpy as np

    from oscar_core import get_embodiment, load_trajectory
    from oscar_core.render import conditions as c
    from oscar_core.render.renderer import ChunkedRenderer, prepare_view

    class Flat(ChunkedRenderer):  # every frame one grey, to show the loop and the lookup, not a drawing
        name = "flat"

        def prepare(self, embodiment, traj, camera, size, *, style, resize_mode, device, camera_source):
            traj, camera = prepare_view(embodiment, traj, camera, size, resize_mode, camera_source)
            return types.SimpleNamespace(traj=traj, camera=camera)

        def render_range(self, job, start, stop, out, stats):
            intr = job.camera.intrinsics
            out = np.empty((stop - start, intr.height, intr.width, 3), np.uint8) if out is None else out
            out[...] = 7
            return out

    module = types.ModuleType("flat_condition")
    module.FLAT = Flat()
    monkeypatch.setitem(sys.modules, "flat_condition", module)
    monkeypatch.setitem(c.REGISTRY, "flat", c.Condition("flat", "flat_condition:FLAT"))
    emb = get_embodiment("toyarm")
    traj = load_trajectory(emb.example_trajectory).time_slice(0, 5)
    cam = emb.load_camera(emb.example_camera)
    assert c.check_condition("flat") == "flat" and c.video_condition_of("flat") == "flat"
    video = c.condition_video("flat", emb, traj, cam, (32, 16))
    assert video.shape == (5, 16, 32, 3) and (video == 7).all()
    chunks = list(c.chunk_renderer("flat")(emb, traj, cam, (32, 16), chunk_frames=2))
    assert [len(x) for x in chunks] == [2, 2, 1]


def test_no_condition_is_compared_by_its_literal_name():
    """Code asks the registry entry (``takes_actions``, ``is_video_condition``), never ``== "latent_action"``."""
    found = []
    for path in sorted(CORE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare) and any(isinstance(op, (ast.Eq, ast.NotEq)) for op in node.ops):
                values = [node.left, *node.comparators]
                if any(isinstance(v, ast.Constant) and v.value == "latent_action" for v in values):
                    found.append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert found == []
