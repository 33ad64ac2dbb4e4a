"""Pixel-to-pixel warps through a glass object: the :class:`WarpSet` and :func:`compute_warps`.

Convention:
    Every warp is a *backward* map: for each destination pixel it stores the source pixel
    coordinate ``(x, y)`` (float32, integer values at pixel centres), NaN where invalid, plus a
    bool mask. Perspective arrays are ``(H, W, ...)``, panorama arrays ``(Hp, 2 Hp, ...)``. The
    panorama is an equirectangular image centred at the object
    (:class:`~snell_bench.imaging.PanoramaCamera`; by default at the centre of its bounding box,
    gravity-aligned with the scene's up direction, its centre column looking along the camera's
    horizontal forward direction; ``pano_center`` and ``pano_axes`` choose the authors' pose:
    :func:`~snell_bench.optics.conventions.panorama_pose`).

    =========================  ========  ======================================================
    field                      paper     meaning
    =========================  ========  ======================================================
    ``refraction``             π^R       object pixel -> pixel of I⁻ the refracted ray ends on;
                                         identity outside the object
    ``pano_refraction``        π⁻¹       object pixel -> panorama pixel of the refracted ray's
                                         end
    ``pano_refraction_frame``  π⁻¹       every pixel: ``pano_refraction`` on the object, else
                                         the panorama pixel of the background point the pixel
                                         shows (NaN where the panorama centre cannot see it)
    ``pano_reflection``        π^-R      object pixel -> panorama pixel of the first-bounce
                                         mirror ray's end
    ``pano_to_persp``          π         panorama pixel -> perspective pixel (straight rays from
                                         the panorama centre, through the glass-free scene)
    ``reflection``             —         object pixel -> pixel of I⁻ the mirror ray ends on
    =========================  ========  ======================================================

    Panorama coordinates of a ray are those of *its end point* seen from the panorama centre
    (exact parallax for the scene's geometry), valid only where the centre sees that point (a
    surface in between would lend its colour to the glass: :mod:`~snell_bench.optics.occlusion`);
    only a ray that hits nothing uses its direction (and π^-R with ``reflection_parallax=False``).

Far background at infinity:
    With ``infinity_tolerance_px``, background that moves no warp by more than that many pixels
    leaves the mesh and rays that leave the scene's geometry see it by their direction
    (:mod:`snell_bench.optics.far_field`).

Region of interest:
    With ``roi`` (the default), only pixels inside the projected bounding box of the object's
    vertices can see it (perspective projection maps the convex hull into the convex hull of the
    projected vertices), so primary rays are cast there only; the warps are identical.

Recipe switches of :func:`compute_warps` (:class:`~snell_bench.optics.options.Variant`):
    - ``back_faces``: a refracted ray that ends on the back side of the depth mesh is valid in π^R (at
      the pixel that shows the front of its end point), and π⁻¹'s occlusion test accepts either side
      of the depth mesh (the authors' code); ``False``: such an end is unobserved.
    - ``reflection_parallax``: π^-R is the panorama pixel of the mirror ray's end seen from the
      panorama centre, where the centre sees it; ``False``: of the mirror direction alone.
    - ``half_pixel_shift``: shift the source coordinates of π^R, the reflection warp and π by +0.5 px
      and keep sources in ``[0, W - 1) x [0, H - 1)``
      (:func:`~snell_bench.optics.conventions.shift_half_pixel`: the authors' sampling).
    - ``pano_center``: the panorama's centre, ``bbox`` or ``centroid``; ``pano_axes``: its axes,
      ``level`` or ``camera`` (:func:`~snell_bench.optics.conventions.panorama_pose`).

Stages of :func:`compute_warps`:
    1. check the inputs, derive the options and the cache key, look the key up in the cache;
    2. build the ray-casting scene (far background, background mesh, tracer);
    3. cast primary rays in the region of interest: the object mask;
    4. trace the refracted paths through the object: π^R, bounces, Fresnel reflectance;
    5. cast the first-bounce mirror rays: the reflection warp;
    6. project both ray ends into the panorama and re-cast from its centre to each: π⁻¹ and π^-R;
    7. cast the panorama's straight rays through the glass-free scene: π; re-cast from the
       panorama centre to every background point the image shows: π⁻¹ over the whole frame;
    8. shift the perspective maps by half a pixel (``half_pixel_shift`` only), gather the masks
       and statistics into a :class:`WarpSet` (and save it to the cache).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from snell_bench.imaging.equirect import PanoramaCamera
from snell_bench.optics.conventions import panorama_pose, shift_half_pixel
from snell_bench.optics.far_field import AtInfinity, far_background_mask
from snell_bench.optics.options import Variant, cache_lookup, check_object_in_view, warp_options
from snell_bench.optics.tracer import SceneTracer
from snell_bench.optics.warp_maps import (
    PrimaryRays,
    RayScene,
    pano_refraction_frame_warp,
    pano_to_persp_warp,
    panorama_warps,
    reflection_warps,
    refraction_warps,
    trace_reflection,
    trace_refraction,
)
from snell_bench.optics.warpset import WARPS_VERSION, WarpSet, assemble, warp_inputs_hash
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import build_background
from snell_bench.scene.objects import GlassObject
from snell_bench.utils.timing import Timer

log = logging.getLogger(__name__)

__all__ = ["WarpSet", "compute_warps", "warp_inputs_hash", "far_background_mask", "object_pixel_box", "WARPS_VERSION"]


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
    recipe_max_bounces: int | None = None,
    back_faces: bool = False,
    reflection_parallax: bool = True,
    half_pixel_shift: bool = False,
    pano_center: str = "bbox",
    pano_axes: str = "level",
) -> WarpSet:
    """Trace the camera's rays through ``obj`` placed in the scene of ``depth`` and return every warp.

    The recipe switches ``back_faces``, ``reflection_parallax``, ``half_pixel_shift``, ``pano_center``
    and ``pano_axes`` are described in the module docstring.

    Args:
        depth: ``(H, W)`` z-depth of the object-free image I⁻ (NaN, inf or <= 0 where unknown).
        camera: the camera of I⁻ (its size must match ``depth``).
        obj: a glass object in camera coordinates (placed or built with ``GlassObject.from_mesh``).
        pano_height: height of the 360° panorama (its width is twice that).
        max_bounces: surface interactions per refracted path before it is marked trapped.
        normals: ``"interpolated"`` (smooth shading normals, creased at sharp edges), ``"face"``, or
            ``"radial"`` (from each shell's centre: exact for spheres, wrong for other shapes).
        edge_threshold: relative depth jump at which the background mesh is cut.
        up: the scene's up direction in camera coordinates; default ``obj.up``, else ``(0, -1, 0)``.
        eps: self-intersection offset (default: scaled to the object, see
            :mod:`~snell_bench.optics.tracer`).
        cache_dir: if given, warps are loaded from / saved to ``<cache_dir>/<input hash>.npz``.
        verify_visibility: also cast a camera ray to every background point a warp lands on
            (redundant for depth-map backgrounds, see :func:`self_warp`; for checking).
        roi: cast primary rays only inside the object's projected bounding box (same result,
            faster).
        infinity_tolerance_px: treat background that moves no warp by more than this many pixels
            as at infinity (:mod:`~snell_bench.optics.far_field`); ``None`` keeps the exact geometry.
        recipe_max_bounces: a recipe's own interaction limit; replaces ``max_bounces`` when given.

    Returns:
        The :class:`WarpSet` (from the cache if it holds one for these inputs).

    Raises:
        ValueError: an invalid argument (:func:`~snell_bench.optics.options.warp_options`), the object is
            not placed, not in front of the camera or outside its view, or no depth pixel is valid.

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
    max_bounces = max_bounces if recipe_max_bounces is None else recipe_max_bounces
    variant = Variant(back_faces, reflection_parallax, half_pixel_shift, pano_center, pano_axes)
    tracing = dict(max_bounces=max_bounces, normals=normals, edge_threshold=edge_threshold, up=up, eps=eps, roi=roi)
    checks = dict(verify_visibility=verify_visibility, infinity_tolerance_px=infinity_tolerance_px, variant=variant)
    up_vec, options = warp_options(depth, camera, obj, pano_height, **tracing, **checks)
    key = warp_inputs_hash(depth, camera, obj, options)
    cache_path, cached = cache_lookup(cache_dir, key, tuple(np.shape(depth)))
    if cached is not None:
        return cached
    check_object_in_view(obj, camera)
    return _traced_warps(depth, camera, obj, up_vec, options, variant, key, cache_path)


