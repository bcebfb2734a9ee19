"""The kuka plugin: the xacro, FK against an independent URDF, the RH20T adapter, bad input.

FK oracle: ``rtbdata/xacro/kuka_description/kuka_lbr_iiwa/urdf/lbr_iiwa_14_r820.urdf``
from the ``rtb-data`` wheel (ros-industrial kuka_experimental's description,
MIT), evaluated with yourdfpy (an independent parser and FK). Its meshes are
never opened. Frame correspondence (both place each link frame on its joint
axis, parallel to the base at q = 0, so no re-mapping of axes is needed):

    oracle base_link <-> lbr_iiwa_link_0,  link_k <-> lbr_iiwa_link_k (k = 1..7),
    oracle tool0 <-> lbr_iiwa_flange,      joint_ak <-> lbr_iiwa_joint_k.

The oracle shifts the A2 and A4 axes by -/+0.43624 mm along x (a CAD offset;
KUKA's data sheet has all axes intersecting, which is our default). The xacro
exposes it as the ``axis_offset`` argument: with the oracle's value every
corresponding frame agrees to 1e-6 m; with the default the difference is
bounded by the offset (checked separately).
"""

import importlib.metadata

import numpy as np
import pytest
from render.golden_cases.kuka import CONFIGS as GOLDEN_CONFIGS

from oscar_core import (
    Camera,
    CameraFileError,
    Intrinsics,
    KinematicsFileError,
    Trajectory,
    TrajectoryError,
    project,
    render_skeleton_video,
)
from oscar_embodiments import kuka as kuka_plugin
from oscar_embodiments.kuka import ASSETS, JOINT_NAMES, KukaIiwa14
from oscar_embodiments.kuka.adapters import from_rh20t, rh20t_base_to_camera

ORACLE_SUFFIX = "rtbdata/xacro/kuka_description/kuka_lbr_iiwa/urdf/lbr_iiwa_14_r820.urdf"
ORACLE_AXIS_OFFSET = 0.00043624
OURS = [f"lbr_iiwa_link_{k}" for k in range(8)] + ["lbr_iiwa_flange"]
THEIRS = ["base_link"] + [f"link_{k}" for k in range(1, 8)] + ["tool0"]
HOME = [0.0, 0.3, 0.0, -1.5, 0.0, 1.3, 0.0]


@pytest.fixture(scope="module")
def kuka():
    return KukaIiwa14()


class KukaAsOracle(KukaIiwa14):
    """The same xacro with the oracle's A2/A4 axis offset."""

    xacro_args = {**KukaIiwa14.xacro_args, "axis_offset": str(ORACLE_AXIS_OFFSET)}


@pytest.fixture(scope="module")
def oracle():
    yourdfpy = pytest.importorskip("yourdfpy")
    try:
        dist = importlib.metadata.distribution("rtb-data")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("rtb-data is not installed (pip install 'oscar-wm[dev]')")
    path = next((dist.locate_file(f) for f in dist.files or () if f.as_posix().endswith(ORACLE_SUFFIX)), None)
    assert path is not None, f"rtb-data {dist.version} has no {ORACLE_SUFFIX}"
    return yourdfpy.URDF.load(
        str(path), load_meshes=False, build_collision_scene_graph=False, load_collision_meshes=False
    )


def oracle_poses(urdf, Q):
    out = np.empty((len(Q), len(THEIRS), 4, 4))
    for i, q in enumerate(Q):
        urdf.update_cfg(q)
        out[i] = [urdf.get_transform(name, "base_link") for name in THEIRS]
    return out


def our_poses(emb, Q):
    full = np.concatenate([Q, np.zeros((len(Q), 1))], axis=1)  # + the (unused) finger joint
    return emb.fk(full, links=OURS).numpy()


def configurations(emb, n=30, seed=0):
    lo, hi = emb.tree.limits()
    rng = np.random.default_rng(seed)
    corners = np.stack([lo[:7], hi[:7], np.zeros(7)])
    return np.concatenate([corners, rng.uniform(lo[:7], hi[:7], size=(n, 7))])


# --------------------------------------------------------------------------- kinematics


