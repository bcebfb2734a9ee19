"""Tests for oscar_core.camera: projection vs cv2, conventions, resizing, files."""

from __future__ import annotations

import itertools
import json
import os
import warnings

import cv2
import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from oscar_core.camera import (
    CONVENTION_ALIASES,
    CONVENTIONS,
    DIRECTIONS,
    Camera,
    Intrinsics,
    camera_from_dict,
    camera_to_dict,
    convention_to_opencv,
    load_camera,
    project,
    project_points_cv,
    save_camera,
)
from oscar_core.errors import CameraFileError, OutputPathError

ALL_CONVENTIONS = list(CONVENTIONS) + list(CONVENTION_ALIASES)


# --------------------------------------------------------------------------- helpers


def random_pose(rng: np.random.Generator) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = rng.uniform(-2.0, 2.0, 3)
    return T


def random_intrinsics(rng: np.random.Generator, n_dist: int) -> Intrinsics:
    W, H = int(rng.integers(320, 1920)), int(rng.integers(240, 1080))
    mild = {
        4: [0.1, 0.05, 0.005, 0.005],
        5: [0.1, 0.05, 0.005, 0.005, 0.02],
        8: [0.1, 0.05, 0.005, 0.005, 0.02, 0.05, 0.02, 0.01],
        12: [0.1, 0.05, 0.005, 0.005, 0.02, 0.05, 0.02, 0.01, 0.003, 0.003, 0.003, 0.003],
    }
    dist = tuple(rng.uniform(-1, 1, n_dist) * np.array(mild[n_dist])) if n_dist else ()
    return Intrinsics(
        fx=rng.uniform(300, 900),
        fy=rng.uniform(300, 900),
        cx=W / 2 + rng.uniform(-20, 20),
        cy=H / 2 + rng.uniform(-20, 20),
        width=W,
        height=H,
        distortion=dist,
    )


