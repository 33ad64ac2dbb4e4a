"""Light transport near the glass object: the irradiance of I⁻'s surfaces from each light, with the
object and without it (the differential rendering of :mod:`snell_bench.relight.traced`).

Convention:
    - Frame and units: see :mod:`snell_bench.relight.lights` (camera frame, linear RGB irradiance).
    - Receiver: the surfaces I⁻ shows, one patch per pixel (:func:`receiver_from_depth`): the
      depth map back-projected at pixel centres, its normal from the neighbours (facing the camera),
      the area the pixel sees ``|∂P/∂u × ∂P/∂v|``; pixels at a depth edge (a jump of more than
      ``max_jump`` of the depth between neighbours) or without depth receive nothing.
    - Key light (:func:`key_terms`): ``E cos θ V (1 - b)`` with the object and ``E cos θ V``
      without it, ``b`` the fraction of the light the object hides over the pixel's footprint
      (``samples`` shadow rays, each from a point of a stratified grid over the footprint towards a
      point of the light's cone, through the object's mesh,
      :func:`~snell_bench.relight.shadow.occluded_fraction`), ``V`` whether the depth
      mesh hides the light (one ray along its axis; computed only where the object changes
      something).
    - Caustic (:func:`caustic_irradiance`): the light the object hides is traced through it: a beam
      of rays from the light (origins stratified over the disc that covers the object's bounding
      sphere seen from the light, directions over its cone) through the glass
      (:meth:`~snell_bench.optics.tracer.SceneTracer.trace`: Snell, total internal reflection,
      absorption), each carrying ``E · disc area / rays`` times ``(1 - R) T_interfaces exp(-σ L)``
      (its first-surface reflection, weight ``R``, is traced too); where it ends on a surface the
      camera sees, its flux is added to the pixel whose footprint holds it, blurred by ``blur_px``
      and divided by the pixel's area.
    - Environment (:func:`environment_terms`): without the object, the irradiance of every receiver
      from the environment's 9 spherical-harmonic coefficients (Ramamoorthi and Hanrahan 2001); the
      object's change, near it, by ``samples`` cosine-distributed rays per point: a ray that meets the
      object sees the environment along the direction it leaves in (times its transmission) and the
      first-surface reflection, instead of the environment behind the object.
    - Randomness: ``numpy.random.default_rng(seed)`` only; the same seed gives the same irradiance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

from snell_bench.optics.functional import adjoint_correction
from snell_bench.optics.trace_types import HitKind
from snell_bench.relight.shadow import Occluder, cone_directions, occluded_fraction, orthonormal_basis

__all__ = [
    "Receiver",
    "caustic_irradiance",
    "environment_terms",
    "internal_reflections",
    "key_terms",
    "receiver_from_depth",
    "sh9_irradiance",
]

_GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
#: an internally reflected branch carrying less than this share of its ray's light is not followed
_BRANCH_CUTOFF = 1e-4


@dataclass
class Receiver:
    """I⁻'s surfaces, one patch per pixel (module convention).

    Attributes:
        points: ``(H, W, 3)`` camera-frame points (NaN where not a receiver).
        normals: ``(H, W, 3)`` unit normals facing the camera.
        area: ``(H, W)`` the surface area each pixel sees.
        valid: ``(H, W)`` bool: a receiver.
        eps: offset of rays leaving a receiver (scaled to the scene).
        du, dv: ``(H, W, 3)`` the surface's step for one pixel along x and y (the pixel's footprint).
    """

    points: np.ndarray
    normals: np.ndarray
    area: np.ndarray
    valid: np.ndarray
    eps: float
    du: np.ndarray | None = None
    dv: np.ndarray | None = None


def receiver_from_depth(depth: np.ndarray, camera, max_jump: float = 0.05) -> Receiver:
    """The :class:`Receiver` of a z-depth map ``(H, W)`` (NaN, inf or <= 0 where unknown)."""
    z = np.asarray(depth, np.float64)
    with np.errstate(invalid="ignore"):
        known = np.isfinite(z) & (z > 0)
    P = camera.unproject(np.where(known, z, np.nan))
    du, dv = np.gradient(P, axis=1), np.gradient(P, axis=0)
    n = np.cross(du, dv)
    area = np.linalg.norm(n, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = n / area[..., None]
        n = np.where((np.einsum("hwc,hwc->hw", n, P) > 0)[..., None], -n, n)
        jump = np.maximum(np.abs(np.gradient(z, axis=0)), np.abs(np.gradient(z, axis=1))) > max_jump * z
        valid = known & ~jump & np.isfinite(n).all(-1) & (area > 0)
    scale = float(np.nanmedian(z[known])) if known.any() else 1.0
    keep = valid[..., None]
    return Receiver(
        np.where(keep, P, np.nan),
        np.where(keep, n, 0.0),
        area,
        valid,
        1e-4 * scale,
        np.where(keep, du, 0.0),
        np.where(keep, dv, 0.0),
    )


def key_terms(receiver: Receiver, key, occluder: Occluder, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """``(geometry, blocked)``, each ``(H, W)``: ``max(0, n · l)`` times a point light's falloff at
    every receiver, and the fraction of the key light the object hides (0 outside the receivers)."""
    geometry = np.zeros(receiver.valid.shape)
    blocked = np.zeros(receiver.valid.shape, np.float32)
    if not receiver.valid.any():
        return geometry, blocked
    dirs, _, scale = key.toward(receiver.points[receiver.valid])
    geometry[receiver.valid] = np.clip(np.einsum("nc,nc->n", receiver.normals[receiver.valid], dirs), 0.0, None) * scale
    lit = receiver.valid & (geometry > 0)
    points = receiver.points[lit] + receiver.eps * receiver.normals[lit]
    du, dv = receiver.du[lit], receiver.dv[lit]
    cone = cone_directions(key.direction, key.angular_radius_deg, samples) if key.position is None else None
    side = int(math.ceil(math.sqrt(samples)))
    offsets = [((i + 0.5) / side - 0.5, (j + 0.5) / side - 0.5) for j in range(side) for i in range(side)][:samples]
    acc = np.zeros(len(points), np.float32)
    for s, (a, b) in enumerate(offsets):  # sample s: a point of the pixel's footprint, a point of the light
        p = points + a * du + b * dv
        if cone is None:
            acc += _occluded_toward(occluder, p, key.position)
        else:
            acc += occluded_fraction(occluder, p, cone[s % len(cone)][None])
    blocked[lit] = acc / len(offsets)
    return geometry, blocked


def _occluded_toward(occluder: Occluder, points: np.ndarray, position: np.ndarray) -> np.ndarray:
    """``(N,)`` 1 where the segment from a point to ``position`` meets the occluder (culled by its
    bounding sphere), else 0."""
    import open3d as o3d

    v = position - points
    length = np.linalg.norm(v, axis=1)
    s = np.clip(np.einsum("nc,nc->n", occluder.center - points, v) / length**2, 0.0, 1.0)
    near = np.linalg.norm(points + s[:, None] * v - occluder.center, axis=1) <= occluder.radius
    out = np.zeros(len(points), np.float32)
    if near.any():
        rays = np.concatenate([points[near], v[near]], 1).astype(np.float32)
        hit = occluder.scene.test_occlusions(o3d.core.Tensor.from_numpy(rays), tnear=1e-6, tfar=1.0).numpy()
        out[near] = hit.astype(np.float32)
    return out


def scene_visibility(receiver: Receiver, tracer, key, where: np.ndarray) -> np.ndarray:
    """``(H, W)`` float: 1 where no surface of the depth mesh hides the key light from the receiver
    (a ray towards it reaches the light, the box of unobserved space or nothing), 0 where one does;
    1 outside ``where``."""
    vis = np.ones(where.shape, np.float64)
    sel = where & receiver.valid
    if sel.any():
        o = receiver.points[sel] + receiver.eps * receiver.normals[sel]
        dirs, dist, _ = key.toward(o)
        hit = tracer.cast_background(o, dirs)
        vis[sel] = np.where(np.isfinite(hit.t) & ~hit.on_box & (hit.t < dist), 0.0, 1.0)
    return vis


def _splat(camera, depth: np.ndarray, points: np.ndarray, flux: np.ndarray) -> np.ndarray:
    """The flux ``(N, 3)`` landing at camera-frame ``points``, summed per pixel footprint (the pixel
    whose square ``[x - 0.5, x + 0.5)`` holds the point's projection, as a box-filtered render counts
    it), ``(H, W, 3)``; points the camera does not see (a depth differing by more than 2 % from the
    map's at that pixel) are dropped."""
    H, W = camera.shape
    out = np.zeros((H, W, 3), np.float64)
    pix, z = camera.project(points)
    ok = (
        np.isfinite(pix).all(-1)
        & (pix[:, 0] >= -0.5)
        & (pix[:, 0] < W - 0.5)
        & (pix[:, 1] >= -0.5)
        & (pix[:, 1] < H - 0.5)
    )
    iu = np.clip(np.floor(pix[ok, 0] + 0.5).astype(int), 0, W - 1)
    iv = np.clip(np.floor(pix[ok, 1] + 0.5).astype(int), 0, H - 1)
    seen = np.abs(np.asarray(depth, np.float64)[iv, iu] - z[ok]) <= 0.02 * z[ok]
    for c in range(3):
        np.add.at(out[..., c], (iv[seen], iu[seen]), flux[ok][seen, c])
    return out


def _weights(tr) -> np.ndarray:
    """``(N, 3)`` the share of a ray's light that follows its refracted path out of the object."""
    od = tr.optical_depth if tr.optical_depth is not None else np.zeros((len(tr.kind), 3))
    return ((1.0 - tr.fresnel) * tr.interface_transmission * tr.adjoint)[:, None] * np.exp(-od)


def caustic_irradiance(
    receiver: Receiver,
    camera,
    depth,
    tracer,
    occluder: Occluder,
    key,
    rays: int,
    seed: int,
    blur_px: float = 0.0,
    generations: int = 4,
) -> tuple[np.ndarray, dict]:
    """``(H, W, 3)`` irradiance of the light of ``key`` that passes through (or reflects off) the
    object and lands on a receiver (module convention), and a record of the beam's energy;
    ``generations`` internal reflections at the exits are followed (0: the refracted path alone)."""
    rng = np.random.default_rng(int(seed))
    if key.position is not None:
        origins, dirs, flux = _point_beam(key, occluder, rays, rng)
    else:
        origins, dirs, flux = _distant_beam(key, occluder, rays, rng)
    t_obj = tracer.cast_object(origins, dirs)["t"]
    hits = np.isfinite(t_obj) & (t_obj < tracer.cast_background(origins, dirs).t)
    tr = tracer.trace(origins[hits], dirs[hits], from_light=True)
    landed = tr.kind == HitKind.OBSERVED
    refl = tracer.trace_reflection(tr)
    bounced = refl.kind == HitKind.OBSERVED
    through = _splat(camera, depth, tr.point[landed], _weights(tr)[landed] * flux * _falloff(key, tr.point[landed]))
    mirror_w = tr.fresnel * adjoint_correction(dirs[hits], tr.reflected, tr.first_normal, tr.first_geometric_normal)
    mirrored = _splat(
        camera, depth, refl.point[bounced], mirror_w[bounced, None] * flux * _falloff(key, refl.point[bounced])
    )
    inner = _internal_splat(camera, depth, tracer, tr, key, flux, generations)
    img = through + mirrored + inner
    if blur_px > 0:
        img = np.stack([gaussian_filter(img[..., c], blur_px, mode="constant") for c in range(3)], -1)
    E = np.where(receiver.valid[..., None], img / np.where(receiver.area > 0, receiver.area, np.inf)[..., None], 0.0)
    record = {
        "rays": int(len(origins)),
        "rays_on_object": int(hits.sum()),
        "flux_into_object": (flux * hits.sum()).round(9).tolist(),
        "flux_refracted_on_receivers": through.sum((0, 1)).round(9).tolist(),
        "flux_reflected_on_receivers": mirrored.sum((0, 1)).round(9).tolist(),
        "flux_internally_reflected_on_receivers": inner.sum((0, 1)).round(9).tolist(),
    }
    return E, record


def internal_reflections(tracer, trace, generations: int):
    """The light each exit reflects back into the object (Fresnel ``R``), followed through it again,
    generation by generation (each starts where the last one's paths leave): yields
    ``(trace, weight, length, index)`` per generation: its :class:`~snell_bench.optics.trace_types.RefractionTrace`
    (``start_inside``), the ``(M,)`` share of the original rays' light that leaves along it (Fresnel
    and adjoint factors, no absorption), the ``(M,)`` path length inside the object before it started
    and the ``(M,)`` rows of ``trace`` each belongs to.

    For a clear sphere the first generation carries about 4 % of the light through it, spread wide
    of the caustic; near-grazing exits (a cylinder's wall) reflect far more. Branches carrying
    less than ``1e-4`` of their ray's light are dropped; a trace without an
    :class:`~snell_bench.optics.trace_types.ExitRecord` (not traced ``from_light``; several media) yields nothing.
    """
    if trace.exit is None:
        return
    carried = 1.0 - trace.fresnel  # what the light carries before the trace's interface products
    before = np.zeros(len(carried))  # path length inside before the trace
    index = np.arange(len(carried))
    for _ in range(generations):
        ex = trace.exit
        sel = np.isfinite(ex.point).all(1) & (ex.fresnel > 0) & (ex.fresnel < 1)
        nf, ng, mirror = ex.shading_normal[sel], ex.geometric_normal[sel], ex.mirror[sel]
        arrived = mirror - 2.0 * np.einsum("nc,nc->n", mirror, nf)[:, None] * nf  # the direction it met the exit along
        w = carried[sel] * ex.transmission[sel] * ex.adjoint[sel] * ex.fresnel[sel]
        w = w * adjoint_correction(arrived, mirror, nf, ng)
        keep = w > _BRANCH_CUTOFF
        if not keep.any():
            return
        side = np.where(np.einsum("nc,nc->n", mirror, ng) >= 0, 1.0, -1.0)
        start = (ex.point[sel] + (tracer.eps * side)[:, None] * ng)[keep]
        carried, before = w[keep], (before[sel] + ex.path_length[sel])[keep]
        index = index[sel][keep]
        trace = tracer.trace(start, mirror[keep], start_inside=True, from_light=True)
        yield trace, carried * trace.interface_transmission * trace.adjoint, before, index


def _internal_splat(camera, depth, tracer, trace, key, flux: np.ndarray, generations: int) -> np.ndarray:
    """``(H, W, 3)``: the light of :func:`internal_reflections` that lands on a receiver."""
    img = np.zeros(camera.shape + (3,))
    sigma = np.asarray(tracer.obj.absorption, np.float64)
    for tr, weight, before, _ in internal_reflections(tracer, trace, generations):
        landed = (tr.kind == HitKind.OBSERVED) & np.isfinite(tr.first_point).all(1)  # it met the object again
        w = weight[:, None] * np.exp(-(before + tr.path_length)[:, None] * sigma)
        img += _splat(camera, depth, tr.point[landed], w[landed] * flux * _falloff(key, tr.point[landed]))
    return img


def _falloff(key, points: np.ndarray) -> np.ndarray:
    """``(N, 1)``: a point light's ``d² / (d² + falloff)`` at the points where its rays land (``d``
    their distance from the light), the shading's falloff law applied where the light arrives; 1
    for a distant light."""
    if key.position is None or key.falloff == 0.0:
        return np.ones((len(points), 1))
    d2 = np.sum((np.asarray(points, np.float64) - key.position) ** 2, axis=1)
    return (d2 / (d2 + key.falloff))[:, None]


def _point_beam(key, occluder: Occluder, rays: int, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays from a point light over the cone of the object's bounding sphere (a jittered Fibonacci
    spiral of equal solid angle), starting just before the sphere; the flux each carries."""
    axis = occluder.center - key.position
    dist = float(np.linalg.norm(axis))
    axis = axis / dist
    if dist <= occluder.radius:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(3)
    cos_a = math.sqrt(1.0 - (occluder.radius / dist) ** 2)
    i = np.arange(rays) + rng.random(rays)
    cos_t = 1.0 - (1.0 - cos_a) * i / rays
    sin_t = np.sqrt(np.clip(1.0 - cos_t**2, 0.0, None))
    phi = np.arange(rays) * _GOLDEN_ANGLE + 2.0 * math.pi * rng.random()
    u, v = orthonormal_basis(axis)
    dirs = cos_t[:, None] * axis + sin_t[:, None] * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
    start = max(0.0, dist - 1.01 * occluder.radius)
    solid = 2.0 * math.pi * (1.0 - cos_a) / rays
    flux = np.asarray(key.irradiance, np.float64) * solid
    return key.position + start * dirs, dirs, flux


def _distant_beam(key, occluder: Occluder, rays: int, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Parallel rays (each from a point of the light's disc) over the disc that covers the object's
    bounding sphere seen from the light; the flux each carries."""
    axis = key.direction
    u, v = orthonormal_basis(axis)
    r = occluder.radius
    m = max(1, int(math.sqrt(rays * 4.0 / math.pi)))  # a jittered m x m grid over the disc's square
    cell = 2.0 * r / m
    gx, gy = np.meshgrid(np.arange(m), np.arange(m))
    x = -r + (gx.ravel() + rng.random(m * m)) * cell
    y = -r + (gy.ravel() + rng.random(m * m)) * cell
    disc = x * x + y * y <= r * r
    x, y = x[disc], y[disc]
    start = occluder.center + 1.01 * r * axis
    origins = start + x[:, None] * u + y[:, None] * v
    if key.angular_radius_deg > 0:  # each ray from a point of the light's disc, uniform over its cap
        cos_t = 1.0 - rng.random(len(x)) * (1.0 - math.cos(math.radians(key.angular_radius_deg)))
        phi = 2.0 * math.pi * rng.random(len(x))
        sin_t = np.sqrt(np.clip(1.0 - cos_t**2, 0.0, None))
        toward = cos_t[:, None] * axis + sin_t[:, None] * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
    else:
        toward = np.broadcast_to(axis, origins.shape)
    return origins, -np.ascontiguousarray(toward), np.asarray(key.irradiance, np.float64) * cell * cell


def sh9_irradiance(environment, normals: np.ndarray, directions: int = 4096) -> np.ndarray:
    """``(..., 3)`` irradiance of surfaces of unit ``normals`` ``(..., 3)`` under ``environment``,
    from its 9 spherical-harmonic coefficients (exact for radiance of degree <= 2, and for a sky
    and ground of two colours), the coefficients summed over ``directions`` Fibonacci directions.

    Examples:
        >>> from snell_bench.relight.lights import hemisphere_environment
        >>> env = hemisphere_environment([1.0, 0.5, 0.2], [0.1, 0.1, 0.1], [0.0, -1.0, 0.0])
        >>> sh9_irradiance(env, np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])).round(3).tolist()
        [[1.0, 0.5, 0.2], [0.55, 0.3, 0.15]]
    """
    i = np.arange(directions) + 0.5
    zc = 1.0 - 2.0 * i / directions
    rho = np.sqrt(1.0 - zc * zc)
    phi = i * _GOLDEN_ANGLE
    w = np.stack([rho * np.cos(phi), rho * np.sin(phi), zc], -1)
    L = np.asarray(environment(w), np.float64)
    coef = (4.0 * math.pi / directions) * _sh9(w).T @ L  # (9, 3)
    band = np.array([math.pi] + [2.0 * math.pi / 3.0] * 3 + [math.pi / 4.0] * 5)
    n = np.asarray(normals, np.float64)
    return ((_sh9(n.reshape(-1, 3)) * band) @ coef).reshape(n.shape[:-1] + (3,))


def _sh9(d: np.ndarray) -> np.ndarray:
    """The 9 real spherical harmonics of degree <= 2 at unit directions ``(N, 3)``: ``(N, 9)``."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return np.stack(
        [
            np.full_like(x, 0.282095),
            0.488603 * y,
            0.488603 * z,
            0.488603 * x,
            1.092548 * x * y,
            1.092548 * y * z,
            0.315392 * (3.0 * z * z - 1.0),
            1.092548 * x * z,
            0.546274 * (x * x - y * y),
        ],
        -1,
    )


def _cosine_directions(normals: np.ndarray, samples: int, rng) -> np.ndarray:
    """``(N, S, 3)`` cosine-distributed directions about each normal: a Fibonacci spiral of equal
    projected area, turned by a random angle per point."""
    i = np.arange(samples) + 0.5
    rad = np.sqrt(i / samples)
    phi = i * _GOLDEN_ANGLE + 2.0 * math.pi * rng.random((len(normals), 1))
    local = np.stack([rad * np.cos(phi), rad * np.sin(phi), np.broadcast_to(np.sqrt(1.0 - rad * rad), phi.shape)], -1)
    a = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t = np.cross(normals, a)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(normals, t)
    return local[..., :1] * t[:, None] + local[..., 1:2] * b[:, None] + local[..., 2:] * normals[:, None]


def environment_terms(
    receiver: Receiver, tracer, occluder: Occluder, environment, samples: int, seed: int, reach: float = 6.0
) -> tuple[np.ndarray, np.ndarray]:
    """``(E_without, delta)``, each ``(H, W, 3)``: the environment's irradiance of every receiver
    without the object, and the object's change to it (module convention) at receivers within
    ``reach`` bounding radii of the object that see it above their horizon (0 elsewhere)."""
    H, W = receiver.valid.shape
    e0 = np.zeros((H, W, 3))
    e0[receiver.valid] = sh9_irradiance(environment, receiver.normals[receiver.valid])
    delta = np.zeros((H, W, 3))
    q = occluder.center - np.where(receiver.valid[..., None], receiver.points, 0.0)
    dist = np.linalg.norm(q, axis=-1)
    near = receiver.valid & (dist < reach * occluder.radius)
    near &= np.einsum("hwc,hwc->hw", q, receiver.normals) > -occluder.radius
    if not near.any():
        return e0, delta
    rng = np.random.default_rng(int(seed))
    pts = receiver.points[near] + receiver.eps * receiver.normals[near]
    dirs = _cosine_directions(receiver.normals[near], samples, rng)
    o = np.repeat(pts, samples, 0)
    d = dirs.reshape(-1, 3)
    t_obj = tracer.cast_object(o, d)["t"]
    hit = np.isfinite(t_obj) & (t_obj < tracer.cast_background(o, d).t)
    change = np.zeros((len(o), 3))
    if hit.any():
        tr = tracer.trace(o[hit], d[hit])
        out = tr.kind != HitKind.TRAPPED
        seen = np.zeros((int(hit.sum()), 3))
        seen[out] = _weights(tr)[out] * environment(tr.direction[out])
        first = np.isfinite(tr.reflected).all(-1)
        seen[first] += tr.fresnel[first, None] * environment(tr.reflected[first])
        change[hit] = seen - environment(d[hit])
    delta[near] = math.pi * change.reshape(-1, samples, 3).mean(1)
    return e0, delta
