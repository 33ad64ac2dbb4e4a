"""The true render of a procedural scene with a glass object, from the scene's exact 3-D geometry.

:func:`render_true` renders a :class:`~snell_bench.scene.procedural.ProceduralScene` with the object
from its exact 3-D geometry (no depth map): it shows what the object really refracts, including
surfaces that I⁻ does not show. It uses our own tracer (:mod:`snell_bench.optics`), not Mitsuba.

Convention:
    - Frames and pixels: the camera frame and pixel centres of :mod:`snell_bench.scene.camera`.
    - Colour: radiance is linear RGB (:meth:`ProceduralScene.radiance`); samples are averaged in linear
      RGB, clipped to [0, 1] and encoded to sRGB.
    - Randomness: sub-pixel offsets from ``numpy.random.default_rng(seed)``; the same inputs, ``spp``
      and ``seed`` give the same image.
"""

from __future__ import annotations

import math

import numpy as np

from snell_bench.imaging.color import linear_to_srgb
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import BackgroundMesh, bounding_box_mesh
from snell_bench.scene.objects import GlassObject

__all__ = ["render_true"]


def _sample_offsets(spp: int, jitter: bool, rng: np.random.Generator, shape: tuple[int, int]) -> list[np.ndarray]:
    """Sub-pixel offsets (x, y) in [-0.5, 0.5) for each of ``spp`` samples.

    ``jitter=False`` needs a square ``spp = s * s`` and gives the centres of an s x s grid of strata
    (the pattern of ``ProceduralScene.render(supersample=s)``). ``jitter=True`` jitters within those
    strata if ``spp`` is square, else draws uniform offsets.

    Args:
        spp: number of samples.
        jitter: jitter the samples (else strata centres).
        rng: the random generator (not used with ``jitter=False``).
        shape: ``(H, W)`` of the image.

    Returns:
        ``spp`` arrays ``(H, W, 2)``.

    Raises:
        ValueError: ``jitter=False`` with a ``spp`` that is not a square.
    """
    s = math.isqrt(spp)
    square = s * s == spp
    if not jitter:
        if not square:
            raise ValueError(f"jitter=False needs a square spp (1, 4, 9, ...), got {spp}")
        c = (np.arange(s) + 0.5) / s - 0.5
        return [np.broadcast_to(np.array([ox, oy]), shape + (2,)) for oy in c for ox in c]
    if square:
        out = []
        for j in range(s):
            for i in range(s):
                u = rng.random(shape + (2,))
                out.append((np.stack([i + u[..., 0], j + u[..., 1]], -1)) / s - 0.5)
        return out
    return [rng.random(shape + (2,)) - 0.5 for _ in range(spp)]


def render_true(
    scene,
    camera: Camera,
    obj: GlassObject,
    *,
    spp: int = 4,
    max_bounces: int = 8,
    seed: int = 0,
    jitter: bool = True,
) -> np.ndarray:
    """The true render of a procedural scene with the glass object.

    Uses the scene's exact 3-D geometry and radiance (:meth:`ProceduralScene.radiance`), not a
    depth map. Per pixel sample: if the camera ray hits the object first, it is traced through the
    object with :class:`~snell_bench.optics.tracer.SceneTracer` (background = the scene's mesh and a
    box around it) and its colour is ``R c_refl + (1 - R) c_refr`` in linear RGB, with ``c_refr`` the
    radiance along the exit ray, ``c_refl`` along the mirror ray at the first surface, ``R`` the
    Fresnel reflectance there; rays still inside after ``max_bounces`` interactions are black.
    Other rays get the scene's radiance. Samples are averaged in linear RGB, clipped to [0, 1] and
    encoded to sRGB.

    ``spp`` sub-pixel samples, drawn from ``numpy.random.default_rng(seed)``: jittered in an s x s
    grid of strata when ``spp = s * s``, else uniform. ``jitter=False`` (square ``spp``) uses the
    strata centres, the pattern of ``scene.render(supersample=s)``, so pixels that do not see the
    object equal that render exactly.

    Args:
        scene: the :class:`~snell_bench.scene.procedural.ProceduralScene`.
        camera: the camera (of the scene's frame).
        obj: the glass object, placed in camera coordinates.
        spp: samples per pixel.
        max_bounces: most interactions of a ray inside the object.
        seed: seed of the sub-pixel offsets.
        jitter: jitter the samples (``False``: strata centres; needs a square ``spp``).

    Returns:
        ``(H, W, 3)`` float32 sRGB in [0, 1].

    Raises:
        ValueError: ``spp`` is not a positive integer (or not a square with ``jitter=False``), or
            the object is not placed.
    """
    if int(spp) != spp or spp < 1:
        raise ValueError(f"spp must be a positive integer, got {spp!r}")
    if not obj.placed:
        raise ValueError(
            f"{obj.name}: the object is in its canonical frame; place it first (snell_bench.scene.place_object)"
        )
    tracer = _tracer(scene, obj, max_bounces)
    H, W = camera.shape
    grid = camera.pixel_grid()
    rng = np.random.default_rng(seed)
    acc = np.zeros((H * W, 3), np.float64)
    for off in _sample_offsets(int(spp), jitter, rng, (H, W)):
        acc += _sample_colours(scene, tracer, camera.pixel_rays(grid + off).reshape(-1, 3))
    linear = (acc / spp).reshape(H, W, 3)
    return linear_to_srgb(np.clip(linear, 0.0, 1.0)).astype(np.float32)


