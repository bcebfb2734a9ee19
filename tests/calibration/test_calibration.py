"""``oscar calibrate``: a known camera recovered from noisy skeleton points, outliers named, degenerate input refused.

The answers are known in advance: synthetic problems (:func:`oscar_core.calibration.synthetic.problem`)
project the embodiment's FK skeleton points through a camera made with ``look_at`` and add Gaussian pixel
noise. The thresholds scale with the noise sigma; they come from ``python benchmarks/calibration.py pnp``
(30 seeds per embodiment, docs/calibration.md), whose worst case they exceed by a factor of 1.5 or more;
the tests run seeds 0-4 of the same problems.
"""

import json

import numpy as np
import pytest

from oscar_core import Camera, Intrinsics, Skeleton, get_embodiment, load_camera, save_trajectory
from oscar_core.calibration.pnp import calibrate, position_error_mm, rotation_error_deg
from oscar_core.calibration.points import PixelPoints, PointsFileError, load_points, save_points
from oscar_core.calibration.synthetic import SIZE, observe, problem
from oscar_core.cli import main
from oscar_core.kinematics.trajectory import Trajectory
from oscar_core.plugin.embodiment import Embodiment

SEEDS = range(5)


def threshold_for(sigma):
    return max(4.0, 4.0 * sigma)  # as benchmarks/calibration.py


@pytest.fixture(scope="module", params=["franka", "kuka"])
def emb(request):
    return get_embodiment(request.param)


@pytest.mark.parametrize("sigma", [0.5, 1.0, 2.0])
def test_known_intrinsics_recover_the_pose(emb, sigma):
    # benchmark (30 seeds per embodiment), worst: 0.19 / 0.41 / 0.62 degrees, 6.2 / 14.0 / 22.8 mm at sigma 0.5 / 1 / 2
    for seed in SEEDS:
        traj, cam, pts = problem(emb, seed, sigma)
        res = calibrate(emb, traj, pts, SIZE, cam.intrinsics, threshold_px=threshold_for(sigma))
        assert rotation_error_deg(res.camera, cam) < 0.6 * sigma, seed
        assert position_error_mm(res.camera, cam) < 25.0 * sigma, seed
        assert res.camera.intrinsics == cam.intrinsics and res.camera.embodiment == emb.name
        assert res.rms_px < 2.0 * sigma  # an inlier's 2D error has rms sqrt(2) sigma


@pytest.mark.parametrize("sigma", [0.5, 1.0, 2.0])
def test_estimated_intrinsics_are_recovered(emb, sigma):
    # benchmark (30 seeds per embodiment), worst: 0.60 / 1.75 / 3.84 degrees, 38 / 64 / 154 mm, focal 1.6 / 3.4 / 6.8 %,
    # principal point 8.7 / 21 / 54 px at sigma 0.5 / 1 / 2
    for seed in SEEDS:
        traj, cam, pts = problem(emb, seed, sigma)
        res = calibrate(emb, traj, pts, SIZE, None, threshold_px=threshold_for(sigma))
        got, true = res.camera.intrinsics, cam.intrinsics
        assert res.estimated_intrinsics and (got.width, got.height) == SIZE
        assert rotation_error_deg(res.camera, cam) < 3.0 * sigma, seed
        assert position_error_mm(res.camera, cam) < 120.0 * sigma, seed
        assert max(abs(got.fx - true.fx), abs(got.fy - true.fy)) / true.fx < 0.05 * sigma, seed
        assert np.hypot(got.cx - true.cx, got.cy - true.cy) < 40.0 * sigma, seed


def test_the_report_is_the_projects_own_projection():
    emb = get_embodiment("franka")
    traj, cam, pts = problem(emb, 0, 1.0)
    res = calibrate(emb, traj, pts, SIZE, cam.intrinsics)
    # a second implementation of the pinhole: world -> OpenCV camera frame -> pixels
    from oscar_core.calibration.pnp import skeleton_points

    P = skeleton_points(emb, traj)[pts.frame, [emb.skeleton.links.index(n) for n in pts.name]]
    M = res.camera.world_to_cv()
    Pc = P @ M[:3, :3].T + M[:3, 3]
    i = res.camera.intrinsics
    uv = np.stack([i.fx * Pc[:, 0] / Pc[:, 2] + i.cx, i.fy * Pc[:, 1] / Pc[:, 2] + i.cy], axis=1)
    np.testing.assert_allclose(res.residual_px, np.linalg.norm(uv - pts.uv, axis=1), atol=1e-9)
    assert sum(r["points"] for r in res.per_frame) == sum(r["points"] for r in res.per_point) == len(pts)
    frame0 = next(r for r in res.per_frame if r["frame"] == 0)
    assert frame0["mean_px"] == pytest.approx(res.residual_px[pts.frame == 0].mean())


