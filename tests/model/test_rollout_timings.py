"""`oscar rollout`'s timings: diffusers' import counted as import only when nothing waits on the Hub."""

import argparse

from oscar_core.model.rollout_files import _loads_without_network


def _args(model, offline=False):
    return argparse.Namespace(model=str(model), revision=None, offline=offline)


def test_disk_only_models_import_diffusers_up_front(tmp_path, monkeypatch):
    monkeypatch.setenv("OSCAR_ZOO_REGISTRY", str(tmp_path / "zoo.json"))
    assert _loads_without_network(_args(tmp_path))  # a folder
    assert _loads_without_network(_args("oscar-toy"))  # bundled with oscar
    assert not _loads_without_network(_args("oscar-2b"))  # a Hub checkpoint: the probe comes first
    assert not _loads_without_network(_args("someone/some-model"))
    assert _loads_without_network(_args("someone/some-model", offline=True))
    assert not _loads_without_network(_args(tmp_path / "missing"))  # unknown: the load reports it
