"""Streaming render: NumPy FK, chunks, frame independence, near-plane cut, fold-back guard, empty views, YUV."""

import warnings

import numpy as np
import pytest

from oscar_core import get_embodiment, load_trajectory, render_skeleton_video
from oscar_core.camera import Camera, Intrinsics, project
from oscar_core.kinematics.trajectory import Trajectory
from oscar_core.plugin.embodiment import SkeletonFrames
from oscar_core.render.guarded_projection import distortion_valid_radius, guarded_project
from oscar_core.render.renderer import EmptyViewError, EmptyViewWarning, RenderStats, format_frames
from oscar_core.render.skeleton_stream import iter_skeleton_chunks


def toyarm():
    emb = get_embodiment("toyarm")
    return emb, load_trajectory(emb.example_trajectory), emb.load_camera(emb.example_camera)


# ------------------------------------------------------------------ NumPy FK


@pytest.mark.slow  # imports torch and pytorch-kinematics
@pytest.mark.parametrize("name", ["toyarm", "franka", "kuka", "hsr", "agibot_g1"])
def test_numpy_fk_matches_pytorch_kinematics(name):
    from oscar_core.kinematics.fk_numpy import NumpyForwardKinematics
    from oscar_core.kinematics.fk_torch import ForwardKinematics

    tree = get_embodiment(name).tree
    lo, hi = tree.limits()
    lo, hi = np.where(np.isfinite(lo), lo, -np.pi), np.where(np.isfinite(hi), hi, np.pi)
    rng = np.random.default_rng(0)
    q = lo + rng.random((6, len(lo))) * (hi - lo)
    base = np.tile(np.eye(4), (6, 1, 1))
    base[:, :3, 3] = rng.normal(size=(6, 3))
    links = list(tree.links)
    ref = ForwardKinematics(tree)(q, links, base).numpy()
    mine = NumpyForwardKinematics(tree)(q, links, base)
    np.testing.assert_allclose(mine, ref, atol=1e-10)


def test_render_path_imports_neither_torch_nor_matplotlib():
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from oscar_core import get_embodiment, load_trajectory, render_skeleton_video\n"
        "e = get_embodiment('toyarm'); t = load_trajectory(e.example_trajectory)\n"
        "render_skeleton_video(e, t.time_slice(0, 1), e.load_camera(e.example_camera), (64, 36))\n"
        "print(sorted(m for m in ('torch', 'matplotlib', 'pytorch_kinematics', 'scipy') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


# ------------------------------------------------------------------ chunks and batches


def test_chunks_concatenate_to_the_whole_video():
    emb, traj, cam = toyarm()
    whole = render_skeleton_video(emb, traj, cam, (160, 90))
    stats = RenderStats()
    chunks = list(iter_skeleton_chunks(emb, traj, cam, (160, 90), chunk_frames=7, stats=stats))
    assert [len(c) for c in chunks] == [7] * 11 + [4]
    np.testing.assert_array_equal(np.concatenate(chunks), whole)
    assert stats.frames == len(traj) and stats.empty_frames == []


def test_a_frame_alone_is_pixel_identical_to_that_frame_in_the_video():
    """The gripper disc's polygon resolution follows its own radius, not the batch's largest."""
    emb, traj, cam = toyarm()
    whole = render_skeleton_video(emb, traj, cam, (512, 288))
    openness = emb.gripper_openness(traj.gripper)[:, 0]
    for t in (int(np.argmin(openness)), int(np.argmax(openness)), 40):
        alone = render_skeleton_video(emb, traj.time_slice(t, t + 1), cam, (512, 288))
        np.testing.assert_array_equal(alone[0], whole[t], err_msg=f"frame {t}")


# ------------------------------------------------------------ a body given as points


class Points:
    """A minimal embodiment: fixed world points per frame, joined in a chain."""

    name = "points"

    def __init__(self, pts, gripper=None):
        self.pts = np.asarray(pts, float)
        self.g = np.zeros((len(self.pts), 0, 3)) if gripper is None else np.asarray(gripper, float)

    def check_trajectory(self, traj):
        return traj

    def check_camera(self, camera, source):
        pass

    def colors(self):
        K = self.pts.shape[1]
        return np.full((K, 3), (0, 0, 255), np.uint8), np.full((K - 1, 3), (255, 0, 0), np.uint8)

    def edge_index(self):
        K = self.pts.shape[1]
        return np.array([[k, k + 1] for k in range(K - 1)])

    def frames(self, traj, device="cpu", mount_link=None):
        t0 = int(traj.timestamps[0])
        T = len(traj)
        G = self.g.shape[1]
        return SkeletonFrames(self.pts[t0 : t0 + T], self.g[t0 : t0 + T], np.ones((T, G)), None)


def points_traj(T):
    return Trajectory((), np.zeros((T, 0)), fps=10.0, timestamps=np.arange(T, dtype=float))


def camera(dist=(), f=200.0, W=512, H=288):
    """At the origin looking along +z (OpenCV axes, camera-to-world identity)."""
    return Camera(Intrinsics(f, f, (W - 1) / 2, (H - 1) / 2, W, H, tuple(dist)), np.eye(4))


def test_an_edge_with_one_end_behind_the_camera_is_cut_at_the_near_plane_not_dropped():
    # A in front on the optical axis, B behind the camera and to the right: the visible
    # part of AB runs from the image centre out through the right edge.
    pts = np.array([[[0.0, 0.0, 1.0], [0.5, 0.0, -1.0]]])
    emb = Points(pts)
    video = np.concatenate(list(iter_skeleton_chunks(emb, points_traj(1), camera())))
    row = video[0, 143:146].max(axis=0)  # rows around cy = 143.5
    assert row[300:505, 0].min() > 100  # the red edge reaches the right border
    assert row[:240].max() == 0  # nothing to the left of the dot
    # both ends behind: nothing at all
    behind = Points(np.array([[[0.0, 0.0, -1.0], [0.5, 0.0, -1.0]]]))
    with pytest.warns(EmptyViewWarning, match="0 \\(1 of 1 frames\\)|in 1 of 1 frames: 0"):
        assert not np.concatenate(list(iter_skeleton_chunks(behind, points_traj(1), camera()))).any()


