"""The camera of a photo: from its intrinsics or field of view (:func:`camera_from`), and of the
upright photo a file's EXIF orientation shows (:func:`photo_camera`).

Convention: a :class:`~snell_bench.scene.camera.Camera`, ``K`` in pixels of the image,
integer pixel coordinates at pixel centres (OpenCV); intrinsics ``[fx, fy, cx, cy]``; a field of
view is horizontal, in degrees. Error messages name ``scene.intrinsics`` or ``scene.fov_deg``; a
setting that no camera fits raises :class:`~snell_bench.config.errors.ConfigError` (a ``ValueError``),
one line that the command line prints without a traceback.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from snell_bench.config.errors import ConfigError
from snell_bench.scene.camera import Camera
from snell_bench.scene.photo_file import PhotoHeader, orient_intrinsics

__all__ = ["camera_from", "photo_camera"]


def camera_from(
    width: int, height: int, *, intrinsics: Sequence[float] | None = None, fov_deg: float | None = None
) -> Camera:
    """The camera of a ``width x height`` image from its intrinsics or its horizontal field of view.

    Args:
        width: image width in pixels.
        height: image height in pixels.
        intrinsics: ``[fx, fy, cx, cy]`` in pixels of this image (OpenCV: integer coordinates at
            pixel centres, so the centre of a 640-wide image is cx = 319.5); fx and fy may differ.
        fov_deg: the horizontal field of view in degrees, in (0, 180): square pixels, principal
            point at the image centre (:meth:`Camera.from_fov`).

    Returns:
        The :class:`Camera`.

    Raises:
        ValueError: a width or height that is not a positive integer.
        ConfigError: neither or both given; intrinsics not four finite numbers, a focal length <= 0,
            or a principal point outside the image (``scene.intrinsics``); a field of view outside
            (0, 180) (``scene.fov_deg``).

    Examples:
        >>> camera_from(640, 480, intrinsics=[520.9, 521.0, 325.1, 249.7])
        Camera(width=640, height=480, fx=520.900, fy=521.000, cx=325.100, cy=249.700)
        >>> round(float(camera_from(640, 480, fov_deg=60.0).K[0, 0]), 3)
        554.256
    """
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or int(v) != v or v < 1:
            raise ValueError(f"the image {name} must be a positive integer, got {v!r}")
    width, height = int(width), int(height)
    if (intrinsics is None) == (fov_deg is None):
        got = "both" if intrinsics is not None else "neither"
        raise ConfigError(
            [
                f"set exactly one of scene.intrinsics ([fx, fy, cx, cy] in pixels) and scene.fov_deg (the horizontal "
                f"field of view in degrees); got {got}"
            ]
        )
    if fov_deg is not None:
        try:
            fov = float(fov_deg)
        except (TypeError, ValueError):
            fov = math.nan
        if isinstance(fov_deg, bool) or not (0.0 < fov < 180.0):
            raise ConfigError([f"scene.fov_deg={fov_deg!r} must be a horizontal field of view in degrees in (0, 180)"])
        return Camera.from_fov(width, height, fov)

    hint = "set scene.intrinsics=[fx, fy, cx, cy] (pixels; from a 3x3 K: [K00, K11, K02, K12])"
    if isinstance(intrinsics, str | bytes) or not isinstance(intrinsics, Sequence | np.ndarray):
        raise ConfigError([f"scene.intrinsics={intrinsics!r} is not a list of four numbers; {hint}"])
    vals = (
        list(np.asarray(intrinsics, dtype=object).reshape(-1))
        if isinstance(intrinsics, np.ndarray)
        else list(intrinsics)
    )
    if len(vals) != 4:
        raise ConfigError([f"scene.intrinsics={vals!r} has {len(vals)} values, not 4; {hint}"])
    try:
        if any(isinstance(v, bool | str | bytes) for v in vals):
            raise TypeError
        fx, fy, cx, cy = (float(v) for v in vals)
    except (TypeError, ValueError):
        raise ConfigError([f"scene.intrinsics={vals!r} holds values that are not numbers; {hint}"]) from None
    if not all(math.isfinite(v) for v in (fx, fy, cx, cy)):
        raise ConfigError([f"scene.intrinsics={vals!r} must be finite numbers (no NaN or inf); {hint}"])
    if fx <= 0 or fy <= 0:
        raise ConfigError([f"scene.intrinsics: the focal lengths fx={fx}, fy={fy} must be > 0 (pixels); {hint}"])
    if not (-0.5 <= cx <= width - 0.5 and -0.5 <= cy <= height - 0.5):
        raise ConfigError(
            [
                f"scene.intrinsics: the principal point (cx, cy) = ({cx}, {cy}) is outside the {width}x{height} image "
                f"(x in [-0.5, {width - 0.5}], y in [-0.5, {height - 0.5}]); the intrinsics must be in pixels of this "
                "image: scale them if they were calibrated at another resolution"
            ]
        )
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return Camera(K=K, width=width, height=height)


def photo_camera(
    header: PhotoHeader, *, intrinsics: Sequence[float] | None = None, fov_deg: float | None = None
) -> Camera:
    """The camera of the upright photo of ``header``.

    ``intrinsics`` are in pixels of the file as stored: checked against the stored size
    (:func:`camera_from`), then turned with the photo (:func:`orient_intrinsics`). ``fov_deg`` is the
    horizontal field of view of the upright photo.

    Args:
        header: the photo's :class:`PhotoHeader`.
        intrinsics: ``scene.intrinsics``, ``[fx, fy, cx, cy]``.
        fov_deg: ``scene.fov_deg``.

    Returns:
        The :class:`Camera` of the upright photo.

    Raises:
        ConfigError: as :func:`camera_from` (the message says when the photo was turned by EXIF).
    """
    if intrinsics is None or fov_deg is not None:
        w, h = header.upright_size
        return camera_from(w, h, intrinsics=intrinsics, fov_deg=fov_deg)
    try:
        camera_from(header.width, header.height, intrinsics=intrinsics)
    except ConfigError as e:
        if header.orientation == 1:
            raise
        raise ConfigError(
            [
                f"{e} (scene.intrinsics are in pixels of the file as stored, {header.width}x{header.height}; "
                f"{header.rotation()})"
            ]
        ) from None
    w, h = header.upright_size
    k = orient_intrinsics(intrinsics, header.width, header.height, header.orientation)
    return camera_from(w, h, intrinsics=k)
