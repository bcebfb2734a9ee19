"""The agibot_g1 plugin: FK against the reference URDF, grippers, head camera, the AgiBot World adapter, bad input.

FK oracle: AgiBot's ``G1_omnipicker.urdf`` (genie_sim, MPL-2.0) in the shared
reference folder, evaluated with yourdfpy (an independent parser and FK); the
test is skipped when that folder is absent. The plugin's ``assets/g1.urdf``
keeps the reference's link and joint names, so links correspond one to one.

The adapter is checked on a small synthetic record built with the layout
documented by AgiBot World (see embodiments/agibot_g1/README.md).
"""

import sys
import types
import warnings
from pathlib import Path

import numpy as np
import pytest
from _paths import SHARED
from render.golden_cases.agibot_g1 import CONFIGS as GOLDEN_CONFIGS

from oscar_core import (
    Camera,
    CameraFileError,
    Intrinsics,
    Trajectory,
    TrajectoryError,
    get_embodiment,
    load_camera,
    load_trajectory,
    render_skeleton_video,
)
from oscar_core.render.skeleton_video import project_skeleton
from oscar_embodiments import agibot_g1 as plugin
from oscar_embodiments.agibot_g1 import HEAD_CAMERA_LINK, JOINTS, LEFT_ARM, RIGHT_ARM, AgiBotG1
from oscar_embodiments.agibot_g1.adapters import (
    AGIBOT_WORLD_FPS,
    HEAD_IMAGE_SIZE,
    MountConsistencyWarning,
    from_agibot_world,
    load_agibot_world_episode,
)

REFERENCE = SHARED / "reference" / "agibot_g1" / "G1_omnipicker.urdf"
READY_L = [1.872, -0.959, -2.46, -1.45, 1.913, 1.476, 0.028]
READY = [0.15, 0.20, 0.0, 0.35] + READY_L + [-v for v in READY_L]
FINGER_JOINTS = ("idx41_gripper_l_outer_joint1", "idx81_gripper_r_outer_joint1")


@pytest.fixture(scope="module")
def g1():
    return AgiBotG1()


def ready(T=1, grip=(0.0, 0.0)):
    return Trajectory(JOINTS, np.tile(READY, (T, 1)), fps=30, gripper=np.tile(grip, (T, 1)))


# --------------------------------------------------------------------------- FK against the reference


@pytest.fixture(scope="module")
def reference():
    yourdfpy = pytest.importorskip("yourdfpy")
    if not REFERENCE.is_file():
        pytest.skip(f"reference URDF not available at {REFERENCE}")
    return yourdfpy.URDF.load(
        str(REFERENCE), load_meshes=False, build_collision_scene_graph=False, load_collision_meshes=False
    )


def test_fk_matches_the_reference_on_random_configurations(g1, reference):
    ours = g1.tree
    assert set(ours.links) <= set(reference.link_map), "every link of the description exists in the reference"
    shared = [n for n in ours.joint_names if n in reference.joint_map]
    assert shared == list(ours.joint_names)  # 18 body joints + the two driven finger joints
    lo, hi = ours.limits()
    rng = np.random.default_rng(7)
    q = rng.uniform(lo, hi, size=(12, len(lo)))
    poses = g1.fk(q, links=list(ours.links)).numpy()
    worst_p = worst_r = 0.0
    for t in range(len(q)):
        reference.update_cfg({n: float(v) for n, v in zip(ours.joint_names, q[t])})  # other joints stay at 0
        for k, link in enumerate(ours.links):
            T = reference.get_transform(link, reference.base_link)
            worst_p = max(worst_p, np.abs(T[:3, 3] - poses[t, k, :3, 3]).max())
            worst_r = max(worst_r, np.abs(T[:3, :3] - poses[t, k, :3, :3]).max())
    assert worst_p < 1e-6 and worst_r < 1e-6, (worst_p, worst_r)


