"""Geometry of the reference render: the background built from I⁻'s depth, and the object's arrays.

Nothing here imports Mitsuba: the functions return numpy arrays that
:mod:`snell_bench.render.reference` turns into Mitsuba meshes (:func:`~snell_bench.render.pieces.mesh`).

Convention:
    - Frames and pixels: the camera frame and pixel centres of :mod:`snell_bench.scene.camera`; pixel
      ``(x, y)`` covers ``[x - 0.5, x + 0.5) x [y - 0.5, y + 0.5)``.
    - Background: the depth mesh of :func:`~snell_bench.scene.depth_mesh.build_background` (vertex
      ``y * W + x`` at the unprojected centre of pixel ``(x, y)``, the geometry our tracer uses),
      extended by half a pixel at the image border (border depth repeated): extended vertex
      ``(y + 1) * (W + 2) + x + 1``. UV = image position ``((x + 0.5) / W, (y + 0.5) / H)`` (Mitsuba's
      ``v = 0`` is the *top* row of a bitmap). For the image pass every triangle is split at the image
      midpoints of its sides (:func:`subdivide`), so that each piece lies in one pixel's footprint and
      shows exactly that texel.
    - Depth edges: where ``depth_to_mesh`` cuts a triangle (or depth is invalid), each valid pixel's
      remaining footprint is a *flap* (:func:`flaps`): a fronto-parallel piece at the pixel's own depth
      (half a pixel wide). So the camera sees I⁻ exactly wherever it sees the background directly,
      while a depth edge stays open for other rays, as in our tracer.
    - Object normals: each face corner gets its own vertex (vertices split at every corner) with the
      creased shading normal of :meth:`GlassObject.corner_normals`, so smooth parts interpolate and
      sharp edges stay sharp, as in our tracer.
    - ``object_mask``: pixel-centre rays that hit the object before the background (the background is
      hit at the pixel's own depth-mesh vertex), as in :func:`~snell_bench.optics.warps.compute_warps`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import BackgroundMesh, valid_depth_mask
from snell_bench.scene.objects import GlassObject

__all__ = [
    "BackgroundGeometry",
    "triangulate_grid",
    "grid_triangle_ids",
    "background_geometry",
    "subdivide",
    "flaps",
    "inward_box",
    "object_arrays",
    "object_rect",
    "object_mask",
]


# ============================================================================ the pixel grid
def triangulate_grid(rows: int, cols: int) -> np.ndarray:
    """The triangles of a ``rows x cols`` vertex grid, split like ``depth_to_mesh``.

    Returns:
        ``(2 (rows - 1) (cols - 1), 3)`` int64 vertex indices (row-major vertices).
    """
    idx = np.arange(rows * cols, dtype=np.int64).reshape(rows, cols)
    a, b = idx[:-1, :-1], idx[:-1, 1:]
    c, d = idx[1:, :-1], idx[1:, 1:]
    return np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])


def grid_triangle_ids(faces: np.ndarray, cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Ids of the triangles of :func:`triangulate_grid`, whatever the vertex order.

    Args:
        faces: ``(F, 3)`` vertex indices into a grid of ``cols`` columns.
        cols: the grid's number of columns.

    Returns:
        ``(ids, ok)``: ``ids = 2 * lowest vertex index + kind`` (int64) and ``ok``, False for a
        triangle that is not one of the grid's.
    """
    s = np.sort(np.asarray(faces, np.int64), axis=1)
    d1, d2 = s[:, 1] - s[:, 0], s[:, 2] - s[:, 0]
    kind_b = (d1 == cols - 1) & (d2 == cols)
    ok = ((d1 == 1) & (d2 == cols)) | kind_b
    return 2 * s[:, 0] + kind_b, ok


# ============================================================================ the background
@dataclass
class BackgroundGeometry:
    """The depth mesh on the vertex grid extended by a half-pixel ring (see the conventions).

    Attributes:
        vertices: ``(Ne, 3)`` float32, the extended vertex grid.
        pixels: ``(Ne, 2)`` float64 pixel coordinates ``(x, y)`` of the vertices.
        valid: ``(Ne,)`` bool: the vertex has a valid depth.
        observed: ``(F, 3)`` int64 faces: the depth mesh (and its border extension).
        open: ``(S, 3)`` int64 grid triangles left out (cut at depth edges or invalid depth).
    """

    vertices: np.ndarray
    pixels: np.ndarray
    valid: np.ndarray
    observed: np.ndarray
    open: np.ndarray


