"""Reference renders of a glass object in a scene: Mitsuba 3 from I⁻ and its depth, and the true
render of a procedural scene.

:func:`render_reference` is the physically based reference that generated images are scored
against. It uses only what a generated scene provides (I⁻, its z-depth, K) and an independent
renderer (Mitsuba 3), so it cross-checks our own tracer (:mod:`snell_bench.optics`).
:func:`render_true` renders a :class:`~snell_bench.scene.procedural.ProceduralScene` with the object
from its exact 3-D geometry (no depth map): it shows what the object really refracts, including
surfaces that I⁻ does not show.

Convention
----------
- Frames: everything is in the camera frame of :mod:`snell_bench.scene.camera` (OpenCV: x right,
  y down, z forward, camera at the origin). Mitsuba's perspective camera looks along its local +z
  with +x to the *left* and +y *up* of the image, so its ``to_world`` is the rotation
  ``diag(-1, -1, 1)`` (180° about z). The field of view is ``2 atan(W / (2 fx))`` along x; the
  principal point offset is ``((W - 1) / 2 - cx) / W`` and ``((H - 1) / 2 - cy) / H`` (Mitsuba's
  offsets are fractions of the film, measured from its centre, and shift the ray, not the image).
  Pixels must be square (``fx == fy``): Mitsuba's pinhole camera has one focal length.
- Pixels: Mitsuba's film pixel ``i`` covers ``[i, i + 1)``; ours (centres at integers) covers
  ``[x - 0.5, x + 0.5)``; a ``box`` pixel filter makes each pixel the average over its own footprint.
- Background: the depth mesh of :func:`~snell_bench.scene.depth_mesh.build_background` (vertex
  ``y * W + x`` at the unprojected centre of pixel ``(x, y)``, the geometry our tracer uses),
  extended by half a pixel at the image border (border depth repeated). Its front side is an
  ``area`` emitter textured with I⁻ decoded to linear RGB, texel-exact (``filter_type = nearest``),
  UV = image position ``((x + 0.5) / W, (y + 0.5) / H)`` (Mitsuba's ``v = 0`` is the *top* row of a
  bitmap); its BSDF is black. For the image pass every triangle is split at the image midpoints of
  its sides, so that each piece lies in one pixel's footprint and shows exactly that texel.
- Depth edges: where ``depth_to_mesh`` cuts a triangle (or depth is invalid), each valid pixel's
  remaining footprint is a *flap*: a fronto-parallel piece at the pixel's own depth (half a pixel
  wide). So the camera sees I⁻ exactly wherever it sees the background directly, while a depth
  edge stays open for other rays, as in our tracer.
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
  the ray tracer, count for neither). Outer-surface reflections do not count: they mostly see the space behind
  the camera and would otherwise exclude every pixel whose Fresnel reflectance exceeds the threshold.
- Object normals: each face corner gets its own vertex (vertices split at every corner) with the
  creased shading normal of :meth:`GlassObject.corner_normals`, so smooth parts interpolate and
  sharp edges stay sharp, as in our tracer.
- ``object_mask``: pixel-centre rays that hit the object before the background (the background is
  hit at the pixel's own depth-mesh vertex), as in :func:`~snell_bench.optics.warps.compute_warps`.
- Randomness: Mitsuba's ``independent`` sampler seeded with ``seed``; the same inputs, ``spp``,
  ``seed`` and variant give the same images.
"""

from __future__ import annotations

import logging
import math
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import BackgroundMesh, bounding_box_mesh, build_background, valid_depth_mask
from snell_bench.scene.objects import GlassObject

log = logging.getLogger(__name__)

__all__ = ["ReferenceRender", "mitsuba_variant", "render_reference", "render_true", "VARIANT_ENV"]

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
#: The back sides of the background sit this far (relative to their distance) behind the front.
_BACK_OFFSET = 1e-4

_probed_variant: str | None = None
_registered: set[str] = set()


