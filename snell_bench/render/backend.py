"""Mitsuba 3 for the reference renderer: importing it, choosing its variant, the refraction-path
BSDF, and the scene pieces (meshes, sensor, emitters) that :mod:`snell_bench.render.reference`
assembles.

Importing this module does not import Mitsuba; :func:`import_mitsuba` and :func:`set_variant` do.

Convention:
    - Frames: everything is in the camera frame of :mod:`snell_bench.scene.camera` (OpenCV: x right,
      y down, z forward, camera at the origin).
    - Sensor: any pinhole ``K`` (see :func:`sensor`). Square pixels without skew (``fx == fy``,
      ``K[0, 1] == K[1, 0] == 0``) use Mitsuba's ``perspective`` sensor: it looks along its local +z
      with +x to the *left* and +y *up* of the image, so its ``to_world`` is the rotation
      ``diag(-1, -1, 1)`` (180° about z); the field of view is ``2 atan(W / (2 fx))`` along x; the
      principal point offset is ``((W - 1) / 2 - cx) / W`` and ``((H - 1) / 2 - cy) / H`` (Mitsuba's
      offsets are fractions of the film, measured from its centre, and shift the ray, not the image).
      Any other ``K`` uses the ``snell_pinhole`` sensor registered here, which casts the ray
      ``K⁻¹ (x, y, 1)`` through each film sample.
    - Pixels: Mitsuba's film pixel ``i`` covers ``[i, i + 1)``; ours (centres at integers) covers
      ``[x - 0.5, x + 0.5)``; a ``box`` pixel filter makes each pixel the average over its own footprint.
    - Emitters and BSDFs: surfaces that emit are ``area`` emitters, textured texel-exact
      (``filter_type = nearest``, ``raw``) or of one RGB colour; their BSDF is black (a zero conductor:
      delta, so no light sampling, and the path ends there).
    - Randomness: one of Mitsuba's samplers (:data:`SAMPLERS`; the sensors here default to
      ``independent``) seeded with ``seed``; the same inputs, sampler, ``spp``, ``seed``, render
      window and variant give the same images (``llvm_*`` variants with several Dr.Jit threads: up
      to float rounding, where a pixel's samples are summed by two threads in either order; on one
      thread, ``drjit.set_thread_count(1)``, bit for bit). The stratified samplers accept only some
      sample counts (see :func:`sample_count`).
    - Windows: a render may cover only a window ``(x0, y0, x1, y1)`` of the image (end exclusive), a
      crop window of the same film (``crop_offset`` / ``crop_size``): its pixels see exactly the rays
      they see in the whole image, but draw other random numbers (the sampler's stream follows the
      window's pixel order), so a window matches the whole image exactly only where a pixel's value
      does not depend on which samples it draws.
"""

from __future__ import annotations

import logging
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from snell_bench.scene.camera import Camera

log = logging.getLogger(__name__)

__all__ = [
    "VARIANT_ENV",
    "SAMPLERS",
    "check_sampler",
    "sample_count",
    "import_mitsuba",
    "mitsuba_variant",
    "set_variant",
    "probe_render",
    "mesh",
    "square_pixels",
    "sensor",
    "perspective_sensor",
    "pinhole_sensor",
    "black_bsdf",
    "rgb_emitter",
    "texture_emitter",
    "render_linear",
]

#: Environment variable that forces a Mitsuba variant (e.g. ``scalar_rgb``), skipping the probe.
VARIANT_ENV = "SNELL_BENCH_MITSUBA_VARIANT"
_PREFERRED_VARIANT = "llvm_ad_rgb"
_FALLBACK_VARIANT = "scalar_rgb"
_PROBE_TIMEOUT_S = 300
_PROBE_OK = "SNELL_BENCH_MITSUBA_PROBE_OK"
_INSTALL_HINT = (
    "the reference renderer needs Mitsuba 3: install the render extra with "
    "`pip install snell_bench[render]` (or `make setup EXTRAS=test,render`)"
)

