"""oscar's distribution is ``oscar-wm``: nothing may tell users or plugins to install ``oscar``.

``oscar`` on the package index is an unrelated project (docs/write-a-plugin.md,
"Depend on oscar-wm, never on oscar"). These checks read the repository's
own files, so a new ``pip install "oscar[extra]"`` message or a plugin that
depends on ``oscar`` fails here rather than sending a user to the other project.
"""

import re
from pathlib import Path

import pytest
import tomllib
from _paths import REPO

DIST = "oscar-wm"
# "oscar[...]" as a requirement or install command (not oscar-wm[...], not a Python subscript such as foo_oscar[...])
WRONG_EXTRA = re.compile(r"""(?<![\w.-])oscar\\?\[""")
SKIP_PARTS = {".git", "build", "__pycache__", ".pytest_cache", "golden-results", "demo_out"}


def repo_text_files():
    for path in REPO.rglob("*"):
        if not path.is_file() or path == Path(__file__).resolve() or SKIP_PARTS & set(path.relative_to(REPO).parts):
            continue
        if any(part.endswith(".egg-info") for part in path.parts):
            continue
        if path.suffix in (".py", ".md", ".toml", ".txt", ".cfg", ".yaml", ".yml") or path.name == "Makefile":
            yield path


def requirement_name(req: str) -> str:
    return re.split(r"[\s\[<>=!~;@(]", req.strip(), maxsplit=1)[0].lower().replace("_", "-")


def test_the_core_distribution_is_oscar_wm():
    meta = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert meta["name"] == DIST


def test_no_file_says_install_oscar_with_extras():
    bad = []
    for path in repo_text_files():
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if WRONG_EXTRA.search(line):
                bad.append(f"{path.relative_to(REPO)}:{n}: {line.strip()}")
    assert not bad, "use oscar-wm[...] (oscar on the package index is another project):\n" + "\n".join(bad)


@pytest.mark.parametrize("pyproject", sorted(str(p.relative_to(REPO)) for p in REPO.glob("examples/*/pyproject.toml")))
def test_example_plugins_depend_on_oscar_wm(pyproject):
    deps = tomllib.loads((REPO / pyproject).read_text())["project"]["dependencies"]
    names = [requirement_name(d) for d in deps]
    assert "oscar" not in names and DIST in names, deps


def test_the_plugin_guide_declares_oscar_wm():
    text = (REPO / "docs" / "write-a-plugin.md").read_text()
    block = re.search(r'```toml title="oscar-twolink/pyproject.toml"\n(.*?)```', text, re.S).group(1)
    deps = tomllib.loads(block)["project"]["dependencies"]
    assert [requirement_name(d) for d in deps] == [DIST], deps


def test_the_guard_catches_the_old_spellings():
    for line in (
        'pip install "oscar[mano]"',
        "pip install 'oscar[dev]'",
        r'match=r"pip install \"oscar\[plots\]\""',
        'dependencies = ["oscar[mano]>=0.1"]',
    ):
        assert WRONG_EXTRA.search(line), line
    for line in ('pip install "oscar-wm[mano]"', "x = my_oscar[0]", "self.oscar[k]"):
        assert not WRONG_EXTRA.search(line), line
    assert [
        requirement_name(d) for d in ("oscar", "oscar>=0.1", "oscar_wm >= 0.1", "oscar-wm[mano]; python_version>'3'")
    ] == ["oscar", "oscar", "oscar-wm", "oscar-wm"]
