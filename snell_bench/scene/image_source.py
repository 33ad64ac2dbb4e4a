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
and how to fix it. Bad values raise ``ValueError``, missing files ``FileNotFoundError``; a depth
format whose reader is not installed (OpenEXR) raises ``ImportError``.

Depth formats (by file suffix, case-insensitive):
    - ``.png``, ``.pgm``: integer (8- or 16-bit) via Pillow; ``scale`` required.
    - ``.tif``, ``.tiff``: integer or float via tifffile (Pillow where tifffile is missing).
    - ``.npy``: numpy, float (metres) or integer (``scale`` required).
    - ``.pfm``: read with numpy (the sign of the scale line gives the byte order; rows are stored
      bottom to top).
    - ``.exr``: the OpenEXR package (``pip install OpenEXR``), an optional dependency.

``scale`` is in file units per metre (depth in metres = value / scale): 5000 for the TUM RGB-D
benchmark, 1000 for millimetres. Integer files need it; float files default to metres (scale 1).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps

from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_files import DEPTH_SUFFIXES, PathLike, read_depth_file, read_pfm

log = logging.getLogger(__name__)

__all__ = [
    "DEPTH_KINDS",
    "DEPTH_SUFFIXES",
    "RGBDFrame",
    "camera_from",
    "fit_to_block",
    "load_depth",
    "load_frame",
    "load_image",
    "read_pfm",
]

#: What a depth file's values measure: ``"z"`` (along the optical axis) or ``"range"`` (along the ray).
DEPTH_KINDS = ("z", "range")


# ---------------------------------------------------------------------------------------------- files
def _existing_file(path: PathLike, key: str, what: str) -> Path:
    """``path`` as a :class:`Path` (``~`` expanded); raises if it is missing or a folder."""
    if path is None or (isinstance(path, str) and not path.strip()):
        raise ValueError(f"{key} is not set; set {key} to the path of {what}")
    p = Path(path).expanduser()
    if p.is_dir():
        files = sorted(q.name for q in p.iterdir() if q.is_file())[:8]
        listing = f" (files there: {', '.join(files)})" if files else " (it holds no files)"
        raise ValueError(f"{key}='{path}' is a folder, not a file{listing}; set {key} to {what} inside it")
    if not p.is_file():
        raise FileNotFoundError(
            f"{key}='{path}' does not exist (looked for '{p.absolute()}'); set {key} to the path of {what}"
        )
    return p


# ---------------------------------------------------------------------------------------------- image
def load_image(path: PathLike, *, key: str = "scene.image", orient: bool = True) -> np.ndarray:
    """Read a photo as float32 ``(H, W, 3)`` sRGB in ``[0, 1]``.

    Any Pillow mode is accepted: RGB, RGBA and LA (alpha dropped, colour kept), L and 1 (grey
    repeated), P (palette resolved), CMYK and YCbCr (converted), 16-bit grey (``I;16``, ``I``:
    divided by 65535), float (``F``: clipped to ``[0, 1]``). The values are taken as sRGB (an
    embedded colour profile is not applied). Multi-frame files give their first frame.

    Args:
        path: a PNG or JPEG file (any format Pillow reads works).
        key: the configuration key named in error messages.
        orient: apply the EXIF orientation tag, so a phone photo comes out upright (as viewers show
            it). A depth map must then be in the same, upright, orientation.

    Returns:
        float32 array ``(H, W, 3)`` in ``[0, 1]``.

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: ``path`` is a folder, or the file is not a readable image.

    Examples:
        >>> import tempfile
        >>> from PIL import Image
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     Image.new("RGBA", (4, 2), (255, 0, 51, 128)).save(f"{tmp}/photo.png")
        ...     img = load_image(f"{tmp}/photo.png")
        >>> img.shape, img.dtype, img[0, 0].tolist()
        ((2, 4, 3), dtype('float32'), [1.0, 0.0, 0.20000000298023224])
    """
    p = _existing_file(path, key, "an image file (PNG or JPEG)")
    try:
        with Image.open(p) as im:
            im.load()
            if orient:
                im = ImageOps.exif_transpose(im)
            img = _to_rgb01(im)
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as e:
        raise ValueError(
            f"{key}='{path}' is not a readable image ({type(e).__name__}: {e}); "
            f"set {key} to a PNG or JPEG file, or re-save the file as one"
        ) from e
    log.info("loaded %s: %dx%d image", p, img.shape[1], img.shape[0])
    return img


