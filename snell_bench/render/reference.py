"""The physically based reference render of a glass object in the scene of I⁻, with Mitsuba 3.

:func:`render_reference` is the reference that generated images are scored against. It uses only
what a generated scene provides (I⁻, its z-depth, K) and an independent renderer (Mitsuba 3), so it
cross-checks our own tracer (:mod:`snell_bench.optics`).

Convention:
    - Settings: one :class:`~snell_bench.render.reference_settings.ReferenceSettings`; ``spp``,
      ``reflection=True``, ``crop=True`` and the like below name its fields.
    - Stages of :func:`render_reference`, each a function: the scene and its window, the image pass,
      the unobserved pass (:mod:`snell_bench.render.reference_passes`), the paste outside the
      window, the metric mask, the self-noise.
    - Frames, pixels and sensor: see :mod:`snell_bench.render.pieces`; randomness and render
      windows: see :mod:`snell_bench.render.integrator`; the background, its flaps at depth edges,
      the object's normals and ``object_mask``: see :mod:`snell_bench.render.geometry`.
    - Object BSDFs: Mitsuba's ``dielectric``, or the refraction-only glass or the refraction-path
      BSDF of :mod:`snell_bench.render.plugins`.
    - Background: its front side is an ``area`` emitter textured with I⁻ decoded to linear RGB,
      texel-exact; its BSDF is black.
    - Unobserved: the back sides of the background (a copy with flipped faces just behind it) and the
      bounding box (faces pointing inwards), as in :class:`~snell_bench.optics.tracer.HitKind`.
    - Passes (both linear; Mitsuba is linear in emission):
      (a) ``image``: observed surfaces emit I⁻, the unobserved box and back sides are black; the object
      is Mitsuba's ``dielectric`` (``int_ior = obj.ior``, ``ext_ior = 1``), so reflection, refraction,
      Fresnel and internal bounces are all sampled by Mitsuba (``reflection=True``), or the
      refraction-only glass of the paper's Blender reference and the authors' ``render_gt``
      (``reflection=False``): the camera ray's first hit on the object transmits with weight 1
      (no first-surface reflection, no Fresnel loss there), every later interaction is the
      dielectric's (Fresnel split at the exit, internal reflections, total internal reflection).
      At normal incidence on a sphere in front of a background of radiance ``L`` (and nothing
      behind the camera) that gives ``L (1 - F) / (1 + F)`` with reflection and ``L / (1 + F)``
      without (``F = 0.04`` at IOR 1.5: 0.923 L and 0.962 L). Encoded to sRGB.
      (b) ``unobserved``: observed surfaces emit (0, 1, 0), unobserved ones (1, 0, 0), and the object
      follows the *refraction path* (refract at every interface; reflect only under total internal
      reflection), the path that the metric mask is defined on. ``unobserved = R / (R + G)``: the share
      of the pixel's refracted light that comes from surfaces I⁻ does not show (1 where no path ends on
      a surface, e.g. trapped; samples that end on the front of a back-side copy, through a crack of
      the ray tracer, count for neither). Outer-surface reflections do not count: they mostly see the
      space behind the camera and would otherwise exclude every pixel whose Fresnel reflectance
      exceeds the threshold.
    - Window (``crop=True``): both passes render only the object's rectangle
      (:func:`~snell_bench.render.geometry.object_rect`: every pixel whose footprint can overlap the
      object's projection) grown by ``crop_margin_px``, a crop window of the full film, so each pixel
      in it sees the rays it sees in a full-frame render (other random numbers, though: see
      :mod:`snell_bench.render.integrator`). Outside it no camera ray meets the object, so a full-frame
      render there shows the background seen directly, and that is pasted: a pixel with a valid depth
      shows its own texel (``linear`` = I⁻ decoded to linear RGB, ``unobserved`` = 0), a pixel
      without one shows nothing (``linear`` = 0, ``unobserved`` = 1: its ray leaves through the hole
      in the depth mesh and ends on the unobserved box). A full-frame render agrees with that to
      float rounding except at the pixels where a sample slips through a crack between two
      background triangles (the ray tracer is not watertight: 0.1 to 0.6 % of the pixels, each
      darker by the share of its samples lost), which the paste does not have. An object with a
      vertex closer than the near clip plane (or behind the camera) has no bounded projection, and
      one outside the image nothing to crop to: then the whole frame is rendered.
    - Sampler: one of Mitsuba's (:data:`~snell_bench.render.pieces.SAMPLERS`); all but
      ``independent`` accept only some sample counts and round any other up (logged, see below).
    - Self-noise (``self_noise=True``): the image pass is two independent renders A and B (seeds
      ``2 seed`` and ``2 seed + 1``) of ``n1`` and ``n2`` samples per pixel, ``n1 + n2 = spp``, and
      ``linear`` is their sample-weighted mean ``F = (n1 A + n2 B) / spp``. ``n1 = n2 = spp / 2``,
      rounded up to a count the sampler accepts (so ``spp`` becomes ``2 n1``, logged), except for
      ``independent``, which splits any ``spp >= 2`` as ``n1 = spp // 2``, ``n2 = spp - n1``. With
      A and B independent and unbiased, of per-pixel noise variances ``v_A`` and ``v_B``,
      ``E (A - B)^2 = v_A + v_B`` and ``Var F = (n1^2 v_A + n2^2 v_B) / spp^2``; for equal halves
      (``v_A = v_B``, any sampler) and for the independent sampler (``v ∝ 1 / n``) both give
      ``Var F = E (A - B)^2 n1 n2 / spp^2``: a quarter of the halves' mean squared difference for
      equal halves, not a half (F has half the variance of one half, and A - B twice it). So
      ``self_noise_db = self_noise_halves_db + 10 log10(spp^2 / (n1 n2))`` (+6.02 dB for equal halves)
      estimates the PSNR of ``image`` against its noise-free limit, where ``self_noise_halves_db =
      10 log10(1 / mean (a - b)^2)`` is the PSNR between the halves' sRGB images ``a`` and ``b``
      inside ``mask``, on the metrics' grayscale ``0.299 R + 0.587 G + 0.114 B``
      (:func:`~snell_bench.metrics.masked_psnr`) without histogram matching; ``self_noise_rgb_db``
      is the same estimate on the RGB channels. In sRGB the estimate is first order (the encoding is
      smooth where the noise is small). It is about the highest masked PSNR an image can score
      against this reference: the noise-free render itself scores about that. ``None`` with
      ``spp = 1`` (no halves) or an empty mask; ``inf`` where the halves agree exactly.
      ``self_noise=False`` renders the image pass once, with ``seed``, and measures nothing.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from snell_bench.imaging.color import linear_to_srgb
from snell_bench.optics.media import interface_faces
from snell_bench.render.geometry import object_mask
from snell_bench.render.pieces import SAMPLERS, check_sampler, sample_count
from snell_bench.render.reference_passes import (
    ReferenceScene,
    build_scene,
    render_image_pass,
    render_unobserved_pass,
)
from snell_bench.render.reference_settings import ReferenceSettings
from snell_bench.render.variants import set_variant
from snell_bench.scene.camera import Camera
from snell_bench.scene.objects import GlassObject
from snell_bench.utils.timing import Timer

log = logging.getLogger(__name__)

__all__ = ["ReferenceRender", "ReferenceSettings", "halves_self_noise", "render_reference"]

#: Luma weights (R, G, B) of the metrics' grayscale.
_LUMA = np.array([0.299, 0.587, 0.114], np.float64)


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
        spp: samples per pixel of the image pass (both halves together; after the sampler's
            rounding).
        seed: seed of Mitsuba's sampler.
        timings: seconds per stage (``geometry``, ``image``, ``unobserved``).
        sampler: Mitsuba's sampler.
        unobserved_spp: samples per pixel of the unobserved pass.
        window: ``(x0, y0, x1, y1)``, end exclusive: the pixels rendered (``(0, 0, W, H)``: the
            whole frame); the rest is the background seen directly (see the module's conventions).
        self_noise_db: estimated PSNR (dB, grayscale, inside ``mask``) of ``image`` against its
            noise-free limit; ``None`` where not measured.
        self_noise_rgb_db: the same on the RGB channels.
        self_noise_halves_db: PSNR (dB, grayscale, inside ``mask``) between the two halves.
        halves: ``(n1, n2)``, the samples per pixel of the two halves; ``None``: one render.
        reflection: whether the image pass shows the first-surface reflection (see the module's
            conventions; ``False`` also with ``fresnel=False``).
        file_format: ``None`` (an image in memory), or the file the renderer wrote that ``image``
            decodes (``"jpeg"``: the Cycles reference is already the authors' ``blender.jpg``, so
            ``metrics.files=jpeg`` must not encode it again).
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
    sampler: str = "independent"
    unobserved_spp: int = 0
    window: tuple = ()
    self_noise_db: float | None = None
    self_noise_rgb_db: float | None = None
    self_noise_halves_db: float | None = None
    halves: tuple | None = None
    reflection: bool = True
    file_format: str | None = None

    def summary(self) -> dict:
        """What a results file records about this reference: variant, sampler, counts, window,
        self-noise (dB, ``None`` where not measured; see the module's conventions) and whether it
        shows the first-surface reflection."""

        def db(v):
            return None if v is None else round(float(v), 3)

        return {
            "variant": self.variant,
            "sampler": self.sampler,
            "spp": int(self.spp),
            "unobserved_spp": int(self.unobserved_spp),
            "window": [int(v) for v in self.window],
            "halves": None if self.halves is None else [int(n) for n in self.halves],
            "self_noise_db": db(self.self_noise_db),
            "self_noise_rgb_db": db(self.self_noise_rgb_db),
            "self_noise_halves_db": db(self.self_noise_halves_db),
            "reflection": bool(self.reflection),
        }


def _check_inputs(i_minus, depth, camera: Camera, obj: GlassObject) -> tuple[np.ndarray, np.ndarray]:
    """I⁻ as float32 and the depth as an array, after checking them against the camera.

    Raises:
        ValueError: a shape does not match the camera, I⁻ has non-finite values, or the object is
            not placed, or has several media whose shells' surfaces cross inside a face.
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
    if obj.media is not None:
        interface_faces(obj)  # each face between the same two media, or a ValueError saying so
    if not obj.placed:
        raise ValueError(
            f"{obj.name}: the object is in its canonical frame; place it first (snell_bench.scene.place_object)"
        )
    return img, depth


def halves_self_noise(a: np.ndarray, b: np.ndarray, mask: np.ndarray, n1: int, n2: int) -> tuple[float, float, float]:
    """The self-noise of a reference from its two halves (see the module's conventions).

    Args:
        a, b: ``(h, w, 3)`` sRGB images of the two halves.
        mask: ``(h, w)`` bool, the pixels scored.
        n1, n2: their samples per pixel.

    Returns:
        ``(self_noise_db, self_noise_rgb_db, self_noise_halves_db)``: the estimated PSNR of the
        full reference (grayscale, RGB) and the PSNR between the halves (grayscale); ``inf`` where
        the halves agree exactly.

    Raises:
        ValueError: ``mask`` is empty, or ``n1`` or ``n2`` is not positive.
    """
    if not mask.any():
        raise ValueError("the mask is empty")
    if min(n1, n2) < 1:
        raise ValueError(f"both halves need samples, got {n1} and {n2}")
    d = a[mask].astype(np.float64) - b[mask].astype(np.float64)
    gain = 10.0 * math.log10((n1 + n2) ** 2 / (n1 * n2))

    def db(mse: float) -> float:
        return math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)

    halves = db(float(np.mean((d @ _LUMA) ** 2)))
    return halves + gain, db(float(np.mean(d**2))) + gain, halves


