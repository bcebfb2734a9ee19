"""The mesh condition: visual geometry, the z-buffer rasteriser and the streamed renderer.

Tiny embodiments are built here from URDF text (boxes on prismatic joints) so
that each expected image is computed analytically; franka and the toy arm check
the real paths (meshes, primitives, fingers, CLI and batch).
"""

import json
import sys

import numpy as np
import pytest
from _paths import REPO

from oscar_core import (
    Camera,
    Embodiment,
    Intrinsics,
    KinematicsFileError,
    PluginError,
    Skeleton,
    Trajectory,
    look_at,
    project,
)
from oscar_core.kinematics.mesh_simplify import cluster_vertices
from oscar_core.kinematics.visual import (
    LinkGeometry,
    VisualGeometry,
    box_mesh,
    capsule_mesh,
    cylinder_mesh,
    sphere_mesh,
)
from oscar_core.render.mesh import (
    MeshStyle,
    iter_mesh_chunks,
    link_palette,
    mesh_geometry,
    mesh_vertices,
    render_mesh_video,
)
from oscar_core.render.mesh_raster import rasterise_mesh

sys.path.insert(0, str(REPO / "examples" / "oscar-toyarm"))
from oscar_toyarm import ToyArm

FULL = MeshStyle(simplify=None)


def make_embodiment(tmp_path, links_xml: str, joints_xml: str, links: tuple[str, ...], name="boxes"):
    """An Embodiment class on a URDF written to tmp_path (joints: prismatic along x)."""
    urdf = tmp_path / f"{name}.urdf"
    urdf.write_text(f'<robot name="{name}">{links_xml}{joints_xml}</robot>')

    class Boxes(Embodiment):
        pass

    Boxes.name = name
    Boxes.urdf = urdf
    Boxes.skeleton = Skeleton(links=links)
    return Boxes


def slider(name, parent, child, xyz="0 0 0"):
    return (
        f'<joint name="{name}" type="prismatic"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{xyz}" rpy="0 0 0"/><axis xyz="1 0 0"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
    )


def box_link(name, size, xyz="0 0 0"):
    return (
        f'<link name="{name}"><visual><origin xyz="{xyz}" rpy="0 0 0"/>'
        f'<geometry><box size="{size}"/></geometry></visual></link>'
    )


# camera 2 m above the origin looking straight down (OpenCV: x right = world x, y down = world -y)
DOWN = Camera(Intrinsics(200.0, 200.0, 63.5, 47.5, 128, 96), look_at((0.0, 0.0, 2.0), (0.0, 0.0, 0.0), up=(0, 1, 0)))


# ------------------------------------------------------------------------------ geometry


