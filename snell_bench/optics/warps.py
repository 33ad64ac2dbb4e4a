"""Pixel-to-pixel warps through a glass object: the :class:`WarpSet` and :func:`compute_warps`.

Convention:
    Every warp is a *backward* map: for each destination pixel it stores the source pixel
    coordinate ``(x, y)`` (float32, integer values at pixel centres), NaN where invalid, plus a
    bool mask. Perspective arrays are ``(H, W, ...)``, panorama arrays ``(Hp, 2 Hp, ...)``. The
    panorama is an equirectangular image centred at the object
    (:class:`~snell_bench.imaging.PanoramaCamera`, gravity-aligned with the scene's up direction,
    its centre column looking along the camera's horizontal forward direction).

    =====================  ==========  ======================================================
    field                  paper       meaning
    =====================  ==========  ======================================================
    ``refraction``         π^R         object pixel -> pixel of I⁻ the refracted ray ends on;
                                       identity outside the object
    ``pano_refraction``    π⁻¹         object pixel -> panorama pixel of the refracted ray's
                                       end
    ``pano_reflection``    π^-R        object pixel -> panorama pixel of the first-bounce
                                       mirror ray's end
    ``pano_to_persp``      π           panorama pixel -> perspective pixel (straight rays from
                                       the panorama centre, through the glass-free scene)
    ``reflection``         —           object pixel -> pixel of I⁻ the mirror ray ends on
    =====================  ==========  ======================================================

    Panorama coordinates of a ray are those of *its end point* seen from the panorama centre
    (exact parallax for the scene's geometry); only a ray that hits nothing uses its direction.

Far background at infinity:
    With ``infinity_tolerance_px``, background that moves no warp by more than that many pixels
    leaves the mesh and rays that leave the scene's geometry see it by their direction
    (:mod:`snell_bench.optics.far_field`).

Region of interest:
    With ``roi`` (the default), only pixels inside the projected bounding box of the object's
    vertices can see it (perspective projection maps the convex hull into the convex hull of the
    projected vertices), so primary rays are cast there only; the warps are identical.

Stages of :func:`compute_warps`:
    1. check the inputs, derive the options and the cache key, look the key up in the cache;
    2. build the ray-casting scene (far background, background mesh, tracer);
    3. cast primary rays in the region of interest: the object mask;
    4. trace the refracted paths through the object: π^R, bounces, Fresnel reflectance;
    5. cast the first-bounce mirror rays: the reflection warp;
    6. project both ray ends into the panorama: π⁻¹ and π^-R;
    7. cast the panorama's straight rays through the glass-free scene: π;
    8. gather the masks and statistics into a :class:`WarpSet` (and save it to the cache).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from snell_bench.imaging.equirect import PanoramaCamera
from snell_bench.optics.far_field import POINT_AT_INFINITY, AtInfinity, far_background_mask
from snell_bench.optics.tracer import BackgroundHit, HitKind, RefractionTrace, SceneTracer
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import BackgroundMesh, build_background
from snell_bench.scene.objects import GlassObject
from snell_bench.utils.io import atomic_write
from snell_bench.utils.timing import Timer

log = logging.getLogger(__name__)

__all__ = ["WarpSet", "compute_warps", "warp_inputs_hash", "far_background_mask", "object_pixel_box", "WARPS_VERSION"]

#: Bump when the meaning or computation of any warp changes (invalidates caches).
WARPS_VERSION = 1

_ARRAYS = (
    "object_mask",
    "refraction",
    "refraction_valid",
    "refraction_kind",
    "bounces",
    "fresnel",
    "reflection",
    "reflection_valid",
    "pano_refraction",
    "pano_refraction_valid",
    "pano_reflection",
    "pano_reflection_valid",
    "pano_to_persp",
    "pano_to_persp_valid",
    "pano_to_persp_object",
)

#: The arrays of a :class:`WarpSet` indexed by panorama pixels; every other one by image pixels.
_PANO_ARRAYS = ("pano_to_persp", "pano_to_persp_valid", "pano_to_persp_object")


@dataclass(eq=False)
class WarpSet:
    """All warps of one (scene, object) pair; see the module docstring for conventions.

    Examples:
        >>> import tempfile
        >>> T = np.eye(4); T[:3, 3] = [0.0, -0.5, 3.0]  # the unit-diameter sphere centred at z = 3
        >>> obj = GlassObject.sphere(subdivisions=2).transformed(T)
        >>> ws = compute_warps(np.full((24, 32), 5.0), Camera.from_fov(32, 24, 60.0), obj, pano_height=8)
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     back = WarpSet.load(ws.save(Path(tmp) / "warps.npz"))
        >>> bool(np.array_equal(back.refraction, ws.refraction, equal_nan=True)), back.ior
        (True, 1.5)
        >>> ws.summary()["object_pixels"]
        68
    """

    camera: Camera
    pano: PanoramaCamera
    ior: float
    #: (H, W) bool: the pixel's camera ray hits the object before the background.
    object_mask: np.ndarray
    #: (H, W, 2) float32 π^R; identity outside the object, NaN where invalid.
    refraction: np.ndarray
    #: (H, W) bool: true outside the object; inside, the refracted ray ends on a background point
    #: that I⁻ observes (front side, in view, not hidden behind other background geometry).
    refraction_valid: np.ndarray
    #: (H, W) int8 :class:`HitKind` of the refracted ray's end (NONE outside the object).
    refraction_kind: np.ndarray
    #: (H, W) uint8 surface interactions along the refracted path.
    bounces: np.ndarray
    #: (H, W) float32 unpolarised Fresnel reflectance at the first surface (0 outside the object).
    fresnel: np.ndarray
    #: (H, W, 2) float32 I⁻ pixel seen by the first-bounce mirror ray, NaN where invalid.
    reflection: np.ndarray
    reflection_valid: np.ndarray
    #: (H, W, 2) float32 π⁻¹: panorama pixel of the refracted ray (object pixels), NaN elsewhere.
    pano_refraction: np.ndarray
    pano_refraction_valid: np.ndarray
    #: (H, W, 2) float32 π^-R: panorama pixel of the mirror ray (object pixels), NaN elsewhere.
    pano_reflection: np.ndarray
    pano_reflection_valid: np.ndarray
    #: (Hp, Wp, 2) float32 π: perspective pixel seen by each panorama pixel, NaN where invalid.
    pano_to_persp: np.ndarray
    #: (Hp, Wp) bool: the panorama ray ends on a background point observed in I⁻.
    pano_to_persp_valid: np.ndarray
    #: (Hp, Wp) bool: valid, but the perspective pixel shows the glass object (the image *with*
    #: the object does not show that point there; I⁻ does).
    pano_to_persp_object: np.ndarray
    input_hash: str = ""
    options: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)

    # ------------------------------------------------------------------ aliases (paper notation)
    @property
    def pi_R(self) -> np.ndarray:
        """π^R, the refraction warp (:attr:`refraction`)."""
        return self.refraction

    @property
    def pi_inv(self) -> np.ndarray:
        """π⁻¹, the panorama warp of the refracted rays (:attr:`pano_refraction`)."""
        return self.pano_refraction

    @property
    def pi_minus_R(self) -> np.ndarray:
        """π^-R, the panorama warp of the mirror rays (:attr:`pano_reflection`)."""
        return self.pano_reflection

    @property
    def pi(self) -> np.ndarray:
        """π, the panorama-to-perspective warp (:attr:`pano_to_persp`)."""
        return self.pano_to_persp

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | os.PathLike) -> Path:
        """Write every array and the metadata to one ``.npz`` file, atomically.

        Args:
            path: the target file; missing parent folders are created.

        Returns:
            ``path`` as a :class:`~pathlib.Path`.
        """
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = {
            "version": WARPS_VERSION,
            "camera": self.camera.to_dict(),
            "pano": self.pano.to_dict(),
            "ior": self.ior,
            "input_hash": self.input_hash,
            "options": self.options,
            "stats": self.stats,
        }
        arrays = {k: getattr(self, k) for k in _ARRAYS}
        return atomic_write(path, lambda f: np.savez_compressed(f, meta=np.array(json.dumps(meta)), **arrays))

    @classmethod
    def load(cls, path: str | os.PathLike) -> "WarpSet":
        """Read a file written by :meth:`save`.

        Args:
            path: an ``.npz`` file written by :meth:`save`.

        Returns:
            The :class:`WarpSet` it holds.

        Raises:
            ValueError: the file holds warps of another :data:`WARPS_VERSION`.
        """
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            if meta.get("version") != WARPS_VERSION:
                raise ValueError(
                    f"{path} holds warps of version {meta.get('version')}, this code writes {WARPS_VERSION}; "
                    "delete the file to recompute it"
                )
            arrays = {k: z[k] for k in _ARRAYS}
        return cls(
            camera=Camera.from_dict(meta["camera"]),
            pano=PanoramaCamera.from_dict(meta["pano"]),
            ior=float(meta["ior"]),
            input_hash=meta["input_hash"],
            options=meta["options"],
            stats=meta["stats"],
            **arrays,
        )

    def summary(self) -> dict:
        """Counts for logs and reports.

        Returns:
            A JSON-serialisable dict: object pixels, valid refraction in the object, the end kinds of
            the refracted rays, the most bounces, the mean Fresnel reflectance in the object and the
            valid fraction of π.
        """
        m = self.object_mask
        n = int(m.sum())
        kinds = {k.name.lower(): int((self.refraction_kind[m] == k).sum()) for k in HitKind if k != HitKind.NONE}
        return {
            "object_pixels": n,
            "refraction_valid_in_object": int(self.refraction_valid[m].sum()),
            "refraction_end": kinds,
            "max_bounces_used": int(self.bounces.max()) if n else 0,
            "mean_fresnel_in_object": float(self.fresnel[m].mean()) if n else float("nan"),
            "pano_to_persp_valid_fraction": float(self.pano_to_persp_valid.mean()),
        }

    def __repr__(self) -> str:
        return f"WarpSet({self.camera!r}, pano={self.pano.height}x{self.pano.width}, ior={self.ior}, {self.summary()})"


def warp_inputs_hash(depth: np.ndarray, camera: Camera, obj: GlassObject, options: dict) -> str:
    """Content hash of everything a :class:`WarpSet` depends on (its cache key).

    Args:
        depth: the ``(H, W)`` depth map (hashed as float32).
        camera: the camera of ``depth``.
        obj: the placed glass object.
        options: the JSON-serialisable options of :func:`compute_warps` (key order does not matter).

    Returns:
        A 64-character hexadecimal SHA-256 digest.

    Examples:
        >>> cam = Camera.from_fov(8, 6, 60.0)
        >>> T = np.eye(4); T[:3, 3] = [0.0, -0.5, 3.0]  # the unit-diameter sphere centred at z = 3
        >>> obj = GlassObject.sphere(subdivisions=1).transformed(T)
        >>> a = warp_inputs_hash(np.ones((6, 8)), cam, obj, {"pano_height": 8, "eps": None})
        >>> len(a), a == warp_inputs_hash(np.ones((6, 8)), cam, obj, {"eps": None, "pano_height": 8})
        (64, True)
        >>> a == warp_inputs_hash(np.ones((6, 8)), cam, obj, {"pano_height": 16, "eps": None})
        False
    """
    h = hashlib.sha256()
    h.update(f"warps-v{WARPS_VERSION}".encode())
    d = np.ascontiguousarray(depth, dtype=np.float32)
    h.update(repr(d.shape).encode())
    h.update(d.tobytes())
    h.update(json.dumps(camera.to_dict(), sort_keys=True).encode())
    h.update(obj.content_hash().encode())
    h.update(json.dumps(options, sort_keys=True, default=str).encode())
    return h.hexdigest()


def object_pixel_box(obj: GlassObject, camera: Camera) -> tuple[int, int, int, int]:
    """The pixels whose camera rays can hit the object: the bounding box of its projection.

    Args:
        obj: a placed object in front of the camera.
        camera: the camera.

    Returns:
        ``(x0, y0, x1, y1)``, inclusive pixel-centre bounds of the projection of the object's
        vertices, clipped to the image.

    Examples:
        >>> T = np.eye(4); T[:3, 3] = [0.0, -0.5, 3.0]  # the unit-diameter sphere centred at z = 3
        >>> obj = GlassObject.sphere(subdivisions=2).transformed(T)
        >>> object_pixel_box(obj, Camera.from_fov(32, 24, 60.0))
        (10, 6, 21, 17)
    """
    pix, _ = camera.project(obj.vertices)
    lo, hi = np.floor(pix.min(axis=0)), np.ceil(pix.max(axis=0))
    x0, y0 = int(max(lo[0], 0)), int(max(lo[1], 0))
    x1, y1 = int(min(hi[0], camera.width - 1)), int(min(hi[1], camera.height - 1))
    return x0, y0, x1, y1


def compute_warps(
    depth: np.ndarray,
    camera: Camera,
    obj: GlassObject,
    pano_height: int = 1024,
    *,
    max_bounces: int = 8,
    normals: str = "interpolated",
    edge_threshold: float = 0.05,
    up=None,
    eps: float | None = None,
    cache_dir: str | os.PathLike | None = None,
    verify_visibility: bool = False,
    roi: bool = True,
    infinity_tolerance_px: float | None = None,
) -> WarpSet:
    """Trace the camera's rays through ``obj`` placed in the scene of ``depth`` and return every warp.

    Args:
        depth: ``(H, W)`` z-depth of the object-free image I⁻ (NaN, inf or <= 0 where unknown).
        camera: the camera of I⁻ (its size must match ``depth``).
        obj: a glass object in camera coordinates (placed or built with ``GlassObject.from_mesh``).
        pano_height: height of the 360° panorama (its width is twice that).
        max_bounces: surface interactions per refracted path before it is marked trapped.
        normals: ``"interpolated"`` (smooth shading normals, creased at sharp edges) or ``"face"``.
        edge_threshold: relative depth jump at which the background mesh is cut.
        up: the scene's up direction in camera coordinates; default ``obj.up``, else ``(0, -1, 0)``.
        eps: self-intersection offset (default: scaled to the object, see
            :mod:`~snell_bench.optics.tracer`).
        cache_dir: if given, warps are loaded from / saved to ``<cache_dir>/<input hash>.npz``.
        verify_visibility: also cast a camera ray to every background point a warp lands on
            (redundant for depth-map backgrounds, see :func:`_self_warp`; for checking).
        roi: cast primary rays only inside the object's projected bounding box (same result,
            faster).
        infinity_tolerance_px: treat background that moves no warp by more than this many pixels
            as at infinity (:mod:`~snell_bench.optics.far_field`); ``None`` keeps the exact geometry.

    Returns:
        The :class:`WarpSet` (from the cache if it holds one for these inputs).

    Raises:
        ValueError: the depth map does not match the camera, ``pano_height``, ``up`` or
            ``infinity_tolerance_px`` is invalid, the object is not placed, not in front of the
            camera or outside its view, or the depth map has no valid pixel.

    Examples:
        >>> cam = Camera.from_fov(32, 24, 60.0)
        >>> T = np.eye(4); T[:3, 3] = [0.0, -0.5, 3.0]  # the unit-diameter sphere centred at z = 3
        >>> obj = GlassObject.sphere(subdivisions=2).transformed(T)
        >>> ws = compute_warps(np.full(cam.shape, 5.0), cam, obj, pano_height=8)
        >>> ws.refraction.shape, ws.pano_to_persp.shape
        ((24, 32, 2), (8, 16, 2))
        >>> bool(ws.object_mask[12, 16]), round(float(ws.fresnel[12, 16]), 2)
        (True, 0.04)
        >>> ws.refraction[0, 0].tolist()  # the identity outside the object
        [0.0, 0.0]
    """
    # 1. inputs, options, cache
    depth = np.asarray(depth)
    up_vec, options = _warp_options(
        depth, camera, obj, pano_height, max_bounces=max_bounces, normals=normals, edge_threshold=edge_threshold,
        up=up, eps=eps, verify_visibility=verify_visibility, infinity_tolerance_px=infinity_tolerance_px,
    )
    pano_height = options["pano_height"]
    key = warp_inputs_hash(depth, camera, obj, options)
    cache_path, cached = _cache_lookup(cache_dir, key)
    if cached is not None:
        return cached
    _check_object_in_view(obj, camera)
    timer = Timer()

    # 2. the ray-casting scene
    with timer("build"):
        scene = _build_scene(depth, camera, obj, infinity_tolerance_px, pano_height, edge_threshold=edge_threshold,
                             max_bounces=max_bounces, normals=normals, eps=eps)
    # 3. primary rays: which pixels see the object
    with timer("primary"):
        primary = _trace_primary(camera, obj, scene.tracer, roi)
    # 4. refraction through the object
    with timer("refraction"):
        tr = _trace_refraction(scene, primary)
        arrays = _refraction_warps(camera, scene.tracer, tr, primary, verify_visibility)
    # 5. first-bounce reflection
    with timer("reflection"):
        refl = _trace_reflection(scene, tr)
        arrays |= _reflection_warps(camera, scene.tracer, refl, primary, verify_visibility)
    # 6. panorama coordinates of the refracted and mirror rays
    with timer("panorama"):
        pano = PanoramaCamera.level(obj.center, up_vec, (0.0, 0.0, 1.0), pano_height)
        arrays |= _panorama_warps(pano, tr, refl, primary)
    # 7. the panorama seen through the glass-free scene
    with timer("panorama"):
        arrays |= _pano_to_persp_warp(pano, camera, scene, primary, verify_visibility)
    # 8. masks, statistics, the WarpSet
    arrays["object_mask"] = primary.mask
    stats = _warp_stats(timer, scene, primary, roi)
    ws = _assemble(camera, pano, obj.ior, arrays, input_hash=key, options=options, stats=stats)
    if cache_path is not None:
        ws.save(cache_path)
    log.info("warps: %s", ws.summary())
    return ws


# ---------------------------------------------------------------------------------------------
# stage 1: inputs, options and the cache
# ---------------------------------------------------------------------------------------------
def _warp_options(
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
) -> tuple[np.ndarray, dict]:
    """Check the arguments of :func:`compute_warps` and collect the options its warps depend on.

    Args:
        depth, camera, obj, pano_height, max_bounces, normals, edge_threshold, up, eps,
        verify_visibility, infinity_tolerance_px: as :func:`compute_warps` (``depth`` an array).

    Returns:
        ``(up (3,) unit float64, options)``: ``options`` is the JSON-serialisable dict hashed into
        the cache key and stored in the :class:`WarpSet` (``pano_height`` as an int, ``up`` rounded
        to 12 decimals; ``infinity_tolerance_px`` only when given, so exact warps keep their keys).

    Raises:
        ValueError: ``depth`` does not match the camera, or ``pano_height`` or ``up`` is invalid.
    """
    if depth.ndim != 2 or depth.shape != camera.shape:
        raise ValueError(
            f"depth has shape {depth.shape} but the camera is {camera.height}x{camera.width}; "
            "pass a depth map of the camera's (height, width)"
        )
    if int(pano_height) != pano_height or pano_height < 2:
        raise ValueError(f"pano_height must be an integer >= 2, got {pano_height!r}")
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
    return up_vec, options


def _cache_lookup(cache_dir: str | os.PathLike | None, key: str) -> tuple[Path | None, WarpSet | None]:
    """The cache file of ``key`` and the :class:`WarpSet` it holds.

    Args:
        cache_dir: the cache folder, or ``None`` for no caching.
        key: the :func:`warp_inputs_hash` of the inputs.

    Returns:
        ``(path or None, cached WarpSet or None)``: ``path`` is ``<cache_dir>/<key>.npz``; the
        :class:`WarpSet` is loaded when that file exists.
    """
    if cache_dir is None:
        return None, None
    path = Path(cache_dir) / f"{key}.npz"
    if not path.is_file():
        return path, None
    log.info("warps: loading cached %s", path)
    return path, WarpSet.load(path)


def _check_object_in_view(obj: GlassObject, camera: Camera) -> None:
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


# ---------------------------------------------------------------------------------------------
# stage 2: the ray-casting scene
# ---------------------------------------------------------------------------------------------
@dataclass
class _Scene:
    """What the rays are cast against."""

    background: BackgroundMesh  #: the depth mesh (far pixels left out) and the box of unobserved space
    tracer: SceneTracer
    at_inf: AtInfinity | None  #: resolves rays towards far background (``None``: no far pixel)
    far_stats: dict  #: the ``far_background`` statistics (empty without a tolerance)


def _far_background(
    depth: np.ndarray, camera: Camera, obj: GlassObject, tolerance_px: float | None, pano_height: int
) -> tuple[np.ndarray | None, dict]:
    """The far background of :func:`~snell_bench.optics.far_field.far_background_mask` for the
    object's bounding ball (centre ``obj.center``, radius the farthest vertex).

    Args:
        depth, camera, obj, pano_height: as :func:`compute_warps`.
        tolerance_px: ``infinity_tolerance_px``; ``None`` keeps the exact geometry.

    Returns:
        ``(far (H, W) bool or None, stats)``: ``None`` and ``{}`` without a tolerance; else the
        tolerance, the far fraction, the largest bound among far pixels and the nearest far depth
        (``None`` where no pixel is far).
    """
    if tolerance_px is None:
        return None, {}
    radius = float(np.linalg.norm(obj.vertices - obj.center, axis=1).max())
    far, bound = far_background_mask(depth, camera, obj.center, radius, float(tolerance_px), pano_height)
    stats = {
        "tolerance_px": float(tolerance_px),
        "far_fraction": float(far.mean()),
        "max_bound_px_of_far": float(bound[far].max()) if far.any() else None,
        "nearest_far_depth": float(np.asarray(depth)[far].min()) if far.any() else None,
    }
    return far, stats


def _build_scene(
    depth: np.ndarray,
    camera: Camera,
    obj: GlassObject,
    infinity_tolerance_px: float | None,
    pano_height: int,
    *,
    edge_threshold: float,
    max_bounces: int,
    normals: str,
    eps: float | None,
) -> _Scene:
    """Build the background mesh (without the far background, :func:`_far_background`; its box
    encloses the object) and the tracer of the object in it.

    Args:
        depth, camera, obj, infinity_tolerance_px, pano_height, edge_threshold, max_bounces,
        normals, eps: as :func:`compute_warps`.

    Returns:
        The :class:`_Scene`.
    """
    far, far_stats = _far_background(depth, camera, obj, infinity_tolerance_px, pano_height)
    lo, hi = obj.mesh.bounds
    background = build_background(depth, camera, edge_threshold, extra_points=np.stack([lo, hi]), exclude=far)
    tracer = SceneTracer(background, obj, max_bounces=max_bounces, normals=normals, eps=eps)
    at_inf = AtInfinity(camera, far) if far is not None and far.any() else None
    return _Scene(background, tracer, at_inf, far_stats)


# ---------------------------------------------------------------------------------------------
# stage 3: primary rays
# ---------------------------------------------------------------------------------------------
@dataclass
class _Primary:
    """The pixels that see the object (indices into the flattened ``(H * W)`` image)."""

    traced: int  #: primary rays cast (the region of interest, or every pixel)
    pixels: np.ndarray  #: (N,) int flat indices of the object pixels, row-major
    rays: np.ndarray  #: (N, 3) unit camera rays of those pixels
    mask: np.ndarray  #: (H * W,) bool object mask


def _trace_primary(camera: Camera, obj: GlassObject, tracer: SceneTracer, roi: bool) -> _Primary:
    """Cast camera rays through pixel centres; a pixel sees the object where its ray hits the object
    before the background.

    Args:
        camera, obj, roi: as :func:`compute_warps` (with ``roi``, only the pixels of
            :func:`object_pixel_box` are cast).
        tracer: the scene's tracer.

    Returns:
        The :class:`_Primary` rays (an empty mask is logged as a warning).
    """
    H, W = camera.shape
    if roi:
        x0, y0, x1, y1 = object_pixel_box(obj, camera)
        yy, xx = np.mgrid[y0 : y1 + 1, x0 : x1 + 1]
        sel = (yy * W + xx).reshape(-1)
        rays_sel = camera.pixel_rays(np.stack([xx, yy], -1).reshape(-1, 2).astype(np.float64))
    else:
        sel = np.arange(H * W)
        rays_sel = camera.pixel_rays().reshape(-1, 3)
    t_obj = tracer.cast_camera_object(rays_sel)
    hit = np.flatnonzero(np.isfinite(t_obj))
    if len(hit):
        t_bg = tracer.cast_background(np.zeros((len(hit), 3)), rays_sel[hit]).t
        hit = hit[t_obj[hit] < t_bg]
    pixels = sel[hit]
    mask = np.zeros(H * W, bool)
    mask[pixels] = True
    if not len(pixels):
        log.warning("%s covers no pixel centre of the %dx%d image: the object mask is empty", obj.name, W, H)
    return _Primary(traced=int(len(sel)), pixels=pixels, rays=rays_sel[hit], mask=mask)


# ---------------------------------------------------------------------------------------------
# stage 4: refraction
# ---------------------------------------------------------------------------------------------
def _trace_refraction(scene: _Scene, primary: _Primary) -> RefractionTrace:
    """Trace the object pixels' camera rays through the object (far background resolved).

    Args:
        scene: the ray-casting scene.
        primary: the object pixels.

    Returns:
        The :class:`~snell_bench.optics.tracer.RefractionTrace`, one row per object pixel.
    """
    tr = scene.tracer.trace(np.zeros((len(primary.pixels), 3)), primary.rays)
    if scene.at_inf is not None:
        scene.at_inf.resolve(tr.kind, tr.point, tr.direction, tr.on_box)
    return tr


def _refraction_warps(
    camera: Camera, tracer: SceneTracer, tr: RefractionTrace, primary: _Primary, verify_visibility: bool
) -> dict[str, np.ndarray]:
    """π^R and the per-pixel data of the refracted paths, over the whole image.

    Args:
        camera, verify_visibility: as :func:`compute_warps`.
        tracer: the scene's tracer.
        tr: the refracted paths of the object pixels.
        primary: the object pixels.

    Returns:
        Flat ``(H * W, ...)`` arrays ``refraction`` (the identity outside the object, NaN where
        invalid), ``refraction_valid``, ``refraction_kind``, ``bounces`` (clipped to 255) and
        ``fresnel`` (0 outside the object).
    """
    H, W = camera.shape
    cand = primary.pixels
    refraction = camera.pixel_grid().reshape(-1, 2).astype(np.float32)
    refraction_valid = np.ones(H * W, bool)
    src, ok = _self_warp(camera, tracer, tr.point, tr.kind, verify_visibility)
    refraction[cand] = np.where(ok[:, None], src, np.nan)
    refraction_valid[cand] = ok
    kind = np.zeros(H * W, np.int8)
    kind[cand] = tr.kind
    bounces = np.zeros(H * W, np.uint8)
    bounces[cand] = np.minimum(tr.bounces, 255)
    fres = np.zeros(H * W, np.float32)
    fres[cand] = tr.fresnel
    return {
        "refraction": refraction,
        "refraction_valid": refraction_valid,
        "refraction_kind": kind,
        "bounces": bounces,
        "fresnel": fres,
    }


# ---------------------------------------------------------------------------------------------
# stage 5: reflection
# ---------------------------------------------------------------------------------------------
def _trace_reflection(scene: _Scene, tr: RefractionTrace) -> BackgroundHit:
    """Cast the first-bounce mirror rays against the background (far background resolved).

    Args:
        scene: the ray-casting scene.
        tr: the refracted paths (their first surface points and mirror directions).

    Returns:
        The :class:`~snell_bench.optics.tracer.BackgroundHit` of each mirror ray.
    """
    refl = scene.tracer.trace_reflection(tr)
    if scene.at_inf is not None:
        scene.at_inf.resolve(refl.kind, refl.point, tr.reflected, refl.on_box)
    return refl


def _reflection_warps(
    camera: Camera, tracer: SceneTracer, refl: BackgroundHit, primary: _Primary, verify_visibility: bool
) -> dict[str, np.ndarray]:
    """The reflection warp over the whole image.

    Args:
        camera, verify_visibility: as :func:`compute_warps`.
        tracer: the scene's tracer.
        refl: where the mirror rays of the object pixels end.
        primary: the object pixels.

    Returns:
        Flat ``(H * W, ...)`` arrays ``reflection`` (NaN where invalid and outside the object) and
        ``reflection_valid``.
    """
    H, W = camera.shape
    cand = primary.pixels
    src_r, ok_r = _self_warp(camera, tracer, refl.point, refl.kind, verify_visibility)
    reflection = np.full((H * W, 2), np.nan, np.float32)
    reflection_valid = np.zeros(H * W, bool)
    reflection[cand] = np.where(ok_r[:, None], src_r, np.nan)
    reflection_valid[cand] = ok_r
    return {"reflection": reflection, "reflection_valid": reflection_valid}


# ---------------------------------------------------------------------------------------------
# stage 6: panorama coordinates of the refracted and mirror rays
# ---------------------------------------------------------------------------------------------
def _panorama_warps(
    pano: PanoramaCamera, tr: RefractionTrace, refl: BackgroundHit, primary: _Primary
) -> dict[str, np.ndarray]:
    """π⁻¹ and π^-R: panorama pixels of the ends of the refracted and mirror rays.

    Args:
        pano: the panorama centred at the object.
        tr: the refracted paths of the object pixels.
        refl: where their mirror rays end.
        primary: the object pixels.

    Returns:
        Flat ``(H * W, ...)`` arrays ``pano_refraction`` (NaN outside the object and where the
        refracted ray did not leave the object), ``pano_refraction_valid``, ``pano_reflection``
        and ``pano_reflection_valid``.
    """
    n, cand = len(primary.mask), primary.pixels
    exited = np.isin(tr.kind, (HitKind.OBSERVED, HitKind.UNOBSERVED, HitKind.ESCAPED))
    pr = _pano_coords(pano, tr.point, tr.direction)
    pano_refraction = np.full((n, 2), np.nan, np.float32)
    pano_refraction[cand] = np.where(exited[:, None], pr, np.nan)
    pano_refraction_valid = np.zeros(n, bool)
    pano_refraction_valid[cand] = exited & np.isfinite(pr).all(axis=1)
    rr = _pano_coords(pano, refl.point, tr.reflected)
    pano_reflection = np.full((n, 2), np.nan, np.float32)
    pano_reflection[cand] = rr
    pano_reflection_valid = np.zeros(n, bool)
    pano_reflection_valid[cand] = np.isfinite(rr).all(axis=1)
    return {
        "pano_refraction": pano_refraction,
        "pano_refraction_valid": pano_refraction_valid,
        "pano_reflection": pano_reflection,
        "pano_reflection_valid": pano_reflection_valid,
    }


def _pano_coords(pano: PanoramaCamera, points: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Panorama pixels of ray ends.

    Args:
        pano: the panorama.
        points: ``(N, 3)`` ray ends, NaN where a ray hits nothing.
        directions: ``(N, 3)`` ray directions.

    Returns:
        ``(N, 2)`` float32 pixels of each end point seen from the panorama centre, of the direction
        where there is no end point, NaN where neither is finite.
    """
    has_point = np.isfinite(points).all(axis=1)
    out = np.full((len(points), 2), np.nan)
    if has_point.any():
        out[has_point] = pano.project_points(points[has_point])
    rest = ~has_point & np.isfinite(directions).all(axis=1)
    if rest.any():
        out[rest] = pano.project_directions(directions[rest])
    return out.astype(np.float32)


