"""Video I/O: lossless round trips, H.264 quality, atomic writes, bad input."""

import numpy as np
import pytest

from oscar_core.errors import OutputPathError
from oscar_core.video import read_video, video_info, write_video


def random_frames(T=6, H=37, W=53, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (T, H, W, 3), dtype=np.uint8)


def smooth_frames(T=24, H=96, W=160):
    y, x = np.mgrid[:H, :W].astype(float)
    frames = [np.stack([128 + 100 * np.sin((x + 3 * t) / 17), 128 + 100 * np.cos((y - 2 * t) / 13),
                        128 + 80 * np.sin((x + y + t) / 29)], axis=-1) for t in range(T)]
    return np.clip(np.stack(frames), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("target", ["clip.mkv", "frames/"])
def test_lossless_round_trip_is_exact_at_odd_sizes(tmp_path, target):
    frames = random_frames()
    path = write_video(str(tmp_path / target), frames, fps=12)
    np.testing.assert_array_equal(read_video(path), frames)


def test_h264_round_trip_quality_count_and_fps(tmp_path):
    frames = smooth_frames()
    path = write_video(tmp_path / "clip.mp4", frames, fps=29.97)
    back = read_video(path)
    assert back.shape == frames.shape
    mse = np.mean((back.astype(float) - frames) ** 2)
    assert 10 * np.log10(255 ** 2 / mse) > 35
    info = video_info(path)
    assert info["frames"] == len(frames) and info["codec"] == "h264"
    assert info["fps"] == pytest.approx(29.97, abs=1e-3)
    assert (info["width"], info["height"]) == (160, 96)


def test_streaming_frames_from_an_iterable(tmp_path):
    frames = random_frames(T=4, H=16, W=16)
    write_video(tmp_path / "it.mkv", iter(list(frames)), fps=5)
    np.testing.assert_array_equal(read_video(tmp_path / "it.mkv"), frames)


def test_odd_size_h264_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match=r"even width and height, found 53x37"):
        write_video(tmp_path / "odd.mp4", random_frames(), fps=10)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("target", ["crash.mp4", "crash.mkv", "crash_frames/"])
def test_a_crash_mid_write_leaves_nothing(tmp_path, target):
    def frames():
        for i, f in enumerate(smooth_frames(T=6)):
            if i == 3:
                raise RuntimeError("simulated crash")
            yield f

    with pytest.raises(RuntimeError, match="simulated crash"):
        write_video(str(tmp_path / target), frames(), fps=10)
    assert list(tmp_path.iterdir()) == []


def test_unwritable_folder_fails_before_encoding(tmp_path):
    consumed = []

    def frames():
        consumed.append(1)
        yield smooth_frames(T=1)[0]

    with pytest.raises(OutputPathError, match="missing.*does not exist"):
        write_video(tmp_path / "missing" / "x.mp4", frames(), fps=10)
    assert consumed == []


def test_bad_frames_and_suffix(tmp_path):
    with pytest.raises(ValueError, match=r"\(T, H, W, 3\) uint8 RGB, found float64"):
        write_video(tmp_path / "f.mp4", np.zeros((2, 8, 8, 3)), fps=10)
    with pytest.raises(OutputPathError, match=r"unsupported suffix '.avi'.*\.mp4"):
        write_video(tmp_path / "f.avi", random_frames(), fps=10)
    with pytest.raises(ValueError, match="fps"):
        write_video(tmp_path / "f.mkv", random_frames(), fps=0)
    with pytest.raises(FileNotFoundError, match="nope.mp4"):
        read_video(tmp_path / "nope.mp4")
