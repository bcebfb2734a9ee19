"""FK against an independent implementation (yourdfpy) and URDF/xacro parsing errors."""

import importlib.metadata as md
from pathlib import Path

import numpy as np
import pytest
from _paths import REPO

from oscar_core.errors import KinematicsFileError
from oscar_core.kinematics.fk_torch import ForwardKinematics
from oscar_core.kinematics.urdf import build_tree_from_urdf, build_tree_from_urdf_string, build_tree_from_xacro

yourdfpy = pytest.importorskip("yourdfpy")

TOYARM_URDF = REPO / "examples" / "oscar-toyarm" / "oscar_toyarm" / "assets" / "toyarm.urdf"


def random_tree_urdf(seed: int, n_links: int = 14) -> str:
    """A random branching robot: revolute/continuous/prismatic/fixed joints,
    arbitrary origins and axes, and mimic joints with multipliers and offsets."""
    rng = np.random.default_rng(seed)
    links = [f"l{i}" for i in range(n_links)]
    joints, movable = [], []
    for i in range(1, n_links):
        parent = links[int(rng.integers(0, i))]
        jtype = rng.choice(["revolute", "continuous", "prismatic", "fixed"], p=[0.45, 0.15, 0.2, 0.2])
        xyz = " ".join(f"{v:.6f}" for v in rng.normal(0, 0.3, 3))
        rpy = " ".join(f"{v:.6f}" for v in rng.uniform(-np.pi, np.pi, 3))
        axis = rng.normal(size=3)
        # unit axes: the URDF spec asks for them, and implementations differ on
        # non-unit ones (oscar and pytorch-kinematics normalise, yourdfpy does not)
        axis_s = " ".join(f"{v:.15f}" for v in axis / np.linalg.norm(axis))
        body = f'<parent link="{parent}"/><child link="{links[i]}"/><origin xyz="{xyz}" rpy="{rpy}"/>'
        if jtype != "fixed":
            body += f'<axis xyz="{axis_s}"/>'
        if jtype in ("revolute", "prismatic"):
            body += '<limit lower="-2" upper="2" effort="1" velocity="1"/>'
        if jtype != "fixed" and movable and rng.random() < 0.25:
            src = movable[int(rng.integers(0, len(movable)))]
            body += (
                f'<mimic joint="{src}" multiplier="{rng.uniform(-2, 2):.4f}" offset="{rng.uniform(-0.3, 0.3):.4f}"/>'
            )
        else:
            if jtype != "fixed":
                movable.append(f"j{i}")
        joints.append(f'<joint name="j{i}" type="{jtype}">{body}</joint>')
    link_xml = "".join(f'<link name="{l}"/>' for l in links)
    return f'<robot name="rand{seed}">{link_xml}{"".join(joints)}</robot>'


def yourdfpy_poses(urdf_path: Path, tree, q: np.ndarray) -> np.ndarray:
    """(T, L, 4, 4) poses of all links from yourdfpy, with mimic joints resolved by yourdfpy."""
    robot = yourdfpy.URDF.load(
        str(urdf_path),
        load_meshes=False,
        build_scene_graph=True,
        load_collision_meshes=False,
        build_collision_scene_graph=False,
    )
    assert tuple(robot.actuated_joint_names) == tree.joint_names
    out = np.empty((len(q), len(tree.links), 4, 4))
    for t in range(len(q)):
        robot.update_cfg(q[t])
        for k, link in enumerate(tree.links):
            out[t, k] = robot.get_transform(link, robot.base_link)
    return out


def check_against_yourdfpy(urdf_path: Path, seed: int, frames: int = 25):
    tree = build_tree_from_urdf(urdf_path)
    lo, hi = tree.limits()
    rng = np.random.default_rng(seed)
    q = rng.uniform(np.where(np.isfinite(lo), lo, -np.pi), np.where(np.isfinite(hi), hi, np.pi), (frames, len(lo)))
    ours = ForwardKinematics(tree)(q, list(tree.links)).numpy()
    ref = yourdfpy_poses(urdf_path, tree, q)
    err = np.abs(ours[..., :3, 3] - ref[..., :3, 3]).max()
    rot_err = np.abs(ours[..., :3, :3] - ref[..., :3, :3]).max()
    assert err < 1e-6, f"max position error {err} m"
    assert rot_err < 1e-6