#: Mitsuba's samplers and the sample counts each accepts (it rounds any other count up).
SAMPLERS = {
    "independent": "any count",
    "stratified": "a square (4, 9, 16, ...)",
    "multijitter": "a count its stratification grid fills (x * y * y with y = floor(cbrt(n)))",
    "orthogonal": "the square of a prime (4, 9, 25, 49, ...)",
    "ldsampler": "a square power of two (4, 16, 64, 256, ...)",
}

_probed_variant: str | None = None
_registered: set[str] = set()


# ============================================================================ Mitsuba set-up
def import_mitsuba():
    """The ``mitsuba`` module.

    Raises:
        ImportError: Mitsuba is not installed (the message names the ``render`` extra).
    """
    try:
        import mitsuba as mi
    except ImportError as e:
        raise ImportError(f"{_INSTALL_HINT} ({e})") from e
    return mi


def _probe(variant: str) -> bool:
    """Render a tiny scene with ``variant`` in a subprocess (a broken JIT backend can abort the
    whole process, which no ``try`` catches)."""
    root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ)
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env[VARIANT_ENV] = variant
    code = "from snell_bench.render.backend import probe_render; probe_render()"
    try:
        r = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=_PROBE_TIMEOUT_S
        )
    except (subprocess.TimeoutExpired, OSError) as e:
        log.info("mitsuba variant %s: probe failed (%s)", variant, e)
        return False
    ok = r.returncode == 0 and _PROBE_OK in r.stdout
    if not ok:
        tail = (r.stderr or r.stdout).strip().splitlines()[-3:]
        log.info("mitsuba variant %s unusable here (exit code %s): %s", variant, r.returncode, " | ".join(tail))
    return ok


def probe_render() -> None:
    """Body of the variant probe (runs in a subprocess, variant forced by the environment): a tiny
    reference render of a sphere before a textured wall.

    Raises:
        RuntimeError: the render is empty or not finite.
    """
    from snell_bench.render.reference import render_reference
    from snell_bench.scene.objects import GlassObject

    H, W = 8, 12
    cam = Camera.from_fov(W, H, 60.0)
    depth = np.full((H, W), 3.0)
    img = np.linspace(0.1, 0.9, H * W * 3).reshape(H, W, 3)
    T = np.eye(4)
    T[:3, 3] = (0.0, -0.5, 2.0)
    obj = GlassObject.sphere(subdivisions=1).transformed(T)
    ref = render_reference(img, depth, cam, obj, spp=2, sampler="independent", unobserved_spp=2)
    if not (np.isfinite(ref.image).all() and ref.image.max() > 0):
        raise RuntimeError("the probe render is empty or not finite")
    print(_PROBE_OK, flush=True)


def mitsuba_variant() -> str:
    """The Mitsuba variant to render with.

    ``$SNELL_BENCH_MITSUBA_VARIANT`` wins if set. Otherwise ``llvm_ad_rgb`` (vectorised, ~3x faster)
    if a tiny render with it succeeds in a subprocess, else ``scalar_rgb``. The probe runs once per
    process.

    Returns:
        The variant's name.

    Raises:
        ImportError: Mitsuba is not installed.
        ValueError: the environment variable names no Mitsuba variant.
    """
    global _probed_variant
    mi = import_mitsuba()
    forced = os.environ.get(VARIANT_ENV, "").strip()
    if forced:
        if forced not in mi.variants():
            raise ValueError(f"{VARIANT_ENV}={forced!r} is not a Mitsuba variant; available: {mi.variants()}")
        return forced
    if _probed_variant is None:
        usable = _PREFERRED_VARIANT in mi.variants() and _probe(_PREFERRED_VARIANT)
        v = _PREFERRED_VARIANT if usable else _FALLBACK_VARIANT
        log.info("mitsuba: rendering with the %s variant", v)
        _probed_variant = v
    return _probed_variant


def set_variant():
    """Select :func:`mitsuba_variant` and register this module's plugins for it.

    Returns:
        The ``mitsuba`` module, set to that variant.
    """
    mi = import_mitsuba()
    mi.set_variant(mitsuba_variant())
    _register_plugins(mi)
    return mi


