"""The scene of a reference render and its two Mitsuba passes: the stages of
:func:`~snell_bench.render.reference.render_reference` between the inputs and the pasted frame.

Convention:
    - Scene, passes, window and samples: see :mod:`snell_bench.render.reference`; frames and
      pixels: :mod:`snell_bench.render.pieces`; the background's pieces:
      :mod:`snell_bench.render.geometry`.
    - :func:`build_scene` uses no Mitsuba; each pass loads its own shapes and returns linear RGB of
      the window only (``(y1 - y0, x1 - x0, 3)`` float32).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snell_bench.imaging.color import srgb_to_linear
from snell_bench.optics.media import interface_faces
from snell_bench.render.geometry import (
    background_geometry,
    flaps,
    inward_box,
    object_arrays,
    object_rect,
    subdivide,
)
from snell_bench.render.integrator import render_linear
from snell_bench.render.pieces import absorbing_medium, black_bsdf, mesh, rgb_emitter, texture_emitter
from snell_bench.render.plugins import REFRACTION_ONLY_BSDF, REFRACTION_PATH_BSDF
from snell_bench.render.reference_settings import ReferenceSettings
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import build_background, valid_depth_mask
from snell_bench.scene.objects import GlassObject

__all__ = ["ReferenceScene", "build_scene", "render_image_pass", "render_unobserved_pass"]

#: The back sides of the background sit this far (relative to their distance) behind the front.
_BACK_OFFSET = 1e-4
_RED, _GREEN = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)


@dataclass(frozen=True)
class ReferenceScene:
    """The meshes and images of a reference render, in the camera frame (meshes as ``(vertices,
    faces[, uv or normals])`` arrays).

    Attributes:
        textured: ``(v, f, uv)``: the observed surface and its flaps, each triangle split so that
            every piece shows one texel (pass a).
        observed: ``(v, f)``: the same, unsplit (pass b).
        back: ``(v, f)``: its back side, ``_BACK_OFFSET`` behind it, facing away (unobserved).
        box: ``(v, f)``: the bounding box, faces pointing inwards (unobserved).
        obj: ``(v, f, normals)``: the object.
        texture: ``(H, W, 3)`` float32 I⁻ decoded to linear RGB, the background's emission.
        valid: ``(H, W)`` bool, the pixels with a valid depth.
        zmin: the nearest z of the background and of the object's vertices in front of the camera.
        clip: ``(near, far)`` clip planes, well inside the nearest geometry and beyond the farthest.
        rect: the object's rectangle (:func:`~snell_bench.render.geometry.object_rect`).
    """

    textured: tuple
    observed: tuple
    back: tuple
    box: tuple
    obj: tuple
    texture: np.ndarray
    valid: np.ndarray
    zmin: float
    clip: tuple
    rect: tuple


def build_scene(img: np.ndarray, depth: np.ndarray, camera: Camera, obj: GlassObject, edge_threshold: float):
    """Stage 1: the :class:`ReferenceScene` of I⁻ (``img``, sRGB float32), its z-depth and the placed
    object; the depth mesh cut at relative jumps over ``edge_threshold``."""
    lo, hi = obj.mesh.bounds
    bg = build_background(depth, camera, edge_threshold, extra_points=np.stack([lo, hi]))
    geo = background_geometry(bg, depth, camera, edge_threshold)
    fv, ff, fuv = flaps(geo, camera)
    # the observed surface, each triangle split so that every piece shows one texel (pass a) ...
    sv, sf, suv = subdivide(geo, camera.shape, geo.observed)
    textured = (np.concatenate([sv, fv]), np.concatenate([sf, ff + len(sv)]), np.concatenate([suv, fuv]))
    # ... and unsplit (pass b); its back side is unobserved
    obs_v, obs_f = np.concatenate([geo.vertices, fv]), np.concatenate([geo.observed, ff + len(geo.vertices)])
    back = (obs_v * np.float32(1.0 + _BACK_OFFSET), obs_f[:, [0, 2, 1]])
    box = (bg.box_vertices, inward_box(bg.box_vertices, bg.box_faces))
    ov, of, on = object_arrays(obj)
    valid = valid_depth_mask(depth)
    front = ov[:, 2][ov[:, 2] > 0]
    zmin = min([float(np.min(depth[valid]))] + ([float(front.min())] if len(front) else []))
    clip = (1e-3 * zmin, 10.0 * float(np.linalg.norm(np.abs(bg.box_vertices).max(axis=0))))
    return ReferenceScene(
        textured=textured,
        observed=(obs_v, obs_f),
        back=back,
        box=box,
        obj=(ov, of, on),
        texture=np.ascontiguousarray(srgb_to_linear(np.clip(img, 0.0, 1.0)), dtype=np.float32),
        valid=valid,
        zmin=zmin,
        clip=clip,
        rect=object_rect(camera, obj),
    )


def _glass(mi, scene: ReferenceScene, obj: GlassObject, kind: str, **props) -> dict:
    """The object's shapes with the BSDF ``kind``: its mesh (``int_ior = obj.ior``, ``ext_ior = 1``),
    filled with the absorbing medium of its material where it absorbs
    (:func:`~snell_bench.render.pieces.absorbing_medium`); for an object of several media one mesh per
    pair of media that meet (:func:`~snell_bench.optics.media.interface_faces`: faces between equal
    media are left out), each with the IORs and media of its two sides."""
    ov, of, on = scene.obj
    if obj.media is None:
        bsdf = mi.load_dict({"type": kind, "int_ior": float(obj.ior), "ext_ior": 1.0, **props})
        interior = absorbing_medium(mi, obj.absorption) if obj.absorbs else None
        return {"object": mesh(mi, "object", ov, of, normals=on, bsdf=bsdf, interior=interior)}
    media = [absorbing_medium(mi, m.absorption) if any(m.absorption) else None for m in obj.media] + [None]
    ior = [m.ior for m in obj.media] + [1.0]
    behind, front = interface_faces(obj)
    pairs = sorted({(int(b), int(f)) for b, f in zip(behind, front) if b != f}, key=lambda p: (p[1] != -1, p))
    shapes = {}
    for k, (inside, outside) in enumerate(pairs):
        picked = np.flatnonzero((behind == inside) & (front == outside))
        rows = (3 * picked[:, None] + np.arange(3)).ravel()
        bsdf = mi.load_dict({"type": kind, "int_ior": float(ior[inside]), "ext_ior": float(ior[outside]), **props})
        name = "object" if k == 0 else f"object_{k}"
        faces = np.arange(len(rows)).reshape(-1, 3)
        shapes[name] = mesh(
            mi, name, ov[rows], faces, normals=on[rows], bsdf=bsdf, interior=media[inside], exterior=media[outside]
        )
    return shapes


def _emitting(mi, name: str, vf: tuple, rgb: tuple):
    """A black mesh ``vf = (vertices, faces)`` emitting the linear RGB ``rgb``."""
    return mesh(mi, name, *vf, bsdf=black_bsdf(mi), emitter=rgb_emitter(mi, rgb))


def render_image_pass(
    mi, scene: ReferenceScene, camera: Camera, obj: GlassObject, settings: ReferenceSettings, counts, window
) -> list[np.ndarray]:
    """Stage 2, pass (a): observed surfaces emit I⁻, the rest is black; the object is the
    dielectric that ``settings.fresnel`` and ``settings.reflection`` choose. One linear render of
    ``window`` per count of ``counts`` (``(n,)``: seed ``seed``; halves ``(n1, n2)``: seeds
    ``2 seed`` and ``2 seed + 1``)."""
    s = settings
    if not s.fresnel:
        kind, props = REFRACTION_PATH_BSDF, {}
    elif s.reflection:
        kind, props = "dielectric", {}
    else:  # camera rays start on the near clip plane, every other ray on a surface beyond zmin
        kind, props = REFRACTION_ONLY_BSDF, {"camera_z": 0.5 * scene.zmin}
    glass = _glass(mi, scene, obj, kind, **props)
    tv, tf, tuv = scene.textured
    emitter = texture_emitter(mi, mi.Bitmap(scene.texture))
    shapes = {
        "background": mesh(mi, "background", tv, tf, uv=tuv, bsdf=black_bsdf(mi), emitter=emitter),
        **glass,
    }
    python_rect = None if s.fresnel and s.reflection else scene.rect
    seeds = [int(s.seed)] if len(counts) == 1 else [2 * int(s.seed), 2 * int(s.seed) + 1]
    return render_linear(
        mi,
        shapes,
        camera,
        list(counts),
        seeds,
        s.max_depth,
        scene.clip,
        python_rect,
        window=window,
        sampler=s.sampler,
        media=obj.absorbs,
    )


def render_unobserved_pass(
    mi, scene: ReferenceScene, camera: Camera, obj: GlassObject, settings: ReferenceSettings, spp: int, window
) -> np.ndarray:
    """Stage 3, pass (b): observed surfaces emit green ``(0, 1, 0)``, unobserved ones (back sides,
    box) red ``(1, 0, 0)``; the object follows the refraction path. ``spp`` samples per pixel, seed
    ``settings.seed``; returns the window's linear RGB (R: unobserved, G: observed)."""
    shapes = {
        "background": _emitting(mi, "background", scene.observed, _GREEN),
        "back": _emitting(mi, "back", scene.back, _RED),
        "box": _emitting(mi, "box", scene.box, _RED),
        **_glass(mi, scene, obj, REFRACTION_PATH_BSDF),
    }
    s = settings
    return render_linear(
        mi, shapes, camera, spp, s.seed, s.max_depth, scene.clip, scene.rect, window=window, sampler=s.sampler
    )
