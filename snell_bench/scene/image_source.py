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
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps

from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_files import DEPTH_SUFFIXES, PathLike, read_depth_file, read_pfm

log = logging.getLogger(__name__)

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

#: What a depth file's values measure: ``"z"`` (along the optical axis) or ``"range"`` (along the ray).
DEPTH_KINDS = ("z", "range")
#: Metres: a depth map whose every valid value (scaled) is nearer than this is refused: no scene a
#: glass object stands in fits within 5 cm of the camera; the scale is wrong.
NEAREST_SCENE_M = 0.05
#: Metres: a depth map whose median (scaled) is farther than this is refused: the object stands on
#: a surface the photo shows near the camera, so most of a scene cannot lie beyond 1 km.
FARTHEST_MEDIAN_M = 1000.0
#: The EXIF tag of the orientation.
EXIF_ORIENTATION = 0x0112
#: EXIF orientation -> ``(transposed, flip x, flip y)``: the upright pixel ``(x', y')`` of the stored
#: pixel ``(x, y)`` of a ``W x H`` file is ``(x, y)``, swapped when transposed, then ``x' -> W' - 1 - x'``
#: and ``y' -> H' - 1 - y'`` where flipped (``W' x H'``: the upright size). Pillow's
#: ``ImageOps.exif_transpose`` does the same.
_ORIENTATIONS = {
    1: (False, False, False),
    2: (False, True, False),
    3: (False, True, True),
    4: (False, False, True),
    5: (True, False, False),
    6: (True, True, False),
    7: (True, True, True),
    8: (True, False, True),
}
#: What each EXIF orientation does to the stored photo to show it upright.
_ORIENTATION_WORDS = {
    2: "mirrored left to right",
    3: "rotated by 180 degrees",
    4: "mirrored top to bottom",
    5: "transposed (mirrored about its main diagonal)",
    6: "rotated by 90 degrees clockwise",
    7: "transversed (mirrored about its anti-diagonal)",
    8: "rotated by 90 degrees counter-clockwise",
}


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


# ---------------------------------------------------------------------------------------------- header
@dataclass(frozen=True)
class PhotoHeader:
    """What a photo's file header says, read without decoding its pixels.

    Attributes:
        width: width of the file as stored, in pixels.
        height: height of the file as stored.
        orientation: the EXIF orientation tag, 1 (upright, also without a tag) to 8.
    """

    width: int
    height: int
    orientation: int = 1

    @property
    def transposed(self) -> bool:
        """Whether turning the photo upright swaps its width and height (orientations 5 to 8)."""
        return _ORIENTATIONS[self.orientation][0]

    @property
    def upright_size(self) -> tuple[int, int]:
        """``(width, height)`` of the photo as shown (after its EXIF orientation)."""
        return (self.height, self.width) if self.transposed else (self.width, self.height)

    def rotation(self) -> str:
        """What the EXIF orientation does, in words (``""`` for an upright file), e.g. "the photo was
        rotated by 90 degrees clockwise by its EXIF orientation tag 6 from 4000x3000 (as stored) to
        3000x4000 (upright, as viewers show it)"."""
        if self.orientation == 1:
            return ""
        w, h = self.upright_size
        return (
            f"the photo was {_ORIENTATION_WORDS[self.orientation]} by its EXIF orientation tag {self.orientation} "
            f"from {self.width}x{self.height} (as stored) to {w}x{h} (upright, as viewers show it)"
        )


def read_photo_header(path: PathLike, *, key: str = "scene.image") -> PhotoHeader:
    """The stored size and EXIF orientation of a photo, from its header only (no pixel decoded).

    Args:
        path: a PNG or JPEG file (any format Pillow reads).
        key: the configuration key named in error messages.

    Returns:
        The :class:`PhotoHeader`; an orientation tag outside 1..8 counts as 1 (as Pillow's
        ``exif_transpose`` does).

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: ``path`` is a folder, or not an image Pillow can open.

    Examples:
        >>> import tempfile
        >>> from PIL import Image
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     exif = Image.Exif()
        ...     exif[EXIF_ORIENTATION] = 6
        ...     Image.new("RGB", (40, 30)).save(f"{tmp}/phone.jpg", exif=exif)
        ...     header = read_photo_header(f"{tmp}/phone.jpg")
        >>> header, header.upright_size
        (PhotoHeader(width=40, height=30, orientation=6), (30, 40))
    """
    p = _existing_file(path, key, "an image file (PNG or JPEG)")
    try:
        with Image.open(p) as im:
            width, height = im.size
            orientation = int(im.getexif().get(EXIF_ORIENTATION, 1) or 1)
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as e:
        raise ValueError(
            f"{key}='{path}' is not a readable image ({type(e).__name__}: {e}); "
            f"set {key} to a PNG or JPEG file, or re-save the file as one"
        ) from e
    return PhotoHeader(int(width), int(height), orientation if orientation in _ORIENTATIONS else 1)