def test_limits_and_mimic_match_the_reference(g1, reference):
    for joint in g1.tree.joints:
        ref = reference.joint_map[joint.name]
        assert (joint.parent, joint.child) == (ref.parent, ref.child)
        if joint.movable:
            assert joint.type == ref.type and np.allclose(joint.axis, ref.axis)
            assert (joint.lower, joint.upper) == pytest.approx((ref.limit.lower, ref.limit.upper))
        if joint.mimic is not None:
            assert (joint.mimic[0], joint.mimic[1]) == (ref.mimic.joint, ref.mimic.multiplier)


# --------------------------------------------------------------------------- the plugin itself


def test_registered_through_the_entry_point(g1):
    assert plugin.oscar_register_embodiments() == [AgiBotG1]
    emb = get_embodiment("agibot_g1")
    assert isinstance(emb, AgiBotG1) and emb.problems() == []
    assert emb.license == "MPL-2.0" and emb.urdf.name == "g1.urdf"


def test_joint_order_and_groups(g1):
    assert g1.joint_names == JOINTS and len(JOINTS) == 18
    assert LEFT_ARM == tuple(f"idx2{i}_arm_l_joint{i}" for i in range(1, 8))
    assert RIGHT_ARM == tuple(f"idx6{i}_arm_r_joint{i}" for i in range(1, 8))
    colors = g1.skeleton.group_colors()
    assert len({colors["left_arm"], colors["right_arm"], colors["torso_head"]}) == 3
    group = g1.skeleton.group_of()
    assert all(group[l] == "left_arm" for l in g1.skeleton.links if "_l_" in l)
    assert all(group[l] == "right_arm" for l in g1.skeleton.links if "_r_" in l)


def test_skeleton_leaves_out_only_coincident_links(g1):
    # arm links 2, 4, 6 sit on links 1, 3, 5 for every configuration: drawing them would add nothing
    rng = np.random.default_rng(1)
    lo, hi = g1.tree.limits()
    q = rng.uniform(lo, hi, size=(5, len(lo)))
    for side in "lr":
        P = g1.fk(q, links=[f"arm_{side}_link{k}" for k in range(1, 7)]).numpy()[..., :3, 3]
        for a, b in ((0, 1), (2, 3), (4, 5)):
            assert np.abs(P[:, a] - P[:, b]).max() < 1e-9


@pytest.mark.parametrize("side", [0, 1])
def test_gripper_signal_closes_the_fingers(g1, side):
    """0 = open: finger joint at pi/4 and the fingers far apart; 1 = closed: joint at 0."""
    tips = [("gripper_l_outer_link1", "gripper_l_inner_link1"), ("gripper_r_outer_link1", "gripper_r_inner_link1")][
        side
    ]
    k = [g1.skeleton.links.index(t) for t in tips]
    gaps = {}
    for signal in (0.0, 0.5, 1.0):
        grip = [0.0, 0.0]
        grip[side] = signal
        traj = g1.check_trajectory(ready(grip=grip))
        full = g1.full_configuration(traj)
        joint = full[0, g1.tree.joint_names.index(FINGER_JOINTS[side])]
        assert joint == pytest.approx(np.pi / 4 * (1 - signal))
        frames = g1.frames(traj)
        assert frames.openness[0, side] == pytest.approx(1 - signal)
        gaps[signal] = np.linalg.norm(frames.points[0, k[0]] - frames.points[0, k[1]])
    assert gaps[0.0] > gaps[0.5] > gaps[1.0] > 0.07  # 10.9 cm open, 7.6 cm closed (distal pivots)


def test_example_assets(g1):
    traj = g1.check_trajectory(load_trajectory(g1.example_trajectory))
    assert len(traj) >= 81 and traj.gripper.shape == (len(traj), 2)
    left = traj.gripper[:, 0]
    assert left[0] == 0.0 and left.max() == 1.0 and left[-1] == 0.0  # open, closes, opens again
    cam = load_camera(g1.example_camera)
    assert cam.mount_link == HEAD_CAMERA_LINK and cam.embodiment == "agibot_g1"
    video = render_skeleton_video(g1, traj, cam, (192, 144))
    assert (video.reshape(len(traj), -1).max(axis=1) > 0).all()


