"""Every built-in dataset reader: registered through the entry point, cheap to list, honest about missing extras."""

import json
import pickle
import subprocess
import sys

import pytest

pytest.importorskip("h5py")
pytest.importorskip("pyarrow")

from oscar_core.data.readers import BUILTIN_READERS
from oscar_core.plugin.reader import EpisodeError, EpisodeRef, Reader
from oscar_core.plugin.registry import Registry

NAMES = ["agibot_world", "droid_raw", "egodex", "epic_vitra", "interndata_a1", "lerobot", "rh20t"]


def test_all_builtin_readers_register_through_the_entry_point():
    reg = Registry()
    assert set(NAMES) <= set(reg.reader_names()), reg.failures
    for name in NAMES:
        r = reg.get_reader(name)
        assert isinstance(r, Reader) and r.description and r.embodiments
        assert set(r.embodiments) <= set(reg.names()), (name, r.embodiments)
        entry = reg.reader_entries[name]
        assert entry.distribution == "oscar-wm"


def test_listing_the_readers_imports_no_heavy_dependency():
    code = (
        "import sys; from oscar_core.plugin.registry import Registry; r = Registry(); "
        "[r.get_reader(n) for n in r.reader_names()]; "
        "print([m for m in ('h5py', 'pyarrow', 'av') if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out.endswith("[]"), out


def _fixtures(tmp_path):
    """One small dataset per reader, in its real layout (the writers of the per-reader tests)."""
    import test_reader_agibot_world as agi
    import test_reader_droid_raw as droid
    import test_reader_egodex as ego
    import test_reader_epic_vitra as epic
    import test_reader_interndata_a1 as idata
    import test_reader_lerobot as lr
    import test_reader_rh20t as rh

    from oscar_embodiments.agibot_g1 import AgiBotG1

    lr.write_droid_v3(tmp_path / "lerobot")
    agi.write_episode(tmp_path / "agibot", AgiBotG1())
    droid.write_episode(tmp_path / "droid")
    ego.write_episode(tmp_path / "egodex")
    epic.write_episode(tmp_path / "epic")
    idata.write_task(tmp_path / "interndata")
    rh.write_scene(tmp_path / "rh20t", 7)
    return {
        "lerobot": "lerobot",
        "agibot_world": "agibot",
        "droid_raw": "droid",
        "egodex": "egodex",
        "epic_vitra": "epic",
        "interndata_a1": "interndata",
        "rh20t": "rh20t",
    }


@pytest.mark.slow  # builds one dataset per reader (the AgiBot one runs FK: ~15 s on a cold process)
def test_listing_decodes_no_video_and_yields_manifest_ready_refs(tmp_path, monkeypatch):
    folders = _fixtures(tmp_path)
    import av

    def no_video(*a, **k):
        raise AssertionError("list_episodes opened a video")

    monkeypatch.setattr(av, "open", no_video)
    reg = Registry()
    for name, folder in folders.items():
        refs = list(reg.get_reader(name).list_episodes(str(tmp_path / folder)))
        assert refs, name
        for ref in refs:
            assert isinstance(ref, EpisodeRef) and ref.reader == name and ref.episode_id.startswith(ref.source + "/")
            assert ref.cameras and ref.meta.get("camera") == ref.cameras[0], (name, ref.cameras, ref.meta)
            assert ref.paths.get("states") and ref.paths.get("video"), (name, ref.paths)  # common roles
            json.dumps({"paths": ref.paths, "meta": ref.meta, "cameras": ref.cameras, "task": ref.task})
    monkeypatch.undo()
    # and each loads, with a video that has the episode's frames
    for name, folder in folders.items():
        reader = reg.get_reader(name)
        if name == "lerobot":
            reader = type(reader)(intrinsics={"exterior_1_left": (100.0, 100.0, 24.0, 16.0)})
        ref = next(iter(reader.list_episodes(str(tmp_path / folder))))
        ep = reader.load_episode(ref)
        assert ep.video.n_frames == len(ep.trajectory) and ep.camera_name == ref.meta["camera"]
        assert ep.camera.embodiment in (None, ref.embodiment)
        assert ep.video.read([len(ep.trajectory) - 1]).shape[0] == 1  # the last frame decodes


def test_episode_errors_cross_process_boundaries():
    e = EpisodeError("rh20t_cfg5/x", "/d/joint.npy", "joint", "7 values", "6 values")
    assert str(pickle.loads(pickle.dumps(e))) == str(e)


def test_missing_optional_dependency_names_the_extra(tmp_path, monkeypatch):
    from oscar_core.data.readers import _common

    real = _common.import_module

    def fake(name, *a, **k):
        if name.split(".")[0] in ("h5py", "pyarrow"):
            raise ImportError(f"No module named {name!r}")
        return real(name, *a, **k)

    (tmp_path / "proprio_stats").mkdir()
    monkeypatch.setattr(_common, "import_module", fake)
    from oscar_core.data.readers.agibot_world import AgiBotWorldReader
    from oscar_core.data.readers.lerobot import LeRobotReader

    with pytest.raises(
        ImportError, match=r"'agibot_world' dataset reader needs .*'h5py'.*pip install \"oscar-wm\[data\]\""
    ):
        list(AgiBotWorldReader().list_episodes(str(tmp_path)))
    (tmp_path / "meta" / "episodes").mkdir(parents=True)
    (tmp_path / "meta" / "info.json").write_text(
        json.dumps(
            {
                "codebase_version": "v3.0",
                "fps": 15,
                "features": {"observation.state.joint_position": {}, "observation.state.gripper_position": {}},
            }
        )
    )
    with pytest.raises(ImportError, match=r"'lerobot' dataset reader needs .*'pyarrow'.*oscar-wm\[data\]"):
        list(LeRobotReader().list_episodes(str(tmp_path)))


def test_remote_sources_are_refused_with_a_reason(tmp_path):
    from oscar_core.data.readers.egodex import EgoDexReader

    with pytest.raises(ValueError, match="mount or copy s3:// data first"):
        list(EgoDexReader().list_episodes("s3://bucket/egodex"))
    assert list(EgoDexReader().list_episodes(f"file://{tmp_path}")) == []


def test_builtin_list_is_one_line_per_reader():
    assert len(BUILTIN_READERS) == len(set(BUILTIN_READERS)) >= 7