@pytest.mark.parametrize("seed", [3, 11, 2024])
def test_fk_matches_yourdfpy_on_random_trees(tmp_path, seed):
    path = tmp_path / f"rand{seed}.urdf"
    path.write_text(random_tree_urdf(seed))
    check_against_yourdfpy(path, seed + 100)


def test_fk_matches_yourdfpy_toyarm():
    check_against_yourdfpy(TOYARM_URDF, 7)


def _panda_urdf():
    try:
        files = md.distribution("example-robot-data").files or []
    except md.PackageNotFoundError:
        return None
    for f in files:
        if str(f).endswith("panda_description/urdf/panda.urdf"):
            return Path(f.locate())
    return None


def test_fk_matches_yourdfpy_panda():
    path = _panda_urdf()
    if path is None:
        pytest.skip("example-robot-data is not installed")
    check_against_yourdfpy(path, 5)


def test_mimic_joint_follows_its_source():
    tree = build_tree_from_urdf(TOYARM_URDF)
    assert "finger_right" not in tree.joint_names  # mimic joints are not trajectory joints
    fk = ForwardKinematics(tree)
    q = np.zeros((1, len(tree.joint_names)))
    q[0, tree.joint_names.index("finger_left")] = 0.03
    P = fk(q, ["left_finger", "right_finger", "tool"]).numpy()[0]
    left_y = np.linalg.inv(P[2]) @ P[0]
    right_y = np.linalg.inv(P[2]) @ P[1]
    assert left_y[1, 3] == pytest.approx(0.03) and right_y[1, 3] == pytest.approx(-0.03)


def test_base_pose_moves_everything():
    tree = build_tree_from_urdf(TOYARM_URDF)
    fk = ForwardKinematics(tree)
    rng = np.random.default_rng(0)
    q = rng.uniform(-0.5, 0.5, (4, len(tree.joint_names)))
    base = np.tile(np.eye(4), (4, 1, 1))
    base[:, :3, 3] = rng.normal(size=(4, 3))
    c, s = np.cos(0.7), np.sin(0.7)
    base[:, :2, :2] = [[c, -s], [s, c]]
    moved = fk(q, ["tool"], base_pose=base).numpy()
    still = fk(q, ["tool"]).numpy()
    np.testing.assert_allclose(moved, base[:, None] @ still, atol=1e-12)


def test_fk_output_shape_and_dtype():
    import torch

    tree = build_tree_from_urdf(TOYARM_URDF)
    out = ForwardKinematics(tree)(np.zeros((81, len(tree.joint_names))), ["base_link", "tool"])
    assert out.shape == (81, 2, 4, 4) and out.dtype == torch.float64
    with pytest.raises(ValueError, match=r"expected shape \(T, 5\)"):
        ForwardKinematics(tree)(np.zeros((3, 4)), ["tool"])


# ---- bad descriptions --------------------------------------------------------


