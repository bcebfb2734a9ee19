"""``oscar view``: recordings read back with Rerun's own API against the files they were made from.

Each test writes an ``.rrd`` (raw frames: ``--jpeg-quality 0``) and reads it with
``rerun.chunk.RrdReader`` + ``ChunkStore.reader`` (a DataFusion table per entity), then checks entity
paths, frame counts, a joint curve against the trajectory, the camera intrinsics and pose against the
camera JSON, the condition against the skeleton renderer, and a rollout's two videos against their files.
"""

import json
import sys

import numpy as np
import pytest

rr = pytest.importorskip("rerun", reason='oscar view needs the viz extra: pip install "oscar-wm[viz]"')
pytest.importorskip("datafusion", reason="reading recordings back needs rerun-sdk[catalog] (the viz extra)")

from oscar_core import get_embodiment, load_camera, load_trajectory, save_camera, save_trajectory  # noqa: E402
from oscar_core.cli import main  # noqa: E402
from oscar_core.media.video import read_video, write_video  # noqa: E402
from oscar_core.render.skeleton_video import render_skeleton_video  # noqa: E402
from oscar_core.toyworld.episode import episode_rng, make_episode  # noqa: E402
from oscar_core.train.clips import Clip, ClipRecord, ClipSetWriter  # noqa: E402
from oscar_core.viz import capsule_quaternions  # noqa: E402

T, W, H = 12, 96, 72


@pytest.fixture(scope="module")
def episode(tmp_path_factory):
    emb = get_embodiment("franka")
    ep = make_episode(emb, episode_rng(0, "franka", 0), W, H, T)
    d = tmp_path_factory.mktemp("view")
    save_trajectory(ep.trajectory, d / "traj.npz")
    save_camera(ep.camera, d / "cam.json")
    write_video(d / "rgb.mkv", ep.rgb, ep.trajectory.fps)  # FFV1: lossless, so the frames read back exactly
    write_video(d / "gen.mkv", ep.rgb[::-1].copy(), ep.trajectory.fps)  # a "rollout": the frames reversed
    write_video(d / "short.mkv", ep.rgb[: T - 2], ep.trajectory.fps)
    return emb, ep, d


def _store(path):
    return rr.chunk.RrdReader(str(path)).stream().collect()


def _table(store, entity, index="frame"):
    return store.reader(index=index, contents=entity).to_arrow_table()


def _column(table, entity, archetype, component):
    return table.column(f"{entity}:{archetype}:{component}").to_pylist()


def _images(store, entity, shape):
    t = _table(store, entity)
    assert t.column("frame").to_pylist() == list(range(len(t)))
    return np.stack([np.asarray(b[0], np.uint8).reshape(shape) for b in _column(t, entity, "Image", "buffer")])


