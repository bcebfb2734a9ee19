"""The house rules of docs/architecture.md: imports go down the layers, never up, and never in a loop.

Every ``import`` in oscar_core, oscar_zoo and oscar_embodiments is read from the
source (including imports inside functions, which are real dependencies even when
deferred; only imports under ``if TYPE_CHECKING:`` are left out), resolved to the
module it names, and checked against the layer table below. The checker is tested
on a made-up package too, so a broken checker cannot pass silently.
"""

from __future__ import annotations

import ast
import fnmatch
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = {"oscar_core": ROOT / "oscar_core", "oscar_zoo": ROOT / "zoo", "oscar_embodiments": ROOT / "embodiments"}

#: Bottom to top. A module belongs to the first layer with a matching pattern (fnmatch on the
#: dotted name); it may import its own layer and the layers below, never one above.
LAYERS: list[tuple[str, list[str]]] = [
    ("cli", ["oscar_core.cli", "oscar_core.demo", "oscar_core.render.cli", "oscar_core.*.cli",
             "oscar_core.*.cli_*", "oscar_core.train.__main__"]),
    ("toyworld", ["oscar_core.toyworld", "oscar_core.toyworld.*"]),
    ("evaluation", ["oscar_core.evaluation", "oscar_core.evaluation.*"]),
    ("data", ["oscar_core.data", "oscar_core.data.*"]),
    ("train", ["oscar_core.train", "oscar_core.train.*"]),
    ("metrics", ["oscar_core.metrics", "oscar_core.metrics.*"]),
    ("zoo", ["oscar_zoo", "oscar_zoo.*"]),
    ("model", ["oscar_core.model", "oscar_core.model.*"]),
    ("calibration", ["oscar_core.calibration", "oscar_core.calibration.*"]),
    ("render", ["oscar_core.render", "oscar_core.render.*", "oscar_core.media", "oscar_core.media.*"]),
    ("embodiments", ["oscar_embodiments", "oscar_embodiments.*"]),
    ("foundation", ["oscar_core", "oscar_core.*"]),
][::-1]

#: Upward imports kept on purpose, each with its reason. Keep this list short.
ALLOWED_UPWARD: dict[tuple[str, str], str] = {
    ("oscar_core.model.text_encoder", "oscar_zoo._fetch"):
        "TextEncoder.from_hub (public API) downloads through the zoo's verified Hub fetcher",
    ("oscar_core.model.rollout_files", "oscar_zoo"):
        "run_rollout (the Python twin of oscar rollout) loads its model by zoo name, Hub id or folder",
}


def layer_of(module: str, layers=LAYERS) -> int:
    """Index of ``module``'s layer in ``layers`` (0 = bottom); KeyError if no pattern matches."""
    for index in range(len(layers) - 1, -1, -1):  # most specific (top) first: 'oscar_core.*.cli' before 'oscar_core.*'
        if any(fnmatch.fnmatchcase(module, pattern) for pattern in layers[index][1]):
            return index
    raise KeyError(f"{module}: in no layer of the table")


def module_files(packages: dict[str, Path]) -> dict[str, Path]:
    """{dotted module name: file} for every .py file of ``packages`` (a package is its ``__init__``)."""
    out = {}
    for name, folder in packages.items():
        for path in folder.rglob("*.py"):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join([name] + parts)] = path
    return out