@pytest.mark.parametrize(
    "make,volume",
    [
        (lambda: box_mesh((0.1, 0.2, 0.3)), 0.1 * 0.2 * 0.3),
        (lambda: cylinder_mesh(0.05, 0.2), np.pi * 0.05**2 * 0.2),
        (lambda: sphere_mesh(0.1), 4 / 3 * np.pi * 0.1**3),
        (lambda: capsule_mesh(0.05, 0.2), np.pi * 0.05**2 * 0.2 + 4 / 3 * np.pi * 0.05**3),
    ],
)
def test_primitives_are_closed_outward_and_the_right_size(make, volume):
    v, f = make()
    # closed and consistently wound: every directed edge appears once, and its reverse once
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    directed = {tuple(e) for e in edges}
    assert len(directed) == len(edges)
    assert all((b, a) in directed for a, b in directed)
    # outward: the signed volume is positive, within 5 % of the solid's (facets inscribed)
    signed = np.einsum("fi,fi->f", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6
    assert 0.95 * volume < signed <= volume * 1.0001


def test_vertex_clustering_reduces_and_bounds_the_error():
    v, f = sphere_mesh(0.1, n=64)
    cell = 0.02
    v2, f2 = cluster_vertices(v, f, cell)
    assert len(f2) < len(f) / 4 and len(v2) < len(v)
    # every kept vertex is the mean of vertices of one cell: within the cell diagonal of the sphere
    r = np.linalg.norm(v2, axis=1)
    assert np.all(np.abs(r - 0.1) <= cell * np.sqrt(3))
    assert f2.min() >= 0 and f2.max() < len(v2)


def test_urdf_visual_origin_and_mesh_scale(tmp_path):
    stl = tmp_path / "tri.obj"
    stl.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    urdf = (
        '<link name="a"><visual><origin xyz="0 0 1" rpy="0 0 1.5707963267948966"/>'
        '<geometry><mesh filename="tri.obj" scale="2 2 2"/></geometry></visual></link>'
    )
    Emb = make_embodiment(tmp_path, urdf, "", ("a",), name="tri")
    geo = Emb().visual_geometry()
    (g,) = geo.links
    # scaled by 2, turned 90 degrees about z, lifted 1 m
    np.testing.assert_allclose(g.vertices, [[0, 0, 1], [0, 2, 1], [-2, 0, 1]], atol=1e-12)


def test_a_mirroring_mesh_scale_keeps_faces_outward(tmp_path):
    # a tetrahedron wound outward; scale z by -1 mirrors it: the faces must be flipped to stay outward
    (tmp_path / "tet.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    for scale in ("1 1 1", "1 1 -1"):
        urdf = f'<link name="a"><visual><geometry><mesh filename="tet.obj" scale="{scale}"/></geometry></visual></link>'
        (g,) = make_embodiment(tmp_path, urdf, "", ("a",), name="tet")().visual_geometry().links
        v, f = g.vertices, g.faces
        signed = np.einsum("fi,fi->f", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6
        assert signed == pytest.approx(1 / 6), scale


# ------------------------------------------------------------------------------ rasteriser


def test_shared_edges_through_pixel_centres_leave_no_hole():
    # a square split along its diagonal, corners on pixel centres: the diagonal's pixels lie exactly
    # on both triangles' shared edge and must be covered (by one or both), and nothing outside
    uv = np.array([[2.0, 2.0], [9.0, 2.0], [9.0, 9.0], [2.0, 9.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    rgb = np.array([[255, 0, 0], [0, 255, 0]], np.uint8)
    expect = np.zeros((12, 12), bool)
    expect[2:10, 2:10] = True
    for f in (faces, faces[:, ::-1]):  # either winding (no culling here)
        img = rasterise_mesh(uv, np.ones(4), f, rgb, (12, 12))
        np.testing.assert_array_equal(img.any(-1), expect)


def test_random_fan_has_no_cracks():
    # a disc fanned into 97 thin triangles around an off-grid centre: every pixel centre inside is covered
    rng = np.random.default_rng(0)
    angles = np.sort(rng.uniform(0, 2 * np.pi, 97))
    c = np.array([31.37, 29.81])
    uv = np.concatenate([[c], c + 20 * np.stack([np.cos(angles), np.sin(angles)], 1)])
    faces = np.array([[0, 1 + i, 1 + (i + 1) % 97] for i in range(97)])
    img = rasterise_mesh(uv, np.ones(len(uv)), faces, np.full((97, 3), 200, np.uint8), (64, 64))
    yy, xx = np.mgrid[0:64, 0:64]
    well_inside = np.hypot(xx - c[0], yy - c[1]) < 20 * np.cos(np.pi * 2 * np.diff(angles).max() / 2 / np.pi) - 0.5
    assert img.any(-1)[well_inside].all()


def test_depth_is_per_pixel_for_crossing_triangles():
    # two triangles crossing in depth: each is nearer on one side, so each wins there
    uv = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 20.0], [20.0, 20.0]])
    depth = np.array([1.0, 3.0, 1.0, 3.0, 3.0, 1.0, 3.0, 1.0])
    uv2 = np.concatenate([uv, uv])
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 5, 7], [4, 7, 6]])
    rgb = np.array([[255, 0, 0], [255, 0, 0], [0, 0, 255], [0, 0, 255]], np.uint8)
    img = rasterise_mesh(uv2, depth, faces, rgb, (21, 21))
    assert tuple(img[10, 3]) == (255, 0, 0)  # left: the red one is at depth ~1.3, blue ~2.7
    assert tuple(img[10, 17]) == (0, 0, 255)


# ------------------------------------------------------------------------------ renderer