def test_head_camera_follows_the_head_joints(g1):
    cam = load_camera(g1.example_camera).resized(192, 144)
    still = render_skeleton_video(g1, ready(), cam)[0]
    q = np.array([READY])
    q[0, JOINTS.index("idx11_head_joint1")] += 0.2  # head yaw only: the arms do not move
    turned = render_skeleton_video(g1, Trajectory(JOINTS, q, 30, gripper=[[0.0, 0.0]]), cam)[0]
    assert np.abs(still.astype(int) - turned).sum() > 0
    before = g1.frames(g1.check_trajectory(ready()), mount_link=HEAD_CAMERA_LINK)
    after = g1.frames(g1.check_trajectory(Trajectory(JOINTS, q, 30, gripper=[[0.0, 0.0]])), mount_link=HEAD_CAMERA_LINK)
    body = [k for k, l in enumerate(g1.skeleton.links) if l != "head_link2"]
    assert np.allclose(before.points[:, body], after.points[:, body])  # only the head moved in the base frame
    assert not np.allclose(before.mount_pose, after.mount_pose)


def test_golden_configs_are_within_limits_and_one_is_near_a_limit(g1):
    """The configurations of the golden images (tests/render/golden_cases/agibot_g1.py)."""
    lo, hi = g1.tree.limits()
    keep = [g1.tree.joint_names.index(n) for n in JOINTS]
    lo, hi = lo[keep], hi[keep]
    for q, _ in GOLDEN_CONFIGS.values():
        assert np.all((np.array(q) >= lo) & (np.array(q) <= hi))
    q = np.array(GOLDEN_CONFIGS["limits_closed"][0])
    assert np.min(np.minimum(q - lo, hi - q)) <= 0.02


# --------------------------------------------------------------------------- the AgiBot World adapter

HEAD_IN_LINK = np.array([[0.0, 0.0, 1.0, 0.11], [0.0, 1.0, 0.0, -0.03], [-1.0, 0.0, 0.0, 0.0], [0, 0, 0, 1.0]])


def synthetic_record(g1, T=20, seed=0, camera_in_link=HEAD_IN_LINK):
    """An episode in AgiBot World's stored layout, from known joint values and a known head-camera mount."""
    rng = np.random.default_rng(seed)
    lo, hi = g1.tree.limits()
    body = [g1.tree.joint_names.index(n) for n in JOINTS]
    q = np.clip(np.array(READY) + rng.normal(0, 0.05, (T, len(JOINTS))), lo[body], hi[body])
    grip = np.stack([np.linspace(0, 1, T), np.zeros(T)], axis=1)
    traj = Trajectory(JOINTS, q, 30, gripper=grip)
    link = g1.fk(g1.full_configuration(g1.check_trajectory(traj)), links=[HEAD_CAMERA_LINK]).numpy()[:, 0]
    cam_to_base = link @ camera_in_link
    return (
        q,
        grip,
        {
            "timestamp": 1_734_000_000_000_000_000 + np.arange(T, dtype=np.int64) * 33_333_333,
            "state": {
                "joint": {"position": q[:, 4:].astype(np.float32)},  # nested, as an h5py.File reads
                "waist": {"position": q[:, [1, 0]]},  # pitch, lift
                "head": {"position": q[:, [2, 3]]},  # yaw, pitch
            },
            "action/effector/position": grip,  # flat keys work too
            "head_intrinsic_params": {
                "intrinsic": {
                    "fx": 390.1,
                    "fy": 389.7,
                    "ppx": 321.2,
                    "ppy": 243.8,
                    "k1": -0.05,
                    "k2": 0.01,
                    "k3": 0.0,
                    "p1": 0.001,
                    "p2": -0.001,
                }
            },
            "head_extrinsic_params_aligned": [
                {
                    "extrinsic": {
                        "rotation_matrix": np.round(C[:3, :3], 7).tolist(),
                        "translation_vector": C[:3, 3].tolist(),
                    }
                }
                for C in cam_to_base
            ],
        },
    )


