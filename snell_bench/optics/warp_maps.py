"""Stages 4-7 of :func:`~snell_bench.optics.warps.compute_warps`: tracing the refracted and
reflected paths and turning their ends into warps (conventions: :mod:`snell_bench.optics.warps`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snell_bench.imaging.equirect import PanoramaCamera
from snell_bench.optics.far_field import POINT_AT_INFINITY, AtInfinity
from snell_bench.optics.occlusion import ray_ends_seen
from snell_bench.optics.tracer import BackgroundHit, HitKind, RefractionTrace, SceneTracer
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import BackgroundMesh, valid_depth_mask

__all__ = [
    "RayScene",
    "PrimaryRays",
    "trace_refraction",
    "refraction_warps",
    "trace_reflection",
    "reflection_warps",
    "panorama_warps",
    "pano_coords",
    "pano_to_persp_warp",
    "pano_refraction_frame_warp",
    "vertex_normals",
    "self_warp",
]


@dataclass
class RayScene:
    """What the rays are cast against."""

    background: BackgroundMesh  #: the depth mesh (far pixels left out) and the box of unobserved space
    tracer: SceneTracer
    at_inf: AtInfinity | None  #: resolves rays towards far background (``None``: no far pixel)
    far_stats: dict  #: the ``far_background`` statistics (empty without a tolerance)


@dataclass
class PrimaryRays:
    """The pixels that see the object (indices into the flattened ``(H * W)`` image)."""

    traced: int  #: primary rays cast (the region of interest, or every pixel)
    pixels: np.ndarray  #: (N,) int flat indices of the object pixels, row-major
    rays: np.ndarray  #: (N, 3) unit camera rays of those pixels
    mask: np.ndarray  #: (H * W,) bool object mask


# ---------------------------------------------------------------------------------------------
# stage 4: refraction
# ---------------------------------------------------------------------------------------------
def trace_refraction(scene: RayScene, primary: PrimaryRays) -> RefractionTrace:
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


def refraction_warps(
    camera: Camera,
    tracer: SceneTracer,
    tr: RefractionTrace,
    primary: PrimaryRays,
    verify_visibility: bool,
    back_faces: bool = False,
) -> dict[str, np.ndarray]:
    """π^R and the per-pixel data of the refracted paths, over the whole image.

    Args:
        camera, verify_visibility, back_faces: as :func:`compute_warps` (``back_faces``: a path that
            ends on the back side of the depth mesh is valid at the pixel that shows the front side
            of its end point; its ``refraction_kind`` stays UNOBSERVED).
        tracer: the scene's tracer.
        tr: the refracted paths of the object pixels.
        primary: the object pixels.

    Returns:
        Flat ``(H * W, ...)`` arrays ``refraction`` (the identity outside the object, NaN where
        invalid), ``refraction_valid``, ``refraction_kind``, ``bounces`` (clipped to 255),
        ``fresnel``, ``path_length`` and ``optical_depth`` (0 outside the object), ``interface_transmission``
        (1 outside).
    """
    H, W = camera.shape
    cand = primary.pixels
    refraction = camera.pixel_grid().reshape(-1, 2).astype(np.float32)
    refraction_valid = np.ones(H * W, bool)
    back = (tr.kind == HitKind.UNOBSERVED) & ~tr.on_box
    seen_kind = np.where(back_faces & back, np.int8(HitKind.OBSERVED), tr.kind)
    src, ok = self_warp(camera, tracer, tr.point, seen_kind, verify_visibility)
    refraction[cand] = np.where(ok[:, None], src, np.nan)
    refraction_valid[cand] = ok
    kind = np.zeros(H * W, np.int8)
    kind[cand] = tr.kind
    bounces = np.zeros(H * W, np.uint8)
    bounces[cand] = np.minimum(tr.bounces, 255)
    fres = np.zeros(H * W, np.float32)
    fres[cand] = tr.fresnel
    path = np.zeros(H * W, np.float32)
    path[cand] = tr.path_length
    depth = np.zeros((H * W, 3), np.float32)
    depth[cand] = tr.optical_depth
    through = np.ones(H * W, np.float32)
    through[cand] = tr.interface_transmission
    return {
        "refraction": refraction,
        "refraction_valid": refraction_valid,
        "refraction_kind": kind,
        "bounces": bounces,
        "fresnel": fres,
        "path_length": path,
        "optical_depth": depth,
        "interface_transmission": through,
    }


# ---------------------------------------------------------------------------------------------
# stage 5: reflection
# ---------------------------------------------------------------------------------------------
def trace_reflection(scene: RayScene, tr: RefractionTrace) -> BackgroundHit:
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


def reflection_warps(
    camera: Camera, tracer: SceneTracer, refl: BackgroundHit, primary: PrimaryRays, verify_visibility: bool
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
    src_r, ok_r = self_warp(camera, tracer, refl.point, refl.kind, verify_visibility)
    reflection = np.full((H * W, 2), np.nan, np.float32)
    reflection_valid = np.zeros(H * W, bool)
    reflection[cand] = np.where(ok_r[:, None], src_r, np.nan)
    reflection_valid[cand] = ok_r
    return {"reflection": reflection, "reflection_valid": reflection_valid}


# ---------------------------------------------------------------------------------------------
# stage 6: panorama coordinates of the refracted and mirror rays
# ---------------------------------------------------------------------------------------------
def panorama_warps(
    pano: PanoramaCamera,
    scene: RayScene,
    tr: RefractionTrace,
    refl: BackgroundHit,
    primary: PrimaryRays,
    *,
    back_faces: bool = False,
    reflection_parallax: bool = True,
) -> dict[str, np.ndarray]:
    """π⁻¹ and π^-R: panorama pixels of the ends of the refracted and mirror rays.

    π⁻¹ of a refracted ray that left the object is the panorama pixel of its end point seen from
    the panorama centre (its direction where it ends nowhere), valid only where the centre sees
    that point (:func:`~snell_bench.optics.occlusion.ray_ends_seen`): a surface between the centre
    and the point would otherwise lend its colour to the glass. π^-R likewise for the mirror ray's
    end (parallax, occlusion-tested); with ``reflection_parallax=False`` it is the panorama pixel of
    the mirror direction alone, as an environment map at infinity is read (nothing to occlude).

    Args:
        pano: the panorama centred at the object.
        scene: the ray-casting scene (the re-casts from the centre ignore the object).
        tr: the refracted paths of the object pixels.
        refl: where their mirror rays end.
        primary: the object pixels.
        back_faces: the occlusion test accepts a re-cast that reaches either side of the depth mesh
            at the point (the authors' re-cast); ``False``: the side the traced ray arrived on.
        reflection_parallax: as :func:`compute_warps`.

    Returns:
        Flat ``(H * W, ...)`` arrays ``pano_refraction`` (NaN outside the object, where the refracted
        ray did not leave the object and where the centre does not see its end),
        ``pano_refraction_valid``, ``pano_reflection`` and ``pano_reflection_valid`` (likewise).
    """
    n, cand = len(primary.mask), primary.pixels
    c, sides = pano.center, not back_faces
    exited = np.isin(tr.kind, (HitKind.OBSERVED, HitKind.UNOBSERVED, HitKind.ESCAPED))
    pr = pano_coords(pano, tr.point, tr.direction)
    ok = exited & np.isfinite(pr).all(axis=1)
    idx = np.flatnonzero(ok)
    ok[idx] = ray_ends_seen(
        scene.tracer, scene.at_inf, c, tr.point[idx], tr.origin[idx], tr.kind[idx], tr.on_box[idx], sides=sides
    )
    pano_refraction = np.full((n, 2), np.nan, np.float32)
    pano_refraction[cand] = np.where(ok[:, None], pr, np.nan)
    pano_refraction_valid = np.zeros(n, bool)
    pano_refraction_valid[cand] = ok
    if reflection_parallax:
        rr = pano_coords(pano, refl.point, tr.reflected)
    else:
        rr = pano_coords(pano, np.full_like(tr.reflected, np.nan), tr.reflected)
    ok_r = np.isfinite(rr).all(axis=1)
    if reflection_parallax:
        idx = np.flatnonzero(ok_r)
        pts = refl.point[idx]
        ok_r[idx] = ray_ends_seen(
            scene.tracer, scene.at_inf, c, pts, tr.first_point[idx], refl.kind[idx], refl.on_box[idx], sides=sides
        )
    pano_reflection = np.full((n, 2), np.nan, np.float32)
    pano_reflection[cand] = np.where(ok_r[:, None], rr, np.nan)
    pano_reflection_valid = np.zeros(n, bool)
    pano_reflection_valid[cand] = ok_r
    return {
        "pano_refraction": pano_refraction,
        "pano_refraction_valid": pano_refraction_valid,
        "pano_reflection": pano_reflection,
        "pano_reflection_valid": pano_reflection_valid,
    }


def pano_coords(pano: PanoramaCamera, points: np.ndarray, directions: np.ndarray) -> np.ndarray:
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
def pano_to_persp_warp(
    pano: PanoramaCamera, camera: Camera, scene: RayScene, primary: PrimaryRays, verify_visibility: bool
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
    pix, pok = self_warp(camera, scene.tracer, ph.point, ph.kind, verify_visibility)
    pano_to_persp = np.where(pok[:, None], pix, np.nan).astype(np.float32)
    near = np.rint(np.where(pok[:, None], pix, 0)).astype(np.int64)
    near[:, 0] = near[:, 0].clip(0, W - 1)
    near[:, 1] = near[:, 1].clip(0, H - 1)
    pano_to_persp_object = pok & primary.mask[near[:, 1] * W + near[:, 0]]
    return {"pano_to_persp": pano_to_persp, "pano_to_persp_valid": pok, "pano_to_persp_object": pano_to_persp_object}


# ---------------------------------------------------------------------------------------------
# stage 7b: π⁻¹ over the whole frame
# ---------------------------------------------------------------------------------------------
def pano_refraction_frame_warp(
    pano: PanoramaCamera,
    camera: Camera,
    scene: RayScene,
    depth: np.ndarray,
    primary: PrimaryRays,
    pano_refraction: np.ndarray,
) -> dict[str, np.ndarray]:
    """π⁻¹ for every perspective pixel: the panorama pixel that sees what the pixel shows.

    Object pixels keep :func:`panorama_warps`' ``pano_refraction`` (the refracted ray's end). Every
    other pixel shows the background point ``p`` its straight camera ray sees: the depth mesh's
    vertex at the pixel centre (the unprojected depth), or, for far background
    (:mod:`~snell_bench.optics.far_field`), the point at infinity along the pixel's ray. Its
    panorama pixel is ``p`` seen from the panorama centre (:func:`pano_coords`), valid where the
    straight segment from the centre to ``p`` is free in the glass-free scene and the centre is
    on the front side of the surface at ``p`` (its :func:`vertex_normals`;
    :meth:`~snell_bench.optics.tracer.SceneTracer.unoccluded_from`; a point at infinity: the ray
    from the centre along its direction leaves the scene's geometry and resolves to far
    background). NaN where the pixel has no depth or the point is hidden from the centre.

    Args:
        pano: the panorama centred at the object.
        camera: the camera of I⁻.
        scene: the ray-casting scene (the object is not hit: the scene is glass-free).
        depth: ``(H, W)`` z-depth of I⁻.
        primary: the object pixels.
        pano_refraction: flat ``(H * W, 2)`` π⁻¹ of the object pixels (:func:`panorama_warps`).

    Returns:
        Flat ``(H * W, ...)`` arrays ``pano_refraction_frame`` (float32, NaN where invalid) and
        ``pano_refraction_frame_valid``.
    """
    n = camera.height * camera.width
    out = np.full((n, 2), np.nan, np.float32)
    out[primary.pixels] = pano_refraction[primary.pixels]
    has = valid_depth_mask(depth).reshape(-1) & ~primary.mask
    far = scene.at_inf.far & has if scene.at_inf is not None else np.zeros(n, bool)
    near = np.flatnonzero(has & ~far)
    if len(near):
        p = scene.background.vertices[near].astype(np.float64)
        normals = vertex_normals(scene.background.vertices, scene.background.faces)[near]
        seen = scene.tracer.unoccluded_from(pano.center, p, normals)
        out[near[seen]] = pano.project_points(p[seen]).astype(np.float32)
    idx = np.flatnonzero(far)
    if len(idx):
        d = camera.pixel_rays().reshape(-1, 3)[idx]
        h = scene.tracer.cast_background(np.broadcast_to(pano.center, d.shape), d)
        scene.at_inf.resolve(h.kind, h.point, d, h.on_box)
        inf = (h.kind == HitKind.OBSERVED) & (np.linalg.norm(np.nan_to_num(h.point), axis=1) > POINT_AT_INFINITY / 10)
        out[idx[inf]] = pano.project_directions(d[inf]).astype(np.float32)
    return {"pano_refraction_frame": out, "pano_refraction_frame_valid": np.isfinite(out).all(axis=1)}


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals of a triangle mesh (not normalised).

    Args:
        vertices: ``(V, 3)`` positions.
        faces: ``(F, 3)`` vertex indices; a face's normal is ``(v1 - v0) x (v2 - v0)`` (for the depth
            mesh: towards the camera).

    Returns:
        ``(V, 3)`` float64 sums of the normals of the faces at each vertex (twice their areas,
        computed in float32: meant for side tests), zero for a vertex of no face.
    """
    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.int64)
    out = np.zeros((len(v), 3))
    if len(f):
        fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]).astype(np.float64)
        for k in range(3):
            out[:, k] = sum(np.bincount(f[:, j], weights=fn[:, k], minlength=len(v)) for j in range(3))
    return out


def self_warp(
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
