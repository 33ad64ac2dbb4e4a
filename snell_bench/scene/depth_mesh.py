"""Depth map to background geometry.

Convention:
    - Input: a z-depth map ``(H, W)`` (see :mod:`snell_bench.scene.camera`) and its camera.
    - Vertex ``y * W + x`` is the unprojected centre of pixel ``(x, y)``; each 2x2 block of valid
      pixels gives two triangles wound so that their normals face the camera.
    - A triangle is *cut* (dropped) when its depths differ by more than ``edge_threshold`` relative
      to the nearest one (``max z / min z - 1 > edge_threshold``): it would bridge a depth
      discontinuity (an occlusion boundary) with a surface that nobody observed.
    - Invalid depth (NaN, inf, <= 0) drops every triangle touching the pixel; the count is logged.
    - Pixels passed as ``exclude`` (e.g. background far enough to be treated as at infinity) drop
      their triangles the same way, without a warning.
    - A closed axis-aligned *bounding box* around the scene, the camera and any extra points stands
      for unobserved space: a ray that hits it sees something I⁻ does not show.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from snell_bench.scene.camera import Camera

log = logging.getLogger(__name__)

__all__ = ["BackgroundMesh", "depth_to_mesh", "bounding_box_mesh", "build_background", "valid_depth_mask"]


def valid_depth_mask(depth: np.ndarray) -> np.ndarray:
    """``True`` where depth is finite and > 0."""
    depth = np.asarray(depth)
    with np.errstate(invalid="ignore"):
        return np.isfinite(depth) & (depth > 0)


def depth_to_mesh(
    depth: np.ndarray, camera: Camera, edge_threshold: float = 0.05, exclude: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Triangulate a depth map.

    Returns ``(vertices (H*W, 3) float32, faces (F, 3) uint32, info)`` where ``info`` counts
    ``invalid_pixels``, ``excluded_pixels`` and ``cut_triangles``. Vertices of invalid pixels are
    set to 0 and are referenced by no face; ``exclude`` ``(H, W)`` bool leaves pixels out too.
    """
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"depth must be a 2-D (H, W) array, got shape {depth.shape}")
    if depth.shape != camera.shape:
        raise ValueError(
            f"depth has shape {depth.shape} but the camera is {camera.height}x{camera.width}; "
            "pass a depth map of the camera's (height, width)"
        )
    if not np.issubdtype(depth.dtype, np.number):
        raise ValueError(f"depth must be numeric, got dtype {depth.dtype}")
    if not (edge_threshold > 0):
        raise ValueError(f"edge_threshold must be > 0, got {edge_threshold}")
    H, W = depth.shape
    valid = valid_depth_mask(depth)
    n_invalid = int(valid.size - valid.sum())
    if n_invalid == valid.size:
        raise ValueError("depth has no valid pixel (all NaN, inf or <= 0)")
    if n_invalid:
        log.warning("depth: %d of %d pixels are invalid (NaN, inf or <= 0) and are left out", n_invalid, valid.size)
    z = np.where(valid, depth, 0.0).astype(np.float64)
    verts = camera.unproject(z).reshape(-1, 3).astype(np.float32)
    n_excluded = 0
    if exclude is not None:
        exclude = np.asarray(exclude, bool)
        if exclude.shape != depth.shape:
            raise ValueError(f"exclude has shape {exclude.shape}, expected the depth's {depth.shape}")
        n_excluded = int((exclude & valid).sum())
        valid = valid & ~exclude
    info = {"invalid_pixels": n_invalid, "excluded_pixels": n_excluded, "cut_triangles": 0}

    if H < 2 or W < 2:
        return verts, np.zeros((0, 3), np.uint32), info
    idx = np.arange(H * W, dtype=np.int64).reshape(H, W)
    a, b = idx[:-1, :-1], idx[:-1, 1:]
    c, d = idx[1:, :-1], idx[1:, 1:]
    tris = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    zf, vf = z.reshape(-1), valid.reshape(-1)
    ok = vf[tris].all(axis=1)
    zt = zf[tris]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = zt.max(axis=1) / zt.min(axis=1)
    smooth = ok & (ratio <= 1.0 + edge_threshold)
    n_cut = int((ok & ~smooth).sum())
    faces = tris[smooth].astype(np.uint32)
    log.debug("depth mesh: %d triangles, %d cut at depth edges", len(faces), n_cut)
    info["cut_triangles"] = n_cut
    return verts, faces, info


def bounding_box_mesh(points: np.ndarray, margin: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """A closed axis-aligned box around ``points (N, 3)``, grown by ``margin`` of its extent
    on each side. Returns ``(vertices (8, 3) float32, faces (12, 3) uint32)``."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    lo, hi = points.min(axis=0), points.max(axis=0)
    pad = margin * max(float((hi - lo).max()), 1e-3)
    lo, hi = lo - pad, hi + pad
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], np.float32)
    # corners indexed by bits (x, y, z); two triangles per side
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = np.array([t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))], np.uint32)
    return v, f


@dataclass
class BackgroundMesh:
    """The observed surface of a depth map plus a box of unobserved space (camera frame)."""

    vertices: np.ndarray  # (H*W, 3) float32
    faces: np.ndarray  # (F, 3) uint32
    box_vertices: np.ndarray  # (8, 3) float32
    box_faces: np.ndarray  # (12, 3) uint32
    invalid_pixels: int
    cut_triangles: int
    excluded_pixels: int = 0


def build_background(
    depth: np.ndarray,
    camera: Camera,
    edge_threshold: float = 0.05,
    extra_points: np.ndarray | None = None,
    box_margin: float = 0.1,
    exclude: np.ndarray | None = None,
) -> BackgroundMesh:
    """Depth mesh and bounding box enclosing it, the camera and ``extra_points`` (e.g. the object).
    ``exclude``: ``(H, W)`` bool pixels left out of the mesh (and out of the box)."""
    verts, faces, info = depth_to_mesh(depth, camera, edge_threshold, exclude=exclude)
    if len(faces):
        referenced = np.zeros(len(verts), bool)
        referenced[faces.reshape(-1)] = True
    else:
        referenced = valid_depth_mask(depth).reshape(-1)
        if exclude is not None:
            referenced &= ~np.asarray(exclude, bool).reshape(-1)
    used = verts[referenced]
    pts = [used, np.zeros((1, 3), np.float32)]
    if extra_points is not None:
        pts.append(np.asarray(extra_points, np.float32).reshape(-1, 3))
    bv, bf = bounding_box_mesh(np.concatenate(pts), margin=box_margin)
    return BackgroundMesh(verts, faces, bv, bf, info["invalid_pixels"], info["cut_triangles"], info["excluded_pixels"])
