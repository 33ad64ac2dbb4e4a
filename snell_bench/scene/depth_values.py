"""A depth file's values as z-depth in metres (:func:`load_depth`, :func:`depth_from_raw`).

Convention:
    - Depth: float32 ``(H, W)``, the camera-frame z in metres (not the distance along the ray);
      missing depth (0, negative, NaN, infinite) is NaN.
    - ``scale`` is in file units per metre (metres = value / scale): 5000 for the TUM RGB-D
      benchmark, 1000 for millimetres. Integer files need it; float files default to metres.
    - ``kind`` is ``"z"`` (along the optical axis) or ``"range"`` (along the pixel's ray).

Values that contradict ``scale`` are refused, naming ``scene.depth_scale`` and what to set: an 8-bit
integer file, a scale below 1 for an integer file, and a depth all nearer than
:data:`NEAREST_SCENE_M` or with a median farther than :data:`FARTHEST_MEDIAN_M`. A depth whose
values are all negative (OpenGL's camera-frame z) is refused with the advice to negate it. Each
refusal is a :class:`~snell_bench.config.errors.ConfigError` (a ``ValueError``), one line that the
command line prints without a traceback. The reader of each file format is in
:mod:`snell_bench.scene.depth_files`.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from snell_bench.config.errors import ConfigError
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_files import DEPTH_SUFFIXES, PathLike, read_depth_file
from snell_bench.scene.photo_file import PhotoHeader, _existing_file

log = logging.getLogger(__name__)

__all__ = ["DEPTH_KINDS", "FARTHEST_MEDIAN_M", "NEAREST_SCENE_M", "depth_from_raw", "load_depth"]

#: What a depth file's values measure: ``"z"`` (along the optical axis) or ``"range"`` (along the ray).
DEPTH_KINDS = ("z", "range")
#: Metres: a depth map whose every valid value (scaled) is nearer than this is refused: no scene a
#: glass object stands in fits within 5 cm of the camera; the scale is wrong.
NEAREST_SCENE_M = 0.05
#: Metres: a depth map whose median (scaled) is farther than this is refused: the object stands on
#: a surface the photo shows near the camera, so most of a scene cannot lie beyond 1 km.
FARTHEST_MEDIAN_M = 1000.0


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
        ValueError: a folder.
        ConfigError: an unknown suffix, an unreadable file, more than one distinct channel,
            an unknown ``kind`` (``scene.depth_kind``), ``"range"`` without a camera, a size other
            than the camera's, no valid pixel at all (all negative: the message says to negate
            them), or values that contradict ``scale`` (:func:`depth_from_raw`).
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
    try:
        raw = read_depth_file(p, path, key)
    except ValueError as e:  # the reader's refusal names the key and the fix
        raise ConfigError([str(e)]) from e
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
        raise ConfigError(
            [
                f"scene.depth_kind={kind!r} is not a depth kind; choices: z|range "
                "(z: the distance along the optical axis; range: the distance along the pixel's ray)"
            ]
        )
    if kind == "range" and camera is None:
        raise ConfigError(
            [
                "scene.depth_kind=range needs the camera to turn ray distances into z: pass camera= "
                "(set scene.intrinsics or scene.fov_deg)"
            ]
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
        scale: as :func:`load_depth`.
        kind: as :func:`load_depth`.
        camera: as :func:`load_depth`.
        key: as :func:`load_depth`.
        photo: as :func:`load_depth`.

    Returns:
        float32 ``(H, W)`` z in metres, NaN where missing.

    Raises:
        ConfigError: see :func:`load_depth`.
    """
    scale = _check_depth_args(scale, kind, camera)
    problem = _type_problem(raw, scale, path, key)
    if problem is not None:
        raise ConfigError([problem])

    if camera is not None and raw.shape != camera.shape:
        raise ConfigError([_shape_message(raw.shape, camera, path, key, photo)])
    depth = raw.astype(np.float64) / (1.0 if scale is None else scale)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(depth) & (depth > 0)
    if not valid.any():
        raise ConfigError([_no_depth_message(depth, path, key)])
    if kind == "range":
        depth = depth / np.linalg.norm(camera.pixel_rays(normalize=False), axis=-1)
    depth = np.where(valid, depth, np.nan).astype(np.float32)
    _check_plausible(raw, depth[valid], scale, path, key)
    return depth


