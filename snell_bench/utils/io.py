"""Atomic file writes: every file appears complete or not at all.

Each writer writes a temporary file beside the target (``.<name>.<random>.tmp``) and renames it
over the target; on any error the temporary is removed. Files get the mode the process's umask
gives a new file (``0o666 & ~umask``, usually 0644), not the 0600 of :func:`tempfile.mkstemp`.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "atomic_write",
    "atomic_write_bytes",
    "write_text",
    "write_json",
    "save_npy",
    "save_png",
    "to_uint8",
    "from_uint8",
    "saved_pixels",
    "link_or_copy",
    "json_default",
    "json_safe",
    "json_hash",
    "file_sha256",
    "umask_mode",
]


def umask_mode() -> int:
    """The mode the process's umask gives a new file (``0o666 & ~umask``)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def atomic_write(path: str | os.PathLike, write: Callable[[Any], None], *, binary: bool = True) -> Path:
    """Call ``write(f)`` on a temporary file beside ``path``, then rename it to ``path``.

    Args:
        path: the target file; its folder must exist.
        write: writes the content to the open file object it is given.
        binary: open the temporary in binary (default) or text mode (UTF-8).

    Returns:
        ``path`` as a :class:`~pathlib.Path`.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb" if binary else "w", **({} if binary else {"encoding": "utf-8"})) as f:
            write(f)
        os.chmod(tmp, umask_mode())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    return atomic_write(path, lambda f: f.write(data))


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def json_default(o: Any) -> Any:
    """``json.dumps`` fallback for numpy scalars and arrays."""
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


def json_safe(obj: Any) -> Any:
    """``obj`` with every non-finite float (NaN, ±Infinity, Python or numpy) replaced by ``None``
    and numpy values converted, recursively through dicts, lists and tuples: what strict JSON
    parsers accept (``json.dumps`` would write the non-standard ``NaN`` / ``Infinity``). Callers
    that drop a value this way record the reason beside it (as the metrics' ``missing`` does)."""
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def file_sha256(path: str | os.PathLike) -> str:
    """The SHA-256 of a file's bytes (hex), read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def json_hash(obj: Any, length: int = 16) -> str:
    """SHA-256 (its first ``length`` hex digits) of ``obj`` as JSON with sorted keys (values JSON
    cannot hold written with ``str``): a content key for caches and settings."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:length]


def write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Write ``obj`` as indented, strict JSON to ``path`` atomically: numpy values converted,
    non-finite floats written as ``null`` (:func:`json_safe`), never ``NaN`` or ``Infinity``."""
    text = json.dumps(json_safe(obj), indent=2, default=json_default, allow_nan=False)
    return atomic_write_bytes(path, text.encode())


def save_npy(path: str | os.PathLike, arr: np.ndarray) -> Path:
    """Save ``arr`` in ``.npy`` format to ``path`` atomically."""
    buf = io.BytesIO()
    np.save(buf, arr)
    return atomic_write_bytes(path, buf.getvalue())


def to_uint8(image: np.ndarray) -> np.ndarray:
    """A float image in [0, 1] as the 8-bit values :func:`save_png` writes: ``clip(rint(255 x), 0,
    255)`` in float64 (``rint``: round half to even), as ``uint8``; the layout is kept.

    Examples:
        >>> to_uint8(np.array([0.0, 0.5, 1.2, 0.998])).tolist()
        [0, 128, 255, 254]
    """
    return np.clip(np.rint(np.asarray(image, np.float64) * 255.0), 0, 255).astype(np.uint8)


def from_uint8(pixels: np.ndarray) -> np.ndarray:
    """8-bit pixels as the float32 image they decode to, ``value / 255``: the one conversion every
    scorer of a saved image uses (:func:`saved_pixels`, the images a submission holds).

    Examples:
        >>> from_uint8(np.array([0, 128, 255], np.uint8)).tolist() == [0.0, np.float32(128 / 255), 1.0]
        True
    """
    return np.asarray(pixels, np.uint8).astype(np.float32) / np.float32(255)


def saved_pixels(image: np.ndarray) -> np.ndarray:
    """A float image as its PNG (:func:`save_png`) holds it, read back: ``from_uint8(to_uint8(image))``,
    float32, the layout kept. Applied twice it changes nothing."""
    return from_uint8(to_uint8(image))


def save_png(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Save a float image in [0, 1], ``(H, W)`` or ``(H, W, 3)``, as an 8-bit PNG atomically
    (values rounded to the nearest of 0..255 and clipped: :func:`to_uint8`)."""
    from PIL import Image

    arr = to_uint8(image)
    return atomic_write(path, lambda f: Image.fromarray(arr).save(f, format="PNG"))


def link_or_copy(src: str | os.PathLike, dst: str | os.PathLike) -> Path:
    """Make ``dst`` the same file as ``src``: a hard link where possible, else a copy; atomic.

    An existing ``dst`` that already is ``src`` (same inode) is left as it is, so no temporary
    is ever left behind (renaming a link onto another link to the same file does nothing)."""
    src, dst = Path(src), Path(dst)
    try:
        if dst.exists() and os.path.samefile(src, dst):
            return dst
    except OSError:
        pass
    tmp = Path(tempfile.mktemp(dir=dst.parent, prefix=f".{dst.name}.", suffix=".link"))
    try:
        try:
            os.link(src, tmp)
        except OSError:
            shutil.copyfile(src, tmp)
        os.replace(tmp, dst)
    finally:
        tmp.unlink(missing_ok=True)
    return dst
