"""Mitsuba 3 for the reference renderer: importing it, choosing its variant, the refraction-path
BSDF, and the scene pieces (meshes, sensor, emitters) that :mod:`snell_bench.render.reference`
assembles.

Importing this module does not import Mitsuba; :func:`import_mitsuba` and :func:`set_variant` do.

Convention:
    - Frames: everything is in the camera frame of :mod:`snell_bench.scene.camera` (OpenCV: x right,
      y down, z forward, camera at the origin). Mitsuba's perspective camera looks along its local +z
      with +x to the *left* and +y *up* of the image, so its ``to_world`` is the rotation
      ``diag(-1, -1, 1)`` (180° about z). The field of view is ``2 atan(W / (2 fx))`` along x; the
      principal point offset is ``((W - 1) / 2 - cx) / W`` and ``((H - 1) / 2 - cy) / H`` (Mitsuba's
      offsets are fractions of the film, measured from its centre, and shift the ray, not the image).
      Pixels must be square (``fx == fy``): Mitsuba's pinhole camera has one focal length.
    - Pixels: Mitsuba's film pixel ``i`` covers ``[i, i + 1)``; ours (centres at integers) covers
      ``[x - 0.5, x + 0.5)``; a ``box`` pixel filter makes each pixel the average over its own footprint.
    - Emitters and BSDFs: surfaces that emit are ``area`` emitters, textured texel-exact
      (``filter_type = nearest``, ``raw``) or of one RGB colour; their BSDF is black (a zero conductor:
      delta, so no light sampling, and the path ends there).
    - Randomness: Mitsuba's ``independent`` sampler seeded with ``seed``; the same inputs, ``spp``,
      ``seed`` and variant give the same images.
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
    "import_mitsuba",
    "mitsuba_variant",
    "set_variant",
    "probe_render",
    "mesh",
    "sensor",
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
    ref = render_reference(img, depth, cam, obj, spp=2)
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


def _register_plugins(mi) -> None:
    """Register the refraction-path BSDF (``snell_refraction_path``) for the current variant (once
    per variant)."""
    variant = mi.variant()
    if variant in _registered:
        return

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


def sensor(mi, camera: Camera, spp: int, near_clip: float, far_clip: float, rect=None) -> dict:
    """Mitsuba's perspective sensor for ``camera`` (see the module's conventions).

    Args:
        mi: the ``mitsuba`` module, set to a variant.
        camera: the camera (square pixels).
        spp: samples per pixel of its sampler.
        near_clip, far_clip: the clip distances.
        rect: ``(x0, y0, x1, y1)``, end exclusive: render only those pixels (a crop window of the
            same film); ``None``: the whole image.

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
        "film": {
            "type": "hdrfilm",
            "width": W,
            "height": H,
            "rfilter": {"type": "box"},
            "pixel_format": "rgb",
            "component_format": "float32",
        },
        "sampler": {"type": "independent", "sample_count": int(spp)},
    }
    if rect is not None:
        x0, y0, x1, y1 = map(int, rect)
        d["film"].update(crop_offset_x=x0, crop_offset_y=y0, crop_width=x1 - x0, crop_height=y1 - y0)
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
    mi, shapes: dict, camera: Camera, spp: int, seed: int, max_depth: int, clip: tuple, python_rect=None
) -> np.ndarray:
    """Render ``shapes`` with Mitsuba's path tracer.

    Python plugins hold the interpreter lock, so with several render threads they mostly wait for
    each other: on CPU variants the window ``python_rect`` is rendered on one thread and the rest of
    the image, tile by tile, on all threads.

    Args:
        mi: the ``mitsuba`` module, set to a variant.
        shapes: the scene's shapes by name.
        camera: the camera.
        spp: samples per pixel.
        seed: seed of the sampler.
        max_depth: longest light path (surface interactions, the emitter hit included); no Russian
            roulette.
        clip: ``(near_clip, far_clip)``.
        python_rect: ``(x0, y0, x1, y1)``, end exclusive: the only pixels whose rays can reach a
            BSDF written in Python (the object's footprint); ``None``: no such BSDF.

    Returns:
        The linear ``(H, W, 3)`` float32 image.
    """
    scene_dict = {
        "type": "scene",
        # no Russian roulette: paths end at emitters (black BSDFs) or after max_depth interactions
        "integrator": {"type": "path", "max_depth": int(max_depth), "rr_depth": int(max_depth) + 1},
        "sensor": sensor(mi, camera, spp, *clip),
    }
    scene_dict.update(shapes)
    scene = mi.load_dict(scene_dict)

    def render(rect):
        s = mi.load_dict(sensor(mi, camera, spp, *clip, rect=rect))
        return np.array(mi.render(scene, sensor=s, spp=int(spp), seed=int(seed)), dtype=np.float32)[..., :3]

    H, W = camera.shape
    if python_rect is None or not mi.variant().startswith("scalar"):
        return render(None)
    import drjit as dr

    x0, y0, x1, y1 = python_rect
    out = np.zeros((H, W, 3), np.float32)
    for rx0, ry0, rx1, ry1 in ((0, 0, W, y0), (0, y1, W, H), (0, y0, x0, y1), (x1, y0, W, y1)):
        if rx1 > rx0 and ry1 > ry0:
            out[ry0:ry1, rx0:rx1] = render((rx0, ry0, rx1, ry1))
    if x1 > x0 and y1 > y0:
        threads = dr.thread_count()
        dr.set_thread_count(1)
        try:
            out[y0:y1, x0:x1] = render(python_rect)
        finally:
            dr.set_thread_count(threads)
    return out