# ---------------------------------------------------------------------------------------------
# stage 7: the panorama seen through the glass-free scene, and the self-warp
# ---------------------------------------------------------------------------------------------
def _pano_to_persp_warp(
    pano: PanoramaCamera, camera: Camera, scene: _Scene, primary: _Primary, verify_visibility: bool
) -> dict[str, np.ndarray]:
    """π: cast a straight ray from the panorama centre through every panorama pixel and find the
    perspective pixel that observes its end.

    Args:
        pano: the panorama centred at the object.
        camera, verify_visibility: as :func:`compute_warps`.
        scene: the ray-casting scene (the object is not hit: the scene is glass-free).
        primary: the object pixels.

    Returns:
        Flat ``(Hp * Wp, ...)`` arrays ``pano_to_persp`` (NaN where invalid),
        ``pano_to_persp_valid`` and ``pano_to_persp_object`` (valid, and the nearest perspective
        pixel is an object pixel).
    """
    H, W = camera.shape
    pdirs = pano.directions().reshape(-1, 3)
    ph = scene.tracer.cast_background(np.broadcast_to(pano.center, pdirs.shape), pdirs)
    if scene.at_inf is not None:
        scene.at_inf.resolve(ph.kind, ph.point, pdirs, ph.on_box)
    pix, pok = _self_warp(camera, scene.tracer, ph.point, ph.kind, verify_visibility)
    pano_to_persp = np.where(pok[:, None], pix, np.nan).astype(np.float32)
    near = np.rint(np.where(pok[:, None], pix, 0)).astype(np.int64)
    near[:, 0] = near[:, 0].clip(0, W - 1)
    near[:, 1] = near[:, 1].clip(0, H - 1)
    pano_to_persp_object = pok & primary.mask[near[:, 1] * W + near[:, 0]]
    return {"pano_to_persp": pano_to_persp, "pano_to_persp_valid": pok, "pano_to_persp_object": pano_to_persp_object}


