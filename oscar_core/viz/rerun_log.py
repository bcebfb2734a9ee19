"""Log one episode (:class:`~oscar_core.viz.sources.ViewSource`) into a Rerun recording.

Entity paths (one per thing, as LeRobot's viewer does), on two timelines, ``frame``
(the trajectory's frame index) and ``time`` (seconds, frame / fps):

==============================  ==============================================================
``world/camera``                the camera: ``Transform3D`` (its pose in the robot base frame,
                                camera to world) and ``Pinhole`` (K at the video's size, OpenCV
                                axes: x right, y down, z forward); per frame when it moves
``world/camera/rgb``            the real RGB video (``Image``, or JPEG-encoded with ``jpeg_quality``)
``world/camera/condition``      the condition video over it: RGBA, its colour where drawn, alpha
                                0.8 × brightness (as ``oscar render --overlay`` blends it)
``world/robot/links``           the robot in 3D from the embodiment's FK: ``Capsules3D`` along the
                                skeleton edges (radii of the capsule condition), metres
``world/robot/meshes/<link>``    with ``meshes``: the link's visual meshes (``Mesh3D``, static, in the link's frame,
                                ``<link>/<i>``) under its FK pose per frame (``Transform3D``)
``world/robot/points``          the skeleton points (``Points3D``, the skeleton's colours)
``world/robot/grippers``        the gripper indicator points
``joints/<joint>``              joint positions (``Scalars``): radians (revolute), metres (prismatic)
``gripper/<gripper>``           the raw gripper signal, in the embodiment's units
``gripper_openness/<gripper>``  openness in [0, 1]
``rollout/real``, ``rollout/generated``   a rollout's two videos, side by side in the layout
==============================  ==============================================================

A blueprint lays out the 3D view, the camera view, the rollout pair and the curves. The
recording is a plain ``.rrd`` file readable with ``rerun.dataframe.load_recording``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._util.log import get_logger
from .._util.optional import require

__all__ = ["log_source", "write_recording", "blueprint", "capsule_quaternions", "CONDITION_ALPHA"]

_log = get_logger(__name__)

#: opacity of the condition video where it is fully bright (as ``overlay_skeleton``'s default alpha)
CONDITION_ALPHA = 0.8
#: capsule radius, metres, for embodiments without a kinematic tree (hands given as keypoints)
KEYPOINT_RADIUS = 0.006


def capsule_quaternions(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rerun capsules from ``a`` to ``b`` (N, 3) metres: lengths (N,) and xyzw quaternions (N, 4) turning +z
    (a Rerun capsule's axis) onto b - a. Zero-length segments keep the identity."""
    d = np.asarray(b, float) - np.asarray(a, float)
    length = np.linalg.norm(d, axis=-1)
    u = d / np.where(length > 0, length, 1.0)[:, None]
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(np.broadcast_to(z, u.shape), u)
    w = 1.0 + u[:, 2]  # 1 + cos(angle): the half-angle quaternion, normalised below
    q = np.concatenate([axis, w[:, None]], axis=1)
    flip = w < 1e-9  # u = -z: half a turn about x
    q[flip] = [1.0, 0.0, 0.0, 0.0]
    q[length == 0] = [0.0, 0.0, 0.0, 1.0]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return length, q


def _radii(emb, n_edges: int) -> np.ndarray:
    if not emb.uses_kinematic_tree():
        return np.full(n_edges, KEYPOINT_RADIUS)
    from ..render.capsules import body_reach, link_radii

    return link_radii(n_edges, body_reach(emb))


def _set_time(rec, t: int, fps: float) -> None:
    rec.set_time("frame", sequence=t)
    rec.set_time("time", duration=t / fps)


def _image(rr, frame: np.ndarray, jpeg_quality: int | None):
    img = rr.Image(frame)
    return img if jpeg_quality is None else img.compress(jpeg_quality=jpeg_quality)


