"""The one logging setup (oscar_core._util.log): logger tree, verbosity, progress bars, run log files, CLI flags."""

from __future__ import annotations

import logging
import re
import sys

import pytest

from oscar_core._util import log as _log
from oscar_core.cli import main


@pytest.fixture(autouse=True)
def _fresh_state(monkeypatch):
    monkeypatch.delenv(_log.ENV_VERBOSITY, raising=False)
    monkeypatch.delenv(_log.ENV_DISABLE_PROGRESS, raising=False)
    monkeypatch.setattr(_log, "_verbosity", None)
    monkeypatch.setattr(_log, "_progress_enabled", None)
    yield
    _log._apply()


class _TTY:
    def __init__(self):
        self.text = ""

    def isatty(self):
        return True

    def write(self, s):
        self.text += s

    def flush(self):
        pass


def test_loggers_hang_under_the_oscar_root():
    assert _log.get_logger("oscar_core.toyworld.cli").name == "oscar.toyworld.cli"
    assert _log.get_logger("oscar_zoo._fetch").name == "oscar.zoo._fetch"
    assert _log.get_logger("oscar_core").name == "oscar"
    assert _log.get_logger("my_plugin").name == "oscar.my_plugin"
    assert _log.get_logger("oscar_core.data.run").parent.name in ("oscar", "oscar.data")


def test_verbosity_from_the_environment_and_in_code(monkeypatch):
    assert _log.get_verbosity() == logging.WARNING  # library default
    monkeypatch.setenv(_log.ENV_VERBOSITY, "debug")
    assert _log.get_verbosity() == logging.DEBUG
    monkeypatch.setenv(_log.ENV_VERBOSITY, "loud")
    with pytest.raises(ValueError, match=r"OSCAR_VERBOSITY.*'loud'"):
        _log.get_verbosity()
    _log.set_verbosity("error")  # code wins over the environment
    assert _log.get_verbosity() == logging.ERROR
    assert logging.getLogger("oscar").level == logging.ERROR


def test_progress_bars_only_on_a_terminal_and_when_enabled(monkeypatch):
    monkeypatch.setattr(sys, "stderr", _TTY())
    assert _log.progress_bars_enabled()
    assert _log.progress_bar(range(3), enabled=False).disable  # e.g. --json output
    bar = _log.progress_bar(range(3), desc="x")
    assert not bar.disable
    list(bar)
    assert "3/3" in sys.stderr.text  # drawn on (the current) stderr
    monkeypatch.setenv(_log.ENV_DISABLE_PROGRESS, "1")
    assert not _log.progress_bars_enabled()
    monkeypatch.delenv(_log.ENV_DISABLE_PROGRESS)
    _log.disable_progress_bars()
    assert _log.progress_bar(range(3)).disable
    _log.enable_progress_bars()
    assert not _log.progress_bar(range(3)).disable
    monkeypatch.setattr(sys, "stderr", _TTY())
    monkeypatch.setattr(sys.stderr, "isatty", lambda: False)  # redirected output: never a bar
    assert _log.progress_bar(range(3)).disable


def test_run_log_is_timestamped_made_lazily_and_ends_with_the_error(tmp_path):
    log = _log.get_logger("oscar_core.test")
    with pytest.raises(ValueError):
        with _log.run_log(tmp_path / "quiet", "job"):
            log.debug("below INFO: not in the file")
            raise ValueError("rejected before it logged anything")
    assert not (tmp_path / "quiet").exists()  # rejected before logging: no folder
    with pytest.raises(RuntimeError):
        with _log.run_log(tmp_path / "run", "job", command="oscar job --x 1") as path:
            log.info("step %d", 1)
            raise RuntimeError("disk full")
    lines = path.read_text().splitlines()
    assert path.parent == tmp_path / "run" / "logs" and re.fullmatch(r"job-\d{8}T\d{6}Z\.log", path.name)
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d INFO oscar: command: oscar job --x 1", lines[0])
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d INFO oscar\.test: step 1", lines[1])
    assert lines[-1].endswith("ERROR oscar: stopped by RuntimeError: disk full")
    log.info("after the run")  # the handler is gone
    assert "after the run" not in path.read_text()
    assert logging.getLogger("oscar").level == logging.WARNING  # back to the library default


def _generate(tmp_path, *flags):
    return main(
        [
            *flags,
            "toyworld",
            "generate",
            "--embodiments",
            "toyarm",
            "--episodes",
            "2",
            "--size",
            "16x16",
            "--frames",
            "5",
            "--shard-size",
            "1",
            "--out",
            str(tmp_path),
        ]
    )


