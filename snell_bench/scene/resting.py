"""An object resting on the surface under it, not on a plane fitted to it (``object.rest``).

A plane fitted to a rough support (a stone table) passes below its high points: a flat base placed on
the plane, lifted by a thousandth of its size, has the surface's bumps inside it, and light traced
through the base ends on the table inside the glass. :func:`rest_on_surface` lifts the placed object
along its up direction until its lower surface clears the depth surface under it, as a glass set down
on the stone would stand on its highest points.

Convention:
    - Frame: the camera frame; ``up`` the object's (its support's normal, ``GlassObject.up``).
    - The surface under the object: the depth map's points (pixel centres) whose horizontal distance
      from the object's axis is within its horizontal radius and that rise at most ``max_rise`` times
      its size above its lowest point (higher points belong to something else: a wall, another
      object, which the object may stand beside or in front of).
    - A point's penetration: its height above the object's lower surface on the vertical through it
      (a ray cast up from below the object, Open3D); the object rises by the largest penetration plus
      ``clearance`` times its size, or not at all when nothing penetrates.
"""

from __future__ import annotations

import numpy as np

__all__ = ["rest_on_surface"]


def rest_on_surface(obj, depth: np.ndarray, camera, *, clearance: float = 1e-3, max_rise: float = 0.05):
    """``obj`` lifted along its up direction to stand on the depth surface under it (module convention).

    Args:
        obj: the placed :class:`~snell_bench.scene.objects.GlassObject` (with ``up``).
        depth: ``(H, W)`` z-depth of I⁻ (NaN or <= 0 where unknown).
        camera: its camera.
        clearance: the gap left, as a fraction of the object's size.
        max_rise: the highest point considered part of the support, as a fraction of the size.

    Returns:
        ``(object, lift)``: the lifted object (the same object when nothing penetrates) and the
        lift in scene units.

    Raises:
        ValueError: the object is not placed or has no up direction.
    """
    import open3d as o3d

    if not obj.placed or obj.up is None:
        raise ValueError("rest_on_surface needs a placed object with an up direction (place_object sets both)")
    up = np.asarray(obj.up, np.float64)
    v = np.asarray(obj.vertices, np.float64)
    heights = v @ up
    size = float(heights.max() - heights.min())
    bottom = float(heights.min())
    axis = np.asarray(obj.center, np.float64)
    horizontal = (v - axis) - np.outer((v - axis) @ up, up)
    radius = float(np.linalg.norm(horizontal, axis=1).max())
    z = np.asarray(depth, np.float64)
    with np.errstate(invalid="ignore"):
        known = np.isfinite(z) & (z > 0)
    P = camera.unproject(np.where(known, z, 0.0))[known]
    rel = P - axis
    h = P @ up
    flat = rel - np.outer(rel @ up, up)
    near = (np.linalg.norm(flat, axis=1) <= radius) & (h <= bottom + max_rise * size)
    if not near.any():
        return obj, 0.0
    below = 2.0 * size
    start = P[near] - below * up
    rays = np.concatenate([start, np.broadcast_to(up, start.shape)], 1).astype(np.float32)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor.from_numpy(np.ascontiguousarray(v, np.float32)),
        o3d.core.Tensor.from_numpy(np.ascontiguousarray(obj.faces, np.uint32)),
    )
    t = scene.cast_rays(o3d.core.Tensor.from_numpy(rays))["t_hit"].numpy().astype(np.float64)
    hit = np.isfinite(t)
    if not hit.any():
        return obj, 0.0
    penetration = float((below - t[hit]).max())  # the point's height above the lower surface
    if penetration <= 0:
        return obj, 0.0
    lift = penetration + clearance * size
    T = np.eye(4)
    T[:3, 3] = lift * up
    return obj.transformed(T, up=up), lift