def test_hook_returns_the_class():
    assert kuka_plugin.oscar_register_embodiments() == [KukaIiwa14]


def test_registered_through_the_entry_point():
    if "kuka" not in {ep.name for ep in importlib.metadata.entry_points(group="oscar")}:
        pytest.skip("oscar is not installed (pip install -e .): no entry points to check")
    from oscar_core import get_embodiment

    assert isinstance(get_embodiment("kuka"), KukaIiwa14)


def test_xacro_expands_with_its_package_and_joint_order(kuka):
    assert kuka.xacro == ASSETS / "lbr_iiwa_14_r820.urdf.xacro"
    assert "$(find oscar_kuka_description)" in kuka.xacro.read_text()
    assert kuka.joint_names == JOINT_NAMES == tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8))
    assert kuka.tree.joint_names == JOINT_NAMES + ("gripper_finger_joint",)


def test_unresolvable_package_names_the_package():
    class NoPackages(KukaIiwa14):
        packages = {}

    with pytest.raises(KinematicsFileError, match=r"oscar_kuka_description"):
        NoPackages()


def test_limits_are_kukas_published_ones(kuka, oracle):
    lo, hi = kuka.tree.limits()
    deg = np.array([170, 120, 170, 120, 170, 120, 175.0])
    assert np.allclose(hi[:7], np.radians(deg)) and np.allclose(lo[:7], -np.radians(deg))
    theirs = [oracle.joint_map[f"joint_a{k}"].limit for k in range(1, 8)]
    assert np.allclose(hi[:7], [l.upper for l in theirs], atol=1e-3)  # the oracle rounds to 1e-4 rad
    assert np.allclose(lo[:7], [l.lower for l in theirs], atol=1e-3)


def test_fk_matches_the_oracle_on_every_corresponding_frame(oracle):
    ours = KukaAsOracle()
    Q = configurations(ours)
    P, R = our_poses(ours, Q), oracle_poses(oracle, Q)
    assert np.abs(P[..., :3, 3] - R[..., :3, 3]).max() < 1e-6  # metres
    assert np.abs(P[..., :3, :3] - R[..., :3, :3]).max() < 1e-9  # same axes


def test_kuka_data_sheet_geometry_differs_only_by_the_cad_offset(kuka, oracle):
    Q = configurations(kuka, seed=1)
    err = np.linalg.norm(our_poses(kuka, Q)[..., :3, 3] - oracle_poses(oracle, Q)[..., :3, 3], axis=-1)
    assert err.max() <= 2 * ORACLE_AXIS_OFFSET + 1e-9
    assert err[:, :2].max() < 1e-12  # base and A1 frames: no offset before A2
    assert np.abs(our_poses(kuka, Q)[..., :3, :3] - oracle_poses(oracle, Q)[..., :3, :3]).max() < 1e-9


def test_published_lengths_when_stretched(kuka):
    z = our_poses(kuka, np.zeros((1, 7)))[0, :, 2, 3]
    assert np.allclose(z, [0, 0, 0.36, 0.36, 0.78, 0.78, 1.18, 1.18, 1.306], atol=1e-12)


@pytest.mark.parametrize("position", [0.0, 0.5, 1.0])
def test_jaw_opens_with_the_robotiq_position(kuka, position):
    traj = kuka.check_trajectory(Trajectory(JOINT_NAMES, [HOME], fps=10, gripper=[[position]]))
    frames = kuka.frames(traj)
    k = {l: i for i, l in enumerate(kuka.skeleton.links)}
    tips = frames.points[0, [k["gripper_left_finger"], k["gripper_right_finger"]]]
    assert np.linalg.norm(tips[0] - tips[1]) == pytest.approx(0.085 * (1 - position), abs=1e-12)
    assert frames.openness[0, 0] == pytest.approx(1 - position)
    palm = frames.points[0, k["gripper_palm"]]
    assert np.linalg.norm(tips.mean(0) - palm) == pytest.approx(0.10, abs=1e-12)  # tool_length - palm_length