def test_outliers_are_named_and_left_out(emb):
    traj, cam, pts = problem(emb, 3, 1.0)
    rng = np.random.default_rng(3)
    n = len(pts)
    moved = np.sort(rng.choice(n, size=n // 10, replace=False))
    angle = rng.uniform(0, 2 * np.pi, size=len(moved))
    uv = pts.uv.copy()
    uv[moved] += 50.0 * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    uv = np.clip(uv, 0, np.array(SIZE) - 1)  # still inside the image (an edge point moves less than 50 px then)
    moved = moved[np.linalg.norm(uv[moved] - pts.uv[moved], axis=1) > 10]
    bad = PixelPoints(pts.frame, pts.name, uv, pts.embodiment, "p.json")
    for intr in (cam.intrinsics, None):
        res = calibrate(emb, traj, bad, SIZE, intr, threshold_px=4.0)
        assert sorted(r["index"] for r in res.outliers) == moved.tolist()
        assert {(r["frame"], r["point"]) for r in res.outliers} == {(int(pts.frame[i]), pts.name[i]) for i in moved}
        assert rotation_error_deg(res.camera, cam) < (0.5 if intr else 3.0)
        assert sum(r["outliers"] for r in res.per_point) == len(moved)


# ----------------------------------------------------------------------------- refused input, each with its reason


def _refused(emb, traj, pts, intr=None, size=SIZE) -> str:
    with pytest.raises(PointsFileError) as err:
        calibrate(emb, traj, pts, size, intr)
    return str(err.value)


@pytest.fixture(scope="module")
def franka_problem():
    emb = get_embodiment("franka")
    traj, cam, pts = problem(emb, 0, 0.5, keep=1.0)
    return emb, traj, cam, pts


def test_fewer_than_six_distinct_correspondences(franka_problem):
    emb, traj, cam, pts = franka_problem
    pick = [int(np.flatnonzero(pts.frame == f)[-1]) for f in np.unique(pts.frame)[:5]]  # 5 frames, one point each
    few = PixelPoints(pts.frame[pick], tuple(pts.name[i] for i in pick), pts.uv[pick], None, "p.json")
    msg = _refused(emb, traj, few, cam.intrinsics)
    assert msg.startswith("p.json: field 'points': expected at least 6 correspondences with distinct 3D points")
    assert "found 5 (5 entries)" in msg


def test_a_robot_that_did_not_move_with_too_few_points_per_frame(franka_problem):
    emb, traj, cam, _ = franka_problem
    still = Trajectory(
        traj.joint_names,
        np.repeat(traj.q[:1], 20, axis=0),
        traj.fps,
        np.repeat(traj.gripper[:1], 20, 0),
        traj.gripper_names,
    )
    pts = observe(emb, still, cam, np.random.default_rng(1), 0.5)
    keep = np.isin(np.array(pts.name), emb.skeleton.links[:4])  # 4 points on each of 20 frames: 80 entries
    msg = _refused(
        emb,
        still,
        PixelPoints(pts.frame[keep], tuple(np.array(pts.name)[keep]), pts.uv[keep], None, "p.json"),
        cam.intrinsics,
    )
    assert "a robot that did not move" in msg and "at most 4 points on one frame" in msg
    assert "points on frames where the robot has moved, or at least 6 points on one frame" in msg
    # all its points on one still frame are enough
    assert calibrate(emb, still, pts, SIZE, cam.intrinsics).rms_px < 1.5


def test_collinear_points(tmp_path):
    # a robot of two sliders along x: every skeleton point lies on the x axis, whatever the joints
    urdf = tmp_path / "rail.urdf"
    joint = (
        '<joint name="{n}" type="prismatic"><parent link="{p}"/><child link="{c}"/><origin xyz="0.2 0 0"/>'
        '<axis xyz="1 0 0"/><limit lower="-0.5" upper="0.5" effort="1" velocity="1"/></joint>'
    )
    urdf.write_text(
        '<robot name="rail"><link name="base"/><link name="a"/><link name="b"/>'
        + joint.format(n="j1", p="base", c="a")
        + joint.format(n="j2", p="a", c="b")
        + "</robot>"
    )

    class Rail(Embodiment):
        name = "rail"

    Rail.urdf, Rail.skeleton = urdf, Skeleton(links=("base", "a", "b"))
    emb = Rail()
    q = np.stack([np.linspace(-0.4, 0.4, 10), np.linspace(0.3, -0.3, 10)], axis=1)
    traj = Trajectory(("j1", "j2"), q, 10.0)
    from oscar_core import look_at

    cam = Camera(Intrinsics(600, 600, 319.5, 239.5, *SIZE), look_at([0.5, -2.0, 1.0], [0.4, 0, 0]))
    pts = observe(emb, traj, cam, np.random.default_rng(0), 0.5)
    assert len(pts) == 30
    msg = _refused(emb, traj, pts, cam.intrinsics)
    assert "expected 3D points that span more than a line" in msg and "nearly collinear" in msg


def test_coplanar_points_cannot_give_intrinsics():
    # only the first joint turns, so each skeleton point circles the z axis at its own height: the points of
    # one link lie in one horizontal plane
    from oscar_core.calibration.pnp import skeleton_points

    emb = get_embodiment("franka")
    traj, cam, _ = problem(emb, 0)
    rng = np.random.default_rng(0)
    q = np.repeat(traj.q[:1], 30, axis=0)
    q[:, 0] = np.linspace(-1.2, 1.2, 30)
    spin = Trajectory(traj.joint_names, q, traj.fps, np.repeat(traj.gripper[:1], 30, 0), traj.gripper_names)
    k = 4
    assert np.ptp(skeleton_points(emb, spin)[:, k, 2]) < 1e-9
    pts = observe(emb, spin, cam, rng, 0.5)
    keep = np.array(pts.name) == emb.skeleton.links[k]
    flat = PixelPoints(pts.frame[keep], tuple(np.array(pts.name)[keep]), pts.uv[keep], None, "p.json")
    assert len(flat) == 30
    msg = _refused(emb, spin, flat, None)
    assert "nearly coplanar" in msg and "or give the intrinsics" in msg
    assert calibrate(emb, spin, flat, SIZE, cam.intrinsics).rms_px < 1.5  # known intrinsics: a plane is enough


def test_points_outside_the_image(franka_problem):
    emb, traj, cam, pts = franka_problem
    uv = pts.uv.copy()
    uv[7, 0] = SIZE[0] + 3.0
    msg = _refused(emb, traj, PixelPoints(pts.frame, pts.name, uv, None, "p.json"), cam.intrinsics)
    assert msg.startswith("p.json: field 'points[7].u': expected a pixel inside the 640x480 image ([-0.5, 639.5))")
    assert f"found {SIZE[0] + 3:g} (frame {pts.frame[7]}, point {pts.name[7]!r}; 1 entries outside)" in msg


def test_unknown_point_names_list_the_embodiments(franka_problem):
    emb, traj, cam, pts = franka_problem
    names = list(pts.name)
    names[2] = "panda_link99"
    msg = _refused(emb, traj, PixelPoints(pts.frame, tuple(names), pts.uv, None, "p.json"), cam.intrinsics)
    assert msg.startswith("p.json: field 'points[2].point': expected one of franka's skeleton points ['panda_link0',")
    assert msg.endswith("found 'panda_link99'")


def test_frames_beyond_the_trajectory(franka_problem):
    emb, traj, cam, pts = franka_problem
    frame = pts.frame.copy()
    frame[0] = len(traj)
    msg = _refused(emb, traj, PixelPoints(frame, pts.name, pts.uv, None, "p.json"), cam.intrinsics)
    assert f"field 'points[0].frame': expected a frame index below {len(traj)}" in msg


@pytest.mark.parametrize(
    "doc, field, found",
    [
        ([], "<document>", "list"),
        ({"pts": []}, "pts", "unknown keys ['pts']"),
        ({"points": [{"frame": 0, "point": "a", "u": 1}]}, "points[0]", "missing ['v']"),
        ({"points": [{"frame": -1, "point": "a", "u": 1, "v": 2}]}, "points[0].frame", "-1"),
        ({"points": [{"frame": 0, "point": "a", "u": float("nan"), "v": 2}]}, "points[0].u", "NaN"),
        (
            {"points": [{"frame": 0, "point": "a", "u": 1, "v": 2}, {"frame": 0, "point": "a", "u": 3, "v": 4}]},
            "points[1]",
            "a second entry for frame 0, point 'a' (first: points[0])",
        ),
    ],
)
def test_points_file_errors_name_the_field(tmp_path, doc, field, found):
    path = tmp_path / "p.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(PointsFileError) as err:
        load_points(path)
    assert err.value.field == field and found in str(err.value.found)


def test_points_file_round_trip(tmp_path, franka_problem):
    _, _, _, pts = franka_problem
    save_points(pts, tmp_path / "p.json")
    back = load_points(tmp_path / "p.json")
    assert back.name == pts.name and back.embodiment == "franka"
    np.testing.assert_array_equal(back.frame, pts.frame)
    np.testing.assert_array_equal(back.uv, pts.uv)


# ----------------------------------------------------------------------------- the command


def _inputs(tmp_path, emb_name="kuka", seed=1):
    emb = get_embodiment(emb_name)
    traj, cam, pts = problem(emb, seed, 1.0)
    save_trajectory(traj, tmp_path / "traj.npz")
    save_points(pts, tmp_path / "points.json")
    i = cam.intrinsics
    (tmp_path / "intr.json").write_text(
        json.dumps({"image_size": [i.width, i.height], "intrinsics": {"fx": i.fx, "fy": i.fy, "cx": i.cx, "cy": i.cy}})
    )
    return emb, traj, cam


def test_cli_writes_the_camera_and_an_overlay(tmp_path, capsys):
    from oscar_core import read_video, render_skeleton_video, write_video

    emb, traj, cam = _inputs(tmp_path)
    rgb = np.full((len(traj), SIZE[1], SIZE[0], 3), 40, np.uint8)
    write_video(tmp_path / "rgb.mkv", rgb, traj.fps)
    base = [
        "calibrate",
        "--embodiment",
        "kuka",
        "--trajectory",
        str(tmp_path / "traj.npz"),
        "--points",
        str(tmp_path / "points.json"),
        "--size",
        "640x480",
    ]
    assert (
        main(
            base
            + [
                "--intrinsics",
                str(tmp_path / "intr.json"),
                "--out",
                str(tmp_path / "cam.json"),
                "--video",
                str(tmp_path / "rgb.mkv"),
                "--overlay",
                str(tmp_path / "check.mkv"),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert out.startswith(f"wrote {tmp_path / 'cam.json'}:") and "lbr_iiwa_link_4" in out
    got = load_camera(tmp_path / "cam.json")
    assert got.embodiment == "kuka" and rotation_error_deg(got, cam) < 0.5 and position_error_mm(got, cam) < 20
    video = read_video(tmp_path / "check.mkv")
    skel = render_skeleton_video(emb, traj, got)
    drawn = skel.max(-1) > 0
    assert video.shape == rgb.shape
    assert (video[~drawn] == 40).all() and (video[drawn] != 40).any(-1).mean() > 0.9  # the skeleton over the frames

    assert main(base + ["--estimate-intrinsics", "--out", str(tmp_path / "cam2.json"), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["estimated_intrinsics"] and report["out"] == str(tmp_path / "cam2.json")
    assert {r["point"] for r in report["per_point"]} <= set(emb.skeleton.links) and report["outliers"] == []
    assert abs(load_camera(tmp_path / "cam2.json").intrinsics.fx - 600) < 30


@pytest.mark.parametrize(
    "change, expect",
    [
        ({"--points": "missing.json"}, "missing.json"),
        ({"--size": "640x"}, "--size: expected WIDTHxHEIGHT"),
        ({"--embodiment": "franka"}, "points.json: field 'embodiment': expected 'franka', found 'kuka'"),
        ({"--intrinsics": "points.json"}, "points.json: field 'points': expected only the keys"),
        ({"--video": "rgb.mkv"}, "--video and --overlay go together"),
    ],
)
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, capsys, change, expect):
    _inputs(tmp_path)
    args = {
        "--embodiment": "kuka",
        "--trajectory": "traj.npz",
        "--points": "points.json",
        "--size": "640x480",
        "--intrinsics": "intr.json",
        "--out": "cam.json",
        **change,
    }
    argv = ["calibrate"] + [
        x for k, v in args.items() for x in (k, v if k in ("--embodiment", "--size") else str(tmp_path / v))
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and expect in err
    assert not (tmp_path / "cam.json").exists()


def test_cli_refuses_a_short_overlay_video_before_fitting_or_writing(tmp_path, capsys, monkeypatch):
    from oscar_core import write_video
    from oscar_core.calibration import pnp

    emb, traj, cam = _inputs(tmp_path)
    write_video(tmp_path / "short.mkv", np.zeros((len(traj) - 3, SIZE[1], SIZE[0], 3), np.uint8), traj.fps)
    fitted, fit = [], pnp.calibrate
    monkeypatch.setattr(pnp, "calibrate", lambda *a, **k: fitted.append(1) or fit(*a, **k))
    argv = ["calibrate", "--embodiment", "kuka", "--size", "640x480"]
    for k, v in (("--trajectory", "traj.npz"), ("--points", "points.json"), ("--intrinsics", "intr.json"),
                 ("--out", "cam.json"), ("--video", "short.mkv"), ("--overlay", "check.mkv")):  # fmt: skip
        argv += [k, str(tmp_path / v)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert (
        f"short.mkv: field 'frames': expected at least {len(traj)} frames" in err and f"{len(traj) - 3} frames" in err
    )
    assert fitted == [] and not (tmp_path / "cam.json").exists() and not (tmp_path / "check.mkv").exists()


@pytest.mark.parametrize("name", ["franka", "kuka"])
def test_refinement_improves_on_its_starting_pose(name, monkeypatch):
    """The least-squares refinement moves a starting pose 3 degrees and 5 cm off to the least-squares optimum:
    OpenCV's own Levenberg–Marquardt PnP (``cv2.solvePnP``, iterative, started at the true pose) on the same
    points, to 0.01 mm and 0.001 degrees, where the start was tens of millimetres away."""
    import cv2
    from scipy.spatial.transform import Rotation

    from oscar_core.calibration import pnp

    emb = get_embodiment(name)
    traj, cam, pts = problem(emb, 0, 0.5)  # 0.5 px noise: every point within the 4 px threshold at the optimum
    intr = cam.intrinsics
    corr = pnp.build_correspondences(emb, traj, pts, SIZE)
    truth = np.linalg.inv(cam.world_to_cv())  # camera to world
    R_cv, t_cv = truth[:3, :3].T, -truth[:3, :3].T @ truth[:3, 3]
    ok, rvec, tvec = cv2.solvePnP(
        corr.xyz.reshape(-1, 1, 3), corr.uv.reshape(-1, 1, 2), intr.matrix(), np.asarray(intr.distortion, float),
        cv2.Rodrigues(R_cv)[0], t_cv.reshape(3, 1).copy(), useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE,
    )  # fmt: skip
    assert ok
    optimum = pnp._camera(np.concatenate([rvec.ravel(), tvec.ravel()]), intr, SIZE, False, name)
    off = Rotation.from_rotvec(np.deg2rad(3.0) * np.array([0.6, 0.0, 0.8])).as_matrix()
    start = np.concatenate([cv2.Rodrigues(off @ R_cv)[0].ravel(), t_cv + [0.03, -0.04, 0.0]])
    started = pnp._camera(start, intr, SIZE, False, name)
    monkeypatch.setattr(pnp, "_initial", lambda corr, *a, **k: (start.copy(), np.ones(len(corr), bool)))
    res = calibrate(emb, traj, pts, SIZE, intr)
    assert position_error_mm(started, optimum) > 40 and rotation_error_deg(started, optimum) > 2.9
    assert position_error_mm(res.camera, optimum) < 0.01 and rotation_error_deg(res.camera, optimum) < 1e-3
    from oscar_core import project

    def rms(camera):
        return float(np.sqrt(np.mean(np.sum((project(corr.xyz, camera).uv - corr.uv) ** 2, axis=1))))

    assert res.inlier.all() and res.rms_px == pytest.approx(rms(optimum), abs=1e-6) and res.rms_px < 0.75
    assert rms(started) > 10 * res.rms_px
