"""Placing a glass object on a horizontal supporting surface found in the depth map.

Convention:
    Camera frame (OpenCV). ``up_hint`` is the approximate up direction in camera coordinates; for a
    camera held level it is ``(0, -1, 0)`` (y points down). A plane counts as *horizontal* when its
    normal is within ``max_tilt_deg`` of ``up_hint``; the fitted normal then replaces the hint as the
    scene's up direction (``GlassObject.up`` of the placed object).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import valid_depth_mask
from snell_bench.scene.objects import GlassObject

log = logging.getLogger(__name__)

__all__ = ["SupportPlane", "find_support_plane", "place_object", "placement_transform"]


@dataclass(frozen=True)
class SupportPlane:
    """A horizontal plane ``normal . x = normal . point`` with ``normal`` pointing up."""

    point: np.ndarray  # (3,) the centre of the visible supporting region (camera frame)
    normal: np.ndarray  # (3,) unit, pointing up
    inliers: int  # depth points on the plane inside the search window
    pixel: np.ndarray  # (2,) where ``point`` is seen in the image


def find_support_plane(
    depth: np.ndarray,
    camera: Camera,
    *,
    up_hint=(0.0, -1.0, 0.0),
    max_tilt_deg: float = 30.0,
    window: tuple[float, float] = (0.6, 0.9),
    distance_threshold: float = 0.004,
    min_inlier_fraction: float = 0.05,
    prefer: str = "highest",
    max_planes: int = 6,
    max_points: int = 60_000,
    num_iterations: int = 500,
    seed: int = 0,
) -> SupportPlane:
    """Find a horizontal supporting surface near the optical axis with RANSAC (Open3D).

    Points come from a central window of the image (``window`` = fraction of width, height). Planes
    are peeled off one at a time (up to ``max_planes``). Candidates are horizontal, below the camera
    (seen from above) and hold at least ``min_inlier_fraction`` of the window's points; ``prefer``
    picks among them: ``"highest"`` (default: a table top rather than the floor under it),
    ``"largest"`` (most points) or ``"central"`` (nearest the image centre). The object stands at
    the median of the chosen plane's points. ``distance_threshold`` is relative to the median depth. Raises
    ``ValueError`` when no horizontal plane exists. Deterministic for a given ``seed``.
    """
    depth = np.asarray(depth, np.float64)
    if depth.shape != camera.shape:
        raise ValueError(f"depth has shape {depth.shape} but the camera is {camera.height}x{camera.width}")
    up = np.asarray(up_hint, np.float64)
    up = up / np.linalg.norm(up)
    H, W = depth.shape
    fx, fy = window
    x0, x1 = int(round(W * (1 - fx) / 2)), int(round(W * (1 + fx) / 2))
    y0, y1 = int(round(H * (1 - fy) / 2)), int(round(H * (1 + fy) / 2))
    sub = np.zeros_like(depth, bool)
    sub[y0:y1, x0:x1] = True
    sel = sub & valid_depth_mask(depth)
    ys, xs = np.nonzero(sel)
    if prefer not in ("highest", "largest", "central"):
        raise ValueError(f"prefer must be 'highest', 'largest' or 'central', got {prefer!r}")
    if len(ys) < 3:
        raise ValueError("no valid depth near the image centre to find a supporting surface on")
    rng = np.random.default_rng(seed)
    if len(ys) > max_points:
        keep = np.sort(rng.choice(len(ys), max_points, replace=False))
        ys, xs = ys[keep], xs[keep]
    pts = camera.unproject(np.where(sel, depth, 0.0))[ys, xs]
    thr = distance_threshold * float(np.median(pts[:, 2]))
    o3d.utility.random.seed(int(seed))

    remaining = np.arange(len(pts))
    cos_tilt = math.cos(math.radians(max_tilt_deg))
    centre = np.array([(W - 1) / 2.0, (H - 1) / 2.0])
    candidates = []
    for _ in range(max_planes):
        if len(remaining) < max(3, min_inlier_fraction * len(pts)):
            break
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts[remaining]))
        # probability=1 runs every iteration: Open3D's early stop in its parallel loop makes the
        # result depend on thread timing (the same seed gave different planes within one process)
        model, inl = pc.segment_plane(
            distance_threshold=thr, ransac_n=3, num_iterations=num_iterations, probability=1.0
        )
        inl = remaining[np.asarray(inl, np.int64)]
        n = np.asarray(model[:3], np.float64)
        n = n / np.linalg.norm(n)
        if n @ up < 0:
            n = -n
        below_camera = float(-pts[inl].mean(axis=0) @ n) > 0  # seen from above: something can stand on it
        if len(inl) >= min_inlier_fraction * len(pts) and n @ up >= cos_tilt and below_camera:
            # refine the normal by least squares on the inliers
            q = pts[inl]
            c = q.mean(axis=0)
            _, _, vt = np.linalg.svd(q - c, full_matrices=False)
            n2 = vt[-1] if vt[-1] @ up > 0 else -vt[-1]
            pix = np.stack([xs[inl], ys[inl]], -1).astype(np.float64)
            dist_centre = float(np.min(np.linalg.norm(pix - centre, axis=1)))
            candidates.append((dist_centre, -len(inl), n2, q, pix))
        remaining = np.setdiff1d(remaining, inl, assume_unique=True)
    if not candidates:
        raise ValueError(
            f"no horizontal supporting surface found near the image centre (tried {max_planes} planes; a plane "
            f"counts as horizontal within {max_tilt_deg} deg of up_hint={np.round(up, 3).tolist()}). Pass up_hint "
            "for a tilted camera, widen `window`, or place the object explicitly with GlassObject.from_mesh"
        )
    if prefer == "highest":  # a table top rather than the floor under it
        candidates.sort(key=lambda c: (-round(float(c[3].mean(axis=0) @ c[2]), 6), c[1]))
    elif prefer == "largest":
        candidates.sort(key=lambda c: (c[1], round(c[0], 6)))
    else:  # central
        candidates.sort(key=lambda c: (round(c[0], 6), c[1]))
    _, neg_count, normal, q, pix = candidates[0]
    # the centre of the visible supporting region: median of the inliers, projected onto the plane
    c = np.median(q, axis=0)
    c = c - ((c - q.mean(axis=0)) @ normal) * normal
    px, _ = camera.project(c[None])
    return SupportPlane(point=c, normal=normal, inliers=-neg_count, pixel=px[0])


def placement_transform(size: float, point: np.ndarray, up: np.ndarray, yaw_deg: float = 0.0) -> np.ndarray:
    """4x4 transform from an object's canonical frame (y up, bottom centre at the origin, unit
    size) to the camera frame: scaled to ``size``, bottom centre at ``point``, local y along ``up``,
    local +z towards the camera (turned by ``yaw_deg`` about ``up``)."""
    up = np.asarray(up, np.float64)
    up = up / np.linalg.norm(up)
    point = np.asarray(point, np.float64)
    to_cam = -point - (-point @ up) * up  # horizontal direction from the object to the camera
    if np.linalg.norm(to_cam) < 1e-9:
        to_cam = np.cross(up, [1.0, 0.0, 0.0])
    z = to_cam / np.linalg.norm(to_cam)
    if yaw_deg:
        a = math.radians(yaw_deg)
        z = math.cos(a) * z + math.sin(a) * np.cross(up, z)
    x = np.cross(up, z)
    R = np.stack([x, up, z], axis=1)
    T = np.eye(4)
    T[:3, :3] = R * float(size)
    T[:3, 3] = point
    return T


def place_object(
    obj: GlassObject,
    depth: np.ndarray,
    camera: Camera,
    *,
    size: float | None = None,
    relative_size: float = 0.25,
    plane: SupportPlane | None = None,
    yaw_deg: float = 0.0,
    lift: float = 1e-3,
    **plane_kwargs,
) -> GlassObject:
    """Put a canonical object on the supporting surface.

    ``size`` is the object's largest bounding-box side in scene units; by default
    ``relative_size`` times the distance from the camera to the placement point. ``lift`` raises it
    by that fraction of its size, so it stands on the surface instead of touching it.
    """
    if obj.placed:
        raise ValueError(f"{obj.name} is already placed in camera coordinates")
    if plane is None:
        plane = find_support_plane(depth, camera, **plane_kwargs)
    dist = float(np.linalg.norm(plane.point))
    if size is None:
        if not relative_size > 0:
            raise ValueError(f"relative_size must be > 0, got {relative_size}")
        size = relative_size * dist
    if not (size > 0 and math.isfinite(size)):
        raise ValueError(f"size must be finite and > 0, got {size}")
    point = plane.point + lift * size * plane.normal
    T = placement_transform(size, point, plane.normal, yaw_deg)
    placed = obj.transformed(T, up=plane.normal)
    log.info(
        "placed %s (size %.3g) at %s on a plane with normal %s",
        obj.name,
        size,
        np.round(point, 3),
        np.round(plane.normal, 3),
    )
    return placed
