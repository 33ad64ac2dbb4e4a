"""Traced shadows and caustics: the ball lens's focus and the caustic's centre against closed forms,
the light through a sphere against the Fresnel integral, a plate's internal reflections against
the geometric series, a point light's falloff where its light lands, the environment's irradiance
against the hemisphere formula, and the differential compositing."""

import math

import numpy as np
import pytest
import torch

from snell_bench.optics.tracer import SceneTracer
from snell_bench.relight.lights import KeyLight, LightRig, hemisphere_environment
from snell_bench.relight.shadow import Occluder
from snell_bench.relight.traced import TracedRelighter, apply_ratio, relight_ratio
from snell_bench.relight.transport import caustic_irradiance, internal_reflections, receiver_from_depth
from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import build_background
from snell_bench.scene.objects import GlassObject

N = 1.5
R = 0.25
CENTRE = np.array([0.0, 0.0, 2.0])
BFD = N * 2 * R / (4 * (N - 1)) - R  # the ball lens's back focal distance from its surface


def _sphere(subdivisions: int = 5) -> GlassObject:
    obj = GlassObject.sphere(subdivisions=subdivisions)  # unit diameter, bottom at the origin
    T = np.diag([2 * R, 2 * R, 2 * R, 1.0])
    T[:3, 3] = CENTRE - np.array([0.0, R, 0.0])
    return obj.transformed(T)


def _wall(z: float, width: int = 160, fov: float = 50.0):
    cam = Camera.from_fov(width, width, fov)
    return cam, np.full(cam.shape, z, np.float32)


def _exact_crossing(b: float) -> float:
    """Where a ray parallel to the axis at height ``b`` leaves a perfect sphere (radius R, index N)
    and crosses the axis, measured from the sphere's back surface along the axis (2-D Snell)."""
    t1 = math.asin(b / R)  # incidence
    t2 = math.asin(math.sin(t1) / N)  # refraction
    deviation = 2 * (t1 - t2)  # total turn towards the axis after both surfaces
    # the entry point's radius is at pi - t1 from the axis, the chord turns it by pi - 2 t2
    phi = 2 * t2 - t1
    x, z = R * math.sin(phi), R * math.cos(phi)  # the exit point (x off the axis, z along it from the centre)
    z_cross = z + x / math.tan(deviation)
    return z_cross - R


def test_the_exact_sphere_focuses_at_the_ball_lens_back_focal_distance():
    assert _exact_crossing(1e-5 * R) == pytest.approx(BFD, rel=1e-8)
    assert _exact_crossing(0.5 * R) < BFD  # spherical aberration: marginal rays focus closer


def test_traced_rays_cross_the_axis_where_the_exact_sphere_sends_them():
    """Rays parallel to the axis through the mesh sphere cross it where the exact sphere's do, within
    the bound of the corner normals' error (entry and exit normals off radial by at most ``err``
    turn the exit ray by at most 2 (1 + 1/N) err, which moves the crossing by that over the ray's
    angle to the axis times its distance)."""
    obj = _sphere()
    cam, depth = _wall(CENTRE[2] + 4 * R)
    tracer = SceneTracer(build_background(depth, cam, extra_points=obj.vertices), obj, max_bounces=4)
    b = np.linspace(0.1, 0.4, 7) * R
    origins = np.stack([b, np.zeros_like(b), np.full_like(b, CENTRE[2] - 2 * R)], 1)
    tr = tracer.trace(origins, np.tile([0.0, 0.0, 1.0], (len(b), 1)))
    p, d = tr.origin, tr.direction  # the last segment: where it leaves the sphere, and its direction
    crossing = p[:, 2] + p[:, 0] / -d[:, 0] * d[:, 2] - (CENTRE[2] + R)
    cn = obj.corner_normals()
    radial = obj.vertices[obj.faces] - CENTRE
    radial /= np.linalg.norm(radial, axis=-1, keepdims=True)
    err = float(np.arccos(np.clip(np.einsum("fcd,fcd->fc", cn, radial), -1, 1)).max())
    angle = np.abs(np.arctan2(d[:, 0], d[:, 2]))
    dist = np.hypot(p[:, 0], crossing + CENTRE[2] + R - p[:, 2])
    bound = 2 * (1 + 1 / N) * err * dist / angle + 1e-6
    exact = np.array([_exact_crossing(x) for x in b])
    assert (np.abs(crossing - exact) <= bound).all(), (crossing - exact, bound)


