"""A fixed camera's pose (and optionally its intrinsics) from 2D–3D correspondences over many frames.

The 3D points are the embodiment's canonical skeleton points, from forward
kinematics of the recorded joints (``Embodiment.frames``, as every renderer gets
them): point k on frame t is ``frames.points[t, k]``, metres in the world / robot
base frame. The 2D points are pixel positions of the same points on the same
frames (:mod:`oscar_core.calibration.points`). Every observation of every frame
is one correspondence of one static camera, so a robot that moves gives many
distinct 3D points.

Steps (:func:`calibrate`):

1. checks that refuse input a camera cannot be computed from, each with its
   reason, before any work (:func:`check_geometry`);
2. a robust first pose: OpenCV's RANSAC PnP (``cv2.solvePnPRansac``). With the
   intrinsics unknown, a sweep of focal lengths (horizontal fields of view
   :data:`FOV_SWEEP_DEG`, principal point at the image centre), each followed by a
   robust (soft-L1) least-squares fit of pose and intrinsics; the sweep keeps the
   fit of lowest robust cost;
3. least squares (``scipy.optimize.least_squares``, Levenberg–Marquardt with
   OpenCV's analytic Jacobian from ``cv2.projectPoints``) over the pose
   [+ fx, fy, cx, cy] on the inliers, the inliers chosen again from the new
   residuals, until they no longer change (at most :data:`MAX_ROUNDS` rounds);
4. the reprojection error of every correspondence with the project's own
   projection (:func:`oscar_core.camera.pinhole.project`), per frame and per point,
   and the outliers (residual > ``threshold_px``) by name.

Distortion: with given intrinsics their distortion is kept fixed; estimated
intrinsics have none.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._util.log import get_logger
from ..camera import Camera, Intrinsics, camera_to_dict, project
from .points import PixelPoints, PointsFileError

__all__ = [
    "MIN_CORRESPONDENCES",
    "DISTINCT_MM",
    "COLLINEAR_RATIO",
    "FOV_SWEEP_DEG",
    "MAX_ROUNDS",
    "Correspondences",
    "CalibrationResult",
    "skeleton_points",
    "build_correspondences",
    "check_geometry",
    "calibrate",
    "rotation_error_deg",
    "position_error_mm",
]

_log = get_logger(__name__)

#: correspondences with distinct 3D points a calibration needs at least (a pose has 6 unknowns, 4 more with intrinsics)
MIN_CORRESPONDENCES = 6
#: two 3D points closer than this (millimetres) are one point (a robot standing still gives the same points per frame)
DISTINCT_MM = 1.0
#: the points are "nearly collinear" when the second singular value of their centred cloud is below this fraction
#: of the first: they spread less than 1 % as far across their main line as along it
COLLINEAR_RATIO = 0.01
#: horizontal fields of view (degrees) tried as first guesses when the intrinsics are estimated
FOV_SWEEP_DEG = (20.0, 30.0, 40.0, 50.0, 60.0, 75.0, 90.0, 110.0)
#: rounds of "refit on the inliers, choose the inliers again"
MAX_ROUNDS = 5


@dataclass(frozen=True)
class Correspondences:
    """N correspondences: frame (N,) int; point (N,) index into ``names``; names: the embodiment's K
    skeleton point names; uv (N, 2) pixels; xyz (N, 3) metres in the world / base frame; source: the
    points file."""

    frame: np.ndarray
    point: np.ndarray
    names: tuple[str, ...]
    uv: np.ndarray
    xyz: np.ndarray
    source: str = "<points>"

    def __len__(self) -> int:
        return len(self.frame)


@dataclass
class CalibrationResult:
    """A calibrated camera and how well it explains the points.

    camera: the :class:`Camera` (OpenCV axes, camera-to-world, static);
    residual_px: (N,) reprojection error of each correspondence, pixels;
    inlier: (N,) bool, residual <= ``threshold_px``; threshold_px: the outlier threshold;
    rms_px: root mean square residual of the inliers; per_frame / per_point: rows
    {frame | point, points, outliers, mean_px, max_px}; outliers: rows
    {index, frame, point, residual_px} (index: the entry in the points file), worst first;
    estimated_intrinsics: whether fx, fy, cx, cy were fitted; rounds: refit rounds run.
    """

    camera: Camera
    residual_px: np.ndarray
    inlier: np.ndarray
    threshold_px: float
    rms_px: float
    per_frame: list[dict] = field(default_factory=list)
    per_point: list[dict] = field(default_factory=list)
    outliers: list[dict] = field(default_factory=list)
    estimated_intrinsics: bool = False
    rounds: int = 0

    def to_dict(self) -> dict:
        """A JSON-ready report (the camera in the camera file format)."""
        return {
            "camera": camera_to_dict(self.camera),
            "correspondences": int(len(self.residual_px)),
            "inliers": int(self.inlier.sum()),
            "threshold_px": self.threshold_px,
            "rms_px": self.rms_px,
            "median_px": float(np.median(self.residual_px)),
            "estimated_intrinsics": self.estimated_intrinsics,
            "rounds": self.rounds,
            "outliers": self.outliers,
            "per_frame": self.per_frame,
            "per_point": self.per_point,
        }


# ----------------------------------------------------------------------------- inputs


def skeleton_points(embodiment, traj) -> np.ndarray:
    """(T, K, 3) world positions (metres) of ``embodiment``'s skeleton points along ``traj`` (checked here),
    by the embodiment's own forward kinematics (``Embodiment.frames``)."""
    return np.asarray(embodiment.frames(embodiment.check_trajectory(traj)).points, dtype=np.float64)