def _view(args, capsys):
    code = main(["view", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def test_an_episode_reads_back_as_logged(episode, tmp_path, capsys):
    emb, ep, d = episode
    rrd = tmp_path / "ep.rrd"
    args = ["--embodiment", "franka", "--trajectory", d / "traj.npz", "--camera", d / "cam.json"]
    code, out, err = _view([*args, "--video", d / "rgb.mkv", "--save", rrd, "--jpeg-quality", "0", "--json"], capsys)
    assert code == 0, err
    summary = json.loads(out)
    store = _store(rrd)
    entities = {c.split(":")[0] for c in store.reader(index="frame").to_arrow_table().schema.names if ":" in c}
    entities |= {c.split(":")[0] for c in store.reader(index=None).to_arrow_table().schema.names if ":" in c}
    want = {"/world/camera", "/world/camera/rgb", "/world/camera/condition", "/world/robot/links"}
    want |= {"/world/robot/points", "/world/robot/grippers", "/gripper/gripper", "/gripper_openness/gripper"}
    want |= {f"/joints/{n}" for n in emb.joint_names}
    assert want <= entities and {"/" + e for e in summary["entities"]} == want
    assert summary["frames"] == T

    traj = load_trajectory(d / "traj.npz")
    joints = _table(store, "/joints/**")
    assert joints.column("frame").to_pylist() == list(range(T))
    np.testing.assert_allclose(joints.column("time").to_pandas().dt.total_seconds(), np.arange(T) / traj.fps)
    for j, name in enumerate(traj.joint_names):  # float64 scalars: exactly the trajectory's values
        got = [v[0] for v in _column(joints, f"/joints/{name}", "Scalars", "scalars")]
        assert got == traj.q[:, j].tolist()
    grip = _table(store, "/gripper/gripper")
    assert [v[0] for v in _column(grip, "/gripper/gripper", "Scalars", "scalars")] == traj.gripper[:, 0].tolist()

    cam = load_camera(d / "cam.json")
    static = _table(store, "/world/camera", index=None).to_pylist()[0]
    K = np.asarray(static["/world/camera:Pinhole:image_from_camera"][0]).reshape(3, 3).T  # stored column-major
    i = cam.intrinsics
    np.testing.assert_allclose(K, [[i.fx, 0, i.cx], [0, i.fy, i.cy], [0, 0, 1]], rtol=1e-6)  # float32 in the file
    assert static["/world/camera:Pinhole:resolution"][0] == [W, H]
    cam_to_world = np.linalg.inv(cam.world_to_cv())
    np.testing.assert_allclose(static["/world/camera:Transform3D:translation"][0], cam_to_world[:3, 3], atol=1e-6)
    R = np.asarray(static["/world/camera:Transform3D:mat3x3"][0]).reshape(3, 3).T
    np.testing.assert_allclose(R, cam_to_world[:3, :3], atol=1e-6)

    np.testing.assert_array_equal(_images(store, "/world/camera/rgb", (H, W, 3)), read_video(d / "rgb.mkv"))
    cond = _images(store, "/world/camera/condition", (H, W, 4))
    skel = render_skeleton_video(emb, emb.check_trajectory(traj), cam)
    np.testing.assert_array_equal(cond[..., :3], skel)
    np.testing.assert_array_equal(cond[..., 3], np.round(0.8 * skel.max(axis=-1).astype(np.float32)).astype(np.uint8))
    assert cond[..., 3].max() > 0  # the robot is in view

    links = _table(store, "/world/robot/links")
    assert links.column("frame").to_pylist() == list(range(T))
    pts = _table(store, "/world/robot/points")
    fk = emb.frames(emb.check_trajectory(traj)).points
    got = np.asarray(_column(pts, "/world/robot/points", "Points3D", "positions")[5])
    np.testing.assert_allclose(got, fk[5], atol=1e-6)  # float32 positions
    starts = np.asarray(_column(links, "/world/robot/links", "Capsules3D", "translations")[5])
    np.testing.assert_allclose(starts, fk[5][emb.edge_index()[:, 0]], atol=1e-6)
    assert len(rr.chunk.RrdReader(str(rrd)).blueprints()) == 1  # the layout travels with the recording


def test_a_rollout_shows_generated_beside_real(episode, tmp_path, capsys):
    emb, ep, d = episode
    rrd = tmp_path / "rollout.rrd"
    args = ["--embodiment", "franka", "--trajectory", d / "traj.npz", "--camera", d / "cam.json"]
    code, out, err = _view(
        [*args, "--video", d / "rgb.mkv", "--generated", d / "gen.mkv", "--save", rrd, "--jpeg-quality", "0"], capsys
    )
    assert code == 0, err
    assert out.strip() == f"wrote {rrd}: {T} frames, 17 entities"
    store = _store(rrd)
    np.testing.assert_array_equal(_images(store, "/rollout/generated", (H, W, 3)), read_video(d / "gen.mkv"))
    np.testing.assert_array_equal(_images(store, "/rollout/real", (H, W, 3)), read_video(d / "rgb.mkv"))


def test_jpeg_frames_are_close_and_smaller(episode, tmp_path, capsys):
    emb, ep, d = episode
    args = ["--embodiment", "franka", "--trajectory", d / "traj.npz", "--camera", d / "cam.json", "--video"]
    assert _view([*args, d / "rgb.mkv", "--save", tmp_path / "raw.rrd", "--jpeg-quality", "0"], capsys)[0] == 0
    assert _view([*args, d / "rgb.mkv", "--save", tmp_path / "jpg.rrd"], capsys)[0] == 0
    t = _table(_store(tmp_path / "jpg.rrd"), "/world/camera/rgb")
    assert len(t) == T and "/world/camera/rgb:EncodedImage:blob" in t.schema.names


def test_a_clip_of_a_clip_set(episode, tmp_path, capsys):
    emb, ep, d = episode
    traj = emb.check_trajectory(ep.trajectory)
    skel = render_skeleton_video(emb, traj, ep.camera)
    skel[:, :2] = 255  # a stored skeleton video that differs from the rendered one: the stored one is shown
    rec = ClipRecord(
        id="franka-000000", source="toyworld", embodiment="franka", n_frames=T, fps=float(traj.fps), width=W,
        height=H, openness=tuple(tuple(r) for r in emb.gripper_openness(traj.gripper).tolist()), files={},
    )  # fmt: skip
    w = ClipSetWriter(tmp_path / "clips")
    with w.shard("shard-000000") as s:
        s.add(Clip(rec, rgb=ep.rgb, trajectory=traj, camera=ep.camera, skeleton=skel))
    rrd = tmp_path / "clip.rrd"
    code, out, err = _view(
        [tmp_path / "clips", "--clip", "franka-000000", "--save", rrd, "--jpeg-quality", "0"], capsys
    )
    assert code == 0, err
    store = _store(rrd)
    np.testing.assert_array_equal(_images(store, "/world/camera/condition", (H, W, 4))[..., :3], skel)
    np.testing.assert_array_equal(_images(store, "/world/camera/rgb", (H, W, 3)), ep.rgb)
    code, out, err = _view([tmp_path / "clips", "--clip", "nope", "--save", rrd], capsys)
    assert code == 2 and "field 'id'" in err and "franka-000000" in err


def test_a_closed_loop_cell_folder(episode, tmp_path, capsys):
    emb, ep, d = episode
    cell = tmp_path / "cells" / "s1" / "pi0"
    cell.mkdir(parents=True)
    save_trajectory(ep.trajectory, cell / "trajectory.npz")
    write_video(cell / "video.mkv", ep.rgb[::-1].copy(), 10.0)
    cond = render_skeleton_video(emb, emb.check_trajectory(ep.trajectory), ep.camera)
    write_video(cell / "condition.mkv", cond, 10.0)
    (cell / "record.json").write_text(json.dumps({"session": "s1", "policy": "pi0", "status": "ok"}))
    rrd = tmp_path / "cell.rrd"
    code, out, err = _view([cell, "--embodiment", "franka", "--camera", d / "cam.json", "--save", rrd, "--jpeg-quality", "0"], capsys)  # fmt: skip
    assert code == 0, err
    store = _store(rrd)
    np.testing.assert_array_equal(_images(store, "/rollout/generated", (H, W, 3)), ep.rgb[::-1])
    np.testing.assert_array_equal(_images(store, "/world/camera/condition", (H, W, 4))[..., :3], cond)
    (cell / "record.json").write_text(json.dumps({"session": "s1", "policy": "pi0", "status": "failed"}))
    code, out, err = _view([cell, "--embodiment", "franka", "--camera", d / "cam.json", "--save", rrd], capsys)
    assert code == 2 and "record.json: field 'status': expected 'ok'" in err and "found 'failed'" in err


def test_a_closed_loop_cell_takes_its_camera_from_the_closed_loop_manifest(episode, tmp_path, capsys):
    """``--manifest`` a closed-loop manifest: the cell's embodiment and camera are its session's (paths resolved
    from the manifest's folder), for the cell folder and for OUT --cell SESSION/POLICY alike."""
    emb, ep, d = episode
    import cv2

    cell = tmp_path / "out" / "cells" / "s1" / "pi0"
    cell.mkdir(parents=True)
    save_trajectory(ep.trajectory, cell / "trajectory.npz")
    write_video(cell / "video.mkv", ep.rgb[::-1].copy(), 10.0)
    (cell / "record.json").write_text(json.dumps({"session": "s1", "policy": "pi0", "status": "ok"}))
    m = tmp_path / "study"
    m.mkdir()
    cv2.imwrite(str(m / "first.png"), ep.rgb[0][..., ::-1])
    save_camera(ep.camera, m / "cam.json")
    save_trajectory(ep.trajectory, m / "state.npz")
    manifest = {
        "format": "oscar-closed-loop-manifest",
        "policies": [{"name": "pi0", "policy": "oscar_core.toyworld.image_policies:ExactPolicy"}],
        "sessions": [{"session": "s1", "task": "reach", "embodiment": "franka", "first_frame": "first.png",
                      "camera": "cam.json", "initial_state": "state.npz", "horizon": T}],
    }  # fmt: skip
    (m / "manifest.json").write_text(json.dumps(manifest))
    cam_to_world = np.linalg.inv(ep.camera.world_to_cv())
    for source in ([cell], [tmp_path / "out", "--cell", "s1/pi0"]):
        rrd = tmp_path / "cl.rrd"
        code, out, err = _view([*source, "--manifest", m / "manifest.json", "--save", rrd, "--jpeg-quality", "0", "--json"], capsys)  # fmt: skip
        assert code == 0, err
        assert json.loads(out)["camera"] == str(m / "cam.json") and json.loads(out)["embodiment"] == "franka"
        store = _store(rrd)
        static = _table(store, "/world/camera", index=None).to_pylist()[0]
        np.testing.assert_allclose(static["/world/camera:Transform3D:translation"][0], cam_to_world[:3, 3], atol=1e-6)
        cond = _images(store, "/world/camera/condition", (H, W, 4))[..., :3]
        np.testing.assert_array_equal(cond, render_skeleton_video(emb, emb.check_trajectory(ep.trajectory), ep.camera))
    code, out, err = _view([cell, "--save", tmp_path / "x.rrd"], capsys)
    assert code == 2 and "expected --manifest FILE (the closed-loop manifest), or --embodiment and --camera" in err


def test_an_eval_run_cell(episode, tmp_path, capsys):
    emb, ep, d = episode
    import cv2

    cv2.imwrite(str(tmp_path / "first.png"), ep.rgb[0][..., ::-1])
    manifest = {
        "format": "oscar-eval-manifest", "policies": ["pi0"],
        "defaults": {"embodiment": "franka", "camera": str(d / "cam.json")},
        "cells": [{"session": "s1", "policy": "pi0", "task": "reach", "first_frame": "first.png",
                   "trajectory": str(d / "traj.npz"), "real_video": str(d / "rgb.mkv")}],
    }  # fmt: skip
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    (tmp_path / "run" / "rollouts" / "s1").mkdir(parents=True)
    write_video(tmp_path / "run" / "rollouts" / "s1" / "pi0.mkv", ep.rgb[::-1].copy(), 10.0)
    rrd = tmp_path / "run.rrd"
    base = [tmp_path / "run", "--manifest", tmp_path / "manifest.json", "--save", rrd, "--jpeg-quality", "0"]
    code, out, err = _view([*base, "--cell", "s1/pi0"], capsys)
    assert code == 0, err
    store = _store(rrd)
    np.testing.assert_array_equal(_images(store, "/rollout/generated", (H, W, 3)), ep.rgb[::-1])
    np.testing.assert_array_equal(_images(store, "/rollout/real", (H, W, 3)), ep.rgb)
    code, out, err = _view([*base, "--cell", "s1/pi1"], capsys)
    assert code == 2 and "field 'cells'" in err and "['s1/pi0']" in err and "'s1/pi1'" in err


@pytest.mark.parametrize("fps, n", [(16.0, 31), (10.0, 20)])
def test_an_eval_run_cells_real_video_is_shown_by_time(tmp_path, capsys, fps, n):
    """A RoboArena cell: the real camera at 15 fps, 30 frames (1.933 s); the trajectory resampled to ``fps``
    (``n`` frames over the same 1.933 s). Each trajectory frame shows the real frame nearest in time."""
    from oscar_core.evaluation.roboarena import resample_joints
    from oscar_core.trajectory import Trajectory

    emb = get_embodiment("franka")
    ep = make_episode(emb, episode_rng(0, "franka", 0), W, H, 30)
    src = emb.check_trajectory(ep.trajectory)
    times = np.arange(30) / 15.0
    q, at = resample_joints(np.concatenate([src.q, src.gripper], axis=1), times, fps)
    assert len(q) == n
    J = len(src.joint_names)
    traj = Trajectory(src.joint_names, q[:, :J], fps, gripper=q[:, J:], gripper_names=src.gripper_names)
    save_trajectory(traj, tmp_path / "traj.npz")
    save_camera(ep.camera, tmp_path / "cam.json")
    real = np.zeros((30, H, W, 3), np.uint8)
    real[:] = (np.arange(30) * 8)[:, None, None, None]  # frame i is grey level 8 i: which frame is shown is read back
    write_video(tmp_path / "real.mkv", real, 15.0)
    import cv2

    cv2.imwrite(str(tmp_path / "first.png"), real[0])
    manifest = {
        "format": "oscar-eval-manifest", "policies": ["pi0"],
        "defaults": {"embodiment": "franka", "camera": "cam.json"},
        "cells": [{"session": "s1", "policy": "pi0", "task": "reach", "first_frame": "first.png",
                   "trajectory": "traj.npz", "real_video": "real.mkv"}],
    }  # fmt: skip
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    (tmp_path / "run" / "rollouts" / "s1").mkdir(parents=True)
    write_video(tmp_path / "run" / "rollouts" / "s1" / "pi0.mkv", ep.rgb[:1].repeat(n, axis=0), fps)
    rrd = tmp_path / "run.rrd"
    args = [tmp_path / "run", "--manifest", tmp_path / "manifest.json", "--cell", "s1/pi0", "--save", rrd]
    code, out, err = _view([*args, "--jpeg-quality", "0"], capsys)
    assert code == 0, err
    shown = _images(_store(rrd), "/rollout/real", (H, W, 3))[:, 0, 0, 0] // 8
    assert len(shown) == n
    from fractions import Fraction as F

    # the real frame nearest in time, in exact arithmetic (a tie, as at 10 fps, goes to the earlier frame)
    want = [min(range(30), key=lambda i: abs(F(i, 15) - F(t) / F(fps))) for t in range(n)]
    assert shown.tolist() == want
    assert np.abs(shown / 15.0 - np.arange(n) / fps).max() <= 0.5 / 15.0 + 1e-9

    write_video(tmp_path / "real.mkv", real[:20], 15.0)  # 1.27 s of video for a 1.93 s trajectory
    code, out, err = _view(args, capsys)
    assert code == 2 and "real.mkv: field 'frames': expected at least 29 frames at 15 fps" in err, err


@pytest.mark.parametrize(
    "change, message",
    [
        (
            {"--trajectory": "missing.npz"},
            "missing.npz: field 'trajectory': expected an existing file, found no such file",
        ),
        ({"--video": "short.mkv"}, "short.mkv: field 'frames': expected at least 12 frames"),
        ({"--embodiment": "franky"}, "franky"),
        ({"--save": "out.txt"}, "--save: expected a file name ending in .rrd, found"),
        ({"--camera": "missing.json"}, "missing.json: field 'camera': expected an existing file"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(episode, tmp_path, capsys, change, message):
    emb, ep, d = episode
    opts = {"--embodiment": "franka", "--trajectory": d / "traj.npz", "--camera": d / "cam.json",
            "--video": d / "rgb.mkv", "--save": tmp_path / "x.rrd"}  # fmt: skip
    for k, v in change.items():
        opts[k] = v if k in ("--embodiment",) else (tmp_path / v if k == "--save" else d / v)
    code, out, err = _view([x for kv in opts.items() for x in kv], capsys)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not list(tmp_path.glob("*.rrd")) and not list(tmp_path.glob(".*.tmp"))


def test_without_the_extra_the_error_names_the_install_command(episode, tmp_path, capsys, monkeypatch):
    emb, ep, d = episode
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun raises ImportError
    code, out, err = _view(
        ["--embodiment", "franka", "--trajectory", d / "traj.npz", "--save", tmp_path / "x.rrd"], capsys
    )
    assert code == 2 and 'pip install "oscar-wm[viz]"' in err and len(err.strip().splitlines()) == 1


def test_capsule_rotations_turn_z_onto_the_segment():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    a = rng.normal(size=(50, 3))
    d = rng.normal(size=(50, 3))
    d[0] = [0, 0, -2.0]  # straight down: the half turn
    d[1] = [0, 0, 3.0]  # straight up: no turn
    length, q = capsule_quaternions(a, a + d)
    np.testing.assert_allclose(length, np.linalg.norm(d, axis=1), rtol=1e-12)
    z = Rotation.from_quat(q).apply([0.0, 0.0, 1.0])  # scipy: xyzw, as Rerun
    np.testing.assert_allclose(z * length[:, None], d, atol=1e-12)


def test_without_save_or_spawn_the_recording_goes_to_the_current_folder(episode, tmp_path, capsys, monkeypatch):
    emb, ep, d = episode
    monkeypatch.chdir(tmp_path)
    code, out, err = _view(["--embodiment", "franka", "--trajectory", d / "traj.npz"], capsys)
    assert code == 0, err
    assert out.strip() == f"wrote traj.rrd: {T} frames, 12 entities"  # no camera: no frustum, video or condition
    t = _table(_store(tmp_path / "traj.rrd"), "/joints/**")
    assert len(t) == T


def test_meshes_sit_at_their_links_fk_poses(episode, tmp_path, capsys):
    from oscar_core.render.mesh import mesh_geometry

    emb, ep, d = episode
    rrd = tmp_path / "mesh.rrd"
    code, out, err = _view(
        ["--embodiment", "franka", "--trajectory", d / "traj.npz", "--meshes", "--save", rrd], capsys
    )
    assert code == 0, err
    store = _store(rrd)
    geo = mesh_geometry(emb)
    first = geo.links[0]
    static = _table(store, f"/world/robot/meshes/{first.link}/0", index=None).to_pylist()[0]
    got = np.asarray(static[f"/world/robot/meshes/{first.link}/0:Mesh3D:vertex_positions"])
    np.testing.assert_allclose(got, first.vertices, atol=1e-6)  # float32, in the link's own frame
    # the link's pose per frame, against the torch FK (pytorch-kinematics; the recording uses the NumPy FK)
    traj = emb.check_trajectory(load_trajectory(d / "traj.npz"))
    for link in geo.link_names[1:4]:
        poses = _table(store, f"/world/robot/meshes/{link}")
        assert poses.column("frame").to_pylist() == list(range(T))
        t_col = np.asarray(_column(poses, f"/world/robot/meshes/{link}", "Transform3D", "translation"))[:, 0]
        R_col = np.asarray(_column(poses, f"/world/robot/meshes/{link}", "Transform3D", "mat3x3"))[:, 0]
        want = emb.fk(emb.full_configuration(traj), traj.base_pose, links=[link]).double().numpy()[:, 0]
        np.testing.assert_allclose(t_col, want[:, :3, 3], atol=1e-6)
        np.testing.assert_allclose(
            R_col.reshape(T, 3, 3).transpose(0, 2, 1), want[:, :3, :3], atol=1e-6
        )  # column-major


def test_a_moving_camera_has_a_pose_per_frame(episode, tmp_path, capsys):
    from dataclasses import replace

    emb, ep, d = episode
    M = np.repeat(np.asarray(ep.camera.extrinsic)[None], T, axis=0)
    M[:, 0, 3] += np.linspace(0.0, 0.1, T)  # a camera sliding 10 cm along the world x axis
    moving = replace(ep.camera, extrinsic=M)
    save_camera(moving, tmp_path / "moving.json")
    rrd = tmp_path / "moving.rrd"
    args = ["--embodiment", "franka", "--trajectory", d / "traj.npz", "--camera", tmp_path / "moving.json"]
    code, out, err = _view([*args, "--save", rrd], capsys)
    assert code == 0, err
    poses = _table(_store(rrd), "/world/camera")
    assert poses.column("frame").to_pylist() == list(range(T))
    got = np.asarray(_column(poses, "/world/camera", "Transform3D", "translation"))[:, 0]
    want = np.linalg.inv(moving.world_to_cv())[:, :3, 3]
    np.testing.assert_allclose(got, want, atol=1e-6)
    assert np.ptp(got[:, 0]) == pytest.approx(0.1, abs=1e-6)
    save_camera(replace(ep.camera, extrinsic=M[:5]), tmp_path / "five.json")
    args[-1] = tmp_path / "five.json"
    code, out, err = _view([*args, "--save", tmp_path / "five.rrd"], capsys)
    assert code == 2 and "five.json: field 'extrinsic': expected 12 per-frame extrinsics" in err


def test_a_rollout_written_as_png_frames(episode, tmp_path, capsys):
    import cv2

    emb, ep, d = episode
    (tmp_path / "frames").mkdir()
    for t, f in enumerate(ep.rgb[::-1]):  # oscar rollout --out frames/ writes one PNG per frame
        cv2.imwrite(str(tmp_path / "frames" / f"{t:06d}.png"), f[..., ::-1])
    rrd = tmp_path / "png.rrd"
    args = ["--embodiment", "franka", "--trajectory", d / "traj.npz", "--camera", d / "cam.json"]
    code, out, err = _view([*args, "--generated", tmp_path / "frames", "--save", rrd, "--jpeg-quality", "0"], capsys)
    assert code == 0, err
    np.testing.assert_array_equal(_images(_store(rrd), "/rollout/generated", (H, W, 3)), ep.rgb[::-1])


def test_meshes_of_an_embodiment_without_visual_geometry_are_refused_first(tmp_path, capsys, monkeypatch):
    from oscar_core.kinematics.trajectory import Trajectory

    emb = get_embodiment("mano")  # keypoints, no URDF: no visual geometry
    P = len(emb.skeleton.links)
    kp = np.random.default_rng(0).normal(0, 0.05, (4, P, 3))
    traj = Trajectory((), np.zeros((4, 0)), 10.0, gripper=np.zeros((4, len(emb.gripper_names))), keypoints=kp)
    save_trajectory(traj, tmp_path / "hand.npz")
    rrd = tmp_path / "hand.rrd"
    code, out, err = _view(["--embodiment", "mano", "--trajectory", tmp_path / "hand.npz", "--save", rrd], capsys)
    assert code == 0, err  # capsules of the keypoint skeleton

    def no_recording(*a, **k):
        raise AssertionError("a recording was opened before the input was refused")

    monkeypatch.setattr(rr, "RecordingStream", no_recording)
    code, out, err = _view(["--embodiment", "mano", "--trajectory", tmp_path / "hand.npz", "--meshes", "--save", tmp_path / "m.rrd"], capsys)  # fmt: skip
    assert code == 2 and "has no visual geometry" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "m.rrd").exists() and not list(tmp_path.glob(".*.tmp"))
