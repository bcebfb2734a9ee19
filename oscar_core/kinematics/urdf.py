"""Read a robot's kinematic tree from URDF or xacro, without meshes.

Only what the skeleton needs is kept: links, joints (type, parent, child,
origin, axis, limits) and mimic relations. Visual, collision, inertial,
transmission and gazebo elements are ignored, so no mesh file is ever opened.

xacro files are expanded with the ``xacro`` package. ``$(find pkg)`` normally
needs a ROS installation (ament_index); here package paths are resolved from a
mapping the caller gives (``packages={"my_description": "/path/to/share"}``).
"""

from __future__ import annotations

import contextlib
import sys
import threading
import types
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from lxml import etree

from ..errors import InputFileError, KinematicsFileError

__all__ = [
    "Joint",
    "KinematicTree",
    "build_tree_from_urdf",
    "build_tree_from_urdf_string",
    "build_tree_from_xacro",
    "expand_xacro",
    "rpy_to_matrix",
]

SUPPORTED_JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed")


def rpy_to_matrix(rpy) -> np.ndarray:
    """URDF roll-pitch-yaw (radians, fixed axes X then Y then Z) → (3, 3) rotation.

    R = Rz(yaw) @ Ry(pitch) @ Rx(roll), as the URDF specification defines it.
    """
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


@dataclass(frozen=True)
class Joint:
    """One URDF joint.

    origin: (4, 4) pose of the child link frame in the parent link frame at q = 0
    (metres). axis: (3,) unit vector in the child frame. lower/upper: limits in
    radians (revolute) or metres (prismatic); None for continuous/fixed.
    mimic: (source joint name, multiplier, offset) or None.
    """

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float | None = None
    upper: float | None = None
    mimic: tuple[str, float, float] | None = None

    @property
    def movable(self) -> bool:
        return self.type != "fixed"


@dataclass(frozen=True)
class KinematicTree:
    """A robot's links and joints.

    ``joint_names`` is the order trajectories use: every movable joint that is
    not a mimic joint, in document order. Mimic joints are filled in from
    their source joint (``q_mimic = multiplier * q_source + offset``).
    """

    name: str
    source: str
    root: str
    links: tuple[str, ...]
    joints: tuple[Joint, ...]
    parent_of: Mapping[str, str] = field(repr=False)  # child link -> parent link
    joint_of: Mapping[str, Joint] = field(repr=False)  # child link -> joint above it

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints if j.movable and j.mimic is None)

    @property
    def movable_joints(self) -> tuple[Joint, ...]:
        return tuple(j for j in self.joints if j.movable)

    def joint(self, name: str) -> Joint:
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(f"{self.source}: no joint named {name!r}; joints: {', '.join(self.joint_names)}")

    def limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(J,) lower and (J,) upper limits of ``joint_names``; ±inf where unlimited."""
        by_name = {j.name: j for j in self.joints}
        lo = np.array([-np.inf if by_name[n].lower is None else by_name[n].lower for n in self.joint_names])
        hi = np.array([np.inf if by_name[n].upper is None else by_name[n].upper for n in self.joint_names])
        return lo, hi

    def ancestors(self, link: str) -> list[str]:
        """Links from ``link``'s parent up to the root, nearest first."""
        out = []
        while link in self.parent_of:
            link = self.parent_of[link]
            out.append(link)
        return out


def _floats(text: str | None, n: int, default, where: str, source: str, field_name: str) -> np.ndarray:
    if text is None:
        return np.array(default, dtype=float)
    parts = text.split()
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = None
    if values is None or len(values) != n or not np.all(np.isfinite(values)):
        raise KinematicsFileError(source, f"{where}.{field_name}", f"{n} finite numbers", repr(text))
    return np.array(values, dtype=float)