def build_correspondences(
    embodiment, traj, pixels: PixelPoints, size: tuple[int, int], points: np.ndarray | None = None
) -> Correspondences:
    """Pair each observed pixel with its 3D point; :class:`PointsFileError` on an entry that does not fit.

    size: (width, height) of the image the pixels were read on. points: (T, K, 3) skeleton points when
    the caller has them (else :func:`skeleton_points`). Refused, naming the entry: a point name the
    embodiment does not have (its names are listed), a frame beyond the trajectory, a pixel outside the
    image ([-0.5, W - 0.5) x [-0.5, H - 0.5)), a file made for another embodiment.
    """
    src = pixels.source
    names = tuple(embodiment.skeleton.links)
    if pixels.embodiment is not None and pixels.embodiment != embodiment.name:
        raise PointsFileError(src, "embodiment", repr(embodiment.name), repr(pixels.embodiment))
    at = {n: k for k, n in enumerate(names)}
    unknown = [(i, n) for i, n in enumerate(pixels.name) if n not in at]
    if unknown:
        i, n = unknown[0]
        more = f" (and {len(unknown) - 1} more entries)" if len(unknown) > 1 else ""
        raise PointsFileError(
            src, f"points[{i}].point", f"one of {embodiment.name}'s skeleton points {list(names)}", f"{n!r}{more}"
        )
    T = len(traj)
    bad = np.flatnonzero(pixels.frame >= T)
    if bad.size:
        i = int(bad[0])
        raise PointsFileError(
            src, f"points[{i}].frame", f"a frame index below {T} (the trajectory's length)", str(int(pixels.frame[i]))
        )
    W, H = size
    for axis, key, extent in ((0, "u", W), (1, "v", H)):
        outside = np.flatnonzero((pixels.uv[:, axis] < -0.5) | (pixels.uv[:, axis] >= extent - 0.5))
        if outside.size:
            i = int(outside[0])
            raise PointsFileError(
                src,
                f"points[{i}].{key}",
                f"a pixel inside the {W}x{H} image ([-0.5, {extent - 0.5:g}))",
                f"{pixels.uv[i, axis]:g} (frame {int(pixels.frame[i])}, "
                f"point {pixels.name[i]!r}; {outside.size} entries outside)",
            )
    P = skeleton_points(embodiment, traj) if points is None else np.asarray(points, dtype=np.float64)
    idx = np.array([at[n] for n in pixels.name], dtype=np.int64)
    xyz = P[pixels.frame, idx] if len(idx) else np.zeros((0, 3))
    return Correspondences(pixels.frame.copy(), idx, names, pixels.uv.copy(), xyz, src)


def _distinct(xyz: np.ndarray) -> np.ndarray:
    """The distinct 3D points of ``xyz`` (N, 3) metres, two points within :data:`DISTINCT_MM` being one."""
    if len(xyz) == 0:
        return xyz
    cells = np.round(xyz / (DISTINCT_MM * 1e-3)).astype(np.int64)
    _, first = np.unique(cells, axis=0, return_index=True)
    return xyz[np.sort(first)]