def _iter_frames(path, n: int):
    """The first ``n`` frames of a video file or PNG folder, one (H, W, 3) uint8 RGB array at a time."""
    from pathlib import Path

    path = Path(path)
    if path.is_dir():
        import cv2

        for f in sorted(path.glob("*.png"))[:n]:
            img = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if img is None:
                raise ValueError(f"{f}: not a readable PNG frame")
            yield img[..., ::-1]
        return
    import av

    with av.open(str(path)) as container:
        for i, frame in enumerate(container.decode(video=0)):
            if i >= n:
                break
            yield frame.to_ndarray(format="rgb24")


def _iter_frames_at(path, indices):
    """Frames ``indices`` (non-decreasing ints) of a video file or PNG folder, one (H, W, 3) array per index:
    a frame shown at several trajectory frames is yielded again, a skipped one is decoded and dropped."""
    frames = _iter_frames(path, int(indices[-1]) + 1)
    i, frame = -1, None
    for want in indices:
        while i < want:
            frame, i = next(frames), i + 1
        yield frame


def _iter_condition(source, size):
    """The condition video at ``size``, frame by frame: the stored one (fitted to ``size``), else the skeleton
    rendered through the camera chunk by chunk."""
    from ..render.conditions import chunk_renderer
    from ..render.skeleton_video import fit_image

    T = len(source.trajectory)
    if source.condition is not None:
        for f in _iter_frames(source.condition, T):
            yield f if f.shape[:2] == (size[1], size[0]) else fit_image(f, *size)
        return
    for chunk in chunk_renderer("skeleton")(
        source.embodiment, source.trajectory, source.camera, tuple(size), camera_source=source.camera_source
    ):
        yield from chunk


def _log_camera(rr, rec, source, size, fps: float, mount_pose) -> None:
    i0 = source.camera.intrinsics
    cam = source.camera if (i0.width, i0.height) == tuple(size) else source.camera.resized(*size)
    i = cam.intrinsics
    K = np.array([[i.fx, 0.0, i.cx], [0.0, i.fy, i.cy], [0.0, 0.0, 1.0]])
    rec.log(
        "world/camera",
        rr.Pinhole(
            image_from_camera=K, resolution=list(size), camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.2
        ),
        static=True,
    )
    world_to_cv = cam.world_to_cv(mount_pose) if cam.mount_link is not None else cam.world_to_cv()
    cam_to_world = np.linalg.inv(world_to_cv)
    if cam_to_world.ndim == 2:
        rec.log(
            "world/camera", rr.Transform3D(translation=cam_to_world[:3, 3], mat3x3=cam_to_world[:3, :3]), static=True
        )
        return
    for t, M in enumerate(cam_to_world):
        _set_time(rec, t, fps)
        rec.log("world/camera", rr.Transform3D(translation=M[:3, 3], mat3x3=M[:3, :3]))


def _log_curves(rr, rec, source, frames) -> None:
    traj, emb = source.trajectory, source.embodiment
    T = len(traj)
    idx = [rr.TimeColumn("frame", sequence=np.arange(T)), rr.TimeColumn("time", duration=np.arange(T) / traj.fps)]
    for j, name in enumerate(traj.joint_names):
        rec.send_columns(f"joints/{name}", indexes=idx, columns=rr.Scalars.columns(scalars=np.asarray(traj.q[:, j])))
    if traj.gripper is not None:
        for g, name in enumerate(emb.gripper_names):
            rec.send_columns(
                f"gripper/{name}", indexes=idx, columns=rr.Scalars.columns(scalars=np.asarray(traj.gripper[:, g]))
            )
    for g, name in enumerate(emb.gripper_names):
        if g < frames.openness.shape[1]:
            rec.send_columns(
                f"gripper_openness/{name}", indexes=idx, columns=rr.Scalars.columns(scalars=frames.openness[:, g])
            )


