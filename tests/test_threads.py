"""Thread and worker defaults come from the idle cores; asking for more warns."""

from __future__ import annotations

import os
import warnings

import pytest

from oscar_core._util import threads as _threads
from oscar_core._util.threads import ThreadOversubscriptionWarning, check_threads, default_threads, idle_cpus


@pytest.fixture
def machine(monkeypatch):
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