@pytest.mark.parametrize(
    "xml, field, fragment",
    [
        ("<robot><link name='a'/>", "<xml>", "well-formed"),
        ("<notarobot/>", "<root element>", "<robot>"),
        (
            "<robot><link name='a'/><link name='b'/><joint name='j' type='floating'><parent link='a'/><child link='b'/></joint></robot>",
            "joint[j].type",
            "floating",
        ),
        (
            "<robot><link name='a'/><link name='b'/><joint name='j' type='revolute'><parent link='a'/><child link='b'/></joint></robot>",
            "joint[j].limit",
            "<limit>",
        ),
        (
            "<robot><link name='a'/><joint name='j' type='fixed'><parent link='a'/><child link='zz'/></joint></robot>",
            "joint[j].child",
            "'zz'",
        ),
        (
            "<robot><link name='a'/><link name='b'/><joint name='j' type='continuous'><parent link='a'/><child link='b'/>"
            "<origin xyz='0 0'/></joint></robot>",
            "joint[j].origin.xyz",
            "'0 0'",
        ),
        (
            "<robot><link name='a'/><link name='b'/><joint name='j' type='continuous'><parent link='a'/><child link='b'/>"
            "<mimic joint='nope'/></joint></robot>",
            "joint[j].mimic.joint",
            "'nope'",
        ),
        ("<robot><link name='a'/><link name='b'/></robot>", "robot", "roots"),
    ],
)
def test_bad_urdf_names_file_and_field(xml, field, fragment):
    with pytest.raises(KinematicsFileError) as info:
        build_tree_from_urdf_string(xml, source="bad.urdf")
    msg = str(info.value)
    assert msg.startswith("bad.urdf: field '" + field + "'"), msg
    assert fragment in msg


def test_missing_urdf_file(tmp_path):
    with pytest.raises(KinematicsFileError, match="no_such.urdf.*readable URDF"):
        build_tree_from_urdf(tmp_path / "no_such.urdf")


# ---- xacro ---------------------------------------------------------------------


def test_xacro_with_find_and_args_without_ros(tmp_path):
    share = tmp_path / "share" / "toy_description"
    (share / "urdf").mkdir(parents=True)
    (share / "urdf" / "arm.xacro").write_text("""<?xml version="1.0"?>
<robot xmlns:xacro="http://www.ros.org/wiki/xacro">
  <xacro:macro name="segment" params="name parent length">
    <link name="${name}"/>
    <joint name="${name}_joint" type="revolute">
      <parent link="${parent}"/><child link="${name}"/>
      <origin xyz="0 0 ${length}"/><axis xyz="0 1 0"/>
      <limit lower="-1" upper="1" effort="1" velocity="1"/>
    </joint>
  </xacro:macro>
</robot>""")
    top = tmp_path / "robot.urdf.xacro"
    top.write_text("""<?xml version="1.0"?>
<robot name="xtoy" xmlns:xacro="http://www.ros.org/wiki/xacro">
  <xacro:arg name="upper_length" default="0.3"/>
  <xacro:include filename="$(find toy_description)/urdf/arm.xacro"/>
  <link name="base"/>
  <xacro:segment name="upper" parent="base" length="0.1"/>
  <xacro:segment name="lower" parent="upper" length="$(arg upper_length)"/>
</robot>""")
    tree = build_tree_from_xacro(top, args={"upper_length": "0.45"}, packages={"toy_description": share})
    assert tree.joint_names == ("upper_joint", "lower_joint")
    assert tree.joint("lower_joint").origin[2, 3] == pytest.approx(0.45)
    import sys

    assert "ament_index_python" not in sys.modules  # the stand-in is removed afterwards
    with pytest.raises(KinematicsFileError, match=r"robot.urdf.xacro.*\$\(find toy_description\)"):
        build_tree_from_xacro(top, packages={})


def test_xacro_missing_file_and_broken_macro(tmp_path):
    with pytest.raises(KinematicsFileError, match="missing.xacro"):
        build_tree_from_xacro(tmp_path / "missing.xacro")
    bad = tmp_path / "bad.xacro"
    bad.write_text('<robot name="b" xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:nosuchmacro/></robot>')
    with pytest.raises(KinematicsFileError, match="bad.xacro: field '<xacro>'"):
        build_tree_from_xacro(bad)


def test_axes_are_normalised_as_the_urdf_spec_asks():
    xml = (
        "<robot name='n'><link name='a'/><link name='b'/><joint name='slide' type='prismatic'>"
        "<parent link='a'/><child link='b'/><axis xyz='0 0 2'/><limit lower='0' upper='1' effort='1' velocity='1'/>"
        "</joint></robot>"
    )
    tree = build_tree_from_urdf_string(xml)
    P = ForwardKinematics(tree)(np.array([[0.25]]), ["b"]).numpy()
    assert P[0, 0, 2, 3] == pytest.approx(0.25)