def check_sampler(sampler) -> dict:
    """The properties of the sampler ``sampler`` names, after checking it.

    Args:
        sampler: a name of :data:`SAMPLERS`, or a dict of Mitsuba sampler properties with such a
            ``type`` (e.g. ``{"type": "stratified", "jitter": False}``); no ``sample_count``.

    Returns:
        A new dict of the sampler's properties, with its ``type``.

    Raises:
        ValueError: no such sampler (the message names ``reference.sampler`` and the choices), or
            a dict that sets ``sample_count`` (the render's ``spp`` does).
    """
    props = dict(sampler) if isinstance(sampler, dict) else {"type": sampler}
    if props.get("type") not in SAMPLERS:
        raise ValueError(f"reference.sampler={props.get('type')!r} is not one of Mitsuba's samplers {list(SAMPLERS)}")
    if "sample_count" in props:
        raise ValueError("the sampler's sample_count is the render's spp; leave it out of the sampler")
    return props


def sample_count(mi, sampler, spp: int) -> int:
    """The sample count Mitsuba's ``sampler`` renders when asked for ``spp`` (its own rounding, up
    to the next count it accepts, see :data:`SAMPLERS`; Mitsuba's warning about it silenced).

    Args:
        mi: the ``mitsuba`` module, set to a variant.
        sampler: as in :func:`check_sampler`.
        spp: the requested samples per pixel (a positive integer).

    Returns:
        The count, ``>= spp``.
    """
    props = check_sampler(sampler)
    logger = mi.logger()
    level = logger.log_level()
    logger.set_log_level(mi.LogLevel.Error)
    try:
        return int(mi.load_dict({**props, "sample_count": int(spp)}).sample_count())
    finally:
        logger.set_log_level(level)