def _to_rgb01(im: Image.Image) -> np.ndarray:
    mode = im.mode
    if mode in ("I;16", "I;16L", "I;16B", "I;16N", "I"):
        a = np.asarray(im).astype(np.float32) / np.float32(65535.0)
    elif mode == "F":
        a = np.nan_to_num(np.asarray(im, dtype=np.float32), nan=0.0)
    else:
        if mode in ("PA", "La", "RGBa"):
            im = im.convert("RGBA")
        a = np.asarray(im.convert("RGB"), dtype=np.float32) / np.float32(255.0)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=-1)
    return np.ascontiguousarray(np.clip(a, 0.0, 1.0), dtype=np.float32)


# ---------------------------------------------------------------------------------------------- depth
def load_depth(
    path: PathLike,
    *,
    scale: float | None = None,
    kind: str = "z",
    camera: Camera | None = None,
    key: str = "scene.depth",
) -> np.ndarray:
    """Read a depth map as float32 ``(H, W)`` z-depth in metres, NaN where it is missing.

    Values that are 0, negative, NaN or infinite become NaN (a sensor's "no reading").

    Args:
        path: a depth file; the suffix picks the reader (module docstring): ``.png``/``.pgm``
            (integer), ``.tif``/``.tiff``, ``.npy``, ``.pfm``, ``.exr``. One channel; a file with
            identical colour channels is accepted (its first channel is used).
        scale: file units per metre (metres = value / scale), e.g. 5000 for TUM, 1000 for
            millimetres. Required for integer data; float data defaults to metres (1).
        kind: ``"z"`` (the value is the z coordinate) or ``"range"`` (the distance from the camera
            centre along the pixel's ray; converted to z with ``camera``: z = range / |K⁻¹ [u, v, 1]|).
        camera: the image's camera; when given, the depth must have its size. Needed for ``"range"``.
        key: the configuration key of ``path`` named in error messages.

    Returns:
        float32 array ``(H, W)``: z in metres, NaN where missing.

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: a folder, an unknown suffix, an unreadable file, more than one distinct channel,
            a missing/zero/negative ``scale`` for integer data (``scene.depth_scale``), an unknown
            ``kind`` (``scene.depth_kind``), ``"range"`` without a camera, a size other than the
            camera's, or no valid pixel at all.
        ImportError: an ``.exr`` file without the OpenEXR package.

    Examples:
        >>> import tempfile
        >>> from PIL import Image
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     Image.fromarray(np.array([[0, 5000, 12345]], np.uint16)).save(f"{tmp}/depth.png")
        ...     depth = load_depth(f"{tmp}/depth.png", scale=5000)
        >>> depth.dtype, depth.tolist()
        (dtype('float32'), [[nan, 1.0, 2.4690001010894775]])
    """
    if kind not in DEPTH_KINDS:
        raise ValueError(
            f"scene.depth_kind={kind!r} is not a depth kind; choices: z|range "
            "(z: the distance along the optical axis; range: the distance along the pixel's ray)"
        )
    if scale is not None:
        scale = _check_scale(scale)
    if kind == "range" and camera is None:
        raise ValueError(
            "scene.depth_kind=range needs the camera to turn ray distances into z: pass camera= "
            "(set scene.intrinsics or scene.fov_deg)"
        )
    p = _existing_file(path, key, f"a depth file ({', '.join(DEPTH_SUFFIXES)})")
    raw = read_depth_file(p, path, key)

    if raw.dtype.kind in "iu":
        if scale is None:
            raise ValueError(
                f"{key}='{path}' holds integers ({raw.dtype}): set scene.depth_scale to the file's units per "
                "metre (metres = value / scale), e.g. scene.depth_scale=5000 for TUM RGB-D, 1000 for millimetres"
            )
    elif raw.dtype.kind != "f":
        raise ValueError(f"{key}='{path}' holds {raw.dtype} values, not numbers; save the depth as numbers")
    depth = raw.astype(np.float64) / (1.0 if scale is None else scale)

    if camera is not None and depth.shape != camera.shape:
        raise ValueError(
            f"{key}='{path}' has shape {depth.shape} (height, width) but scene.image is {camera.shape}; "
            f"the depth must be registered to the image pixel for pixel: resize or re-register it to "
            f"{camera.width}x{camera.height} (width x height)"
        )
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(depth) & (depth > 0)
    if not valid.any():
        raise ValueError(
            f"{key}='{path}' has no valid depth: all {depth.size} pixels are 0, negative, NaN or infinite; "
            f"set {key} to a depth map (and scene.depth_scale to its units per metre)"
        )
    if kind == "range":
        depth = depth / np.linalg.norm(camera.pixel_rays(normalize=False), axis=-1)
    depth = np.where(valid, depth, np.nan).astype(np.float32)

    median = float(np.median(depth[valid]))
    log.info(
        "loaded %s: %dx%d depth, %.1f %% missing, median %.3g m",
        p,
        depth.shape[1],
        depth.shape[0],
        100.0 * (1.0 - valid.mean()),
        median,
    )
    if not 0.01 <= median <= 1000.0:
        log.warning(
            "%s: the median depth is %.3g m; is scene.depth_scale (%s units per metre) right?", p, median, scale
        )
    return depth