def test_caustic_centre_lies_on_the_line_through_the_centre_along_the_light():
    """A tilted light: the caustic on a wall at the focal distance is centred where the line through
    the sphere's centre along the light meets the wall, within 2 px."""
    obj = _sphere()
    z_wall = CENTRE[2] + R + BFD
    cam, depth = _wall(z_wall)
    a = math.radians(12.0)
    key = KeyLight([math.sin(a), 0.0, -math.cos(a)], [1.0, 1.0, 1.0], 0.0)
    tracer = SceneTracer(build_background(depth, cam, extra_points=obj.vertices), obj, max_bounces=8)
    rec = receiver_from_depth(depth, cam)
    E, record = caustic_irradiance(
        rec, cam, depth, tracer, Occluder.from_mesh(obj.vertices, obj.faces), key, 200_000, 0, 0.0
    )
    flux = E[..., 1] * rec.area
    v, u = np.mgrid[0 : cam.height, 0 : cam.width]
    centroid = np.array([(flux * u).sum(), (flux * v).sum()]) / flux.sum()
    t = (z_wall - CENTRE[2]) / math.cos(a)
    target, _ = cam.project(CENTRE - t * key.direction)
    assert np.linalg.norm(centroid - target) <= 2.0, (centroid, target)
    peak = np.unravel_index(np.argmax(flux), flux.shape)
    assert np.linalg.norm(np.array(peak[::-1]) - target) <= 2.0


def test_light_through_a_sphere_is_the_fresnel_integral():
    """Light along the axis: the refracted flux that reaches the wall is E π R² times the mean of
    (1 - R(θ))² over the disc (entry and exit reflect alike on a sphere; nothing is absorbed); the
    tolerance covers the mesh's silhouette and normals (2e-3) and the stratified beam (1e-3)."""
    from snell_bench.optics.functional import fresnel_cos

    obj = _sphere()
    cam, depth = _wall(CENTRE[2] + R + BFD, fov=60.0)
    key = KeyLight([0.0, 0.0, -1.0], [2.0, 1.0, 0.5], 0.0)
    tracer = SceneTracer(build_background(depth, cam, extra_points=obj.vertices), obj, max_bounces=8)
    rec = receiver_from_depth(depth, cam)
    _, record = caustic_irradiance(
        rec, cam, depth, tracer, Occluder.from_mesh(obj.vertices, obj.faces), key, 200_000, 1, 0.0
    )
    s = np.linspace(0.0, 1.0, 200_001)[:-1] + 0.5 / 200_000  # b / R
    cos = torch.from_numpy(np.sqrt(1 - s**2))
    mean = float(((1 - fresnel_cos(cos, 1.0, N)) ** 2 * 2 * torch.from_numpy(s)).mean())
    expected = np.array(key.irradiance) * math.pi * R**2 * mean
    np.testing.assert_allclose(record["flux_refracted_on_receivers"], expected, rtol=3e-3)


def test_internal_reflections_of_a_slab_sum_to_the_geometric_series():
    """A plate of glass: every interface of a ray meets it at the same angle, so of the light
    entering it the share leaving after k internal reflections is (1 - R)² R^k; with the
    first-surface reflection, G generations leave R + (1 - R)(1 - R^(G+1)) in all, and generation k
    starts after k + 1 crossings of d / cos θt. Flat faces (shading normal = face normal, adjoint
    factor 1), so only rounding is left; incidence 50-75°, where every term exceeds the 1e-4 cut."""
    import trimesh

    from snell_bench.optics.functional import fresnel_cos

    thick = 0.2
    plate = trimesh.creation.box(extents=(40.0, 40.0, thick))
    plate.apply_translation(CENTRE)
    obj = GlassObject(mesh=plate, ior=N, name="plate")
    cam, depth = _wall(CENTRE[2] + 4.0)
    tracer = SceneTracer(build_background(depth, cam, extra_points=obj.vertices), obj, max_bounces=4)
    theta = np.radians(np.linspace(50.0, 75.0, 11))
    d = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], 1)
    origins = CENTRE - (thick / 2 + 0.1) / d[:, 2:3] * d
    tr = tracer.trace(origins, d, from_light=True)
    crossing = thick / np.sqrt(1 - (np.sin(theta) / N) ** 2)
    generations = 3
    total = tr.fresnel + (1 - tr.fresnel) * tr.interface_transmission * tr.adjoint
    for k, (sub, weight, before, index) in enumerate(internal_reflections(tracer, tr, generations)):
        assert len(index) == len(theta) and (sub.bounces == 1).all()  # each branch leaves at its first interface
        np.testing.assert_allclose(before, (k + 1) * crossing[index], rtol=1e-9, atol=4 * (k + 1) * tracer.eps)
        total += np.bincount(index, weights=weight, minlength=len(theta))
    Rb = fresnel_cos(torch.from_numpy(np.cos(theta)), 1.0, N).numpy()
    np.testing.assert_allclose(tr.adjoint, 1.0, rtol=1e-12)
    np.testing.assert_allclose(total, Rb + (1 - Rb) * (1 - Rb ** (generations + 1)), rtol=1e-9)
    assert ((1 - Rb) * (Rb - Rb ** (generations + 1)) > 1e-3).all()  # what the branches carry


