"""The house rule on function length: no function in oscar_core is over 100 lines.

Length is counted as Python's ``ast`` gives it, ``end_lineno - lineno + 1`` (the ``def`` line to the last line of
the body, docstring and comments included, decorators not), for every ``def`` and ``async def``: methods and
functions nested inside other functions too. A long function is split where its steps are (plan / run / write).

The one exception is a function whose length is one flat table, such as a parser's options: at most
``MAX_FLAT_TABLES`` of them, each named in ``FLAT_TABLES`` and saying so in the first line of its docstring
(the words "flat table"). The checker is tested on made-up sources too, so a broken checker cannot pass silently.
"""

from __future__ import annotations

import ast
from pathlib import Path

from _paths import REPO

MAX_LINES = 100
MAX_FLAT_TABLES = 5
#: ``"path/under/oscar_core.py:qualified.name"`` of the functions allowed over ``MAX_LINES`` because their length
#: is one flat table (a parser's options); each says "flat table" in the first line of its docstring.
FLAT_TABLES: frozenset[str] = frozenset()
FLAT_TABLE_WORDS = "flat table"


def function_lengths(source: str) -> list[tuple[str, int, str]]:
    """``(qualified name, lines, first docstring line)`` of every function of a module's source, nested ones
    included (a method is ``Class.method``, a nested function ``outer.inner``)."""
    found: list[tuple[str, int, str]] = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    doc = (ast.get_docstring(child) or "").strip().splitlines()
                    found.append((name, child.end_lineno - child.lineno + 1, doc[0] if doc else ""))
                visit(child, name + ".")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return found


def too_long(sources: dict[str, str], flat_tables=frozenset(), max_lines: int = MAX_LINES) -> list[str]:
    """One line per function over ``max_lines`` in ``sources`` (path → source) that is not an allowed flat table:
    allowed means named ``path:qualified.name`` in ``flat_tables`` and saying "flat table" in its docstring's first
    line."""
    bad = []
    for path, source in sorted(sources.items()):
        for name, lines, first_doc in function_lengths(source):
            if lines <= max_lines:
                continue
            key = f"{path}:{name}"
            if key in flat_tables and FLAT_TABLE_WORDS in first_doc.lower():
                continue
            why = " (listed as a flat table, but its docstring's first line does not say so)" * (key in flat_tables)
            bad.append(f"{key}: {lines} lines{why}")
    return bad


def _oscar_core_sources() -> dict[str, str]:
    root = REPO / "oscar_core"
    return {p.relative_to(root).as_posix(): p.read_text(encoding="utf-8") for p in sorted(root.rglob("*.py"))}


def test_no_function_in_oscar_core_is_over_100_lines_but_a_few_flat_tables():
    bad = too_long(_oscar_core_sources(), FLAT_TABLES)
    assert not bad, (
        f"functions over {MAX_LINES} lines (split them where their steps are; a parser's flat table of options may "
        f"instead be listed in FLAT_TABLES, at most {MAX_FLAT_TABLES}, saying 'flat table' in its docstring's first "
        "line):\n" + "\n".join(bad)
    )


def test_the_flat_table_list_is_short_and_names_functions_that_exist_and_are_long():
    assert len(FLAT_TABLES) <= MAX_FLAT_TABLES
    sources = _oscar_core_sources()
    lengths = {
        f"{path}:{name}": lines for path, source in sources.items() for name, lines, _ in function_lengths(source)
    }
    for key in FLAT_TABLES:
        assert key in lengths, f"FLAT_TABLES names {key}, which is not a function of oscar_core"
        assert lengths[key] > MAX_LINES, f"{key} is {lengths[key]} lines: take it off FLAT_TABLES"


def _function(name: str, body_lines: int, doc: str = "A function.", indent: str = "") -> str:
    """A made-up function of exactly ``2 + body_lines`` lines: the def line, its docstring, ``body_lines`` lines."""
    body = "".join(f"{indent}    x{i} = {i}\n" for i in range(body_lines))
    return f'{indent}def {name}():\n{indent}    """{doc}"""\n{body}'


def test_the_checker_counts_lines_as_ast_does_nested_and_methods_included():
    assert function_lengths(_function("f", 98)) == [("f", 100, "A function.")]
    assert too_long({"m.py": _function("f", 98)}) == []
    assert too_long({"m.py": _function("f", 99)}) == ["m.py:f: 101 lines"]
    nested = "def outer():\n" + _function("inner", 99, indent="    ")
    assert too_long({"m.py": nested}) == ["m.py:outer: 102 lines", "m.py:outer.inner: 101 lines"]
    method = "class C:\n" + _function("method", 120, indent="    ")
    assert too_long({"m.py": method}) == ["m.py:C.method: 122 lines"]
    async_src = _function("f", 99).replace("def f", "async def f")
    assert too_long({"m.py": async_src}) == ["m.py:f: 101 lines"]


def test_the_checker_lets_a_listed_flat_table_pass_only_when_its_docstring_says_so():
    table = _function("add_parser", 150, doc="Register the options: one flat table of them.\n\n    More.")
    plain = _function("add_parser", 150, doc="Register the options.")
    assert too_long({"cli.py": table}, frozenset({"cli.py:add_parser"})) == []
    assert too_long({"cli.py": table}) == ["cli.py:add_parser: 154 lines"]  # not listed (2 more docstring lines)
    assert too_long({"cli.py": plain}, frozenset({"cli.py:add_parser"})) == [
        "cli.py:add_parser: 152 lines (listed as a flat table, but its docstring's first line does not say so)"
    ]
    second_line = _function("add_parser", 150, doc="Register the options.\n\n    One flat table of them.")
    assert too_long({"cli.py": second_line}, frozenset({"cli.py:add_parser"})) != []


def test_the_paths_are_those_under_oscar_core():
    sources = _oscar_core_sources()
    assert "evaluation/closed_loop.py" in sources and "cli.py" in sources
    assert all(not Path(p).is_absolute() for p in sources)
