"""The depth-file readers behind :func:`snell_bench.scene.image_source.load_depth`.

Each reader returns the file's values as stored (integer or float, one or more channels);
:func:`read_depth_file` picks the reader by suffix and keeps one channel. The scale, the depth kind
and missing values are :func:`~snell_bench.scene.image_source.load_depth`'s.

Formats (by file suffix, case-insensitive):
    - ``.png``, ``.pgm``: Pillow (a palette image is refused).
    - ``.tif``, ``.tiff``: tifffile, Pillow where tifffile is missing.
    - ``.npy``: numpy (no pickles).
    - ``.pfm``: :func:`read_pfm` (numpy).
    - ``.exr``: the OpenEXR package (``pip install OpenEXR``), an optional dependency.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
from PIL import Image

__all__ = [
    "DEPTH_SUFFIXES",
    "PathLike",
    "read_depth_file",
    "read_exr",
    "read_npy",
    "read_pfm",
    "read_pillow",
    "read_tiff",
    "single_channel",
]

#: The depth file suffixes :func:`~snell_bench.scene.image_source.load_depth` reads.
DEPTH_SUFFIXES = (".png", ".pgm", ".tif", ".tiff", ".npy", ".pfm", ".exr")

#: A path as the user gives it.
PathLike = str | os.PathLike


def read_pillow(p: Path) -> np.ndarray:
    """An integer image (PNG, PGM, TIFF) via Pillow; a palette image is refused."""
    with Image.open(p) as im:
        im.load()
        if im.mode == "P":
            raise ValueError(f"a palette image ({im.mode}) holds colour indices, not depth")
        return np.asarray(im)


def read_tiff(p: Path) -> np.ndarray:
    """The first page of a TIFF via tifffile, or via Pillow where tifffile is missing."""
    try:
        import tifffile
    except ImportError:  # tifffile comes with scikit-image; Pillow reads the common TIFFs too
        return read_pillow(p)
    return tifffile.imread(p, key=0)


def read_npy(p: Path) -> np.ndarray:
    """A numpy ``.npy`` array (no pickles)."""
    return np.load(p, allow_pickle=False)


_PFM_HEADER = re.compile(rb"(P[Ff])\s+(\d+)\s+(\d+)\s+([-+]?[0-9.]+(?:[eE][-+]?\d+)?)\s")


def read_pfm(path: PathLike) -> np.ndarray:
    """Read a PFM file: float32 ``(H, W)`` (``Pf``) or ``(H, W, 3)`` (``PF``), top row first.

    The scale line's sign gives the byte order (negative: little-endian); its magnitude is ignored.

    Raises:
        ValueError: not a PFM file, or too little data for its header.
    """
    data = Path(path).read_bytes()
    m = _PFM_HEADER.match(data)
    if m is None:
        raise ValueError("no PFM header (expected 'Pf' or 'PF', width, height, scale)")
    channels = 3 if m.group(1) == b"PF" else 1
    w, h, s = int(m.group(2)), int(m.group(3)), float(m.group(4))
    if s == 0 or w < 1 or h < 1:
        raise ValueError(f"bad PFM header: width {w}, height {h}, scale {s}")
    n = w * h * channels
    if len(data) - m.end() < 4 * n:
        raise ValueError(f"PFM data too short: {len(data) - m.end()} bytes for {w}x{h}x{channels} floats")
    a = np.frombuffer(data, dtype="<f4" if s < 0 else ">f4", count=n, offset=m.end())
    a = a.reshape((h, w, channels) if channels == 3 else (h, w))[::-1]  # rows are stored bottom to top
    return np.ascontiguousarray(a, dtype=np.float32)


def read_exr(p: Path, path: PathLike, key: str) -> np.ndarray:
    """The depth channel of an OpenEXR file: its only channel, the one named Z / depth / dist, or
    identical R, G, B; ``ImportError`` without the OpenEXR package (``path`` and ``key`` name the file
    in error messages)."""
    try:
        import OpenEXR
    except ImportError as e:
        raise ImportError(
            f"{key}='{path}' is an OpenEXR file; reading it needs the OpenEXR package: pip install OpenEXR "
            "(or save the depth as .npy, .pfm or a 32-bit float .tif)"
        ) from e
    if not hasattr(OpenEXR, "File"):
        raise ImportError(f"{key}='{path}': reading .exr needs OpenEXR >= 3.3: pip install -U OpenEXR")
    try:
        with OpenEXR.File(str(p), separate_channels=True) as f:
            channels = {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}
    except Exception as e:  # the bindings raise plain RuntimeError / OpenEXR errors for bad files
        raise ValueError(f"{key}='{path}' is not a readable .exr file ({type(e).__name__}: {e})") from e
    if len(channels) == 1:
        return next(iter(channels.values()))
    names = list(channels)
    depthish = [n for n in names if n.rsplit(".", 1)[-1].upper() == "Z" or "depth" in n.lower() or "dist" in n.lower()]
    if len(depthish) == 1:
        return channels[depthish[0]]
    colour = [n for n in ("R", "G", "B") if n in channels]
    if colour and all(np.array_equal(channels[colour[0]], channels[n], equal_nan=True) for n in colour):
        return channels[colour[0]]
    raise ValueError(
        f"{key}='{path}' has the channels {names} and none is plainly the depth; "
        "save the depth as a single channel (or one named Z)"
    )


_READERS = {
    ".png": read_pillow,
    ".pgm": read_pillow,
    ".tif": read_tiff,
    ".tiff": read_tiff,
    ".npy": read_npy,
    ".pfm": read_pfm,
}


def read_depth_file(p: Path, path: PathLike, key: str) -> np.ndarray:
    """The one-channel ``(H, W)`` values of the depth file ``p``, read by its suffix (:data:`DEPTH_SUFFIXES`).

    Args:
        p: the file.
        path: ``p`` as the user gave it, quoted in error messages.
        key: the configuration key of ``path`` named in error messages.

    Returns:
        The values as stored (integer or float), one channel (:func:`single_channel`).

    Raises:
        ValueError: a suffix that is not a depth format, an unreadable file, more than one distinct
            channel.
        ImportError: an ``.exr`` file without the OpenEXR package.
    """
    suffix = p.suffix.lower()
    if suffix not in DEPTH_SUFFIXES:
        raise ValueError(
            f"{key}='{path}' has the suffix {p.suffix!r}, which is not a depth format; "
            f"save the depth as one of {', '.join(DEPTH_SUFFIXES)}"
        )
    if suffix == ".exr":
        raw = read_exr(p, path, key)  # its ImportError passes through
    else:
        try:
            raw = _READERS[suffix](p)
        except (OSError, SyntaxError, ValueError, EOFError, Image.DecompressionBombError) as e:
            raise ValueError(
                f"{key}='{path}' is not a readable {suffix} depth file ({type(e).__name__}: {e}); "
                f"set {key} to a valid depth file ({', '.join(DEPTH_SUFFIXES)})"
            ) from e
    return single_channel(np.asarray(raw), path, key)


def single_channel(a: np.ndarray, path: PathLike, key: str) -> np.ndarray:
    """``(H, W)`` from ``(H, W)``, ``(H, W, 1)`` or ``(H, W, C)`` with identical colour channels."""
    if a.size == 0:
        raise ValueError(f"{key}='{path}' holds no pixels (an array of shape {a.shape}); set {key} to a depth map")
    if a.ndim == 3 and a.shape[-1] == 1:
        a = a[..., 0]
    elif a.ndim == 3 and a.shape[-1] in (2, 3, 4):
        c = a.shape[-1] if a.shape[-1] == 3 else a.shape[-1] - 1  # the colour channels (not alpha)
        if all(np.array_equal(a[..., 0], a[..., i], equal_nan=a.dtype.kind == "f") for i in range(1, c)):
            a = a[..., 0]
    if a.ndim != 2 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(
            f"{key}='{path}' holds an array of shape {a.shape}; a depth map is one channel (height, width) "
            "(a colour-mapped depth picture cannot be read back as depth)"
        )
    return a
