"""The size a photo is used at: :func:`max_side_size` (``scene.max_side``) and
:func:`fit_to_block` (a generator's block), the camera following the pixels.

Convention: images ``(H, W, C)`` float (sRGB in ``[0, 1]``), depth ``(H, W)`` z in metres (NaN
where missing), sizes ``(width, height)`` in pixels; ``K`` follows the pixel-centre convention of
:meth:`~snell_bench.scene.camera.Camera.scaled`, so a 3-D point projects onto the same image
content before and after a crop or resize.
"""

from __future__ import annotations

import math

import numpy as np
from PIL import Image

from snell_bench.scene.camera import Camera

__all__ = ["fit_to_block", "max_side_size"]


def max_side_size(width: int, height: int, max_side: int | None, *, block: int = 1) -> tuple[int, int]:
    """The size a ``width x height`` photo is resized to for ``scene.max_side``.

    The longer side becomes ``max_side`` and the other keeps the aspect ratio (rounded to the
    nearest pixel); a photo already within ``max_side`` (or ``max_side=None``) keeps its size.

    Args:
        width: the photo's width.
        height: its height.
        max_side: ``scene.max_side``, or ``None``.
        block: the generator's block (``model.multiple``): both sides must keep at least one block.

    Returns:
        ``(width, height)`` after the resize.

    Raises:
        ValueError: ``max_side`` is not a positive integer, or leaves a side shorter than ``block``.

    Examples:
        >>> max_side_size(4000, 3000, 1024)
        (1024, 768)
        >>> max_side_size(640, 480, 1024)
        (640, 480)
    """
    if max_side is None:
        return int(width), int(height)
    if isinstance(max_side, bool) or not isinstance(max_side, int | np.integer) or max_side < 1:
        raise ValueError(
            f"scene.max_side={max_side!r} must be a positive whole number of pixels (the photo's longer side "
            "after resizing), e.g. scene.max_side=1024, or null to keep the photo's size"
        )
    longer = max(width, height)
    if longer <= max_side:
        return int(width), int(height)
    s = max_side / longer
    w, h = (int(max_side) if n == longer else max(1, int(math.floor(n * s + 0.5))) for n in (width, height))
    if min(w, h) < block:
        need = math.ceil(block * longer / min(width, height))
        raise ValueError(
            f"scene.max_side={max_side} makes the {width}x{height} photo {w}x{h}, narrower than one {block}-pixel "
            f"block of the generator (model.multiple={block}); set scene.max_side to at least {need}"
        )
    return w, h


def fit_to_block(
    image: np.ndarray,
    depth: np.ndarray | None,
    camera: Camera,
    block: int,
    *,
    mode: str = "crop",
    size: tuple[int, int] | None = None,
) -> tuple[np.ndarray, np.ndarray | None, Camera]:
    """Make the image's width and height multiples of ``block`` (a generator's block size).

    ``mode="crop"`` (default) cuts the ``W % block`` and ``H % block`` extra pixels, the odd one
    from the right/bottom, and shifts the principal point: no resampling, the depth stays exact.
    ``mode="resize"`` resamples to ``size`` (default: the nearest multiples of ``block``): the
    image with Lanczos (antialiased when shrinking), the depth by nearest neighbour (values are
    copied from the input, a missing pixel never mixes with its neighbours), ``K`` scaled with the
    pixel-centre convention of :meth:`Camera.scaled` (per axis: an aspect change gives fx != fy).
    Either way a 3-D point projects onto the same image content before and after.

    Args:
        image: ``(H, W, 3)`` float image.
        depth: ``(H, W)`` depth, or ``None``.
        camera: the image's camera.
        block: the block size, >= 1 (16 for FLUX, 8 for the analytic backend).
        mode: ``"crop"`` or ``"resize"``.
        size: ``(width, height)`` for ``"resize"``, each a multiple of ``block``.

    Returns:
        ``(image, depth, camera)``; the inputs themselves when nothing changes.

    Raises:
        ValueError: shapes that disagree with the camera, a bad ``block``, ``mode`` or ``size``, an
            image smaller than one block.

    Examples:
        >>> from snell_bench.scene.photo_camera import camera_from
        >>> cam = camera_from(642, 481, intrinsics=[500.0, 500.0, 320.5, 240.0])
        >>> img, depth, cam16 = fit_to_block(np.zeros((481, 642, 3), np.float32), None, cam, 16)
        >>> img.shape, cam16
        ((480, 640, 3), Camera(width=640, height=480, fx=500.000, fy=500.000, cx=319.500, cy=240.000))
    """
    image = np.asarray(image)
    block = _check_fit(image, depth, camera, block)
    if mode == "crop":
        return _crop_to_block(image, depth, camera, block, size)
    if mode != "resize":
        raise ValueError(f"mode must be 'crop' or 'resize', got {mode!r}")
    return _resize_to(image, depth, camera, _resize_target(camera, block, size))


