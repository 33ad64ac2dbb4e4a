"""A mesh fit for tracing as glass: cleaned, wound outwards, and refused where it encloses no
volume, is open or not orientable, or crosses itself (:func:`self_crossings`).

Convention: a mesh is a :class:`trimesh.Trimesh` (vertices ``(V, 3)`` float64, faces ``(F, 3)``
vertex indices) in any frame; faces wind counter-clockwise seen from outside (normals point out);
sizes are relative to the mesh's bounding box. Refusals raise ``ValueError`` naming the mesh and
the ``object.*`` setting or repair that fixes it.
"""

from __future__ import annotations

import itertools
import logging
from typing import NamedTuple

import numpy as np
import trimesh

log = logging.getLogger(__name__)

__all__ = ["MIN_RELATIVE_THICKNESS", "Crossings", "self_crossings"]

#: A mesh thinner than this fraction of its bounding-box diagonal (its mean thickness, twice its
#: volume over its area; or the spread of its vertices across their best-fitting plane) encloses no
#: usable volume: the tracer restarts rays 1e-5 of the diagonal off each surface
#: (:class:`~snell_bench.optics.tracer.SceneTracer`), so rays skip glass thinner than that; this
#: keeps a factor of ten of margin.
MIN_RELATIVE_THICKNESS = 1e-4

#: Self-crossings closer than this fraction of the mesh's largest side to an edge's ends are not
#: counted (surfaces that only touch at a vertex; the float32 rounding of the ray caster).
_CROSSING_TOL = 1e-6

#: Vertices closer than this fraction of the mesh's bounding-box diagonal are one vertex (a triangle
#: soup: every face with its own copies of its corners, maybe jittered by float rounding), and faces
#: thinner than it are degenerate. Relative, so a mesh cleans the same in any unit; 1e-8 is
#: trimesh's own merge tolerance (``trimesh.tol.merge``, absolute) at unit size, so a unit-size mesh
#: merges as before; far above float64 rounding (1e-16 of a coordinate), and a thousandth of the 1e-5 of
#: the diagonal the tracer restarts rays off a surface, so no surface it can resolve moves.
_MERGE_TOL = 1e-8


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
    edges = _unique_edges(f, len(points))
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
    hit = np.flatnonzero((t < t_max) & (length > 2.0 * _CROSSING_TOL))
    face = r["primitive_ids"].numpy().astype(np.int64)[hit]
    near = _neighbours(f, edges, hit, face)
    found = [(hit[~near], face[~near], t[hit[~near]])]
    again = hit[near]  # the first hit grazes a neighbour (nearly coplanar): every hit along the edge
    if len(again):
        found.append(_first_far_hits(scene, rays, again, t_max, f, edges, nthreads))
    idx, hit_face, th = (np.concatenate(x) for x in zip(*found))
    order = np.argsort(idx, kind="stable")
    idx, hit_face, th = idx[order], hit_face[order], th[order]
    ends = edges[idx]
    where = points[ends[:, 0]] + (s[idx] + th)[:, None] * (points[ends[:, 1]] - points[ends[:, 0]])
    return Crossings(first[ends], np.asarray(hit_face, np.int64), where)