def test_agibot_world_layout(g1):
    q, grip, record = synthetic_record(g1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MountConsistencyWarning)
        traj, cam = from_agibot_world(record, source="task_327/648642", head_camera="head_link")
    assert traj.joint_names == JOINTS and traj.gripper_names == ("left_gripper", "right_gripper")
    assert np.allclose(traj.q, q, atol=1e-6)  # float32 arms
    assert traj.q[0, 0] == q[0, 0] and traj.q[0, 1] == q[0, 1]  # lift first, then pitch
    assert np.array_equal(traj.gripper, grip)
    assert traj.fps == pytest.approx(30.0, rel=1e-6) and traj.timestamps[1] == pytest.approx(0.033333333)
    assert cam.mount_link == HEAD_CAMERA_LINK and cam.direction == "camera_to_world" and cam.convention == "opencv"
    assert np.abs(cam.extrinsic - HEAD_IN_LINK).max() < 1e-5
    i = cam.intrinsics
    assert (i.fx, i.fy, i.cx, i.cy, i.width, i.height) == (390.1, 389.7, 321.2, 243.8, *HEAD_IMAGE_SIZE)
    assert i.distortion == (-0.05, 0.01, 0.001, -0.001, 0.0)  # OpenCV order k1, k2, p1, p2, k3
    video = render_skeleton_video(g1, traj, cam, (160, 120), camera_source="task_327/648642")
    assert video.shape == (len(q), 120, 160, 3) and video.max() > 0


def test_agibot_world_options(g1):
    _, _, record = synthetic_record(g1, T=5)
    del record["timestamp"]
    record["image_size"] = [1280, 720]
    traj, cam = from_agibot_world(record)
    assert traj.fps == AGIBOT_WORLD_FPS and traj.timestamps is None
    assert (cam.intrinsics.width, cam.intrinsics.height) == (1280, 720)
    traj, cam = from_agibot_world(record, image_size=(848, 480), fps=15.0)
    assert traj.fps == 15.0 and cam.intrinsics.width == 848
    # extrinsics recorded for fewer frames than the proprioception: the common frames are used
    record["head_extrinsic_params_aligned"] = record["head_extrinsic_params_aligned"][:3]
    _, cam = from_agibot_world(record, head_camera="head_link")
    assert np.abs(cam.extrinsic - HEAD_IN_LINK).max() < 1e-5
    # ... but not for a per-frame camera, which needs one pose per frame
    with pytest.raises(CameraFileError) as err:
        from_agibot_world(record, source="ep")
    assert err.value.field == "head_extrinsic_params_aligned" and "5 poses, one per state frame" in str(err.value)
    assert err.value.found == "3 poses"
    with pytest.raises(ValueError, match="head_camera must be one of"):
        from_agibot_world(record, head_camera="mean")


