"""Stage 1 of :func:`~snell_bench.optics.warps.compute_warps`: its arguments checked, the options its
warps depend on (hashed into the cache key), the cache and the object's placement checked."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from snell_bench.optics.conventions import PANO_AXES, PANO_CENTERS
from snell_bench.optics.warpset import WarpSet
from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject

log = logging.getLogger(__name__)

__all__ = ["Variant", "warp_options", "cache_lookup", "check_object_in_view"]


@dataclass(frozen=True)
class Variant:
    """Where the paper's text and the authors' code compute the warps differently (the recipe
    switches of the ``warps`` node; :func:`~snell_bench.optics.warps.compute_warps` documents each).
    The defaults are the paper's."""

    back_faces: bool = False
    reflection_parallax: bool = True
    half_pixel_shift: bool = False
    pano_center: str = "bbox"
    pano_axes: str = "level"

    def changed(self) -> dict:
        """The fields that differ from the defaults (the options hashed into the cache key: warps
        with the defaults keep their keys)."""
        default = Variant()
        return {k: v for k, v in vars(self).items() if getattr(default, k) != v}


def warp_options(
    depth: np.ndarray,
    camera: Camera,
    obj: GlassObject,
    pano_height,
    *,
    max_bounces,
    normals: str,
    edge_threshold,
    up,
    eps,
    verify_visibility,
    infinity_tolerance_px,
    roi: bool = True,
    variant: Variant = Variant(),
) -> tuple[np.ndarray, dict]:
    """Check the arguments of :func:`~snell_bench.optics.warps.compute_warps` and collect the options
    its warps depend on.

    Args:
        depth, camera, obj, pano_height, max_bounces, normals, edge_threshold, up, eps,
        verify_visibility, infinity_tolerance_px, roi: as ``compute_warps`` (``depth`` an array;
        ``max_bounces`` the limit in force, after ``recipe_max_bounces``).
        variant: the recipe switches.

    Returns:
        ``(up (3,) unit float64, options)``: ``options`` is the JSON-serialisable dict hashed into
        the cache key and stored in the :class:`WarpSet` (``pano_height`` as an int, ``up`` rounded
        to 12 decimals; ``infinity_tolerance_px`` only when given and the recipe switches only where
        they differ from the paper's, so the other warps keep their keys).

    Raises:
        ValueError: ``depth`` does not match the camera, or ``pano_height``, ``up``,
            ``pano_center`` or ``pano_axes`` is invalid.
    """
    if depth.ndim != 2 or depth.shape != camera.shape:
        raise ValueError(
            f"depth has shape {depth.shape} but the camera is {camera.height}x{camera.width}; "
            "pass a depth map of the camera's (height, width)"
        )
    if int(pano_height) != pano_height or pano_height < 2:
        raise ValueError(f"pano_height must be an integer >= 2, got {pano_height!r}")
    if variant.pano_center not in PANO_CENTERS:
        raise ValueError(f"pano_center={variant.pano_center!r} is unknown; use one of {list(PANO_CENTERS)}")
    if variant.pano_axes not in PANO_AXES:
        raise ValueError(f"pano_axes={variant.pano_axes!r} is unknown; use one of {list(PANO_AXES)}")
    pano_height = int(pano_height)
    up_vec = np.asarray(up if up is not None else (obj.up if obj.up is not None else (0.0, -1.0, 0.0)), np.float64)
    if up_vec.shape != (3,) or not np.all(np.isfinite(up_vec)) or np.linalg.norm(up_vec) == 0:
        raise ValueError(f"up must be a non-zero 3-vector, got {up!r}")
    up_vec = up_vec / np.linalg.norm(up_vec)
    options = {
        "pano_height": pano_height,
        "max_bounces": int(max_bounces),
        "normals": normals,
        "edge_threshold": float(edge_threshold),
        "up": up_vec.round(12).tolist(),
        "eps": eps,
        "verify_visibility": bool(verify_visibility),
    }
    if infinity_tolerance_px is not None:  # keeps the hashes of exact warps unchanged
        options["infinity_tolerance_px"] = float(infinity_tolerance_px)
    if not roi:  # the same arrays, other statistics (traced rays, timings): a cache entry of its own
        options["roi"] = False
    options.update(variant.changed())
    return up_vec, options


def cache_lookup(
    cache_dir: str | os.PathLike | None, key: str, shape: tuple[int, int] | None = None
) -> tuple[Path | None, WarpSet | None]:
    """The cache file of ``key`` and the :class:`WarpSet` it holds.

    Args:
        cache_dir: the cache folder, or ``None`` for no caching.
        key: the :func:`~snell_bench.optics.warpset.warp_inputs_hash` of the inputs.
        shape: the ``(H, W)`` of the request's depth map when the caller knows it, else ``None``.

    Returns:
        ``(path or None, cached WarpSet or None)``: ``path`` is ``<cache_dir>/<key>.npz``; the
        :class:`WarpSet` is loaded when that file exists and holds the warps of ``key``. An entry
        that cannot be read (truncated, corrupt, of another version or layout, arrays of
        inconsistent shapes) or holds other warps (its stored ``input_hash`` is not ``key``, its
        camera is not of ``shape``: :meth:`WarpSet.mismatch`; a file copied under the wrong name)
        is a miss: it is logged as a warning with its path, deleted, and the warps are recomputed,
        never an error.
    """
    if cache_dir is None:
        return None, None
    path = Path(cache_dir) / f"{key}.npz"
    if not path.is_file():
        return path, None
    log.info("warps: loading cached %s", path)
    try:
        cached = WarpSet.load(path)
    except Exception as e:  # noqa: BLE001 - any unreadable entry is a miss; the recomputation overwrites it
        log.warning(
            "warps: cache entry %s cannot be read (%s: %s); deleting it and recomputing", path, type(e).__name__, e
        )
        path.unlink(missing_ok=True)
        return path, None
    problem = cached.mismatch(key, shape)
    if problem is not None:
        log.warning(
            "warps: cache entry %s was loaded for key %s but holds the warps of input_hash %s (%s); "
            "deleting it and recomputing",
            path,
            key,
            cached.input_hash or "(none)",
            problem,
        )
        path.unlink(missing_ok=True)
        return path, None
    return path, cached


def check_object_in_view(obj: GlassObject, camera: Camera) -> None:
    """Raise ``ValueError`` unless ``obj`` is placed, entirely in front of the camera (z > 0) and
    its projection overlaps the image."""
    if not obj.placed:
        raise ValueError(
            f"{obj.name}: the object is in its canonical frame, not in camera coordinates; place it first "
            "(snell_bench.scene.place_object) or build it with GlassObject.from_mesh(...) from camera-frame vertices"
        )
    v = obj.vertices
    zmin = float(v[:, 2].min())
    if zmin <= 0:
        where = "behind the camera" if float(v[:, 2].max()) <= 0 else "crossing the camera plane (z <= 0)"
        raise ValueError(
            f"{obj.name}: the object is {where} (min z = {zmin:.4g}); move it in front of the camera (z > 0)"
        )
    pix, _ = camera.project(v)
    lo, hi = pix.min(axis=0), pix.max(axis=0)
    if hi[0] < -0.5 or lo[0] > camera.width - 0.5 or hi[1] < -0.5 or lo[1] > camera.height - 0.5:
        raise ValueError(
            f"{obj.name}: the object is outside the view (its projection spans x in [{lo[0]:.1f}, {hi[0]:.1f}], "
            f"y in [{lo[1]:.1f}, {hi[1]:.1f}], the image is {camera.width}x{camera.height}); move it into the frustum"
        )
