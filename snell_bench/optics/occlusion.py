"""Whether the panorama centre sees the ends of traced rays: the occlusion test of π⁻¹ and π^-R.

Convention:
    Camera frame (OpenCV), float64 numpy arrays. A traced ray (a refracted ray leaving the object,
    or a first-surface mirror ray) ends at a background point ``p``; the panorama, centred at ``c``
    inside the object, shows in the direction of ``p`` whatever ``c`` sees first along it in the
    glass-free scene. The panorama pixel of ``p`` (:func:`~snell_bench.optics.warp_maps.pano_coords`)
    carries the colour of ``p`` only where nothing stands between ``c`` and ``p`` and ``c`` looks at
    the side of the surface the ray arrived on; anywhere else an occluder (or the other side of the
    surface) would lend its colour to the glass, so those panorama coordinates are invalid.
"""

from __future__ import annotations

import numpy as np

from snell_bench.optics.far_field import POINT_AT_INFINITY, AtInfinity
from snell_bench.optics.tracer import HitKind, SceneTracer

__all__ = ["ray_ends_seen", "occlusion_tolerance"]

#: Unit roundoff of float32 (Open3D's only ray type).
_U32 = 2.0**-24
#: Sine of the grazing angle below which the tolerance stops growing (about 0.9 degrees).
_GRAZING = 2.0**-6


def occlusion_tolerance(center: np.ndarray, origins: np.ndarray, points: np.ndarray, cos: np.ndarray) -> np.ndarray:
    """How far before a ray end ``p`` a hit of the re-cast from ``c`` may come and still be ``p``'s own
    surface, from float32 rounding (``u = 2⁻²⁴``).

    The traced ray from ``o`` reached ``p = o + t d`` with ``o``, ``d`` rounded to float32 and ``t``
    from Embree's float32 intersection: ``p`` lies within ``8 u (|o| + |p|)`` of the (float32-vertex)
    triangle it hit, measured along the normal (rounding of the ray moves it across itself by at most
    ``√3 u (|o| + |p - o|)``, the intersection adds a few ulps of the coordinates). The re-cast from
    ``c`` meets that triangle within ``8 u (|c| + |p|)`` of the exact plane, likewise. The two offsets
    along the normal become a distance along the re-cast over ``|n · r|``, the sine of the angle
    between the re-cast and the triangle; with a factor 2 of margin,
    ``tol = 16 u (|c| + |o| + 2 |p|) / max(|n · r|, 2⁻⁶)`` (grazing re-casts, below about 0.9°, get the
    cap: at most ``1024 u`` times the scale, about ``6e-5`` of it).

    Args:
        center: ``(3,)`` the panorama centre ``c``.
        origins: ``(N, 3)`` origins ``o`` of the traced rays' last segments.
        points: ``(N, 3)`` their ends ``p``.
        cos: ``(N,)`` ``n · r`` of the re-cast's hit (any sign; 0 where nothing is hit).

    Returns:
        ``(N,)`` float64 tolerances in the scene's length unit.

    Examples:
        A ray end 5 m away, hit head-on by the re-cast from a centre 3 m away (ray origins there too):

        >>> c = np.array([0.0, 0.0, 3.0])
        >>> tol = occlusion_tolerance(c, c[None], np.array([[0.0, 0.0, 5.0]]), np.array([1.0]))
        >>> bool(np.isclose(tol[0], 16 * 2.0**-24 * 16))
        True
    """
    scale = np.linalg.norm(center) + np.linalg.norm(origins, axis=1) + 2.0 * np.linalg.norm(points, axis=1)
    return 16.0 * _U32 * scale / np.maximum(np.abs(cos), _GRAZING)