# ============================================================================ Mitsuba set-up
def _import_mitsuba():
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
    code = "from snell_bench.render.mitsuba_ref import _probe_render; _probe_render()"
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


def _probe_render() -> None:
    """Body of the variant probe (runs in a subprocess, variant forced by the environment): a tiny
    reference render of a sphere before a textured wall."""
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
    process. Raises ``ImportError`` if Mitsuba is not installed.
    """
    global _probed_variant
    mi = _import_mitsuba()
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


def _set_variant():
    mi = _import_mitsuba()
    mi.set_variant(mitsuba_variant())
    _register_plugins(mi)
    return mi


def _register_plugins(mi) -> None:
    """Register the refraction-path BSDF for the current variant (once per variant)."""
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


# ============================================================================ results
@dataclass
class ReferenceRender:
    """A reference render (see the module's conventions).

    Attributes
    ----------
    image: ``(H, W, 3)`` float32 sRGB in [0, 1].
    linear: ``(H, W, 3)`` float32 linear RGB (not clipped).
    unobserved: ``(H, W)`` float32 in [0, 1]: share of the pixel's refracted light from surfaces
        that I⁻ does not show.
    object_mask: ``(H, W)`` bool: the pixel-centre ray hits the object first.
    mask: ``(H, W)`` bool: ``object_mask & (unobserved < unobserved_threshold)``, the metric mask.
    unobserved_threshold, spp, seed: the settings it was rendered with.
    variant: the Mitsuba variant it was rendered with.
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


# ============================================================================ geometry
def _triangulate_grid(rows: int, cols: int) -> np.ndarray:
    """The triangles of a ``rows x cols`` vertex grid, split like ``depth_to_mesh`` (int64)."""
    idx = np.arange(rows * cols, dtype=np.int64).reshape(rows, cols)
    a, b = idx[:-1, :-1], idx[:-1, 1:]
    c, d = idx[1:, :-1], idx[1:, 1:]
    return np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])


