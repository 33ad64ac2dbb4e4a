"""Placing a glass object on a horizontal supporting surface found in the depth map.

Convention:
    Camera frame (OpenCV). ``up_hint`` is the approximate up direction in camera coordinates; for a
    camera held level it is ``(0, -1, 0)`` (y points down). A plane counts as *horizontal* when its
    normal is within ``max_tilt_deg`` of ``up_hint``; the fitted normal then replaces the hint as the
    scene's up direction (``GlassObject.up`` of the placed object).
    Where to look: by default the points come from a central window of the image; a ``region``
    (a bool ``(H, W)`` mask of the supporting surface, e.g. from
    :mod:`snell_bench.models.segment`) replaces the window, so the named surface can lie anywhere
    in the image.
    Two anchors (config key ``object.anchor``, :data:`ANCHORS`):

    - ``plane`` (default): a RANSAC plane fitted to the depth inside the region (or window); the
      object's bottom centre at the median of the plane's points, lifted by ``lift`` x its size
      along the plane's normal, its front turned to the camera.
    - ``centre_ray``: the authors' rule (``utils/obj_placement.py``, ``place_object_on_surface_sam3``):
      the camera ray through the centre of the region's box (SAM 3's predicted box when the region
      carries one, else the box of the mask; without a region, the pixel where the ``plane``
      anchor's plane centre is seen) meets the depth
      mesh (:func:`~snell_bench.scene.depth_mesh.depth_to_mesh`); the normal of the triangle it hits,
      turned up, tilts the object (:func:`centre_ray_support`, :func:`centre_ray_transform`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d
import trimesh

from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import depth_to_mesh, valid_depth_mask
from snell_bench.scene.objects import GlassObject

log = logging.getLogger(__name__)

__all__ = [
    "ANCHORS",
    "CENTRE_RAY_LIFT",
    "SupportPlane",
    "anchor_pixel",
    "centre_ray_support",
    "centre_ray_transform",
    "find_support_plane",
    "place_object",
    "placement_transform",
]

#: Where the object stands (config key ``object.anchor``).
ANCHORS = ("plane", "centre_ray")
#: The ``centre_ray`` anchor's lift in scene units (metres) along the up direction: the authors'
#: ``eps = 0.005`` added to the height (Blender's z), not along the surface normal.
CENTRE_RAY_LIFT = 0.005


@dataclass(frozen=True)
class SupportPlane:
    """A horizontal plane ``normal . x = normal . point`` with ``normal`` pointing up (the
    ``centre_ray`` anchor: the hit point and the hit triangle's normal, ``inliers=1``)."""

    point: np.ndarray  # (3,) the centre of the visible supporting region (camera frame)
    normal: np.ndarray  # (3,) unit, pointing up
    inliers: int  # depth points on the plane inside the search window (or region)
    pixel: np.ndarray  # (2,) where ``point`` is seen in the image


def find_support_plane(
    depth: np.ndarray,
    camera: Camera,
    *,
    up_hint=(0.0, -1.0, 0.0),
    max_tilt_deg: float = 30.0,
    window: tuple[float, float] = (0.6, 0.9),
    region: np.ndarray | None = None,
    distance_threshold: float = 0.004,
    min_inlier_fraction: float = 0.05,
    prefer: str | None = None,
    max_planes: int = 6,
    max_points: int = 60_000,
    num_iterations: int = 500,
    seed: int = 0,
) -> SupportPlane:
    """Find a horizontal supporting surface with RANSAC (Open3D), near the optical axis or inside a region.

    Points come from the central ``window`` or, when given, from ``region`` alone (a segmented
    surface may lie anywhere in the image). Planes are peeled off one at a time; candidates are
    horizontal, below the camera (seen from above) and hold at least ``min_inlier_fraction`` of the
    points; ``prefer`` picks among them. The object stands at the median of the chosen plane's
    points. Deterministic for a given ``seed``; ``region=None`` is the same as no argument.

    Args:
        depth: ``(H, W)`` z-depth; missing depth is 0, negative or not finite.
        camera: the camera of ``depth``.
        up_hint: the approximate up direction in camera coordinates.
        max_tilt_deg: a plane counts as horizontal within this angle of ``up_hint``.
        window: ``(fraction of width, fraction of height)`` of the central search window; ignored
            when ``region`` is given.
        region: ``(H, W)`` bool mask of the supporting surface (``True`` = surface), e.g. a
            :class:`~snell_bench.models.segment.SurfaceSegmenter`'s output; only its pixels with
            valid depth are used. ``None``: the central ``window``.
        distance_threshold: RANSAC inlier distance, as a fraction of the median depth of the points.
        min_inlier_fraction: the smallest share of the points a candidate plane must hold.
        prefer: ``"highest"`` (a table top rather than the floor under it), ``"largest"`` (most
            points) or ``"central"`` (nearest the image centre). ``None`` (default): ``"highest"``
            without a region and ``"largest"`` with one (the region *is* the surface, so its
            dominant plane is; "highest" would pick the top of a small thing lying on it).
        max_planes: the most planes peeled off.
        max_points: the points are subsampled (deterministically, from ``seed``) to at most this many.
        num_iterations: RANSAC iterations per plane (all of them run, for determinism).
        seed: seeds the subsampling and RANSAC.

    Returns:
        The chosen plane.

    Raises:
        ValueError: if no horizontal plane is found; if ``region`` has the wrong shape or has no
            pixel with valid depth (the message names the config keys ``segment`` and
            ``scene.depth``); if ``prefer`` is unknown.
        TypeError: if ``region`` is not boolean.
    """
    depth = np.asarray(depth, np.float64)
    if depth.shape != camera.shape:
        raise ValueError(f"depth has shape {depth.shape} but the camera is {camera.height}x{camera.width}")
    up = _unit(up_hint)
    sub, where, prefer = _search_setup(depth, region, window, prefer)
    pts, xs, ys = _search_points(depth, camera, sub, region is not None, max_points, seed)
    cos_tilt = math.cos(math.radians(max_tilt_deg))
    candidates = [
        _candidate(pts, xs, ys, inl, n, up, camera)
        for inl, n in _peel_planes(pts, up, distance_threshold, min_inlier_fraction, max_planes, num_iterations, seed)
        # horizontal and seen from above (below the camera): something can stand on it
        if len(inl) >= min_inlier_fraction * len(pts) and n @ up >= cos_tilt and float(-pts[inl].mean(axis=0) @ n) > 0
    ]
    if not candidates:
        raise ValueError(
            f"no horizontal supporting surface found {where} (tried {max_planes} planes; a plane "
            f"counts as horizontal within {max_tilt_deg} deg of up_hint={np.round(up, 3).tolist()}). Pass up_hint "
            "for a tilted camera, widen `window` (or check the region: config group `segment`), or place the "
            "object explicitly with GlassObject.from_mesh"
        )
    return _chosen_plane(candidates, prefer, camera)


def _unit(v) -> np.ndarray:
    """``v`` as a float64 array scaled to unit length."""
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def _search_setup(depth: np.ndarray, region, window, prefer: str | None) -> tuple[np.ndarray, str, str]:
    """``(mask, where, prefer)``: bool ``(H, W)`` pixels searched (window or region), their name in errors, the rule."""
    H, W = depth.shape
    if region is None:
        fx, fy = window
        x0, x1 = int(round(W * (1 - fx) / 2)), int(round(W * (1 + fx) / 2))
        y0, y1 = int(round(H * (1 - fy) / 2)), int(round(H * (1 + fy) / 2))
        sub = np.zeros_like(depth, bool)
        sub[y0:y1, x0:x1] = True
        where = "near the image centre"
    else:
        sub = np.asarray(region)
        if sub.dtype != np.bool_:
            raise TypeError(f"region must be a bool mask, got dtype {sub.dtype}")
        if sub.shape != depth.shape:
            raise ValueError(f"region has shape {sub.shape} but the depth is {H}x{W}")
        where = "inside the supporting-surface region"
    if prefer is None:
        prefer = "highest" if region is None else "largest"
    if prefer not in ("highest", "largest", "central"):
        raise ValueError(f"prefer must be 'highest', 'largest' or 'central', got {prefer!r}")
    return sub, where, prefer


def _search_points(depth, camera: Camera, sub: np.ndarray, is_region: bool, max_points: int, seed: int):
    """``(pts (N, 3), xs, ys)``: camera-frame points of ``sub``'s valid pixels, at most ``max_points`` (by ``seed``)."""
    sel = sub & valid_depth_mask(depth)
    ys, xs = np.nonzero(sel)
    if len(ys) < 3:
        if is_region:
            raise ValueError(
                f"the supporting surface has no valid depth: its region has {int(sub.sum())} pixels, {len(ys)} of "
                "them with valid depth (3 are needed). Check the segmentation (config group `segment`: the "
                "surface phrase `scene.surface`, or the mask file `segment.mask`) and the depth map (`scene.depth`)"
            )
        raise ValueError("no valid depth near the image centre to find a supporting surface on")
    if len(ys) > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(len(ys), max_points, replace=False))
        ys, xs = ys[keep], xs[keep]
    return camera.unproject(np.where(sel, depth, 0.0))[ys, xs], xs, ys


