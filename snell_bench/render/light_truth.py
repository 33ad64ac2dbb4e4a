"""The true relit image of a procedural scene with the glass in place: its own lights, path traced by
Mitsuba 3 (shadows and caustics included), the independent truth the relighters are scored against.

Convention:
    - A procedural scene's image is ``albedo (ambient + key cos θ V)`` (no interreflection,
      :mod:`snell_bench.scene.procedural.shading`). With the glass in place each receiver's
      irradiance changes by ``ΔE = E_with - E_without``; the truth is ``I⁻ + albedo ΔE`` in linear
      RGB at every pixel that sees a lit surface (elsewhere I⁻), the object's own pixels excepted
      (:attr:`LightTruth.receivers`).
    - ``ΔE`` is two light groups (light transport is linear in the emitters): the key light, light
      traced by Mitsuba's particle tracer ``ptracer`` (the light's paths through the glass to a
      diffuse receiver and to the camera, so caustics converge) with and without the glass; and the
      ambient, an environment of radiance ``sky / π`` above the horizon and ``ground / π`` below
      (the shading's ``sky (1 + n_y) / 2 + ground (1 - n_y) / 2``), path traced (``path``).
    - Receivers: the faces within ``reach`` bounding radii of the object whose material casts
      shadows (the shading's shadow rays test those), of a diffuse reflectance ``albedo`` (0.02: interreflection adds at most about 2 % of the direct
      light, which the shading does not have); a pixel's radiance is ``albedo E / π``, so
      ``ΔE = π (with - without) / albedo``. A point light's ``1 / d²`` is brought to the shading's
      ``1 / (d² + falloff)`` at each pixel's surface point. Only pixels whose surface lies within
      ``reach`` change; the key light's change only where the whole scene lets the light reach the
      surface (:meth:`~snell_bench.scene.procedural.ProceduralScene.key_direct` > 0), since the
      renders hold the object's surroundings alone.
    - The glass: Mitsuba's ``dielectric`` (``int_ior``) with the tracer's per-corner shading normals
      (a cylinder's caps stay flat), clear, of one material: ``ptracer`` ignores media, so a tinted
      object (or one of several media) is refused.
    - Both renders of a group use the same seeds and the same bounding box (:func:`_anchor`), so
      every light path that misses the glass is the same in both and cancels in ``ΔE``.
    - Variance: where the glass hides the key light from a pixel's surface point (a shadow ray at
      the pixel's centre, ``b``), the key's ``ΔE`` is ``E_with - E_exact`` (the shading's own
      irradiance without the glass, noise-free), elsewhere ``E_with - E_without``: one estimator,
      ``E_with - (1 - b) E_without - b E_exact``, unbiased since ``E_without`` estimates ``E_exact``.
    - Noise: each group is two renders of ``spp / 2`` samples (seeds ``2 seed``, ``2 seed + 1``);
      :attr:`LightTruth.self_noise_db` is the PSNR of the truth against its noise-free limit inside
      the region the object changes (as the reference's self-noise, +6.02 dB over the halves').
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear
from snell_bench.render.pieces import mesh, sensor

__all__ = ["LightTruth", "light_truth"]


@dataclass
class LightTruth:
    """The truth of a procedural scene relit with the glass in place (module convention).

    Attributes:
        image: ``(H, W, 3)`` float32 sRGB, I⁻ with the object's shadow and caustic (the object's own
            pixels: I⁻).
        delta_key: ``(H, W, 3)`` ``ΔE`` of the key light (linear RGB irradiance).
        delta_ambient: ``(H, W, 3)`` ``ΔE`` of the ambient.
        albedo: ``(H, W, 3)`` the albedo each pixel sees.
        receivers: ``(H, W)`` bool: a lit surface, not the object.
        self_noise_db: the truth's PSNR against its noise-free limit in the changed region (sRGB).
        info: the settings and sample counts.
    """

    image: np.ndarray
    delta_key: np.ndarray
    delta_ambient: np.ndarray
    albedo: np.ndarray
    receivers: np.ndarray
    self_noise_db: float | None
    info: dict = field(default_factory=dict)


def _receivers(mi, scene, albedo: float, centre: np.ndarray, reach: float) -> dict:
    vertices, faces, normals = scene.shadow_casters()
    faces = faces[(np.linalg.norm(vertices - centre, axis=1) <= reach)[faces].any(1)]
    used, faces = np.unique(faces, return_inverse=True)  # only the vertices used: the mesh's bounding box
    bsdf = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": [albedo] * 3}})
    return {"receivers": mesh(mi, "receivers", vertices[used], faces.reshape(-1, 3), normals=normals[used], bsdf=bsdf)}


def _glass(mi, obj) -> dict:
    if obj.media is not None or obj.absorbs:
        raise ValueError(
            f"the light truth renders clear objects of one material; {obj.name} "
            f"{'has several media' if obj.media is not None else 'absorbs'}: Mitsuba's particle tracer, which the "
            "key light's caustics need, ignores media"
        )
    bsdf = mi.load_dict({"type": "dielectric", "int_ior": float(obj.ior), "ext_ior": 1.0})
    # the tracer's shading normals, per face corner (sharp edges keep their faces' normals): one
    # vertex per corner, as the reference renders the object
    corners = np.asarray(obj.vertices, np.float64)[obj.faces].reshape(-1, 3)
    faces = np.arange(len(corners)).reshape(-1, 3)
    return {"glass": mesh(mi, "glass", corners, faces, normals=obj.corner_normals().reshape(-1, 3), bsdf=bsdf)}


def _key_emitter(light, up) -> dict:
    if light.kind == "directional":
        return {
            "type": "directional",
            "direction": (-np.asarray(light.vector, np.float64)).tolist(),
            "irradiance": {"type": "rgb", "value": np.asarray(light.color, np.float64).tolist()},
        }
    return {
        "type": "point",
        "position": np.asarray(light.vector, np.float64).tolist(),
        "intensity": {"type": "rgb", "value": np.asarray(light.color, np.float64).tolist()},
    }


def _ambient_emitter(mi, light, up) -> dict:
    """An ``envmap`` of ``sky / π`` above the horizon of ``up`` and ``ground / π`` below (Mitsuba's
    environment maps have +y up: ``to_world`` turns +y to ``up``)."""
    h = 64
    img = np.empty((h, 2 * h, 3), np.float32)
    img[: h // 2] = np.asarray(light.ambient_sky, np.float32) / math.pi
    img[h // 2 :] = np.asarray(light.ambient_ground, np.float32) / math.pi
    y = np.asarray(up, np.float64) / np.linalg.norm(up)
    a = np.array([1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = np.cross(y, a)
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    M = np.eye(4)
    M[:3, :3] = np.stack([x, y, z], 1)
    return {"type": "envmap", "bitmap": mi.Bitmap(img), "to_world": mi.ScalarTransform4f(M.tolist())}


def _anchor(mi, lo: np.ndarray, hi: np.ndarray) -> dict:
    """Two tiny black triangles at opposite corners of ``[lo, hi]``: the scenes with and without the
    glass get the same bounding box, so a directional light's rays (drawn over the scene's bounding
    disc) and every path that misses the glass are the same in both renders and cancel exactly."""
    tiny = 1e-6 * float(np.linalg.norm(hi - lo))
    v = np.array([lo, lo + [tiny, 0, 0], lo + [0, tiny, 0], hi, hi - [tiny, 0, 0], hi - [0, tiny, 0]])
    from snell_bench.render.pieces import black_bsdf

    return {"anchor": mesh(mi, "anchor", v, np.array([[0, 1, 2], [3, 5, 4]]), bsdf=black_bsdf(mi))}


def _render(mi, shapes: dict, emitter: dict, integrator: dict, camera, spp: int, seed: int, clip) -> np.ndarray:
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": integrator,
            "sensor": sensor(mi, camera, spp, *clip),
            "light": emitter,
            **shapes,
        }
    )
    return np.asarray(mi.render(scene, seed=int(seed), spp=int(spp)), np.float32)[..., :3]


def light_truth(
    scene,
    camera,
    i_minus: np.ndarray,
    obj,
    *,
    spp: int = 256,
    seed: int = 0,
    albedo: float = 0.02,
    max_depth: int = 12,
    reach: float = 8.0,
) -> LightTruth:
    """The procedural ``scene`` relit with the placed ``obj`` (module convention).

    Args:
        scene: the :class:`~snell_bench.scene.procedural.ProceduralScene`.
        camera: its camera (I⁻'s).
        i_minus: ``(H, W, 3)`` sRGB I⁻ of that camera.
        obj: the placed glass object (one material).
        spp: samples per pixel of each group (two halves).
        seed: the renders' seed.
        albedo: the receivers' diffuse reflectance in the renders.
        max_depth: longest light path.
        reach: the receivers rendered, in bounding radii of the object.
    """
    from scipy.ndimage import binary_dilation

    from snell_bench.render.variants import set_variant

    mi = set_variant()
    light = scene.light
    centre = np.asarray(obj.center, np.float64)
    radius = float(np.linalg.norm(obj.vertices - centre, axis=1).max())
    points = camera.unproject(scene.depth(camera))
    halves = _deltas(
        mi, scene, camera, obj, points, spp=spp, seed=seed, albedo=albedo, max_depth=max_depth, reach=reach * radius
    )
    deltas = {name: 0.5 * (h[0] + h[1]) for name, h in halves.items()}
    alb, lit = scene.albedo(camera)
    # the silhouette's rim too: a pixel there sees the glass over part of its footprint
    on_object = binary_dilation(np.isfinite(_object_depth(obj, camera)), iterations=1)
    receivers = lit & ~on_object & (np.linalg.norm(points - centre, axis=-1) <= reach * radius)
    lin = srgb_to_linear(np.asarray(i_minus, np.float32)).astype(np.float64)

    def compose(dk, da):
        out = lin + np.where(receivers[..., None], alb * (dk + da), 0.0)
        return linear_to_srgb(np.clip(out, 0.0, None).astype(np.float32)).clip(0.0, 1.0)

    image = compose(deltas["key"], deltas["ambient"])
    a, b = compose(halves["key"][0], halves["ambient"][0]), compose(halves["key"][1], halves["ambient"][1])
    region = receivers & (np.abs(image - np.asarray(i_minus, np.float32)).max(-1) > 2 / 255)
    noise = None
    if region.any():
        mse = float(((a - b)[region] ** 2).mean())
        noise = math.inf if mse == 0 else 10 * math.log10(1.0 / mse) + 10 * math.log10(4.0)
    info = {
        "spp": 2 * max(1, spp // 2),
        "seed": int(seed),
        "albedo": albedo,
        "max_depth": max_depth,
        "key": light.kind,
        "reach": reach,
    }
    return LightTruth(image, deltas["key"], deltas["ambient"], alb, receivers, noise, info)


def _deltas(mi, scene, camera, obj, points, *, spp, seed, albedo, max_depth, reach) -> dict:
    """``{"key": [ΔE of half 1, of half 2], "ambient": [...]}`` (module convention), each ``(H, W, 3)``."""
    light, up = scene.light, np.asarray(scene.up, np.float64)
    dist = np.linalg.norm(scene.mesh().vertices, axis=1)
    clip = (max(1e-3, 1e-3 * float(np.median(dist))), 10.0 * float(dist.max()))
    base = _receivers(mi, scene, albedo, np.asarray(obj.center, np.float64), reach)
    glass = _glass(mi, obj)
    box = base["receivers"].bbox()
    margin = 1e-3 * reach
    lo = np.minimum(np.array(box.min), obj.vertices.min(0)) - margin
    hi = np.maximum(np.array(box.max), obj.vertices.max(0)) + margin
    base = {**base, **_anchor(mi, lo, hi)}
    half = max(1, spp // 2)
    paths = {"max_depth": max_depth, "rr_depth": max_depth + 1, "hide_emitters": True}
    groups = {
        "key": (_key_emitter(light, up), {"type": "ptracer", **paths}),
        "ambient": (_ambient_emitter(mi, light, up), {"type": "path", **paths}),
    }
    scale = np.ones(camera.shape + (1,))
    if light.kind != "directional":  # the shading's 1 / (d² + falloff) instead of Mitsuba's 1 / d²
        d2 = np.sum((points - np.asarray(light.vector)) ** 2, -1)
        scale = np.where(np.isfinite(d2), d2 / (d2 + light.falloff), 1.0)[..., None]
    direct = scene.key_direct(camera)[..., None]
    exact = direct * np.asarray(light.color, np.float64)  # the key's irradiance without the glass
    blocked = _blocked(obj, points, light)[..., None]
    halves = {}
    for name, (emitter, integrator) in groups.items():
        runs = []
        for k in (0, 1):
            w = math.pi / albedo * _render(mi, {**base, **glass}, emitter, integrator, camera, half, 2 * seed + k, clip)
            wo = math.pi / albedo * _render(mi, base, emitter, integrator, camera, half, 2 * seed + k, clip)
            if name == "key":  # a control variate: where the glass hides the light, the exact irradiance
                w, wo = w * scale, wo * scale
                runs.append(np.where(direct > 0, w - (1 - blocked) * wo - blocked * exact, 0.0))
            else:
                runs.append(w - wo)
        halves[name] = runs
    return halves


def _blocked(obj, points: np.ndarray, light) -> np.ndarray:
    """``(H, W)`` 1 where the glass lies between a pixel's surface point and the key light."""
    import open3d as o3d

    from snell_bench.relight.shadow import Occluder

    occ = Occluder.from_mesh(obj.vertices, obj.faces)
    p = points.reshape(-1, 3)
    ok = np.isfinite(p).all(1)
    out = np.zeros(len(p))
    if light.kind == "directional":
        v = np.broadcast_to(np.asarray(light.vector, np.float64), p.shape) * 1e6
    else:
        v = np.asarray(light.vector, np.float64) - p
    rays = np.concatenate([p[ok], v[ok]], 1).astype(np.float32)
    out[ok] = occ.scene.test_occlusions(o3d.core.Tensor.from_numpy(rays), tnear=1e-9, tfar=1.0).numpy()
    return out.reshape(points.shape[:-1])


def _object_depth(obj, camera) -> np.ndarray:
    from snell_bench.relight.shadow import Occluder

    occ = Occluder.from_mesh(obj.vertices, obj.faces)
    import open3d as o3d

    d = camera.pixel_rays().reshape(-1, 3)
    rays = np.concatenate([np.zeros_like(d), d], 1).astype(np.float32)
    t = occ.scene.cast_rays(o3d.core.Tensor.from_numpy(rays))["t_hit"].numpy()
    return np.where(np.isfinite(t), t, np.nan).reshape(camera.shape)
