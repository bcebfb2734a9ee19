"""The `oscar` command builds only the parser of the command it runs: `oscar --help` and a light command import none
of the heavy modules (diffusers, torch, torch._dynamo, transformers), and what a person sees is the same as with
every parser built."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from oscar_core import cli

HEAVY = ("torch", "torch._dynamo", "diffusers", "transformers", "scipy", "numpy")


def imported_by(code: str) -> set[str]:
    """The modules a fresh interpreter holds after running ``code`` (a command's SystemExit is caught)."""
    script = (
        "import json, sys\n"
        f"try:\n    {code}\nexcept SystemExit:\n    pass\n"
        "print(json.dumps(sorted(sys.modules)), file=sys.stderr)\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return set(json.loads(proc.stderr.strip().splitlines()[-1]))


@pytest.mark.parametrize(
    "code",
    [
        "import oscar_core.cli",
        "from oscar_core.cli import main; main(['--help'])",
        "from oscar_core.cli import main; main(['rollout', '--help'])",
        "from oscar_core.cli import main; main(['zoo', 'list', '--json'])",
        # what `oscar rollout` imports before it loads the world model (diffusers, torch) for a run
        "import oscar_core.cli, oscar_core.model.cli, oscar_core.model.rollout_files",
    ],
)
def test_help_and_light_commands_import_nothing_heavy(code):
    loaded = imported_by(code)
    assert "oscar_core.cli" in loaded  # the probe ran
    assert [m for m in HEAVY if m in loaded] == []


def test_the_probe_sees_a_heavy_import():
    assert "numpy" in imported_by("import numpy")


def test_help_with_stand_ins_is_the_help_with_every_parser_built():
    assert cli.build_parser(stubs=True).format_help() == cli.build_parser().format_help()


def subcommands(parser) -> dict:
    return next(a for a in parser._actions if a.dest == "command").choices


@pytest.mark.parametrize("name", list(cli.COMMANDS))
def test_each_command_built_alone_is_the_command_built_with_all(name):
    alone, full = subcommands(cli.build_parser(only=name))[name], subcommands(cli.build_parser())[name]
    assert alone.format_help() == full.format_help()
    assert alone.get_default("func") is full.get_default("func")


def test_the_command_of_a_command_line_skips_the_global_options():
    assert cli.command_of(["-q", "--plugin", "p.py", "render", "--out", "x.mp4", "-v"]) == "render"
    assert cli.command_of(["zoo", "list", "--help"]) == "zoo"
    with pytest.raises(SystemExit) as exc:
        cli.command_of(["nope"])
    assert exc.value.code == 2