def _peel_planes(pts, up, distance_threshold, min_fraction, max_planes, iterations, seed):
    """Yield ``(inlier indices, unit normal towards up)`` of RANSAC planes peeled off ``pts`` one at a time."""
    thr = distance_threshold * float(np.median(pts[:, 2]))
    o3d.utility.random.seed(int(seed))
    remaining = np.arange(len(pts))
    for _ in range(max_planes):
        if len(remaining) < max(3, min_fraction * len(pts)):
            break
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts[remaining]))
        # probability=1 runs every iteration: Open3D's early stop in its parallel loop makes the
        # result depend on thread timing (the same seed gave different planes within one process)
        model, inl = pc.segment_plane(distance_threshold=thr, ransac_n=3, num_iterations=iterations, probability=1.0)
        inl = remaining[np.asarray(inl, np.int64)]
        n = _unit(model[:3])
        yield inl, (-n if n @ up < 0 else n)
        remaining = np.setdiff1d(remaining, inl, assume_unique=True)


def _candidate(pts, xs, ys, inl: np.ndarray, n: np.ndarray, up: np.ndarray, camera: Camera) -> tuple:
    """``(nearest inlier pixel's distance to the centre, -count, least-squares normal, points, pixels)``."""
    centre = np.array([(camera.width - 1) / 2.0, (camera.height - 1) / 2.0])
    q = pts[inl]
    _, _, vt = np.linalg.svd(q - q.mean(axis=0), full_matrices=False)
    n2 = vt[-1] if vt[-1] @ up > 0 else -vt[-1]
    pix = np.stack([xs[inl], ys[inl]], -1).astype(np.float64)
    dist_centre = float(np.min(np.linalg.norm(pix - centre, axis=1)))
    return dist_centre, -len(inl), n2, q, pix