def _traced_warps(
    depth: np.ndarray,
    camera: Camera,
    obj: GlassObject,
    up_vec: np.ndarray,
    options: dict,
    variant: Variant,
    key: str,
    cache_path: Path | None,
) -> WarpSet:
    """Stages 2-8 from the hashed ``options`` alone (``up_vec`` (3,) unit, camera frame); saved to ``cache_path``."""
    timer, roi, verify = Timer(), options.get("roi", True), options["verify_visibility"]
    # 2. the ray-casting scene
    scene_args = {k: options[k] for k in ("max_bounces", "normals", "edge_threshold", "eps")}
    with timer("build"):
        scene = _build_scene(
            depth, camera, obj, options.get("infinity_tolerance_px"), options["pano_height"], **scene_args
        )
    # 3. primary rays: which pixels see the object
    with timer("primary"):
        primary = _trace_primary(camera, obj, scene.tracer, roi)
    pano = panorama_pose(obj, up_vec, options["pano_height"], variant.pano_center, variant.pano_axes)
    arrays = _trace_warps(scene, primary, camera, depth, pano, variant, verify, timer)
    # 8. masks, statistics, the WarpSet
    arrays["object_mask"] = primary.mask
    stats = _warp_stats(timer, scene, primary, roi)
    ws = assemble(
        camera, pano, obj.ior, arrays, input_hash=key, options=options, stats=stats, absorption=obj.absorption
    )
    if cache_path is not None:
        ws.save(cache_path)
    log.info("warps: %s", ws.summary())
    return ws


