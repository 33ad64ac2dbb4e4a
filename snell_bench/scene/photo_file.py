"""A photo file: its pixels, its header and its EXIF orientation (read by :mod:`snell_bench.scene.image_source`).

Convention (that of :mod:`snell_bench.scene.camera`):
    - Image: float32 ``(H, W, 3)`` sRGB in ``[0, 1]`` (:func:`load_image`), turned upright by its
      EXIF orientation unless asked not to.
    - A photo's *stored* size is that of the file; its *upright* size is the one viewers show
      (:attr:`PhotoHeader.upright_size`). Intrinsics ``[fx, fy, cx, cy]`` are in pixels, integer
      pixel coordinates at pixel centres; :func:`orient_intrinsics` turns those of the stored file
      into those of the upright photo.

Error messages name the configuration key to change (``scene.image``); bad values raise
``ValueError``, missing files ``FileNotFoundError``.

Pixel limit: a photo of more than :data:`MAX_PHOTO_PIXELS` pixels is refused from its header, before
any pixel is decoded (:class:`PhotoTooLargeError`, naming the long side to downscale it to). Pillow's
own decompression-bomb check is lifted while a photo's header is read, so this limit, and its
advice, applies instead.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps

from snell_bench.config.errors import ConfigError
from snell_bench.scene.depth_files import PathLike

log = logging.getLogger(__name__)

__all__ = [
    "EXIF_ORIENTATION",
    "MAX_PHOTO_PIXELS",
    "PhotoHeader",
    "PhotoTooLargeError",
    "load_image",
    "orient_intrinsics",
    "read_photo_header",
]

#: The most pixels a photo may have (100 Mpx, near Pillow's own warning at 89.5 Mpx). A photo is
#: decoded whole before ``scene.max_side`` resizes it (about 30 bytes a pixel: 3 GB at the limit),
#: and no cell uses a photo near this size: the reference renders 2.65 kB per pixel of I⁻
#: (:mod:`snell_bench.experiment.memory`), so a photo this large runs only with ``scene.max_side``
#: far below it, and a copy downscaled first loses nothing.
MAX_PHOTO_PIXELS = 100_000_000

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


class PhotoTooLargeError(ConfigError):
    """A photo of more than :data:`MAX_PHOTO_PIXELS` pixels (one line: the key, the size, the limit
    and the long side to downscale it to); a refused input, printed without a traceback."""

    def __init__(self, message: str) -> None:
        super().__init__([message])


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
        PhotoTooLargeError: the photo has more than :data:`MAX_PHOTO_PIXELS` pixels (nothing decoded).
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
    with _open_photo(p, path, key) as im:
        try:
            im.load()
            if orient:
                im = ImageOps.exif_transpose(im)
            img = _to_rgb01(im)
        except (OSError, SyntaxError, ValueError) as e:
            raise _unreadable(path, key, e) from e
    log.info("loaded %s: %dx%d image", p, img.shape[1], img.shape[0])
    return img


def _unreadable(path: PathLike, key: str, e: BaseException) -> ValueError:
    return ValueError(
        f"{key}='{path}' is not a readable image ({type(e).__name__}: {e}); "
        f"set {key} to a PNG or JPEG file, or re-save the file as one"
    )


def _fitting_side(width: int, height: int, limit: int = MAX_PHOTO_PIXELS) -> int:
    """The longest side a ``width x height`` photo downscaled to at most ``limit`` pixels (its
    aspect ratio kept) may have.

    Examples:
        >>> _fitting_side(12000, 9200)
        11420
    """
    long, short = max(width, height), min(width, height)
    side = math.isqrt(limit * long // short)
    while side * max(1, round(side * short / long)) > limit:
        side -= 1
    return side


@contextmanager
def _open_photo(p: Path, path: PathLike, key: str) -> Iterator[Image.Image]:
    """``with _open_photo(p, path, key) as im``: the photo opened (its header read, no pixel
    decoded) with Pillow's decompression-bomb limit lifted, and :data:`MAX_PHOTO_PIXELS` applied
    instead.

    Raises:
        PhotoTooLargeError: more than :data:`MAX_PHOTO_PIXELS` pixels.
        ValueError: not an image Pillow can open.
    """
    before = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = None  # only while the header is read: the size is checked below
    try:
        im = Image.open(p)
    except (OSError, SyntaxError, ValueError) as e:
        raise _unreadable(path, key, e) from e
    finally:
        Image.MAX_IMAGE_PIXELS = before
    with im:
        w, h = im.size
        if w * h > MAX_PHOTO_PIXELS:
            raise PhotoTooLargeError(
                f"{key}='{path}' is {w}x{h} pixels ({w * h / 1e6:.1f} Mpx), more than the "
                f"{MAX_PHOTO_PIXELS / 1e6:g} Mpx a photo may have (it is decoded whole before scene.max_side "
                f"resizes it): downscale the file to at most {_fitting_side(w, h)} pixels on its long side"
            )
        yield im


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
        PhotoTooLargeError: the photo has more than :data:`MAX_PHOTO_PIXELS` pixels.
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
    with _open_photo(p, path, key) as im:
        width, height = im.size
        try:
            orientation = int(im.getexif().get(EXIF_ORIENTATION, 1) or 1)
        except (OSError, SyntaxError, ValueError) as e:
            raise _unreadable(path, key, e) from e
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