def _chosen_plane(candidates: list, prefer: str, camera: Camera) -> SupportPlane:
    """The ``prefer`` candidate as a plane through the median of its inliers (projected onto it)."""
    if prefer == "highest":  # a table top rather than the floor under it
        candidates.sort(key=lambda c: (-round(float(c[3].mean(axis=0) @ c[2]), 6), c[1]))
    elif prefer == "largest":
        candidates.sort(key=lambda c: (c[1], round(c[0], 6)))
    else:  # central
        candidates.sort(key=lambda c: (round(c[0], 6), c[1]))
    _, neg_count, normal, q, _ = candidates[0]
    # the centre of the visible supporting region: median of the inliers, projected onto the plane
    c = np.median(q, axis=0)
    c = c - ((c - q.mean(axis=0)) @ normal) * normal
    return SupportPlane(point=c, normal=normal, inliers=-neg_count, pixel=camera.project(c[None])[0][0])


def placement_transform(size: float, point: np.ndarray, up: np.ndarray, yaw_deg: float = 0.0) -> np.ndarray:
    """4x4 transform from an object's canonical frame (y up, bottom centre at the origin, unit
    size) to the camera frame: scaled to ``size``, bottom centre at ``point``, local y along ``up``,
    local +z towards the camera (turned by ``yaw_deg`` about ``up``)."""
    up = _unit(up)
    point = np.asarray(point, np.float64)
    T = np.eye(4)
    T[:3, :3] = _frame(-point - (-point @ up) * up, up, yaw_deg) * float(size)  # z: horizontal, to the camera
    T[:3, 3] = point
    return T


def anchor_pixel(region: np.ndarray | None, camera: Camera) -> np.ndarray:
    """The pixel the ``centre_ray`` anchor aims at, ``(x, y)`` with integer pixel centres.

    The centre of the region's box: its ``box`` attribute (``x0, y0, x1, y1`` with the image's edges
    at 0 and ``W``, ``H``, e.g. SAM 3's predicted box, as the authors take it) when it has one, else
    the box of its pixels (the first pixel's left edge to the last one's right edge); without a
    region, the image centre (:func:`place_object` aims at the fitted plane's centre instead). The authors' ray uses ``X / W`` of a box coordinate ``X``: the same
    ray as pixel ``X - 0.5`` here for a centred principal point.

    Raises:
        ValueError: for an empty region (naming ``segment``).
    """
    if region is None:
        return np.array([(camera.width - 1) / 2.0, (camera.height - 1) / 2.0])
    box = getattr(region, "box", None)
    if box is None:
        ys, xs = np.nonzero(np.asarray(region))
        if len(xs) == 0:
            raise ValueError("the supporting-surface region is empty: check the segmentation (config group `segment`)")
        box = (xs.min(), ys.min(), xs.max() + 1.0, ys.max() + 1.0)
    x0, y0, x1, y1 = (float(v) for v in box)
    return np.array([(x0 + x1) / 2.0 - 0.5, (y0 + y1) / 2.0 - 0.5])