def ray_ends_seen(
    tracer: SceneTracer,
    at_inf: AtInfinity | None,
    center: np.ndarray,
    points: np.ndarray,
    origins: np.ndarray,
    kind: np.ndarray,
    on_box: np.ndarray,
    *,
    sides: bool = True,
) -> np.ndarray:
    """Whether the panorama centre sees where traced rays end (module docstring).

    - A finite end ``p`` (on the depth mesh or the box of unobserved space): a straight ray is cast
      from ``c`` towards ``p`` against the background and the box (not the object); ``p`` is hidden
      where it hits something more than :func:`occlusion_tolerance` before ``p``. A re-cast that
      slips past ``p`` (its hit lies beyond: a ray aimed at an edge of the depth mesh may pass
      between triangles) has nothing in front of ``p``.
    - With ``sides``, where the re-cast hits the depth mesh at ``p`` (within the tolerance), it must
      hit the side the traced ray arrived on: the front (``kind`` OBSERVED) or the back
      (UNOBSERVED, not on the box). The panorama shows the front of a surface that a ray reached
      from behind, not the surface the ray saw.
    - A point at infinity (far background, :mod:`~snell_bench.optics.far_field`): seen where the ray
      from ``c`` along its direction leaves the scene's geometry and resolves to far background.
    - No end point (NaN: the panorama is read by the ray's direction): nothing to occlude, True.

    Args:
        tracer: the scene's tracer.
        at_inf: resolves rays towards far background (``None``: no far pixel).
        center: ``(3,)`` the panorama centre.
        points: ``(N, 3)`` ray ends, NaN where none.
        origins: ``(N, 3)`` origins of the rays' last segments (for the tolerance).
        kind: ``(N,)`` :class:`~snell_bench.optics.tracer.HitKind` of each end.
        on_box: ``(N,)`` bool: the end lies on the box of unobserved space.
        sides: require the re-cast to reach the side of the depth mesh the ray arrived on.

    Returns:
        ``(N,)`` bool (False for an end at the centre itself).
    """
    c = np.asarray(center, np.float64).reshape(3)
    p = np.asarray(points, np.float64)
    out = np.ones(len(p), bool)
    finite = np.isfinite(p).all(axis=1)
    far = finite & (np.linalg.norm(np.where(finite[:, None], p, 0.0), axis=1) > POINT_AT_INFINITY / 10)
    near = np.flatnonzero(finite & ~far)
    if len(near):
        out[near] = _near_ends_seen(tracer, c, p[near], np.asarray(origins)[near], kind[near], on_box[near], sides)
    idx = np.flatnonzero(far)
    if len(idx):
        d = p[idx] - c
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        h = tracer.cast_background(np.broadcast_to(c, d.shape), d)
        if at_inf is not None:
            at_inf.resolve(h.kind, h.point, d, h.on_box)
        reach = np.linalg.norm(np.nan_to_num(h.point), axis=1) > POINT_AT_INFINITY / 10
        out[idx] = (h.kind == HitKind.OBSERVED) & reach
    return out


def _near_ends_seen(
    tracer: SceneTracer,
    c: np.ndarray,
    p: np.ndarray,
    o: np.ndarray,
    kind: np.ndarray,
    on_box: np.ndarray,
    sides: bool,
) -> np.ndarray:
    """:func:`ray_ends_seen` for finite, near ends ``p`` (``(N, 3)``; origins ``o``)."""
    v = p - c
    r = np.linalg.norm(v, axis=1)
    ok = r > 0
    d = np.where(ok[:, None], v / np.where(ok, r, 1.0)[:, None], 0.0)
    h = tracer.cast_background(np.broadcast_to(c, d.shape), d)
    cos = np.einsum("ij,ij->i", h.normal, d)
    tol = occlusion_tolerance(c, o, p, cos)
    seen = ok & (h.t >= r - tol)
    if sides:
        at_point = seen & (h.t <= r + tol) & ~h.on_box & ~on_box
        arrived_front = kind == HitKind.OBSERVED
        recast_front = h.kind == HitKind.OBSERVED
        seen &= ~at_point | (arrived_front == recast_front)
    return seen