def _register_plugins(mi) -> None:
    """Register the refraction-path BSDF (``snell_refraction_path``) and the pinhole sensor
    (``snell_pinhole``) for the current variant (once per variant)."""
    variant = mi.variant()
    if variant in _registered:
        return
    import drjit as dr

    rgb = bool(mi.is_rgb)
    unit_weight = mi.Color3f(1.0) if rgb else None

    class RefractionPathBSDF(mi.BSDF):
        """Mitsuba's smooth dielectric, but following the refraction path deterministically:
        transmission at every interface, reflection only under total internal reflection."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self._inner = mi.load_dict(
                {"type": "dielectric", "int_ior": props.get("int_ior", 1.5), "ext_ior": props.get("ext_ior", 1.0)}
            )
            sides = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
            refl = mi.BSDFFlags.DeltaReflection | sides
            trans = mi.BSDFFlags.DeltaTransmission | sides
            self.m_components = [refl, trans]
            self.m_flags = refl | trans

        def sample(self, ctx, si, sample1, sample2, active=True):
            # the dielectric reflects iff sample1 <= Fresnel reflectance: with 1 only under TIR
            return self._inner.sample(ctx, si, sample1 * 0.0 + 1.0, sample2, active)

        def eval(self, ctx, si, wo, active=True):
            return self._inner.eval(ctx, si, wo, active)  # zero: delta lobes

        def pdf(self, ctx, si, wo, active=True):
            return self._inner.pdf(ctx, si, wo, active)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self._inner.eval_pdf(ctx, si, wo, active)

        def traverse(self, callback):
            pass

        def parameters_changed(self, keys):
            pass

        def to_string(self):
            return f"RefractionPathBSDF[{self._inner}]"

    mi.register_bsdf("snell_refraction_path", lambda props: RefractionPathBSDF(props))

    class PinholeSensor(mi.Sensor):
        """A pinhole camera at the origin with any intrinsics: the ray through film position ``u``
        (Mitsuba's film pixels, pixel ``i`` covering ``[i, i + 1)``) has the direction of
        ``K⁻¹ (u - 0.5, 1)`` in the camera frame (no ``to_world``). See :func:`pinhole_sensor`."""

        def __init__(self, props):
            mi.Sensor.__init__(self, props)
            self.m_needs_sample_3 = False  # no aperture: the sampler's stream is that of `perspective`
            self._inv_k = [float(props.get(f"inv_k_{i}{j}")) for i in range(2) for j in range(3)]
            self._near = float(props.get("near_clip"))
            self._far = float(props.get("far_clip"))
            film = self.film()
            offset, size = film.crop_offset(), film.crop_size()
            # position samples are fractions of the crop window; pixel centres are at integers
            self._x0, self._y0 = float(offset[0]) - 0.5, float(offset[1]) - 0.5
            self._sx, self._sy = float(size[0]), float(size[1])

        def _ray(self, time, wavelength_sample, position_sample, active):
            if rgb:
                wavelengths, weight = mi.Color0f(), unit_weight
            else:
                wavelengths, weight = self.sample_wavelengths(
                    dr.zeros(mi.SurfaceInteraction3f), wavelength_sample, active
                )
            a, b, c, d, e, f = self._inv_k
            x = position_sample.x * self._sx + self._x0
            y = position_sample.y * self._sy + self._y0
            # the direction of K⁻¹ (x, y, 1) is (dx, dy, 1) / n; the clip planes are planes of
            # constant z, as in `perspective`: the ray starts at z = near_clip, ends at z = far_clip
            dx, dy = a * x + b * y + c, d * x + e * y + f
            n = dr.sqrt(dx * dx + dy * dy + 1.0)
            inv_n = 1.0 / n
            ray = mi.RayDifferential3f(
                mi.Point3f(dx * self._near, dy * self._near, self._near),
                mi.Vector3f(dx * inv_n, dy * inv_n, inv_n),
                time,
                wavelengths,
            )
            ray.maxt = (self._far - self._near) * n
            # has_differentials stays False: texel-exact (nearest) textures use none
            return ray, weight

        def sample_ray(self, time, sample1, sample2, sample3, active=True):
            ray, weight = self._ray(time, sample1, sample2, active)
            return mi.Ray3f(ray), weight

        def sample_ray_differential(self, time, sample1, sample2, sample3, active=True):
            return self._ray(time, sample1, sample2, active)

        def bbox(self):
            return mi.ScalarBoundingBox3f(mi.ScalarPoint3f(0.0))

        def traverse(self, callback):
            pass

        def parameters_changed(self, keys):
            pass

        def to_string(self):
            return f"PinholeSensor[inv_k={self._inv_k}, near_clip={self._near}, far_clip={self._far}]"

    mi.register_sensor("snell_pinhole", lambda props: PinholeSensor(props))
    _registered.add(variant)


# ============================================================================ scene pieces
def mesh(mi, name: str, vertices, faces, *, uv=None, normals=None, bsdf=None, emitter=None):
    """A Mitsuba triangle mesh.

    Args:
        mi: the ``mitsuba`` module, set to a variant.
        name: the mesh's name.
        vertices: ``(N, 3)`` positions.
        faces: ``(F, 3)`` vertex indices.
        uv: ``(N, 2)`` texture coordinates, or ``None``.
        normals: ``(N, 3)`` shading normals, or ``None`` (face normals).
        bsdf: the mesh's BSDF, or ``None`` (Mitsuba's default).
        emitter: an ``area`` emitter, or ``None``.

    Returns:
        The ``mi.Mesh``.
    """
    props = mi.Properties()
    if bsdf is not None:
        props["bsdf"] = bsdf
    if emitter is not None:
        props["emitter"] = emitter
    m = mi.Mesh(
        name,
        len(vertices),
        len(faces),
        props=props,
        has_vertex_normals=normals is not None,
        has_vertex_texcoords=uv is not None,
    )
    p = mi.traverse(m)

    def put(key, arr, dtype):
        p[key] = type(p[key])(np.ascontiguousarray(arr, dtype).ravel())

    put("vertex_positions", vertices, np.float32)
    put("faces", faces, np.uint32)
    if normals is not None:
        put("vertex_normals", normals, np.float32)
    if uv is not None:
        put("vertex_texcoords", uv, np.float32)
    p.update()
    return m


def square_pixels(camera: Camera) -> bool:
    """Whether ``camera`` has square pixels without skew (``fx == fy``, ``K[0, 1] == K[1, 0] == 0``,
    exactly), the cameras that Mitsuba's ``perspective`` sensor represents."""
    K = camera.K
    return bool(K[0, 0] == K[1, 1] and K[0, 1] == 0.0 and K[1, 0] == 0.0)