def import_graph(packages: dict[str, Path]) -> dict[str, set[str]]:
    """{module: modules of ``packages`` it imports}, with relative imports resolved and names of
    submodules (``from pkg import mod``) counted as imports of those submodules."""
    files = module_files(packages)
    graph: dict[str, set[str]] = {m: set() for m in files}

    def known(name: str) -> str | None:
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name or None

    def runtime_nodes(tree):
        """Every node but those under ``if TYPE_CHECKING:`` (annotations only, never imported at run time)."""
        todo = [tree]
        while todo:
            node = todo.pop()
            yield node
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                    todo.extend(child.orelse)
                else:
                    todo.append(child)

    for module, path in files.items():
        is_package = path.name == "__init__.py"
        for node in runtime_nodes(ast.parse(path.read_text(), str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = module.split(".") if is_package else module.split(".")[:-1]
                    base = base[: len(base) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                targets = [target] + [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in files]
            for target in targets:
                found = known(target) if target.split(".")[0] in packages else None
                if found and found != module:
                    graph[module].add(found)
    return graph


def upward_imports(graph, layers=LAYERS, allowed=ALLOWED_UPWARD) -> list[str]:
    bad = []
    for module, targets in sorted(graph.items()):
        for target in sorted(targets):
            if layer_of(target, layers) > layer_of(module, layers) and (module, target) not in allowed:
                bad.append(f"{module} ({layers[layer_of(module, layers)][0]}) imports {target} "
                           f"({layers[layer_of(target, layers)][0]})")
    return bad


def cycles(graph) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def sub_cli_imports(graph) -> list[str]:
    """A package's CLI module importing another package's CLI module (only oscar_core.cli assembles them)."""
    def is_cli(m):
        return m != "oscar_core.cli" and (m.endswith(".cli") or ".cli_" in m)

    return [f"{m} imports {t}" for m, ts in sorted(graph.items()) if is_cli(m) for t in sorted(ts)
            if is_cli(t) and t.rsplit(".", 1)[0] != m.rsplit(".", 1)[0]]


@pytest.fixture(scope="module")
def graph():
    return import_graph(PACKAGES)


def test_every_module_is_in_a_layer(graph):
    for module in graph:
        layer_of(module)


def test_no_lower_layer_imports_a_higher_one(graph):
    assert upward_imports(graph) == []


def test_no_import_loops(graph):
    # package __init__ files only name their exports as strings (oscar_core._util.lazy), so they take no part
    assert cycles(graph) == []


def test_only_the_top_cli_assembles_sub_commands(graph):
    assert sub_cli_imports(graph) == []
    assert {"oscar_core.metrics.cli", "oscar_core.evaluation.cli", "oscar_core.data.cli"} <= graph["oscar_core.cli"]


def test_allowed_upward_imports_still_exist(graph):
    # a stale exception would let the same upward import come back unnoticed elsewhere
    for module, target in ALLOWED_UPWARD:
        assert target in graph[module], f"{module} no longer imports {target}: drop it from ALLOWED_UPWARD"


def test_the_checker_finds_an_upward_import_a_loop_and_a_cli_reaching_sideways(tmp_path):
    pkg = tmp_path / "pkg"
    for rel, text in {
        "__init__.py": "",
        "low.py": "def f():\n    from .high import g\n",          # upward, and deferred inside a function
        "high.py": "from . import low\n",                             # closes a loop low -> high -> low
        "a/__init__.py": "", "a/cli.py": "from ..b.cli import x\n",   # one sub-CLI importing another
        "b/__init__.py": "", "b/cli.py": "import pkg.low\nif TYPE_CHECKING:\n    from .. import high\n",
    }.items():
        (pkg / rel).parent.mkdir(parents=True, exist_ok=True)
        (pkg / rel).write_text(text)
    layers = [("low", ["pkg.low", "pkg", "pkg.a", "pkg.b"]), ("high", ["pkg.high"]), ("cli", ["pkg.*.cli"])]
    g = import_graph({"pkg": pkg})
    assert g["pkg.low"] == {"pkg.high"} and g["pkg.b.cli"] == {"pkg.low"}
    assert upward_imports(g, layers, {}) == ["pkg.low (low) imports pkg.high (high)"]
    assert upward_imports(g, layers, {("pkg.low", "pkg.high"): "reason"}) == []
    assert cycles(g) == [["pkg.high", "pkg.low"]]
    assert [s.replace("pkg.", "") for s in sub_cli_imports({"pkg.a.cli": {"pkg.b.cli"}, "pkg.b.cli": set()})] \
        == ["a.cli imports b.cli"]


#: the import paths that plugins and the docs use, with the module that holds their names
PUBLIC_PATHS = {"oscar_core.camera": None, "oscar_core.trajectory": "oscar_core.kinematics.trajectory",
                "oscar_core.urdf": "oscar_core.kinematics.urdf", "oscar_core.embodiment": "oscar_core.plugin.embodiment",
                "oscar_core.hookspecs": "oscar_core.plugin.hookspecs"}
CAMERA_NAMES = {"CONVENTIONS", "CONVENTION_ALIASES", "DIRECTIONS", "Intrinsics", "Camera", "Projection",
                "canonical_convention", "as_rigid_transform", "as_rigid_transforms", "look_at", "convention_to_opencv",
                "project", "project_points_cv", "load_camera", "save_camera", "camera_from_dict", "camera_to_dict"}


@pytest.mark.parametrize("path", sorted(PUBLIC_PATHS))
def test_public_import_paths_keep_working(path):
    import importlib

    public = importlib.import_module(path)
    names = set(public.__all__)
    if PUBLIC_PATHS[path] is None:
        assert names == CAMERA_NAMES
    else:
        home = importlib.import_module(PUBLIC_PATHS[path])
        assert names == set(home.__all__) and names
        assert all(getattr(public, n) is getattr(home, n) for n in names)
    assert all(getattr(public, n) is not None for n in names)


def test_every_name_of_the_flat_api_imports():
    import oscar_core

    assert len(oscar_core.__all__) == len(set(oscar_core.__all__)) > 30
    for name in oscar_core.__all__:
        namespace: dict = {}
        exec(f"from oscar_core import {name}", namespace)  # the spelling users write
        assert namespace[name] is getattr(oscar_core, name)
