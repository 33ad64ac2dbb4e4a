"""Where the panorama sits and how perspective maps address their source: the choices on which the
paper's text and the authors' code differ (``warps.pano_center``, ``warps.pano_axes``,
``warps.half_pixel_shift``).

Convention:
    Camera frame (OpenCV: x right, y down, z forward); pixel coordinates with integer values at
    pixel centres (:mod:`snell_bench.scene.camera`); the panorama of
    :class:`~snell_bench.imaging.PanoramaCamera`.
"""

from __future__ import annotations

import numpy as np

from snell_bench.imaging.equirect import PanoramaCamera
from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject

__all__ = ["PANO_CENTERS", "PANO_AXES", "PERSPECTIVE_MAPS", "panorama_pose", "shift_half_pixel"]

#: ``warps.pano_center``: the bounding box's centre, or the surface's area-weighted centroid.
PANO_CENTERS = ("bbox", "centroid")
#: ``warps.pano_axes``: gravity-level, or the camera's own axes.
PANO_AXES = ("level", "camera")
#: The flat ``(H * W, 2)`` / ``(Hp * Wp, 2)`` maps whose source is a perspective image (I⁻), and
#: the masks that go with them.
PERSPECTIVE_MAPS = (
    ("refraction", "refraction_valid"),
    ("reflection", "reflection_valid"),
    ("pano_to_persp", "pano_to_persp_valid"),
)


def panorama_pose(
    obj: GlassObject, up: np.ndarray, height: int, center: str = "bbox", axes: str = "level"
) -> PanoramaCamera:
    """The panorama camera at the object.

    Args:
        obj: the placed object (camera frame).
        up: ``(3,)`` unit up direction of the scene (camera frame).
        height: panorama height.
        center: ``bbox`` (:attr:`GlassObject.center`, the bounding box's centre) or ``centroid``
            (trimesh's ``Trimesh.centroid``: the mean of the triangles' centres weighted by their
            areas, a point of the surface's distribution, not of the solid's volume; the authors'
            code centres its panorama there).
        axes: ``level`` (gravity-aligned: top row along ``up``, centre column along the camera's
            forward made horizontal; :meth:`PanoramaCamera.level`) or ``camera`` (the panorama frame
            is the camera frame: its centre column looks along the camera's +z, its top row along
            the camera's -y, whatever the camera's tilt; the authors' code).

    Returns:
        The :class:`~snell_bench.imaging.PanoramaCamera`.

    Raises:
        ValueError: an unknown ``center`` or ``axes``.

    Examples:
        >>> import trimesh
        >>> box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
        >>> _ = box.apply_translation((0.0, 0.0, 3.0))
        >>> obj = GlassObject.from_mesh(box.vertices, box.faces)
        >>> tilted = np.array([0.0, -np.cos(0.3), -np.sin(0.3)])
        >>> panorama_pose(obj, tilted, 8, axes="camera").rotation.tolist() == np.eye(3).tolist()
        True
        >>> [round(float(x), 4) for x in -panorama_pose(obj, tilted, 8).rotation[:, 1]]  # top row looks up
        [0.0, -0.9553, -0.2955]
    """
    if center not in PANO_CENTERS:
        raise ValueError(f"warps.pano_center={center!r} is unknown; use one of {list(PANO_CENTERS)}")
    if axes not in PANO_AXES:
        raise ValueError(f"warps.pano_axes={axes!r} is unknown; use one of {list(PANO_AXES)}")
    c = np.asarray(obj.mesh.centroid if center == "centroid" else obj.center, np.float64)
    if axes == "camera":
        return PanoramaCamera(center=c, rotation=np.eye(3), height=height)
    return PanoramaCamera.level(c, up, (0.0, 0.0, 1.0), height)


def shift_half_pixel(arrays: dict[str, np.ndarray], camera: Camera, object_mask: np.ndarray) -> dict[str, np.ndarray]:
    """Shift every perspective map by +0.5 px, as the authors' maps are read.

    Their maps store a point's pixel in pixel-edge coordinates (``x = (x_ndc + 1) W / 2``, pixel ``i``
    spanning ``[i, i + 1)``, its centre at ``i + 0.5``), and ``grid_sample(..., align_corners=True)``
    reads coordinate ``x`` at ``x / (W - 1)`` of the way from the first pixel's centre to the last's,
    i.e. at pixel-centre coordinate ``x``: the point at pixel-centre coordinate ``x_c`` is sampled at
    ``x_c + 0.5`` (and ``y_c + 0.5``). They keep a point only where ``0 <= x < W - 1`` and
    ``0 <= y < H - 1`` (in those coordinates); outside the object their perspective image is used
    as it is (the identity is not shifted).

    Args:
        arrays: flat warps as :func:`~snell_bench.optics.warps.compute_warps` gathers them; the maps
            of :data:`PERSPECTIVE_MAPS` present are replaced (float32 ``(N, 2)``, NaN where invalid)
            with their masks.
        camera: the perspective camera (the maps' source).
        object_mask: ``(H * W,)`` bool object pixels (``refraction`` is shifted there only).

    Returns:
        The shifted maps and masks (new arrays; ``arrays`` is not changed).

    Examples:
        >>> cam = Camera.from_fov(4, 3, 60.0)
        >>> m = np.array([[0.0, 0.0], [2.4, 1.0], [2.6, 1.0]], np.float32)
        >>> out = shift_half_pixel({"pano_to_persp": m, "pano_to_persp_valid": np.ones(3, bool)}, cam, None)
        >>> out["pano_to_persp"].tolist()[:2], out["pano_to_persp_valid"].tolist()
        ([[0.5, 0.5], [2.9000000953674316, 1.5]], [True, True, False])
    """
    W, H = camera.width, camera.height
    out = {}
    for name, valid_name in PERSPECTIVE_MAPS:
        if name not in arrays:
            continue
        m = np.asarray(arrays[name], np.float32)
        rows = np.ones(len(m), bool) if name != "refraction" else np.asarray(object_mask, bool)
        shifted = m + np.float32(0.5)
        with np.errstate(invalid="ignore"):
            inside = (shifted[:, 0] >= 0) & (shifted[:, 0] < W - 1) & (shifted[:, 1] >= 0) & (shifted[:, 1] < H - 1)
        valid = np.asarray(arrays[valid_name], bool).copy()
        valid[rows] &= inside[rows]
        new = m.copy()
        new[rows] = np.where(valid[rows, None], shifted[rows], np.nan)
        out[name], out[valid_name] = new, valid
    return out