def _self_warp(
    camera: Camera, tracer: SceneTracer, points: np.ndarray, kind: np.ndarray, verify_visibility: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of I⁻ that observe background points.

    The background is a depth-map mesh: its triangles project onto the image without overlapping,
    so the front side of any of its points is seen by the camera (nothing else in I⁻ can hide it).
    ``verify_visibility`` casts the camera ray to every point anyway (the test suite checks that
    both agree); points at infinity (far background) are visible by construction.

    Args:
        camera: the camera of I⁻.
        tracer: the scene's tracer (for ``verify_visibility``).
        points: ``(N, 3)`` ray ends, NaN where none.
        kind: ``(N,)`` :class:`~snell_bench.optics.tracer.HitKind` of each end.
        verify_visibility: cast a camera ray to every observed point.

    Returns:
        ``(pixels (N, 2) float32, ok (N,) bool)``: ``ok`` where the point is observed, in view and
        in front of the camera (and, with ``verify_visibility``, visible).
    """
    pix, z = camera.project(np.where(np.isfinite(points), points, 0.0))
    ok = (kind == HitKind.OBSERVED) & camera.in_view(pix) & (z > 0)
    if verify_visibility and ok.any():
        finite = np.linalg.norm(np.where(np.isfinite(points), points, 0.0), axis=1) < POINT_AT_INFINITY / 10
        idx = np.flatnonzero(ok & finite)
        ok[idx] = tracer.visible_from_camera(points[idx])
    return pix.astype(np.float32), ok


# ---------------------------------------------------------------------------------------------
# stage 8: statistics and the WarpSet
# ---------------------------------------------------------------------------------------------
def _warp_stats(timer: Timer, scene: _Scene, primary: _Primary, roi: bool) -> dict:
    """The ``stats`` of a :class:`WarpSet`.

    Args:
        timer: the stage timings (rounded to 0.1 ms).
        scene: the ray-casting scene.
        primary: the primary rays.
        roi: as :func:`compute_warps`.

    Returns:
        A JSON-serialisable dict: ``timings_s``, ``invalid_depth_pixels``, ``cut_triangles``,
        ``roi``, ``traced_primary_rays``, ``far_background`` (with a tolerance only),
        ``background_triangles`` and ``eps``.
    """
    return {
        "timings_s": timer.rounded(4),
        "invalid_depth_pixels": scene.background.invalid_pixels,
        "cut_triangles": scene.background.cut_triangles,
        "roi": bool(roi),
        "traced_primary_rays": primary.traced,
        **({"far_background": scene.far_stats} if scene.far_stats else {}),
        "background_triangles": int(len(scene.background.faces)),
        "eps": scene.tracer.eps,
    }


def _assemble(
    camera: Camera, pano: PanoramaCamera, ior: float, arrays: dict[str, np.ndarray], **meta
) -> WarpSet:
    """A :class:`WarpSet` from flat per-pixel arrays.

    Args:
        camera: the perspective camera (``(H, W)`` arrays).
        pano: the panorama (``(Hp, Wp)`` arrays).
        ior: the object's index of refraction.
        arrays: every array of :data:`_ARRAYS`, flattened over its pixels (``(H * W, ...)`` or
            ``(Hp * Wp, ...)``).
        **meta: ``input_hash``, ``options`` and ``stats``.

    Returns:
        The :class:`WarpSet`, its arrays reshaped to ``(H, W, ...)`` and ``(Hp, Wp, ...)``.
    """
    shaped = {}
    for name in _ARRAYS:
        a = arrays[name]
        shaped[name] = a.reshape((pano.shape if name in _PANO_ARRAYS else camera.shape) + a.shape[1:])
    return WarpSet(camera=camera, pano=pano, ior=ior, **shaped, **meta)