def points_in_view(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) points in the OpenCV camera frame, |x/z|, |y/z| <= 0.6, z in [0.3, 5]."""
    z = rng.uniform(0.3, 5.0, n)
    xy = rng.uniform(-0.6, 0.6, (n, 2)) * z[:, None]
    return np.column_stack([xy, z])


def transform(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ T[:3, :3].T + T[:3, 3]


def cv2_project(points_world: np.ndarray, T_cv_world: np.ndarray, intr: Intrinsics) -> np.ndarray:
    rvec, _ = cv2.Rodrigues(T_cv_world[:3, :3])
    dist = np.array(intr.distortion, dtype=np.float64) if intr.distortion else None
    uv, _ = cv2.projectPoints(points_world.reshape(-1, 1, 3), rvec, T_cv_world[:3, 3].copy(), intr.matrix(), dist)
    return uv.reshape(-1, 2)


def user_extrinsic(T_world_cv: np.ndarray, convention: str, direction: str) -> np.ndarray:
    """The extrinsic a user of ``convention`` / ``direction`` would write for this camera pose."""
    T_world_conv = T_world_cv @ convention_to_opencv(convention)  # T_world_cv @ T_cv_conv
    return T_world_conv if direction == "camera_to_world" else np.linalg.inv(T_world_conv)


# --------------------------------------------------------------------------- projection vs cv2


@pytest.mark.parametrize("n_dist", [0, 4, 5, 8, 12])
@pytest.mark.parametrize("convention", ALL_CONVENTIONS)
@pytest.mark.parametrize("direction", DIRECTIONS)
def test_projection_matches_cv2(n_dist, convention, direction):
    rng = np.random.default_rng(1000 + n_dist)
    for _ in range(3):
        intr = random_intrinsics(rng, n_dist)
        T_world_cv = random_pose(rng)
        pts_world = transform(T_world_cv, points_in_view(rng, 50))
        cam = Camera(intr, user_extrinsic(T_world_cv, convention, direction), convention, direction)
        proj = project(pts_world, cam)
        expected = cv2_project(pts_world, np.linalg.inv(T_world_cv), intr)
        assert proj.uv.shape == (50, 2) and proj.uv.dtype == np.float64
        assert np.abs(proj.uv - expected).max() < 1e-6
        assert proj.in_front.all()
        np.testing.assert_allclose(proj.depth, transform(np.linalg.inv(T_world_cv), pts_world)[:, 2], atol=1e-12)


def test_project_points_cv_and_batch_shapes_and_torch():
    rng = np.random.default_rng(7)
    intr = random_intrinsics(rng, 5)
    pts = points_in_view(rng, 24)
    expected = cv2_project(pts, np.eye(4), intr)
    proj = project_points_cv(pts.reshape(2, 3, 4, 3), intr)
    assert proj.uv.shape == (2, 3, 4, 2) and proj.depth.shape == (2, 3, 4)
    assert proj.in_image.shape == (2, 3, 4) and proj.visible is proj.in_image
    assert np.abs(proj.uv.reshape(-1, 2) - expected).max() < 1e-6
    cam = Camera(intr, np.eye(4))
    proj_t = project(torch.tensor(pts, dtype=torch.float64, requires_grad=True), cam)
    assert np.abs(proj_t.uv - expected).max() < 1e-6


def test_moving_camera_matches_hand_composition():
    rng = np.random.default_rng(3)
    T, K = 81, 20
    intr = random_intrinsics(rng, 8)
    T_link_cv = random_pose(rng)
    T_world_link = np.stack([random_pose(rng) for _ in range(T)])
    pts_cv = points_in_view(rng, T * K).reshape(T, K, 3)
    pts_world = (
        np.einsum(
            "tij,tkj->tki",
            T_world_link[:, :3, :3],
            np.einsum("ij,tkj->tki", T_link_cv[:3, :3], pts_cv) + T_link_cv[:3, 3],
        )
        + T_world_link[:, None, :3, 3]
    )
    for convention, direction in itertools.product(CONVENTIONS, DIRECTIONS):
        cam = Camera(
            intr, user_extrinsic(T_link_cv, convention, direction), convention, direction, mount_link="head_link"
        )
        proj = project(pts_world, cam, mount_pose=T_world_link)
        assert proj.uv.shape == (T, K, 2)
        for t in range(0, T, 10):
            T_cv_world = np.linalg.inv(T_world_link[t] @ T_link_cv)
            np.testing.assert_allclose(cam.world_to_cv(T_world_link[t]), T_cv_world, atol=1e-12)
            assert np.abs(proj.uv[t] - cv2_project(pts_world[t], T_cv_world, intr)).max() < 1e-6
        # a single (4, 4) mount pose works for one frame of points
        one = project(pts_world[5], cam, mount_pose=T_world_link[5])
        np.testing.assert_allclose(one.uv, proj.uv[5], atol=1e-9)


def test_mount_pose_misuse_raises():
    intr = Intrinsics(500, 500, 320, 240, 640, 480)
    static = Camera(intr, np.eye(4))
    mounted = Camera(intr, np.eye(4), mount_link="wrist")
    with pytest.raises(ValueError, match="static"):
        static.world_to_cv(np.eye(4))
    with pytest.raises(ValueError, match="wrist"):
        project(np.zeros((3, 3)), mounted)
    with pytest.raises(ValueError, match="shape"):
        project(np.zeros((4, 2, 3)), mounted, mount_pose=np.tile(np.eye(4), (5, 1, 1)))


# --------------------------------------------------------------------------- conventions


@pytest.mark.parametrize("convention", ALL_CONVENTIONS)
def test_point_straight_ahead_hits_principal_point(convention):
    forward = {
        "opencv": [0, 0, 1],
        "ros_optical": [0, 0, 1],
        "opengl": [0, 0, -1],
        "blender": [0, 0, -1],
        "ros_body": [1, 0, 0],
        "ros": [1, 0, 0],
    }[convention]
    intr = Intrinsics(600, 610, 333.0, 244.0, 640, 480, (0.1, -0.05, 0.01, 0.002, 0.01))
    T_world_cam = random_pose(np.random.default_rng(11))  # camera pose in its own convention
    point = transform(T_world_cam, np.array(forward, dtype=float))
    for direction, E in (("camera_to_world", T_world_cam), ("world_to_camera", np.linalg.inv(T_world_cam))):
        proj = project(point, Camera(intr, E, convention, direction))
        np.testing.assert_allclose(proj.uv, [333.0, 244.0], atol=1e-9)
        assert proj.depth == pytest.approx(1.0) and proj.in_image


def test_convention_matrices_and_unknown_name():
    # opengl/blender: y up and z backward flip sign; ros_body: x fwd, y left, z up.
    np.testing.assert_array_equal(convention_to_opencv("blender") @ [0, 1, 0, 1], [0, -1, 0, 1])
    np.testing.assert_array_equal(convention_to_opencv("ros") @ [1, 2, 3, 1], [-2, -3, 1, 1])
    with pytest.raises(ValueError, match="opengl"):
        convention_to_opencv("unreal")
    with pytest.raises(ValueError, match="convention"):
        Camera(Intrinsics(1, 1, 0, 0, 2, 2), np.eye(4), convention="unreal")
    assert Camera(Intrinsics(1, 1, 0, 0, 2, 2), np.eye(4), convention="blender").convention == "opengl"


# --------------------------------------------------------------------------- masks


def test_behind_and_nan_points_no_warnings():
    intr = Intrinsics(500, 500, 320, 240, 640, 480, (0.1, 0.01, 0.0, 0.0, 0.01, 0.02, 0.0, 0.0))
    pts = np.array(
        [[0, 0, -1.0], [0.1, 0.1, 0.0], [np.nan, 0, 1], [0, 0, np.nan], [np.inf, 0, 1], [0, 0, 1e-9], [0, 0, 2.0]]
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        proj = project(pts, Camera(intr, np.eye(4)))
    # inf * 0 in the rigid transform gives NaN depth: non-finite input is never in front
    np.testing.assert_array_equal(proj.in_front, [False, False, False, False, False, False, True])
    np.testing.assert_array_equal(proj.in_image, [False, False, False, False, False, False, True])
    assert np.isnan(proj.uv[2:4]).all()


def test_in_image_boundary_uses_pixel_edges():
    # Image spans [-0.5, W - 0.5) x [-0.5, H - 0.5): pixel centres at integers.
    W, H = 64, 48
    intr = Intrinsics(100.0, 100.0, 10.0, 10.0, W, H)
    u = np.array([-0.5, -0.5 - 1e-9, W - 0.5 - 1e-9, W - 0.5, 10.0, 10.0, 10.0, 10.0])
    v = np.array([10.0, 10.0, 10.0, 10.0, -0.5, -0.5 - 1e-9, H - 0.5 - 1e-9, H - 0.5])
    pts = np.column_stack([(u - 10.0) / 100.0, (v - 10.0) / 100.0, np.ones_like(u)])
    proj = project_points_cv(pts, intr)
    np.testing.assert_allclose(proj.uv, np.column_stack([u, v]), atol=1e-12)
    np.testing.assert_array_equal(proj.in_image, [True, False, True, False, True, False, True, False])


# --------------------------------------------------------------------------- resizing


def test_resized_crop_and_stretch_hand_worked():
    intr = Intrinsics(600.0, 600.0, 640.0, 360.0, 1280, 720, (0.1, 0.01, 0.0, 0.0))
    # crop 1280x720 -> 512x512: source wider than 1:1, keep 720 columns centred:
    #   x0 = (1280 - 720) / 2 = 280, y0 = 0; scale s = 512 / 720.
    #   fx = 600 * 512/720 = 426.666..., cx = (640 - 280 + 0.5) * 512/720 - 0.5 = 255.855...,
    #   cy = (360 + 0.5) * 512/720 - 0.5 = 255.855...
    r = intr.resized(512, 512)
    s = 512 / 720
    assert (r.width, r.height, r.distortion) == (512, 512, intr.distortion)
    assert r.fx == pytest.approx(426.6666666667) and r.fy == pytest.approx(426.6666666667)
    assert r.cx == pytest.approx(360.5 * s - 0.5) and r.cx == pytest.approx(255.8555555556)
    assert r.cy == pytest.approx(360.5 * s - 0.5)
    # crop 640x480 -> 320x120 (aspect 8:3): source taller, keep 640 x 240 rows centred:
    #   y0 = (480 - 240) / 2 = 120, s = 0.5; cx = (330 + 0.5) * 0.5 - 0.5 = 164.75,
    #   cy = (250 - 120 + 0.5) * 0.5 - 0.5 = 64.75, fx = 250, fy = 260.
    r = Intrinsics(500.0, 520.0, 330.0, 250.0, 640, 480).resized(320, 120)
    assert (r.fx, r.fy, r.cx, r.cy, r.width, r.height) == pytest.approx((250, 260, 164.75, 64.75, 320, 120))
    # stretch 1280x720 -> 640x480: sx = 0.5, sy = 2/3.
    #   fx = 300, fy = 400, cx = 640.5 * 0.5 - 0.5 = 319.75, cy = 360.5 * 2/3 - 0.5 = 239.8333...
    r = intr.resized(640, 480, mode="stretch")
    assert (r.fx, r.fy, r.cx, r.cy) == pytest.approx((300, 400, 319.75, 239.8333333333))
    # crop(x0, y0, w, h) just shifts the principal point.
    c = intr.crop(100, 50, 400, 300)
    assert (c.cx, c.cy, c.fx, c.width, c.height) == (540.0, 310.0, 600.0, 400, 300)
    with pytest.raises(ValueError, match="mode"):
        intr.resized(10, 10, mode="fit")


@pytest.mark.parametrize("size", [(512, 512), (320, 120), (1920, 1080), (300, 700)])
@pytest.mark.parametrize("mode", ["crop", "stretch"])
def test_resized_projection_equals_transformed_pixels(size, mode):
    rng = np.random.default_rng(5)
    intr = random_intrinsics(rng, 12)
    pts = points_in_view(rng, 40)
    W, H = intr.width, intr.height
    w, h = size
    if mode == "crop":
        s = min(W / w, H / h)  # source pixels per output pixel
        cw, ch = w * s, h * s
        x0, y0, sx, sy = (W - cw) / 2, (H - ch) / 2, 1 / s, 1 / s
    else:
        x0, y0, sx, sy = 0.0, 0.0, w / W, h / H
    uv = project_points_cv(pts, intr).uv
    expected = np.column_stack([(uv[:, 0] - x0 + 0.5) * sx - 0.5, (uv[:, 1] - y0 + 0.5) * sy - 0.5])
    cam = Camera(intr, np.eye(4)).resized(w, h, mode)
    np.testing.assert_allclose(project(pts, cam).uv, expected, atol=1e-8)
    crop = intr.crop(13, 7, 100, 90)
    np.testing.assert_allclose(project_points_cv(pts, crop).uv, uv - [13, 7], atol=1e-9)


# --------------------------------------------------------------------------- files


def base_dict(**extrinsic) -> dict:
    return {
        "image_size": [1280, 720],
        "intrinsics": {"fx": 600.0, "fy": 610.0, "cx": 640.0, "cy": 360.0},
        "distortion": [-0.05, 0.01, 0.001, 0.0, 0.0],
        "extrinsic": extrinsic or {"xyz_rpy": [0.5, 0.1, 1.2, 0.1, 0.6, 3.0]},
        "convention": "ros",
        "direction": "camera_to_world",
        "mount": {"link": "head_link"},
        "embodiment": "franka",
    }


def write(tmp_path, d, name="cam.json"):
    p = tmp_path / name
    p.write_text(d if isinstance(d, str) else json.dumps(d, indent=2))
    return p


def test_json_round_trip_and_extrinsic_forms(tmp_path):
    xyz, rpy = [0.5, 0.1, 1.2], [0.1, 0.6, 3.0]
    R = Rotation.from_euler("xyz", rpy)
    cam = load_camera(write(tmp_path, base_dict(xyz_rpy=xyz + rpy)))
    np.testing.assert_allclose(cam.extrinsic[:3, :3], R.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(cam.extrinsic[:3, 3], xyz)
    assert (cam.convention, cam.mount_link, cam.embodiment) == ("ros_body", "head_link", "franka")
    assert cam.intrinsics.distortion == (-0.05, 0.01, 0.001, 0.0, 0.0)

    for form, value in (("xyz_quat_xyzw", xyz + list(R.as_quat())), ("matrix", cam.extrinsic.tolist())):
        other = load_camera(write(tmp_path, base_dict(**{form: value}), f"{form}.json"))
        np.testing.assert_allclose(other.extrinsic, cam.extrinsic, atol=1e-12)

    d = base_dict()
    d["intrinsics"] = {"K": [[600.0, 0, 640.0], [0, 610.0, 360.0], [0, 0, 1]]}
    assert load_camera(write(tmp_path, d, "k.json")).intrinsics == cam.intrinsics

    out = tmp_path / "saved.json"
    save_camera(cam, out)
    assert load_camera(out) == cam
    assert camera_from_dict(camera_to_dict(cam)) == cam
    assert sorted(os.listdir(tmp_path)) == sorted(
        ["cam.json", "xyz_quat_xyzw.json", "matrix.json", "k.json", "saved.json"]
    )

    minimal = {
        "image_size": [64, 48],
        "intrinsics": {"fx": 1, "fy": 1, "cx": 0, "cy": 0},
        "extrinsic": {"matrix": np.eye(4).tolist()},
    }
    m = camera_from_dict(minimal)
    assert (m.convention, m.direction, m.mount_link, m.intrinsics.distortion) == ("opencv", "camera_to_world", None, ())


def _bad(**changes):
    d = base_dict()
    for k, v in changes.items():
        if v is KeyError:
            del d[k]
        else:
            d[k] = v
    return d


@pytest.mark.parametrize(
    "content, field",
    [
        (_bad(intrinsics=KeyError), "intrinsics"),
        ('{"image_size": [640, 480],\n  "intrinsics": {"fx": 1,,}}', "<document>"),
        (_bad(extrinsic={"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}), "extrinsic.matrix"),
        (_bad(extrinsic={"matrix": [[1, 0.01, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}), "extrinsic.matrix"),
        (_bad(convention="unreal"), "convention"),
        (_bad(direction="sideways"), "direction"),
        (_bad(camera_name="front"), "camera_name"),
        (_bad(intrinsics={"fx": "600", "fy": 600, "cx": 1, "cy": 1}), "intrinsics.fx"),
        (_bad(intrinsics={"fx": 600, "fy": -1, "cx": 1, "cy": 1}), "intrinsics.fy"),
        (_bad(image_size=[640]), "image_size"),
        (_bad(distortion=[0.0] * 14), "distortion"),
        (_bad(distortion=[0.0] * 6), "distortion"),
        (_bad(extrinsic={"xyz_rpy": [0, 0, 0]}), "extrinsic.xyz_rpy"),
        (_bad(extrinsic={"euler": [0, 0, 0]}), "extrinsic"),
        (_bad(mount={"joint": "x"}), "mount"),
    ],
)
def test_bad_files_name_file_and_field(tmp_path, content, field):
    path = write(tmp_path, content, "bad_camera.json")
    with pytest.raises(CameraFileError) as exc:
        load_camera(path)
    msg = str(exc.value)
    assert "bad_camera.json" in msg and f"'{field}'" in msg and exc.value.field == field
    assert isinstance(exc.value, ValueError)


def test_error_details(tmp_path):
    with pytest.raises(CameraFileError, match=r"line 2, column"):
        load_camera(write(tmp_path, '{"image_size": [1, 1],\n "x": }'))
    with pytest.raises(CameraFileError, match=r"R\^T R - I\| = 0\.01"):
        camera_from_dict(_bad(extrinsic={"matrix": [[1, 0.01, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}))
    with pytest.raises(CameraFileError, match="image_size"):  # valid keys are listed
        camera_from_dict(_bad(foo=1))
    with pytest.raises(CameraFileError, match="tilt"):
        Intrinsics(1, 1, 0, 0, 2, 2, (0.0,) * 14)
    with pytest.raises(CameraFileError, match="det"):
        Camera(Intrinsics(1, 1, 0, 0, 2, 2), np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(CameraFileError, match="last row"):
        Camera(Intrinsics(1, 1, 0, 0, 2, 2), np.array([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]))


def test_atomic_save_into_missing_directory(tmp_path):
    cam = Camera(Intrinsics(500, 500, 320, 240, 640, 480), np.eye(4))
    target = tmp_path / "missing" / "cam.json"
    with pytest.raises(OutputPathError, match="missing"):
        save_camera(cam, target)
    assert os.listdir(tmp_path) == []
    # overwriting an existing file goes through a temp file that is cleaned up
    save_camera(cam, tmp_path / "cam.json")
    save_camera(cam.resized(320, 240), tmp_path / "cam.json")
    assert os.listdir(tmp_path) == ["cam.json"]
    assert load_camera(tmp_path / "cam.json").intrinsics.width == 320


def test_defaults_from_the_embodiment_spec_fill_omitted_keys(tmp_path):
    from oscar_core.plugin.embodiment import CameraSpec

    d = {
        "image_size": [640, 480],
        "intrinsics": {"fx": 500, "fy": 500, "cx": 320, "cy": 240},
        "extrinsic": {"matrix": np.eye(4).tolist()},
    }
    p = tmp_path / "cam.json"
    p.write_text(json.dumps(d))
    spec = CameraSpec(convention="opengl", direction="world_to_camera")
    cam = load_camera(p, defaults=spec)
    assert (cam.convention, cam.direction) == ("opengl", "world_to_camera")
    d["convention"] = "opencv"
    p.write_text(json.dumps(d))
    assert load_camera(p, defaults=spec).convention == "opencv"  # the file wins
    assert load_camera(p).direction == "camera_to_world"


def test_float32_calibration_is_accepted_and_made_orthonormal():
    from scipy.spatial.transform import Rotation

    R = Rotation.from_euler("xyz", [0.3, -1.1, 2.0]).as_matrix()
    M = np.eye(4)
    M[:3, :3] = R + 2e-5 * np.random.default_rng(0).normal(size=(3, 3))  # a calibration stored with few digits
    cam = Camera(Intrinsics(500, 500, 320, 240, 640, 480), M)
    Rc = cam.extrinsic[:3, :3]
    assert np.abs(Rc.T @ Rc - np.eye(3)).max() < 1e-12 and np.abs(Rc - R).max() < 1e-4
    M[:3, :3] = R * 1.01
    with pytest.raises(CameraFileError, match="orthonormal"):
        Camera(Intrinsics(500, 500, 320, 240, 640, 480), M)
