"""The house rules of docs/architecture.md: imports go down the floors, never up, and never in a loop; the
top level of oscar_core holds only the modules named here.

The floors are read from the folders: every package folder of oscar_core (and the two sibling import packages
oscar_zoo and oscar_embodiments) belongs to exactly one floor of ``FLOORS``, and a module's floor is its folder's --
a sub-command's ``cli``, ``cli_*`` or ``__main__`` module included: it may import its own floor and those below,
so ``oscar eval closed-loop`` (evaluation) does not reach up into the toy world, nor ``oscar rollout`` (model) into
the zoo. The few modules at oscar_core's top level are listed one by one (``TOP_LEVEL``); ``oscar_core.cli`` (which
assembles every sub-command), ``demo`` and ``testing`` are the top floor. A new top-level module or a new folder
with no floor fails the test.

Every ``import`` is read from the source (including imports inside functions, which are real dependencies even when
deferred) and resolved to the module it names. Imports under ``if TYPE_CHECKING:`` count for the floors too (a type
in a signature is a dependency of the interface: ``kinematics.workspace`` once named the plugin's ``Embodiment``
that way) but not for loops (they never run). The checker is tested on a made-up package too, so a broken checker
cannot pass silently.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from _paths import REPO

PACKAGES = {"oscar_core": REPO / "oscar_core", "oscar_zoo": REPO / "zoo", "oscar_embodiments": REPO / "embodiments"}

#: Bottom to top; each floor names its folders (packages of oscar_core, or a sibling import package) and the
#: top-level modules of oscar_core that sit on it. A module may import its own floor and the floors below.
FLOORS: list[tuple[str, tuple[str, ...]]] = [
    ("base", ("_util", "errors", "__init__")),  # helpers, error types; the flat API imports its names lazily
    ("camera", ("camera",)),
    ("kinematics", ("kinematics",)),
    ("plugin", ("plugin", "embodiment", "hookspecs", "trajectory", "urdf")),  # the contract + its public paths
    ("embodiments", ("oscar_embodiments",)),
    ("policy", ("policy",)),  # the policy protocol, action spaces and IK, remote policies
    ("media", ("media",)),
    ("render", ("render",)),
    ("calibration", ("calibration",)),  # cameras from 2D-3D points, and how well a camera fits a video
    ("model", ("model",)),
    ("zoo", ("oscar_zoo",)),
    ("metrics", ("metrics",)),
    ("train", ("train",)),
    ("data", ("data",)),
    ("evaluation", ("evaluation",)),
    ("toyworld", ("toyworld",)),
    ("envs", ("envs",)),  # Gymnasium environments over the closed loop (the world model or the toy simulator)
    ("viz", ("viz",)),  # episodes, clips, rollouts and evaluation cells logged into Rerun
    ("cli", ("cli", "demo", "testing")),  # oscar_core.cli assembles the sub-commands; each folder's cli is its own
]

#: The only modules allowed at oscar_core's top level (everything else lives in a folder of ``FLOORS``).
TOP_LEVEL = {"__init__", "cli", "demo", "errors", "embodiment", "trajectory", "urdf", "hookspecs"}

#: Folders of oscar_core that hold no Python (package data).
DATA_FOLDERS = {"templates", "__pycache__"}

#: Upward imports kept on purpose, each with its reason. Keep this list short.
ALLOWED_UPWARD: dict[tuple[str, str], str] = {
    (
        "oscar_core.model.text_encoder",
        "oscar_zoo._fetch",
    ): "TextEncoder.from_hub (public API) downloads through the zoo's verified Hub fetcher",
    (
        "oscar_core.model.rollout_files",
        "oscar_zoo",
    ): "run_rollout (the Python twin of oscar rollout) loads its model by zoo name, Hub id or folder",
}


def is_cli(module: str) -> bool:
    """A command-line module: ``cli``, ``cli_*`` or ``__main__`` (these sit on the top floor wherever they are)."""
    last = module.rsplit(".", 1)[-1]
    return last in ("cli", "__main__") or last.startswith("cli_")


def unit_of(module: str, root: str = "oscar_core") -> str:
    """The name a floor lists for ``module``: its folder under ``root`` (``oscar_core.render.raster`` -> ``render``),
    its own name at ``root``'s top level (``oscar_core.errors`` -> ``errors``; ``oscar_core`` -> ``__init__``), or
    its import package when outside ``root`` (``oscar_zoo._hub`` -> ``oscar_zoo``)."""
    parts = module.split(".")
    if parts[0] != root:
        return parts[0]
    return parts[1] if len(parts) > 1 else "__init__"


def layer_of(module: str, floors=FLOORS, root: str = "oscar_core") -> int:
    """Index of ``module``'s floor in ``floors`` (0 = bottom): its folder's (a sub-command's cli module too); KeyError
    if its folder is on no floor."""
    unit = unit_of(module, root)
    for index, (_, units) in enumerate(floors):
        if unit in units:
            return index
    raise KeyError(f"{module}: its folder or name {unit!r} is on no floor of FLOORS")


def top_level_strays(folder: Path, floors=FLOORS, allowed=TOP_LEVEL, data_folders=DATA_FOLDERS) -> list[str]:
    """Entries of the package ``folder``'s top level that break the layout: a module outside ``allowed``, a folder
    with Python in it that is on no floor, a folder named on a floor that is a module, or a non-package folder."""
    on_floors = {unit for _, units in floors for unit in units}
    bad = []
    for entry in sorted(folder.iterdir()):
        if entry.is_file() and entry.suffix == ".py" and entry.stem not in allowed:
            bad.append(f"{entry.name}: a module at the top level outside the allowed set {sorted(allowed)}")
        elif entry.is_dir() and entry.name not in data_folders:
            if entry.name not in on_floors:
                bad.append(f"{entry.name}/: a folder on no floor (add it to FLOORS, or move its modules into one)")
            elif not (entry / "__init__.py").is_file():
                bad.append(f"{entry.name}/: a folder on a floor without an __init__.py")
    return bad


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


def import_graph(packages: dict[str, Path], annotations: bool = False) -> dict[str, set[str]]:
    """{module: modules of ``packages`` it imports}, with relative imports resolved and names of
    submodules (``from pkg import mod``) counted as imports of those submodules; ``annotations``: imports under
    ``if TYPE_CHECKING:`` too (they name types, and never run), but for a package's ``__init__``, where they mirror
    the lazy flat API for type checkers (at run time its exports are strings, :mod:`oscar_core._util.lazy`)."""
    files = module_files(packages)
    graph: dict[str, set[str]] = {m: set() for m in files}

    def known(name: str) -> str | None:
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name or None

    def runtime_nodes(tree, typed: bool):
        """Every node; without ``typed``, not those under ``if TYPE_CHECKING:`` (never imported at run time)."""
        todo = [tree]
        while todo:
            node = todo.pop()
            yield node
            for child in ast.iter_child_nodes(node):
                if not typed and isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                    todo.extend(child.orelse)
                else:
                    todo.append(child)

    for module, path in files.items():
        is_package = path.name == "__init__.py"
        for node in runtime_nodes(ast.parse(path.read_text(), str(path)), annotations and not is_package):
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


def upward_imports(graph, floors=FLOORS, allowed=ALLOWED_UPWARD, root: str = "oscar_core") -> list[str]:
    bad = []
    for module, targets in sorted(graph.items()):
        for target in sorted(targets):
            low, high = layer_of(module, floors, root), layer_of(target, floors, root)
            if high > low and (module, target) not in allowed:
                bad.append(f"{module} ({floors[low][0]}) imports {target} ({floors[high][0]})")
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


def sub_cli_imports(graph, top: str = "oscar_core.cli") -> list[str]:
    """A package's CLI module importing another package's CLI module (only ``top`` assembles them)."""

    def sub_cli(m):
        return m != top and is_cli(m)

    return [
        f"{m} imports {t}"
        for m, ts in sorted(graph.items())
        if sub_cli(m)
        for t in sorted(ts)
        if sub_cli(t) and t.rsplit(".", 1)[0] != m.rsplit(".", 1)[0]
    ]


@pytest.fixture(scope="module")
def graph():
    return import_graph(PACKAGES)


@pytest.fixture(scope="module")
def typed_graph():
    """The graph with the imports under ``if TYPE_CHECKING:``: what the floors are checked on."""
    return import_graph(PACKAGES, annotations=True)


def test_every_module_is_on_a_floor(graph):
    for module in graph:
        layer_of(module)


def test_the_top_level_holds_only_the_allowed_modules_and_floor_folders():
    assert top_level_strays(PACKAGES["oscar_core"]) == []


def test_the_architecture_page_draws_every_floor():
    diagram = (REPO / "docs" / "architecture.md").read_text().split("```")[1]
    drawn = [line.split()[0] for line in diagram.splitlines() if line[:1] == " " and line.split()[0].isidentifier()]
    assert drawn == [name for name, _ in FLOORS][::-1]


#: Test folders beside the floors' own: the command line, and checks of the repository as a whole (layers, docs,
#: packaging, benchmarks); ``typing`` holds the type-checked example, ``golden`` folders the reference images.
TEST_FOLDERS_BESIDE_FLOORS = {"cli", "project", "typing", "__pycache__"}


def test_tests_are_organised_by_floor():
    tests = REPO / "tests"
    assert sorted(p.name for p in tests.glob("test_*.py")) == [], "a test module belongs in its floor's folder"
    folders = {p.name for p in tests.iterdir() if p.is_dir()}
    assert folders - {name for name, _ in FLOORS} - TEST_FOLDERS_BESIDE_FLOORS == set()


def test_every_floor_names_something_that_exists():
    # a stale entry would let a new module of that name in unnoticed
    units = {unit_of(module) for module in module_files(PACKAGES)}
    assert {unit for _, names in FLOORS for unit in names} <= units


def test_no_lower_layer_imports_a_higher_one(typed_graph):
    assert upward_imports(typed_graph) == []


def test_no_import_loops(graph):
    # package __init__ files only name their exports as strings (oscar_core._util.lazy), so they take no part
    assert cycles(graph) == []


def test_only_the_top_cli_assembles_sub_commands(graph):
    assert sub_cli_imports(graph) == []
    assert {"oscar_core.metrics.cli", "oscar_core.evaluation.cli", "oscar_core.data.cli"} <= graph["oscar_core.cli"]


def test_allowed_upward_imports_still_exist(typed_graph):
    # a stale exception would let the same upward import come back unnoticed elsewhere
    for module, target in ALLOWED_UPWARD:
        assert target in typed_graph[module], f"{module} no longer imports {target}: drop it from ALLOWED_UPWARD"


def make_package(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return root


def test_the_checker_finds_an_upward_import_a_loop_and_a_cli_reaching_sideways(tmp_path):
    pkg = make_package(
        tmp_path / "pkg",
        {
            "__init__.py": "if TYPE_CHECKING:\n    from .high.b import B\n",  # a lazy flat API's names: not counted
            "cli.py": "from .high import cli\n",
            "low/__init__.py": "",
            "low/a.py": "def f():\n    from ..high.b import g\n",  # upward, deferred in a function
            "low/cli.py": "from ..high import b\n",  # a sub-command's cli reaching above its folder's floor
            "low/typed.py": "if TYPE_CHECKING:\n    from ..high.b import B\n",  # upward in an annotation only
            "high/__init__.py": "",
            "high/b.py": "from ..low import a\n",  # closes a loop a -> b -> a
            "high/cli.py": "from ..side.cli import x\n",  # one sub-CLI importing another
            "side/__init__.py": "",
            "side/cli.py": "import pkg.low.a\nif TYPE_CHECKING:\n    from ..high import b\n",
        },
    )
    floors = [("low", ("low", "__init__")), ("high", ("high", "side")), ("cli", ("cli",))]
    g = import_graph({"pkg": pkg})
    assert g["pkg.low.a"] == {"pkg.high.b"} and g["pkg.side.cli"] == {"pkg.low.a"} and g["pkg.low.typed"] == set()
    typed = import_graph({"pkg": pkg}, annotations=True)
    assert typed["pkg.side.cli"] == {"pkg.low.a", "pkg.high", "pkg.high.b"} and typed["pkg.low.typed"] == {"pkg.high.b"}
    # the floor comes from the folder, a sub-command's cli module included; the package's own cli is the top
    assert [layer_of(m, floors, "pkg") for m in ("pkg", "pkg.low.a", "pkg.low.cli", "pkg.high.cli", "pkg.cli")] == [
        0,
        0,
        0,
        1,
        2,
    ]
    assert upward_imports(g, floors, {}, "pkg") == [
        "pkg.low.a (low) imports pkg.high.b (high)",
        "pkg.low.cli (low) imports pkg.high (high)",
        "pkg.low.cli (low) imports pkg.high.b (high)",
    ]
    assert upward_imports(typed, floors, {("pkg.low.a", "pkg.high.b"): "reason"}, "pkg") == [
        "pkg.low.cli (low) imports pkg.high (high)",
        "pkg.low.cli (low) imports pkg.high.b (high)",
        "pkg.low.typed (low) imports pkg.high.b (high)",
    ]
    # the same imports are allowed once the folders share a floor: the rule is the folders' order, nothing else
    assert upward_imports(typed, [("all", ("low", "high", "side", "__init__")), ("cli", ("cli",))], {}, "pkg") == []
    assert cycles(g) == [["pkg.high.b", "pkg.low.a"]]
    assert sub_cli_imports(g, top="pkg.cli") == ["pkg.high.cli imports pkg.side.cli"]


def test_the_checker_finds_a_stray_top_level_module_and_a_folder_on_no_floor(tmp_path):
    pkg = make_package(
        tmp_path / "pkg",
        {
            "__init__.py": "",
            "errors.py": "",
            "cli.py": "",
            "low/__init__.py": "",
            "low/a.py": "",
            "helpers.py": "",  # a new top-level module
            "extra/__init__.py": "",
            "extra/m.py": "",  # a new folder that no floor names
            "loose/m.py": "",  # a floor's folder that is not a package
            "templates/page.html.j2": "",  # package data: allowed
        },
    )
    floors = [("low", ("low", "loose", "errors", "__init__")), ("cli", ("cli",))]
    allowed = {"__init__", "errors", "cli"}
    assert top_level_strays(pkg, floors, allowed, {"templates"}) == [
        "extra/: a folder on no floor (add it to FLOORS, or move its modules into one)",
        "helpers.py: a module at the top level outside the allowed set ['__init__', 'cli', 'errors']",
        "loose/: a folder on a floor without an __init__.py",
    ]
    assert top_level_strays(pkg, floors + [("extra", ("extra",))], allowed | {"helpers"}, {"templates", "loose"}) == []
    with pytest.raises(KeyError, match="'extra' is on no floor"):
        layer_of("pkg.extra.m", floors, "pkg")
    with pytest.raises(KeyError, match="'helpers' is on no floor"):
        layer_of("pkg.helpers", floors, "pkg")


#: the import paths that plugins and the docs use, with the module that holds their names
PUBLIC_PATHS = {
    "oscar_core.camera": None,
    "oscar_core.trajectory": "oscar_core.kinematics.trajectory",
    "oscar_core.urdf": "oscar_core.kinematics.urdf",
    "oscar_core.embodiment": "oscar_core.plugin.embodiment",
    "oscar_core.hookspecs": "oscar_core.plugin.hookspecs",
}
CAMERA_NAMES = {
    "CONVENTIONS",
    "CONVENTION_ALIASES",
    "DIRECTIONS",
    "Intrinsics",
    "Camera",
    "Projection",
    "canonical_convention",
    "as_rigid_transform",
    "as_rigid_transforms",
    "look_at",
    "convention_to_opencv",
    "project",
    "project_points_cv",
    "load_camera",
    "save_camera",
    "camera_from_dict",
    "camera_to_dict",
}


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


def test_every_package_is_in_the_distribution():
    # an installed oscar (pip install, not an editable checkout) holds only the packages pyproject lists
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    listed = set(tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(REPO).parts) for p in (REPO / "oscar_core").rglob("__init__.py")}
    assert found - listed == set()
