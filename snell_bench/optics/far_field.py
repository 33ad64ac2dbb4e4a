"""Far background at infinity: which background pixels may be replaced by a surface at infinity,
and how rays that leave the scene's geometry then end on them.

Convention:
    A background pixel whose depth is so large that replacing its surface by a surface at infinity
    moves *any* warp that could land on it by less than a tolerance (in pixels; the bound of
    :func:`far_background_mask`) is left out of the background mesh. A ray that leaves the scene's
    geometry (it ends on the bounding box of unobserved space, or on nothing) then sees the pixel
    its *direction* projects to, if that pixel is such a far one (:class:`AtInfinity`). Rays need
    no intersection with the far surface, and an estimated depth of the sky or the horizon (often
    unreliable) no longer matters.

    Points at infinity are stored as ``direction / |direction| * 1e12`` (camera frame), so that every
    later projection of the point (perspective or panorama) uses its direction.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import minimum_filter

from snell_bench.optics.tracer import HitKind
from snell_bench.scene.camera import Camera

__all__ = ["far_background_mask", "AtInfinity", "POINT_AT_INFINITY"]

#: Distance (camera-frame units) at which points at infinity are stored.
POINT_AT_INFINITY = 1e12


def far_background_mask(
    depth: np.ndarray,
    camera: Camera,
    center: np.ndarray,
    radius: float,
    tolerance_px: float,
    pano_height: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Background pixels that may be treated as at infinity, and the bound behind the decision.

    A ray leaving a point ``p`` of the object's bounding ball ``|p - c| <= r`` with direction ``d``
    ends on the background at ``q = p + t d``; at infinity it would be seen at the pixel ``u`` that
    ``d`` projects to. With ``u'`` the normalised coordinates of ``u`` (``d ∝ (u'_x, u'_y, 1)``), the
    exact pixel is ``u + f (p_xy - p_z u') / q_z``, so the error is at most
    ``f (|c_xy - c_z u'| + r sqrt(1 + |u'|²)) / q_z`` (``f`` the larger focal length). ``q_z`` is
    bounded below by the smallest depth around the pixel (3 x 3, the border pixels repeated). The
    panorama's straight rays start at ``c`` (covered by the same bound); its angular coordinates of
    a refracted ray move by at most ``r / (|q| - |c|)`` radians, ``pano_height / π`` pixels per
    radian.

    Args:
        depth: ``(H, W)`` z-depth of the camera's image (NaN, inf or <= 0 where unknown).
        camera: the camera of ``depth``.
        center: ``(3,)`` centre ``c`` of the object's bounding ball (camera frame).
        radius: radius ``r`` of that ball.
        tolerance_px: largest allowed warp error in pixels (finite, > 0).
        pano_height: height of the panorama whose warps the bound must also cover; ``None`` covers
            the perspective warps only.

    Returns:
        ``(far (H, W) bool, bound_px (H, W) float64)``: ``far`` where the bound is below
        ``tolerance_px``; invalid depth is never far (it stays a hole) and has an infinite bound.

    Raises:
        ValueError: ``tolerance_px`` is not a finite positive number.

    Examples:
        >>> cam = Camera.from_fov(8, 6, 60.0)
        >>> depth = np.full(cam.shape, 1000.0)
        >>> depth[0, 0] = np.nan
        >>> far, bound = far_background_mask(depth, cam, np.array([0.0, 0.0, 3.0]), 0.5, 1.0)
        >>> int(far.sum()), bool(far[0, 0])
        (47, False)
        >>> round(float(bound[3, 4]), 4)
        0.0056
    """
    if not (tolerance_px > 0) or not np.isfinite(tolerance_px):
        raise ValueError(
            f"infinity_tolerance_px must be a positive number of pixels, got {tolerance_px!r}; "
            "use null to keep the exact geometry"
        )
    depth = np.asarray(depth, np.float64)
    valid = np.isfinite(depth) & (depth > 0)
    z = np.where(valid, depth, np.inf)
    zmin = minimum_filter(z, size=3, mode="nearest")  # "nearest" repeats the border pixels
    c = np.asarray(center, np.float64)
    un = camera.pixel_rays(normalize=False)[..., :2]  # (H, W, 2): u'
    f = float(max(camera.K[0, 0], camera.K[1, 1]))
    lateral = np.linalg.norm(c[:2] - c[2] * un, axis=-1) + radius * np.sqrt(1.0 + (un**2).sum(-1))
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = f * lateral / zmin
        if pano_height is not None:
            dist = zmin * np.sqrt(1.0 + (un**2).sum(-1)) - float(np.linalg.norm(c))
            bound = np.maximum(bound, np.where(dist > 0, pano_height / np.pi * radius / dist, np.inf))
    bound = np.where(valid & np.isfinite(zmin), bound, np.inf)
    return valid & (bound < tolerance_px), bound


class AtInfinity:
    """Resolves rays that leave the scene's geometry towards far background at infinity.

    Args:
        camera: the camera of the image whose pixels ``far`` marks.
        far: ``(H, W)`` bool far pixels (:func:`far_background_mask`).

    Examples:
        >>> cam = Camera.from_fov(8, 6, 60.0)
        >>> at_inf = AtInfinity(cam, np.ones(cam.shape, bool))
        >>> kind = np.array([HitKind.ESCAPED], np.int8)
        >>> point = np.full((1, 3), np.nan)
        >>> at_inf.resolve(kind, point, np.array([[0.0, 0.0, 2.0]]), np.zeros(1, bool))
        >>> HitKind(int(kind[0])).name, point[0].tolist()
        ('OBSERVED', [0.0, 0.0, 1000000000000.0])
    """

    def __init__(self, camera: Camera, far: np.ndarray) -> None:
        self.camera = camera
        self.far = far.reshape(-1)

    def resolve(self, kind: np.ndarray, point: np.ndarray, direction: np.ndarray, on_box: np.ndarray) -> None:
        """Turn rays that end on far background at infinity into observed hits, in place.

        A ray that ends on the bounding box or nowhere (``ESCAPED``), and whose direction projects
        onto a far pixel (the nearest pixel centre), becomes ``OBSERVED`` at that pixel's point at
        infinity: its ``point`` is set to ``direction / |direction| * 1e12``.

        Args:
            kind: ``(N,)`` int8 :class:`~snell_bench.optics.tracer.HitKind` of each ray's end
                (updated in place).
            point: ``(N, 3)`` end points, NaN where none (updated in place).
            direction: ``(N, 3)`` directions of the rays (any length > 0).
            on_box: ``(N,)`` bool: the ray ends on the box of unobserved space.
        """
        idx = np.flatnonzero(on_box | (kind == HitKind.ESCAPED))
        if not len(idx):
            return
        d = np.asarray(direction[idx], np.float64)
        pix, z = self.camera.project(np.where(np.isfinite(d), d, 0.0))
        ok = (z > 0) & self.camera.in_view(pix)
        idx, pix, d = idx[ok], pix[ok], d[ok]
        W, H = self.camera.width, self.camera.height
        near = np.rint(pix).astype(np.int64)
        near[:, 0] = near[:, 0].clip(0, W - 1)
        near[:, 1] = near[:, 1].clip(0, H - 1)
        is_far = self.far[near[:, 1] * W + near[:, 0]]
        idx, d = idx[is_far], d[is_far]
        kind[idx] = HitKind.OBSERVED
        point[idx] = d / np.linalg.norm(d, axis=1, keepdims=True) * POINT_AT_INFINITY