def _parse_joint(el, source: str) -> Joint:
    name = el.get("name")
    if not name:
        raise KinematicsFileError(source, "joint.name", "a non-empty name", "a joint without one")
    where = f"joint[{name}]"
    jtype = el.get("type")
    if jtype not in SUPPORTED_JOINT_TYPES:
        raise KinematicsFileError(
            source,
            f"{where}.type",
            f"one of {', '.join(SUPPORTED_JOINT_TYPES)} (model a floating or planar base with the trajectory's base_pose)",
            repr(jtype),
        )
    parent_el, child_el = el.find("parent"), el.find("child")
    if parent_el is None or child_el is None or not parent_el.get("link") or not child_el.get("link"):
        raise KinematicsFileError(source, f"{where}.parent/child", "<parent link=...> and <child link=...>", "missing")
    origin_el = el.find("origin")
    xyz = _floats(None if origin_el is None else origin_el.get("xyz"), 3, (0, 0, 0), where, source, "origin.xyz")
    rpy = _floats(None if origin_el is None else origin_el.get("rpy"), 3, (0, 0, 0), where, source, "origin.rpy")
    origin = np.eye(4)
    origin[:3, :3] = rpy_to_matrix(rpy)
    origin[:3, 3] = xyz
    axis_el = el.find("axis")
    axis = _floats(None if axis_el is None else axis_el.get("xyz"), 3, (1, 0, 0), where, source, "axis.xyz")
    if jtype != "fixed":
        norm = np.linalg.norm(axis)
        if norm < 1e-12:
            raise KinematicsFileError(source, f"{where}.axis.xyz", "a non-zero axis", repr(axis.tolist()))
        axis = axis / norm
    lower = upper = None
    limit_el = el.find("limit")
    if jtype in ("revolute", "prismatic"):
        if limit_el is None:
            raise KinematicsFileError(source, f"{where}.limit", f"a <limit> element for a {jtype} joint", "none")
        try:
            lower = float(limit_el.get("lower", "0"))
            upper = float(limit_el.get("upper", "0"))
        except ValueError:
            raise KinematicsFileError(
                source, f"{where}.limit", "numeric lower/upper", f"{limit_el.get('lower')!r}/{limit_el.get('upper')!r}"
            ) from None
    mimic = None
    mimic_el = el.find("mimic")
    if mimic_el is not None and jtype != "fixed":
        try:
            mimic = (mimic_el.get("joint"), float(mimic_el.get("multiplier", "1")), float(mimic_el.get("offset", "0")))
        except ValueError:
            raise KinematicsFileError(
                source, f"{where}.mimic", "numeric multiplier/offset", etree.tostring(mimic_el).decode()
            ) from None
        if not mimic[0]:
            raise KinematicsFileError(source, f"{where}.mimic.joint", "the name of the joint to follow", "none")
    return Joint(name, jtype, parent_el.get("link"), child_el.get("link"), origin, axis, lower, upper, mimic)


def build_tree_from_urdf_string(text: str | bytes, source: str = "<string>") -> KinematicTree:
    """Parse URDF XML into a :class:`KinematicTree`. ``source`` names the file in errors."""
    if isinstance(text, str):
        text = text.encode()
    try:
        root = etree.fromstring(text, parser=etree.XMLParser(remove_comments=True, resolve_entities=False))
    except etree.XMLSyntaxError as exc:
        raise KinematicsFileError(source, "<xml>", "well-formed URDF XML", str(exc)) from None
    if root.tag != "robot":
        raise KinematicsFileError(source, "<root element>", "<robot>", f"<{root.tag}>")
    links = [el.get("name") for el in root.findall("link")]
    if not links:
        raise KinematicsFileError(source, "robot.link", "at least one <link>", "none")
    if len(set(links)) != len(links):
        dup = sorted({n for n in links if links.count(n) > 1})
        raise KinematicsFileError(source, "robot.link", "unique link names", f"duplicates {dup}")
    joints = [_parse_joint(el, source) for el in root.findall("joint")]
    names = [j.name for j in joints]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise KinematicsFileError(source, "robot.joint", "unique joint names", f"duplicates {dup}")
    link_set = set(links)
    parent_of: dict[str, str] = {}
    joint_of: dict[str, Joint] = {}
    for j in joints:
        for role, link in (("parent", j.parent), ("child", j.child)):
            if link not in link_set:
                raise KinematicsFileError(
                    source, f"joint[{j.name}].{role}", "the name of a <link> in the file", repr(link)
                )
        if j.child in parent_of:
            raise KinematicsFileError(
                source, f"joint[{j.name}].child", "a link with one parent joint", f"{j.child!r} has two"
            )
        parent_of[j.child] = j.parent
        joint_of[j.child] = j
    roots = [l for l in links if l not in parent_of]
    if len(roots) != 1:
        raise KinematicsFileError(source, "robot", "exactly one root link (a tree)", f"roots {roots}")
    for link in links:  # cycle check
        seen, cur = set(), link
        while cur in parent_of:
            if cur in seen:
                raise KinematicsFileError(source, "robot", "a tree without cycles", f"a cycle through {cur!r}")
            seen.add(cur)
            cur = parent_of[cur]
    by_name = {j.name: j for j in joints}
    for j in joints:
        if j.mimic is not None:
            src = by_name.get(j.mimic[0])
            if src is None or not src.movable:
                raise KinematicsFileError(
                    source, f"joint[{j.name}].mimic.joint", "a movable joint of this robot", repr(j.mimic[0])
                )
            if src.mimic is not None:
                raise KinematicsFileError(
                    source, f"joint[{j.name}].mimic.joint", "a joint that is not itself a mimic", repr(src.name)
                )
    return KinematicTree(root.get("name", ""), source, roots[0], tuple(links), tuple(joints), parent_of, joint_of)