def test_a_point_far_outside_the_view_never_wraps_back_in():
    k1 = -0.5  # r·(1 + k1 r²) peaks at r = 0.816, then folds back
    cam = camera(dist=(k1, 0.0, 0.0, 0.0))
    assert distortion_valid_radius(cam.intrinsics.distortion) == pytest.approx(np.sqrt(2 / 3), abs=2e-3)
    assert distortion_valid_radius(()) == np.inf
    far = np.array([1.6, 0.0, 1.0])  # 58° right of the axis: the plain model folds it to u ≈ 166
    naive = project(far, cam)
    assert naive.in_image and naive.uv[0] < cam.intrinsics.cx  # the bug this guards against
    guarded = guarded_project(far, cam.intrinsics)
    assert not guarded.in_image and guarded.uv[0] > cam.intrinsics.width
    near = np.array([0.3, 0.1, 1.0])  # inside the valid radius: the lens model as is
    np.testing.assert_allclose(guarded_project(near, cam.intrinsics).uv, project(near, cam).uv)
    # drawn: a dot there leaves the frame black, and the camera is reported as seeing nothing
    emb = Points(far[None, None])
    with pytest.warns(EmptyViewWarning):
        video = np.concatenate(list(iter_skeleton_chunks(emb, points_traj(1), cam)))
    assert not video.any()


def test_empty_view_warns_naming_the_frames_and_strict_makes_it_an_error():
    T = 10
    pts = np.tile(np.array([[[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]]]), (T, 1, 1))
    pts[[2, 3, 4, 8], :, 2] = -1.0  # behind the camera in frames 2-4 and 8
    emb = Points(pts)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        list(iter_skeleton_chunks(emb, points_traj(T), camera(), chunk_frames=3, camera_source="cam.json"))
    messages = [str(w.message) for w in caught if w.category is EmptyViewWarning]
    assert messages == [
        "cam.json: the camera sees nothing of the robot (every point behind the camera or "
        "outside the image) in 4 of 10 frames: 2-4, 8"
    ]
    with pytest.raises(EmptyViewError, match="cam.json.*2 of 10 frames: 2-3.*strict"):
        list(iter_skeleton_chunks(emb, points_traj(T), camera(), chunk_frames=4, strict=True, camera_source="cam.json"))


def test_format_frames():
    assert format_frames([0, 1, 2, 5, 7, 8]) == "0-2, 5, 7-8"
    assert format_frames(list(range(0, 40, 2)), limit=2) == "0, 2, … (18 more runs)"


# ------------------------------------------------------------------ RGB -> YUV


@pytest.mark.parametrize("H, W", [(36, 64), (54, 96)])  # H / 2 even, and odd (planes do not fill whole rows)
def test_rgb_to_yuv420p_is_bt601_limited_range_with_averaged_chroma(H, W):
    from oscar_core.media.video import rgb_to_yuv420p

    rng = np.random.default_rng(1)
    frame = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    got = rgb_to_yuv420p(frame).astype(float)
    assert got.shape == (H * 3 // 2, W)
    rgb = frame.astype(float)
    M = np.array([[65.481, 128.553, 24.966], [-37.797, -74.203, 112.0], [112.0, -93.786, -18.214]]) / 255
    ycc = rgb @ M.T + [16, 128, 128]
    mean = ycc.reshape(H // 2, 2, W // 2, 2, 3).mean(axis=(1, 3))
    flat = got.reshape(-1)
    n, m = H * W, (H // 2) * (W // 2)
    assert np.abs(got[:H] - ycc[..., 0]).max() <= 1.0
    assert np.abs(flat[n : n + m].reshape(H // 2, W // 2) - mean[..., 1]).max() <= 2.0
    assert np.abs(flat[n + m :].reshape(H // 2, W // 2) - mean[..., 2]).max() <= 2.0


@pytest.mark.parametrize("yuv", ["opencv", "swscale"])
def test_h264_of_a_skeleton_keeps_its_colours(tmp_path, yuv):
    from oscar_core.media.video import read_video, write_video

    emb, traj, cam = toyarm()
    video = render_skeleton_video(emb, traj.time_slice(0, 12), cam, (320, 180))
    back = read_video(write_video(tmp_path / "s.mp4", video, 10, yuv=yuv)).astype(float)
    psnr = 10 * np.log10(255**2 / np.mean((back - video) ** 2))
    assert psnr > 33, psnr


@pytest.mark.slow  # imports torch
def test_a_plugin_that_overrides_fk_keeps_its_own_kinematics():
    emb, traj, cam = toyarm()
    calls = []

    class Shifted(type(emb)):
        def fk(self, q, base_pose=None, links=None, device="cpu", dtype=None):
            calls.append(device)
            poses = super().fk(q, base_pose, links, device, dtype).clone()
            poses[..., 2, 3] += 0.05  # 5 cm up: a visibly different skeleton
            return poses

    shifted = Shifted()
    plain = emb.frames(traj.time_slice(0, 3))
    moved = shifted.frames(traj.time_slice(0, 3))
    assert calls == ["cpu"]
    np.testing.assert_allclose(
        moved.points - plain.points, np.broadcast_to([0, 0, 0.05], plain.points.shape), atol=1e-12
    )