def test_a_link_behind_another_is_hidden(tmp_path):
    links = (
        box_link("base", "0.05 0.05 0.05")
        + box_link("near", "0.2 0.2 0.02", "0 0 0.5")
        + box_link("far", "1.0 1.0 0.02", "0 0 -0.5")
    )
    joints = slider("j_near", "base", "near") + slider("j_far", "base", "far")
    emb = make_embodiment(tmp_path, links, joints, ("base", "near", "far"))()
    order = mesh_geometry(emb, None).link_names
    pal = link_palette(len(order)).astype(float)

    def which(px):  # the link whose palette colour px is a shade of
        px = np.asarray(px, float)
        cos = pal @ px / (np.linalg.norm(pal, axis=1) * np.linalg.norm(px))
        return order[int(np.argmax(cos))]

    traj = Trajectory(emb.joint_names, np.zeros((1, 2)), fps=10, gripper=np.zeros((1, 0)))
    img = render_mesh_video(emb, traj, DOWN, style=FULL)[0]
    assert which(img[47, 63]) == "near"  # the centre: the near plate hides the base and the far plate
    assert which(img[47, 63 + 30]) == "far"  # beyond the near plate (13 px half-width), within the far one (40)
    # slide the near plate away along x: now the centre shows the base box above the far plate
    j = list(emb.joint_names).index("j_near")
    q = np.zeros((1, 2))
    q[0, j] = 0.8
    img = render_mesh_video(emb, Trajectory(emb.joint_names, q, fps=10, gripper=np.zeros((1, 0))), DOWN, style=FULL)[0]
    assert which(img[47, 63]) == "base"
    assert which(img[47, 63 + 10]) == "far"


def test_one_box_link_matches_its_analytic_silhouette(tmp_path):
    sx, sy, sz = 0.3, 0.2, 0.1
    links = '<link name="base"/>' + box_link("box", f"{sx} {sy} {sz}")
    emb = make_embodiment(tmp_path, links, slider("slide", "base", "box"), ("base", "box"))()
    xs = np.array([0.0, 0.1, -0.23])
    traj = Trajectory(("slide",), xs[:, None], fps=10, gripper=np.zeros((3, 0)))
    video = render_mesh_video(emb, traj, DOWN, style=FULL)
    f, cx, cy = 200.0, 63.5, 47.5
    d = 2.0 - sz / 2  # distance to the top face, which bounds the silhouette (the box's sides are hidden)
    yy, xx = np.mgrid[0:96, 0:128]
    for t, x in enumerate(xs):
        u0, u1 = cx + f * (x - sx / 2) / d, cx + f * (x + sx / 2) / d
        v0, v1 = cy - f * (sy / 2) / d, cy + f * (sy / 2) / d
        expect = (xx >= u0) & (xx <= u1) & (yy >= v0) & (yy <= v1)
        np.testing.assert_array_equal(video[t].any(-1), expect, err_msg=f"frame {t}")


def test_triangles_reaching_behind_the_camera_are_cut_not_dropped(tmp_path):
    # a 20 m floor plate under a camera 0.5 m up looking ahead and down: its two top triangles have corners
    # behind the camera; cut at the near plane they still cover exactly the floor the camera sees
    links = '<link name="base"/>' + box_link("floor", "20 20 0.01", "0 0 -0.005")
    emb = make_embodiment(tmp_path, links, slider("slide", "base", "floor"), ("base", "floor"), name="floor")()
    cam = Camera(Intrinsics(60.0, 60.0, 63.5, 47.5, 128, 96), look_at((0.0, 0.0, 0.5), (1.0, 0.0, 0.0)))
    traj = Trajectory(("slide",), np.zeros((1, 1)), fps=10, gripper=np.zeros((1, 0)))
    img = render_mesh_video(emb, traj, cam, style=FULL)[0]
    # analytic: the ray through each pixel centre meets z = 0 inside the plate
    yy, xx = np.mgrid[0:96, 0:128]
    d_cv = np.stack([(xx - 63.5) / 60.0, (yy - 47.5) / 60.0, np.ones_like(xx, float)], -1)
    M = cam.world_to_cv(None)
    d = d_cv @ M[:3, :3]  # camera-to-world rotation applied to each ray (R^T d)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -0.5 / d[..., 2]
        hit = (d[..., 2] < 0) & (np.abs(s * d[..., 0]) < 10) & (np.abs(s * d[..., 1]) < 10)
    covered = img.any(-1)
    assert hit.mean() > 0.3
    assert (covered != hit).mean() < 0.01  # the plate's far edge: a pixel row at most


