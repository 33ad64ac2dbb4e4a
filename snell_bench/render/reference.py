"""The physically based reference render of a glass object in the scene of I⁻, with Mitsuba 3.

:func:`render_reference` is the reference that generated images are scored against. It uses only
what a generated scene provides (I⁻, its z-depth, K) and an independent renderer (Mitsuba 3), so it
cross-checks our own tracer (:mod:`snell_bench.optics`).

Convention:
    - Frames, pixels, sensor and randomness: see :mod:`snell_bench.render.backend`; the background,
      its flaps at depth edges, the object's normals and ``object_mask``: see
      :mod:`snell_bench.render.geometry`.
    - Background: its front side is an ``area`` emitter textured with I⁻ decoded to linear RGB,
      texel-exact; its BSDF is black.
    - Unobserved: the back sides of the background (a copy with flipped faces just behind it) and the
      bounding box (faces pointing inwards), as in :class:`~snell_bench.optics.tracer.HitKind`.
    - Passes (both linear; Mitsuba is linear in emission):
      (a) ``image``: observed surfaces emit I⁻, the unobserved box and back sides are black; the object
      is Mitsuba's ``dielectric`` (``int_ior = obj.ior``, ``ext_ior = 1``), so reflection, refraction,
      Fresnel and internal bounces are all sampled by Mitsuba. Encoded to sRGB.
      (b) ``unobserved``: observed surfaces emit (0, 1, 0), unobserved ones (1, 0, 0), and the object
      follows the *refraction path* (refract at every interface; reflect only under total internal
      reflection), the path that the metric mask is defined on. ``unobserved = R / (R + G)``: the share
      of the pixel's refracted light that comes from surfaces I⁻ does not show (1 where no path ends on
      a surface, e.g. trapped; samples that end on the front of a back-side copy, through a crack of
      the ray tracer, count for neither). Outer-surface reflections do not count: they mostly see the
      space behind the camera and would otherwise exclude every pixel whose Fresnel reflectance
      exceeds the threshold.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear
from snell_bench.render.backend import black_bsdf, mesh, render_linear, rgb_emitter, set_variant, texture_emitter
from snell_bench.render.geometry import (
    background_geometry,
    flaps,
    inward_box,
    object_arrays,
    object_mask,
    object_rect,
    subdivide,
)
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import build_background, valid_depth_mask
from snell_bench.scene.objects import GlassObject

log = logging.getLogger(__name__)

__all__ = ["ReferenceRender", "render_reference"]

#: The back sides of the background sit this far (relative to their distance) behind the front.
_BACK_OFFSET = 1e-4


@dataclass
class ReferenceRender:
    """A reference render (see the module's conventions).

    Attributes:
        image: ``(H, W, 3)`` float32 sRGB in [0, 1].
        linear: ``(H, W, 3)`` float32 linear RGB (not clipped).
        unobserved: ``(H, W)`` float32 in [0, 1]: share of the pixel's refracted light from
            surfaces that I⁻ does not show.
        object_mask: ``(H, W)`` bool: the pixel-centre ray hits the object first.
        mask: ``(H, W)`` bool: ``object_mask & (unobserved < unobserved_threshold)``, the metric
            mask.
        unobserved_threshold: the threshold of ``mask``.
        variant: the Mitsuba variant it was rendered with.
        spp: samples per pixel of each pass.
        seed: seed of Mitsuba's sampler.
        timings: seconds per stage (``geometry``, ``image``, ``unobserved``).
    """

    image: np.ndarray
    linear: np.ndarray
    unobserved: np.ndarray
    object_mask: np.ndarray
    mask: np.ndarray
    unobserved_threshold: float
    variant: str
    spp: int
    seed: int
    timings: dict = field(default_factory=dict)


def _check_inputs(i_minus, depth, camera: Camera, obj: GlassObject, spp: int) -> tuple[np.ndarray, np.ndarray]:
    """I⁻ as float32 and the depth as an array, after checking them against the camera.

    Raises:
        ValueError: a shape does not match the camera, I⁻ has non-finite values, the object is not
            placed, or ``spp`` is not a positive integer.
    """
    img = np.asarray(i_minus, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"i_minus must be an (H, W, 3) RGB image, got shape {img.shape}")
    if img.shape[:2] != camera.shape:
        raise ValueError(f"i_minus is {img.shape[0]}x{img.shape[1]} but the camera is {camera.height}x{camera.width}")
    if not np.isfinite(img).all():
        raise ValueError("i_minus has non-finite values")
    depth = np.asarray(depth)
    if depth.shape != camera.shape:
        raise ValueError(
            f"depth has shape {depth.shape} but the camera is {camera.height}x{camera.width}; "
            "pass a depth map of the camera's (height, width)"
        )
    if not obj.placed:
        raise ValueError(
            f"{obj.name}: the object is in its canonical frame; place it first (snell_bench.scene.place_object)"
        )
    if int(spp) != spp or spp < 1:
        raise ValueError(f"spp must be a positive integer, got {spp!r}")
    return img, depth


def render_reference(
    i_minus: np.ndarray,
    depth: np.ndarray,
    camera: Camera,
    obj: GlassObject,
    *,
    spp: int = 16,
    edge_threshold: float = 0.05,
    seed: int = 0,
    unobserved_threshold: float = 0.05,
    max_depth: int = 16,
    fresnel: bool = True,
) -> ReferenceRender:
    """Render ``obj`` placed in the scene of I⁻ with Mitsuba 3.

    Camera frame and pixel centres of :mod:`snell_bench.scene.camera`; images ``(H, W, 3)`` float32,
    sRGB in [0, 1] in and out (rendering is in linear RGB); masks ``(H, W)`` bool. Two passes of
    ``spp`` samples per pixel: the image (observed surfaces emit I⁻, the object is a dielectric) and
    the unobserved share (refraction path only). See the module's docstring for the scene.

    Args:
        i_minus: ``(H, W, 3)`` sRGB image in [0, 1] of the object-free scene.
        depth: ``(H, W)`` z-depth of I⁻ (NaN, inf or <= 0 where unknown).
        camera: the camera of I⁻, any pinhole ``K`` (``fx != fy`` and skew included; see
            :func:`~snell_bench.render.backend.sensor`).
        obj: the glass object in camera coordinates.
        spp: samples per pixel of each of the two passes.
        edge_threshold: relative depth jump at which the depth mesh is cut (as in ``compute_warps``).
        seed: seed of Mitsuba's sampler.
        unobserved_threshold: object pixels whose unobserved share is below this form ``mask``.
        max_depth: longest light path (surface interactions, the emitter hit included).
        fresnel: ``True`` (default): the object is Mitsuba's ``dielectric`` (reflection and
            refraction sampled with Fresnel weights). ``False``: every pixel sample follows the
            refraction path (refraction at each interface, reflection only under total internal
            reflection) with weight 1, so ``image`` shows what our self-warp π^R predicts, without
            Fresnel reflection or loss: a purely geometric render, for cross-checks.

    Returns:
        The :class:`ReferenceRender`.

    Raises:
        ImportError: Mitsuba is not installed (the message names the ``render`` extra).
        ValueError: invalid inputs (shapes, an object not placed, ``spp`` or ``unobserved_threshold``
            out of range).
    """
    img, depth = _check_inputs(i_minus, depth, camera, obj, spp)
    if not (0.0 < unobserved_threshold <= 1.0):
        raise ValueError(f"unobserved_threshold must be in (0, 1], got {unobserved_threshold}")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    mi = set_variant()
    variant = mi.variant()

    lo, hi = obj.mesh.bounds
    bg = build_background(depth, camera, edge_threshold, extra_points=np.stack([lo, hi]))
    geo = background_geometry(bg, depth, camera, edge_threshold)
    fv, ff, fuv = flaps(geo, camera)
    # the observed surface, each triangle split so that every piece shows one texel (pass a) ...
    sv, sf, suv = subdivide(geo, camera.shape, geo.observed)
    tex_v, tex_f, tex_uv = np.concatenate([sv, fv]), np.concatenate([sf, ff + len(sv)]), np.concatenate([suv, fuv])
    # ... and unsplit (pass b); its back side is unobserved
    obs_v, obs_f = np.concatenate([geo.vertices, fv]), np.concatenate([geo.observed, ff + len(geo.vertices)])
    back_v, back_f = obs_v * np.float32(1.0 + _BACK_OFFSET), obs_f[:, [0, 2, 1]]
    box_faces = inward_box(bg.box_vertices, bg.box_faces)
    ov, of, on = object_arrays(obj)
    # clip planes well inside the nearest geometry and beyond the farthest
    front = ov[:, 2][ov[:, 2] > 0]
    zmin = min([float(np.min(depth[valid_depth_mask(depth)]))] + ([float(front.min())] if len(front) else []))
    clip = (1e-3 * zmin, 10.0 * float(np.linalg.norm(np.abs(bg.box_vertices).max(axis=0))))
    texture = mi.Bitmap(np.ascontiguousarray(srgb_to_linear(np.clip(img, 0.0, 1.0)), dtype=np.float32))
    rect = object_rect(camera, obj)
    timings["geometry"] = time.perf_counter() - t0

    def dielectric(kind: str):
        return mi.load_dict({"type": kind, "int_ior": float(obj.ior), "ext_ior": 1.0})

    def object_shape(bsdf):
        return mesh(mi, "object", ov, of, normals=on, bsdf=bsdf)

    # ---- (a) observed surfaces emit I⁻, the rest is black; Mitsuba's dielectric
    t0 = time.perf_counter()
    shapes = {
        "background": mesh(
            mi, "background", tex_v, tex_f, uv=tex_uv, bsdf=black_bsdf(mi), emitter=texture_emitter(mi, texture)
        ),
        "object": object_shape(dielectric("dielectric" if fresnel else "snell_refraction_path")),
    }
    linear = render_linear(mi, shapes, camera, spp, seed, max_depth, clip, None if fresnel else rect)
    timings["image"] = time.perf_counter() - t0

    # ---- (b) observed surfaces emit green, unobserved ones red; the refraction path
    t0 = time.perf_counter()
    red, green = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
    shapes = {
        "background": mesh(mi, "background", obs_v, obs_f, bsdf=black_bsdf(mi), emitter=rgb_emitter(mi, green)),
        "back": mesh(mi, "back", back_v, back_f, bsdf=black_bsdf(mi), emitter=rgb_emitter(mi, red)),
        "box": mesh(mi, "box", bg.box_vertices, box_faces, bsdf=black_bsdf(mi), emitter=rgb_emitter(mi, red)),
        "object": object_shape(dielectric("snell_refraction_path")),
    }
    share = render_linear(mi, shapes, camera, spp, seed, max_depth, clip, rect)
    timings["unobserved"] = time.perf_counter() - t0

    u, o = np.clip(share[..., 0], 0.0, None), np.clip(share[..., 1], 0.0, None)
    total = u + o
    with np.errstate(divide="ignore", invalid="ignore"):
        unobserved = np.where(total > 1e-6, u / total, 1.0)
    unobserved = np.clip(unobserved, 0.0, 1.0).astype(np.float32)
    obj_mask = object_mask(depth, camera, obj)
    mask = obj_mask & (unobserved < unobserved_threshold)
    image = linear_to_srgb(np.clip(linear, 0.0, 1.0)).astype(np.float32)
    log.info(
        "reference (%s, %d spp): %d object pixels, %d in the mask; %s",
        variant,
        spp,
        int(obj_mask.sum()),
        int(mask.sum()),
        {k: round(v, 2) for k, v in timings.items()},
    )
    return ReferenceRender(
        image=image,
        linear=linear,
        unobserved=unobserved,
        object_mask=obj_mask,
        mask=mask,
        unobserved_threshold=float(unobserved_threshold),
        variant=variant,
        spp=int(spp),
        seed=int(seed),
        timings=timings,
    )
