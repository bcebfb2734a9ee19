"""The contract one embodiment plugin fulfils.

A plugin subclasses :class:`Embodiment`, sets a few class attributes and
returns the class from the ``oscar_register_embodiments`` hook::

    class ToyArm(Embodiment):
        name = "toyarm"
        urdf = ASSETS / "toyarm.urdf"
        skeleton = Skeleton(links=("base", "upper", "fore", "tool"))
        grippers = (Gripper("gripper", link="tool", signal_range=(0.0, 0.08), closed_at="low"),)

Everything else has defaults: edges come from the kinematic tree, colours
from a palette, the camera convention is OpenCV camera-to-world with a static
camera. Embodiments that are not URDF robots (e.g. hands given as keypoints)
override :meth:`Embodiment.frames`.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from ..errors import CameraFileError, PluginError, TrajectoryError
from ..kinematics.trajectory import Trajectory
from .skeleton import Skeleton, collapse_tree_edges

__all__ = ["Embodiment", "Gripper", "CameraSpec", "SkeletonFrames", "JointLimitWarning", "DefaultPoseWarning"]

NAME_CHARS = set("abcdefghijklmnopqrstuvwxyz0123456789_-")


class JointLimitWarning(UserWarning):
    """A trajectory goes beyond a joint's limits; it is rendered anyway."""


class DefaultPoseWarning(UserWarning):
    """A trajectory left out joints; the embodiment's ``default_pose`` filled them in.

    joints: the names filled in, in the embodiment's joint order;
    values: {name: value} used for each (radians / metres).
    """

    def __init__(self, message: str, joints: tuple[str, ...] = (), values: Mapping[str, float] | None = None):
        super().__init__(message)
        self.joints = tuple(joints)
        self.values = dict(values or {})


@dataclass(frozen=True)
class Gripper:
    """One gripper (or hand) and its state signal.

    name: the signal's name (trajectory ``gripper_names`` use it).
    link: link where the indicator is drawn; point: offset in that link's
        frame, metres.
    signal_range: (low, high) of the raw dataset signal, in its units (e.g.
        metres of finger width, or 0–1 of a Robotiq position).
    closed_at: "low" if ``low`` means closed (a width), "high" if ``high``
        means closed (a Robotiq position, 1 = closed).
    tolerance: fraction of the range a value may exceed it by before it is an
        error (sensor noise); such values are clipped.
    joint: optional finger joint driven by this signal; it is then not part
        of the trajectory's ``q`` but set from openness, linearly from
        ``joint_range[0]`` (closed) to ``joint_range[1]`` (open).
    """

    name: str
    link: str
    point: tuple[float, float, float] = (0.0, 0.0, 0.0)
    signal_range: tuple[float, float] = (0.0, 1.0)
    closed_at: str = "low"
    tolerance: float = 0.05
    joint: str | None = None
    joint_range: tuple[float, float] = (0.0, 0.0)

    def openness(self, signal: np.ndarray, source: str = "<trajectory>") -> np.ndarray:
        """Raw signal (T,) → openness (T,) in [0, 1], 1 = fully open."""
        lo, hi = (float(v) for v in self.signal_range)
        span = hi - lo
        slack = self.tolerance * span
        bad = np.flatnonzero((signal < lo - slack) | (signal > hi + slack))
        if bad.size:
            t = int(bad[0])
            raise TrajectoryError(
                source,
                f"gripper[{self.name}]",
                f"values in [{lo:g}, {hi:g}] (the gripper's documented range, ±{self.tolerance:.0%})",
                f"{signal[t]:g} at frame {t} ({bad.size} frames out of range)",
            )
        frac = np.clip((signal - lo) / span, 0.0, 1.0)
        return frac if self.closed_at == "low" else 1.0 - frac


@dataclass(frozen=True)
class CameraSpec:
    """How this embodiment's datasets give camera calibrations.

    convention: axes of the extrinsic's camera frame ("opencv", "opengl",
        "ros_body"; see :mod:`oscar_core.camera.pinhole`) in this embodiment's usual
        calibrations; the default for camera files that omit ``convention``.
    direction: "camera_to_world" (the camera's pose) or "world_to_camera";
        the default for camera files that omit ``direction``. Dataset adapters
        that read other layouts set both explicitly on the cameras they build.
    mount_link: None for a static camera in the robot base frame, or the
        link the camera is attached to (a head), whose pose moves it.
    """

    convention: str = "opencv"
    direction: str = "camera_to_world"
    mount_link: str | None = None