def sensor(mi, camera: Camera, spp: int, near_clip: float, far_clip: float, rect=None, sampler="independent") -> dict:
    """The sensor for ``camera``, any pinhole ``K``: :func:`perspective_sensor` for square pixels,
    else :func:`pinhole_sensor`.

    Why a sensor of its own for other cameras: Mitsuba's ``perspective`` sensor has one field of
    view and square film pixels, and the alternatives are not exact:

    - Rendering a square-pixel grid of another height and resampling its rows to ``H`` mixes
      neighbouring pixels' footprints (a bilinear resample of box-filtered pixels is not the box
      filter over the target pixel), so the background would no longer be I⁻ texel for texel.
    - Scaling the scene along y by ``fx / fy`` makes the projection square-pixel but changes the
      glass: refraction is not invariant under a non-uniform scale of the object's normals and
      of the ray directions relative to them.
    - A non-uniform scale in the sensor's ``to_world`` (the scene unscaled) would turn its rays
      into those of another ``fy``, up to length; but ``perspective`` refuses it ("Scale factors in
      the camera-to-world transformation are not allowed"): its clip distances and the ray
      directions handed to BSDFs assume an orthonormal frame.

    ``snell_pinhole`` instead casts, for each film sample, the ray ``K⁻¹ (x, y, 1)`` (normalised) that
    :meth:`Camera.pixel_rays` gives for the same pixel coordinates; the scene is unchanged. With
    the same ``spp`` and seed it draws the same samples as ``perspective`` (no aperture sample), so
    for a square-pixel ``K`` both give the same rays up to float rounding; square pixels keep
    ``perspective`` (C++, so faster on CPU variants, and bit for bit Mitsuba's own camera). Each
    pixel is the box-filtered mean over samples uniform in its footprint, each on the ray of its
    exact sub-pixel position: the definition that the warps (pixel-centre rays ``K⁻¹ (x, y, 1)``)
    and the true render (sub-pixel rays of :meth:`Camera.pixel_rays`) use, exact up to float32.

    Args:
        mi: the ``mitsuba`` module, set to a variant (:func:`set_variant` registers ``snell_pinhole``).
        camera: the camera.
        spp: samples per pixel of its sampler.
        near_clip, far_clip: the clip distances (along z).
        rect: ``(x0, y0, x1, y1)``, end exclusive: render only those pixels (a crop window of the
            same film); ``None``: the whole image.
        sampler: the sampler, as in :func:`check_sampler`.

    Returns:
        The sensor's scene dict.
    """
    if square_pixels(camera):
        return perspective_sensor(mi, camera, spp, near_clip, far_clip, rect, sampler)
    return pinhole_sensor(mi, camera, spp, near_clip, far_clip, rect, sampler)


def _film_and_sampler(camera: Camera, spp: int, rect, sampler="independent") -> dict:
    """The film (box filter, float32 RGB, optional crop window) and sampler of a sensor dict."""
    H, W = camera.shape
    film = {
        "type": "hdrfilm",
        "width": W,
        "height": H,
        "rfilter": {"type": "box"},
        "pixel_format": "rgb",
        "component_format": "float32",
    }
    if rect is not None:
        x0, y0, x1, y1 = map(int, rect)
        film.update(crop_offset_x=x0, crop_offset_y=y0, crop_width=x1 - x0, crop_height=y1 - y0)
    return {"film": film, "sampler": {**check_sampler(sampler), "sample_count": int(spp)}}


