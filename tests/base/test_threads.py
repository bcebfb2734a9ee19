"""Thread and worker defaults come from the idle cores; asking for more warns."""

from __future__ import annotations

import os
import warnings

import pytest

from oscar_core._util import threads as _threads
from oscar_core._util.threads import ThreadOversubscriptionWarning, check_threads, default_threads, idle_cpus


@pytest.fixture
def machine(monkeypatch):
    """Stand in ``cores`` available cores at a 1-minute load of ``load``, with no thread count set in the
    environment (a suite run under ``OMP_NUM_THREADS=1`` would otherwise decide every default)."""
    for name in ("OSCAR_NUM_THREADS", "OMP_NUM_THREADS"):
        monkeypatch.delenv(name, raising=False)

    def set_machine(cores: int, load: float):
        monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(cores)), raising=False)
        monkeypatch.setattr(os, "getloadavg", lambda: (load, load, load))

    return set_machine


@pytest.mark.parametrize("cores, load, idle", [(2, 0.0, 2), (2, 1.6, 1), (2, 5.0, 1), (16, 3.2, 13), (4, 0.4, 4)])
def test_idle_cores_are_the_available_ones_minus_the_load(machine, cores, load, idle):
    machine(cores, load)
    assert idle_cpus() == default_threads() == idle


def test_asking_for_more_than_is_idle_warns_and_names_the_flag(machine):
    machine(2, 1.9)
    with pytest.warns(ThreadOversubscriptionWarning, match=r"--threads: 2 requested, but only 1 of 2 cores"):
        check_threads(2, "--threads")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_threads(1, "--threads")  # within what is idle: silent


def test_train_vae_defaults_to_the_idle_cores(machine, monkeypatch, tmp_path):
    from oscar_core.cli import main
    from oscar_core.toyworld import vae_train

    seen = {}

    def fake_train(clips, out, cfg, log=None):
        seen["threads"] = cfg.threads
        return {"heldout_psnr_db": 0.0, "steps_done": 0, "wall_s": 0.0}

    monkeypatch.setattr(vae_train, "train_vae", fake_train)
    machine(8, 5.2)
    assert main(["toyworld", "train-vae", str(tmp_path), "--out", str(tmp_path / "o")]) == 0
    assert seen["threads"] == 3
    with pytest.warns(ThreadOversubscriptionWarning):
        assert main(["toyworld", "train-vae", str(tmp_path), "--out", str(tmp_path / "o"), "--threads", "6"]) == 0
    assert seen["threads"] == 6
    assert _threads.available_cpus() == 8


# ----------------------------------------------------------------------------- one choice for every torch command
@pytest.fixture
def torch_threads(monkeypatch):
    """Keep this process's torch thread count and OpenMP variables as they were."""
    import torch

    before = torch.get_num_threads()
    for var in ("OSCAR_NUM_THREADS", "OMP_NUM_THREADS", "OMP_WAIT_POLICY"):
        monkeypatch.delenv(var, raising=False)  # restored after the test, whatever main() set
    yield torch
    torch.set_num_threads(before)


def test_choose_threads_order_flag_then_env_then_omp_then_idle():
    from oscar_core._util.threads import choose_threads

    assert choose_threads(None, env={}, cpus=2, load=2.3) == 1  # the machine: 2 cores at load 2.3
    assert choose_threads(None, env={}, cpus=16, load=3.4) == 13
    assert choose_threads(None, env={}, cpus=4, load=0.0) == 4
    assert choose_threads(None, env={"OMP_NUM_THREADS": "3"}, cpus=2, load=2.3) == 3  # the user's OpenMP setting
    assert choose_threads(None, env={"OSCAR_NUM_THREADS": "2", "OMP_NUM_THREADS": "3"}, cpus=2, load=2.3) == 2
    assert choose_threads(5, env={"OSCAR_NUM_THREADS": "2"}, cpus=2, load=2.3) == 5  # --threads wins


@pytest.mark.parametrize("bad", ["0", "-1", "two", "1.5"])
def test_a_bad_oscar_num_threads_is_refused_naming_the_variable(bad):
    from oscar_core._util.threads import choose_threads
    from oscar_core.errors import OscarError

    with pytest.raises(OscarError, match=rf"\$OSCAR_NUM_THREADS: expected a positive integer .*found '{bad}'"):
        choose_threads(None, env={"OSCAR_NUM_THREADS": bad})


def test_every_torch_command_has_threads():
    import argparse

    from oscar_core.cli import build_parser

    def leaves(parser, path=()):
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            yield path, parser
        for action in subs:
            for name, child in action.choices.items():
                yield from leaves(child, path + (name,))

    with_threads = {
        path for path, p in leaves(build_parser()) if any(getattr(a, "oscar_threads", False) for a in p._actions)
    }
    for path in [
        ("rollout",),
        ("eval", "run"),
        ("eval", "benchmark", "run"),
        ("render",),
        ("train",),
        ("toyworld", "generate"),
        ("toyworld", "train-vae"),
        ("toyworld", "reconstruct"),
        ("toyworld", "rollout"),
    ]:
        assert path in with_threads, path


def test_the_command_applies_the_choice_to_torch(machine, monkeypatch, tmp_path, torch_threads):
    from oscar_core.cli import main
    from oscar_core.toyworld import vae_train

    monkeypatch.setattr(
        vae_train,
        "train_vae",
        lambda clips, out, cfg, log=None: {
            "heldout_psnr_db": 0.0,
            "steps_done": 0,
            "wall_s": float(torch_threads.get_num_threads()),
        },
    )
    machine(8, 5.2)  # 3 cores idle
    assert main(["toyworld", "train-vae", str(tmp_path), "--out", str(tmp_path / "o")]) == 0
    assert torch_threads.get_num_threads() == 3
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"  # set by the command: OpenMP threads sleep when idle
    monkeypatch.setenv("OSCAR_NUM_THREADS", "2")
    assert main(["toyworld", "train-vae", str(tmp_path), "--out", str(tmp_path / "o")]) == 0
    assert torch_threads.get_num_threads() == 2
    assert main(["toyworld", "train-vae", str(tmp_path), "--out", str(tmp_path / "o"), "--threads", "1"]) == 0
    assert torch_threads.get_num_threads() == 1


def test_a_wait_policy_the_user_set_is_kept(monkeypatch, torch_threads):
    from oscar_core.cli import main

    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    assert main(["embodiments", "--json"]) == 0
    assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE"


def test_the_parser_does_not_load_torch_so_the_wait_policy_is_set_in_time():
    """OMP_WAIT_POLICY is read when torch's OpenMP runtime loads: main() sets it before that, which holds only
    while building the parser imports no torch."""
    import subprocess
    import sys

    code = "import sys; from oscar_core.cli import build_parser; build_parser(); print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