@dataclass(frozen=True)
class SkeletonFrames:
    """3D inputs of the renderer for one trajectory.

    points: (T, K, 3) world positions of the skeleton points, metres.
    gripper_points: (T, G, 3) world positions of the gripper indicators.
    openness: (T, G) in [0, 1].
    mount_pose: (T, 4, 4) world pose of the camera mount link, or None.
    """

    points: np.ndarray
    gripper_points: np.ndarray
    openness: np.ndarray
    mount_pose: np.ndarray | None = None


def _default_pose_problems(pose) -> list[str]:
    """Problems of a ``default_pose`` class attribute visible without the kinematic tree."""
    if not isinstance(pose, Mapping):
        return [f"default_pose: expected a mapping of joint name to value, found {type(pose).__name__}"]
    out = []
    for n, v in pose.items():
        if not isinstance(n, str) or not n:
            out.append(f"default_pose: expected joint names as keys, found {n!r}")
        elif isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v):
            out.append(f"default_pose[{n!r}]: expected a finite number (radians / metres), found {v!r}")
    return out


class Embodiment:
    """Base class of every embodiment. Subclasses set the class attributes."""

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    license: ClassVar[str] = ""  # SPDX identifier of the kinematic description
    datasets: ClassVar[tuple[str, ...]] = ()
    urdf: ClassVar[Path | str | None] = None
    # the URDF XML itself (a one-file plugin needs no asset file); parsed like a file, errors name the plugin
    urdf_text: ClassVar[str | None] = None
    xacro: ClassVar[Path | str | None] = None
    xacro_args: ClassVar[Mapping[str, str]] = {}
    packages: ClassVar[Mapping[str, Path | str]] = {}
    skeleton: ClassVar[Skeleton | None] = None
    grippers: ClassVar[tuple[Gripper, ...]] = ()
    camera: ClassVar[CameraSpec] = CameraSpec()
    # joint name -> value (radians / metres) for joints a trajectory may leave out
    default_pose: ClassVar[Mapping[str, float]] = {}
    example_trajectory: ClassVar[Path | str | None] = None
    example_camera: ClassVar[Path | str | None] = None
    # links whose poses are the end effectors (one per arm, left arm first; used by the latent-action baseline)
    end_effector_links: ClassVar[tuple[str, ...]] = ()

    # ---- contract checks -------------------------------------------------
    @classmethod
    def class_problems(cls) -> list[str]:
        """Contract problems visible without loading files (cheap)."""
        out = []
        name = getattr(cls, "name", "")
        if not isinstance(name, str) or not name or set(name) - NAME_CHARS:
            out.append(f"name: expected a lowercase identifier (a-z 0-9 _ -), found {name!r}")
        if cls.uses_kinematic_tree():
            given = [k for k in ("urdf", "urdf_text", "xacro") if getattr(cls, k) is not None]
            if len(given) != 1:
                out.append(
                    "urdf/urdf_text/xacro: expected exactly one kinematic description, found "
                    + (" and ".join(given) if given else "none")
                )
            if cls.urdf_text is not None and not isinstance(cls.urdf_text, str):
                out.append(f"urdf_text: expected the URDF XML as a str, found {type(cls.urdf_text).__name__}")
        if not isinstance(cls.skeleton, Skeleton):
            out.append(f"skeleton: expected a Skeleton, found {type(cls.skeleton).__name__}")
        else:
            out += cls.skeleton.problems()
        if not isinstance(cls.grippers, tuple) or not all(isinstance(g, Gripper) for g in cls.grippers):
            out.append("grippers: expected a tuple of Gripper")
        else:
            names = [g.name for g in cls.grippers]
            if len(set(names)) != len(names):
                out.append(f"grippers: expected unique names, found {names}")
            for g in cls.grippers:
                if g.closed_at not in ("low", "high"):
                    out.append(f"grippers[{g.name}].closed_at: expected 'low' or 'high', found {g.closed_at!r}")
                if not g.signal_range[1] > g.signal_range[0]:
                    out.append(f"grippers[{g.name}].signal_range: expected low < high, found {g.signal_range}")
        if not isinstance(cls.camera, CameraSpec):
            out.append(f"camera: expected a CameraSpec, found {type(cls.camera).__name__}")
        if not isinstance(cls.datasets, tuple):
            out.append(f"datasets: expected a tuple of names, found {type(cls.datasets).__name__}")
        out += _default_pose_problems(cls.default_pose)
        return out

    @classmethod
    def uses_kinematic_tree(cls) -> bool:
        """True unless the subclass computes its points itself (overrides frames)."""
        return cls.frames is Embodiment.frames

    def problems(self) -> list[str]:
        """Contract problems that need the kinematic description loaded."""
        out = []
        if not self.uses_kinematic_tree():
            return out
        links = self.tree.links
        out += self.skeleton.problems(links)
        known = set(links)
        for g in self.grippers:
            if g.link not in known:
                out.append(f"grippers[{g.name}].link: expected a link of the kinematic tree, found {g.link!r}")
        tree_joints = set(self.tree.joint_names)
        for g in self.grippers:
            if g.joint is not None and g.joint not in tree_joints:
                out.append(
                    f"grippers[{g.name}].joint: expected a movable, non-mimic joint of the tree, found {g.joint!r}"
                )
        for link in self.end_effector_links:
            if link not in known:
                out.append(f"end_effector_links: expected links of the kinematic tree, found {link!r}")
        if self.camera.mount_link is not None and self.camera.mount_link not in known:
            out.append(f"camera.mount_link: expected a link of the kinematic tree, found {self.camera.mount_link!r}")
        if self.default_pose:
            names = self.joint_names
            lo, hi = self.tree.limits()
            limits = {n: (lo[i], hi[i]) for i, n in enumerate(self.tree.joint_names)}
            for n, v in self.default_pose.items():
                if n not in names:
                    out.append(
                        f"default_pose[{n!r}]: expected a joint of the trajectory order {list(names)} "
                        "(not a mimic or gripper-driven joint)"
                    )
                elif not (limits[n][0] - 1e-9 <= float(v) <= limits[n][1] + 1e-9):
                    out.append(
                        f"default_pose[{n!r}]: expected a value within the joint's limits "
                        f"[{limits[n][0]:g}, {limits[n][1]:g}], found {float(v):g}"
                    )
        return out

    def __init__(self):
        problems = self.class_problems()
        if not problems:
            problems = self.problems()
        if problems:
            raise PluginError(
                f"embodiment {self.name!r} ({type(self).__module__}.{type(self).__qualname__}) "
                "breaks the contract:\n  " + "\n  ".join(problems)
            )

    # ---- kinematics ------------------------------------------------------
    @functools.cached_property
    def tree(self):
        """The :class:`~oscar_core.kinematics.urdf.KinematicTree` (parsed once)."""
        from ..kinematics.urdf import build_tree_from_urdf, build_tree_from_urdf_string, build_tree_from_xacro

        if self.urdf is not None:
            return build_tree_from_urdf(self.urdf)
        if self.urdf_text is not None:
            return build_tree_from_urdf_string(self.urdf_text, self.urdf_text_source())
        return build_tree_from_xacro(self.xacro, self.xacro_args, self.packages)

    @classmethod
    def urdf_text_source(cls) -> str:
        """How errors name an embodiment's ``urdf_text``: ``<urdf_text of embodiment 'NAME' (module.Class)>``."""
        return f"<urdf_text of embodiment {cls.name!r} ({cls.__module__}.{cls.__qualname__})>"

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Joint order trajectories use: the tree's movable joints minus mimic
        joints and joints driven by a gripper signal."""
        if not self.uses_kinematic_tree():
            return ()
        driven = {g.joint for g in self.grippers}
        return tuple(n for n in self.tree.joint_names if n not in driven)

    def full_configuration(self, traj: Trajectory) -> np.ndarray:
        """(T, J_tree) joint values in ``tree.joint_names`` order: the trajectory's
        joints plus gripper-driven finger joints set from openness."""
        q = traj.q
        driven = {g.joint: i for i, g in enumerate(self.grippers) if g.joint is not None}
        if not driven:
            return q
        openness = self.gripper_openness(traj.gripper, traj.source)
        cols, k = [], 0
        for n in self.tree.joint_names:
            if n in driven:
                g = self.grippers[driven[n]]
                lo, hi = g.joint_range
                cols.append(lo + openness[:, driven[n]] * (hi - lo))
            else:
                cols.append(q[:, k])
                k += 1
        return np.stack(cols, axis=1)

    @property
    def gripper_names(self) -> tuple[str, ...]:
        return tuple(g.name for g in self.grippers)

    @functools.cached_property
    def edges(self) -> tuple[tuple[str, str], ...]:
        """(parent, child) skeleton edges: given, or the tree collapsed onto the links."""
        if self.skeleton.edges is not None:
            return self.skeleton.edges
        return collapse_tree_edges(self.skeleton.links, self.tree.parent_of)

    def edge_index(self) -> np.ndarray:
        """(E, 2) int indices into ``skeleton.links``."""
        pos = {l: i for i, l in enumerate(self.skeleton.links)}
        return np.array([[pos[a], pos[b]] for a, b in self.edges], dtype=np.int64).reshape(-1, 2)

    def colors(self) -> tuple[np.ndarray, np.ndarray]:
        """(K, 3) point colours and (E, 3) edge colours (child's group), uint8 RGB."""
        group_of, rgb = self.skeleton.group_of(), self.skeleton.group_colors()
        pts = np.array([rgb[group_of[l]] for l in self.skeleton.links], dtype=np.uint8)
        edges = np.array([rgb[group_of[b]] for _, b in self.edges], dtype=np.uint8).reshape(-1, 3)
        return pts, edges

    def forward_kinematics(self, device="cpu", dtype=None):
        """A cached :class:`~oscar_core.kinematics.fk_torch.ForwardKinematics` for this device/dtype."""
        import torch

        from ..kinematics.fk_torch import ForwardKinematics

        key = (str(device), dtype or torch.float64)
        cache = self.__dict__.setdefault("_fk_cache", {})
        if key not in cache:
            cache[key] = ForwardKinematics(self.tree, dtype=key[1], device=device)
        return cache[key]

    def fk(self, q, base_pose=None, links=None, device="cpu", dtype=None):
        """Link poses: q (T, J_tree) in ``tree.joint_names`` order (see
        :meth:`full_configuration`) → (T, K, 4, 4) torch tensor.

        links defaults to the skeleton's links. base_pose: optional (T, 4, 4).
        """
        fk = self.forward_kinematics(device, dtype)
        return fk(q, list(links or self.skeleton.links), base_pose)

    # ---- visual geometry (the mesh condition) -----------------------------
    def visual_geometry(self):
        """Triangles of each link in its own frame: a :class:`~oscar_core.kinematics.visual.VisualGeometry`.

        Default: the ``<visual>`` elements of the URDF (or expanded xacro) this
        embodiment loads, ``package://`` names resolved through ``packages`` (see
        :func:`oscar_core.kinematics.visual.read_urdf_visuals`). Override it to give or replace
        geometry (e.g. meshes from elsewhere for a kinematic-only description).
        Raises :class:`PluginError` when there is none.
        """
        from ..kinematics.visual import read_urdf_visuals

        if not self.uses_kinematic_tree():
            raise PluginError(
                f"embodiment {self.name!r} has no visual geometry: it computes its points itself "
                "(no URDF); override Embodiment.visual_geometry to give triangles per link"
            )
        if self.urdf is not None:
            geo = read_urdf_visuals(self.urdf, self.packages)
        elif self.urdf_text is not None:  # relative mesh names: beside the plugin's module file
            import sys

            module = sys.modules.get(type(self).__module__)
            base = Path(module.__file__).parent if getattr(module, "__file__", None) else Path.cwd()
            geo = read_urdf_visuals(self.urdf_text, self.packages, source=self.urdf_text_source(), base_dir=base)
        else:
            from ..kinematics.urdf import expand_xacro

            geo = read_urdf_visuals(
                expand_xacro(self.xacro, self.xacro_args, self.packages),
                self.packages,
                source=str(self.xacro),
                base_dir=Path(self.xacro).parent,
            )
        if not geo.links:
            raise PluginError(
                f"embodiment {self.name!r} has no visual geometry: {geo.source} has no <visual> "
                "elements (a kinematic-only description); add them to its links or override "
                "Embodiment.visual_geometry"
            )
        return geo

    # ---- trajectories ----------------------------------------------------
    def check_trajectory(self, traj: Trajectory) -> Trajectory:
        """Validate ``traj`` against this embodiment; returns it in this joint order.

        Raises :class:`TrajectoryError` for unknown or missing joints, wrong
        gripper count or names, gripper values out of range, ``keypoints``
        given to a kinematic-tree embodiment or with a point count other than
        ``len(skeleton.links)``; warns with
        :class:`JointLimitWarning` (and renders anyway) for joints beyond limits.
        """
        src = traj.source
        if traj.keypoints is not None:
            K = len(self.skeleton.links)
            if self.uses_kinematic_tree():
                raise TrajectoryError(
                    src,
                    "keypoints",
                    f"no keypoints ({self.name!r} computes its points from joint positions)",
                    f"shape {traj.keypoints.shape}",
                )
            if traj.keypoints.shape[1] != K:
                raise TrajectoryError(
                    src,
                    "keypoints",
                    f"shape (T, {K}, 3): one point per skeleton point of {self.name!r}",
                    f"shape {traj.keypoints.shape}",
                )
        expected = self.joint_names
        traj, filled = self.fill_default_pose(traj)
        if set(traj.joint_names) != set(expected) or len(traj.joint_names) != len(expected):
            unknown = [n for n in traj.joint_names if n not in expected]
            missing = [n for n in expected if n not in traj.joint_names]
            without = " (the embodiment has no default pose for them)" if missing and self.default_pose else ""
            raise TrajectoryError(
                src,
                "joint_names",
                f"the {len(expected)} joints of {self.name!r}: {list(expected)}",
                f"{len(traj.joint_names)} names; unknown {unknown}, missing {missing}{without}",
            )
        if filled:
            warnings.warn(
                DefaultPoseWarning(
                    f"{src}: {len(filled)} joints not in the trajectory were set from the default pose of {self.name!r}: "
                    + ", ".join(f"{n}={v:g}" for n, v in filled.items()),
                    tuple(filled),
                    filled,
                ),
                stacklevel=2,
            )
        if tuple(traj.joint_names) != expected:
            order = [traj.joint_names.index(n) for n in expected]
            traj = traj.replace(joint_names=expected, q=traj.q[:, order])
        G = len(self.grippers)
        if traj.gripper.shape[1] != G:
            raise TrajectoryError(
                src, "gripper", f"shape (T, {G}) for grippers {list(self.gripper_names)}", f"shape {traj.gripper.shape}"
            )
        if traj.gripper_names is not None and tuple(traj.gripper_names) != self.gripper_names:
            if set(traj.gripper_names) != set(self.gripper_names):
                raise TrajectoryError(
                    src, "gripper_names", f"{list(self.gripper_names)}", f"{list(traj.gripper_names)}"
                )
            order = [list(traj.gripper_names).index(n) for n in self.gripper_names]
            traj = traj.replace(gripper_names=self.gripper_names, gripper=traj.gripper[:, order])
        if self.uses_kinematic_tree():
            lo, hi = self.tree.limits()
            keep = [i for i, n in enumerate(self.tree.joint_names) if n in set(expected)]
            lo, hi = lo[keep], hi[keep]
            over = (traj.q < lo - 1e-6) | (traj.q > hi + 1e-6)
            if over.any():
                j = int(np.argmax(over.sum(0)))
                t = int(np.argmax(over[:, j]))
                warnings.warn(
                    f"{src}: joint {expected[j]!r} is beyond its limits [{lo[j]:g}, {hi[j]:g}] in {int(over[:, j].sum())} "
                    f"frames (first: {traj.q[t, j]:g} at frame {t}); {int(over.any(0).sum())} joints affected; rendering anyway",
                    JointLimitWarning,
                    stacklevel=2,
                )
        return traj

    def fill_default_pose(self, traj: Trajectory) -> tuple[Trajectory, dict[str, float]]:
        """Add the joints ``traj`` leaves out that have a ``default_pose`` value.

        Returns the trajectory with those joints appended as constant columns
        (q (T, J + F), radians / metres) and ``{name: value}`` of the F joints
        filled in, in this embodiment's joint order (empty when none were).
        Joints missing without a default stay missing; :meth:`check_trajectory`
        reports them. Called by :meth:`check_trajectory`, which also warns
        with :class:`DefaultPoseWarning`.
        """
        if not self.default_pose or traj.keypoints is not None:
            return traj, {}
        given = set(traj.joint_names)
        filled = {n: float(self.default_pose[n]) for n in self.joint_names if n not in given and n in self.default_pose}
        if not filled:
            return traj, {}
        cols = np.broadcast_to(np.array(list(filled.values())), (len(traj), len(filled)))
        return traj.replace(
            joint_names=tuple(traj.joint_names) + tuple(filled), q=np.concatenate([traj.q, cols], axis=1)
        ), filled

    def gripper_openness(self, gripper: np.ndarray, source: str = "<trajectory>") -> np.ndarray:
        """(T, G) raw gripper signals → (T, G) openness in [0, 1]."""
        cols = [g.openness(gripper[:, i], source) for i, g in enumerate(self.grippers)]
        return np.stack(cols, axis=1) if cols else np.zeros((gripper.shape[0], 0))

    def _link_poses(self, q_full: np.ndarray, base_pose, links: Sequence[str], device="cpu") -> np.ndarray:
        """(T, K, 4, 4) float64 world poses of ``links`` for ``q_full`` (T, J_tree).

        On the CPU with the base class's kinematics this is
        :class:`~oscar_core.kinematics.fk_numpy.NumpyForwardKinematics` (no torch import); on
        another device, or when a plugin overrides ``fk`` or ``forward_kinematics``,
        it is the embodiment's own (torch) ``fk``.
        """
        cls = type(self)
        on_cpu = str(device).split(":")[0] == "cpu"
        if on_cpu and cls.fk is Embodiment.fk and cls.forward_kinematics is Embodiment.forward_kinematics:
            from ..kinematics.fk_numpy import NumpyForwardKinematics

            cache = self.__dict__.setdefault("_numpy_fk", {})
            fk = cache.get("fk")
            if fk is None:
                fk = cache["fk"] = NumpyForwardKinematics(self.tree)
            return fk(q_full, list(links), base_pose)
        import torch

        return self.fk(q_full, base_pose, links=list(links), device=device).to("cpu", torch.float64).numpy()

    def frames(self, traj: Trajectory, device="cpu", mount_link: str | None = None) -> SkeletonFrames:
        """World-frame skeleton points, gripper indicator points and the camera mount's pose.

        ``traj`` must already be checked (:meth:`check_trajectory`).
        mount_link: the link a camera rides on (``Camera.mount_link``), whose
        world pose is returned as ``mount_pose``; None for a static camera.
        One FK call covers the skeleton links, the gripper links and the mount.
        """
        sk_links = list(self.skeleton.links)
        g_links = [g.link for g in self.grippers]
        mount = [mount_link] if mount_link else []
        links = list(dict.fromkeys(sk_links + g_links + mount))
        poses = self._link_poses(self.full_configuration(traj), traj.base_pose, links, device)  # numpy on the CPU
        at = {l: i for i, l in enumerate(links)}

        def points_of(names, offsets):
            P = poses[:, [at[n] for n in names]]  # (T, n, 4, 4)
            return np.einsum("tnij,nj->tni", P[..., :3, :3], offsets) + P[..., :3, 3]

        pts = points_of(sk_links, self.skeleton.point_offsets())
        gpts = points_of(g_links, np.array([g.point for g in self.grippers], dtype=float).reshape(-1, 3))
        mount_pose = poses[:, at[mount[0]]] if mount else None
        return SkeletonFrames(pts, gpts, self.gripper_openness(traj.gripper, traj.source), mount_pose)

    def load_camera(self, path):
        """Read a camera JSON file; ``convention``/``direction`` default to this
        embodiment's :class:`CameraSpec` when the file omits them."""
        from ..camera import load_camera

        return load_camera(path, defaults=self.camera)

    def check_camera(self, camera, source: str = "<camera>"):
        """Raise :class:`CameraFileError` if ``camera`` was calibrated for another mount or embodiment.

        A static camera (in the world / robot base frame) fits every
        embodiment; a camera riding on a link must ride on this embodiment's
        ``camera.mount_link`` (its head camera, say). A camera with one
        extrinsic per frame is checked against the trajectory's length by
        :meth:`Camera.check_frames`, where the renderer meets both.
        """
        if camera.embodiment is not None and camera.embodiment != self.name:
            raise CameraFileError(source, "embodiment", f"{self.name!r}", repr(camera.embodiment))
        if camera.mount_link is not None and camera.mount_link != self.camera.mount_link:
            want = "static (mount: null)"
            if self.camera.mount_link is not None:
                want += f" or mount link {self.camera.mount_link!r}"
            raise CameraFileError(
                source, "mount", f"{want} for embodiment {self.name!r}", f"mount link {camera.mount_link!r}"
            )

    def info(self) -> dict:
        """A summary for listings (loads the kinematic description)."""
        return {
            "name": self.name,
            "description": self.description,
            "joints": len(self.joint_names),
            "links": len(self.skeleton.links),
            "grippers": list(self.gripper_names),
            "datasets": list(self.datasets),
            "license": self.license,
        }
