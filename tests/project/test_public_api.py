"""The flat public API: what type checkers see equals what runs, and the typed example runs.

``oscar_core/__init__.py`` exports its names lazily (``_EXPORTS``: name -> submodule) and repeats them as imports
under ``if TYPE_CHECKING:`` for type checkers; the two must name the same objects. ``tests/typing/public_api.py``
is the file .ci/run type-checks with mypy; here it runs.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import re

import pytest
from _paths import REPO

import oscar_core


def type_checking_imports(source: str) -> dict[str, str]:
    """{name: submodule} imported under ``if TYPE_CHECKING:`` in ``source`` (a package ``__init__``), with the
    submodule relative to the package (``from .camera.pinhole import Camera`` -> ``{"Camera": "camera.pinhole"}``)."""
    out: dict[str, str] = {}
    for node in ast.parse(source).body:
        if isinstance(node, ast.If) and ast.unparse(node.test) == "TYPE_CHECKING":
            for stmt in node.body:
                assert isinstance(stmt, ast.ImportFrom) and stmt.level == 1, ast.unparse(stmt)
                for alias in stmt.names:
                    assert alias.asname in (None, alias.name), f"{alias.name} imported as {alias.asname}"
                    assert alias.name not in out, f"{alias.name} imported twice"
                    out[alias.name] = stmt.module or ""
    return out


def test_type_checkers_see_exactly_the_lazy_exports():
    seen = type_checking_imports((REPO / "oscar_core" / "__init__.py").read_text())
    assert seen == oscar_core._EXPORTS


def test_the_comparison_notices_a_missing_or_moved_name():
    source = "if TYPE_CHECKING:\n    from .camera.pinhole import Camera as Camera\n    from .errors import OscarError\n"
    assert type_checking_imports(source) == {"Camera": "camera.pinhole", "OscarError": "errors"}
    assert type_checking_imports(source) != {"Camera": "camera.geometry", "OscarError": "errors"}
    assert type_checking_imports(source) != {"Camera": "camera.pinhole"}


def test_the_typed_example_runs(tmp_path):
    spec = importlib.util.spec_from_file_location("public_api", REPO / "tests" / "typing" / "public_api.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    from oscar_core.media.video import read_video

    out = module.render_example(tmp_path, frames=2)
    assert out == tmp_path / "skeleton.mp4" and read_video(out).shape[:3] == (2, 96, 128)
    pose = module.camera_pose()
    assert pose.shape == (4, 4) and abs(pose[:3, 2] @ [-1.5, 0.0, -0.3] / (1.5**2 + 0.3**2) ** 0.5 - 1) < 1e-12


# ----------------------------------------------------------------------------- the listed API and its deprecations
#: the packages whose ``__all__`` is the public API (docs/api.md has one section each): oscar_core, oscar_zoo, every
#: package of oscar_core whose ``__init__`` declares ``__all__`` (not ``_``-prefixed) and every built-in embodiment
PUBLIC_PACKAGES = (
    "oscar_core",
    "oscar_zoo",
    *sorted(
        f"oscar_core.{p.parent.name}"
        for p in (REPO / "oscar_core").glob("*/__init__.py")
        if not p.parent.name.startswith("_") and "__all__" in p.read_text()
    ),
    *sorted(f"oscar_embodiments.{p.parent.name}" for p in (REPO / "embodiments").glob("*/__init__.py")),
)


def listed_names(page: str) -> dict[str, list[str]]:
    """{package: names} from the ``## `package` `` sections of docs/api.md (the code spans of the paragraph)."""
    out = {}
    for block in page.split("\n## ")[1:]:
        head, _, body = block.partition("\n")
        if head.startswith("`") and head.endswith("`"):
            out[head.strip("`")] = re.findall(r"`([^`]+)`", body.strip().split("\n\n")[0])
    return out


def deprecated_rows(page: str) -> list[tuple[str, str, str, str]]:
    """(name, use instead, deprecated in, removed in) of docs/api.md's Deprecated table, code spans unwrapped."""
    section = page.split("\n## Deprecated\n", 1)[1].split("\n## ", 1)[0]
    rows = [line.strip("|").split("|") for line in section.splitlines() if line.startswith("| `")]
    return [tuple(cell.strip().strip("`") for cell in row) for row in rows]