def test_tool_length_is_a_xacro_argument():
    class LongTool(KukaIiwa14):
        xacro_args = {**KukaIiwa14.xacro_args, "tool_length": "0.30"}

    P = LongTool().fk(np.zeros((1, 8)), links=["lbr_iiwa_flange", "gripper_tcp"]).numpy()[0]
    assert P[1, 2, 3] - P[0, 2, 3] == pytest.approx(0.30)


def test_golden_near_limits_config_is_within_limits(kuka):
    """The near-limits configuration of the golden images (tests/render/golden_cases/kuka.py) is inside the
    limits, less than 0.1 rad from one of them."""
    lo, hi = kuka.tree.limits()
    q = np.array(GOLDEN_CONFIGS["near_limits_closed"][0])
    assert np.all(q > lo[:7]) and np.all(q < hi[:7])
    assert np.min(np.minimum(q - lo[:7], hi[:7] - q)) < 0.1


# --------------------------------------------------------------------------- RH20T cfg7


SERIAL, IN_HAND = "104122061602", "135122075425"


def rigid(rng):
    A, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    T = np.eye(4)
    T[:3, :3] = A * np.sign(np.linalg.det(A))
    T[:3, 3] = rng.uniform(-1, 1, 3)
    return T


def rh20t_record(T=8):
    rng = np.random.default_rng(5)
    ts = 1650000000000 + 100 * np.arange(T)
    lo, hi = KukaIiwa14().tree.limits()
    q = rng.uniform(lo[:7] + 0.05, hi[:7] - 0.05, size=(T, 7))
    joint = {SERIAL: {str(t): q[i] for i, t in enumerate(ts)}}  # keys as stored, here strings
    widths = np.array([85.0, 85.0, 60.0, 42.5, 20.0, 0.0, 0.0, 85.0])
    gripper = {SERIAL: {int(t): {"gripper_info": [w, 0.0, 0.0]} for t, w in zip(ts, widths)}}
    K = np.array([[915.0, 0.0, 641.0, 0.0], [0.0, 914.0, 360.0, 0.0], [0.0, 0.0, 1.0, 0.0]], dtype=np.float32)
    E = rigid(rng).astype(np.float32)[None]  # RH20T stores float32 (1, 4, 4)
    return joint, gripper, {SERIAL: K}, {SERIAL: E}, q, ts, widths


def test_rh20t_cfg7_layout(kuka):
    joint, gripper, intr, ext, q, ts, widths = rh20t_record()
    traj, cam = from_rh20t(joint, gripper, intr, ext, SERIAL)
    assert traj.joint_names == JOINT_NAMES and np.allclose(traj.q, q)
    assert traj.fps == pytest.approx(10.0) and np.allclose(traj.timestamps, (ts - ts[0]) / 1000)
    # RH20T width (mm) -> Robotiq position: 85 mm = 0 (open), 0 mm = 1 (closed)
    assert np.allclose(traj.gripper[:, 0], 1 - widths / 85)
    assert np.allclose(traj.gripper[[0, 3, 5], 0], [0.0, 0.5, 1.0])
    assert cam.direction == "world_to_camera" and cam.embodiment == "kuka"
    assert np.allclose(cam.extrinsic, ext[SERIAL][0], atol=1e-6)  # re-orthonormalised float32
    t = cam.extrinsic[:3, 3]
    assert np.allclose(project(np.zeros(3), cam).uv, (intr[SERIAL][:, :3].astype(float) @ t)[:2] / t[2])
    video = render_skeleton_video(kuka, traj, cam, (128, 72))
    assert video.shape == (8, 72, 128, 3)


def test_rh20t_base_to_camera_recovers_the_base_aligned_extrinsic():
    rng = np.random.default_rng(6)
    T_cam_base, T_world_base, T_base_tcp, tc_mat = (rigid(rng) for _ in range(4))
    E = {
        SERIAL: T_cam_base @ np.linalg.inv(T_world_base),
        IN_HAND: tc_mat @ np.linalg.inv(T_base_tcp) @ np.linalg.inv(T_world_base),
    }
    R = T_base_tcp[:3, :3]  # rotation -> (w, x, y, z), R is proper and not a half turn here
    w = np.sqrt(1 + np.trace(R)) / 2
    xyz = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (4 * w)
    calib_tcp = np.concatenate([T_base_tcp[:3, 3], [w], xyz])
    assert np.allclose(rh20t_base_to_camera(E, SERIAL, IN_HAND, tc_mat, calib_tcp), T_cam_base, atol=1e-9)