def _grid_triangle_ids(faces: np.ndarray, cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Ids of the triangles of :func:`_triangulate_grid` (``2 * lowest vertex index + kind``),
    whatever the vertex order; ``ok`` is False for a triangle that is not one of them."""
    s = np.sort(np.asarray(faces, np.int64), axis=1)
    d1, d2 = s[:, 1] - s[:, 0], s[:, 2] - s[:, 0]
    kind_b = (d1 == cols - 1) & (d2 == cols)
    ok = ((d1 == 1) & (d2 == cols)) | kind_b
    return 2 * s[:, 0] + kind_b, ok


@dataclass
class _BackgroundGeometry:
    vertices: np.ndarray  # (Ne, 3) float32, the extended vertex grid
    pixels: np.ndarray  # (Ne, 2) float64 pixel coordinates (x, y) of the vertices
    valid: np.ndarray  # (Ne,) bool: the vertex has a valid depth
    observed: np.ndarray  # (F, 3) int64 faces: the depth mesh (and its border extension)
    open: np.ndarray  # (S, 3) int64 grid triangles left out (cut at depth edges or invalid depth)


def _background_geometry(
    bg: BackgroundMesh, depth: np.ndarray, camera: Camera, edge_threshold: float
) -> _BackgroundGeometry:
    """The depth mesh on a vertex grid extended by a half-pixel ring at the image border."""
    H, W = camera.shape
    He, We = H + 2, W + 2
    xs = np.concatenate([[-0.5], np.arange(W, dtype=np.float64), [W - 0.5]])
    ys = np.concatenate([[-0.5], np.arange(H, dtype=np.float64), [H - 0.5]])
    valid = np.pad(valid_depth_mask(depth), 1, mode="edge")
    z = np.pad(np.where(valid_depth_mask(depth), depth, 0.0).astype(np.float64), 1, mode="edge")
    X, Y = np.meshgrid(xs, ys)
    rays = camera.pixel_rays(np.stack([X, Y], -1), normalize=False)
    verts = (rays * z[..., None]).astype(np.float32)
    verts[1:-1, 1:-1] = np.asarray(bg.vertices, np.float32).reshape(H, W, 3)  # exactly the depth mesh
    verts = verts.reshape(-1, 3)

    # interior pixel (x, y) is extended vertex (y + 1) * We + x + 1
    f = np.asarray(bg.faces, np.int64)
    observed_inner = (f // W + 1) * We + (f % W + 1)
    cand = _triangulate_grid(He, We)
    vf, zf = valid.reshape(-1), z.reshape(-1)
    ok = vf[cand].all(axis=1)
    any_valid = vf[cand].any(axis=1)
    row, col = cand // We, cand % We
    border = ((row == 0) | (row == He - 1) | (col == 0) | (col == We - 1)).any(axis=1)
    zt = zf[cand]
    with np.errstate(divide="ignore", invalid="ignore"):
        smooth = zt.max(axis=1) / zt.min(axis=1) <= 1.0 + edge_threshold
    kept_ids, kept_ok = _grid_triangle_ids(observed_inner, We)
    if not kept_ok.all():
        raise RuntimeError("build_background returned triangles that do not follow the pixel grid")
    marked = np.zeros(2 * He * We, bool)
    marked[kept_ids] = True
    kept_inner = marked[_grid_triangle_ids(cand, We)[0]]
    observed_border = border & ok & smooth
    observed = np.concatenate([observed_inner, cand[observed_border]])
    open_ = cand[any_valid & ~kept_inner & ~observed_border]
    return _BackgroundGeometry(verts, np.stack([X, Y], -1).reshape(-1, 2), vf, observed, open_)


def _subdivide(
    geo: _BackgroundGeometry, shape: tuple[int, int], faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split background triangles at the midpoints of their sides, taken in the image, so that
    every piece lies inside one pixel's footprint and textures it with exactly that pixel's texel.

    The grid's pixel edges run through those midpoints. A side's midpoint in the image is the 3-D
    point where ``1/z`` is halfway between its ends; the pieces lie in the plane of their triangle
    (the geometry is unchanged). UVs are the pieces' image positions: interpolated within a piece,
    they stay inside one texel, so the perspective-correct interpolation (not linear in the image)
    cannot shift texels at steep surfaces. Returns ``(vertices, faces, uv)`` of the referenced
    vertices of the half-pixel grid (float32, int64, float32).
    """
    H, W = shape
    He, We = H + 2, W + 2
    Hh, Wh = 2 * He - 1, 2 * We - 1
    f = np.asarray(faces, np.int64)
    r, c = f // We, f % We  # (F, 3) each
    sub = np.empty((4, len(f), 3), np.int64)
    corner = (2 * r) * Wh + 2 * c
    m01, m12, m20 = ((r[:, i] + r[:, j]) * Wh + (c[:, i] + c[:, j]) for i, j in ((0, 1), (1, 2), (2, 0)))
    p0, p1, p2 = corner[:, 0], corner[:, 1], corner[:, 2]
    for k, piece in enumerate(((p0, m01, m20), (m01, p1, m12), (m20, m12, p2), (m01, m12, m20))):
        for j in range(3):
            sub[k, :, j] = piece[j]
    sub = sub.reshape(-1, 3)
    referenced = np.zeros(Hh * Wh, bool)
    referenced[sub.reshape(-1)] = True
    used = np.flatnonzero(referenced)
    inv = (np.cumsum(referenced) - 1)[sub]

    # the half-pixel grid: corners, then midpoints of horizontal, vertical and diagonal sides (the
    # diagonal runs from the top-right to the bottom-left corner of a cell)
    V = geo.vertices.astype(np.float64).reshape(He, We, 3)

    def mid(p, q):
        zp, zq = p[..., 2:3], q[..., 2:3]
        with np.errstate(divide="ignore", invalid="ignore"):
            return (zq * p + zp * q) / (zp + zq)

    P = np.empty((Hh, Wh, 3))
    P[::2, ::2] = V
    P[::2, 1::2] = mid(V[:, :-1], V[:, 1:])
    P[1::2, ::2] = mid(V[:-1], V[1:])
    P[1::2, 1::2] = mid(V[:-1, 1:], V[1:, :-1])
    px = geo.pixels.reshape(He, We, 2)
    xh = np.empty(Wh)
    xh[::2], xh[1::2] = px[0, :, 0], 0.5 * (px[0, :-1, 0] + px[0, 1:, 0])
    yh = np.empty(Hh)
    yh[::2], yh[1::2] = px[:, 0, 1], 0.5 * (px[:-1, 0, 1] + px[1:, 0, 1])
    R, C = used // Wh, used % Wh
    uv = np.stack([(xh[C] + 0.5) / W, (yh[R] + 0.5) / H], -1)
    return P.reshape(-1, 3)[used].astype(np.float32), inv, uv.astype(np.float32)


def _flaps(geo: _BackgroundGeometry, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rest of each valid pixel's footprint where the depth mesh has no triangle: fronto-parallel
    pieces at the pixel's own depth.

    Each left-out grid triangle is split at the image midpoints of its sides into four pieces that
    each lie in one pixel's footprint (the one of the nearest corner); a piece is kept if that pixel
    has a valid depth, and placed at that depth. Seen from the camera, the observed mesh and the
    flaps cover every valid pixel's footprint exactly once; seen from elsewhere, a depth edge stays
    open (as in our tracer) except for these half-pixel flaps. Returns
    ``(vertices (3 P, 3) float32, faces (P, 3), uv (3 P, 2) float32)``.
    """
    H, W = camera.shape
    f = geo.open
    if len(f) == 0:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int64), np.zeros((0, 2), np.float32)
    Q = geo.pixels[f]  # (S, 3, 2)
    z = geo.vertices[f][..., 2].astype(np.float64)  # (S, 3)
    ok = geo.valid[f]
    q0, q1, q2 = Q[:, 0], Q[:, 1], Q[:, 2]
    q01, q12, q20 = 0.5 * (q0 + q1), 0.5 * (q1 + q2), 0.5 * (q2 + q0)
    pieces = np.stack(
        [np.stack(t, 1) for t in ((q0, q01, q20), (q01, q1, q12), (q20, q12, q2), (q01, q12, q20))], 1
    )  # (S, 4, 3, 2), wound like their triangle
    centre = pieces.mean(axis=2)  # (S, 4, 2)
    owner = np.argmin(np.linalg.norm(centre[:, :, None, :] - Q[:, None, :, :], axis=-1), axis=-1)  # (S, 4)
    zo = np.take_along_axis(z, owner, axis=1)
    keep = np.take_along_axis(ok, owner, axis=1)
    pieces, zo = pieces[keep], zo[keep]  # (P, 3, 2), (P,)
    from_pixels = np.linalg.inv(camera.K)
    h = np.concatenate([pieces, np.ones(pieces.shape[:2] + (1,))], axis=-1)  # (P, 3, 3)
    verts = (h @ from_pixels.T) * zo[:, None, None]
    uv = np.stack([(pieces[..., 0] + 0.5) / W, (pieces[..., 1] + 0.5) / H], -1)
    n = len(pieces)
    return (
        verts.reshape(-1, 3).astype(np.float32),
        np.arange(3 * n, dtype=np.int64).reshape(n, 3),
        uv.reshape(-1, 2).astype(np.float32),
    )


def _inward_box(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Box faces wound so that their normals point into the box."""
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64).copy()
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    out = np.einsum("ij,ij->i", n, v[f].mean(axis=1) - v.mean(axis=0)) > 0
    f[out] = f[out][:, [0, 2, 1]]
    return f


def _check_inputs(i_minus, depth, camera: Camera, obj: GlassObject, spp: int) -> tuple[np.ndarray, np.ndarray]:
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
    fx, fy = camera.K[0, 0], camera.K[1, 1]
    if abs(fx - fy) > 1e-4 * max(fx, fy) or abs(camera.K[0, 1]) > 1e-9:
        raise ValueError(
            f"the reference renderer needs square pixels without skew (Mitsuba's pinhole camera has one focal "
            f"length), got fx={fx:.6g}, fy={fy:.6g}, skew={camera.K[0, 1]:.3g}; resample the image to square pixels"
        )
    return img, depth


# ============================================================================ scene assembly
def _mesh(mi, name: str, vertices, faces, *, uv=None, normals=None, bsdf=None, emitter=None):
    props = mi.Properties()
    if bsdf is not None:
        props["bsdf"] = bsdf
    if emitter is not None:
        props["emitter"] = emitter
    mesh = mi.Mesh(
        name, len(vertices), len(faces), props=props,
        has_vertex_normals=normals is not None, has_vertex_texcoords=uv is not None,
    )
    p = mi.traverse(mesh)

    def put(key, arr, dtype):
        p[key] = type(p[key])(np.ascontiguousarray(arr, dtype).ravel())

    put("vertex_positions", vertices, np.float32)
    put("faces", faces, np.uint32)
    if normals is not None:
        put("vertex_normals", normals, np.float32)
    if uv is not None:
        put("vertex_texcoords", uv, np.float32)
    p.update()
    return mesh


def _sensor(mi, camera: Camera, spp: int, near_clip: float, far_clip: float, rect=None) -> dict:
    """Mitsuba's perspective sensor for ``camera``; ``rect = (x0, y0, x1, y1)`` renders only
    those pixels (a crop window of the same film)."""
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


def _black(mi):
    # delta and zero: no light sampling at the emitters, and the path ends there
    return mi.load_dict({"type": "conductor", "specular_reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}})


def _rgb_emitter(mi, rgb):
    return mi.load_dict({"type": "area", "radiance": {"type": "rgb", "value": list(map(float, rgb))}})


def _texture_emitter(mi, bitmap):
    return mi.load_dict(
        {
            "type": "area",
            "radiance": {
                "type": "bitmap", "bitmap": bitmap, "filter_type": "nearest", "wrap_mode": "clamp", "raw": True,
            },
        }
    )


def _render_linear(
    mi, shapes: dict, camera: Camera, spp: int, seed: int, max_depth: int, clip: tuple, python_rect=None
) -> np.ndarray:
    """Render ``shapes`` to a linear ``(H, W, 3)`` image.

    ``python_rect = (x0, y0, x1, y1)``: the only pixels whose rays can reach a BSDF written in
    Python (the object's footprint). Python plugins hold the interpreter lock, so with several
    render threads they mostly wait for each other: on CPU variants that window is rendered on one
    thread and the rest of the image, tile by tile, on all threads.
    """
    scene_dict = {
        "type": "scene",
        # no Russian roulette: paths end at emitters (black BSDFs) or after max_depth interactions
        "integrator": {"type": "path", "max_depth": int(max_depth), "rr_depth": int(max_depth) + 1},
        "sensor": _sensor(mi, camera, spp, *clip),
    }
    scene_dict.update(shapes)
    scene = mi.load_dict(scene_dict)

    def render(rect):
        sensor = mi.load_dict(_sensor(mi, camera, spp, *clip, rect=rect))
        return np.array(mi.render(scene, sensor=sensor, spp=int(spp), seed=int(seed)), dtype=np.float32)[..., :3]

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


def _object_rect(camera: Camera, obj: GlassObject) -> tuple[int, int, int, int]:
    """Pixels whose footprints can overlap the object's projection, plus one pixel of margin:
    ``(x0, y0, x1, y1)``, end exclusive."""
    pix, _ = camera.project(np.asarray(obj.vertices, np.float64))
    lo, hi = np.nanmin(pix, axis=0), np.nanmax(pix, axis=0)
    H, W = camera.shape
    x0, y0 = (int(np.clip(np.floor(v + 0.5) - 1, 0, n)) for v, n in ((lo[0], W), (lo[1], H)))
    x1, y1 = (int(np.clip(np.floor(v + 0.5) + 2, 0, n)) for v, n in ((hi[0], W), (hi[1], H)))
    return x0, y0, x1, y1


def _object_arrays(obj: GlassObject) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices split at every face corner, with the creased corner normals."""
    f = np.asarray(obj.faces, np.int64)
    v = np.asarray(obj.vertices, np.float64)[f].reshape(-1, 3)
    n = obj.corner_normals().reshape(-1, 3)
    return v, np.arange(len(v), dtype=np.int64).reshape(-1, 3), n


def _object_mask(depth: np.ndarray, camera: Camera, obj: GlassObject) -> np.ndarray:
    """Pixel-centre rays that hit the object before the background (which they hit at their own
    depth-mesh vertex, where the depth is valid)."""
    import open3d as o3d

    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(
        o3d.core.Tensor.from_numpy(np.ascontiguousarray(obj.vertices, np.float32)),
        o3d.core.Tensor.from_numpy(np.ascontiguousarray(obj.faces, np.uint32)),
    )
    d = camera.pixel_rays().reshape(-1, 3)
    rays = np.concatenate([np.zeros_like(d), d], axis=1).astype(np.float32)
    t_obj = rc.cast_rays(o3d.core.Tensor.from_numpy(rays))["t_hit"].numpy().astype(np.float64)
    valid = valid_depth_mask(depth)
    t_bg = np.where(valid, np.where(valid, depth, 1.0), np.inf).reshape(-1) / d[:, 2]
    return (np.isfinite(t_obj) & (t_obj < t_bg)).reshape(camera.shape)


# ============================================================================ public API
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

    Convention
    ----------
    Camera frame and pixel centres of :mod:`snell_bench.scene.camera`; images ``(H, W, 3)`` float32,
    sRGB in [0, 1] in and out (rendering is in linear RGB); masks ``(H, W)`` bool. Two passes of
    ``spp`` samples per pixel: the image (observed surfaces emit I⁻, the object is a dielectric) and
    the unobserved share (refraction path only). See the module's docstring for the scene.

    Parameters
    ----------
    i_minus: ``(H, W, 3)`` sRGB image in [0, 1] of the object-free scene.
    depth: ``(H, W)`` z-depth of I⁻ (NaN, inf or <= 0 where unknown).
    camera: the camera of I⁻ (square pixels).
    obj: the glass object in camera coordinates.
    spp: samples per pixel of each of the two passes.
    edge_threshold: relative depth jump at which the depth mesh is cut (as in ``compute_warps``).
    seed: seed of Mitsuba's sampler.
    unobserved_threshold: object pixels whose unobserved share is below this form ``mask``.
    max_depth: longest light path (surface interactions, the emitter hit included).
    fresnel: ``True`` (default): the object is Mitsuba's ``dielectric`` (reflection and refraction
        sampled with Fresnel weights). ``False``: every pixel sample follows the refraction path
        (refraction at each interface, reflection only under total internal reflection) with weight
        1, so ``image`` shows what our self-warp π^R predicts, without Fresnel reflection or loss:
        a purely geometric render, for cross-checks.

    Raises ``ImportError`` (naming the ``render`` extra) when Mitsuba is not installed.
    """
    img, depth = _check_inputs(i_minus, depth, camera, obj, spp)
    if not (0.0 < unobserved_threshold <= 1.0):
        raise ValueError(f"unobserved_threshold must be in (0, 1], got {unobserved_threshold}")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    mi = _set_variant()
    variant = mi.variant()

    lo, hi = obj.mesh.bounds
    bg = build_background(depth, camera, edge_threshold, extra_points=np.stack([lo, hi]))
    geo = _background_geometry(bg, depth, camera, edge_threshold)
    fv, ff, fuv = _flaps(geo, camera)
    # the observed surface, each triangle split so that every piece shows one texel (pass a) ...
    sv, sf, suv = _subdivide(geo, camera.shape, geo.observed)
    tex_v, tex_f, tex_uv = np.concatenate([sv, fv]), np.concatenate([sf, ff + len(sv)]), np.concatenate([suv, fuv])
    # ... and unsplit (pass b); its back side is unobserved
    obs_v, obs_f = np.concatenate([geo.vertices, fv]), np.concatenate([geo.observed, ff + len(geo.vertices)])
    back_v, back_f = obs_v * np.float32(1.0 + _BACK_OFFSET), obs_f[:, [0, 2, 1]]
    box_faces = _inward_box(bg.box_vertices, bg.box_faces)
    ov, of, on = _object_arrays(obj)
    # clip planes well inside the nearest geometry and beyond the farthest
    front = ov[:, 2][ov[:, 2] > 0]
    zmin = min([float(np.min(depth[valid_depth_mask(depth)]))] + ([float(front.min())] if len(front) else []))
    clip = (1e-3 * zmin, 10.0 * float(np.linalg.norm(np.abs(bg.box_vertices).max(axis=0))))
    texture = mi.Bitmap(np.ascontiguousarray(srgb_to_linear(np.clip(img, 0.0, 1.0)), dtype=np.float32))
    rect = _object_rect(camera, obj)
    timings["geometry"] = time.perf_counter() - t0

    def dielectric(kind: str):
        return mi.load_dict({"type": kind, "int_ior": float(obj.ior), "ext_ior": 1.0})

    def object_shape(bsdf):
        return _mesh(mi, "object", ov, of, normals=on, bsdf=bsdf)

    # ---- (a) observed surfaces emit I⁻, the rest is black; Mitsuba's dielectric
    t0 = time.perf_counter()
    shapes = {
        "background": _mesh(mi, "background", tex_v, tex_f, uv=tex_uv, bsdf=_black(mi),
                            emitter=_texture_emitter(mi, texture)),
        "object": object_shape(dielectric("dielectric" if fresnel else "snell_refraction_path")),
    }
    linear = _render_linear(mi, shapes, camera, spp, seed, max_depth, clip, None if fresnel else rect)
    timings["image"] = time.perf_counter() - t0

    # ---- (b) observed surfaces emit green, unobserved ones red; the refraction path
    t0 = time.perf_counter()
    red, green = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
    shapes = {
        "background": _mesh(mi, "background", obs_v, obs_f, bsdf=_black(mi), emitter=_rgb_emitter(mi, green)),
        "back": _mesh(mi, "back", back_v, back_f, bsdf=_black(mi), emitter=_rgb_emitter(mi, red)),
        "box": _mesh(mi, "box", bg.box_vertices, box_faces, bsdf=_black(mi), emitter=_rgb_emitter(mi, red)),
        "object": object_shape(dielectric("snell_refraction_path")),
    }
    share = _render_linear(mi, shapes, camera, spp, seed, max_depth, clip, rect)
    timings["unobserved"] = time.perf_counter() - t0

    u, o = np.clip(share[..., 0], 0.0, None), np.clip(share[..., 1], 0.0, None)
    total = u + o
    with np.errstate(divide="ignore", invalid="ignore"):
        unobserved = np.where(total > 1e-6, u / total, 1.0)
    unobserved = np.clip(unobserved, 0.0, 1.0).astype(np.float32)
    object_mask = _object_mask(depth, camera, obj)
    mask = object_mask & (unobserved < unobserved_threshold)
    image = linear_to_srgb(np.clip(linear, 0.0, 1.0)).astype(np.float32)
    log.info(
        "reference (%s, %d spp): %d object pixels, %d in the mask; %s",
        variant, spp, int(object_mask.sum()), int(mask.sum()), {k: round(v, 2) for k, v in timings.items()},
    )
    return ReferenceRender(
        image=image,
        linear=linear,
        unobserved=unobserved,
        object_mask=object_mask,
        mask=mask,
        unobserved_threshold=float(unobserved_threshold),
        variant=variant,
        spp=int(spp),
        seed=int(seed),
        timings=timings,
    )


def _sample_offsets(spp: int, jitter: bool, rng: np.random.Generator, shape: tuple[int, int]) -> list[np.ndarray]:
    """Sub-pixel offsets ``(H, W, 2)`` (x, y) in [-0.5, 0.5) for each of ``spp`` samples.

    ``jitter=False`` needs a square ``spp = s * s`` and gives the centres of an s x s grid of strata
    (the pattern of ``ProceduralScene.render(supersample=s)``). ``jitter=True`` jitters within those
    strata if ``spp`` is square, else draws uniform offsets.
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
    """The true render ``(H, W, 3)`` float32 sRGB of a procedural scene with the glass object.

    Uses the scene's exact 3-D geometry and radiance (:meth:`ProceduralScene.radiance`), not a
    depth map. Per pixel sample: if the camera ray hits the object first, it is traced through the
    object with :class:`~snell_bench.optics.tracer.SceneTracer` (background = the scene's mesh and a
    box around it) and its colour is ``R c_refl + (1 - R) c_refr`` in linear RGB, with ``c_refr`` the
    radiance along the exit ray, ``c_refl`` along the mirror ray at the first surface, ``R`` the
    Fresnel reflectance there; rays still inside after ``max_bounces`` interactions are black.
    Other rays get the scene's radiance. Samples are averaged in linear RGB, clipped to [0, 1] and
    encoded to sRGB.

    Convention
    ----------
    ``spp`` sub-pixel samples, drawn from ``numpy.random.default_rng(seed)``: jittered in an s x s
    grid of strata when ``spp = s * s``, else uniform. ``jitter=False`` (square ``spp``) uses the
    strata centres, the pattern of ``scene.render(supersample=s)``, so pixels that do not see the
    object equal that render exactly.
    """
    from snell_bench.optics.tracer import HitKind, SceneTracer

    if int(spp) != spp or spp < 1:
        raise ValueError(f"spp must be a positive integer, got {spp!r}")
    if not obj.placed:
        raise ValueError(
            f"{obj.name}: the object is in its canonical frame; place it first (snell_bench.scene.place_object)"
        )
    m = scene.mesh()
    sv = np.asarray(m.vertices, np.float32)
    lo, hi = obj.mesh.bounds
    box_v, box_f = bounding_box_mesh(np.concatenate([sv, np.zeros((1, 3), np.float32), np.stack([lo, hi])]))
    background = BackgroundMesh(sv, np.asarray(m.faces, np.uint32), box_v, box_f, 0, 0)
    tracer = SceneTracer(background, obj, max_bounces=max_bounces)

    H, W = camera.shape
    grid = camera.pixel_grid()
    rng = np.random.default_rng(seed)
    acc = np.zeros((H * W, 3), np.float64)
    exited = (HitKind.OBSERVED, HitKind.UNOBSERVED, HitKind.ESCAPED)
    for off in _sample_offsets(int(spp), jitter, rng, (H, W)):
        d = camera.pixel_rays(grid + off).reshape(-1, 3)
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
            ng = tr.first_geometric_normal
            side = np.where(np.einsum("ij,ij->i", tr.reflected, ng) >= 0, 1.0, -1.0)
            refl = scene.radiance(tr.first_point + (tracer.eps * side)[:, None] * ng, tr.reflected)[0]
            R = tr.fresnel[:, None]
            col[cand] = R * refl + (1.0 - R) * refr
        acc += col
    linear = (acc / spp).reshape(H, W, 3)
    return linear_to_srgb(np.clip(linear, 0.0, 1.0)).astype(np.float32)