def test_agibot_world_per_frame_head_camera_is_the_stored_poses(g1):
    """The default camera keeps every stored pose; where they follow the head rigidly it
    projects as the head-link camera does, and where they do not it follows the record."""
    _, _, record = synthetic_record(g1, T=12)
    poses = np.stack(
        [
            np.block(
                [
                    [
                        np.array(e["extrinsic"]["rotation_matrix"]),
                        np.array(e["extrinsic"]["translation_vector"])[:, None],
                    ],
                    [np.zeros((1, 3)), np.ones((1, 1))],
                ]
            )
            for e in record["head_extrinsic_params_aligned"]
        ]
    )
    traj, cam = from_agibot_world(record)
    assert cam.mount_link is None and cam.num_frames == 12 and cam.embodiment == "agibot_g1"
    assert np.abs(cam.extrinsic - poses).max() < 1e-6  # re-orthonormalised 7-digit rotations
    _, linked = from_agibot_world(record, head_camera="head_link")
    a = project_skeleton(g1, g1.check_trajectory(traj), cam.resized(320, 240))
    b = project_skeleton(g1, g1.check_trajectory(traj), linked.resized(320, 240))
    seen = a.usable & b.usable & (np.abs(a.uv - [160, 120]) < [160, 120]).all(-1)  # in front and in the image
    assert seen.sum() > 12 * 5 and np.abs(a.uv - b.uv)[seen].max() < 0.05  # pixels
    # a camera that ignores the head joints: the per-frame camera keeps it where it was recorded, without a warning
    record["head_extrinsic_params_aligned"] = [record["head_extrinsic_params_aligned"][0]] * 12
    record["state"]["head"]["position"] = np.stack([np.linspace(-0.5, 0.5, 12), np.full(12, 0.3)], axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MountConsistencyWarning)
        traj, cam = from_agibot_world(record)
    assert np.allclose(cam.extrinsic, cam.extrinsic[0])
    video = render_skeleton_video(g1, traj, cam, (160, 120))
    assert video.shape == (12, 120, 160, 3) and video.max() > 0


def test_agibot_world_extrinsics_that_ignore_the_head_joints_warn(g1):
    _, _, record = synthetic_record(g1, T=10)
    fixed = record["head_extrinsic_params_aligned"][0]
    record["head_extrinsic_params_aligned"] = [fixed] * 10  # a camera fixed in the base while the head moves
    record["state"]["head"]["position"] = np.stack([np.linspace(-0.5, 0.5, 10), np.full(10, 0.3)], axis=1)
    with pytest.warns(MountConsistencyWarning, match="do not follow the head link"):
        from_agibot_world(record, head_camera="head_link")


@pytest.mark.parametrize(
    "change, field, words",
    [
        (lambda r: r["state"].pop("waist"), "state/waist/position", "missing"),
        (lambda r: r["state"]["joint"].update(position=np.zeros((20, 7))), "state/joint/position", "shape (N, 14)"),
        (lambda r: r["state"]["head"].update(position=np.zeros((19, 2))), "state/head/position", "19 frames"),
        (
            lambda r: r.update({"action/effector/position": np.full((20, 2), 80.0)}),
            "action/effector/position",
            "35 .. 120",
        ),
        (lambda r: r["state"]["joint"]["position"].__setitem__((3, 2), np.nan), "state/joint/position", "non-finite"),
        (lambda r: r.update(timestamp=np.arange(5)), "timestamp", "20 timestamps"),
    ],
)
def test_agibot_world_bad_proprioception(g1, change, field, words):
    _, _, record = synthetic_record(g1)
    change(record)
    with pytest.raises(TrajectoryError, match="task_9") as err:
        from_agibot_world(record, source="task_9")
    assert err.value.field == field and words in str(err.value)


@pytest.mark.parametrize(
    "change, field",
    [
        (lambda r: r.pop("head_intrinsic_params"), "head_intrinsic_params"),
        (lambda r: r["head_intrinsic_params"]["intrinsic"].pop("ppy"), "head_intrinsic_params.intrinsic"),
        (lambda r: r["head_intrinsic_params"]["intrinsic"].update(fx=-3.0), "head_intrinsic_params.intrinsic.fx"),
        (lambda r: r.pop("head_extrinsic_params_aligned"), "head_extrinsic_params_aligned"),
        (
            lambda r: r["head_extrinsic_params_aligned"][2]["extrinsic"].update(rotation_matrix=np.eye(3) * 2),
            "head_extrinsic_params_aligned[2].rotation_matrix",
        ),
        (
            lambda r: r["head_extrinsic_params_aligned"][1]["extrinsic"].pop("translation_vector"),
            "head_extrinsic_params_aligned[1]",
        ),
        (lambda r: r.update(image_size=(0, 480)), "image_size"),
    ],
)
def test_agibot_world_bad_camera(g1, change, field):
    _, _, record = synthetic_record(g1)
    change(record)
    with pytest.raises(CameraFileError) as err:
        from_agibot_world(record, source="ep")
    assert err.value.field == field and err.value.path == "ep"