def _tracer(scene, obj: GlassObject, max_bounces: int):
    """The :class:`~snell_bench.optics.tracer.SceneTracer` of ``obj`` in ``scene``: the background is
    the scene's mesh and a box around it, the object and the camera (the origin)."""
    from snell_bench.optics.tracer import SceneTracer

    m = scene.mesh()
    sv = np.asarray(m.vertices, np.float32)
    lo, hi = obj.mesh.bounds
    box_v, box_f = bounding_box_mesh(np.concatenate([sv, np.zeros((1, 3), np.float32), np.stack([lo, hi])]))
    background = BackgroundMesh(sv, np.asarray(m.faces, np.uint32), box_v, box_f, 0, 0)
    return SceneTracer(background, obj, max_bounces=max_bounces)


def _sample_colours(scene, tracer, d: np.ndarray) -> np.ndarray:
    """The linear RGB colour ``(N, 3)`` float64 of the camera rays ``d`` ``(N, 3)`` (from the origin),
    as :func:`render_true` says: ``R c_refl + (1 - R) c_refr`` where the ray meets the object first
    (``c_refr`` times ``exp(-σ L)``, summed over the media of its path), the scene's radiance elsewhere."""
    from snell_bench.optics.tracer import HitKind

    exited = (HitKind.OBSERVED, HitKind.UNOBSERVED, HitKind.ESCAPED)
    t_obj = tracer.cast_camera_object(d)
    cand = np.flatnonzero(np.isfinite(t_obj))
    if len(cand):
        t_scene = tracer.cast_background(np.zeros((len(cand), 3)), d[cand]).t
        cand = cand[t_obj[cand] < t_scene]
    on = np.zeros(len(d), bool)
    on[cand] = True
    col = np.zeros((len(d), 3), np.float64)
    if (~on).any():
        col[~on] = scene.radiance(np.zeros(3), d[~on])[0]
    if len(cand):
        tr = tracer.trace(np.zeros((len(cand), 3)), d[cand])
        refr = np.zeros((len(cand), 3))
        ok = np.isin(tr.kind, exited)
        if ok.any():
            refr[ok] = scene.radiance(tr.origin[ok], tr.direction[ok])[0]
        if (tr.optical_depth > 0).any():  # Beer–Lambert along the path inside the glass
            refr *= np.exp(-tr.optical_depth)
        ng = tr.first_geometric_normal
        side = np.where(np.einsum("ij,ij->i", tr.reflected, ng) >= 0, 1.0, -1.0)
        refl = scene.radiance(tr.first_point + (tracer.eps * side)[:, None] * ng, tr.reflected)[0]
        R = tr.fresnel[:, None]
        # Not snell_bench.imaging.blend.fresnel_combine: that one mixes sRGB colours (decode,
        # R (refl - refr) + refr, encode, clamping to [0, 1] on the way). Here the radiance is
        # linear and unclipped (lights exceed 1) and is averaged over samples before encoding;
        # the sRGB round trip and the clamping would change the result.
        col[cand] = R * refl + (1.0 - R) * refr
    return col