def test_rh20t_bad_input():
    joint, gripper, intr, ext, *_ = rh20t_record()
    joint[SERIAL] = {t: v[:6] for t, v in joint[SERIAL].items()}
    with pytest.raises(TrajectoryError, match=r"7 values per frame: \['lbr_iiwa_joint_1'.*found 6 values"):
        from_rh20t(joint, gripper, intr, ext, SERIAL)
    joint, gripper, intr, ext, *_ = rh20t_record()
    first = min(gripper[SERIAL])
    gripper[SERIAL][first]["gripper_info"] = [255.0, 0, 0]  # the raw Robotiq byte, not millimetres
    with pytest.raises(TrajectoryError, match=r"Robotiq 2F-85 width in millimetres in \[0, 85\].*255 at frame 0"):
        from_rh20t(joint, gripper, intr, ext, SERIAL)
    joint, gripper, intr, ext, *_ = rh20t_record()
    joint[SERIAL] = {t: np.degrees(v) for t, v in joint[SERIAL].items()}
    with pytest.raises(TrajectoryError, match=r"radians.*degrees\?"):
        from_rh20t(joint, gripper, intr, ext, SERIAL)
    joint, gripper, intr, ext, *_ = rh20t_record()
    with pytest.raises(CameraFileError, match=rf"intrinsics\['{SERIAL}'\].*have \['1'\].*missing"):
        from_rh20t(joint, gripper, {"1": intr[SERIAL]}, ext, SERIAL)


# --------------------------------------------------------------------------- bad input through the plugin


CAM = Camera(Intrinsics(500.0, 500.0, 63.5, 35.5, 128, 72), np.eye(4), direction="world_to_camera")


def test_wrong_joint_count_or_names_are_refused(kuka):
    panda = tuple(f"panda_joint{i}" for i in range(1, 8))
    with pytest.raises(TrajectoryError, match=r"the 7 joints of 'kuka'.*lbr_iiwa_joint_1.*unknown \['panda_joint1'"):
        render_skeleton_video(kuka, Trajectory(panda, np.zeros((2, 7)), fps=10, gripper=np.zeros((2, 1))), CAM)
    with pytest.raises(TrajectoryError, match=r"missing \['lbr_iiwa_joint_7'\]"):
        render_skeleton_video(
            kuka, Trajectory(JOINT_NAMES[:6], np.zeros((2, 6)), fps=10, gripper=np.zeros((2, 1))), CAM
        )


def test_gripper_outside_its_range_is_refused(kuka):
    traj = Trajectory(JOINT_NAMES, [HOME, HOME], fps=10, gripper=[[0.2], [42.5]])  # millimetres passed as-is
    with pytest.raises(TrajectoryError, match=r"gripper\[gripper\].*\[0, 1\].*42\.5 at frame 1"):
        render_skeleton_video(kuka, traj, CAM)
    with pytest.raises(TrajectoryError, match=r"gripper.*shape \(T, 1\)"):
        render_skeleton_video(kuka, Trajectory(JOINT_NAMES, [HOME], fps=10), CAM)


def test_camera_for_another_mount_or_embodiment_is_refused(kuka):
    traj = Trajectory(JOINT_NAMES, [HOME], fps=10, gripper=[[0.0]])
    intr = CAM.intrinsics
    with pytest.raises(CameraFileError, match=r"static \(mount: null\) for embodiment 'kuka'.*lbr_iiwa_link_7"):
        render_skeleton_video(kuka, traj, Camera(intr, np.eye(4), mount_link="lbr_iiwa_link_7"))
    with pytest.raises(CameraFileError, match=r"embodiment.*'kuka'.*'franka'"):
        render_skeleton_video(kuka, traj, Camera(intr, np.eye(4), embodiment="franka"))