def _unique_edges(f: np.ndarray, n: int) -> np.ndarray:
    """The edges of faces ``f`` ``(F, 3)`` (indices into ``n`` points), each once: ``(E, 2)`` int64,
    the smaller index first, sorted."""
    key = np.unique(np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1) @ np.array([n, 1], np.int64))
    return np.stack([key // n, key % n], axis=1)


def _neighbours(f: np.ndarray, edges: np.ndarray, edge: np.ndarray, face: np.ndarray) -> np.ndarray:
    """Whether each face ``f[face]`` shares a vertex with the edge ``edges[edge]`` (pairwise), ``(K,)`` bool."""
    return (f[face] == edges[edge, :1]).any(axis=1) | (f[face] == edges[edge, 1:]).any(axis=1)


def _first_far_hits(
    scene, rays: np.ndarray, again: np.ndarray, t_max: np.ndarray, f: np.ndarray, edges: np.ndarray, nthreads: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(edge, face, t)`` of the first face along each edge ``again`` (whose first hit grazed a
    neighbour) that is no neighbour, before ``t_max``: every hit along ``rays[again]`` listed by the
    Open3D ``scene``, sorted by edge then ``t`` (edges without one are left out)."""
    import open3d as o3d

    lx = scene.list_intersections(o3d.core.Tensor.from_numpy(rays[again]), nthreads=int(nthreads))
    ray = again[lx["ray_ids"].numpy().astype(np.int64)]
    th = lx["t_hit"].numpy().astype(np.float64)
    fh = lx["primitive_ids"].numpy().astype(np.int64)
    ok = (th < t_max[ray]) & ~_neighbours(f, edges, ray, fh)
    order = np.lexsort((th[ok], ray[ok]))
    ray, th, fh = ray[ok][order], th[ok][order], fh[ok][order]
    first_hit = np.r_[True, ray[1:] != ray[:-1]] if len(ray) else np.zeros(0, bool)
    return ray[first_hit], fh[first_hit], th[first_hit]


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


def _row_ids(rows: np.ndarray) -> np.ndarray:
    """The same id for equal rows of an ``(N, K)`` integer array, ``(N,)`` int64 from 0 in the rows'
    sorted order (``np.unique(rows, axis=0, return_inverse=True)``, several times faster)."""
    order = np.lexsort(rows.T[::-1])
    ordered = rows[order]
    ids = np.empty(len(rows), np.int64)
    ids[order] = np.cumsum(np.r_[False, (ordered[1:] != ordered[:-1]).any(axis=1)])
    return ids


def _weld_groups(vertices: np.ndarray, tol: float) -> np.ndarray:
    """A group per vertex, ``(V,)`` int64: vertices within ``tol`` of each other (and chains of
    them) share one; vertices ``2 sqrt(3) tol`` or more apart only through such chains.

    Eight grids of cells ``2 tol`` wide, each shifted by 0 or ``tol`` along each axis, and a
    vertex joined to its cell in each: two coordinates less than ``tol`` apart share a cell in the
    grid unshifted or shifted along that axis, so two vertices less than ``tol`` apart share a cell
    in one of the eight (rounding to one grid, as trimesh's ``merge_vertices`` does, splits those
    on either side of a cell's edge). ``O(V log V)`` however many vertices crowd one point.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(vertices)
    scaled = (vertices - vertices.min(axis=0)) / (2.0 * tol)
    cells, nodes = [], n
    for shift in itertools.product((0.0, 0.5), repeat=3):
        at = _row_ids(np.floor(scaled + shift).astype(np.int64))
        cells.append(nodes + at)
        nodes += int(at.max()) + 1
    joins = coo_matrix((np.ones(8 * n, bool), (np.tile(np.arange(n), 8), np.concatenate(cells))), shape=(nodes, nodes))
    return connected_components(joins, directed=False)[1][:n].astype(np.int64)


def _merge_close_vertices(mesh: trimesh.Trimesh, tol: float) -> int:
    """Merge the vertices of ``mesh`` within ``tol`` of each other (:func:`_weld_groups`, in
    place), keeping the first of each group where it is; the number merged away."""
    group = _weld_groups(np.asarray(mesh.vertices, np.float64), tol)
    first = np.sort(np.unique(group, return_index=True)[1])  # one vertex per group, in file order
    if len(first) == len(group):
        return 0
    new_index = np.empty(int(group.max()) + 1, np.int64)
    new_index[group[first]] = np.arange(len(first))
    mesh.update_vertices(mask=first, inverse=new_index[group])
    return len(group) - len(first)


def _drop_duplicate_faces(mesh: trimesh.Trimesh, what: str) -> int:
    """Keep the first of faces with the same three vertices, either winding (in place); the number
    dropped.

    Raises:
        ValueError: every face has a copy wound the other way (a surface and its reverse, with no
            volume between them).
    """
    f = np.asarray(mesh.faces, np.int64)
    group = _row_ids(np.sort(f, axis=1))
    if group.max() + 1 == len(f):
        return 0
    rolled = np.take_along_axis(f, (np.argmin(f, axis=1)[:, None] + np.arange(3)) % 3, axis=1)
    ccw = rolled[:, 1] < rolled[:, 2]  # the winding, seen from the smallest vertex
    windings = np.zeros((group.max() + 1, 2), bool)
    windings[group, ccw.astype(np.int64)] = True
    if windings.all():
        raise ValueError(
            f"{what}: the mesh encloses almost no volume (each of its {len(windings):,} faces also appears wound the "
            f"other way: its surfaces lie on top of each other); {_SOLID_FIX}"
        )
    mesh.update_faces(np.sort(np.unique(group, return_index=True)[1]))  # the first of each, in order
    return len(f) - len(mesh.faces)


def _weld(mesh: trimesh.Trimesh, what: str) -> str:
    """Lossless clean-ups of ``mesh`` (in place), whatever ``repair``: merge vertices within
    :data:`_MERGE_TOL` of its diagonal, drop degenerate faces (thinner than that) and duplicate
    ones, and unreferenced vertices; logs what was done and returns it (``""``: nothing)."""
    diagonal = float(np.linalg.norm(np.ptp(np.asarray(mesh.vertices), axis=0)))
    tol = _MERGE_TOL * diagonal
    merged = _merge_close_vertices(mesh, tol) if tol > 0 else 0
    keep = mesh.nondegenerate_faces(height=tol) if tol > 0 else np.zeros(len(mesh.faces), bool)
    degenerate = int((~keep).sum())
    mesh.update_faces(keep)
    duplicate = _drop_duplicate_faces(mesh, what) if len(mesh.faces) else 0
    mesh.remove_unreferenced_vertices()
    done = [f"merged {merged:,} duplicate vertices"] if merged else []
    if degenerate or duplicate:
        done.append(f"dropped {degenerate:,} degenerate and {duplicate:,} duplicate faces")
    summary = ", ".join(done)
    if summary:
        log.info("%s: %s", what, summary)
    return summary


def _refuse_open(mesh: trimesh.Trimesh, what: str, *, repair: bool, cleaned: str) -> None:
    """Raise the ``ValueError`` for a mesh that is not watertight: its boundary and non-manifold
    edges, what was ``cleaned`` already, and what to do."""
    uses = np.unique(np.asarray(mesh.edges_sorted), axis=0, return_counts=True)[1]
    boundary, non_manifold = int((uses == 1).sum()), int((uses > 2).sum())
    edges = ", and ".join(
        [f"{boundary:,} boundary edges, of one face only"] * bool(boundary)
        + [f"{non_manifold:,} non-manifold edges, of three faces or more"] * bool(non_manifold)
    )
    if repair:
        hint = "object.repair=true (repair=True) could not close it: repair the mesh in a mesh editor"
    elif boundary:
        hint = "set object.repair=true (repair=True in Python) to fill simple holes"
    else:
        hint = (
            "object.repair=true cannot join surfaces that meet three or more at an edge: repair the mesh in a mesh "
            "editor"
        )
    raise ValueError(
        f"{what}: the mesh is not watertight ({edges}{'; already cleaned: ' + cleaned if cleaned else ''}), so "
        f"refraction through it is undefined; {hint}, or set object.allow_open=true (allow_open=True) to trace it "
        "anyway (rays may leak through the holes)"
    )


def _clean_mesh(
    mesh: trimesh.Trimesh,
    *,
    allow_open: bool,
    repair: bool,
    what: str,
    allow_self_intersecting: bool = False,
) -> trimesh.Trimesh:
    """A copy of ``mesh`` fit for tracing: vertices merged, degenerate and duplicate faces removed
    (:func:`_weld`), holes filled (``repair``), faces wound outwards; see
    :meth:`GlassObject.from_file` for what is refused.

    Raises:
        ValueError: the mesh is refused (``what`` names it in the message).
    """
    if len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise ValueError(f"{what}: the mesh is empty (0 faces); a glass object needs a closed surface")
    if not np.all(np.isfinite(mesh.vertices)):
        raise ValueError(f"{what}: the mesh has non-finite vertex coordinates")
    mesh = mesh.copy()
    cleaned = _weld(mesh, what)
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
            _refuse_open(mesh, what, repair=repair, cleaned=cleaned)
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