def test_clip_near_shares_cut_points_and_keeps_the_winding():
    from oscar_core.render.mesh_raster import clip_near

    # vertex 0 behind, 1 in front: cutting edge 0-1 from either end rounds differently for these numbers
    P = np.array(
        [
            [0.2739233746429086, -0.4604265724722594, -0.9180529521276106],
            [-0.9669447289429418, 0.6265404784005448, 1.0255111545554434],
            [0.3, 0.8, 0.5],
            [-0.6, -0.7, -0.2],
        ]
    )
    faces = np.array([[0, 1, 2], [1, 0, 3], [1, 2, 3]])  # edge 0-1 shared (crossing), in both directions
    Q, f, src = clip_near(P, faces, z=0.1)
    assert (Q[f][..., 2] >= 0.1 - 1e-15).all()
    cuts = Q[len(P) :]
    on_01 = [c for c in cuts if np.allclose(np.cross(c - P[0], P[1] - P[0]), 0, atol=1e-12)]
    assert len(on_01) >= 2 and all(np.array_equal(on_01[0], c) for c in on_01)  # bitwise the same point

    # each piece faces the way its face did
    def normal(V, t):
        return np.cross(V[t[1]] - V[t[0]], V[t[2]] - V[t[0]])

    for t, k in zip(f, src):
        assert normal(Q, t) @ normal(P, faces[k]) > 0


def test_mesh_vertices_agree_with_camera_project():
    emb = ToyArm()
    cam = Camera(
        Intrinsics(300.0, 300.0, 255.5, 143.5, 512, 288, distortion=(-0.12, 0.03, 0.001, -0.001)),
        look_at((-0.15, 0.95, 0.55), (0.15, 0.0, 0.4)),
    )
    traj = Trajectory(
        ("base_yaw", "shoulder", "elbow", "wrist_pitch"),
        np.array([[0.7, 0.9, 1.3, 0.7]] * 2),
        fps=10,
        gripper=np.array([[0.04], [0.06]]),
    )
    uv, depth = mesh_vertices(emb, traj, cam, style=FULL)
    # independently: torch FK of each link, its triangles moved there, camera.project
    geo = mesh_geometry(emb, None)
    q = emb.full_configuration(emb.check_trajectory(traj))
    poses = emb.fk(q, links=list(geo.link_names)).numpy()
    world = np.concatenate(
        [
            g.vertices @ poses[:, i, :3, :3].transpose(0, 2, 1) + poses[:, i, None, :3, 3]
            for i, g in enumerate(geo.links)
        ],
        axis=1,
    )
    ref = project(world, cam)
    np.testing.assert_allclose(uv, ref.uv, atol=1e-9)
    np.testing.assert_allclose(depth, ref.depth, atol=1e-12)


def test_a_frame_alone_equals_the_same_frame_in_a_video():
    from oscar_core import get_embodiment, load_trajectory

    emb = get_embodiment("franka")
    traj = load_trajectory(emb.example_trajectory).time_slice(0, 12)
    cam = emb.load_camera(emb.example_camera)
    video = np.concatenate(list(iter_mesh_chunks(emb, traj, cam, (256, 144), chunk_frames=5)))
    for t in (0, 7, 11):
        alone = render_mesh_video(emb, traj.time_slice(t, t + 1), cam, (256, 144))[0]
        np.testing.assert_array_equal(alone, video[t])
    assert video[7].any()


def test_back_face_culling_changes_nothing_on_closed_meshes():
    emb = ToyArm()
    cam = Camera(Intrinsics(430.0, 430.0, 319.5, 179.5, 640, 360), look_at((1.05, -0.85, 0.7), (0.15, 0.0, 0.4)))
    traj = Trajectory(
        ("base_yaw", "shoulder", "elbow", "wrist_pitch"),
        np.array([[0.7, 0.9, 1.3, 0.7]]),
        fps=10,
        gripper=np.array([[0.04]]),
    )
    culled = render_mesh_video(emb, traj, cam, (320, 180), style=MeshStyle(cull_back=True))[0]
    both = render_mesh_video(emb, traj, cam, (320, 180), style=MeshStyle(cull_back=False))[0]
    differ = (culled != both).any(-1).sum()
    assert culled.any(-1).sum() > 1000 and differ <= 0.005 * culled.any(-1).sum()  # silhouette-edge ties at most


