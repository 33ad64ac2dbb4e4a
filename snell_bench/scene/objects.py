"""Glass objects: procedural primitives and mesh files (materials: :mod:`snell_bench.config.materials`).

Convention:
    - A *canonical* object (``sphere``, ``cylinder``, ``pyramid``, ``from_file``) lives in its own
      local frame: y up, its bottom centre at the origin, its largest bounding-box side 1 (unit size).
      :func:`snell_bench.scene.placement.place_object` moves it into the camera frame.
    - A *placed* object is in camera coordinates (OpenCV frame, metres or the depth map's unit);
      :meth:`GlassObject.from_mesh` takes a mesh that is already there.
    - Faces wind counter-clockwise seen from outside, so face normals point out of the object.
    - A mesh (:meth:`GlassObject.from_file`, :meth:`GlassObject.from_mesh`) must enclose a volume
      (not flat, not sheets on top of each other), be closed (else ``allow_open``), orientable,
      and not cross itself (else ``allow_self_intersecting``); a file must hold the format its
      suffix names (:func:`sniff_mesh_format`).
    - Shading normals are per face corner (``corner_normals``): vertex normals averaged only over the
      faces whose normal is within ``crease_angle_deg`` of the corner's face, so smooth parts
      interpolate while sharp edges (a cylinder's rim, a pyramid's edges) keep their face normals.
"""

from __future__ import annotations

import hashlib
import logging
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import trimesh

from snell_bench.config.materials import MATERIALS, resolve_ior

log = logging.getLogger(__name__)

__all__ = ["MATERIALS", "Crossings", "GlassObject", "resolve_ior", "self_crossings", "sniff_mesh_format"]

#: Mesh file suffixes trimesh reads that the bundled objects use.
MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")

#: The suffix trimesh reads each format of :func:`sniff_mesh_format` by.
FORMAT_SUFFIXES = {"PLY": ".ply", "OBJ": ".obj", "STL": ".stl", "GLB": ".glb", "glTF": ".gltf", "OFF": ".off"}

#: The first word of an OBJ file's statements (a line of text starting with anything else is not OBJ).
_OBJ_STATEMENTS = frozenset(
    b"v vn vt vp f l p o g s mtllib usemtl cstype deg bmat step curv curv2 surf parm trim hole scrv sp end "
    b"con mg lod bevel c_interp d_interp ctech stech shadow_obj trace_obj".split()
)

#: A mesh thinner than this fraction of its bounding-box diagonal (its mean thickness, twice its
#: volume over its area; or the spread of its vertices across their best-fitting plane) encloses no
#: usable volume: the tracer restarts rays 1e-5 of the diagonal off each surface
#: (:class:`~snell_bench.optics.tracer.SceneTracer`), so rays skip glass thinner than that; this
#: keeps a factor of ten of margin.
MIN_RELATIVE_THICKNESS = 1e-4

#: Self-crossings closer than this fraction of the mesh's largest side to an edge's ends are not
#: counted (surfaces that only touch at a vertex; the float32 rounding of the ray caster).
_CROSSING_TOL = 1e-6


def sniff_mesh_format(path: str | Path) -> str | None:
    """The format a mesh file's first bytes show, whatever its name says.

    Args:
        path: a file.

    Returns:
        ``"PLY"``, ``"OBJ"``, ``"STL"`` (binary or ASCII), ``"GLB"`` (binary glTF), ``"glTF"`` (JSON),
        ``"OFF"`` (keys of :data:`FORMAT_SUFFIXES`), or ``None``: empty, or none of these.

    Examples:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     p = Path(tmp) / "cube.obj"
        ...     _ = p.write_bytes(b"ply\\nformat ascii 1.0\\n")
        ...     sniff_mesh_format(p)
        'PLY'
    """
    path = Path(path)
    size = path.stat().st_size
    with path.open("rb") as f:
        head = f.read(65536)
    if not head:
        return None
    if head.startswith(b"ply") and head[3:4] in (b"\n", b"\r"):
        return "PLY"
    if head.startswith(b"glTF"):
        return "GLB"
    if size >= 84 and size == 84 + 50 * int.from_bytes(head[80:84], "little"):
        return "STL"  # a binary STL's header is free text (it may start with "solid")
    text = head.removeprefix(b"\xef\xbb\xbf").lstrip()
    if text.startswith(b"solid") and b"facet" in text:
        return "STL"
    if text.startswith(b"{"):
        return "glTF" if b'"asset"' in head or b'"meshes"' in head else None
    first = text.split(None, 1)[0] if text else b""
    if first.endswith(b"OFF") and first.isalnum():  # OFF, COFF, NOFF, STOFF, 4OFF, ...
        return "OFF"
    if b"\x00" in head:
        return None
    for line in text.splitlines():
        words = line.split()
        if words and not words[0].startswith(b"#"):
            return "OBJ" if words[0] in _OBJ_STATEMENTS else None
    return None