# ---------------------------------------------------------------------------------------------
# stages 4-7: the warps
# ---------------------------------------------------------------------------------------------
def _trace_warps(
    scene: RayScene,
    primary: PrimaryRays,
    camera: Camera,
    depth: np.ndarray,
    pano: PanoramaCamera,
    variant: Variant,
    verify_visibility: bool,
    timer: Timer,
) -> dict[str, np.ndarray]:
    """Trace the refracted and mirror paths of the object pixels and build every warp from them
    (module docstring, stages 4-7), the perspective maps shifted by half a pixel with
    ``variant.half_pixel_shift``.

    Returns:
        The flat arrays of :func:`~snell_bench.optics.warpset.assemble` but ``object_mask``.
    """
    # 4. refraction through the object
    with timer("refraction"):
        tr = trace_refraction(scene, primary)
        arrays = refraction_warps(camera, scene.tracer, tr, primary, verify_visibility, variant.back_faces)
    # 5. first-bounce reflection
    with timer("reflection"):
        refl = trace_reflection(scene, tr)
        arrays |= reflection_warps(camera, scene.tracer, refl, primary, verify_visibility)
    # 6. panorama coordinates of the refracted and mirror rays, where the panorama centre sees their ends
    with timer("panorama"):
        arrays |= panorama_warps(
            pano,
            scene,
            tr,
            refl,
            primary,
            back_faces=variant.back_faces,
            reflection_parallax=variant.reflection_parallax,
        )
    # 7. the panorama seen through the glass-free scene
    with timer("panorama"):
        arrays |= pano_to_persp_warp(pano, camera, scene, primary, verify_visibility)
    with timer("frame"):
        arrays |= pano_refraction_frame_warp(pano, camera, scene, depth, primary, arrays["pano_refraction"])
    if variant.half_pixel_shift:
        arrays |= shift_half_pixel(arrays, camera, primary.mask)
        arrays["pano_to_persp_object"] &= arrays["pano_to_persp_valid"]
    return arrays


# ---------------------------------------------------------------------------------------------
# stage 2: the ray-casting scene
# ---------------------------------------------------------------------------------------------
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
) -> RayScene:
    """Build the background mesh (without the far background, :func:`_far_background`; its box
    encloses the object) and the tracer of the object in it.

    Args:
        depth, camera, obj, infinity_tolerance_px, pano_height, edge_threshold, max_bounces,
        normals, eps: as :func:`compute_warps`.

    Returns:
        The :class:`RayScene`.
    """
    far, far_stats = _far_background(depth, camera, obj, infinity_tolerance_px, pano_height)
    lo, hi = obj.mesh.bounds
    background = build_background(depth, camera, edge_threshold, extra_points=np.stack([lo, hi]), exclude=far)
    tracer = SceneTracer(background, obj, max_bounces=max_bounces, normals=normals, eps=eps)
    at_inf = AtInfinity(camera, far) if far is not None and far.any() else None
    return RayScene(background, tracer, at_inf, far_stats)


# ---------------------------------------------------------------------------------------------
# stage 3: primary rays
# ---------------------------------------------------------------------------------------------
def _trace_primary(camera: Camera, obj: GlassObject, tracer: SceneTracer, roi: bool) -> PrimaryRays:
    """Cast camera rays through pixel centres; a pixel sees the object where its ray hits the object
    before the background.

    Args:
        camera, obj, roi: as :func:`compute_warps` (with ``roi``, only the pixels of
            :func:`object_pixel_box` are cast).
        tracer: the scene's tracer.

    Returns:
        The :class:`PrimaryRays` rays (an empty mask is logged as a warning).
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
    return PrimaryRays(traced=int(len(sel)), pixels=pixels, rays=rays_sel[hit], mask=mask)


# ---------------------------------------------------------------------------------------------
# stage 8: statistics and the WarpSet
# ---------------------------------------------------------------------------------------------
def _warp_stats(timer: Timer, scene: RayScene, primary: PrimaryRays, roi: bool) -> dict:
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