def perspective_sensor(
    mi, camera: Camera, spp: int, near_clip: float, far_clip: float, rect=None, sampler="independent"
) -> dict:
    """Mitsuba's ``perspective`` sensor for ``camera`` (square pixels; see the module's conventions).

    Args:
        mi: the ``mitsuba`` module, set to a variant.
        camera: the camera; its ``fy`` and skew are ignored.
        spp, near_clip, far_clip, rect, sampler: as in :func:`sensor`.

    Returns:
        The sensor's scene dict.
    """
    H, W = camera.shape
    fx, cx, cy = camera.K[0, 0], camera.K[0, 2], camera.K[1, 2]
    d = {
        "type": "perspective",
        "fov_axis": "x",
        "fov": math.degrees(2.0 * math.atan(W / (2.0 * fx))),
        "principal_point_offset_x": ((W - 1) / 2.0 - cx) / W,
        "principal_point_offset_y": ((H - 1) / 2.0 - cy) / H,
        # Mitsuba's camera: +z forward, +x left, +y up of the image -> OpenCV: x right, y down
        "to_world": mi.ScalarTransform4f(np.diag([-1.0, -1.0, 1.0, 1.0]).tolist()),
        "near_clip": float(near_clip),
        "far_clip": float(far_clip),
    }
    d.update(_film_and_sampler(camera, spp, rect, sampler))
    return d


def pinhole_sensor(
    mi, camera: Camera, spp: int, near_clip: float, far_clip: float, rect=None, sampler="independent"
) -> dict:
    """The ``snell_pinhole`` sensor for ``camera``: any ``K`` (``fx != fy``, skew), exact.

    The film sample at Mitsuba film position ``(u, v)`` (pixel ``i`` covers ``[i, i + 1)``) is our
    pixel coordinate ``(x, y) = (u - 0.5, v - 0.5)``; its ray starts at the origin with the direction
    of ``K⁻¹ (x, y, 1)``, between the planes ``z = near_clip`` and ``z = far_clip``. The box filter
    makes each pixel the average over its footprint ``[x - 0.5, x + 0.5) x [y - 0.5, y + 0.5)``.

    Args:
        mi: the ``mitsuba`` module, set to a variant by :func:`set_variant`.
        camera: the camera.
        spp, near_clip, far_clip, rect, sampler: as in :func:`sensor`.

    Returns:
        The sensor's scene dict.
    """
    inv_k = np.linalg.inv(camera.K)  # the matrix of Camera.pixel_rays
    d = {"type": "snell_pinhole", "near_clip": float(near_clip), "far_clip": float(far_clip)}
    d.update({f"inv_k_{i}{j}": float(inv_k[i, j]) for i in range(2) for j in range(3)})
    d.update(_film_and_sampler(camera, spp, rect, sampler))
    return d