def test_the_api_page_lists_exactly_each_package_s_public_names():
    listed = listed_names((REPO / "docs" / "api.md").read_text())
    assert sorted(listed) == sorted(PUBLIC_PACKAGES)
    for package in PUBLIC_PACKAGES:
        assert listed[package] == sorted(importlib.import_module(package).__all__), (
            f"docs/api.md, section {package}: update it (and CHANGELOG.md) with the package's __all__"
        )


def test_every_public_name_resolves():
    for package in PUBLIC_PACKAGES:
        module = importlib.import_module(package)
        missing = [name for name in module.__all__ if not hasattr(module, name)]
        assert missing == [], f"{package} lists names it cannot give: {missing}"


def test_the_page_reader_sees_a_missing_name_and_the_deprecated_table():
    page = "intro\n\n## Deprecated\n\n| name | use |\n|---|---|\n| `a.B.c()` | `a.d(x)` | 0.2.0 | 0.3.0 |\n\n"
    page += "## `a`\n\n`x`, `y`\n\n## `a.b`\n\n`z`\n"
    assert listed_names(page) == {"a": ["x", "y"], "a.b": ["z"]}
    assert deprecated_rows(page) == [("a.B.c()", "a.d(x)", "0.2.0", "0.3.0")]


def _camera():
    from oscar_core import load_camera

    return load_camera(REPO / "examples" / "oscar-toyarm" / "oscar_toyarm" / "assets" / "example_camera.json")


def _old_and_new(name: str):
    """(use through the deprecated name, the same use through its replacement) for each row of docs/api.md's
    Deprecated table: two functions of no arguments whose results are equal."""
    from oscar_core.camera import Camera, camera_from_dict, camera_to_dict

    cam = _camera()
    return {
        "oscar_core.Camera.from_dict(d)": (
            lambda: camera_to_dict(Camera.from_dict(camera_to_dict(cam))),
            lambda: camera_to_dict(camera_from_dict(camera_to_dict(cam))),
        ),
        "oscar_core.Camera.to_dict()": (lambda: cam.to_dict(), lambda: camera_to_dict(cam)),
        "oscar_core.train.LatentActionTransformer": (
            lambda: importlib.import_module("oscar_core.train").LatentActionTransformer,
            lambda: importlib.import_module("oscar_core.model").LatentActionTransformer,
        ),
        "oscar_core.train.latent_actions": (
            lambda: importlib.import_module("oscar_core.train").latent_actions,
            lambda: importlib.import_module("oscar_core.model").latent_actions,
        ),
    }[name]


def test_each_deprecated_name_still_works_and_warns_naming_its_replacement_and_the_changelog_lists_it():
    from oscar_core import OscarDeprecationWarning

    changelog = (REPO / "CHANGELOG.md").read_text()
    deprecated = changelog.split("### Deprecated\n", 1)[1].split("\n### ", 1)[0].split("\n## ", 1)[0]
    rows = deprecated_rows((REPO / "docs" / "api.md").read_text())
    assert rows
    for name, instead, since, removed_in in rows:
        short = name.removeprefix("oscar_core.") if name.startswith("oscar_core.Camera.") else name
        assert f"`{short}`" in deprecated and f"`{instead}`" in deprecated, f"CHANGELOG.md: {name} -> {instead}"
        old, new = _old_and_new(name)
        with pytest.warns(OscarDeprecationWarning) as caught:
            got = old()
        assert got == new()
        messages = [str(w.message) for w in caught]
        assert any(instead in m and since in m and removed_in in m for m in messages), (name, messages)
        assert all(w.filename == __file__ for w in caught)  # the warning points at the caller's line


def test_deprecated_names_stay_out_of_the_listed_api():
    import oscar_core.train

    assert "LatentActionTransformer" not in oscar_core.train.__all__
    assert "LatentActionTransformer" not in dir(oscar_core.train)


def versions() -> dict[str, str]:
    import tomllib

    changelog = (REPO / "CHANGELOG.md").read_text()
    top = re.search(r"^## \[(?!Unreleased)([^\]]+)\]", changelog, re.MULTILINE)
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    return {"changelog": top.group(1) if top else None, "pyproject": project, "oscar_core": oscar_core.__version__}


def test_the_changelog_s_top_version_is_the_package_version():
    found = versions()
    assert found["changelog"] == found["pyproject"] == found["oscar_core"], found