def _image_counts(mi, sampler, spp: int, halves: bool) -> tuple[int, ...]:
    """Samples per pixel of the image pass's renders: ``(n,)`` or the halves ``(n1, n2)``, in counts
    the sampler accepts (see the module's conventions); a rounding is logged."""
    name = check_sampler(sampler)["type"]
    if not halves or spp < 2:
        counts = (sample_count(mi, sampler, spp),)
    elif name == "independent":
        counts = (spp // 2, spp - spp // 2)
    else:
        n = sample_count(mi, sampler, -(-spp // 2))
        counts = (n, n)
    if sum(counts) != spp:
        log.warning(
            "reference: the %s sampler takes %s; spp=%d rendered as %s = %d samples per pixel",
            name,
            SAMPLERS[name],
            spp,
            " + ".join(map(str, counts)),
            sum(counts),
        )
    return counts


def _window(camera: Camera, obj: GlassObject, rect, margin: int, near_clip: float, crop: bool) -> tuple:
    """The pixels to render: ``rect`` grown by ``margin`` and clipped to the image, or the whole
    image (``crop=False``, an object reaching in front of the near clip plane, or one outside the
    image)."""
    H, W = camera.shape
    if not crop:
        return (0, 0, W, H)
    if not (np.asarray(obj.vertices)[:, 2] > near_clip).all():
        log.info("reference: the object reaches in front of the near clip plane; rendering the whole frame")
        return (0, 0, W, H)
    x0, y0, x1, y1 = rect
    m = int(margin)
    x0, y0, x1, y1 = max(0, x0 - m), max(0, y0 - m), min(W, x1 + m), min(H, y1 + m)
    if x1 <= x0 or y1 <= y0:  # the object is outside the image: nothing to crop to
        return (0, 0, W, H)
    return (x0, y0, x1, y1)


def _paste(scene: ReferenceScene, window: tuple, counts, parts, share) -> tuple[np.ndarray, np.ndarray]:
    """Stage 4, the crop: the frame's ``(linear, unobserved)``, ``(H, W, 3)`` and ``(H, W)`` float32,
    from the passes of ``window`` (``(x0, y0, x1, y1)``, end exclusive).

    Inside the window, ``linear`` is the sample-weighted mean of the image pass's renders (``counts``
    samples each) and ``unobserved = R / (R + G)`` of the unobserved pass (negative radiance clipped
    to 0; 1 where ``R + G <= 1e-6``: no path ends on a surface), clipped to [0, 1]. Outside it, the
    background seen directly (see the module's conventions): a pixel with a valid depth shows its
    texel (``unobserved`` 0), one without shows nothing (``linear`` 0, ``unobserved`` 1).
    """
    x0, y0, x1, y1 = window
    win = sum(n * p for n, p in zip(counts, parts)) / float(sum(counts))
    linear = np.where(scene.valid[..., None], scene.texture, np.float32(0.0)).astype(np.float32)
    linear[y0:y1, x0:x1] = win
    u, o = np.clip(share[..., 0], 0.0, None), np.clip(share[..., 1], 0.0, None)
    total = u + o
    with np.errstate(divide="ignore", invalid="ignore"):
        u_win = np.where(total > 1e-6, u / total, 1.0)
    unobserved = np.where(scene.valid, np.float32(0.0), np.float32(1.0)).astype(np.float32)
    unobserved[y0:y1, x0:x1] = np.clip(u_win, 0.0, 1.0)
    return linear, unobserved


def _metric_mask(depth, camera: Camera, obj: GlassObject, unobserved: np.ndarray, threshold: float) -> tuple:
    """Stage 5, the unobserved mask: ``(object_mask, mask)``, ``(H, W)`` bool: the pixels whose
    centre ray hits the object first, and those of them whose unobserved share is below
    ``threshold`` (the metric mask)."""
    obj_mask = object_mask(depth, camera, obj)
    return obj_mask, obj_mask & (unobserved < threshold)


def _self_noise(parts, counts, mask: np.ndarray, window: tuple, wanted: bool) -> tuple:
    """Stage 6: ``(self_noise_db, self_noise_rgb_db, self_noise_halves_db)`` of the image pass's
    two halves ``parts`` (linear RGB of ``window``, ``counts`` samples each) inside the window's part
    of ``mask`` (see :func:`halves_self_noise`); ``(None, None, None)`` with one render or an empty
    mask (logged where the halves were ``wanted``)."""
    x0, y0, x1, y1 = window
    win_mask = mask[y0:y1, x0:x1]
    if len(parts) == 2 and win_mask.any():
        a, b = (linear_to_srgb(np.clip(p, 0.0, 1.0)) for p in parts)
        return halves_self_noise(a, b, win_mask, *counts)
    if wanted:
        log.info("reference: no self-noise (%s)", "spp=1 has no halves" if len(parts) == 1 else "empty mask")
    return (None, None, None)


def _log_render(ref: ReferenceRender, counts) -> None:
    """One line about a finished render: variant, sampler, counts, window, mask sizes, self-noise and
    the seconds of each stage."""
    x0, y0, x1, y1 = ref.window
    log.info(
        "reference (%s, %s, %s spp in %dx%d px; unobserved %d spp): %d object pixels, %d in the mask; "
        "self-noise %s dB; %s",
        ref.variant,
        ref.sampler,
        "+".join(map(str, counts)),
        x1 - x0,
        y1 - y0,
        ref.unobserved_spp,
        int(ref.object_mask.sum()),
        int(ref.mask.sum()),
        "n/a" if ref.self_noise_db is None else f"{ref.self_noise_db:.1f}",
        {k: round(v, 2) for k, v in ref.timings.items()},
    )


def render_reference(
    i_minus: np.ndarray, depth: np.ndarray, camera: Camera, obj: GlassObject, settings: ReferenceSettings | None = None
) -> ReferenceRender:
    """Render ``obj`` placed in the scene of I⁻ with Mitsuba 3.

    Camera frame and pixel centres of :mod:`snell_bench.scene.camera`; images ``(H, W, 3)`` float32,
    sRGB in [0, 1] in and out (rendering is in linear RGB); masks ``(H, W)`` bool. Stages: the
    scene and its window (:func:`~snell_bench.render.reference_passes.build_scene`), the image pass
    (observed surfaces emit I⁻, the object is a dielectric; ``spp`` samples per pixel, in two halves
    with ``self_noise``) and the unobserved pass (refraction path only; ``unobserved_spp``) of the
    window, the rest of the frame pasted, the metric mask, the self-noise. See the module's
    docstring for the scene, the window and the self-noise.

    Args:
        i_minus: ``(H, W, 3)`` sRGB image in [0, 1] of the object-free scene.
        depth: ``(H, W)`` z-depth of I⁻ (NaN, inf or <= 0 where unknown).
        camera: the camera of I⁻, any pinhole ``K`` (``fx != fy`` and skew included; see
            :func:`~snell_bench.render.pieces.sensor`).
        obj: the glass object in camera coordinates.
        settings: the render's :class:`~snell_bench.render.reference_settings.ReferenceSettings`;
            ``None``: its defaults (a few changed: ``ReferenceSettings(spp=8, crop=False)``).

    Returns:
        The :class:`ReferenceRender`.

    Raises:
        ImportError: Mitsuba is not installed (the message names the ``render`` extra).
        ValueError: invalid inputs (shapes, non-finite I⁻, an object not placed); invalid settings
            raise where the :class:`ReferenceSettings` is made.
    """
    s = ReferenceSettings() if settings is None else settings
    img, depth = _check_inputs(i_minus, depth, camera, obj)
    t = Timer()
    with t("geometry"):
        mi = set_variant()
        counts = _image_counts(mi, s.sampler, int(s.spp), bool(s.self_noise))
        u_spp = sample_count(mi, s.sampler, int(s.spp if s.unobserved_spp is None else s.unobserved_spp))
        scene = build_scene(img, depth, camera, obj, s.edge_threshold)
        window = _window(camera, obj, scene.rect, s.crop_margin_px, scene.clip[0], s.crop)
    with t("image"):
        parts = render_image_pass(mi, scene, camera, obj, s, counts, window)
    with t("unobserved"):
        share = render_unobserved_pass(mi, scene, camera, obj, s, u_spp, window)
    linear, unobserved = _paste(scene, window, counts, parts, share)
    obj_mask, mask = _metric_mask(depth, camera, obj, unobserved, s.unobserved_threshold)
    noise = _self_noise(parts, counts, mask, window, s.self_noise)
    ref = ReferenceRender(
        image=linear_to_srgb(np.clip(linear, 0.0, 1.0)).astype(np.float32),
        linear=linear,
        unobserved=unobserved,
        object_mask=obj_mask,
        mask=mask,
        unobserved_threshold=float(s.unobserved_threshold),
        variant=mi.variant(),
        spp=int(sum(counts)),
        seed=int(s.seed),
        timings=t.seconds,
        sampler=s.sampler_name,
        unobserved_spp=int(u_spp),
        window=tuple(int(v) for v in window),
        self_noise_db=noise[0],
        self_noise_rgb_db=noise[1],
        self_noise_halves_db=noise[2],
        halves=tuple(int(n) for n in counts) if len(counts) == 2 else None,
        reflection=bool(s.fresnel and s.reflection),
    )
    _log_render(ref, counts)
    return ref
