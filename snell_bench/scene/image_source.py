"""Turning a user's photo or RGB-D frame into the arrays of the pipeline.

Convention (that of :mod:`snell_bench.scene.camera`):
    - Image: float32 ``(H, W, 3)`` sRGB in ``[0, 1]``.
    - Depth: float32 ``(H, W)``, the camera-frame z in metres (not the distance along the ray);
      missing depth is NaN. Sensor frames miss a fifth to a third of their pixels: that is normal and
      never an error (the depth mesh treats NaN as unobserved).
    - Camera: :class:`~snell_bench.scene.camera.Camera`, ``K`` in pixels of the image as loaded,
      integer pixel coordinates at pixel centres.

Error messages name the configuration key to change (``scene.image``, ``scene.depth``,
``scene.depth_scale``, ``scene.depth_kind``, ``scene.intrinsics``, ``scene.fov_deg``), what was wrong
and how to fix it. A photo, a depth file or a setting that cannot be used raises
:class:`~snell_bench.config.errors.ConfigError` (a ``ValueError``: one line, which the command line
prints without a traceback), a missing file ``FileNotFoundError``; a depth format whose reader is
not installed (OpenEXR) raises ``ImportError``.

Depth formats (by file suffix, case-insensitive):
    - ``.png``, ``.pgm``: integer (8- or 16-bit) via Pillow; ``scale`` required.
    - ``.tif``, ``.tiff``: integer or float via tifffile (Pillow where tifffile is missing).
    - ``.npy``: numpy, float (metres) or integer (``scale`` required).
    - ``.pfm``: read with numpy (the sign of the scale line gives the byte order; rows are stored
      bottom to top).
    - ``.exr``: the OpenEXR package (``pip install OpenEXR``), an optional dependency.

``scale`` is in file units per metre (depth in metres = value / scale): 5000 for the TUM RGB-D
benchmark, 1000 for millimetres. Integer files need it; float files default to metres (scale 1).

Depth values that contradict ``scale`` are refused, naming ``scene.depth_scale`` and what to set
(:func:`depth_from_raw`): an 8-bit integer file (256 levels: a picture of depth, not a
measurement), a scale below 1 for an integer file (metres per unit instead of units per metre),
and a depth that is implausible in metres once scaled: all of it nearer than
:data:`NEAREST_SCENE_M` or most of it (the median) farther than :data:`FARTHEST_MEDIAN_M`, e.g. a
float file in metres given the scale of an integer one.

Orientation and size (:func:`load_frame`, :func:`load_photo`):
    - A photo with an EXIF orientation tag is turned upright, as viewers show it
      (:func:`load_image`); its depth (and its mask) must be in that upright orientation. The
      intrinsics ``[fx, fy, cx, cy]`` are in pixels of the file as stored (as a calibration gives
      them) and are turned with the photo (:func:`orient_intrinsics`); ``fov_deg`` is the
      horizontal field of view of the upright photo. A depth whose shape does not match the upright
      photo is an error that names the EXIF rotation.
    - ``max_side`` resizes the photo so that its longer side is at most that many pixels
      (:func:`max_side_size`): the image with Lanczos, the depth by nearest neighbour, ``K`` scaled
      (:func:`fit_to_block` with ``mode="resize"``), before the image is fitted to the generator's
      block. What was done is recorded in ``RGBDFrame.info`` (:func:`photo_info`).

This module assembles a frame (:func:`load_frame`, :func:`load_photo`, :func:`inspect_photo`) and
re-exports the parts it is made of, each importable from here: the photo file and its EXIF
orientation (:mod:`snell_bench.scene.photo_file`), its camera
(:mod:`snell_bench.scene.photo_camera`), its depth values (:mod:`snell_bench.scene.depth_values`;
the file readers: :mod:`snell_bench.scene.depth_files`) and its size
(:mod:`snell_bench.scene.photo_size`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from snell_bench.config.errors import ConfigError
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_files import DEPTH_SUFFIXES, PathLike, read_depth_file, read_pfm
from snell_bench.scene.depth_values import (
    DEPTH_KINDS,
    FARTHEST_MEDIAN_M,
    NEAREST_SCENE_M,
    _check_depth_args,
    depth_from_raw,
    load_depth,
)
from snell_bench.scene.photo_camera import camera_from, photo_camera
from snell_bench.scene.photo_file import (
    EXIF_ORIENTATION,
    PhotoHeader,
    _existing_file,
    load_image,
    orient_intrinsics,
    read_photo_header,
)
from snell_bench.scene.photo_size import _resize_image, fit_to_block, max_side_size

log = logging.getLogger(__name__)
T = TypeVar("T")

__all__ = [
    "DEPTH_KINDS",
    "DEPTH_SUFFIXES",
    "EXIF_ORIENTATION",
    "FARTHEST_MEDIAN_M",
    "NEAREST_SCENE_M",
    "PhotoHeader",
    "RGBDFrame",
    "camera_from",
    "depth_from_raw",
    "fit_to_block",
    "inspect_photo",
    "load_depth",
    "load_frame",
    "load_image",
    "load_photo",
    "max_side_size",
    "orient_intrinsics",
    "photo_camera",
    "photo_info",
    "read_pfm",
    "read_photo_header",
]


def _refusing(call: Callable[..., T], *args, **kwargs) -> T:
    """``call(*args, **kwargs)``, a check of the photo's file or size (:func:`read_photo_header`,
    :func:`load_image`, :func:`max_side_size`) whose ``ValueError`` (one line naming the key and
    the fix) is raised as :class:`~snell_bench.config.errors.ConfigError`."""
    try:
        return call(*args, **kwargs)
    except ConfigError:
        raise
    except ValueError as e:
        raise ConfigError([str(e)]) from e


# ---------------------------------------------------------------------------------------------- frame
@dataclass(frozen=True, eq=False)
class RGBDFrame:
    """A photo, its depth (or ``None``, for a depth estimator to fill) and its camera.

    Attributes:
        image: float32 ``(H, W, 3)`` sRGB in ``[0, 1]``.
        depth: float32 ``(H, W)`` z-depth in metres, NaN where missing; or ``None``.
        camera: the :class:`Camera` of ``image``.
        info: what was done to the photo (:func:`photo_info`); empty when not loaded from a file.
    """

    image: np.ndarray
    depth: np.ndarray | None
    camera: Camera
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if np.ndim(self.image) != 3 or np.shape(self.image)[:2] != self.camera.shape or np.shape(self.image)[2] != 3:
            raise ValueError(f"image has shape {np.shape(self.image)}; the camera needs {self.camera.shape + (3,)}")
        if self.depth is not None and np.shape(self.depth) != self.camera.shape:
            raise ValueError(f"depth has shape {np.shape(self.depth)}; the camera needs {self.camera.shape}")


def photo_info(header: PhotoHeader, max_side: int | None, resized: tuple[int, int], size: tuple[int, int]) -> dict:
    """What a cell records about its photo (``scene_info`` of its ``metrics.json``).

    Args:
        header: the photo's header.
        max_side: ``scene.max_side``.
        resized: ``(width, height)`` after :func:`max_side_size` (the upright size when not resized).
        size: ``(width, height)`` used, after fitting to the generator's block.

    Returns:
        ``{"original_size": [W, H] (as stored), "exif_orientation": n, "max_side": max_side,
        "resized_to": [w, h] or None, "size": [w, h]}``.

    Examples:
        >>> photo_info(PhotoHeader(4000, 3000), 1024, (1024, 768), (1024, 768))
        {'original_size': [4000, 3000], 'exif_orientation': 1, 'max_side': 1024, 'resized_to': [1024, 768], 'size': [1024, 768]}
    """
    return {
        "original_size": [int(header.width), int(header.height)],
        "exif_orientation": int(header.orientation),
        "max_side": None if max_side is None else int(max_side),
        "resized_to": None if tuple(resized) == header.upright_size else [int(v) for v in resized],
        "size": [int(v) for v in size],
    }


def _log_orientation(header: PhotoHeader, path: PathLike, with_depth: bool) -> None:
    if header.orientation == 1:
        return
    if with_depth:
        log.warning("scene.image='%s': %s; its depth must be in that upright orientation too", path, header.rotation())
    else:
        log.info("scene.image='%s': %s", path, header.rotation())


def load_photo(
    image: PathLike,
    *,
    intrinsics: Sequence[float] | None = None,
    fov_deg: float | None = None,
    max_side: int | None = None,
    block: int = 1,
) -> tuple[np.ndarray, Camera | None, PhotoHeader]:
    """A photo without a depth file (for a depth estimator): upright, resized for ``max_side``.

    Args:
        image: ``scene.image``.
        intrinsics: ``scene.intrinsics`` (pixels of the file as stored), or ``None``.
        fov_deg: ``scene.fov_deg`` (of the upright photo), or ``None``.
        max_side: ``scene.max_side`` (:func:`max_side_size`).
        block: the generator's block, which both sides must keep.

    Returns:
        ``(image, camera, header)``: the float32 ``(H, W, 3)`` image, its camera (``None`` when
        neither ``intrinsics`` nor ``fov_deg`` is given: the estimator's), the file's header.

    Raises:
        FileNotFoundError: no file at ``image``.
        ConfigError: a photo or setting refused by :func:`load_image`, :func:`photo_camera` or
            :func:`max_side_size`.
    """
    header = _refusing(read_photo_header, image)
    camera = (
        None if intrinsics is None and fov_deg is None else photo_camera(header, intrinsics=intrinsics, fov_deg=fov_deg)
    )
    img = _refusing(load_image, image)
    _log_orientation(header, image, False)
    size = _refusing(max_side_size, img.shape[1], img.shape[0], max_side, block=block)
    if size != (img.shape[1], img.shape[0]):
        if camera is not None:
            img, _, camera = fit_to_block(img, None, camera, 1, mode="resize", size=size)
        else:
            img = _resize_image(img, size)
        log.info("scene.image='%s' resized to %dx%d (scene.max_side=%d)", image, size[0], size[1], max_side)
    return img, camera, header


def inspect_photo(
    image: PathLike,
    depth: PathLike | None = None,
    *,
    depth_scale: float | None = None,
    depth_kind: str = "z",
    intrinsics: Sequence[float] | None = None,
    fov_deg: float | None = None,
    block: int | None = 16,
    max_side: int | None = None,
) -> dict:
    """What :func:`load_frame` will make of a photo, found before any work: the photo's header only
    (no pixel decoded), the camera, and the depth file's values (read, checked, not kept).

    It raises what :func:`load_frame` would raise for the photo's header, the camera and the
    depth's values and shape; a file that cannot be read at all is left for :func:`load_frame`
    (the depth part is skipped).

    Args:
        image: as :func:`load_frame`.
        depth: as :func:`load_frame`.
        depth_scale: as :func:`load_frame`.
        depth_kind: as :func:`load_frame`.
        intrinsics: as :func:`load_frame`.
        fov_deg: as :func:`load_frame`.
        block: as :func:`load_frame`.
        max_side: as :func:`load_frame`.

    Returns:
        :func:`photo_info` of the photo, ``size`` being the size :func:`load_frame` gives, and
        ``"fx"``: the horizontal focal length in pixels of that size (``None`` without intrinsics
        or field of view).

    Raises:
        FileNotFoundError: see :func:`load_frame`.
        ConfigError: see :func:`load_frame`; also a photo smaller than one ``block``.
    """
    header = _refusing(read_photo_header, image)
    w0, h0 = header.upright_size
    camera = None
    if depth is not None or intrinsics is not None or fov_deg is not None:
        camera = photo_camera(header, intrinsics=intrinsics, fov_deg=fov_deg)
    if depth is not None:
        _check_depth_args(depth_scale, depth_kind, camera)
        p = _existing_file(depth, "scene.depth", f"a depth file ({', '.join(DEPTH_SUFFIXES)})")
        try:
            raw = read_depth_file(p, depth, "scene.depth")
        except (ValueError, OSError, ImportError) as e:  # unreadable: load_frame reports it in its cell
            log.debug("not checking scene.depth='%s' before the run: %s", depth, e)
        else:
            depth_from_raw(raw, depth, scale=depth_scale, kind=depth_kind, camera=camera, photo=header)
    size = _refusing(max_side_size, w0, h0, max_side, block=block or 1)
    w, h = size
    if block is not None and block > 1:
        if w < block or h < block:
            raise ConfigError(
                [
                    f"scene.image='{image}' is {w}x{h} pixels, smaller than one {block}x{block} block of the "
                    f"generator (model.multiple={block}); set scene.image to a photo of at least {block}x{block} "
                    "pixels (a few hundred a side, e.g. 640x480)"
                ]
            )
        w, h = w - w % block, h - h % block
    info = photo_info(header, max_side, size, (w, h))
    info["fx"] = None if camera is None else float(camera.K[0, 0]) * size[0] / w0
    return info


def load_frame(
    image: PathLike,
    depth: PathLike | None = None,
    *,
    depth_scale: float | None = None,
    depth_kind: str = "z",
    intrinsics: Sequence[float] | None = None,
    fov_deg: float | None = None,
    block: int | None = 16,
    size: tuple[int, int] | None = None,
    max_side: int | None = None,
) -> RGBDFrame:
    """Load a photo (and its depth), resize it for ``max_side`` and fit it to a generator's block.

    In order: :func:`read_photo_header` and :func:`load_image` (turned upright by its EXIF
    orientation), :func:`photo_camera` (the intrinsics are in pixels of the file as stored, turned
    with it), :func:`load_depth` (the size of the upright image), the resize to
    :func:`max_side_size` (:func:`fit_to_block` with ``mode="resize"``), :func:`fit_to_block`
    (center crop; ``size`` resizes instead).

    Args:
        image: ``scene.image``, the photo (PNG or JPEG).
        depth: ``scene.depth``, its registered depth file, or ``None`` (``RGBDFrame.depth`` is then ``None``).
        depth_scale: ``scene.depth_scale``, file units per metre (required for integer depth files).
        depth_kind: ``scene.depth_kind``, ``"z"`` or ``"range"``.
        intrinsics: ``scene.intrinsics``, ``[fx, fy, cx, cy]`` in pixels of the file as stored.
        fov_deg: ``scene.fov_deg``, the horizontal field of view (when the intrinsics are unknown).
        block: width and height become multiples of it; ``None`` or 1 keeps the size.
        size: ``(width, height)``, multiples of ``block``: resize to it instead of cropping.
        max_side: ``scene.max_side``: first resize so that the longer side is at most this.

    Returns:
        The :class:`RGBDFrame`; its ``info`` is :func:`photo_info`.

    Raises:
        FileNotFoundError, ImportError: see :func:`load_image` and :func:`load_depth`.
        ConfigError: a photo, depth file or setting refused by :func:`load_image`,
            :func:`load_depth`, :func:`photo_camera` or :func:`max_side_size`.
        ValueError: a photo smaller than one ``block`` (:func:`fit_to_block`).
    """
    header = _refusing(read_photo_header, image)
    cam = photo_camera(header, intrinsics=intrinsics, fov_deg=fov_deg)
    img = _refusing(load_image, image)
    _log_orientation(header, image, depth is not None)
    dep = None if depth is None else load_depth(depth, scale=depth_scale, kind=depth_kind, camera=cam, photo=header)
    resized = _refusing(max_side_size, cam.width, cam.height, max_side, block=block or 1)
    if resized != (cam.width, cam.height):
        img, dep, cam = fit_to_block(img, dep, cam, 1, mode="resize", size=resized)
        log.info("scene.image='%s' resized to %dx%d (scene.max_side=%d)", image, resized[0], resized[1], max_side)
    if size is not None:
        img, dep, cam = fit_to_block(img, dep, cam, block or 1, mode="resize", size=size)
    elif block is not None:
        img, dep, cam = fit_to_block(img, dep, cam, block)
    return RGBDFrame(
        image=img, depth=dep, camera=cam, info=photo_info(header, max_side, resized, (cam.width, cam.height))
    )
