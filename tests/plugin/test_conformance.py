"""The contract, checked on every registered embodiment (built-in, example and installed)."""

import numpy as np
import pytest

from oscar_core import default_registry, load_camera, load_trajectory, render_skeleton_video
from oscar_core.render.skeleton_video import project_skeleton

REGISTRY = default_registry()
NAMES = REGISTRY.names()


def test_no_plugin_failed_to_load():
    assert REGISTRY.failures == [], [str(f) for f in REGISTRY.failures]


@pytest.fixture(scope="module", params=NAMES)
def emb(request):
    return REGISTRY.get(request.param)


def example(emb):
    if emb.example_trajectory is None:
        pytest.skip(f"{emb.name} bundles no example trajectory")
    traj = emb.check_trajectory(load_trajectory(emb.example_trajectory))
    return traj, load_camera(emb.example_camera)


def test_contract_fields(emb):
    entry = REGISTRY.entries[emb.name]
    assert entry.distribution and isinstance(emb.description, str) and emb.description
    assert isinstance(emb.license, str) and emb.license, "an SPDX license id is required"
    assert isinstance(emb.datasets, tuple)
    assert emb.problems() == []
    assert len(set(emb.joint_names)) == len(emb.joint_names)


def test_skeleton_edges_form_a_tree_over_the_chosen_links(emb):
    links = emb.skeleton.links
    edges = emb.edges
    # every edge joins two chosen links and each link has at most one parent ...
    children = [b for _, b in edges]
    assert len(children) == len(set(children))
    assert all(a in links and b in links for a, b in edges)
    parent = dict((b, a) for a, b in edges)
    roots = {l for l in links if l not in parent}
    for l in links:  # ... and reaches a root without a cycle: a forest
        seen = set()
        while l in parent:
            assert l not in seen
            seen.add(l)
            l = parent[l]
        assert l in roots
    # a robot's skeleton is one tree over its chosen links; a keypoint body may be
    # several (two hands are two trees)
    if emb.uses_kinematic_tree():
        assert len(roots) == 1 and len(edges) == len(links) - 1


def test_fk_shape_and_openness_range(emb):
    traj, _ = example(emb)
    frames = emb.frames(traj)
    T, K, G = len(traj), len(emb.skeleton.links), len(emb.grippers)
    assert frames.points.shape == (T, K, 3) and np.isfinite(frames.points).all()
    assert frames.gripper_points.shape == (T, G, 3)
    assert frames.openness.shape == (T, G)
    assert ((frames.openness >= 0) & (frames.openness <= 1)).all()
    if emb.uses_kinematic_tree():
        poses = emb.fk(emb.full_configuration(traj), traj.base_pose)
        assert tuple(poses.shape) == (T, K, 4, 4)


def test_render_example(emb):
    traj, cam = example(emb)
    video = render_skeleton_video(emb, traj, cam, (256, 144))
    assert video.shape == (len(traj), 144, 256, 3) and video.dtype == np.uint8
    assert (video.reshape(len(traj), -1).max(axis=1) > 0).mean() > 0.9  # the robot is seen in most frames


def signal_for(gripper, openness):
    lo, hi = gripper.signal_range
    return lo + openness * (hi - lo) if gripper.closed_at == "low" else hi - openness * (hi - lo)


def test_gripper_indicator_changes_when_only_openness_changes(emb):
    if not emb.grippers:
        pytest.skip(f"{emb.name} has no gripper")
    traj, cam = example(emb)
    cam = cam.resized(256, 144)
    one = traj.time_slice(0, 1)
    renders, marks = [], None
    for openness in (0.2, 0.8):
        g = np.array([[signal_for(gr, openness) for gr in emb.grippers]])
        variant = one.replace(gripper=g)
        renders.append(render_skeleton_video(emb, variant, cam)[0])
        marks = project_skeleton(emb, variant, cam).grippers
    for k in range(len(emb.grippers)):
        u, v = marks.uv[0, k]
        if not (marks.visible[0, k] and 0 <= u < 256 and 0 <= v < 144):
            continue
        ys, xs = np.mgrid[:144, :256]
        near = (xs - u) ** 2 + (ys - v) ** 2 <= 12**2
        assert np.any(renders[0][near] != renders[1][near]), (
            f"indicator of gripper {emb.grippers[k].name} did not change"
        )
        return
    pytest.skip("no gripper indicator inside the example camera's first frame")


def test_default_pose_fills_exactly_the_joints_it_names(emb):
    """A declared default pose lies within the limits (``problems()``) and a trajectory
    that leaves out its joints gets exactly those values, with a DefaultPoseWarning."""
    from oscar_core import DefaultPoseWarning

    if not emb.default_pose:
        pytest.skip(f"{emb.name} declares no default pose")
    assert set(emb.default_pose) <= set(emb.joint_names)
    traj, _ = example(emb)
    keep = [i for i, n in enumerate(traj.joint_names) if n not in emb.default_pose]
    partial = traj.replace(joint_names=tuple(traj.joint_names[i] for i in keep), q=traj.q[:, keep])
    with pytest.warns(DefaultPoseWarning) as rec:
        checked = emb.check_trajectory(partial)
    w = next(r.message for r in rec if isinstance(r.message, DefaultPoseWarning))
    assert set(w.joints) == set(emb.default_pose)
    for j, n in enumerate(checked.joint_names):
        expected = emb.default_pose[n] if n in emb.default_pose else traj.q[:, j]
        np.testing.assert_array_equal(checked.q[:, j], expected)