def build_tree_from_urdf(path) -> KinematicTree:
    """Load a URDF file (meshes are never opened)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise KinematicsFileError(str(path), "<file>", "a readable URDF file", exc.strerror or str(exc)) from None
    return build_tree_from_urdf_string(data, str(path))


_XACRO_LOCK = threading.Lock()


@contextlib.contextmanager
def _package_resolver(packages: Mapping[str, str | Path], source: str):
    """Make xacro's ``$(find pkg)`` resolve through ``packages`` without ROS.

    xacro imports ``ament_index_python.packages.get_package_share_directory``
    inside its find handler; a stand-in module answers from the mapping while
    the file is processed, and the previous modules are restored afterwards.
    """

    def get_package_share_directory(pkg: str) -> str:
        if pkg not in packages:
            raise KinematicsFileError(
                source,
                f"$(find {pkg})",
                f"a package given in packages= (known: {sorted(packages) or 'none'})",
                "unknown package",
            )
        return str(packages[pkg])

    fake_root = types.ModuleType("ament_index_python")
    fake_pkgs = types.ModuleType("ament_index_python.packages")
    fake_pkgs.get_package_share_directory = get_package_share_directory
    fake_root.packages = fake_pkgs
    names = ("ament_index_python", "ament_index_python.packages")
    with _XACRO_LOCK:
        saved = {n: sys.modules.get(n) for n in names}
        sys.modules.update({names[0]: fake_root, names[1]: fake_pkgs})
        try:
            yield
        finally:
            for n, mod in saved.items():
                if mod is None:
                    sys.modules.pop(n, None)
                else:
                    sys.modules[n] = mod


def expand_xacro(path, args: Mapping[str, str] | None = None, packages: Mapping[str, str | Path] | None = None) -> str:
    """Expand a xacro file to URDF XML text.

    args: ``name:=value`` mappings; packages: ``{package name: share
    directory}`` used for ``$(find pkg)`` (no ROS needed).
    """
    import xacro

    path = Path(path)
    if not path.is_file():
        raise KinematicsFileError(str(path), "<file>", "an existing xacro file", "no such file")
    try:
        with _package_resolver(packages or {}, str(path)):
            doc = xacro.process_file(str(path), mappings={str(k): str(v) for k, v in (args or {}).items()})
    except InputFileError:
        raise
    except Exception as exc:  # noqa: BLE001 - xacro raises its own XacroException and XML errors
        raise KinematicsFileError(
            str(path), "<xacro>", "a xacro file that expands", f"{type(exc).__name__}: {exc}"
        ) from None
    return doc.toxml()


def build_tree_from_xacro(
    path, args: Mapping[str, str] | None = None, packages: Mapping[str, str | Path] | None = None
) -> KinematicTree:
    """Expand a xacro file (see :func:`expand_xacro`) and parse the result."""
    return build_tree_from_urdf_string(expand_xacro(path, args, packages), str(path))