def centre_ray_support(
    depth: np.ndarray,
    camera: Camera,
    pixel: np.ndarray,
    *,
    up_hint=(0.0, -1.0, 0.0),
    edge_threshold: float = 0.05,
    max_tilt_deg: float = 30.0,
) -> SupportPlane:
    """Where the camera ray through ``pixel`` first meets the depth mesh, and the normal there.

    The mesh is :func:`~snell_bench.scene.depth_mesh.depth_to_mesh` (cut at ``edge_threshold``, as
    ``warps.edge_threshold`` cuts the background); the ray is cast with Open3D, the hit point and
    the normal are recomputed in float64 from the hit triangle. The normal is the hit triangle's
    (flat, as the authors'), turned so that it points along ``up_hint``. A normal more than
    ``max_tilt_deg`` off ``up_hint`` is used anyway (the authors do not check) and logged.

    Returns:
        ``SupportPlane(point, normal, inliers=1, pixel)``: one triangle holds the point.

    Raises:
        ValueError: if the ray meets no depth (a hole or a cut depth edge), naming the keys.
    """
    up = _unit(up_hint)
    verts, faces, _ = depth_to_mesh(depth, camera, edge_threshold)
    px = np.asarray(pixel, np.float64).reshape(2)
    d = camera.pixel_rays(px[None], normalize=False)[0]
    scene = o3d.t.geometry.RaycastingScene()
    if len(faces):
        scene.add_triangles(o3d.core.Tensor.from_numpy(verts), o3d.core.Tensor.from_numpy(faces))
    rays = o3d.core.Tensor(np.concatenate([np.zeros(3), d])[None].astype(np.float32))
    hit = scene.cast_rays(rays)
    prim = int(hit["primitive_ids"].numpy()[0])
    if not len(faces) or not np.isfinite(float(hit["t_hit"].numpy()[0])) or prim < 0 or prim >= len(faces):
        raise ValueError(
            f"the ray through pixel ({px[0]:.1f}, {px[1]:.1f}), the centre of the supporting surface's box, meets "
            "no depth (a hole or a depth edge there): check the segmentation (config group `segment`) and the depth "
            "(scene.depth, depth.edge_rtol), or stand the object on a fitted plane (object.anchor=plane)"
        )
    a, b, c = verts[faces[prim]].astype(np.float64)
    n = _unit(np.cross(b - a, c - a))
    point = d * float(n @ a) / float(n @ d)
    if n @ up < 0:
        n = -n
    tilt = math.degrees(math.acos(min(1.0, float(n @ up))))
    if tilt > max_tilt_deg:
        log.warning(
            "centre_ray: the surface under pixel %s is %.1f deg off up (object.max_tilt_deg=%g)", px, tilt, max_tilt_deg
        )
    return SupportPlane(point=point, normal=n, inliers=1, pixel=px)


def _frame(z: np.ndarray, up: np.ndarray, yaw_deg: float) -> np.ndarray:
    """3x3 columns ``(up x z, up, z)``, ``z`` (``up x e_x`` if ~0) normalised and turned ``yaw_deg`` about ``up``."""
    if np.linalg.norm(z) < 1e-9:
        z = np.cross(up, [1.0, 0.0, 0.0])
    z = z / np.linalg.norm(z)
    if yaw_deg:
        t = math.radians(yaw_deg)
        z = math.cos(t) * z + math.sin(t) * np.cross(up, z)
    return np.stack([np.cross(up, z), up, z], axis=1)