def _type_problem(raw: np.ndarray, scale: float | None, path: PathLike, key: str) -> str | None:
    """Why values of ``raw``'s type cannot be read at ``scale`` (see :func:`depth_from_raw`), or ``None``."""
    if raw.dtype.kind in "iu":
        if raw.dtype.itemsize == 1:
            steps = (
                ""
                if scale is None
                else f" (at scene.depth_scale={scale:g}: steps of {1 / scale:.3g} m up to {255 / scale:.3g} m)"
            )
            return (
                f"{key}='{path}' is an 8-bit file: its 256 levels{steps} are a picture of depth made for viewing, "
                "not a measurement; save the depth as a 16-bit PNG with its units per metre in scene.depth_scale "
                "(e.g. millimetres and scene.depth_scale=1000), or as float metres (.npy, .pfm, .exr, 32-bit .tif) "
                "with scene.depth_scale=null"
            )
        if scale is None:
            return (
                f"{key}='{path}' holds integers ({raw.dtype}): set scene.depth_scale to the file's units per "
                "metre (metres = value / scale), e.g. scene.depth_scale=5000 for TUM RGB-D, 1000 for millimetres"
            )
        if scale < 1.0:
            return (
                f"scene.depth_scale={scale:g} is below 1 for the integer file {key}='{path}': the scale is file "
                "units per metre (metres = value / scale), not metres per unit; "
                f"set scene.depth_scale={1 / scale:g}"
            )
    elif raw.dtype.kind != "f":
        return f"{key}='{path}' holds {raw.dtype} values, not numbers; save the depth as numbers"
    return None


def _no_depth_message(depth: np.ndarray, path: PathLike, key: str) -> str:
    """The error of a depth without a valid (finite, positive) value; when its values are negative
    it says to negate them (OpenGL and some renderers store the camera-frame z, negative in front)."""
    with np.errstate(invalid="ignore"):
        negative = int((np.isfinite(depth) & (depth < 0)).sum())
    fix = f"set {key} to a depth map (and scene.depth_scale to its units per metre)"
    if negative == 0:
        return f"{key}='{path}' has no valid depth: all {depth.size} pixels are 0, NaN or infinite; {fix}"
    which = f"all {depth.size} pixels are" if negative == depth.size else f"{negative} of its {depth.size} pixels are"
    rest = "" if negative == depth.size else " (the others 0, NaN or infinite)"
    return (
        f"{key}='{path}' has no valid depth: {which} negative{rest}: if the file stores depth as negative z "
        f"(OpenGL), negate it (save -depth); else {fix}"
    )


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
    raise ConfigError(
        [
            f"{key}='{path}' ({kind} values, median {raw_median:.4g}) read at scene.depth_scale="
            f"{'null' if scale is None else f'{scale:g}'} is implausible as depth in metres: {problem}; {hint}"
            + (
                " (a float file is read as metres without a scale)"
                if raw.dtype.kind == "f" and scale is not None
                else ""
            )
        ]
    )


def _check_scale(scale) -> float:
    try:
        s = float(scale)
    except (TypeError, ValueError):
        s = math.nan
    if isinstance(scale, bool) or not (math.isfinite(s) and s > 0):
        raise ConfigError(
            [
                f"scene.depth_scale={scale!r} must be a positive number of file units per metre "
                "(metres = value / scale), e.g. 5000 for TUM RGB-D, 1000 for millimetres"
            ]
        )
    return s