def black_bsdf(mi):
    """A black BSDF: delta and zero, so no light sampling at emitters, and the path ends there."""
    return mi.load_dict({"type": "conductor", "specular_reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}})


def rgb_emitter(mi, rgb):
    """An ``area`` emitter of the linear RGB radiance ``rgb``."""
    return mi.load_dict({"type": "area", "radiance": {"type": "rgb", "value": list(map(float, rgb))}})


def texture_emitter(mi, bitmap):
    """An ``area`` emitter textured with the linear RGB ``bitmap``, texel-exact (nearest texel,
    clamped at the border, no colour conversion)."""
    return mi.load_dict(
        {
            "type": "area",
            "radiance": {
                "type": "bitmap",
                "bitmap": bitmap,
                "filter_type": "nearest",
                "wrap_mode": "clamp",
                "raw": True,
            },
        }
    )


def render_linear(
    mi,
    shapes: dict,
    camera: Camera,
    spp: int,
    seed,
    max_depth: int,
    clip: tuple,
    python_rect=None,
    *,
    window=None,
    sampler="independent",
):
    """Render ``shapes`` with Mitsuba's path tracer, once per seed, from one loaded scene.

    Python plugins hold the interpreter lock, so with several render threads they mostly wait for
    each other: on CPU variants the part of the window inside ``python_rect`` is rendered on one
    thread and the rest of the window, tile by tile, on all threads; with the Python sensor of a
    non-square-pixel camera (:func:`pinhole_sensor`) every ray starts in Python, and the whole window
    is rendered on one thread.

    Args:
        mi: the ``mitsuba`` module, set to a variant.
        shapes: the scene's shapes by name.
        camera: the camera.
        spp: samples per pixel (a count ``sampler`` accepts, see :func:`sample_count`), or one per
            seed.
        seed: seed of the sampler, or a sequence of seeds: one render each, of the same scene.
        max_depth: longest light path (surface interactions, the emitter hit included); no Russian
            roulette.
        clip: ``(near_clip, far_clip)``.
        python_rect: ``(x0, y0, x1, y1)``, end exclusive: the only pixels whose rays can reach a
            BSDF written in Python (the object's footprint); ``None``: no such BSDF.
        window: ``(x0, y0, x1, y1)``, end exclusive: render only these pixels (a crop window of
            the film, see the module's conventions); ``None``: the whole image.
        sampler: the sampler, as in :func:`check_sampler`.

    Returns:
        The linear float32 image of the window, ``(y1 - y0, x1 - x0, 3)`` (``(H, W, 3)`` without a
        window); a list of them, one per seed, when ``seed`` is a sequence.
    """
    H, W = camera.shape
    many = isinstance(seed, (list, tuple))
    seeds = [int(s) for s in seed] if many else [int(seed)]
    counts = [int(n) for n in spp] if isinstance(spp, (list, tuple)) else [int(spp)] * len(seeds)
    if len(counts) != len(seeds):
        raise ValueError(f"{len(counts)} sample counts for {len(seeds)} seeds")
    wx0, wy0, wx1, wy1 = (0, 0, W, H) if window is None else tuple(map(int, window))
    if not (0 <= wx0 < wx1 <= W and 0 <= wy0 < wy1 <= H):
        raise ValueError(f"window {window} is empty or not inside the {W}x{H} image")
    full = (wx0, wy0, wx1, wy1) == (0, 0, W, H)
    scene_dict = {
        "type": "scene",
        # no Russian roulette: paths end at emitters (black BSDFs) or after max_depth interactions
        "integrator": {"type": "path", "max_depth": int(max_depth), "rr_depth": int(max_depth) + 1},
        "sensor": sensor(mi, camera, counts[0], *clip, rect=None if full else (wx0, wy0, wx1, wy1), sampler=sampler),
    }
    scene_dict.update(shapes)
    scene = mi.load_dict(scene_dict)

    def render(rect, s, n):
        if rect == (wx0, wy0, wx1, wy1):
            sen = scene.sensors()[0]
        else:
            sen = mi.load_dict(sensor(mi, camera, n, *clip, rect=rect, sampler=sampler))
        return np.array(mi.render(scene, sensor=sen, spp=n, seed=s), dtype=np.float32)[..., :3]

    def one_thread(rect, s, n):
        import drjit as dr

        threads = dr.thread_count()
        dr.set_thread_count(1)
        try:
            return render(rect, s, n)
        finally:
            dr.set_thread_count(threads)

    python_sensor = not square_pixels(camera)

    def render_window(s, n):
        if not mi.variant().startswith("scalar") or (python_rect is None and not python_sensor):
            return render((wx0, wy0, wx1, wy1), s, n)
        if python_sensor:
            return one_thread((wx0, wy0, wx1, wy1), s, n)
        # the Python BSDF's pixels (clipped to the window) on one thread, the rest tile by tile
        x0, y0, x1, y1 = python_rect
        x0, x1 = min(max(x0, wx0), wx1), min(max(x1, wx0), wx1)
        y0, y1 = min(max(y0, wy0), wy1), min(max(y1, wy0), wy1)
        out = np.zeros((wy1 - wy0, wx1 - wx0, 3), np.float32)
        tiles = ((wx0, wy0, wx1, y0), (wx0, y1, wx1, wy1), (wx0, y0, x0, y1), (x1, y0, wx1, y1))
        for rx0, ry0, rx1, ry1 in tiles:
            if rx1 > rx0 and ry1 > ry0:
                out[ry0 - wy0 : ry1 - wy0, rx0 - wx0 : rx1 - wx0] = render((rx0, ry0, rx1, ry1), s, n)
        if x1 > x0 and y1 > y0:
            out[y0 - wy0 : y1 - wy0, x0 - wx0 : x1 - wx0] = one_thread((x0, y0, x1, y1), s, n)
        return out

    images = [render_window(s, n) for s, n in zip(seeds, counts)]
    return images if many else images[0]
