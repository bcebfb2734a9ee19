"""The flat public API: what type checkers see equals what runs, and the typed example runs.

``oscar_core/__init__.py`` exports its names lazily (``_EXPORTS``: name -> submodule) and repeats them as imports
under ``if TYPE_CHECKING:`` for type checkers; the two must name the same objects. ``tests/typing/public_api.py``
is the file .ci/run type-checks with mypy; here it runs.
"""

from __future__ import annotations

import ast
import importlib.util

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