def _check_fit(image: np.ndarray, depth: np.ndarray | None, camera: Camera, block: int) -> int:
    """``block`` as an int, after checking it and the shapes of ``image`` and ``depth`` against
    ``camera`` (:func:`fit_to_block`'s ``ValueError`` otherwise)."""
    if image.ndim != 3 or image.shape[:2] != camera.shape:
        raise ValueError(f"image has shape {image.shape} but the camera is {camera.shape} (height, width)")
    if depth is not None and np.shape(depth) != camera.shape:
        raise ValueError(f"depth has shape {np.shape(depth)} but the camera is {camera.shape} (height, width)")
    if isinstance(block, bool) or int(block) != block or block < 1:
        raise ValueError(f"block must be a positive integer, got {block!r}")
    return int(block)


def _crop_to_block(
    image: np.ndarray, depth: np.ndarray | None, camera: Camera, block: int, size: tuple[int, int] | None
) -> tuple[np.ndarray, np.ndarray | None, Camera]:
    """:func:`fit_to_block`'s ``mode="crop"``: the centred ``(H - H % block, W - W % block)`` window
    (the odd pixel cut from the right/bottom), the principal point shifted by the cut; the inputs
    themselves when nothing is cut."""
    if size is not None:
        raise ValueError("size is for mode='resize'; mode='crop' keeps the largest multiple of block")
    H, W = camera.shape
    if W < block or H < block:
        raise ValueError(f"scene.image is {W}x{H}, smaller than one {block}x{block} block; use a larger image")
    w, h = W - W % block, H - H % block
    if (w, h) == (W, H):
        return image, depth, camera
    x0, y0 = (W - w) // 2, (H - h) // 2
    K = camera.K.copy()
    K[0, 2] -= x0
    K[1, 2] -= y0
    image = image[y0 : y0 + h, x0 : x0 + w].copy()
    if depth is not None:
        depth = np.asarray(depth)[y0 : y0 + h, x0 : x0 + w].copy()
    return image, depth, Camera(K=K, width=w, height=h)


def _resize_target(camera: Camera, block: int, size: tuple[int, int] | None) -> tuple[int, int]:
    """``(width, height)`` of :func:`fit_to_block`'s ``mode="resize"``: ``size`` after checking it
    (positive multiples of ``block``), else the camera's sides rounded to the nearest multiples."""
    H, W = camera.shape
    if size is None:
        return tuple(max(block, block * round(n / block)) for n in (W, H))
    try:
        w, h = (int(n) for n in size)
        ok = tuple(size) == (w, h)
    except (TypeError, ValueError):
        ok = False
    if not ok or w < 1 or h < 1 or w % block or h % block:
        raise ValueError(f"size must be (width, height), positive multiples of block={block}; got {size!r}")
    return w, h


def _resize_to(
    image: np.ndarray, depth: np.ndarray | None, camera: Camera, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray | None, Camera]:
    """``image`` (Lanczos), ``depth`` (nearest neighbour) and ``camera`` (``K`` scaled per axis about
    pixel centres) at ``size = (width, height)``; the inputs themselves when it is their size."""
    H, W = camera.shape
    w, h = size
    if (w, h) == (W, H):
        return image, depth, camera
    sx, sy = w / W, h / H
    K = camera.K.copy()
    K[0, 0] *= sx
    K[1, 1] *= sy
    K[0, 1] *= sx
    K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    out = _resize_image(image, (w, h))
    if depth is not None:
        xs = np.minimum(((np.arange(w) + 0.5) * (W / w)).astype(np.int64), W - 1)
        ys = np.minimum(((np.arange(h) + 0.5) * (H / h)).astype(np.int64), H - 1)
        depth = np.asarray(depth)[ys[:, None], xs[None, :]]
    return out, depth, Camera(K=K, width=w, height=h)


def _resize_image(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``image (H, W, C)`` resampled to ``size = (width, height)`` with Lanczos (antialiased when
    shrinking), per channel in float32, clipped to ``[0, 1]``."""
    chans = [
        np.asarray(
            Image.fromarray(np.ascontiguousarray(image[..., c], np.float32), mode="F").resize(
                tuple(size), Image.Resampling.LANCZOS
            )
        )
        for c in range(image.shape[2])
    ]
    return np.clip(np.stack(chans, axis=-1), 0.0, 1.0).astype(image.dtype if image.dtype.kind == "f" else np.float32)