def background_geometry(
    bg: BackgroundMesh, depth: np.ndarray, camera: Camera, edge_threshold: float
) -> BackgroundGeometry:
    """The depth mesh on a vertex grid extended by a half-pixel ring at the image border.

    Args:
        bg: the background of ``depth`` (:func:`~snell_bench.scene.depth_mesh.build_background`).
        depth: ``(H, W)`` z-depth (NaN, inf or <= 0 where unknown).
        camera: the camera of ``depth``.
        edge_threshold: relative depth jump at which the border extension is cut.

    Returns:
        The :class:`BackgroundGeometry`.

    Raises:
        RuntimeError: ``bg`` has triangles that do not follow the pixel grid.
    """
    H, W = camera.shape
    He, We = H + 2, W + 2
    xs = np.concatenate([[-0.5], np.arange(W, dtype=np.float64), [W - 0.5]])
    ys = np.concatenate([[-0.5], np.arange(H, dtype=np.float64), [H - 0.5]])
    valid = np.pad(valid_depth_mask(depth), 1, mode="edge")
    z = np.pad(np.where(valid_depth_mask(depth), depth, 0.0).astype(np.float64), 1, mode="edge")
    X, Y = np.meshgrid(xs, ys)
    rays = camera.pixel_rays(np.stack([X, Y], -1), normalize=False)
    verts = (rays * z[..., None]).astype(np.float32)
    verts[1:-1, 1:-1] = np.asarray(bg.vertices, np.float32).reshape(H, W, 3)  # exactly the depth mesh
    verts = verts.reshape(-1, 3)

    # interior pixel (x, y) is extended vertex (y + 1) * We + x + 1
    f = np.asarray(bg.faces, np.int64)
    observed_inner = (f // W + 1) * We + (f % W + 1)
    cand = triangulate_grid(He, We)
    vf, zf = valid.reshape(-1), z.reshape(-1)
    ok = vf[cand].all(axis=1)
    any_valid = vf[cand].any(axis=1)
    row, col = cand // We, cand % We
    border = ((row == 0) | (row == He - 1) | (col == 0) | (col == We - 1)).any(axis=1)
    zt = zf[cand]
    with np.errstate(divide="ignore", invalid="ignore"):
        smooth = zt.max(axis=1) / zt.min(axis=1) <= 1.0 + edge_threshold
    kept_ids, kept_ok = grid_triangle_ids(observed_inner, We)
    if not kept_ok.all():
        raise RuntimeError("build_background returned triangles that do not follow the pixel grid")
    marked = np.zeros(2 * He * We, bool)
    marked[kept_ids] = True
    kept_inner = marked[grid_triangle_ids(cand, We)[0]]
    observed_border = border & ok & smooth
    observed = np.concatenate([observed_inner, cand[observed_border]])
    open_ = cand[any_valid & ~kept_inner & ~observed_border]
    return BackgroundGeometry(verts, np.stack([X, Y], -1).reshape(-1, 2), vf, observed, open_)


def subdivide(
    geo: BackgroundGeometry, shape: tuple[int, int], faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split background triangles at the midpoints of their sides, taken in the image, so that
    every piece lies inside one pixel's footprint and textures it with exactly that pixel's texel.

    The grid's pixel edges run through those midpoints. A side's midpoint in the image is the 3-D
    point where ``1/z`` is halfway between its ends; the pieces lie in the plane of their triangle
    (the geometry is unchanged). UVs are the pieces' image positions: interpolated within a piece,
    they stay inside one texel, so the perspective-correct interpolation (not linear in the image)
    cannot shift texels at steep surfaces.

    Args:
        geo: the background geometry.
        shape: ``(H, W)`` of the image.
        faces: ``(F, 3)`` triangles of ``geo``'s vertex grid.

    Returns:
        ``(vertices, faces, uv)`` of the referenced vertices of the half-pixel grid (float32,
        int64, float32).
    """
    H, W = shape
    He, We = H + 2, W + 2
    Hh, Wh = 2 * He - 1, 2 * We - 1
    f = np.asarray(faces, np.int64)
    r, c = f // We, f % We  # (F, 3) each
    sub = np.empty((4, len(f), 3), np.int64)
    corner = (2 * r) * Wh + 2 * c
    m01, m12, m20 = ((r[:, i] + r[:, j]) * Wh + (c[:, i] + c[:, j]) for i, j in ((0, 1), (1, 2), (2, 0)))
    p0, p1, p2 = corner[:, 0], corner[:, 1], corner[:, 2]
    for k, piece in enumerate(((p0, m01, m20), (m01, p1, m12), (m20, m12, p2), (m01, m12, m20))):
        for j in range(3):
            sub[k, :, j] = piece[j]
    sub = sub.reshape(-1, 3)
    referenced = np.zeros(Hh * Wh, bool)
    referenced[sub.reshape(-1)] = True
    used = np.flatnonzero(referenced)
    inv = (np.cumsum(referenced) - 1)[sub]

    # the half-pixel grid: corners, then midpoints of horizontal, vertical and diagonal sides (the
    # diagonal runs from the top-right to the bottom-left corner of a cell)
    V = geo.vertices.astype(np.float64).reshape(He, We, 3)

    def mid(p, q):
        zp, zq = p[..., 2:3], q[..., 2:3]
        with np.errstate(divide="ignore", invalid="ignore"):
            return (zq * p + zp * q) / (zp + zq)

    P = np.empty((Hh, Wh, 3))
    P[::2, ::2] = V
    P[::2, 1::2] = mid(V[:, :-1], V[:, 1:])
    P[1::2, ::2] = mid(V[:-1], V[1:])
    P[1::2, 1::2] = mid(V[:-1, 1:], V[1:, :-1])
    px = geo.pixels.reshape(He, We, 2)
    xh = np.empty(Wh)
    xh[::2], xh[1::2] = px[0, :, 0], 0.5 * (px[0, :-1, 0] + px[0, 1:, 0])
    yh = np.empty(Hh)
    yh[::2], yh[1::2] = px[:, 0, 1], 0.5 * (px[:-1, 0, 1] + px[1:, 0, 1])
    R, C = used // Wh, used % Wh
    uv = np.stack([(xh[C] + 0.5) / W, (yh[R] + 0.5) / H], -1)
    return P.reshape(-1, 3)[used].astype(np.float32), inv, uv.astype(np.float32)


def flaps(geo: BackgroundGeometry, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rest of each valid pixel's footprint where the depth mesh has no triangle: fronto-parallel
    pieces at the pixel's own depth.

    Each left-out grid triangle is split at the image midpoints of its sides into four pieces that
    each lie in one pixel's footprint (the one of the nearest corner); a piece is kept if that pixel
    has a valid depth, and placed at that depth. Seen from the camera, the observed mesh and the
    flaps cover every valid pixel's footprint exactly once; seen from elsewhere, a depth edge stays
    open (as in our tracer) except for these half-pixel flaps.

    Args:
        geo: the background geometry.
        camera: the camera of the depth map.

    Returns:
        ``(vertices (3 P, 3) float32, faces (P, 3) int64, uv (3 P, 2) float32)``.
    """
    H, W = camera.shape
    f = geo.open
    if len(f) == 0:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int64), np.zeros((0, 2), np.float32)
    Q = geo.pixels[f]  # (S, 3, 2)
    z = geo.vertices[f][..., 2].astype(np.float64)  # (S, 3)
    ok = geo.valid[f]
    q0, q1, q2 = Q[:, 0], Q[:, 1], Q[:, 2]
    q01, q12, q20 = 0.5 * (q0 + q1), 0.5 * (q1 + q2), 0.5 * (q2 + q0)
    pieces = np.stack(
        [np.stack(t, 1) for t in ((q0, q01, q20), (q01, q1, q12), (q20, q12, q2), (q01, q12, q20))], 1
    )  # (S, 4, 3, 2), wound like their triangle
    centre = pieces.mean(axis=2)  # (S, 4, 2)
    owner = np.argmin(np.linalg.norm(centre[:, :, None, :] - Q[:, None, :, :], axis=-1), axis=-1)  # (S, 4)
    zo = np.take_along_axis(z, owner, axis=1)
    keep = np.take_along_axis(ok, owner, axis=1)
    pieces, zo = pieces[keep], zo[keep]  # (P, 3, 2), (P,)
    from_pixels = np.linalg.inv(camera.K)
    h = np.concatenate([pieces, np.ones(pieces.shape[:2] + (1,))], axis=-1)  # (P, 3, 3)
    verts = (h @ from_pixels.T) * zo[:, None, None]
    uv = np.stack([(pieces[..., 0] + 0.5) / W, (pieces[..., 1] + 0.5) / H], -1)
    n = len(pieces)
    return (
        verts.reshape(-1, 3).astype(np.float32),
        np.arange(3 * n, dtype=np.int64).reshape(n, 3),
        uv.reshape(-1, 2).astype(np.float32),
    )


def inward_box(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Box faces wound so that their normals point into the box.

    Args:
        vertices: ``(N, 3)`` box vertices.
        faces: ``(F, 3)`` box triangles.

    Returns:
        ``(F, 3)`` int64 faces (a copy).
    """
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64).copy()
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    out = np.einsum("ij,ij->i", n, v[f].mean(axis=1) - v.mean(axis=0)) > 0
    f[out] = f[out][:, [0, 2, 1]]
    return f


# ============================================================================ the object
def object_rect(camera: Camera, obj: GlassObject) -> tuple[int, int, int, int]:
    """Pixels whose footprints can overlap the object's projection, plus one pixel of margin.

    Returns:
        ``(x0, y0, x1, y1)``, end exclusive, clipped to the image.
    """
    pix, _ = camera.project(np.asarray(obj.vertices, np.float64))
    lo, hi = np.nanmin(pix, axis=0), np.nanmax(pix, axis=0)
    H, W = camera.shape
    x0, y0 = (int(np.clip(np.floor(v + 0.5) - 1, 0, n)) for v, n in ((lo[0], W), (lo[1], H)))
    x1, y1 = (int(np.clip(np.floor(v + 0.5) + 2, 0, n)) for v, n in ((hi[0], W), (hi[1], H)))
    return x0, y0, x1, y1


def object_arrays(obj: GlassObject) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The object's mesh with its vertices split at every face corner.

    Returns:
        ``(vertices (3 F, 3) float64, faces (F, 3) int64, normals (3 F, 3))``: the creased corner
        normals of :meth:`GlassObject.corner_normals`.
    """
    f = np.asarray(obj.faces, np.int64)
    v = np.asarray(obj.vertices, np.float64)[f].reshape(-1, 3)
    n = obj.corner_normals().reshape(-1, 3)
    return v, np.arange(len(v), dtype=np.int64).reshape(-1, 3), n


def object_mask(depth: np.ndarray, camera: Camera, obj: GlassObject) -> np.ndarray:
    """Pixel-centre rays that hit the object before the background (which they hit at their own
    depth-mesh vertex, where the depth is valid).

    Returns:
        ``(H, W)`` bool.
    """
    import open3d as o3d

    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(
        o3d.core.Tensor.from_numpy(np.ascontiguousarray(obj.vertices, np.float32)),
        o3d.core.Tensor.from_numpy(np.ascontiguousarray(obj.faces, np.uint32)),
    )
    d = camera.pixel_rays().reshape(-1, 3)
    rays = np.concatenate([np.zeros_like(d), d], axis=1).astype(np.float32)
    t_obj = rc.cast_rays(o3d.core.Tensor.from_numpy(rays))["t_hit"].numpy().astype(np.float64)
    valid = valid_depth_mask(depth)
    t_bg = np.where(valid, np.where(valid, depth, 1.0), np.inf).reshape(-1) / d[:, 2]
    return (np.isfinite(t_obj) & (t_obj < t_bg)).reshape(camera.shape)