def _check_scale(scale) -> float:
    try:
        s = float(scale)
    except (TypeError, ValueError):
        s = math.nan
    if isinstance(scale, bool) or not (math.isfinite(s) and s > 0):
        raise ValueError(
            f"scene.depth_scale={scale!r} must be a positive number of file units per metre "
            "(metres = value / scale), e.g. 5000 for TUM RGB-D, 1000 for millimetres"
        )
    return s


# ---------------------------------------------------------------------------------------------- camera
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
        ValueError: neither or both given; intrinsics not four finite numbers, a focal length <= 0,
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
        raise ValueError(
            f"set exactly one of scene.intrinsics ([fx, fy, cx, cy] in pixels) and scene.fov_deg (the horizontal "
            f"field of view in degrees); got {got}"
        )
    if fov_deg is not None:
        try:
            fov = float(fov_deg)
        except (TypeError, ValueError):
            fov = math.nan
        if isinstance(fov_deg, bool) or not (0.0 < fov < 180.0):
            raise ValueError(f"scene.fov_deg={fov_deg!r} must be a horizontal field of view in degrees in (0, 180)")
        return Camera.from_fov(width, height, fov)

    hint = "set scene.intrinsics=[fx, fy, cx, cy] (pixels; from a 3x3 K: [K00, K11, K02, K12])"
    if isinstance(intrinsics, str | bytes) or not isinstance(intrinsics, Sequence | np.ndarray):
        raise ValueError(f"scene.intrinsics={intrinsics!r} is not a list of four numbers; {hint}")
    vals = (
        list(np.asarray(intrinsics, dtype=object).reshape(-1))
        if isinstance(intrinsics, np.ndarray)
        else list(intrinsics)
    )
    if len(vals) != 4:
        raise ValueError(f"scene.intrinsics={vals!r} has {len(vals)} values, not 4; {hint}")
    try:
        if any(isinstance(v, bool | str | bytes) for v in vals):
            raise TypeError
        fx, fy, cx, cy = (float(v) for v in vals)
    except (TypeError, ValueError):
        raise ValueError(f"scene.intrinsics={vals!r} holds values that are not numbers; {hint}") from None
    if not all(math.isfinite(v) for v in (fx, fy, cx, cy)):
        raise ValueError(f"scene.intrinsics={vals!r} must be finite numbers (no NaN or inf); {hint}")
    if fx <= 0 or fy <= 0:
        raise ValueError(f"scene.intrinsics: the focal lengths fx={fx}, fy={fy} must be > 0 (pixels); {hint}")
    if not (-0.5 <= cx <= width - 0.5 and -0.5 <= cy <= height - 0.5):
        raise ValueError(
            f"scene.intrinsics: the principal point (cx, cy) = ({cx}, {cy}) is outside the {width}x{height} image "
            f"(x in [-0.5, {width - 0.5}], y in [-0.5, {height - 0.5}]); the intrinsics must be in pixels of this "
            "image: scale them if they were calibrated at another resolution"
        )
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return Camera(K=K, width=width, height=height)