def _log_meshes(rr, rec, source) -> list[str]:
    """The embodiment's visual meshes (the mesh condition's, simplified as it does) under their FK poses."""
    from ..render.mesh import mesh_geometry

    emb, traj = source.embodiment, source.trajectory
    geo = mesh_geometry(emb)
    links = list(dict.fromkeys(geo.link_names))
    poses = emb._link_poses(emb.full_configuration(traj), traj.base_pose, links)  # (T, L, 4, 4), the FK frames() uses
    count: dict[str, int] = {}
    for g in geo.links:
        i = count[g.link] = count.get(g.link, -1) + 1
        rec.log(
            f"world/robot/meshes/{g.link}/{i}",
            rr.Mesh3D(vertex_positions=g.vertices, triangle_indices=g.faces),
            static=True,
        )
    for t in range(len(traj)):
        _set_time(rec, t, float(traj.fps))
        for k, link in enumerate(links):
            M = poses[t, k]
            rec.log(f"world/robot/meshes/{link}", rr.Transform3D(translation=M[:3, 3], mat3x3=M[:3, :3]))
    return [f"world/robot/meshes/{link}" for link in links]


def log_source(source, rec, *, jpeg_quality: int | None = None, meshes: bool = False, progress=None) -> dict:
    """Log ``source`` into the Rerun recording stream ``rec``; returns ``{"entities": [...], "frames": T}``.

    jpeg_quality: None logs raw RGB frames (exact; large); 1-100 logs JPEG-encoded frames.
    meshes: also log the embodiment's visual meshes (:func:`oscar_core.render.mesh.mesh_geometry`; a
    :class:`~oscar_core.errors.PluginError` when it has none).
    progress: an optional callable ``progress(t)`` called after each frame.
    """
    rr = require("rerun", "viz")
    from ..media.video import video_info
    from ..render.skeleton_video import fit_image

    emb, traj, cam = source.embodiment, source.trajectory, source.camera
    T, fps = len(traj), float(traj.fps)
    frames = emb.frames(traj, mount_link=None if cam is None else cam.mount_link)
    entities = []

    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    # videos are read (and the condition rendered) frame by frame: an episode never sits in memory whole
    rgb = None
    if source.rgb is not None:  # the real video by time: its frame nearest to each trajectory frame
        rgb = _iter_frames_at(source.rgb, source.rgb_frames or range(T))
    gen = _iter_frames(source.generated, T) if source.generated is not None else None
    size = None
    if cam is not None:
        base = source.rgb or source.generated
        info = video_info(base) if base is not None else None
        size = (info["width"], info["height"]) if info else (cam.intrinsics.width, cam.intrinsics.height)
        _log_camera(rr, rec, source, size, fps, frames.mount_pose)
        entities.append("world/camera")
    cond = _iter_condition(source, size) if cam is not None else None

    edges = emb.edge_index()
    radii = _radii(emb, len(edges))
    pts_rgb, _ = emb.colors()
    _log_curves(rr, rec, source, frames)
    entities += [f"joints/{n}" for n in traj.joint_names]
    entities += [f"gripper/{n}" for n in emb.gripper_names if traj.gripper is not None]
    entities += [f"gripper_openness/{n}" for n in emb.gripper_names[: frames.openness.shape[1]]]
    if meshes:
        entities += _log_meshes(rr, rec, source)
    for t in range(T):
        _set_time(rec, t, fps)
        P = frames.points[t]
        ok = np.isfinite(P[edges]).all(axis=(1, 2))
        a, b = P[edges[ok, 0]], P[edges[ok, 1]]
        length, quat = capsule_quaternions(a, b)
        rec.log(
            "world/robot/links",
            rr.Capsules3D(lengths=length, radii=radii[ok], translations=a, quaternions=quat),
        )
        rec.log("world/robot/points", rr.Points3D(P, colors=pts_rgb, radii=0.01))
        if len(frames.gripper_points[t]):
            rec.log("world/robot/grippers", rr.Points3D(frames.gripper_points[t], radii=0.015))
        if rgb is not None:
            real = next(rgb)
            real = real if cam is None or real.shape[:2] == (size[1], size[0]) else fit_image(real, *size)
            rec.log("world/camera/rgb" if cam is not None else "camera/rgb", _image(rr, real, jpeg_quality))
            if gen is not None:
                rec.log("rollout/real", _image(rr, real, jpeg_quality))
        if cond is not None:
            c = next(cond)
            alpha = np.round(CONDITION_ALPHA * c.max(axis=-1, keepdims=True).astype(np.float32)).astype(np.uint8)
            rec.log("world/camera/condition", rr.Image(np.concatenate([c, alpha], axis=-1), color_model="RGBA"))
        if gen is not None:
            rec.log("rollout/generated", _image(rr, next(gen), jpeg_quality))
        if progress is not None:
            progress(t)
    entities += ["world/robot/links", "world/robot/points"]
    if len(frames.gripper_points[0]):
        entities.append("world/robot/grippers")
    if rgb is not None:
        entities.append("world/camera/rgb" if cam is not None else "camera/rgb")
    if cond is not None:
        entities.append("world/camera/condition")
    if gen is not None:
        entities += ["rollout/generated"] + (["rollout/real"] if rgb is not None else [])
    return {"entities": sorted(entities), "frames": T}


