"""Scene pieces of the reference renderer as Mitsuba objects and scene dicts: meshes, sensors,
emitters, BSDFs and samplers, which :mod:`snell_bench.render.reference` assembles.

Importing this module does not import Mitsuba: every function takes the ``mitsuba`` module, set to a
variant by :func:`~snell_bench.render.variants.set_variant` (which also registers the plugins of
:mod:`snell_bench.render.plugins`).

Convention:
    - Frames: everything is in the camera frame of :mod:`snell_bench.scene.camera` (OpenCV: x right,
      y down, z forward, camera at the origin).
    - Sensor: any pinhole ``K`` (see :func:`sensor`). Square pixels without skew (``fx == fy``,
      ``K[0, 1] == K[1, 0] == 0``) use Mitsuba's ``perspective`` sensor: it looks along its local +z
      with +x to the *left* and +y *up* of the image, so its ``to_world`` is the rotation
      ``diag(-1, -1, 1)`` (180° about z); the field of view is ``2 atan(W / (2 fx))`` along x; the
      principal point offset is ``((W - 1) / 2 - cx) / W`` and ``((H - 1) / 2 - cy) / H`` (Mitsuba's
      offsets are fractions of the film, measured from its centre, and shift the ray, not the image).
      Any other ``K`` uses the ``snell_pinhole`` sensor of :mod:`snell_bench.render.plugins`, which
      casts the ray ``K⁻¹ (x, y, 1)`` through each film sample.
    - Pixels: Mitsuba's film pixel ``i`` covers ``[i, i + 1)``; ours (centres at integers) covers
      ``[x - 0.5, x + 0.5)``; a ``box`` pixel filter makes each pixel the average over its own footprint.
    - Windows: a sensor may cover only a window ``(x0, y0, x1, y1)`` of the image (end exclusive), a
      crop window of the same film (``crop_offset`` / ``crop_size``): its pixels see exactly the rays
      they see in the whole image.
    - Emitters and BSDFs: surfaces that emit are ``area`` emitters, textured texel-exact
      (``filter_type = nearest``, ``raw``) or of one RGB colour; their BSDF is black (a zero conductor:
      delta, so no light sampling, and the path ends there).
    - Samplers: one of Mitsuba's (:data:`SAMPLERS`; the sensors here default to ``independent``),
      with ``sample_count`` the render's samples per pixel. The stratified samplers accept only some
      sample counts (see :func:`sample_count`).
"""

from __future__ import annotations

import math

import numpy as np

from snell_bench.render.plugins import PINHOLE_SENSOR
from snell_bench.scene.camera import Camera

__all__ = [
    "SAMPLERS",
    "absorbing_medium",
    "black_bsdf",
    "check_sampler",
    "mesh",
    "perspective_sensor",
    "pinhole_sensor",
    "rgb_emitter",
    "sample_count",
    "sensor",
    "square_pixels",
    "texture_emitter",
]

#: Mitsuba's samplers and the sample counts each accepts (it rounds any other count up).
SAMPLERS = {
    "independent": "any count",
    "stratified": "a square (4, 9, 16, ...)",
    "multijitter": "a count its stratification grid fills (x * y * y with y = floor(cbrt(n)))",
    "orthogonal": "the square of a prime (4, 9, 25, 49, ...)",
    "ldsampler": "a square power of two (4, 16, 64, 256, ...)",
}


# ============================================================================ samplers
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


# ============================================================================ meshes, sensors, emitters, BSDFs
def mesh(
    mi, name: str, vertices, faces, *, uv=None, normals=None, bsdf=None, emitter=None, interior=None, exterior=None
):
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
        interior: the medium inside the (closed) mesh, or ``None`` (the surroundings').
        exterior: the medium outside it, or ``None`` (the scene's: none).

    Returns:
        The ``mi.Mesh``.
    """
    props = mi.Properties()
    if interior is not None:
        props["interior"] = interior
    if exterior is not None:
        props["exterior"] = exterior
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
        mi: the ``mitsuba`` module, set to a variant
            (:func:`~snell_bench.render.variants.set_variant` registers ``snell_pinhole``).
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
        mi: the ``mitsuba`` module, set to a variant by :func:`~snell_bench.render.variants.set_variant`.
        camera: the camera.
        spp, near_clip, far_clip, rect, sampler: as in :func:`sensor`.

    Returns:
        The sensor's scene dict.
    """
    inv_k = np.linalg.inv(camera.K)  # the matrix of Camera.pixel_rays
    d = {"type": PINHOLE_SENSOR, "near_clip": float(near_clip), "far_clip": float(far_clip)}
    d.update({f"inv_k_{i}{j}": float(inv_k[i, j]) for i in range(2) for j in range(3)})
    d.update(_film_and_sampler(camera, spp, rect, sampler))
    return d


def absorbing_medium(mi, sigma):
    """A purely absorbing ``homogeneous`` medium: extinction ``sigma`` per scene unit (linear RGB),
    albedo 0 (nothing scattered), so a path of length ``L`` inside keeps ``exp(-sigma L)``; it
    needs a volumetric integrator (``volpathmis``; ``path`` ignores media)."""
    top = max(float(x) for x in sigma)  # an RGB value is read in [0, 1]: the largest goes in ``scale``
    return mi.load_dict(
        {
            "type": "homogeneous",
            "albedo": 0.0,
            "sigma_t": {"type": "rgb", "value": [float(x) / top for x in sigma]},
            "scale": top,
        }
    )


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