def orient_intrinsics(intrinsics: Sequence[float], width: int, height: int, orientation: int) -> list[float]:
    """``[fx, fy, cx, cy]`` of a stored ``width x height`` photo turned into those of the upright
    photo its EXIF ``orientation`` shows.

    The principal point moves as a pixel does (:data:`_ORIENTATIONS`); a transposing orientation
    (5 to 8) swaps the focal lengths. A mirroring orientation (2, 4, 5, 7) shows the scene
    mirrored: the upright camera is the mirrored scene's (the focal lengths stay positive), so the
    photo and a depth map in its upright orientation still agree pixel for pixel.

    Args:
        intrinsics: ``[fx, fy, cx, cy]`` in pixels of the stored file.
        width: width of the stored file.
        height: height of the stored file.
        orientation: the EXIF orientation, 1 to 8.

    Returns:
        ``[fx', fy', cx', cy']`` in pixels of the upright photo.

    Raises:
        ValueError: an orientation outside 1..8.

    Examples:
        >>> orient_intrinsics([500.0, 510.0, 100.0, 60.0], 400, 300, 6)  # 90 degrees clockwise
        [510.0, 500.0, 239.0, 100.0]
    """
    if orientation not in _ORIENTATIONS:
        raise ValueError(f"EXIF orientation must be 1 to 8, got {orientation!r}")
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    transposed, flip_x, flip_y = _ORIENTATIONS[orientation]
    if transposed:
        fx, fy, cx, cy, width, height = fy, fx, cy, cx, height, width
    if flip_x:
        cx = width - 1 - cx
    if flip_y:
        cy = height - 1 - cy
    return [fx, fy, cx, cy]


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
        ValueError: as :func:`camera_from` (the message says when the photo was turned by EXIF).
    """
    if intrinsics is None or fov_deg is not None:
        w, h = header.upright_size
        return camera_from(w, h, intrinsics=intrinsics, fov_deg=fov_deg)
    try:
        camera_from(header.width, header.height, intrinsics=intrinsics)
    except ValueError as e:
        if header.orientation == 1:
            raise
        raise ValueError(
            f"{e} (scene.intrinsics are in pixels of the file as stored, {header.width}x{header.height}; "
            f"{header.rotation()})"
        ) from None
    w, h = header.upright_size
    k = orient_intrinsics(intrinsics, header.width, header.height, header.orientation)
    return camera_from(w, h, intrinsics=k)


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


# ---------------------------------------------------------------------------------------------- depth
def load_depth(
    path: PathLike,
    *,
    scale: float | None = None,
    kind: str = "z",
    camera: Camera | None = None,
    key: str = "scene.depth",
    photo: PhotoHeader | None = None,
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
        photo: the header of the photo the depth belongs to: a size mismatch then says when the
            photo was turned by its EXIF orientation.

    Returns:
        float32 array ``(H, W)``: z in metres, NaN where missing.

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: a folder, an unknown suffix, an unreadable file, more than one distinct channel,
            an unknown ``kind`` (``scene.depth_kind``), ``"range"`` without a camera, a size other
            than the camera's, no valid pixel at all, or values that contradict ``scale``
            (:func:`depth_from_raw`).
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
    _check_depth_args(scale, kind, camera)
    p = _existing_file(path, key, f"a depth file ({', '.join(DEPTH_SUFFIXES)})")
    raw = read_depth_file(p, path, key)
    depth = depth_from_raw(raw, path, scale=scale, kind=kind, camera=camera, key=key, photo=photo)
    valid = np.isfinite(depth)
    log.info(
        "loaded %s: %dx%d depth, %.1f %% missing, median %.3g m",
        p,
        depth.shape[1],
        depth.shape[0],
        100.0 * (1.0 - valid.mean()),
        float(np.median(depth[valid])),
    )
    return depth


def _check_depth_args(scale, kind: str, camera: Camera | None) -> float | None:
    """``scale`` as a float (``None`` stays), after checking ``scale``, ``kind`` and ``camera``."""
    if kind not in DEPTH_KINDS:
        raise ValueError(
            f"scene.depth_kind={kind!r} is not a depth kind; choices: z|range "
            "(z: the distance along the optical axis; range: the distance along the pixel's ray)"
        )
    if kind == "range" and camera is None:
        raise ValueError(
            "scene.depth_kind=range needs the camera to turn ray distances into z: pass camera= "
            "(set scene.intrinsics or scene.fov_deg)"
        )
    return None if scale is None else _check_scale(scale)


def depth_from_raw(
    raw: np.ndarray,
    path: PathLike,
    *,
    scale: float | None = None,
    kind: str = "z",
    camera: Camera | None = None,
    key: str = "scene.depth",
    photo: PhotoHeader | None = None,
) -> np.ndarray:
    """The z-depth in metres of a depth file's values as stored (:func:`load_depth` after reading).

    Values that contradict ``scale`` are refused (each error names ``scene.depth_scale`` and the
    setting that fits the file's values):

    - 8-bit integers: 256 levels are a picture of depth (normalised for viewing), not a measurement;
    - integers with ``scale < 1``: a scale in metres per unit, not units per metre;
    - scaled depths all nearer than :data:`NEAREST_SCENE_M`, or with a median farther than
      :data:`FARTHEST_MEDIAN_M` (e.g. a float file in metres given an integer file's scale, or
      millimetres read as metres).

    Args:
        raw: ``(H, W)`` values as stored (:func:`~snell_bench.scene.depth_files.read_depth_file`).
        path: the file, as the user gave it (quoted in error messages).
        scale, kind, camera, key, photo: as :func:`load_depth`.

    Returns:
        float32 ``(H, W)`` z in metres, NaN where missing.

    Raises:
        ValueError: see :func:`load_depth`.
    """
    scale = _check_depth_args(scale, kind, camera)
    if raw.dtype.kind in "iu":
        if raw.dtype.itemsize == 1:
            steps = (
                ""
                if scale is None
                else f" (at scene.depth_scale={scale:g}: steps of {1 / scale:.3g} m up to {255 / scale:.3g} m)"
            )
            raise ValueError(
                f"{key}='{path}' is an 8-bit file: its 256 levels{steps} are a picture of depth made for viewing, "
                "not a measurement; save the depth as a 16-bit PNG with its units per metre in scene.depth_scale "
                "(e.g. millimetres and scene.depth_scale=1000), or as float metres (.npy, .pfm, .exr, 32-bit .tif) "
                "with scene.depth_scale=null"
            )
        if scale is None:
            raise ValueError(
                f"{key}='{path}' holds integers ({raw.dtype}): set scene.depth_scale to the file's units per "
                "metre (metres = value / scale), e.g. scene.depth_scale=5000 for TUM RGB-D, 1000 for millimetres"
            )
        if scale < 1.0:
            raise ValueError(
                f"scene.depth_scale={scale:g} is below 1 for the integer file {key}='{path}': the scale is file units "
                f"per metre (metres = value / scale), not metres per unit; set scene.depth_scale={1 / scale:g}"
            )
    elif raw.dtype.kind != "f":
        raise ValueError(f"{key}='{path}' holds {raw.dtype} values, not numbers; save the depth as numbers")

    if camera is not None and raw.shape != camera.shape:
        raise ValueError(_shape_message(raw.shape, camera, path, key, photo))
    depth = raw.astype(np.float64) / (1.0 if scale is None else scale)
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
    _check_plausible(raw, depth[valid], scale, path, key)
    return depth


def _shape_message(shape: tuple, camera: Camera, path: PathLike, key: str, photo: PhotoHeader | None) -> str:
    """The error of a depth of ``shape`` (height, width) that does not match the photo's camera."""
    msg = (
        f"{key}='{path}' has shape {tuple(shape)} (height, width) but scene.image is {camera.shape}; "
        "the depth must be registered to the image pixel for pixel"
    )
    if photo is None or photo.orientation == 1:
        return f"{msg}: resize or re-register it to {camera.width}x{camera.height} (width x height)"
    stored = tuple(shape) == (photo.height, photo.width)
    return (
        f"{msg}: {photo.rotation()}"
        + (", and the depth has the stored shape" if stored else "")
        + f"; {'rotate' if photo.transposed else 'turn'} the depth the same way (to {camera.width}x{camera.height}) "
        "or re-save the photo without its EXIF orientation tag"
    )


def _check_plausible(raw: np.ndarray, metres: np.ndarray, scale: float | None, path: PathLike, key: str) -> None:
    """Refuse valid depths ``metres`` (scaled from ``raw``) that no scene has (see
    :func:`depth_from_raw`), naming the scale that fits."""
    far, median = float(metres.max()), float(np.median(metres))
    if far >= NEAREST_SCENE_M and median <= FARTHEST_MEDIAN_M:
        return
    s = 1.0 if scale is None else scale
    raw_median = median * s
    problem = (
        f"all of it is nearer than {NEAREST_SCENE_M:g} m (the farthest valid value is {far:.3g} m)"
        if far < NEAREST_SCENE_M
        else f"its median is {median:.4g} m, farther than {FARTHEST_MEDIAN_M:g} m"
    )
    fits = []
    integer = raw.dtype.kind != "f"
    for fix, unit in ((None, "metres"), (1000.0, "millimetres"), (5000.0, "TUM RGB-D")):
        if fix == scale or (fix is None and (integer or scale in (None, 1.0))) or (fix == 5000.0 and not integer):
            continue
        m = raw_median / (1.0 if fix is None else fix)
        if 0.1 <= m <= 100.0:
            fits.append(f"scene.depth_scale={'null' if fix is None else f'{fix:g}'} ({unit}: median {m:.3g} m)")
    hint = (
        ("set " + " or ".join(fits))
        if fits
        else "set scene.depth_scale to the file's units per metre (metres = value / scale)"
    )
    kind = "integer" if integer else "float"
    raise ValueError(
        f"{key}='{path}' ({kind} values, median {raw_median:.4g}) read at scene.depth_scale="
        f"{'null' if scale is None else f'{scale:g}'} is implausible as depth in metres: {problem}; {hint}"
        + (" (a float file is read as metres without a scale)" if raw.dtype.kind == "f" and scale is not None else "")
    )


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
        FileNotFoundError, ValueError: see :func:`load_image`, :func:`photo_camera` and
            :func:`max_side_size`.
    """
    header = read_photo_header(image)
    camera = (
        None if intrinsics is None and fov_deg is None else photo_camera(header, intrinsics=intrinsics, fov_deg=fov_deg)
    )
    img = load_image(image)
    _log_orientation(header, image, False)
    size = max_side_size(img.shape[1], img.shape[0], max_side, block=block)
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
        image, depth, depth_scale, depth_kind, intrinsics, fov_deg, block, max_side: as
            :func:`load_frame`.

    Returns:
        :func:`photo_info` of the photo, ``size`` being the size :func:`load_frame` gives, and
        ``"fx"``: the horizontal focal length in pixels of that size (``None`` without intrinsics
        or field of view).

    Raises:
        FileNotFoundError, ValueError: see :func:`load_frame`.
    """
    header = read_photo_header(image)
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
    size = max_side_size(w0, h0, max_side, block=block or 1)
    w, h = size
    if block is not None and block > 1:
        if w < block or h < block:
            raise ValueError(f"scene.image is {w}x{h}, smaller than one {block}x{block} block; use a larger image")
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
        FileNotFoundError, ValueError, ImportError: see :func:`load_image`, :func:`load_depth`,
            :func:`photo_camera`, :func:`max_side_size` and :func:`fit_to_block`.
    """
    header = read_photo_header(image)
    cam = photo_camera(header, intrinsics=intrinsics, fov_deg=fov_deg)
    img = load_image(image)
    _log_orientation(header, image, depth is not None)
    dep = None if depth is None else load_depth(depth, scale=depth_scale, kind=depth_kind, camera=cam, photo=header)
    resized = max_side_size(cam.width, cam.height, max_side, block=block or 1)
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
