"""A robot's visual geometry: triangle meshes per link, from URDF ``<visual>`` elements.

The mesh condition (:mod:`oscar_core.render.mesh`) draws these triangles through
the same camera as the skeleton. Each ``<visual>`` of a link becomes triangles in
that link's frame (metres), its ``<origin>`` and mesh ``scale`` already applied:

- ``<mesh filename=… scale=…>``: STL, DAE, OBJ (and what else ``trimesh`` reads),
  loaded with the optional dependency ``trimesh`` (``pip install "oscar-wm[mesh]"``);
  ``package://NAME/…`` is resolved from the embodiment's ``packages`` mapping, else
  from an ancestor folder of the URDF named ``NAME`` (or holding ``NAME``), as
  ``example-robot-data``'s files are laid out; ``file://`` and relative paths too;
- primitives ``<box size>``, ``<cylinder radius length>``, ``<sphere radius>`` and
  ``<capsule radius length>`` (axis along the visual frame's z, centred), built here.

Heavy meshes are simplified by vertex clustering (:mod:`oscar_core.kinematics.mesh_simplify`).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote, urlparse

import numpy as np

from ..errors import InputFileError, KinematicsFileError

__all__ = [
    "LinkGeometry",
    "VisualGeometry",
    "box_mesh",
    "cylinder_mesh",
    "sphere_mesh",
    "capsule_mesh",
    "read_urdf_visuals",
    "load_mesh_file",
]

#: segments around a cylinder / capsule / sphere: ~1.3 % radius error at the flat of a facet
ROUND_SEGMENTS = 20


@dataclass(frozen=True)
class LinkGeometry:
    """Triangles of one link, in the link's frame.

    vertices: (V, 3) float64 metres; faces: (F, 3) int64 indices into ``vertices``.
    """

    link: str
    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self):
        v = np.asarray(self.vertices, dtype=np.float64)
        f = np.asarray(self.faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
            raise ValueError(f"link {self.link!r}: vertices: expected finite (V, 3) metres, found shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or (f.size and (f.min() < 0 or f.max() >= len(v))):
            raise ValueError(
                f"link {self.link!r}: faces: expected (F, 3) indices into {len(v)} vertices, "
                f"found shape {f.shape}" + (f" with indices {f.min()}..{f.max()}" if f.size else "")
            )
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)


@dataclass(frozen=True)
class VisualGeometry:
    """A robot's visual geometry: one :class:`LinkGeometry` per link that has any.

    source: where it came from (a URDF path, or the plugin), for messages.
    """

    links: tuple[LinkGeometry, ...]
    source: str = "<visual geometry>"

    @property
    def link_names(self) -> tuple[str, ...]:
        return tuple(g.link for g in self.links)

    @property
    def face_count(self) -> int:
        return int(sum(len(g.faces) for g in self.links))

    def simplified(self, cell: float) -> VisualGeometry:
        """Every link's mesh vertex-clustered on a grid of ``cell`` metres (see :mod:`oscar_core.kinematics.mesh_simplify`)."""
        from .mesh_simplify import cluster_vertices

        out = []
        for g in self.links:
            v, f = cluster_vertices(g.vertices, g.faces, cell)
            out.append(LinkGeometry(g.link, v, f))
        return VisualGeometry(tuple(out), self.source)


# ----------------------------------------------------------------------------- primitives


def box_mesh(size) -> tuple[np.ndarray, np.ndarray]:
    """Box of ``size`` (x, y, z) metres centred at the origin → (8, 3) vertices, (12, 3) faces (outward, CCW)."""
    sx, sy, sz = (float(s) / 2 for s in size)
    v = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)])
    # vertex index = 4*ix + 2*iy + iz
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = []
    for a, b, c, d in quads:
        f += [(a, b, c), (a, c, d)]
    return v, np.array(f, dtype=np.int64)


def _ring(radius: float, z: float, n: int) -> np.ndarray:
    a = np.arange(n) * (2 * np.pi / n)
    return np.stack([radius * np.cos(a), radius * np.sin(a), np.full(n, z)], axis=1)


def _tube_faces(start_a: int, start_b: int, n: int) -> list[tuple[int, int, int]]:
    """Side faces between ring a (lower z) and ring b (upper z), n vertices each, outward."""
    f = []
    for i in range(n):
        j = (i + 1) % n
        f += [(start_a + i, start_a + j, start_b + j), (start_a + i, start_b + j, start_b + i)]
    return f