def test_load_agibot_world_episode_reads_the_dataset_folders(g1, tmp_path, monkeypatch):
    import json

    _, _, record = synthetic_record(g1, T=4)
    arrays = {
        "state/joint/position": record["state"]["joint"]["position"],
        "state/waist/position": record["state"]["waist"]["position"],
        "state/head/position": record["state"]["head"]["position"],
        "action/effector/position": record["action/effector/position"],
        "timestamp": record["timestamp"],
    }

    class File(dict):  # stands in for h5py.File (only "in", [] and the context manager are used)
        def __init__(self, path, mode):
            assert Path(path) == tmp_path / "proprio_stats" / "327" / "648642" / "proprio_stats.h5" and mode == "r"
            super().__init__(arrays)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

    monkeypatch.setitem(sys.modules, "h5py", types.SimpleNamespace(File=File))
    camera_dir = tmp_path / "parameters" / "327" / "648642" / "parameters" / "camera"
    camera_dir.mkdir(parents=True)
    for name in ("head_intrinsic_params", "head_extrinsic_params_aligned"):
        (camera_dir / f"{name}.json").write_text(json.dumps(record[name]))
    loaded = load_agibot_world_episode(tmp_path, 327, 648642)
    traj, cam = from_agibot_world(loaded, head_camera="head_link")
    assert len(traj) == 4 and np.abs(cam.extrinsic - HEAD_IN_LINK).max() < 1e-5


# --------------------------------------------------------------------------- bad input to the embodiment


def test_wrong_joint_count_or_names_are_refused(g1):
    with pytest.raises(TrajectoryError, match="the 18 joints of 'agibot_g1'") as err:
        g1.check_trajectory(Trajectory(JOINTS[:-1], np.zeros((1, 17)), 30, gripper=[[0.0, 0.0]]))
    assert "missing ['idx67_arm_r_joint7']" in str(err.value)
    names = ("waist_lift",) + JOINTS[1:]
    with pytest.raises(TrajectoryError, match=r"unknown \['waist_lift'\]"):
        g1.check_trajectory(Trajectory(names, np.zeros((1, 18)), 30, gripper=[[0.0, 0.0]]))
    with pytest.raises(TrajectoryError, match=r"shape \(T, 2\) for grippers \['left_gripper', 'right_gripper'\]"):
        g1.check_trajectory(Trajectory(JOINTS, np.zeros((1, 18)), 30, gripper=[[0.0]]))


def test_gripper_outside_its_range_is_refused(g1):
    traj = g1.check_trajectory(ready(grip=(0.0, 35.0)))  # a millimetre reading where 0..1 belongs
    with pytest.raises(TrajectoryError, match=r"gripper\[right_gripper\].*values in \[0, 1\].*found 35"):
        g1.frames(traj)


def test_camera_for_another_mount_or_embodiment_is_refused(g1):
    intr = Intrinsics(380.0, 380.0, 319.5, 239.5, 640, 480)
    g1.check_camera(Camera(intr, np.eye(4)))  # a static outside camera fits any embodiment
    other_link = Camera(intr, np.eye(4), mount_link="head_link1")
    with pytest.raises(
        CameraFileError, match="static .mount: null. or mount link 'head_link2' for embodiment 'agibot_g1'"
    ) as err:
        render_skeleton_video(g1, ready(), other_link, camera_source="cam.json")
    assert err.value.path == "cam.json" and err.value.found == "mount link 'head_link1'"
    other_robot = Camera(intr, np.eye(4), mount_link="head_link2", embodiment="hsr")
    with pytest.raises(CameraFileError, match="expected 'agibot_g1', found 'hsr'"):
        g1.check_camera(other_robot)