def check_geometry(corr: Correspondences, estimate_intrinsics: bool = False) -> None:
    """Refuse correspondences a camera cannot be computed from, with the reason (:class:`PointsFileError`).

    - a robot that did not move (points seen on several frames, none travelling :data:`DISTINCT_MM` or more
      between the frames it is seen on) and fewer than :data:`MIN_CORRESPONDENCES` points on one frame;
    - fewer than :data:`MIN_CORRESPONDENCES` correspondences with distinct 3D points;
    - 3D points (nearly) on one line: singular values s1 >= s2 >= s3 of the centred distinct points with
      s2 < :data:`COLLINEAR_RATIO` · s1 (a pose about that line is then undetermined);
    - with ``estimate_intrinsics``, 3D points (nearly) on one plane (s3 < COLLINEAR_RATIO · s1): one view of a
      plane does not fix the focal length and the pose together.
    """
    src, need = corr.source, MIN_CORRESPONDENCES
    distinct = _distinct(corr.xyz)
    n = len(distinct)
    if len(corr) and n < need:
        travel = 0.0
        for k in np.unique(corr.point):
            p = corr.xyz[corr.point == k]
            travel = max(travel, float(np.linalg.norm(p - p[0], axis=1).max()))
        per_frame = int(np.bincount(corr.frame).max())
        frames = np.unique(corr.frame)
        if travel < DISTINCT_MM * 1e-3 and len(frames) > 1:
            raise PointsFileError(
                src,
                "points",
                f"points on frames where the robot has moved, or at least {need} points on one frame",
                f"a robot that did not move (its observed points travel {travel * 1e3:.2g} mm over the {len(frames)} "
                f"frames seen) and at most {per_frame} points on one frame",
            )
    if n < need:
        raise PointsFileError(
            src, "points", f"at least {need} correspondences with distinct 3D points", f"{n} ({len(corr)} entries)"
        )
    s = np.linalg.svd(distinct - distinct.mean(0), compute_uv=False)
    if s[1] < COLLINEAR_RATIO * s[0]:
        raise PointsFileError(
            src,
            "points",
            "3D points that span more than a line",
            f"{n} nearly collinear points (singular values {s[0]:.3g}, {s[1]:.2g}, {s[2]:.2g} m; "
            f"ratio {s[1] / s[0]:.2g} < {COLLINEAR_RATIO:g})",
        )
    if estimate_intrinsics and s[2] < COLLINEAR_RATIO * s[0]:
        raise PointsFileError(
            src,
            "points",
            "3D points off one plane to estimate intrinsics (or give the intrinsics)",
            f"{n} nearly coplanar points (singular values {s[0]:.3g}, {s[1]:.3g}, {s[2]:.2g} m; "
            f"ratio {s[2] / s[0]:.2g} < {COLLINEAR_RATIO:g})",
        )


# ----------------------------------------------------------------------------- fitting


def _project_cv(params: np.ndarray, xyz: np.ndarray, intr: np.ndarray, dist: np.ndarray, fit_intr: bool):
    """uv (N, 2) and the Jacobian (2N, P) of ``cv2.projectPoints`` for params = rvec, tvec[, fx, fy, cx, cy]."""
    import cv2

    f = params[6:10] if fit_intr else intr
    K = np.array([[f[0], 0.0, f[2]], [0.0, f[1], f[3]], [0.0, 0.0, 1.0]])
    uv, J = cv2.projectPoints(xyz.reshape(-1, 1, 3), params[:3], params[3:6], K, dist)
    cols = slice(0, 10) if fit_intr else slice(0, 6)  # rvec 3, tvec 3, (fx, fy) 2, (cx, cy) 2, distortion …
    return uv.reshape(-1, 2), J[:, cols]


def _fit(params, xyz, uv, intr, dist, fit_intr: bool, loss: str = "linear", f_scale: float = 1.0):
    """Least squares of the pixel residuals over params (see :func:`_project_cv`); returns (params, cost)."""
    from scipy.optimize import least_squares

    def fun(p):
        return (_project_cv(p, xyz, intr, dist, fit_intr)[0] - uv).ravel()

    def jac(p):
        return _project_cv(p, xyz, intr, dist, fit_intr)[1]

    method = "lm" if loss == "linear" and len(uv) * 2 >= len(params) else "trf"
    res = least_squares(fun, params, jac=jac, method=method, loss=loss, f_scale=f_scale, x_scale="jac", max_nfev=200)
    return res.x, float(res.cost)