def blueprint(source):
    """The layout of a recording of ``source``: the 3D view beside the camera view, the rollout pair, the curves."""
    rrb = require("rerun.blueprint", "viz")
    has_camera, has_generated, has_rgb = source.camera is not None, source.generated is not None, source.rgb is not None
    top = [rrb.Spatial3DView(origin="/world", name="robot (3D)")]
    if has_camera:
        top.append(rrb.Spatial2DView(origin="/world/camera", name="camera + condition"))
    views = [rrb.Horizontal(*top)]
    if has_generated:
        pair = [rrb.Spatial2DView(origin="/rollout/generated", name="generated")]
        if has_rgb:
            pair.insert(0, rrb.Spatial2DView(origin="/rollout/real", name="real"))
        views.append(rrb.Horizontal(*pair))
    curves = [rrb.TimeSeriesView(origin="/joints", name="joints")]
    if source.embodiment.gripper_names and source.trajectory.gripper is not None:
        curves.append(rrb.TimeSeriesView(origin="/gripper", name="gripper"))
    views.append(rrb.Horizontal(*curves))
    return rrb.Blueprint(rrb.Vertical(*views), collapse_panels=False)


def write_recording(
    source, save=None, *, spawn: bool = False, jpeg_quality: int | None = 90, meshes: bool = False, progress=None
) -> dict:
    """Log ``source`` into a new recording and write it to ``save`` (an ``.rrd`` file, atomically) and/or send it
    to a newly spawned viewer (``spawn``). Returns :func:`log_source`'s summary plus ``"save"``."""
    rr = require("rerun", "viz")
    if save is None and not spawn:
        raise ValueError("write_recording: give save=FILE.rrd, spawn=True, or both")
    if meshes:  # an embodiment without visual geometry is refused before a file is opened
        from ..render.mesh import mesh_geometry

        mesh_geometry(source.embodiment)
    rec = rr.RecordingStream("oscar_view", recording_id=source.name)
    layout = blueprint(source)
    tmp = None
    sinks = []
    if spawn:
        rec.spawn(connect=False, default_blueprint=layout)
        sinks.append(rr.GrpcSink())
    if save is not None:
        save = Path(save)
        tmp = save.with_name(f".{save.name}.tmp")
        sinks.append(rr.FileSink(str(tmp)))
    rec.set_sinks(*sinks, default_blueprint=layout)
    try:
        summary = log_source(source, rec, jpeg_quality=jpeg_quality, meshes=meshes, progress=progress)
        rec.flush()
        rec.disconnect()
        if tmp is not None:
            tmp.replace(save)
    except BaseException:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise
    summary["save"] = None if save is None else str(save)
    return summary