def _centre_ray_terms(vertices, point, normal, up, yaw_deg, lift):
    """``(base, coef, R, B, bottom, mean)``: a canonical vertex v lands at ``base + size * coef(v)``."""
    up, normal = _unit(up), _unit(normal)
    B = _frame(np.array([0.0, 0.0, -1.0]) - (-up[2]) * up, up, yaw_deg)  # faces the camera's axis, not the camera
    v = np.asarray(vertices, np.float64)
    bottom = v[v[:, 1] == v[:, 1].min()].mean(axis=0)  # the mean of the lowest vertices (exactly the lowest)
    mean = v.mean(axis=0)
    R = trimesh.geometry.align_vectors(up, normal)[:3, :3]
    coef = (v - mean) @ (R @ B).T + (mean - bottom) @ B.T
    return np.asarray(point, np.float64) + lift * up, coef, R, B, bottom, mean


def centre_ray_transform(
    vertices: np.ndarray,
    size: float,
    point: np.ndarray,
    normal: np.ndarray,
    up: np.ndarray,
    yaw_deg: float = 0.0,
    lift: float = CENTRE_RAY_LIFT,
) -> np.ndarray:
    """4x4 transform from the canonical frame (y up, unit size) to the camera frame, the authors'
    pose: (1) scaled to ``size`` with its local y along ``up`` and local z along the camera's -z made
    horizontal (their mesh keeps the camera's axes; ``yaw_deg`` turns it about ``up``); (2) moved so
    that its bottom centre, the mean of its lowest vertices, is at ``point``; (3) turned about the
    mean of its vertices by the smallest rotation taking ``up`` to ``normal`` (so on a tilted
    surface the bottom leaves ``point`` by ``2 h sin(tilt / 2)``, h the mean's height above the
    bottom); (4) raised by ``lift`` (scene units) along ``up``, not along the normal.

    ``vertices`` ``(N, 3)`` are the canonical ones (only their lowest ones and their mean matter);
    ``point``, ``normal``, ``up`` are ``(3,)`` in the camera frame; ``lift`` is in scene units.
    """
    base, _, R, B, bottom, mean = _centre_ray_terms(vertices, point, normal, up, yaw_deg, lift)
    # v -> base + size (R B (v - mean) + B (mean - bottom)) = base + size (B (mean - bottom) - R B mean) + size R B v
    T = np.eye(4)
    T[:3, :3] = size * (R @ B)
    T[:3, 3] = base + size * (B @ (mean - bottom) - R @ B @ mean)
    return T


#: Smallest projected extent (pixels) an object must span to be traced and scored.
MIN_EXTENT_PX = 4.0


def _size_keys(size: float, dist: float) -> str:
    return f"object.size={size:.3g} (or object.relative_size={size / dist:.3g} x the distance {dist:.3g})"


def _check_fits(obj, camera: Camera, p: np.ndarray, coef: np.ndarray, *, size: float, dist: float):
    """Raise ``ValueError`` naming the size keys and the size that works if the object placed at
    ``size`` reaches behind the camera or spans fewer than :data:`MIN_EXTENT_PX` pixels; a vertex of
    the canonical object lands at ``p + size * coef`` (linear in the size)."""
    p = np.asarray(p, np.float64)
    z = p[2] + size * coef[:, 2]
    near = 1e-3 * dist
    if float(z.min()) <= near:
        behind = coef[:, 2] < 0
        largest = 0.9 * float(np.min((p[2] - near) / -coef[behind, 2]))
        raise ValueError(
            f"{obj.name}: at {_size_keys(size, dist)} it reaches behind the camera, since it stands "
            f"{p[2]:.3g} in front of it; the largest size that fits in front of the camera is about "
            f"{_size_keys(largest, dist)}: set object.size or object.relative_size at most that"
        )
    pix, _ = camera.project(p + size * coef)
    lo, hi = (np.clip(f(pix, axis=0), -0.5, [camera.width - 0.5, camera.height - 0.5]) for f in (np.nanmin, np.nanmax))
    extent = float(np.min(hi - lo))
    if extent < MIN_EXTENT_PX:
        full = float(np.min(np.nanmax(pix, axis=0) - np.nanmin(pix, axis=0)))
        smallest = size * MIN_EXTENT_PX / max(full, 1e-12) * 1.1
        raise ValueError(
            f"{obj.name}: at {_size_keys(size, dist)} it spans only {extent:.2g} pixels of the "
            f"{camera.width}x{camera.height} image, too few to trace and score (at least {MIN_EXTENT_PX:g}): set "
            f"object.size to at least {smallest:.3g} (object.relative_size "
            f"{smallest / dist:.3g}), or null to use object.relative_size"
        )