def _ransac(xyz, uv, K, dist, threshold_px: float, seed: int):
    """(rvec, tvec, inlier mask) from ``cv2.solvePnPRansac``, or None when it finds no pose."""
    import cv2

    cv2.setRNGSeed(int(seed))
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        xyz.reshape(-1, 1, 3),
        uv.reshape(-1, 1, 2),
        K,
        dist,
        iterationsCount=2000,
        reprojectionError=float(threshold_px),
        confidence=0.999,
    )
    if not ok or inl is None or len(inl) < MIN_CORRESPONDENCES:
        return None
    mask = np.zeros(len(uv), bool)
    mask[inl.ravel()] = True
    return rvec.ravel(), tvec.ravel(), mask


def _initial(corr: Correspondences, size, intr: Intrinsics | None, threshold_px: float, seed: int):
    """First parameters (rvec, tvec[, fx, fy, cx, cy]) and inlier mask."""
    W, H = size
    dist = np.asarray(intr.distortion if intr is not None else (), dtype=np.float64)
    if intr is not None:
        got = _ransac(corr.xyz, corr.uv, intr.matrix(), dist, threshold_px, seed)
        if got is None:
            raise PointsFileError(
                corr.source,
                "points",
                f"a pose that puts at least {MIN_CORRESPONDENCES} points within {threshold_px:g} px (RANSAC PnP)",
                "none",
            )
        rvec, tvec, mask = got
        return np.concatenate([rvec, tvec]), mask
    best = None
    cx, cy = (W - 1) / 2.0, (H - 1) / 2.0
    for fov in FOV_SWEEP_DEG:
        f = 0.5 * W / np.tan(np.deg2rad(fov) / 2)
        K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
        got = _ransac(corr.xyz, corr.uv, K, dist, max(3 * threshold_px, 0.02 * max(W, H)), seed)
        if got is None:
            continue
        p0 = np.concatenate([got[0], got[1], [f, f, cx, cy]])
        p, cost = _fit(p0, corr.xyz, corr.uv, None, dist, True, loss="soft_l1", f_scale=threshold_px)
        _log.debug("intrinsics sweep: fov %g deg -> fx %.1f fy %.1f, robust cost %.4g", fov, p[6], p[7], cost)
        if p[6] > 0 and p[7] > 0 and (best is None or cost < best[1]):
            best = (p, cost)
    if best is None:
        raise PointsFileError(
            corr.source,
            "points",
            "a camera that explains the points (RANSAC PnP over fields "
            f"of view {FOV_SWEEP_DEG[0]:g}-{FOV_SWEEP_DEG[-1]:g} degrees)",
            "none",
        )
    p = best[0]
    resid = np.linalg.norm(_project_cv(p, corr.xyz, None, dist, True)[0] - corr.uv, axis=1)
    return p, resid <= threshold_px


def _camera(params: np.ndarray, intr: Intrinsics | None, size, fit_intr: bool, embodiment: str | None) -> Camera:
    import cv2

    R, _ = cv2.Rodrigues(params[:3])
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, params[3:6]  # T_cv_world
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = R.T, -R.T @ params[3:6]  # T_world_cv: the camera's pose
    if fit_intr:
        fx, fy, cx, cy = (float(v) for v in params[6:10])
        intr = Intrinsics(fx, fy, cx, cy, size[0], size[1])
    return Camera(intr, pose, convention="opencv", direction="camera_to_world", embodiment=embodiment)


def _rows(key: str, labels, residual: np.ndarray, inlier: np.ndarray, order=None) -> list[dict]:
    """One row per distinct label (in ``order``, else sorted): {key: label, points, outliers, mean_px, max_px}."""
    out = []
    for label in sorted(set(labels)) if order is None else [x for x in order if x in set(labels)]:
        sel = np.array([lb == label for lb in labels])
        r = residual[sel]
        out.append(
            {
                key: label,
                "points": int(sel.sum()),
                "outliers": int((~inlier[sel]).sum()),
                "mean_px": float(r.mean()),
                "max_px": float(r.max()),
            }
        )
    return out


