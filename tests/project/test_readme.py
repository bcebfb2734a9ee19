"""The README is a front door: small, complete about installing, with links that resolve and a tour that runs.

The tour test runs the README's "A five-minute tour" commands exactly as printed (every line of its ```bash
blocks, in order, in a scratch folder that stands for the clone's root), each of which must exit 0 without a
traceback.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import tomllib
from _paths import REPO

README = REPO / "README.md"
DOCS = REPO / "docs"
MAX_BYTES = 12 * 1024

#: phrases about the project's own past, which have no place on its front door or in its docs' new pages
HISTORY = re.compile(r"\bissue \d+|\bthe old default|\bused to\b|\bin an earlier run|\bbefore this work", re.I)


def section(text: str, title: str) -> str:
    """The body of the ``## title`` section of markdown ``text`` (up to the next ``## ``)."""
    match = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text, re.M | re.S)
    assert match, f"README.md: expected a section '## {title}', found none"
    return match.group(1)


def bash_blocks(markdown: str) -> list[str]:
    """The command lines of every ```bash block, in order (blank lines and comments left out)."""
    lines = []
    for block in re.findall(r"^```bash\n(.*?)^```", markdown, re.M | re.S):
        lines += [line for line in block.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    return lines


def links(markdown: str) -> list[str]:
    return [t for t in re.findall(r"\]\(([^)\s]+)\)", markdown) if not re.match(r"[a-z]+:", t)]


def extras() -> set[str]:
    return set(tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"])


def test_the_readme_is_at_most_12_kb():
    assert README.stat().st_size <= MAX_BYTES, f"README.md is {README.stat().st_size} bytes, over {MAX_BYTES}"


def test_the_install_line_and_the_extras_table_name_every_extra():
    text = README.read_text()
    line = re.search(r'pip install "oscar-wm\[([a-z,]+)\]"', text)
    assert line, 'README.md: expected a line pip install "oscar-wm[…]"'
    assert set(line.group(1).split(",")) == extras() - {"dev"}
    table = set(re.findall(r"^\| `([a-z]+)` \| ", section(text, "Install"), re.M))
    assert table == extras()


def test_the_readme_says_nothing_about_the_projects_history():
    assert HISTORY.findall(README.read_text()) == []
    for page in [
        "index.md",
        "benchmarks.md",
        "rendering.md",
        "cli.md",
        "architecture.md",
        *(f"studies/{p.name}" for p in (DOCS / "studies").glob("*.md")),
    ]:
        assert HISTORY.findall((DOCS / page).read_text()) == [], page


@pytest.mark.parametrize("page", [README, *sorted(DOCS.rglob("*.md"))], ids=lambda p: str(p.relative_to(REPO)))
def test_relative_links_resolve(page):
    for target in links(page.read_text()):
        path = target.split("#")[0]
        if path:
            assert (page.parent / path).exists(), f"{page.relative_to(REPO)}: a link to {target}, which does not exist"


def test_the_docs_index_maps_every_page():
    listed = {(DOCS / t.split("#")[0]).resolve() for t in links((DOCS / "index.md").read_text())}
    pages = {p.resolve() for p in DOCS.rglob("*.md")} - {(DOCS / "index.md").resolve()}
    assert sorted(str(p.relative_to(DOCS)) for p in pages - listed) == []


def test_the_checks_notice_a_missing_extra_and_a_history_phrase():
    text = 'pip install "oscar-wm[mano]"'
    assert set(re.search(r'pip install "oscar-wm\[([a-z,]+)\]"', text).group(1).split(",")) != extras() - {"dev"}
    assert HISTORY.findall("as issue 23 asked, unlike the old default") == ["issue 23", "the old default"]
    assert bash_blocks("```bash\n# a comment\noscar a\n\noscar b --x\n```\n```console\noscar c\n```\n") == [
        "oscar a",
        "oscar b --x",
    ]


@pytest.mark.slow
def test_the_tour_runs_as_printed(tmp_path):
    bin_dir = Path(sys.executable).parent
    env = {
        **os.environ,
        "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}",
        "OSCAR_DISABLE_PROGRESS_BARS": "1",
    }
    (tmp_path / "examples").symlink_to(REPO / "examples")  # the scratch folder stands for the clone's root
    commands = bash_blocks(section(README.read_text(), "A five-minute tour"))
    assert len(commands) >= 5
    for command in commands:
        proc = subprocess.run(shlex.split(command), cwd=tmp_path, env=env, capture_output=True, text=True, timeout=1800)
        assert proc.returncode == 0 and "Traceback" not in proc.stderr, (
            f"README tour: {command}\nexit {proc.returncode}\n{proc.stderr[-3000:]}"
        )
        # a newcomer's first commands print no warning (progress and timing lines are fine)
        assert not re.search(r"(?i)warn", proc.stderr), f"README tour: {command} warned:\n{proc.stderr[-3000:]}"
    for made in ("skeleton.mp4", "toy_rollout.mp4", "cl_wm/report.html", "cl_sim/report.json", "toy_eval/report.html"):
        assert (tmp_path / made).is_file(), f"README tour: {made} was not written"