def place_object(
    obj: GlassObject,
    depth: np.ndarray,
    camera: Camera,
    *,
    size: float | None = None,
    relative_size: float = 0.25,
    plane: SupportPlane | None = None,
    region: np.ndarray | None = None,
    yaw_deg: float = 0.0,
    lift: float = 1e-3,
    anchor: str = "plane",
    **plane_kwargs,
) -> GlassObject:
    """Put a canonical object on the supporting surface.

    With ``anchor="plane"`` ``lift`` raises it by that fraction of its size along the plane's normal,
    so it stands on the surface instead of touching it; ``anchor="centre_ray"`` is the authors' pose
    (:func:`centre_ray_support`, :func:`centre_ray_transform`, :data:`CENTRE_RAY_LIFT` along up).

    Args:
        obj: the canonical (unplaced) object.
        depth: ``(H, W)`` z-depth of the scene.
        camera: the camera of ``depth``.
        size: the object's largest bounding-box side in scene units; ``None``: ``relative_size`` x
            the distance from the camera to the placement point.
        relative_size: see ``size``.
        plane: the supporting plane; ``None``: :func:`find_support_plane` (``region`` and
            ``plane_kwargs`` are used only then).
        region: ``(H, W)`` bool mask of the supporting surface, passed to :func:`find_support_plane`
            (the plane is fitted inside it; ``None``: the central window).
        yaw_deg: turn about the up direction, in degrees.
        lift: raise the object by this fraction of its size (``anchor="plane"``).
        anchor: ``"plane"`` or ``"centre_ray"`` (:data:`ANCHORS`; config key ``object.anchor``).
        **plane_kwargs: more arguments of :func:`find_support_plane` (``"centre_ray"``: its
            ``up_hint`` and ``max_tilt_deg``, and ``edge_threshold`` of the depth mesh).

    Returns:
        The placed object.

    Raises:
        ValueError: if the object is already placed, ``size`` is invalid, or no plane is found.
    """
    if obj.placed:
        raise ValueError(f"{obj.name} is already placed in camera coordinates")
    if anchor not in ANCHORS:
        raise ValueError(f"object.anchor={anchor!r}: use one of {', '.join(ANCHORS)}")
    up = _unit(plane_kwargs.get("up_hint", (0.0, -1.0, 0.0)))
    if plane is None:
        plane = _support(depth, camera, region, anchor, up, plane_kwargs)
    dist = float(np.linalg.norm(plane.point))
    if size is None:
        if not relative_size > 0:
            raise ValueError(f"relative_size must be > 0, got {relative_size}")
        size = relative_size * dist
    if not (size > 0 and math.isfinite(size)):
        raise ValueError(f"size must be finite and > 0, got {size}")
    if anchor == "centre_ray":
        point, coef, *_ = _centre_ray_terms(obj.vertices, plane.point, plane.normal, up, yaw_deg, CENTRE_RAY_LIFT)
        base, T = point, centre_ray_transform(obj.vertices, size, plane.point, plane.normal, up, yaw_deg)
    else:
        point = plane.point + lift * size * plane.normal
        T = placement_transform(size, point, plane.normal, yaw_deg)
        # a vertex v of the canonical object lands at p + s (lift n + R v): linear in the size s
        R = placement_transform(1.0, np.zeros(3), plane.normal, yaw_deg)[:3, :3]
        base, coef = plane.point, obj.vertices @ R.T + lift * plane.normal
    _check_fits(obj, camera, base, coef, size=size, dist=dist)
    placed = obj.transformed(T, up=plane.normal)
    log.info("placed %s (size %.3g) at %s, normal %s", obj.name, size, np.round(point, 3), np.round(plane.normal, 3))
    return placed


def _support(depth, camera: Camera, region, anchor: str, up: np.ndarray, plane_kwargs: dict) -> SupportPlane:
    """The supporting plane :func:`place_object` finds for ``anchor`` (``plane_kwargs`` as it was given)."""
    if anchor != "centre_ray":
        return find_support_plane(depth, camera, region=region, **plane_kwargs)
    keep = {k: plane_kwargs.pop(k) for k in ("max_tilt_deg", "edge_threshold") if k in plane_kwargs}
    # without a region the ray aims where the fitted plane's centre is seen (the image centre often shows a wall)
    pixel = (
        anchor_pixel(region, camera)
        if region is not None
        else find_support_plane(depth, camera, max_tilt_deg=keep.get("max_tilt_deg", 30.0), **plane_kwargs).pixel
    )
    return centre_ray_support(depth, camera, pixel, up_hint=up, **keep)