def test_cli_flags_control_the_console_and_the_job_keeps_a_log(tmp_path, capsys):
    assert _generate(tmp_path / "a") == 0
    cap = capsys.readouterr()
    assert cap.err.count("shard-toyarm-000000: 1 episode written") == 1  # INFO on stderr, once (no doubled handler)
    assert "episodes written" in cap.out and "shard-" not in cap.out  # results on stdout, progress on stderr
    logs = list((tmp_path / "a" / "logs").glob("toyworld-generate-*.log"))
    assert len(logs) == 1 and "INFO oscar.toyworld.generate: shard-toyarm-000001" in logs[0].read_text()
    assert _generate(tmp_path / "b", "-q") == 0
    cap = capsys.readouterr()
    assert "shard-" not in cap.err and "episodes written" in cap.out
    logs = list((tmp_path / "b" / "logs").glob("*.log"))
    assert "shard-toyarm-000001" in logs[0].read_text()  # -q quiets the console, not the log file
    assert (
        main(
            [
                "toyworld",
                "generate",
                "--embodiments",
                "toyarm",
                "--episodes",
                "1",
                "--out",
                str(tmp_path / "c"),
                "-v",
                "-q",
            ]
        )
        == 2
    )
    assert "found both" in capsys.readouterr().err
    assert logging.getLogger("oscar").handlers == [] and logging.getLogger("oscar").propagate  # main cleans up


def test_every_command_takes_the_same_output_flags():
    from oscar_core.cli import _leaves, build_parser

    parser = build_parser()
    leaves = list(_leaves(parser))
    assert len(leaves) > 20
    for leaf in leaves:
        opts = {o for a in leaf._actions for o in a.option_strings}
        assert {"-v", "-q", "--no-progress"} <= opts, leaf.prog
    args = parser.parse_args(["--no-progress", "-q", "toyworld", "baseline", "clips", "--out", "x"])
    assert args.no_progress and args.quiet == 1  # the top-level spelling is not overwritten by the leaf's default
    args = parser.parse_args(["toyworld", "baseline", "clips", "--out", "x", "--no-progress"])
    assert args.no_progress and args.quiet == 0
    # a command with its own --progress/--no-progress pair keeps its default
    args = parser.parse_args(
        ["render", "--embodiment", "toyarm", "--trajectory", "t.npz", "--camera", "c.json", "--out", "o.mp4"]
    )
    assert args.progress is None and args.no_progress is False


def test_a_finished_job_logs_its_command_line_first_and_its_result_last(tmp_path, monkeypatch):
    log = _log.get_logger("oscar_core.test")
    monkeypatch.setattr(sys, "argv", ["/usr/bin/oscar", "data", "ingest", "my src", "--out", "r"])
    monkeypatch.setattr(_log, "_COMMAND", None)  # no command named by main(): sys.argv
    with _log.run_log(tmp_path / "a", "job") as path:
        log.info("working")
        _log.log_result("3 shards written")
    lines = path.read_text().splitlines()
    assert lines[0].endswith("INFO oscar: command: oscar data ingest 'my src' --out r")  # a shell takes it back
    assert lines[1].endswith("INFO oscar.test: working")
    assert re.search(r"INFO oscar: result: 3 shards written \(\d+\.\d s\)$", lines[2]) and len(lines) == 3
    with _log.run_log(tmp_path / "b", "job", command="oscar quiet") as path:
        pass  # a job that logged nothing still leaves its command and result
    lines = path.read_text().splitlines()
    assert lines[0].endswith("command: oscar quiet") and re.search(r"result: finished \(\d+\.\d s\)$", lines[1])
    _log.log_result("no run log open: ignored")


def test_cli_run_logs_hold_the_command_and_the_result(tmp_path):
    assert _generate(tmp_path / "a") == 0
    text = next((tmp_path / "a" / "logs").glob("toyworld-generate-*.log")).read_text().splitlines()
    assert "command: " in text[0] and "toyworld generate --embodiments toyarm" in text[0]
    assert re.search(r"result: 2 episodes written, 0 kept \(\d+\.\d s\)$", text[-1])


def test_quiet_draws_no_progress_bars_even_on_a_terminal(monkeypatch):
    monkeypatch.setattr(sys, "stderr", _TTY())
    assert _log.progress_bars_enabled()  # stderr is a terminal here (the fixture)
    with _log.cli_output(quiet=1):  # the command's set-up, undone after (the oscar logger left as found)
        assert not _log.progress_bars_enabled() and _log.progress_bar(range(3)).disable
    with _log.cli_output():
        assert _log.progress_bars_enabled()