def _check_format(path: Path) -> None:
    """Refuse an empty file, and a file whose first bytes show another format than its suffix
    (trimesh would read it by its suffix and call it damaged)."""
    if path.stat().st_size == 0:
        raise ValueError(f"{path} is empty (0 bytes): re-export the mesh or choose another file")
    fmt = sniff_mesh_format(path)
    if fmt is None:
        return
    suffix = FORMAT_SUFFIXES[fmt]
    if path.suffix.lower() != suffix:
        named = f"its name ends in {path.suffix}" if path.suffix else "its name has no suffix"
        raise ValueError(
            f"{path} holds a {fmt} file but {named} (a mesh file is read by its suffix): rename it to "
            f"{path.with_suffix(suffix).name}"
        )


class Crossings(NamedTuple):
    """Where a triangle mesh crosses itself (:func:`self_crossings`), one row per crossing edge.

    Attributes:
        edges: ``(K, 2)`` int64 vertex indices of the edges that pass through a face.
        faces: ``(K,)`` int64 the face each of them passes through (the first along the edge).
        points: ``(K, 3)`` float64 where (in the coordinates of the vertices).
    """

    edges: np.ndarray
    faces: np.ndarray
    points: np.ndarray


def self_crossings(vertices: np.ndarray, faces: np.ndarray, *, nthreads: int = 0) -> Crossings:
    """The edges of a triangle mesh that pass through one of its faces (the surface crosses itself).

    Faces that share a vertex or an edge with the edge never count (neighbours meet there; vertices
    at the same point count as one, so a seam of split vertices is no crossing). Two triangles that
    cross have an edge of one passing through the other, so the surface crosses itself exactly
    where some edge passes through a face: each edge, as a ray segment, is cast against every face
    through Open3D's BVH (Embree), ``O(E log F)`` (about 0.15 s for 70,000 faces, where Open3D's
    ``TriangleMesh.is_self_intersecting``, comparing all pairs of faces, takes 20 s). The first face
    along each edge is reported.

    Convention: coordinates are normalised to the largest bounding-box side and cast in float32;
    crossings within ``1e-6`` of that side from an edge's end vertices, surfaces that only touch
    and faces overlapping within one plane are not found.

    Args:
        vertices: ``(V, 3)`` coordinates.
        faces: ``(F, 3)`` vertex indices.
        nthreads: Open3D threads (0: all cores).

    Returns:
        The :class:`Crossings` (empty arrays: the surface does not cross itself).

    Examples:
        Two closed boxes that overlap cross each other; each alone does not:

        >>> a = trimesh.creation.box()
        >>> b = trimesh.creation.box(transform=trimesh.transformations.translation_matrix([0.5, 0.3, 0.2]))
        >>> len(self_crossings(a.vertices, a.faces).edges)
        0
        >>> both = trimesh.util.concatenate([a, b])
        >>> len(self_crossings(both.vertices, both.faces).edges) > 0
        True
    """
    import open3d as o3d

    v = np.asarray(vertices, np.float64)
    empty = Crossings(np.zeros((0, 2), np.int64), np.zeros(0, np.int64), np.zeros((0, 3)))
    if len(faces) < 2:
        return empty
    # one index per point: vertices split at seams are neighbours of each other's faces
    points, first, at = np.unique(v, axis=0, return_index=True, return_inverse=True)
    f = at.reshape(-1)[np.asarray(faces, np.int64)]
    lo, hi = points.min(axis=0), points.max(axis=0)
    side = float((hi - lo).max())
    if not side > 0:
        return empty
    vs = ((points - (lo + hi) / 2.0) / side).astype(np.float32)  # in [-0.5, 0.5]^3
    n = len(points)
    key = np.unique(np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1) @ np.array([n, 1], np.int64))
    edges = np.stack([key // n, key % n], axis=1)
    a = vs[edges[:, 0]].astype(np.float64)
    e = vs[edges[:, 1]].astype(np.float64) - a
    length = np.linalg.norm(e, axis=1)
    s = _CROSSING_TOL / np.maximum(length, 1e-30)  # the tolerance in units of the edge
    t_max = 1.0 - 2.0 * s
    rays = np.concatenate([a + s[:, None] * e, e], axis=1).astype(np.float32)
    scene = o3d.t.geometry.RaycastingScene(nthreads=int(nthreads))
    scene.add_triangles(o3d.core.Tensor.from_numpy(vs), o3d.core.Tensor.from_numpy(f.astype(np.uint32)))
    r = scene.cast_rays(o3d.core.Tensor.from_numpy(rays), nthreads=int(nthreads))
    t = r["t_hit"].numpy().astype(np.float64)

    def neighbour(edge: np.ndarray, face: np.ndarray) -> np.ndarray:
        return (f[face] == edges[edge, :1]).any(axis=1) | (f[face] == edges[edge, 1:]).any(axis=1)

    hit = np.flatnonzero((t < t_max) & (length > 2.0 * _CROSSING_TOL))
    face = r["primitive_ids"].numpy().astype(np.int64)[hit]
    near = neighbour(hit, face)
    found = [(hit[~near], face[~near], t[hit[~near]])]
    again = hit[near]  # the first hit grazes a neighbour (nearly coplanar): every hit along the edge
    if len(again):
        lx = scene.list_intersections(o3d.core.Tensor.from_numpy(rays[again]), nthreads=int(nthreads))
        ray = again[lx["ray_ids"].numpy().astype(np.int64)]
        th = lx["t_hit"].numpy().astype(np.float64)
        fh = lx["primitive_ids"].numpy().astype(np.int64)
        ok = (th < t_max[ray]) & ~neighbour(ray, fh)
        order = np.lexsort((th[ok], ray[ok]))
        ray, th, fh = ray[ok][order], th[ok][order], fh[ok][order]
        first_hit = np.r_[True, ray[1:] != ray[:-1]] if len(ray) else np.zeros(0, bool)
        found.append((ray[first_hit], fh[first_hit], th[first_hit]))
    idx, hit_face, th = (np.concatenate(x) for x in zip(*found))
    order = np.argsort(idx, kind="stable")
    idx, hit_face, th = idx[order], hit_face[order], th[order]
    ends = edges[idx]
    where = points[ends[:, 0]] + (s[idx] + th)[:, None] * (points[ends[:, 1]] - points[ends[:, 0]])
    return Crossings(first[ends], np.asarray(hit_face, np.int64), where)


def _signed_volume(mesh: trimesh.Trimesh) -> float:
    """The volume the faces enclose, signed by their winding (positive: wound outwards), summed
    over the tetrahedra from the vertices' centroid (for a closed mesh, its volume wherever the
    apex; for an open one, about its centroid)."""
    tri = np.asarray(mesh.triangles, np.float64) - np.asarray(mesh.vertices, np.float64).mean(axis=0)
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6.0


_SOLID_FIX = (
    "a glass object must enclose a volume: export the object as a closed solid (a surface with a thickness, e.g. "
    "Blender's Solidify modifier), not a sheet"
)


def _check_not_flat(mesh: trimesh.Trimesh, what: str) -> None:
    """Refuse a mesh whose vertices lie within :data:`MIN_RELATIVE_THICKNESS` of its bounding-box
    diagonal of their best-fitting plane: it encloses no volume, whatever its faces."""
    v = np.asarray(mesh.vertices, np.float64)
    diagonal = float(np.linalg.norm(np.ptp(v, axis=0)))
    if not diagonal > 0:
        raise ValueError(f"{what}: every vertex is at the same point, so the mesh encloses no volume; {_SOLID_FIX}")
    centred = v - v.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]  # of the best-fitting plane
    spread = float(np.ptp(centred @ normal))
    if spread <= MIN_RELATIVE_THICKNESS * diagonal:
        within = "in one plane" if spread == 0 else f"within {spread:.3g} of one plane, {diagonal:.3g} across"
        raise ValueError(
            f"{what}: the mesh is flat (its vertices lie {within}), so it encloses no volume; {_SOLID_FIX}"
        )


def _check_thickness(mesh: trimesh.Trimesh, what: str) -> None:
    """Refuse a consistently wound mesh whose mean thickness ``2 |V| / A`` (``V`` its signed volume,
    ``A`` its area) is below :data:`MIN_RELATIVE_THICKNESS` of its bounding-box diagonal: sheets
    lying on top of each other (a surface and its copy wound the other way, a closed box of height
    0) enclose no volume."""
    diagonal = float(np.linalg.norm(np.ptp(np.asarray(mesh.vertices), axis=0)))
    volume, area = _signed_volume(mesh), float(mesh.area)
    if 2.0 * abs(volume) <= MIN_RELATIVE_THICKNESS * diagonal * area:
        raise ValueError(
            f"{what}: the mesh encloses almost no volume ({volume:.3g} for a surface area of {area:.3g}, "
            f"{diagonal:.3g} across: its surfaces lie on top of each other); {_SOLID_FIX}"
        )


def _wind_consistently(mesh: trimesh.Trimesh, what: str) -> None:
    """Wind neighbouring faces the same way (trimesh's ``fix_winding``, in place).

    Raises:
        ValueError: a closed surface cannot be wound consistently (it is not orientable).
    """
    trimesh.repair.fix_winding(mesh)
    if mesh.is_watertight and not mesh.is_winding_consistent:
        raise ValueError(
            f"{what}: the closed surface cannot be wound consistently (it is not orientable: it has one side, like a "
            "Klein bottle), so it has no inside; repair the mesh in a mesh tool"
        )


def _clean_mesh(
    mesh: trimesh.Trimesh,
    *,
    allow_open: bool,
    repair: bool,
    what: str,
    allow_self_intersecting: bool = False,
) -> trimesh.Trimesh:
    """A copy of ``mesh`` fit for tracing: vertices merged, degenerate faces removed, holes filled
    (``repair``), faces wound outwards; see :meth:`GlassObject.from_file` for what is refused.

    Raises:
        ValueError: the mesh is refused (``what`` names it in the message).
    """
    if len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise ValueError(f"{what}: the mesh is empty (0 faces); a glass object needs a closed surface")
    if not np.all(np.isfinite(mesh.vertices)):
        raise ValueError(f"{what}: the mesh has non-finite vertex coordinates")
    mesh = mesh.copy()
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    keep = mesh.nondegenerate_faces()
    n_degenerate = int((~keep).sum())
    if n_degenerate:
        log.info("%s: removed %d degenerate faces", what, n_degenerate)
        mesh.update_faces(keep)
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise ValueError(f"{what}: every face is degenerate (zero area), so the mesh encloses no volume; {_SOLID_FIX}")
    _check_not_flat(mesh, what)
    _wind_consistently(mesh, what)
    _check_thickness(mesh, what)
    if not mesh.is_watertight and repair:
        trimesh.repair.fill_holes(mesh)
        log.info("%s: filled holes, watertight now: %s", what, mesh.is_watertight)
        _wind_consistently(mesh, what)
        _check_thickness(mesh, what)
    if not mesh.is_watertight:
        if not allow_open:
            hint = (
                "object.repair=true (repair=True) could not close it: repair the mesh in a mesh editor"
                if repair
                else "set object.repair=true (repair=True in Python) to fill simple holes"
            )
            raise ValueError(
                f"{what}: the mesh is not watertight (it has boundary edges), so refraction through it is "
                f"undefined; {hint}, or set object.allow_open=true (allow_open=True) to trace it anyway (rays may "
                "leak through the holes)"
            )
        log.warning("%s: tracing a mesh that is not watertight (allow_open=True)", what)
    if _signed_volume(mesh) < 0:  # wound inside-out: the normals point in
        mesh.invert()
        log.info("%s: the faces were wound inside-out (negative volume); turned them outwards", what)
    if not allow_self_intersecting:
        crossing = self_crossings(mesh.vertices, mesh.faces)
        if len(crossing.edges):
            x, y, z = crossing.points[0]
            raise ValueError(
                f"{what}: the surface crosses itself ({len(crossing.edges)} edges pass through other faces, e.g. at "
                f"({x:.4g}, {y:.4g}, {z:.4g}) in its coordinates), so its inside is ill defined and rays would refract "
                "at surfaces inside the glass; repair the mesh in a mesh tool (e.g. a boolean union of the overlapping "
                "parts, or a remesh), or set object.allow_self_intersecting=true (allow_self_intersecting=True in "
                "Python) to trace it anyway"
            )
    return mesh


def _canonicalize(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Bottom centre to the origin and the largest bounding-box side to 1 (y is up)."""
    lo, hi = mesh.bounds
    extent = float((hi - lo).max())
    if extent <= 0:
        raise ValueError("the mesh has zero extent")
    T = np.eye(4)
    T[:3, 3] = -np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    S = np.diag([1 / extent] * 3 + [1.0])
    mesh = mesh.copy()
    mesh.apply_transform(S @ T)
    return mesh


_Z_TO_Y_UP = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=float)


@dataclass(frozen=True, eq=False)
class GlassObject:
    """A closed triangle mesh of a transparent material.

    Attributes:
        mesh: the surface (see the module's conventions for its frame).
        ior: index of refraction of the material (the surroundings are air, IOR 1).
        name: a short label (``sphere``, a file stem, ...).
        placed: whether ``mesh`` is in camera coordinates.
        up: the scene's up direction in camera coordinates, set by placement (``None`` if unknown).
        crease_angle_deg: faces meeting at a sharper angle than this do not share shading normals.
        pose: ``(4, 4)`` float64, the transform that took the canonical object (as its constructor
            built it) to ``mesh`` (:meth:`transformed` composes it; camera from object once placed),
            or None for a mesh given already placed.
    """

    mesh: trimesh.Trimesh
    ior: float = 1.5
    name: str = "object"
    placed: bool = False
    up: np.ndarray | None = None
    crease_angle_deg: float = 30.0
    pose: np.ndarray | None = field(default=None, repr=False, compare=False)
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "ior", resolve_ior(self.ior))
        if self.up is not None:
            up = np.asarray(self.up, np.float64).reshape(3)
            object.__setattr__(self, "up", up / np.linalg.norm(up))
        if not (0.0 <= self.crease_angle_deg <= 180.0):
            raise ValueError(f"crease_angle_deg must be in [0, 180], got {self.crease_angle_deg}")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def sphere(cls, ior: str | float = "glass", subdivisions: int = 5) -> GlassObject:
        """Unit-diameter icosphere (``subdivisions=5``: 20,480 faces)."""
        m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.5)
        return cls(mesh=_canonicalize(m), ior=ior, name="sphere")

    @classmethod
    def cylinder(cls, ior: str | float = "glass", radius: float = 0.35, sections: int = 128) -> GlassObject:
        """Upright cylinder of height 1 before normalisation (``radius`` relative to the height)."""
        m = trimesh.creation.cylinder(radius=radius, height=1.0, sections=sections)
        m.apply_transform(_Z_TO_Y_UP)
        return cls(mesh=_canonicalize(m), ior=ior, name="cylinder")

    @classmethod
    def pyramid(cls, ior: str | float = "glass", base: float = 1.0, height: float = 1.0) -> GlassObject:
        """Square pyramid (a 4-sided cone, the edges of its base along the diagonals)."""
        m = trimesh.creation.cone(radius=base / math.sqrt(2.0), height=height, sections=4)
        m.apply_transform(_Z_TO_Y_UP)
        return cls(mesh=_canonicalize(m), ior=ior, name="pyramid")

    @classmethod
    def from_file(
        cls,
        path: str | Path,
        ior: str | float = "glass",
        *,
        up_axis: str = "y",
        allow_open: bool = False,
        repair: bool = False,
        allow_self_intersecting: bool = False,
    ) -> GlassObject:
        """Any mesh trimesh reads (.ply, .obj, .glb, .stl, ...), normalised to the canonical frame.

        Vertices at the same point are merged and zero-area faces removed; the faces are wound
        outwards (a mesh wound inside-out is turned over). Refused, each with what to do: a file whose
        first bytes show another format than its suffix (:func:`sniff_mesh_format`), an empty or
        unreadable file, a mesh that encloses no volume (flat, or thinner than
        :data:`MIN_RELATIVE_THICKNESS` of its size), an open one (unless ``allow_open``), a closed
        surface that cannot be oriented, and one that crosses itself (:func:`self_crossings`, unless
        ``allow_self_intersecting``).

        Args:
            path: the mesh file.
            ior: a material name or the index of refraction.
            up_axis: the file's up axis (``y``, ``z``, ``-y``, ...).
            allow_open: trace a mesh that is not watertight (rays may leak through its holes).
            repair: fill simple holes (trimesh's ``fill_holes``) first.
            allow_self_intersecting: trace a mesh whose surface crosses itself (rays then refract at
                its surfaces inside the glass).

        Returns:
            The canonical object, named after the file's stem.

        Raises:
            IsADirectoryError: ``path`` is a folder.
            FileNotFoundError: there is no such file.
            ValueError: the file or its mesh is refused (see above).
        """
        path = Path(path)
        if path.is_dir():
            meshes = sorted(p.name for p in path.iterdir() if p.suffix.lower() in MESH_SUFFIXES)[:5]
            raise IsADirectoryError(
                f"{path} is a folder, not a mesh file; give a file"
                + (f" (it holds {', '.join(meshes)})" if meshes else f" ({', '.join(MESH_SUFFIXES)})")
            )
        if not path.is_file():
            raise FileNotFoundError(f"mesh file not found: {path}")
        _check_format(path)
        try:
            loaded = trimesh.load(path, force="mesh", process=False)
        except Exception as e:  # trimesh raises many kinds
            first = str(e).strip().splitlines()[0][:160] if str(e).strip() else type(e).__name__
            raise ValueError(
                f"{path} could not be read as a mesh ({type(e).__name__}: {first}); the file is damaged or not a "
                f"{path.suffix or 'mesh'} file: re-export it from a mesh editor or choose another file"
            ) from e
        if not isinstance(loaded, trimesh.Trimesh) or len(getattr(loaded, "faces", [])) == 0:
            raise ValueError(
                f"{path} holds no triangle mesh (0 faces read); the file is empty, damaged or holds only points or "
                "lines: re-export it with faces"
            )
        mesh = _clean_mesh(
            loaded,
            allow_open=allow_open,
            repair=repair,
            allow_self_intersecting=allow_self_intersecting,
            what=str(path),
        )
        mesh.apply_transform(_up_axis_transform(up_axis))
        return cls(mesh=_canonicalize(mesh), ior=ior, name=path.stem)

    @classmethod
    def from_mesh(
        cls,
        vertices: np.ndarray,
        faces: np.ndarray,
        ior: str | float = "glass",
        *,
        name: str = "mesh",
        up=None,
        allow_open: bool = False,
        repair: bool = False,
        allow_self_intersecting: bool = False,
    ) -> GlassObject:
        """A mesh already in camera coordinates (placed as given), cleaned and checked as
        :meth:`from_file` does.

        Args:
            vertices: ``(V, 3)`` coordinates.
            faces: ``(F, 3)`` vertex indices.
            ior: a material name or the index of refraction.
            name: a short label.
            up: the scene's up direction in camera coordinates, if known.
            allow_open: trace a mesh that is not watertight.
            repair: fill simple holes first.
            allow_self_intersecting: trace a mesh whose surface crosses itself.

        Returns:
            The placed object.

        Raises:
            ValueError: the arrays are malformed or the mesh is refused (see :meth:`from_file`).
        """
        vertices = np.asarray(vertices, dtype=np.float64)
        faces = np.asarray(faces)
        if vertices.ndim != 2 or vertices.shape[1:] != (3,) or faces.ndim != 2 or faces.shape[1:] != (3,):
            if vertices.size == 0 or faces.size == 0:
                raise ValueError("from_mesh: the mesh is empty (0 faces); a glass object needs a closed surface")
            raise ValueError(
                f"from_mesh: expected vertices (V, 3) and faces (F, 3), got {vertices.shape} and {faces.shape}"
            )
        if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise ValueError(f"from_mesh: face indices out of range [0, {len(vertices)})")
        mesh = trimesh.Trimesh(vertices=vertices, faces=faces.astype(np.int64), process=False)
        mesh = _clean_mesh(
            mesh,
            allow_open=allow_open,
            repair=repair,
            allow_self_intersecting=allow_self_intersecting,
            what="from_mesh",
        )
        return cls(mesh=mesh, ior=ior, name=name, placed=True, up=up)

    # ------------------------------------------------------------------ derived objects
    def with_ior(self, ior: str | float) -> GlassObject:
        return replace(self, ior=ior, _cache={})

    def transformed(self, matrix: np.ndarray, *, up=None) -> GlassObject:
        """Apply a 4x4 rigid or similarity transform; the result is a placed object."""
        m = self.mesh.copy()
        matrix = np.asarray(matrix, dtype=np.float64)
        m.apply_transform(matrix)
        before = np.eye(4) if self.pose is None and not self.placed else self.pose
        pose = None if before is None else matrix @ before
        return replace(self, mesh=m, placed=True, up=up if up is not None else self.up, pose=pose, _cache={})

    # ------------------------------------------------------------------ geometry
    @property
    def vertices(self) -> np.ndarray:
        return np.asarray(self.mesh.vertices)

    @property
    def faces(self) -> np.ndarray:
        return np.asarray(self.mesh.faces)

    @property
    def center(self) -> np.ndarray:
        """Centre of the axis-aligned bounding box (the panorama is centred here)."""
        lo, hi = self.mesh.bounds
        return (lo + hi) / 2.0

    @property
    def diameter(self) -> float:
        lo, hi = self.mesh.bounds
        return float(np.linalg.norm(hi - lo))

    def corner_normals(self) -> np.ndarray:
        """Unit shading normals per face corner, ``(F, 3, 3)`` float64 (see module docs)."""
        if "corner_normals" not in self._cache:
            self._cache["corner_normals"] = _corner_normals(self.mesh, self.crease_angle_deg)
        return self._cache["corner_normals"]

    def content_hash(self) -> str:
        h = hashlib.sha256()
        h.update(np.ascontiguousarray(self.vertices, dtype=np.float64).tobytes())
        h.update(np.ascontiguousarray(self.faces, dtype=np.int64).tobytes())
        h.update(repr((round(self.ior, 12), self.crease_angle_deg, self.placed)).encode())
        return h.hexdigest()

    def __repr__(self) -> str:
        return (
            f"GlassObject(name={self.name!r}, ior={self.ior}, faces={len(self.mesh.faces)}, placed={self.placed}, "
            f"center={np.round(self.center, 4).tolist()})"
        )


def _up_axis_transform(up_axis: str) -> np.ndarray:
    axis = up_axis.strip().lower()
    sign = -1.0 if axis.startswith("-") else 1.0
    axis = axis.lstrip("+-")
    if axis not in ("x", "y", "z"):
        raise ValueError(f"up_axis must be one of x, y, z (optionally signed), got {up_axis!r}")
    up = np.zeros(3)
    up["xyz".index(axis)] = sign
    # rotation taking `up` to +y by the shortest arc
    target = np.array([0.0, 1.0, 0.0])
    T = np.eye(4)
    if np.allclose(up, target):
        return T
    if np.allclose(up, -target):
        T[:3, :3] = np.diag([1.0, -1.0, -1.0])
        return T
    T[:3, :3] = trimesh.geometry.align_vectors(up, target)[:3, :3]
    return T


def _corner_normals(mesh: trimesh.Trimesh, crease_angle_deg: float) -> np.ndarray:
    faces = np.asarray(mesh.faces)
    fn = np.asarray(mesh.face_normals, dtype=np.float64)  # unit
    area = np.asarray(mesh.area_faces, dtype=np.float64)
    vf = np.asarray(mesh.vertex_faces)  # (V, max_valence), padded with -1
    nbr = vf[faces]  # (F, 3, k) faces around each corner's vertex
    valid = nbr >= 0
    nbr_safe = np.where(valid, nbr, 0)
    nbr_n = fn[nbr_safe]  # (F, 3, k, 3)
    cos = np.einsum("fckd,fd->fck", nbr_n, fn)
    w = np.where(valid & (cos >= math.cos(math.radians(crease_angle_deg)) - 1e-9), area[nbr_safe], 0.0)
    n = np.einsum("fck,fckd->fcd", w, nbr_n)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    fallback = np.broadcast_to(fn[:, None, :], n.shape)
    return np.where(norm > 1e-12, n / np.maximum(norm, 1e-300), fallback)