def test_the_gripper_state_shows_through_the_fingers():
    emb = ToyArm()
    cam = Camera(Intrinsics(430.0, 430.0, 319.5, 179.5, 640, 360), look_at((1.05, -0.85, 0.7), (0.15, 0.0, 0.4)))
    q = np.zeros((2, 4))
    video = render_mesh_video(
        emb,
        Trajectory(("base_yaw", "shoulder", "elbow", "wrist_pitch"), q, fps=10, gripper=np.array([[0.0], [0.08]])),
        cam,
        (320, 180),
    )
    diff = (video[0] != video[1]).any(-1)
    ys, xs = np.nonzero(diff)
    assert diff.sum() > 20 and ys.max() < 60  # only the fingers, at the top of the image, changed


# ------------------------------------------------------------------------------ bad inputs


def test_a_plugin_without_geometry_says_so(tmp_path):
    urdf = '<link name="a"/><link name="b"/>'
    emb = make_embodiment(tmp_path, urdf, slider("j", "a", "b"), ("a", "b"), name="bare")()
    traj = Trajectory(("j",), np.zeros((1, 1)), fps=10, gripper=np.zeros((1, 0)))
    with pytest.raises(PluginError, match="'bare' has no visual geometry.*bare.urdf has no <visual>"):
        render_mesh_video(emb, traj, DOWN)


def test_a_missing_mesh_file_is_named(tmp_path):
    urdf = (
        '<link name="a"><visual><geometry><mesh filename="package://nowhere/meshes/gone.stl"/>'
        "</geometry></visual></link>"
    )
    emb = make_embodiment(tmp_path, urdf, "", ("a",), name="gone")()
    with pytest.raises(KinematicsFileError, match=r"link\[a\]\.visual\[0\]\.geometry\.mesh\.filename.*gone\.stl"):
        emb.visual_geometry()


def test_a_plugin_can_give_its_own_geometry(tmp_path):
    urdf = '<link name="a"/><link name="b"/>'
    Bare = make_embodiment(tmp_path, urdf, slider("j", "a", "b"), ("a", "b"), name="given")
    v, f = box_mesh((0.3, 0.2, 0.1))

    class Given(Bare):
        def visual_geometry(self):
            return VisualGeometry((LinkGeometry("b", v, f),), "Given")

    traj = Trajectory(("j",), np.zeros((1, 1)), fps=10, gripper=np.zeros((1, 0)))
    assert render_mesh_video(Given(), traj, DOWN).any()

    class Wrong(Bare):
        def visual_geometry(self):
            return VisualGeometry((LinkGeometry("nope", v, f),), "Wrong")

    with pytest.raises(PluginError, match=r"names links \['nope'\]"):
        render_mesh_video(Wrong(), traj, DOWN)


# ------------------------------------------------------------------------------ CLI and batch


def test_cli_and_batch_render_the_mesh_condition(tmp_path):
    from oscar_core.cli import main
    from oscar_core.media.video import read_video
    from oscar_core.render.batch import read_manifest, render_many

    assets = REPO / "examples" / "oscar-toyarm" / "oscar_toyarm" / "assets"
    traj, cam = assets / "example_trajectory.npz", assets / "example_camera.json"
    common = ["render", "--embodiment", "toyarm", "--trajectory", str(traj), "--camera", str(cam), "--size", "128x72"]
    assert main(common + ["--out", str(tmp_path / "m"), "--format", "png", "--condition", "mesh"]) == 0
    assert main(common + ["--out", str(tmp_path / "s"), "--format", "png"]) == 0
    mesh, skel = read_video(tmp_path / "m"), read_video(tmp_path / "s")
    assert mesh.shape == skel.shape and not np.array_equal(mesh, skel)
    from oscar_core import get_embodiment, load_camera, load_trajectory

    expect = render_mesh_video(get_embodiment("toyarm"), load_trajectory(traj), load_camera(cam), (128, 72))
    np.testing.assert_array_equal(mesh, expect)
    manifest = tmp_path / "m.jsonl"
    manifest.write_text(
        json.dumps(
            {
                "embodiment": "toyarm",
                "trajectory": str(traj),
                "camera": str(cam),
                "out": str(tmp_path / "b") + "/",
                "size": "128x72",
                "condition": "mesh",
            }
        )
        + "\n"
    )
    (result,) = render_many(read_manifest(manifest))
    assert result.ok, result.error
    np.testing.assert_array_equal(read_video(tmp_path / "b"), expect)