def cylinder_mesh(radius: float, length: float, n: int = ROUND_SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """Cylinder along z, centred, closed by two caps → (2n + 2, 3) vertices, (4n, 3) faces."""
    h = float(length) / 2
    v = np.concatenate([_ring(radius, -h, n), _ring(radius, h, n), [[0, 0, -h], [0, 0, h]]])
    f = _tube_faces(0, n, n)
    lo, hi = 2 * n, 2 * n + 1
    for i in range(n):
        j = (i + 1) % n
        f += [(lo, j, i), (hi, n + i, n + j)]
    return v, np.array(f, dtype=np.int64)


def _latitude_stack(radius: float, rings: list[tuple[float, float]], n: int) -> tuple[np.ndarray, np.ndarray]:
    """Rings given as (ring radius factor, z) from bottom to top, with poles below and above."""
    (_, z_bottom), (_, z_top) = rings[0], rings[-1]
    v = [np.array([[0.0, 0.0, z_bottom]])]
    for r, z in rings[1:-1]:
        v.append(_ring(radius * r, z, n))
    v.append(np.array([[0.0, 0.0, z_top]]))
    v = np.concatenate(v)
    f = []
    m = len(rings) - 2  # rings with n vertices
    for i in range(n):  # bottom fan
        f.append((0, 1 + (i + 1) % n, 1 + i))
    for k in range(m - 1):
        f += _tube_faces(1 + k * n, 1 + (k + 1) * n, n)
    top = len(v) - 1
    base = 1 + (m - 1) * n
    for i in range(n):
        f.append((top, base + i, base + (i + 1) % n))
    return v, np.array(f, dtype=np.int64)


def sphere_mesh(radius: float, n: int = ROUND_SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """UV sphere centred at the origin (n segments, n // 2 latitude bands)."""
    bands = max(2, n // 2)
    th = np.linspace(np.pi, 0.0, bands + 1)
    rings = [(float(np.sin(t)), float(radius * np.cos(t))) for t in th]
    return _latitude_stack(radius, rings, n)


def capsule_mesh(radius: float, length: float, n: int = ROUND_SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """Capsule along z: a cylinder of ``length`` between two hemispheres of ``radius`` (URDF/SDF convention)."""
    h = float(length) / 2
    q = max(2, n // 4)  # bands per hemisphere
    th = np.linspace(np.pi, np.pi / 2, q + 1)
    lower = [(float(np.sin(t)), -h + float(radius * np.cos(t))) for t in th]
    upper = [(float(np.sin(t)), h + float(radius * np.cos(t))) for t in np.linspace(np.pi / 2, 0.0, q + 1)]
    return _latitude_stack(radius, lower + upper, n)


# ----------------------------------------------------------------------------- meshes


def load_mesh_file(path) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) vertices (file units) and (F, 3) faces of a mesh file, all its parts merged.

    Uses ``trimesh`` (the ``mesh`` extra); COLLADA ``<unit>`` scales are applied by its loader.
    Raises :class:`InputFileError` for a file without triangles.
    """
    from .._util.optional import require

    trimesh = require("trimesh", "mesh")
    m = trimesh.load(str(path), force="mesh", process=False)
    v = np.asarray(getattr(m, "vertices", np.zeros((0, 3))), dtype=np.float64)
    f = np.asarray(getattr(m, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(f) == 0:
        raise InputFileError(path, "faces", "a mesh with at least one triangle", "none")
    return v, f


@functools.lru_cache(maxsize=64)
def _cached_mesh(path: str, mtime: float) -> tuple[np.ndarray, np.ndarray]:
    return load_mesh_file(path)


def _resolve_filename(filename: str, urdf_dir: Path | None, packages: Mapping[str, Path | str]) -> Path:
    """A URDF mesh ``filename`` → a local path (which may not exist)."""
    if filename.startswith("package://"):
        rest = filename[len("package://") :]
        pkg, _, rel = rest.partition("/")
        if pkg in packages:
            return Path(packages[pkg]) / rel
        if urdf_dir is not None:
            for d in (urdf_dir, *urdf_dir.parents):
                if d.name == pkg:
                    return d / rel
                if (d / pkg).is_dir():
                    return d / pkg / rel
        return Path(rel)
    if filename.startswith("file://"):
        return Path(unquote(urlparse(filename).path))
    p = Path(filename)
    return p if p.is_absolute() or urdf_dir is None else urdf_dir / p


def _floats(el, attr: str, n: int, default, source: str, where: str) -> np.ndarray:
    text = el.get(attr) if el is not None else None
    if text is None:
        if default is None:
            raise KinematicsFileError(source, f"{where}.{attr}", f"{n} numbers", "nothing")
        return np.array(default, dtype=float)
    try:
        vals = [float(t) for t in text.split()]
    except ValueError:
        vals = []
    if len(vals) != n or not np.all(np.isfinite(vals)):
        raise KinematicsFileError(source, f"{where}.{attr}", f"{n} finite numbers", repr(text))
    return np.array(vals, dtype=float)


def _positive(el, attr: str, source: str, where: str) -> float:
    v = float(_floats(el, attr, 1, None, source, where)[0])
    if not v > 0:
        raise KinematicsFileError(source, f"{where}.{attr}", "a positive length in metres", repr(el.get(attr)))
    return v


def _visual_triangles(
    vis, source: str, where: str, urdf_dir: Path | None, packages: Mapping[str, Path | str]
) -> tuple[np.ndarray, np.ndarray]:
    from .urdf import rpy_to_matrix

    geom = vis.find("geometry")
    shapes = [c for c in (geom if geom is not None else []) if isinstance(c.tag, str)]
    if len(shapes) != 1:
        raise KinematicsFileError(
            source,
            f"{where}.geometry",
            "one of mesh, box, cylinder, sphere, capsule",
            f"{len(shapes)} elements" if shapes or geom is not None else "no <geometry>",
        )
    shape = shapes[0]
    w = f"{where}.geometry.{shape.tag}"
    if shape.tag == "box":
        size = _floats(shape, "size", 3, None, source, w)
        if not np.all(size > 0):
            raise KinematicsFileError(source, f"{w}.size", "3 positive lengths in metres", repr(shape.get("size")))
        v, f = box_mesh(size)
    elif shape.tag == "cylinder":
        v, f = cylinder_mesh(_positive(shape, "radius", source, w), _positive(shape, "length", source, w))
    elif shape.tag == "capsule":
        v, f = capsule_mesh(_positive(shape, "radius", source, w), _positive(shape, "length", source, w))
    elif shape.tag == "sphere":
        v, f = sphere_mesh(_positive(shape, "radius", source, w))
    elif shape.tag == "mesh":
        filename = shape.get("filename")
        if not filename:
            raise KinematicsFileError(source, f"{w}.filename", "a mesh file name", "none")
        path = _resolve_filename(filename, urdf_dir, packages)
        if not path.is_file():
            raise KinematicsFileError(
                source,
                f"{w}.filename",
                "an existing mesh file (STL, DAE, OBJ)",
                f"{filename!r} → {path} (no such file)",
            )
        v, f = _cached_mesh(str(path.resolve()), os.path.getmtime(path))
        scale = _floats(shape, "scale", 3, (1.0, 1.0, 1.0), source, w)
        v = v * scale
        if np.prod(scale) < 0:  # a mirror: keep the faces wound counter-clockwise seen from outside
            f = f[:, ::-1]
    else:
        raise KinematicsFileError(
            source, f"{where}.geometry", "one of mesh, box, cylinder, sphere, capsule", f"<{shape.tag}>"
        )
    origin = vis.find("origin")
    R = rpy_to_matrix(_floats(origin, "rpy", 3, (0.0, 0.0, 0.0), source, f"{where}.origin"))
    t = _floats(origin, "xyz", 3, (0.0, 0.0, 0.0), source, f"{where}.origin")
    return v @ R.T + t, f


def read_urdf_visuals(
    urdf, packages: Mapping[str, Path | str] | None = None, *, source: str | None = None, base_dir=None
) -> VisualGeometry:
    """Every link's ``<visual>`` triangles from a URDF file path or a URDF string.

    urdf: a path, or the XML text (then ``source`` names it in messages and
    ``base_dir`` is where relative and ``package://`` names are looked up).
    packages: package name → folder, for ``package://`` names.
    Links without ``<visual>`` are left out; raises :class:`KinematicsFileError`
    naming the link and field for a malformed element or a missing mesh file.
    """
    from lxml import etree

    packages = dict(packages or {})
    if isinstance(urdf, (str, os.PathLike)) and not str(urdf).lstrip().startswith("<"):
        path = Path(urdf)
        source = source or str(path)
        if not path.is_file():
            raise KinematicsFileError(source, "file", "an existing URDF file", "no such file")
        root = etree.parse(str(path), etree.XMLParser(remove_comments=True)).getroot()
        urdf_dir = path.resolve().parent
    else:
        text = urdf if isinstance(urdf, str) else str(urdf)
        root = etree.fromstring(text.encode(), etree.XMLParser(remove_comments=True))
        source = source or "<urdf string>"
        urdf_dir = Path(base_dir).resolve() if base_dir is not None else None
    links = []
    for link in root.findall("link"):
        name = link.get("name")
        parts = [
            _visual_triangles(vis, source, f"link[{name}].visual[{i}]", urdf_dir, packages)
            for i, vis in enumerate(link.findall("visual"))
        ]
        if not parts:
            continue
        offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
        links.append(
            LinkGeometry(
                name,
                np.concatenate([v for v, _ in parts]),
                np.concatenate([f + o for (_, f), o in zip(parts, offsets)]),
            )
        )
    return VisualGeometry(tuple(links), source)