# ---------------------------------------------------------------------------------------------- block size
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
        >>> cam = camera_from(642, 481, intrinsics=[500.0, 500.0, 320.5, 240.0])
        >>> img, depth, cam16 = fit_to_block(np.zeros((481, 642, 3), np.float32), None, cam, 16)
        >>> img.shape, cam16
        ((480, 640, 3), Camera(width=640, height=480, fx=500.000, fy=500.000, cx=319.500, cy=240.000))
    """
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[:2] != camera.shape:
        raise ValueError(f"image has shape {image.shape} but the camera is {camera.shape} (height, width)")
    if depth is not None and np.shape(depth) != camera.shape:
        raise ValueError(f"depth has shape {np.shape(depth)} but the camera is {camera.shape} (height, width)")
    if isinstance(block, bool) or int(block) != block or block < 1:
        raise ValueError(f"block must be a positive integer, got {block!r}")
    block = int(block)
    H, W = camera.shape
    if mode == "crop":
        if size is not None:
            raise ValueError("size is for mode='resize'; mode='crop' keeps the largest multiple of block")
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
    if mode != "resize":
        raise ValueError(f"mode must be 'crop' or 'resize', got {mode!r}")

    if size is None:
        w, h = (max(block, block * round(n / block)) for n in (W, H))
    else:
        try:
            w, h = (int(n) for n in size)
            ok = tuple(size) == (w, h)
        except (TypeError, ValueError):
            ok = False
        if not ok or w < 1 or h < 1 or w % block or h % block:
            raise ValueError(f"size must be (width, height), positive multiples of block={block}; got {size!r}")
    if (w, h) == (W, H):
        return image, depth, camera
    sx, sy = w / W, h / H
    K = camera.K.copy()
    K[0, 0] *= sx
    K[1, 1] *= sy
    K[0, 1] *= sx
    K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    chans = [
        np.asarray(
            Image.fromarray(np.ascontiguousarray(image[..., c], np.float32), mode="F").resize(
                (w, h), Image.Resampling.LANCZOS
            )
        )
        for c in range(image.shape[2])
    ]
    out = np.clip(np.stack(chans, axis=-1), 0.0, 1.0).astype(image.dtype if image.dtype.kind == "f" else np.float32)
    if depth is not None:
        xs = np.minimum(((np.arange(w) + 0.5) * (W / w)).astype(np.int64), W - 1)
        ys = np.minimum(((np.arange(h) + 0.5) * (H / h)).astype(np.int64), H - 1)
        depth = np.asarray(depth)[ys[:, None], xs[None, :]]
    return out, depth, Camera(K=K, width=w, height=h)


# ---------------------------------------------------------------------------------------------- frame
@dataclass(frozen=True, eq=False)
class RGBDFrame:
    """A photo, its depth (or ``None``, for a depth estimator to fill) and its camera.

    Attributes:
        image: float32 ``(H, W, 3)`` sRGB in ``[0, 1]``.
        depth: float32 ``(H, W)`` z-depth in metres, NaN where missing; or ``None``.
        camera: the :class:`Camera` of ``image``.
    """

    image: np.ndarray
    depth: np.ndarray | None
    camera: Camera

    def __post_init__(self) -> None:
        if np.ndim(self.image) != 3 or np.shape(self.image)[:2] != self.camera.shape or np.shape(self.image)[2] != 3:
            raise ValueError(f"image has shape {np.shape(self.image)}; the camera needs {self.camera.shape + (3,)}")
        if self.depth is not None and np.shape(self.depth) != self.camera.shape:
            raise ValueError(f"depth has shape {np.shape(self.depth)}; the camera needs {self.camera.shape}")


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
) -> RGBDFrame:
    """Load a photo (and its depth) and fit it to a generator's block size.

    In order: :func:`load_image`, :func:`camera_from` (the intrinsics are in pixels of the image
    file as stored), :func:`load_depth` (same size as the image), :func:`fit_to_block` (center
    crop; ``size`` resizes instead).

    Args:
        image: ``scene.image``, the photo (PNG or JPEG).
        depth: ``scene.depth``, its registered depth file, or ``None`` (``RGBDFrame.depth`` is then ``None``).
        depth_scale: ``scene.depth_scale``, file units per metre (required for integer depth files).
        depth_kind: ``scene.depth_kind``, ``"z"`` or ``"range"``.
        intrinsics: ``scene.intrinsics``, ``[fx, fy, cx, cy]`` in pixels.
        fov_deg: ``scene.fov_deg``, the horizontal field of view (when the intrinsics are unknown).
        block: width and height become multiples of it; ``None`` or 1 keeps the size.
        size: ``(width, height)``, multiples of ``block``: resize to it instead of cropping.

    Returns:
        The :class:`RGBDFrame`.

    Raises:
        FileNotFoundError, ValueError, ImportError: see :func:`load_image`, :func:`load_depth`,
            :func:`camera_from` and :func:`fit_to_block`.
    """
    img = load_image(image)
    cam = camera_from(img.shape[1], img.shape[0], intrinsics=intrinsics, fov_deg=fov_deg)
    dep = None if depth is None else load_depth(depth, scale=depth_scale, kind=depth_kind, camera=cam)
    if size is not None:
        img, dep, cam = fit_to_block(img, dep, cam, block or 1, mode="resize", size=size)
    elif block is not None:
        img, dep, cam = fit_to_block(img, dep, cam, block)
    return RGBDFrame(image=img, depth=dep, camera=cam)