def test_a_point_lights_falloff_applies_where_its_light_lands():
    """The shading's ``1 / (d² + falloff)``: with a falloff, each pixel's caustic is the one without
    times ``d² / (d² + falloff)`` at the point where its light lands, within that factor's change over
    the pixel's footprint (not one factor at the object's distance)."""
    obj = _sphere()
    cam, depth = _wall(CENTRE[2] + R + BFD, fov=60.0)
    tracer = SceneTracer(build_background(depth, cam, extra_points=obj.vertices), obj, max_bounces=8)
    rec = receiver_from_depth(depth, cam)
    occ = Occluder.from_mesh(obj.vertices, obj.faces)
    light = CENTRE + np.array([0.05, -0.1, -1.0])
    falloff = 0.8
    E = {}
    for f in (0.0, falloff):
        key = KeyLight(CENTRE - light, [1.0, 1.0, 1.0], 0.0, position=light, falloff=f)
        E[f], _ = caustic_irradiance(rec, cam, depth, tracer, occ, key, 100_000, 3, 0.0)
    lit = E[0.0][..., 1] > 1e-3 * E[0.0][..., 1].max()
    d = np.linalg.norm(rec.points - light, axis=-1)
    g = d**2 / (d**2 + falloff)
    slope = 2 * d * falloff / (d**2 + falloff) ** 2
    reach = 0.5 * (np.linalg.norm(rec.du, axis=-1) + np.linalg.norm(rec.dv, axis=-1))
    ratio = E[falloff][..., 1] / np.where(lit, E[0.0][..., 1], 1.0)
    assert (np.abs(ratio - g)[lit] <= (slope * reach)[lit] + 1e-9).all()
    dc = np.linalg.norm(CENTRE - light)  # one factor at the object's distance misses it by far
    assert np.abs(dc**2 / (dc**2 + falloff) - g[lit]).min() > 10 * (slope * reach)[lit].max()


def test_environment_seen_through_nothing_changes_nothing_and_compositing_keeps_untouched_pixels():
    """An object far from every receiver changes no pixel: the ratio is 1 and the image is returned
    bit for bit; a ratio of 2 in linear RGB doubles the linear value."""
    obj = _sphere()
    cam, depth = _wall(CENTRE[2] + 40.0)
    lights = LightRig(keys=(), environment=hemisphere_environment([1, 1, 1], [0.2, 0.2, 0.2], [0, -1, 0]))
    tracer = SceneTracer(build_background(depth, cam, extra_points=obj.vertices), obj)
    from types import SimpleNamespace

    ratio, _ = relight_ratio(
        SimpleNamespace(depth=depth, camera=cam),
        obj,
        lights,
        tracer=tracer,
        shadow_samples=4,
        caustic_rays=1000,
        env_samples=8,
        seed=0,
    )
    assert (ratio == 1.0).all()
    img = torch.rand(1, 3, *cam.shape, generator=torch.Generator().manual_seed(0))
    assert torch.equal(apply_ratio(img, ratio), img)
    from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear

    half = torch.full((1, 3, 2, 2), 0.2)
    out = apply_ratio(half, np.full((2, 2, 3), 2.0))
    torch.testing.assert_close(srgb_to_linear(out), 2 * srgb_to_linear(half), rtol=1e-5, atol=1e-6)
    assert linear_to_srgb is not None


def test_relighter_refuses_bad_settings():
    with pytest.raises(ValueError, match="lights='sun'"):
        TracedRelighter(lights="sun")
    with pytest.raises(ValueError, match="caustic_rays=-1"):
        TracedRelighter(caustic_rays=-1)
