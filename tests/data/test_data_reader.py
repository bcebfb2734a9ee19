"""The dataset-reader contract: registration through the plugin hook, and frame-exact video slices."""

import textwrap

import numpy as np
import pytest

from oscar_core.errors import PluginError
from oscar_core.media.video import write_video
from oscar_core.plugin.reader import EpisodeError, EpisodeRef, Reader, VideoSource
from oscar_core.plugin.registry import Registry


def _plugin(tmp_path, body):
    path = tmp_path / "myreader.py"
    path.write_text(textwrap.dedent(body))
    return Registry(plugin_paths=[path], autoload=False, warn=False)


def test_reader_registers_through_the_hook(tmp_path):
    reg = _plugin(
        tmp_path,
        """
        from oscar_core.plugin.hookspecs import hookimpl
        from oscar_core.plugin.reader import Reader, EpisodeRef

        class Mine(Reader):
            name = "mine"
            def list_episodes(self, source):
                yield EpisodeRef("mine/0", "mine", "mine", "toyarm", {"states": source})
            def load_episode(self, ref, registry=None):
                raise NotImplementedError

        @hookimpl
        def oscar_register_readers():
            return [Mine]
    """,
    )
    assert reg.reader_names() == ["mine"] and not reg.failures
    refs = list(reg.get_reader("mine").list_episodes("/x"))
    assert refs[0].episode_id == "mine/0"
    with pytest.raises(PluginError, match="unknown dataset reader 'other'; registered: mine"):
        reg.get_reader("other")


def test_broken_reader_is_reported_and_others_load(tmp_path):
    reg = _plugin(
        tmp_path,
        """
        from oscar_core.plugin.hookspecs import hookimpl
        from oscar_core.plugin.reader import Reader

        class NoLoad(Reader):
            name = "noload"
            def list_episodes(self, source):
                return iter(())

        @hookimpl
        def oscar_register_readers():
            return [NoLoad, int]
    """,
    )
    assert reg.reader_names() == []
    errors = " | ".join(f.error for f in reg.failures)
    assert "does not implement `load_episode`" in errors and "expected a Reader subclass" in errors


def test_video_source_reads_a_time_range_of_a_shared_file(tmp_path):
    # three "episodes" of 6 frames share one file, as LeRobot v3 stores them; each frame encodes its index
    frames = np.zeros((18, 16, 16, 3), np.uint8)
    for i in range(18):
        frames[i] = i * 12
    path = write_video(tmp_path / "shared.mkv", frames, fps=15)
    src = VideoSource(str(path), n_frames=6, fps=15.0, start=6 / 15)
    got = src.read()
    np.testing.assert_array_equal(got[:, 0, 0, 0], np.arange(6, 12) * 12)
    np.testing.assert_array_equal(src.read([5, 0, 2])[:, 0, 0, 0], np.array([11, 6, 8]) * 12)
    with pytest.raises(ValueError, match=r"frame indices must lie in \[0, 6\)"):
        src.read([6])
    late = VideoSource(str(path), n_frames=6, fps=15.0, start=15 / 15)
    with pytest.raises(ValueError, match=r"frames \[3, 4, 5\] are missing"):
        late.read()


def test_episode_error_names_everything():
    err = EpisodeError("agibot/327/648642", "/d/proprio_stats.h5", "state/joint/position", "(N, 14)", "(N, 12)")
    assert str(err) == (
        "episode 'agibot/327/648642': /d/proprio_stats.h5: field 'state/joint/position': "
        "expected (N, 14), found (N, 12)"
    )
    assert isinstance(EpisodeRef("a", "b", "c", "d", {}).meta, dict)
    assert Reader.class_problems() == [
        "declares no `name`",
        "does not implement `list_episodes`",
        "does not implement `load_episode`",
    ]
