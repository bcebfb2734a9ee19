"""Refuse, before any work, a worker pool started from a script's unguarded top level.

oscar's pools (:func:`oscar_core._util.stage.pool_context`) start workers from a
fork server, or by spawn (CUDA, macOS, Windows). Neither copies the calling
process, so each worker prepares itself by running the calling script again,
under the name ``__mp_main__``. Code under ``if __name__ == "__main__":`` is
skipped there; code at the script's top level runs again in every worker. A
top-level call that starts a pool then starts one inside each worker, which
multiprocessing refuses; before this check a user saw every episode fail with
``BrokenProcessPool`` and the script's other top-level work done once per
worker.

:func:`check_main_guard` is called where a pool is about to start. It raises
:class:`MainGuardError` naming the script and the line when

* this process is a worker running a script's top level again (a module
  named ``__mp_main__`` is executing), or
* this process is the one making the pool, the main module is a script file
  the workers would run again, and the statement of that script now running
  is not inside an ``if __name__ == "__main__":`` block (read from the
  script's source with :mod:`ast`).

A script read from standard input (``python - < script.py``) is refused
too: the workers look for a file named ``<stdin>`` and die.

Where it cannot tell (no script file: ``python -c``, a notebook, an embedding
program; ``python -m pkg`` whose main module is ``pkg/__main__.py``, which
workers never run again; an unreadable source) it lets the pool start.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path
from types import FrameType

from ..errors import OscarError

__all__ = ["MainGuardError", "check_main_guard"]

_GUARD = 'if __name__ == "__main__":'


class MainGuardError(OscarError, RuntimeError):
    """A worker pool would run the calling script's top level again in every worker."""


def _message(what: str, path: str, line: int) -> str:
    return (
        f"{what}: {path}, line {line}: expected this call under `{_GUARD}`, found it at the script's top "
        f"level. Each worker process imports the script again (as `__mp_main__`: fork-server and spawn "
        f"workers do not copy this process) and would run this call, and everything else at the top level, "
        f"once more. Move the script's top-level work under `{_GUARD}` (e.g. into a main() called there), "
        f"or use workers=1."
    )


def _module_frame(start: FrameType | None, globals_of=None, name: str | None = None) -> FrameType | None:
    """The innermost frame running a module's top level: of the module whose globals are ``globals_of``, or
    whose ``__name__`` is ``name``."""
    frame = start
    while frame is not None:
        if frame.f_code.co_name == "<module>" and (
            (globals_of is not None and frame.f_globals is globals_of)
            or (name is not None and frame.f_globals.get("__name__") == name)
        ):
            return frame
        frame = frame.f_back
    return None


def _is_main_test(node: ast.expr) -> str | None:
    """'body' for ``__name__ == "__main__"``, 'orelse' for ``__name__ != "__main__"`` (either order, also inside
    an ``and``), else None."""
    if isinstance(node, ast.BoolOp) and isinstance(node.op, ast.And):
        for value in node.values:
            if _is_main_test(value) == "body":
                return "body"
        return None
    if not (isinstance(node, ast.Compare) and len(node.ops) == 1 and len(node.comparators) == 1):
        return None
    sides = [node.left, node.comparators[0]]
    has_name = any(isinstance(s, ast.Name) and s.id == "__name__" for s in sides)
    has_main = any(isinstance(s, ast.Constant) and s.value == "__main__" for s in sides)
    if not (has_name and has_main):
        return None
    if isinstance(node.ops[0], ast.Eq):
        return "body"
    if isinstance(node.ops[0], ast.NotEq):
        return "orelse"
    return None


def _within(stmts: list[ast.stmt], line: int) -> ast.stmt | None:
    for stmt in stmts:
        if stmt.lineno <= line <= (stmt.end_lineno or stmt.lineno):
            return stmt
    return None


def guarded(source: str, line: int) -> bool | None:
    """Whether module-level statement running at ``line`` of ``source`` sits inside an ``if __name__ ==
    "__main__":`` block (at any depth of if/with/try/for/while); None when the source does not parse."""
    try:
        tree = ast.parse(source)
    except (SyntaxError, ValueError):
        return None
    stmts: list[ast.stmt] = tree.body
    while True:
        stmt = _within(stmts, line)
        if stmt is None or isinstance(stmt, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            return False
        if isinstance(stmt, ast.If):
            branch = _is_main_test(stmt.test)
            if branch is not None and _within(getattr(stmt, branch), line) is not None:
                return True
        blocks = [getattr(stmt, f, None) for f in ("body", "orelse", "finalbody")]
        blocks += [h.body for h in getattr(stmt, "handlers", [])]
        blocks += [c.body for c in getattr(stmt, "cases", [])]
        inner = [b for b in blocks if isinstance(b, list) and _within(b, line) is not None]
        if not inner:
            return False
        stmts = inner[0]


def check_main_guard(what: str) -> None:
    """Raise :class:`MainGuardError` if a worker pool started now would run the calling script's top level again
    (module docstring). what: the call to name in the message, e.g. ``"render_many(workers=2)"``."""
    caller = sys._getframe(1)
    worker = _module_frame(caller, name="__mp_main__")
    if worker is not None:  # we are a worker, preparing itself by running the script again
        raise MainGuardError(_message(what, worker.f_code.co_filename, worker.f_lineno))
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    spec_name = getattr(getattr(main, "__spec__", None), "name", None) or ""
    if main is None or not path or spec_name == "__main__" or spec_name.endswith(".__main__"):
        return  # no script, or one the workers never run again
    if path.startswith("<") and path.endswith(">"):  # python - < script.py: workers look for a file named <stdin>
        raise MainGuardError(
            f"{what}: expected the main script in a file, found {path} (a script read from "
            f"standard input); every worker process imports the main script again and cannot "
            f"find it. Run it from a file, or use workers=1."
        )
    frame = _module_frame(caller, globals_of=vars(main))
    if frame is None or Path(frame.f_code.co_filename).resolve() != Path(path).resolve():
        return  # not called while the script's top level runs (a thread, an exec'd string): nothing to re-run
    try:
        source = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return
    if guarded(source, frame.f_lineno) is False:
        raise MainGuardError(_message(what, path, frame.f_lineno))