def calibrate(
    embodiment,
    traj,
    pixels: PixelPoints,
    size: tuple[int, int],
    intrinsics: Intrinsics | None = None,
    *,
    threshold_px: float = 4.0,
    seed: int = 0,
) -> CalibrationResult:
    """A static camera seeing ``embodiment`` move along ``traj`` from the observed ``pixels``.

    size: (width, height) of the image, pixels. intrinsics: the camera's, kept fixed (resized to ``size``
    when calibrated at another size); None estimates fx, fy, cx, cy (no distortion). threshold_px: a
    correspondence whose reprojection error exceeds it is an outlier (left out of the fit, named in the
    result). seed: RANSAC's random seed. Bad input raises :class:`PointsFileError` with its reason before
    any fitting.
    """
    if not (np.isfinite(threshold_px) and threshold_px > 0):
        raise ValueError(f"threshold_px: expected a positive number of pixels, found {threshold_px!r}")
    W, H = int(size[0]), int(size[1])
    if intrinsics is not None and (intrinsics.width, intrinsics.height) != (W, H):
        intrinsics = intrinsics.resized(W, H)
    corr = build_correspondences(embodiment, traj, pixels, (W, H))
    fit_intr = intrinsics is None
    check_geometry(corr, estimate_intrinsics=fit_intr)
    dist = np.asarray(intrinsics.distortion if intrinsics is not None else (), dtype=np.float64)
    fixed = None if fit_intr else np.array([intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy])
    params, inlier = _initial(corr, (W, H), intrinsics, threshold_px, seed)
    rounds = 0
    for rounds in range(1, MAX_ROUNDS + 1):  # noqa: B007 (the count of rounds run is reported)
        if inlier.sum() < MIN_CORRESPONDENCES:
            raise PointsFileError(
                corr.source,
                "points",
                f"at least {MIN_CORRESPONDENCES} points within {threshold_px:g} px of the fitted camera",
                f"{int(inlier.sum())} of {len(corr)}",
            )
        params, _ = _fit(params, corr.xyz[inlier], corr.uv[inlier], fixed, dist, fit_intr)
        uv = _project_cv(params, corr.xyz, fixed, dist, fit_intr)[0]
        new = np.linalg.norm(uv - corr.uv, axis=1) <= threshold_px
        if np.array_equal(new, inlier):
            break
        inlier = new
    camera = _camera(params, intrinsics, (W, H), fit_intr, embodiment.name)
    proj = project(corr.xyz, camera)  # the project's own projection, for the report
    residual = np.linalg.norm(proj.uv - corr.uv, axis=1)
    residual = np.where(proj.in_front, residual, np.inf)
    inlier = residual <= threshold_px
    rms = float(np.sqrt(np.mean(residual[inlier] ** 2))) if inlier.any() else float("nan")
    names = [corr.names[k] for k in corr.point]
    outliers = [
        {"index": int(i), "frame": int(corr.frame[i]), "point": names[i], "residual_px": float(residual[i])}
        for i in np.flatnonzero(~inlier)
    ]
    outliers.sort(key=lambda r: -r["residual_px"])
    result = CalibrationResult(
        camera,
        residual,
        inlier,
        float(threshold_px),
        rms,
        _rows("frame", corr.frame.tolist(), residual, inlier),
        _rows("point", names, residual, inlier, corr.names),
        outliers,
        fit_intr,
        rounds,
    )
    _log.info(
        "calibrated from %d correspondences: %d inliers, rms %.3g px, %d outliers",
        len(corr),
        int(inlier.sum()),
        rms,
        len(outliers),
    )
    return result


# ----------------------------------------------------------------------------- comparing cameras


def rotation_error_deg(a: Camera, b: Camera) -> float:
    """Angle (degrees) of the rotation between the OpenCV camera frames of two static cameras."""
    Ra, Rb = a.world_to_cv()[:3, :3], b.world_to_cv()[:3, :3]
    c = (np.trace(Ra @ Rb.T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def position_error_mm(a: Camera, b: Camera) -> float:
    """Distance (millimetres) between the optical centres of two static cameras."""

    def centre(cam):
        M = cam.world_to_cv()
        return -M[:3, :3].T @ M[:3, 3]

    return float(np.linalg.norm(centre(a) - centre(b)) * 1e3)
